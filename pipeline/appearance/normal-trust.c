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

void imp_normal_trust_params_default(struct imp_normal_trust_params *ret) {
        *ret = (struct imp_normal_trust_params) { .rough_k = 0.1, .edge = true };
}

static void unit_normal(const float *nx_, const float *ny_, size_t t, double n[3]) {
        n[0] = nx_[t];
        n[1] = ny_[t];
        n[2] = sqrt(fmax(0.0, 1 - n[0] * n[0] - n[1] * n[1]));
}

/* Largest angle (degrees) between texel (i, j)'s normal and a 4-neighbour's on the mask. */
static double neighbour_angle(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, int i, int j) {
        static const int di[4] = { 1, -1, 0, 0 }, dj[4] = { 0, 0, 1, -1 };
        double a[3], b[3], mx = 0;
        unit_normal(nx_, ny_, (size_t) j * nx + i, a);
        for (int k = 0; k < 4; k++) {
                int x = i + di[k], y = j + dj[k];
                if (x < 0 || y < 0 || x >= nx || y >= ny || !mask[(size_t) y * nx + x])
                        continue;
                unit_normal(nx_, ny_, (size_t) y * nx + x, b);
                double c = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
                mx = fmax(mx, acos(IMP_CLAMP(c, -1.0, 1.0)) * NT_DEG);
        }
        return mx;
}

/* Whether texel s's normal is not vouched for: off the mask, a flag about its samples or
 * its normal before this stage (flags0; not the location flag frame_adjacent, nor
 * fit_failed, which is the BRDF's), or σ_n above the limit after rule 1 (sigma1). */
static bool unvouched(const uint8_t *mask, const uint16_t *flags0, const float *sigma1, size_t s) {
        return !mask[s] || (flags0[s] & ~(IMP_TEXEL_FRAME_ADJACENT | IMP_TEXEL_FIT_FAILED)) ||
               !(sigma1[s] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG);
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
            !(p->rough_k >= 0) || !isfinite(p->rough_k))
                return -EINVAL;
        size_t n = (size_t) nx * ny;
        _cleanup_free_ float *sigma1 = malloc(n * sizeof *sigma1);
        _cleanup_free_ uint16_t *flags0 = malloc(n * sizeof *flags0);
        if (!sigma1 || !flags0)
                return -ENOMEM;
        memcpy(flags0, texel_flags, n * sizeof *flags0);
        long cnt = 0, rough = 0, edge = 0;
        /* rule 1 everywhere first: rule 2 reads the neighbours' σ after it */
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : cnt, rough)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        sigma1[t] = sigma_n_deg[t];
                        if (!mask[t])
                                continue;
                        cnt++;
                        double cv = neighbour_angle(nx, ny, mask, nx_, ny_, i, j);
                        sigma1[t] = (float) fmin(180.0, hypot(sigma_n_deg[t], p->rough_k * cv));
                        rough += !(sigma1[t] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG) &&
                                 sigma_n_deg[t] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG &&
                                 !(flags0[t] & IMP_TEXEL_NORMAL_UNCERTAIN);
                }
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : edge)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!mask[t])
                                continue;
                        float s = sigma1[t];
                        bool by_rough = !(s <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG);
                        float se = p->edge ? edge_sigma(nx, ny, mask, flags0, sigma1, i, j) : -1;
                        sigma_n_deg[t] = fmaxf(s, se);
                        if (by_rough || se >= 0)
                                texel_flags[t] |= IMP_TEXEL_NORMAL_UNCERTAIN;
                        edge += se >= 0 && !by_rough && !(flags0[t] & IMP_TEXEL_NORMAL_UNCERTAIN);
                }
        if (ret_stats)
                *ret_stats = (struct imp_normal_trust_stats) { .n_texels = cnt, .n_rough_flagged = rough,
                                                               .n_edge_flagged = edge };
        return 0;
}
