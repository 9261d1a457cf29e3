/* Heights from positions and normals (fuse.h): the normal equations
 * (W + DxᵀDx + DyᵀDy) z = W z0 + Dxᵀ(2p gx) + Dyᵀ(2p gy), applied matrix-free on the grid
 * and solved by Jacobi-preconditioned conjugate gradients. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#include "fuse.h"
#include "macro.h"

#define DEG (180.0 / M_PI)
#define FUSE_WEIGHT_RATIO_MAX 100.0   /* (σ_ref/σ_t)² is kept within [1/100, 100] */

void imp_fuse_params_default(struct imp_fuse_params *ret) {
        *ret = (struct imp_fuse_params) { .lambda = 0.3, .min_nz = 0.2, .max_iter = 500, .tol = 1e-6 };
}

struct system {
        int nx, ny;
        const uint8_t *in;            /* unknown (mask) */
        const uint8_t *rx, *ry;       /* a gradient row is centred on this texel */
        const double *w;              /* position weight; 0 off the mask */
        double *tx, *ty;              /* scratch: row values */
};

/* out = A v over the mask (A = W + DxᵀDx + DyᵀDy); out is 0 off the mask. */
static void apply(const struct system *s, const double *v, double *out) {
        int nx = s->nx, ny = s->ny;
        #pragma omp parallel for schedule(static)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        s->tx[t] = s->rx[t] ? v[t + 1] - v[t - 1] : 0;
                        s->ty[t] = s->ry[t] ? v[t + nx] - v[t - nx] : 0;
                }
        #pragma omp parallel for schedule(static)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!s->in[t]) {
                                out[t] = 0;
                                continue;
                        }
                        double a = s->w[t] * v[t];
                        if (i > 0) a += s->tx[t - 1];
                        if (i + 1 < nx) a -= s->tx[t + 1];
                        if (j > 0) a += s->ty[t - nx];
                        if (j + 1 < ny) a -= s->ty[t + nx];
                        out[t] = a;
                }
}

static double dot(const double *a, const double *b, size_t n) {
        double s = 0;
        #pragma omp parallel for schedule(static) reduction(+ : s)
        for (size_t i = 0; i < n; i++)
                s += a[i] * b[i];
        return s;
}

/* Slope the normal asks for, or false when it gives none. */
static bool slope(const float *n, double min_nz, double *gx, double *gy) {
        if (!(n[2] >= min_nz) || !isfinite(n[0]) || !isfinite(n[1]))
                return false;
        *gx = -n[0] / n[2], *gy = -n[1] / n[2];
        return true;
}

/* Mean angle between the normals and the central-difference normals of z (texels with
 * both rows). */
static double agreement_deg(const struct system *s, const double *z, const float *normal, double p) {
        double sum = 0;
        long cnt = 0;
        for (size_t t = 0; t < (size_t) s->nx * s->ny; t++) {
                if (!s->rx[t] || !s->ry[t])
                        continue;
                double gx = (z[t + 1] - z[t - 1]) / (2 * p), gy = (z[t + s->nx] - z[t - s->nx]) / (2 * p);
                const float *n = &normal[3 * t];
                double c = (-gx * n[0] - gy * n[1] + n[2]) / sqrt(gx * gx + gy * gy + 1);
                sum += acos(fmax(-1.0, fmin(1.0, c))) * DEG;
                cnt++;
        }
        return cnt ? sum / cnt : 0;
}

static int cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return (x > y) - (x < y);
}

/* Median of the positive finite σ over the measured mask texels (0 when none). */
static double sigma_ref(const float *sigma, const uint8_t *in, const uint8_t *mask, size_t n) {
        if (!sigma)
                return 0;
        _cleanup_free_ float *v = malloc((n ? n : 1) * sizeof *v);
        size_t m = 0;
        if (!v)
                return 0;
        for (size_t t = 0; t < n; t++)
                if (in[t] && !(mask && mask[t] == 2) && isfinite(sigma[t]) && sigma[t] > 0)
                        v[m++] = sigma[t];
        if (!m)
                return 0;
        qsort(v, m, sizeof *v, cmp_float);
        return v[m / 2];
}

int imp_fuse_heights(int nx, int ny, double pitch_mm, float *height_mm, const float *normal,
                     const float *sigma_mm, const uint8_t *mask, const struct imp_fuse_params *p,
                     struct imp_fuse_stats *ret_stats) {
        if (nx <= 0 || ny <= 0 || !(pitch_mm > 0) || !height_mm || !normal || !p || !(p->lambda > 0) ||
            p->max_iter < 0 || !(p->tol >= 0))
                return -EINVAL;
        size_t n = (size_t) nx * ny;
        _cleanup_free_ uint8_t *flags = calloc(n, 3);
        _cleanup_free_ double *buf = malloc(n * 10 * sizeof(double));
        if (!flags || !buf)
                return -ENOMEM;
        uint8_t *in = flags, *rx = flags + n, *ry = flags + 2 * n;
        double *z = buf, *b = buf + n, *r = buf + 2 * n, *d = buf + 3 * n, *q = buf + 4 * n, *s = buf + 5 * n;
        double *w = buf + 6 * n, *prec = buf + 7 * n, *tx = buf + 8 * n, *ty = buf + 9 * n;
        struct imp_fuse_stats st = {};
        for (size_t t = 0; t < n; t++) {
                in[t] = (!mask || mask[t]) && isfinite(height_mm[t]);
                st.n_texels += in[t];
        }
        double sref = sigma_ref(sigma_mm, in, mask, n);
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        double gx = 0, gy = 0;
                        bool g = in[t] && slope(&normal[3 * t], p->min_nz, &gx, &gy);
                        rx[t] = g && i > 0 && i + 1 < nx && in[t - 1] && in[t + 1];
                        ry[t] = g && j > 0 && j + 1 < ny && in[t - nx] && in[t + nx];
                        st.n_rows += rx[t] + ry[t];
                        tx[t] = rx[t] ? 2 * pitch_mm * gx : 0;
                        ty[t] = ry[t] ? 2 * pitch_mm * gy : 0;
                        double ratio = 1;
                        if (sref > 0 && sigma_mm && isfinite(sigma_mm[t]) && sigma_mm[t] > 0)
                                ratio = IMP_CLAMP((sref / sigma_mm[t]) * (sref / sigma_mm[t]),
                                                  1 / FUSE_WEIGHT_RATIO_MAX, FUSE_WEIGHT_RATIO_MAX);
                        /* mask value 2 (IMP_HF_MASK_FILLED): no position, height from the
                         * normals and the measured texels it is connected to */
                        w[t] = in[t] && !(mask && mask[t] == 2) ? p->lambda * ratio : 0;
                        z[t] = in[t] ? height_mm[t] : 0;
                }
        /* b = W z0 + Dxᵀ tx + Dyᵀ ty, Jacobi diagonal. */
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!in[t]) {
                                b[t] = 0, prec[t] = 0;
                                continue;
                        }
                        double a = w[t] * z[t], dg = w[t];
                        if (i > 0) a += tx[t - 1], dg += rx[t - 1];
                        if (i + 1 < nx) a -= tx[t + 1], dg += rx[t + 1];
                        if (j > 0) a += ty[t - nx], dg += ry[t - nx];
                        if (j + 1 < ny) a -= ty[t + nx], dg += ry[t + nx];
                        b[t] = a;
                        prec[t] = dg > 0 ? 1 / dg : 0;   /* 0: a filled texel in no row keeps z0 */
                }
        struct system sys = { nx, ny, in, rx, ry, w, tx, ty };
        st.agree_deg_before = agreement_deg(&sys, z, normal, pitch_mm);
        /* CG from z0. */
        apply(&sys, z, q);
        for (size_t t = 0; t < n; t++) {
                r[t] = b[t] - q[t];
                s[t] = prec[t] * r[t];
                d[t] = s[t];
        }
        double bn = sqrt(dot(b, b, n)), rs = dot(r, s, n), rn = sqrt(dot(r, r, n));
        int it = 0;
        while (it < p->max_iter && bn > 0 && rn > p->tol * bn) {
                apply(&sys, d, q);
                double dq = dot(d, q, n);
                if (!(dq > 0))
                        break;
                double alpha = rs / dq;
                #pragma omp parallel for schedule(static)
                for (size_t t = 0; t < n; t++) {
                        z[t] += alpha * d[t];
                        r[t] -= alpha * q[t];
                        s[t] = prec[t] * r[t];
                }
                double rs2 = dot(r, s, n), beta = rs2 / rs;
                rs = rs2;
                #pragma omp parallel for schedule(static)
                for (size_t t = 0; t < n; t++)
                        d[t] = s[t] + beta * d[t];
                rn = sqrt(dot(r, r, n));
                it++;
        }
        st.iterations = it;
        st.residual_rel = bn > 0 ? rn / bn : 0;
        st.agree_deg_after = agreement_deg(&sys, z, normal, pitch_mm);
        double ss = 0;
        for (size_t t = 0; t < n; t++)
                if (in[t] && isfinite(z[t])) {
                        ss += (z[t] - height_mm[t]) * (z[t] - height_mm[t]);
                        height_mm[t] = (float) z[t];
                }
        st.change_rms_mm = st.n_texels ? sqrt(ss / st.n_texels) : 0;
        if (ret_stats)
                *ret_stats = st;
        return 0;
}
