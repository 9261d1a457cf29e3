/* What one normal per texel can promise (normal-trust.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "macro.h"
#include "normal-trust.h"
#include "quality.h"

#define NT_DEG (180.0 / M_PI)
#define NT_EDGE_SIGMA_MAX 90.0f       /* a neighbour's σ passed on at most (180: unknown) */
#define NT_FINE_K 1.6                 /* rule 3: σ per degree of the window's rms bend */
#define NT_FINE_RADIUS 2              /* rule 3: the window is (2R + 1)² texels */

void imp_normal_trust_params_default(struct imp_normal_trust_params *ret) {
        *ret = (struct imp_normal_trust_params) { .rough_k = 0.1, .edge = true, .fine_k = NT_FINE_K,
                                                  .fine_radius = NT_FINE_RADIUS };
}

static void unit_normal(const float *nx_, const float *ny_, size_t t, double n[3]) {
        n[0] = nx_[t];
        n[1] = ny_[t];
        n[2] = sqrt(fmax(0.0, 1 - n[0] * n[0] - n[1] * n[1]));
}

/* Texel (i, j)'s normal against its 4-neighbours' on the mask (degrees): the largest
 * angle to one of them (rule 1) and the angle to their mean (rule 3: the bend at the
 * texel's own scale, the shortest wavelength the grid can show); 0 without one. */
static void neighbour_angles(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, int i, int j,
                             float *ret_max, float *ret_bend) {
        static const int di[4] = { 1, -1, 0, 0 }, dj[4] = { 0, 0, 1, -1 };
        double a[3], b[3], m[3] = { 0, 0, 0 }, mx = 0;
        unit_normal(nx_, ny_, (size_t) j * nx + i, a);
        for (int k = 0; k < 4; k++) {
                int x = i + di[k], y = j + dj[k];
                if (x < 0 || y < 0 || x >= nx || y >= ny || !mask[(size_t) y * nx + x])
                        continue;
                unit_normal(nx_, ny_, (size_t) y * nx + x, b);
                double c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
                mx = fmax(mx, acos(IMP_CLAMP(c, -1.0, 1.0)) * NT_DEG);
                m[0] += b[0], m[1] += b[1], m[2] += b[2];
        }
        double len = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        double c = len > 0 ? (a[0] * m[0] + a[1] * m[1] + a[2] * m[2]) / len : 1;
        *ret_max = (float) mx;
        *ret_bend = (float) (acos(IMP_CLAMP(c, -1.0, 1.0)) * NT_DEG);
}

/* Rule 3 at texel (i, j): the rms of the bends over the (2R + 1)² window on the mask. */
static double window_rms(int nx, int ny, const uint8_t *mask, const float *bend, int R, int i, int j) {
        double s = 0;
        int c = 0;
        for (int y = IMP_MAX(0, j - R); y <= IMP_MIN(ny - 1, j + R); y++)
                for (int x = IMP_MAX(0, i - R); x <= IMP_MIN(nx - 1, i + R); x++) {
                        size_t q = (size_t) y * nx + x;
                        if (!mask[q])
                                continue;
                        s += (double) bend[q] * bend[q];
                        c++;
                }
        return c ? sqrt(s / c) : 0;
}

/* Whether texel s's normal is not vouched for: off the mask, a flag about its samples or
 * its normal before this stage (flags0; not the location flag frame_adjacent, nor
 * fit_failed, which is the BRDF's), or σ_n above the limit after rule 1 (sigma_r). */
static bool unvouched(const uint8_t *mask, const uint16_t *flags0, const float *sigma_r, size_t s) {
        return !mask[s] || (flags0[s] & ~(IMP_TEXEL_FRAME_ADJACENT | IMP_TEXEL_FIT_FAILED)) ||
               !(sigma_r[s] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG);
}

/* Rule 2 at texel (i, j): the largest σ of an unvouched 8-neighbour, −1 when none. */
static float edge_sigma(int nx, int ny, const uint8_t *mask, const uint16_t *flags0, const float *sigma1, int i,
                        int j) {
        float s = -1;
        for (int y = IMP_MAX(0, j - 1); y <= IMP_MIN(ny - 1, j + 1); y++)
                for (int x = IMP_MAX(0, i - 1); x <= IMP_MIN(nx - 1, i + 1); x++) {
                        size_t q = (size_t) y * nx + x;
                        if ((x == i && y == j) || !unvouched(mask, flags0, sigma1, q))
                                continue;
                        s = fmaxf(s, mask[q] ? fminf(sigma1[q], NT_EDGE_SIGMA_MAX) : 0.0f);
                }
        return s;
}

int imp_normal_trust(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, float *sigma_n_deg,
                     uint16_t *texel_flags, const struct imp_normal_trust_params *p,
                     struct imp_normal_trust_stats *ret_stats) {
        if (nx <= 0 || ny <= 0 || !mask || !nx_ || !ny_ || !sigma_n_deg || !texel_flags || !p ||
            !(p->rough_k >= 0) || !isfinite(p->rough_k) || !(p->fine_k >= 0) || !isfinite(p->fine_k) ||
            p->fine_radius < 0 || p->fine_radius > 16)
                return -EINVAL;
        size_t n = (size_t) nx * ny;
        _cleanup_free_ float *sigma1 = malloc(n * sizeof *sigma1), *bend = malloc(n * sizeof *bend),
                             *cv = malloc(n * sizeof *cv);
        _cleanup_free_ uint16_t *flags0 = malloc(n * sizeof *flags0);
        if (!sigma1 || !flags0 || !bend || !cv)
                return -ENOMEM;
        memcpy(flags0, texel_flags, n * sizeof *flags0);
        long cnt = 0, rough = 0, fine = 0, edge = 0;
#pragma omp parallel for schedule(dynamic, 16)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        cv[t] = bend[t] = 0;
                        if (mask[t])
                                neighbour_angles(nx, ny, mask, nx_, ny_, i, j, &cv[t], &bend[t]);
                }
        /* rules 1 and 3 everywhere first; rule 2 reads the neighbours' σ after rule 1
         * (sigma_r, in cv's place): rule 3's window already spreads its own σ, and its rims
         * flagged too cost the demo 7 % more flagged texels for nothing it needed */
        float *sigma_r = cv;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : cnt, rough, fine)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        sigma1[t] = sigma_n_deg[t];
                        if (!mask[t])
                                continue;
                        cnt++;
                        double s_rough = hypot(sigma_n_deg[t], p->rough_k * cv[t]);
                        double fw = p->fine_k > 0 ? p->fine_k * window_rms(nx, ny, mask, bend, p->fine_radius, i, j) : 0;
                        sigma1[t] = (float) fmin(180.0, hypot(s_rough, fw));
                        sigma_r[t] = (float) fmin(180.0, s_rough);
                        bool was_ok = sigma_n_deg[t] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG &&
                                      !(flags0[t] & IMP_TEXEL_NORMAL_UNCERTAIN);
                        bool rough_out = !(s_rough <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG);
                        rough += was_ok && rough_out;
                        fine += was_ok && !rough_out && !(sigma1[t] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG);
                }
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : edge)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!mask[t])
                                continue;
                        float s = sigma1[t];
                        bool by_rough = !(s <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG);
                        float se = p->edge ? edge_sigma(nx, ny, mask, flags0, sigma_r, i, j) : -1;
                        sigma_n_deg[t] = fmaxf(s, se);
                        if (by_rough || se >= 0)
                                texel_flags[t] |= IMP_TEXEL_NORMAL_UNCERTAIN;
                        edge += se >= 0 && !by_rough && !(flags0[t] & IMP_TEXEL_NORMAL_UNCERTAIN);
                }
        if (ret_stats)
                *ret_stats = (struct imp_normal_trust_stats) { .n_texels = cnt, .n_rough_flagged = rough,
                                                               .n_fine_flagged = fine, .n_edge_flagged = edge };
        return 0;
}
