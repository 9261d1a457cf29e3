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
#define NT_FINE_K 2.4                 /* rule 3: σ per degree of the window's rms fine bend */
#define NT_FINE_RADIUS 2              /* rule 3: the window is (2R + 1)² texels */
#define NT_FINE_HALF 3                /* rule 3: the fine bend is a difference of order 2·this */

void imp_normal_trust_params_default(struct imp_normal_trust_params *ret) {
        *ret = (struct imp_normal_trust_params) { .rough_k = 0.1, .edge = true, .fine_k = NT_FINE_K,
                                                  .fine_radius = NT_FINE_RADIUS };
}

static void unit_normal(const float *nx_, const float *ny_, size_t t, double n[3]) {
        n[0] = nx_[t];
        n[1] = ny_[t];
        n[2] = sqrt(fmax(0.0, 1 - n[0] * n[0] - n[1] * n[1]));
}

/* The difference of order 2·NT_FINE_HALF (binomial weights of alternating sign, e.g.
 * [1 −6 15 −20 15 −6 1] for 3), divided by 4^NT_FINE_HALF, of the unit normals along axis (di, dj) through texel (i, j),
 * centred on the texel or, near a mask edge, on the nearest texel (at most NT_FINE_HALF
 * away along the axis) whose taps are all on the mask; false when there is none. */
static bool fine_difference(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, int i, int j,
                            int di, int dj, double ret[3]) {
        const int h = NT_FINE_HALF;
        double w[2 * NT_FINE_HALF + 1];
        w[0] = 1;
        for (int k = 1; k <= 2 * h; k++)   /* (−1)^k C(2h, k) */
                w[k] = -w[k - 1] * (2 * h - k + 1) / k;
        for (int s = 0; s <= 2 * h; s++) {
                int sh = (s + 1) / 2 * (s % 2 ? 1 : -1);   /* 0, 1, −1, 2, −2, … */
                int ci = i + sh * di, cj = j + sh * dj, k;
                for (k = -h; k <= h; k++) {
                        int x = ci + k * di, y = cj + k * dj;
                        if (x < 0 || y < 0 || x >= nx || y >= ny || !mask[(size_t) y * nx + x])
                                break;
                }
                if (k <= h)
                        continue;
                double b[3];
                ret[0] = ret[1] = ret[2] = 0;
                for (k = -h; k <= h; k++) {
                        unit_normal(nx_, ny_, (size_t) (cj + k * dj) * nx + (ci + k * di), b);
                        for (int c = 0; c < 3; c++)
                                ret[c] += w[k + h] * b[c];
                }
                for (int c = 0; c < 3; c++)
                        ret[c] /= ldexp(1.0, 2 * h);
                return true;
        }
        return false;
}

/* The angle (degrees) between two unit vectors whose difference is v. */
static double chord_deg(const double v[3]) {
        return 2 * asin(fmin(1.0, sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]) / 2)) * NT_DEG;
}

/* Texel (i, j)'s normal against its 4-neighbours' on the mask (degrees): the largest
 * angle to one of them (rule 1) and the bend at the texel's own scale that smooth relief
 * does not explain (rule 3); 0 without a neighbour.
 *
 * Rule 3's bend: b1 = a − m̂1, the normal a against the unit mean m̂1 of its 4-neighbours,
 * is a Laplacian: it bends as much on relief the grid resolves as on relief it aliases.
 * The fine bend is what smooth relief does not explain: the sixth differences
 * [1 −6 15 −20 15 −6 1]/64 of the normals along x plus along y. Along a sinusoid of f
 * cycles per texel b1 is 2·sin²(πf) of its amplitude and the fine bend 2·sin⁶(πf): it
 * keeps sin⁴(πf) of b1, 1 % at 10 texels per period, 25 % at 4, 91 % at 2.3 and all of it
 * at the Nyquist period of 2, where aliased relief leaves its trace. Measured with
 * `impasto process` + `compare` (docs/copy-quality.md, rule 3): the demo's relief is
 * resolved (error ≈ 0.1 × the neighbour angle) and its flagged fraction went 78.8 → 62.6 %
 * (the fourth difference, sin²(πf) of b1, left 71 %), while the painting tiles' aliased
 * relief (0.2 mm grooves at 0.1 mm texels, error 0.4–0.9 × the neighbour angle) stays
 * flagged. NaN when no taps on the mask fit along an axis; ret_bend1 is |b1| (degrees). */
static void neighbour_angles(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, int i, int j,
                             float *ret_max, float *ret_bend1, float *ret_fine) {
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
        *ret_max = (float) mx;
        *ret_bend1 = 0;
        *ret_fine = NAN;
        double len = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        if (!(len > 0))
                return;
        double v[3], dx[3], dy[3];
        for (int k = 0; k < 3; k++)
                v[k] = a[k] - m[k] / len;
        *ret_bend1 = (float) chord_deg(v);
        if (!fine_difference(nx, ny, mask, nx_, ny_, i, j, 1, 0, dx) ||
            !fine_difference(nx, ny, mask, nx_, ny_, i, j, 0, 1, dy))
                return;
        for (int k = 0; k < 3; k++)
                v[k] = dx[k] + dy[k];
        *ret_fine = (float) chord_deg(v);
}

/* Rule 3 at texel (i, j): the rms of the fine bends over the (2R + 1)² window on the
 * mask, leaving out texels whose fine bend is unknown (NaN: no 7 taps on the mask along
 * an axis within 3 texels; the window's inner texels see the relief there); the rms of
 * the bends b1 where the whole window is unknown (a strip narrower than 7 texels: the
 * cautious side). */
static double window_rms(int nx, int ny, const uint8_t *mask, const float *fine, const float *bend1, int R, int i,
                         int j) {
        double s = 0, s1 = 0;
        int c = 0, c1 = 0;
        for (int y = IMP_MAX(0, j - R); y <= IMP_MIN(ny - 1, j + R); y++)
                for (int x = IMP_MAX(0, i - R); x <= IMP_MIN(nx - 1, i + R); x++) {
                        size_t q = (size_t) y * nx + x;
                        if (!mask[q])
                                continue;
                        s1 += (double) bend1[q] * bend1[q];
                        c1++;
                        if (isnan(fine[q]))
                                continue;
                        s += (double) fine[q] * fine[q];
                        c++;
                }
        return c ? sqrt(s / c) : c1 ? sqrt(s1 / c1) : 0;
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

void imp_normal_trust_cache_done(struct imp_normal_trust_cache *c) {
        if (!c)
                return;
        free(c->angle_max);
        free(c->fine_rms);
        *c = (struct imp_normal_trust_cache) {};
}

/* Rules 1 and 3's reading of the mask and normals into c: the largest neighbour angle of
 * every texel, and with fine the window rms of the fine bends. */
static int trust_geometry(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, int R, bool fine,
                          struct imp_normal_trust_cache *c) {
        size_t n = (size_t) nx * ny;
        _cleanup_free_ float *bend = malloc(n * sizeof *bend), *fineb = malloc(n * sizeof *fineb);
        *c = (struct imp_normal_trust_cache) { nx, ny, R, malloc(n * sizeof *c->angle_max),
                                               fine ? malloc(n * sizeof *c->fine_rms) : NULL };
        if (!bend || !fineb || !c->angle_max || (fine && !c->fine_rms)) {
                imp_normal_trust_cache_done(c);
                return -ENOMEM;
        }
        float *cv = c->angle_max;
#pragma omp parallel for schedule(dynamic, 16)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        cv[t] = bend[t] = 0;
                        fineb[t] = NAN;
                        if (mask[t])
                                neighbour_angles(nx, ny, mask, nx_, ny_, i, j, &cv[t], &bend[t], &fineb[t]);
                }
        if (!fine)
                return 0;
#pragma omp parallel for schedule(dynamic, 16)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        c->fine_rms[t] = mask[t] ? window_rms(nx, ny, mask, fineb, bend, R, i, j) : 0;
                }
        return 0;
}

int imp_normal_trust(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, float *sigma_n_deg,
                     uint16_t *texel_flags, const struct imp_normal_trust_params *p,
                     struct imp_normal_trust_stats *ret_stats) {
        return imp_normal_trust_cached(nx, ny, mask, nx_, ny_, sigma_n_deg, texel_flags, p, NULL, ret_stats);
}

int imp_normal_trust_cached(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_,
                            float *sigma_n_deg, uint16_t *texel_flags, const struct imp_normal_trust_params *p,
                            struct imp_normal_trust_cache *cache, struct imp_normal_trust_stats *ret_stats) {
        if (nx <= 0 || ny <= 0 || !mask || !nx_ || !ny_ || !sigma_n_deg || !texel_flags || !p ||
            !(p->rough_k >= 0) || !isfinite(p->rough_k) || !(p->fine_k >= 0) || !isfinite(p->fine_k) ||
            p->fine_radius < 0 || p->fine_radius > 16)
                return -EINVAL;
        size_t n = (size_t) nx * ny;
        struct imp_normal_trust_cache own = {};
        bool fine_on = p->fine_k > 0;
        if (!cache || !cache->angle_max || cache->nx != nx || cache->ny != ny || cache->fine_radius != p->fine_radius ||
            (fine_on && !cache->fine_rms)) {
                imp_normal_trust_cache_done(cache);
                int r = trust_geometry(nx, ny, mask, nx_, ny_, p->fine_radius, fine_on, cache ? cache : &own);
                if (r < 0)
                        return r;
        }
        const struct imp_normal_trust_cache *geo = cache ? cache : &own;
        _cleanup_free_ float *sigma1 = malloc(n * sizeof *sigma1), *sigma_r = malloc(n * sizeof *sigma_r);
        _cleanup_free_ uint16_t *flags0 = malloc(n * sizeof *flags0);
        if (!sigma1 || !flags0 || !sigma_r) {
                imp_normal_trust_cache_done(&own);
                return -ENOMEM;
        }
        memcpy(flags0, texel_flags, n * sizeof *flags0);
        long cnt = 0, rough = 0, fine = 0, edge = 0;
        const float *cv = geo->angle_max;
        /* rules 1 and 3 everywhere first; rule 2 reads the neighbours' σ after rule 1
         * (sigma_r, in cv's place): rule 3's window already spreads its own σ, and its rims
         * flagged too cost the demo 7 % more flagged texels for nothing it needed */
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : cnt, rough, fine)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        sigma1[t] = sigma_n_deg[t];
                        sigma_r[t] = 0;
                        if (!mask[t])
                                continue;
                        cnt++;
                        double s_rough = hypot(sigma_n_deg[t], p->rough_k * cv[t]);
                        double fw = fine_on ? p->fine_k * geo->fine_rms[t] : 0;
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
        imp_normal_trust_cache_done(&own);
        return 0;
}
