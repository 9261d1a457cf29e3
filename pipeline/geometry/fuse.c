/* Heights from positions and normals (fuse.h): the normal equations
 * (W + DxᵀDx + DyᵀDy) z = W z0 + Dxᵀ(2p gx) + Dyᵀ(2p gy), applied matrix-free on the grid
 * and solved by Jacobi-preconditioned conjugate gradients. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "fuse.h"
#include "image.h"
#include "macro.h"
#include "numerics.h"
#include "quality.h"

#define DEG (180.0 / M_PI)
#define FUSE_WEIGHT_RATIO_MAX 100.0   /* (σ_ref/σ_t)² is kept within [1/100, 100] */

void imp_fuse_params_default(struct imp_fuse_params *ret) {
        *ret = (struct imp_fuse_params) { .lambda = 0.3, .min_nz = 0.2, .max_iter = 500, .tol = 1e-6,
                                          .max_row_sigma = 3, .fill_normal_sigma_deg = 3,
                                          .segment_max = 4, .row_weight_max = 10, .row_weight_gain = 6 };
}

struct system {
        int nx, ny;
        const uint8_t *in;            /* unknown (mask) */
        const uint8_t *rx, *ry;       /* a gradient row is centred on this texel */
        const double *w;              /* position weight; 0 off the mask */
        double *tx, *ty;              /* the rows' right-hand sides (2p g), times their weight */
        double *wx, *wy;              /* the rows' weights (1 unless weighted by the normal's σ) */
};

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
        return imp_select_kth_float(v, m, m / 2);   /* the sorted array's element, without sorting */
}

/* Slope σ of a normal with angular σ sd (degrees): d(tan θ)/dθ = 1/cos²θ = 1/nz². */
static double slope_sigma(const float *n, double sd) {
        double nz = fmax(n[2], 0.05);
        return tan(fmin(sd, 80.0) / DEG) / (nz * nz);
}

/* The slopes the normals ask for (gx, gy; NAN where a normal gives none). */
struct slopes {
        double *gx, *gy;
};

static void photometric_slopes(size_t n, const float *normal, const uint8_t *in, double min_nz, struct slopes *g) {
        for (size_t t = 0; t < n; t++) {
                double x, y;
                bool ok = in[t] && slope(&normal[3 * t], min_nz, &x, &y);
                g->gx[t] = ok ? x : NAN, g->gy[t] = ok ? y : NAN;
        }
}

/* Whether the gradient row over texels a, b (centred on t) agrees with the measured
 * heights within max_row_sigma × its σ. Rows touching a filled texel have no position
 * to disagree with. */
static bool row_consistent(const float *h, const float *sigma, const uint8_t *mask, double sd,
                           const float *n, double grad, double pitch, size_t a, size_t b,
                           const struct imp_fuse_params *p) {
        if (mask && (mask[a] == 2 || mask[b] == 2))
                return true;
        double sa = sigma ? sigma[a] : 0, sb = sigma ? sigma[b] : 0;
        double sg = 2 * pitch * slope_sigma(n, sd);
        double sr = sqrt(sa * sa + sb * sb + sg * sg);
        return fabs((h[b] - h[a]) - 2 * pitch * grad) <= p->max_row_sigma * sr;
}

/* The back-off over longer baselines. Why the row check alone lets wrong normals through:
 * its tolerance holds the normal's own slope σ, tan σn / nz², which on the steep flank of a
 * ridge (a 0.5 mm ridge on the canvas tilted 25° under the dome, hard-tilted-25) is as
 * large as the error, and it looks at two texels, where a normal's error is a fraction of
 * the heights' noise; the solve then weights every accepted row alike, and the integration
 * adds up the coherent errors along the flank (20–30° off there: 15.3 µm height RMSE fused
 * against 5.7 µm from the positions alone). Nehab et al. 2005 (§3, "Combining positions
 * and normals") rest on the normals being right at the high frequencies and the positions
 * at the low ones; where the normals integrated over a few texels disagree with the
 * positions beyond the positions' σ, the positions know those frequencies better. So the
 * slopes are integrated (trapezoids) along the segment of half-length L = 2 … segment_max
 * centred on t and compared with the measured height difference of its ends: beyond
 * max_row_sigma × the ends' height σ (the normals' σ left out on purpose, it is what
 * hides the error) the row is left out. A segment reaching a texel without a position or
 * a slope stops there. Returns whether every segment agrees. */
static bool segment_consistent(const float *h, const float *sigma, const uint8_t *mask, const uint8_t *in,
                               const double *g, double pitch, size_t t, long stride, int room_lo, int room_hi,
                               const struct imp_fuse_params *p) {
        double integ = 0;
        int Lmax = p->segment_max < room_lo ? p->segment_max : room_lo;
        Lmax = Lmax < room_hi ? Lmax : room_hi;
        for (int L = 1; L <= Lmax; L++) {
                size_t a = t - (size_t) L * stride, b = t + (size_t) L * stride;
                if (!in[a] || !in[b] || !isfinite(g[a]) || !isfinite(g[b]) || (mask && (mask[a] == 2 || mask[b] == 2)))
                        return true;
                integ += pitch * 0.5 * (g[a] + g[a + stride] + g[b - stride] + g[b]);
                if (L < 2)
                        continue;
                double sa = sigma[a], sb = sigma[b];
                if (fabs((h[b] - h[a]) - integ) > p->max_row_sigma * sqrt(sa * sa + sb * sb))
                        return false;
        }
        return true;
}

/* Unknowns, gradient rows (with the back-off), position weights and z0. */
static void setup_rows(int nx, int ny, double pitch_mm, const float *height_mm, const float *normal,
                       const float *sigma_mm, const uint8_t *mask, const struct imp_fuse_params *p,
                       const struct imp_fuse_texels *tex, const struct slopes *gs, struct system *sys, double *z,
                       struct imp_fuse_stats *st) {
        uint8_t *in = (uint8_t *) sys->in, *rx = (uint8_t *) sys->rx, *ry = (uint8_t *) sys->ry;
        double *w = (double *) sys->w, *tx = sys->tx, *ty = sys->ty;
        size_t n = (size_t) nx * ny;
        const float *nsd = tex ? tex->normal_sigma_deg : NULL;
        double sref = sigma_ref(sigma_mm, in, mask, n);
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        double gx = gs->gx[t], gy = gs->gy[t];
                        bool g = in[t] && isfinite(gx) && isfinite(gy);
                        rx[t] = g && i > 0 && i + 1 < nx && in[t - 1] && in[t + 1];
                        ry[t] = g && j > 0 && j + 1 < ny && in[t - nx] && in[t + nx];
                        if (nsd && (rx[t] || ry[t])) {
                                bool okx = !rx[t] || (row_consistent(height_mm, sigma_mm, mask, nsd[t], &normal[3 * t],
                                                                     gx, pitch_mm, t - 1, t + 1, p) &&
                                                      (!sigma_mm ||
                                                       segment_consistent(height_mm, sigma_mm, mask, in, gs->gx, pitch_mm,
                                                                          t, 1, i, nx - 1 - i, p)));
                                bool oky = !ry[t] || (row_consistent(height_mm, sigma_mm, mask, nsd[t], &normal[3 * t],
                                                                     gy, pitch_mm, t - nx, t + nx, p) &&
                                                      (!sigma_mm ||
                                                       segment_consistent(height_mm, sigma_mm, mask, in, gs->gy, pitch_mm,
                                                                          t, nx, j, ny - 1 - j, p)));
                                st->n_rows_rejected += !okx + !oky;
                                if (!okx || !oky) {
                                        st->n_backed_off += (!okx || !rx[t]) && (!oky || !ry[t]);
                                        if (tex->flags)
                                                tex->flags[t] |= IMP_TEXEL_PHOTOMETRIC_REJECTED;
                                }
                                rx[t] = rx[t] && okx;
                                ry[t] = ry[t] && oky;
                        }
                        st->n_rows += rx[t] + ry[t];
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
}

/* Whether a filled texel lies within FILL_ROW_REACH texels of t along the row's axis
 * (stride 1: x, nx: y). */
#define FILL_ROW_REACH 10
static bool near_filled(const struct system *s, const uint8_t *mask, size_t t, size_t stride) {
        if (!mask)
                return false;
        long i = (long) (stride == 1 ? t % (size_t) s->nx : t / (size_t) s->nx);
        long len = stride == 1 ? s->nx : s->ny;
        for (long d = -FILL_ROW_REACH; d <= FILL_ROW_REACH; d++)
                if (i + d >= 0 && i + d < len && mask[(long) t + d * (long) stride] == 2)
                        return true;
        return false;
}

/* The rows' weights (fuse.h row_weight_max): (σ_ref/σ_t)² with σ_t the slope σ of the
 * row's normal (slope_sigma of its normal_sigma_deg), σ_ref their median over the rows,
 * within [1/row_weight_max, row_weight_max]; 1 without normal σ or with row_weight_max ≤ 1.
 * The right-hand sides tx, ty are scaled by them. Least squares with each residual weighted
 * by its inverse variance (Nehab et al. 2005 §3 weigh positions against normals by their
 * noise; here each normal by its own, as the positions already are). */
static int row_weights(size_t n, const float *normal, const uint8_t *mask, const struct imp_fuse_params *p,
                       const struct imp_fuse_texels *tex, struct system *s) {
        for (size_t t = 0; t < n; t++)
                s->wx[t] = s->rx[t], s->wy[t] = s->ry[t];
        const float *nsd = !tex ? NULL : tex->row_sigma_deg ? tex->row_sigma_deg : tex->normal_sigma_deg;
        if (!nsd || !(p->row_weight_max > 1))
                return 0;
        _cleanup_free_ float *v = malloc((n ? n : 1) * sizeof *v);
        if (!v)
                return -ENOMEM;
        size_t m = 0;
        for (size_t t = 0; t < n; t++)
                if ((s->rx[t] || s->ry[t]) && isfinite(nsd[t]) && nsd[t] > 0)
                        v[m++] = (float) slope_sigma(&normal[3 * t], nsd[t]);
        if (!m)
                return 0;
        double ref = imp_select_kth_float(v, m, m / 2);
        for (size_t t = 0; t < n; t++) {
                if (!(s->rx[t] || s->ry[t]))
                        continue;
                double sg = isfinite(nsd[t]) && nsd[t] > 0 ? slope_sigma(&normal[3 * t], nsd[t]) : ref;
                double wr = IMP_CLAMP((ref / sg) * (ref / sg), 1 / p->row_weight_max, p->row_weight_max);
                /* a row within FILL_ROW_REACH of a filled texel (no position) keeps weight
                 * 1: there the rows alone shape the heights, and weighting them measured
                 * worse (the demo's filled texels: 5.94 µm unweighted; 7.36 µm with only
                 * the rows touching one kept at 1, 6.97 within 3 texels, 6.21 within 10) */
                bool fx = near_filled(s, mask, t, 1), fy = near_filled(s, mask, t, s->nx);
                wr *= p->row_weight_gain;
                s->wx[t] *= fx ? 1 : wr, s->tx[t] *= fx ? 1 : wr;
                s->wy[t] *= fy ? 1 : wr, s->ty[t] *= fy ? 1 : wr;
        }
        return 0;
}

/* (A v)_t for an unknown t (A = W + DxᵀDx + DyᵀDy), the rows' differences taken straight
 * from v (no row scratch, so a thread needs no other thread's row values). Inlined by
 * force: as a call (gcc's choice once it has two callers) the fusion took 1.7x as long. */
static inline __attribute__((always_inline)) double apply_at(const struct system *s, const double *v, size_t t,
                                                             int i, int j) {
        int nx = s->nx;
        double a = s->w[t] * v[t];
        if (j >= 2 && j + 2 < s->ny) {
                /* two rows from the edges every neighbour read is in the grid, and a row
                 * that is not used has weight 0 (row_weights; at a row's ends too, rx
                 * needs both neighbours): no tests, the same sums (a term of +0) */
                size_t nx2 = 2 * (size_t) nx;
                a += s->wx[t - 1] * (v[t] - v[t - 2]);
                a -= s->wx[t + 1] * (v[t + 2] - v[t]);
                a += s->wy[t - nx] * (v[t] - v[t - nx2]);
                a -= s->wy[t + nx] * (v[t + nx2] - v[t]);
                return a;
        }
        if (i > 0 && s->rx[t - 1]) a += s->wx[t - 1] * (v[t] - v[t - 2]);
        if (i + 1 < s->nx && s->rx[t + 1]) a -= s->wx[t + 1] * (v[t + 2] - v[t]);
        if (j > 0 && s->ry[t - nx]) a += s->wy[t - nx] * (v[t] - v[t - 2 * (size_t) nx]);
        if (j + 1 < s->ny && s->ry[t + nx]) a -= s->wy[t + nx] * (v[t + 2 * (size_t) nx] - v[t]);
        return a;
}

/* out = A v over [t0, t1) (0 off the mask); returns Σ v·out over the range. */
static double apply_range(const struct system *s, const double *v, double *out, size_t t0, size_t t1) {
        int i = (int) (t0 % s->nx), j = (int) (t0 / s->nx);
        double dot = 0;
        for (size_t t = t0; t < t1; t++) {
                out[t] = s->in[t] ? apply_at(s, v, t, i, j) : 0;
                dot += v[t] * out[t];
                if (++i == s->nx)
                        i = 0, j++;
        }
        return dot;
}

/* The next direction d = s + β d and its image q = A s + β q (= A d) over [t0, t1);
 * returns Σ d·q over the range. */
static double direction_range(const struct system *sys, const double *s, double beta, double *d, double *q,
                              size_t t0, size_t t1) {
        int i = (int) (t0 % sys->nx), j = (int) (t0 / sys->nx);
        double dot = 0;
        for (size_t t = t0; t < t1; t++) {
                double as = sys->in[t] ? apply_at(sys, s, t, i, j) : 0;
                d[t] = s[t] + beta * d[t];
                q[t] = as + beta * q[t];
                dot += d[t] * q[t];
                if (++i == sys->nx)
                        i = 0, j++;
        }
        return dot;
}

#define CG_PAD 8   /* doubles between two threads' partial sums (a cache line) */

/* Sum of the threads' partial sums k, in thread order (the same value in every thread). */
static double sum_parts(const double *part, int nthr, int k) {
        double s = 0;
        for (int u = 0; u < nthr; u++)
                s += part[u * CG_PAD + k];
        return s;
}

struct cg {
        const struct system *sys;
        const double *b, *prec;
        double *z, *r, *d, *q, *s;
        double *part;                 /* CG_PAD doubles per thread: the partial sums */
        const struct imp_fuse_params *p;
        int iterations;
        double bn, rn;
};

/* One thread's share of the solve. Every thread runs the same iteration, its contiguous
 * range of texels fixed; the dot products are per-thread partial sums added in thread
 * order, so every thread takes the same decisions and the result does not depend on
 * timing. Two barriers per iteration: A reads its neighbours, so it is applied to the
 * preconditioned residual s (complete after the z, r, s update's barrier) rather than to
 * the new direction d = s + β d, and q = A d follows by linearity as A s + β q (the
 * recurrence of Chronopoulos and Gear's s-step CG, 1989); d and q are then each thread's
 * own range only, and the direction update needs no barrier of its own. A partial sum
 * slot is written only after the barrier that follows every thread's last read of it. */
static void cg_thread(struct cg *c, int tid, int nthr) {
        size_t n = (size_t) c->sys->nx * c->sys->ny, q0 = n / nthr, rem = n % nthr;
        size_t t0 = tid * q0 + ((size_t) tid < rem ? (size_t) tid : rem), t1 = t0 + q0 + ((size_t) tid < rem);
        double *z = c->z, *r = c->r, *d = c->d, *q = c->q, *s = c->s, *part = c->part + tid * CG_PAD;
        const double *b = c->b, *prec = c->prec;
        apply_range(c->sys, z, q, t0, t1);
        part[0] = part[1] = part[2] = 0;
        for (size_t t = t0; t < t1; t++) {
                r[t] = b[t] - q[t];
                s[t] = prec[t] * r[t];
                d[t] = q[t] = 0;   /* β = 0 the first iteration: d = s, q = A s */
                part[0] += b[t] * b[t], part[1] += r[t] * s[t], part[2] += r[t] * r[t];
        }
        #pragma omp barrier
        double bn = sqrt(sum_parts(c->part, nthr, 0)), rs = sum_parts(c->part, nthr, 1);
        double rn = sqrt(sum_parts(c->part, nthr, 2)), beta = 0;
        int it = 0;
        while (it < c->p->max_iter && bn > 0 && rn > c->p->tol * bn) {
                part[3] = direction_range(c->sys, s, beta, d, q, t0, t1);
                #pragma omp barrier
                double dq = sum_parts(c->part, nthr, 3);
                if (!(dq > 0))
                        break;
                double alpha = rs / dq, rs_part = 0, rr_part = 0;
                for (size_t t = t0; t < t1; t++) {
                        z[t] += alpha * d[t];
                        r[t] -= alpha * q[t];
                        s[t] = prec[t] * r[t];
                        rs_part += r[t] * s[t], rr_part += r[t] * r[t];
                }
                part[4] = rs_part, part[5] = rr_part;
                #pragma omp barrier
                double rs2 = sum_parts(c->part, nthr, 4);
                beta = rs2 / rs;
                rs = rs2;
                rn = sqrt(sum_parts(c->part, nthr, 5));
                it++;
        }
        if (tid == 0)
                c->iterations = it, c->bn = bn, c->rn = rn;
}

/* Jacobi-preconditioned CG from z (b: right-hand side, prec: inverse diagonal), the whole
 * solve one parallel region (a fork and join per vector operation spent most of the
 * stage's CPU time spin-waiting on a loaded machine). */
static int solve_cg(const struct system *sys, const double *b, const double *prec, double *z, double *buf,
                    const struct imp_fuse_params *p, struct imp_fuse_stats *st) {
        size_t n = (size_t) sys->nx * sys->ny;
        int maxthr = 1;
#ifdef _OPENMP
        maxthr = omp_get_max_threads();
#endif
        _cleanup_free_ double *part = calloc((size_t) maxthr * CG_PAD, sizeof *part);
        if (!part)
                return -ENOMEM;
        struct cg c = { sys, b, prec, z, buf, buf + n, buf + 2 * n, buf + 3 * n, part, p, 0, 0, 0 };
        #pragma omp parallel
        {
                int tid = 0, nthr = 1;
#ifdef _OPENMP
                tid = omp_get_thread_num(), nthr = omp_get_num_threads();
#endif
                cg_thread(&c, tid, nthr);
        }
        st->iterations = c.iterations;
        st->residual_rel = c.bn > 0 ? c.rn / c.bn : 0;
        return 0;
}

#define FILL_SWEEPS_MAX 64
#define FUSE_SIGMA_UNKNOWN_MM 1e3f   /* σ of a filled texel no measured texel reaches */

/* σ of the filled texels (imp_fuse_texels.sigma_mm): the cheapest path from a measured
 * texel, relaxed by alternating raster sweeps until nothing changes. */
static int fill_sigma(int nx, int ny, double pitch_mm, const float *normal, const float *sigma_mm,
                      const uint8_t *mask, const uint8_t *in, const struct imp_fuse_params *p,
                      const struct imp_fuse_texels *tex, struct imp_fuse_stats *st) {
        size_t n = (size_t) nx * ny;
        _cleanup_free_ float *out = malloc(n * sizeof *out);   /* tex->sigma_mm may alias sigma_mm */
        if (!out)
                return -ENOMEM;
        for (size_t t = 0; t < n; t++) {
                if (!in[t])
                        continue;
                bool filled = mask && mask[t] == 2;
                double s0 = sigma_mm && isfinite(sigma_mm[t]) ? sigma_mm[t] : 0;
                out[t] = filled ? INFINITY : (float) s0;
        }
        /* the sweeps visit only the filled texels, in raster order and back (the same
         * order, and so the same result, as sweeping the whole grid), each one's step
         * computed once */
        size_t nf = 0;
        for (size_t t = 0; t < n && mask; t++)
                nf += in[t] && mask[t] == 2;
        _cleanup_free_ size_t *fill = malloc((nf ? nf : 1) * sizeof *fill);
        _cleanup_free_ double *step = malloc((nf ? nf : 1) * sizeof *step);
        if (!fill || !step)
                return -ENOMEM;
        for (size_t t = 0, k = 0; t < n && mask; t++)
                if (in[t] && mask[t] == 2) {
                        double sd = tex->normal_sigma_deg ? tex->normal_sigma_deg[t] : p->fill_normal_sigma_deg;
                        fill[k] = t, step[k++] = pitch_mm * slope_sigma(&normal[3 * t], sd);
                }
        bool changed = true;
        for (int sweep = 0; sweep < FILL_SWEEPS_MAX && changed; sweep++) {
                changed = false;
                bool fwd = !(sweep & 1);
                for (size_t k0 = 0; k0 < nf; k0++) {
                        size_t k = fwd ? k0 : nf - 1 - k0, t = fill[k];
                        int i = (int) (t % nx), j = (int) (t / nx);
                        double best = out[t];
                        size_t nb[4] = { t - 1, t + 1, t - nx, t + nx };
                        bool ok[4] = { i > 0, i + 1 < nx, j > 0, j + 1 < ny };
                        for (int e = 0; e < 4; e++)
                                if (ok[e] && in[nb[e]] && out[nb[e]] + step[k] < best)
                                        best = out[nb[e]] + step[k];
                        if (best < out[t]) {
                                out[t] = (float) best;
                                changed = true;
                        }
                }
        }
        for (size_t t = 0; t < n; t++) {
                if (!in[t])
                        continue;
                double s0 = sigma_mm && isfinite(sigma_mm[t]) ? sigma_mm[t] : 0;
                if (!(mask && mask[t] == 2)) {
                        tex->sigma_mm[t] = (float) s0;
                        continue;
                }
                /* unreachable from a measured texel: its σ says nothing is known */
                float v = isfinite(out[t]) ? (float) fmax(out[t], s0) : FUSE_SIGMA_UNKNOWN_MM;
                tex->sigma_mm[t] = v;
                st->fill_sigma_max_mm = fmax(st->fill_sigma_max_mm, v);
        }
        return 0;
}

int imp_fuse_heights(int nx, int ny, double pitch_mm, float *height_mm, const float *normal,
                     const float *sigma_mm, const uint8_t *mask, const struct imp_fuse_params *p,
                     const struct imp_fuse_texels *tex, struct imp_fuse_stats *ret_stats) {
        if (nx <= 0 || ny <= 0 || !(pitch_mm > 0) || !height_mm || !normal || !p || !(p->lambda > 0) ||
            p->max_iter < 0 || !(p->tol >= 0) || !(p->max_row_sigma > 0) || !(p->fill_normal_sigma_deg >= 0) ||
            p->segment_max < 0 || p->segment_max > IMP_FUSE_SEGMENT_MAX)
                return -EINVAL;
        size_t n = (size_t) nx * ny;
        /* The solver's 10 doubles a texel (72 MB for a demo tile) are above glibc's largest
         * mmap threshold, so malloc maps them afresh every call: huge pages fault them in
         * ~30x cheaper. The smaller arrays come from the heap, which reuses pages already
         * resident (in an arena they would add to the peak RSS). */
        _cleanup_(imp_image_arena_freep) struct imp_image_arena *arena = NULL;
        if (imp_image_arena_new(&arena) < 0)
                return -ENOMEM;
        _cleanup_free_ uint8_t *flags = calloc(n, 3);
        double *buf = imp_image_arena_alloc(arena, n * 10 * sizeof(double));
        _cleanup_free_ double *gbuf = malloc(n * 4 * sizeof(double));
        if (!flags || !buf || !gbuf)
                return -ENOMEM;
        uint8_t *in = flags, *rx = flags + n, *ry = flags + 2 * n;
        double *z = buf, *b = buf + n, *w = buf + 6 * n, *prec = buf + 7 * n, *tx = buf + 8 * n, *ty = buf + 9 * n;
        struct imp_fuse_stats st = {};
        struct system sys = { nx, ny, in, rx, ry, w, tx, ty, gbuf + 2 * n, gbuf + 3 * n };
        struct slopes gs = { gbuf, gbuf + n };
        for (size_t t = 0; t < n; t++) {
                in[t] = (!mask || mask[t]) && isfinite(height_mm[t]);
                st.n_texels += in[t];
        }
        photometric_slopes(n, normal, in, p->min_nz, &gs);
        setup_rows(nx, ny, pitch_mm, height_mm, normal, sigma_mm, mask, p, tex, &gs, &sys, z, &st);
        int rw = row_weights(n, normal, mask, p, tex, &sys);
        if (rw < 0)
                return rw;
        /* b = W z0 + Dxᵀ tx + Dyᵀ ty, Jacobi diagonal. */
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!in[t]) {
                                b[t] = 0, prec[t] = 0;
                                continue;
                        }
                        double a = w[t] * z[t], dg = w[t];
                        if (i > 0) a += tx[t - 1], dg += rx[t - 1] * sys.wx[t - 1];
                        if (i + 1 < nx) a -= tx[t + 1], dg += rx[t + 1] * sys.wx[t + 1];
                        if (j > 0) a += ty[t - nx], dg += ry[t - nx] * sys.wy[t - nx];
                        if (j + 1 < ny) a -= ty[t + nx], dg += ry[t + nx] * sys.wy[t + nx];
                        b[t] = a;
                        prec[t] = dg > 0 ? 1 / dg : 0;   /* 0: a filled texel in no row keeps z0 */
                }
        st.agree_deg_before = agreement_deg(&sys, z, normal, pitch_mm);
        int rc = solve_cg(&sys, b, prec, z, buf + 2 * n, p, &st);
        if (rc < 0)
                return rc;
        st.agree_deg_after = agreement_deg(&sys, z, normal, pitch_mm);
        if (tex && tex->sigma_mm) {
                int r = fill_sigma(nx, ny, pitch_mm, normal, sigma_mm, mask, in, p, tex, &st);
                if (r < 0)
                        return r;
        }
        if (tex && tex->flags && mask)
                for (size_t t = 0; t < n; t++)
                        if (in[t] && mask[t] == 2)
                                tex->flags[t] |= IMP_TEXEL_FILLED;
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
