/* A conservative horizon of a heightfield, per texel and per quadrant of azimuth: an
 * upper bound on the slope (rise over horizontal run) at which any ray leaving the texel
 * into that quadrant can still pass below the surface by more than the shadow bias. A
 * shadow or visibility ray whose slope is at least the bound cannot be blocked, so the
 * march (seed 000 §5.2's linear-then-binary search) is skipped for it; other rays are
 * marched as before. Every decision is therefore the march's own.
 *
 * The bound (horizon-map idea of Max, "Horizon mapping", 1988, made conservative and
 * light-independent so that it is built once per heightfield for every light and the
 * camera). A ray from texel P = (u, v) into quadrant (su, sv) (su = +1 when du ≥ 0, …)
 * stays in the closed quadrant. A point Q of it at horizontal distance s (texels) lies
 * in the box Bq(r) = [u, u + su·r] × [v, v + sv·r] for any integer r ≥ s (Chebyshev ≤
 * Euclid), where the bilinear surface never exceeds Mq(r), the largest finite corner
 * height in that box. Radii r_0 = 1 < r_1 < … grow by at most 1.5× (1, 2, 3, 4, 6, 9,
 * 13, …) until the box covers the grid. A hit at s ∈ (r_{k-1}, r_k] needs
 * Mq(r_k) − bias − h(P) > m·s·pitch > m·r_{k-1}·pitch (m: the ray's slope), so the ray
 * is clear in that band when m ≥ (Mq(r_k) − bias − h(P)) / (r_{k-1}·pitch). For s ≤ 1
 * the ray stays in P's cell of the quadrant, where the bilinear surface rises along
 * any direction (a, b) of the quadrant by at most √(A⁺² + B⁺²) per texel (A⁺, B⁺: the
 * largest rises of the cell's edges in the quadrant's u and v directions, or 0): clear
 * when m·pitch ≥ that. The bound is the largest of these; a cell with a non-finite
 * corner never occludes (the march reads its heights as −∞), so it adds nothing.
 *
 * The bound is kept in two parts split at the run IMP_BTF_HORIZON_SPLIT (a band radius
 * r_k): the near part, the largest over the near cell and the bands with r_k ≤ SPLIT
 * (s ≤ SPLIT), and the far part over the bands beyond (s > SPLIT); the bound is their
 * maximum. A ray at least as steep as the near part cannot be blocked within SPLIT
 * texels of run, one at least as steep as the far part cannot be blocked beyond: the
 * march then starts, or stops, there (btf-samples.c). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>

#include "btf.h"

struct imp_btf_horizon {
        int width, height;
        float *slope;                 /* 8 planes of width·height: near parts of quadrant q = (du < 0) | (dv < 0) << 1,
                                         then the far parts (plane 4 + q) */
};

void imp_btf_horizon_free(struct imp_btf_horizon *hz) {
        if (!hz)
                return;
        free(hz->slope);
        free(hz);
}

/* Rounding margin in mm: the march's z and bilinear h are computed in double from float
 * heights of at most a few hundred mm, far below this. */
#define HZ_EPS_MM 1e-9

static float ffinite(float h) {
        return isfinite(h) ? h : -HUGE_VALF;
}

/* The near band (s ≤ 1) of quadrant q at texel (u, v): the largest rise per texel of
 * the bilinear surface over P's cell in that quadrant; 0 outside the grid or when a
 * corner is not finite (the cell never occludes). */
static double near_rise(const struct imp_btf_heightfield *hf, int u, int v, int q) {
        int su = q & 1 ? -1 : 1, sv = q & 2 ? -1 : 1, u1 = u + su, v1 = v + sv;
        if (u1 < 0 || v1 < 0 || u1 >= hf->width || v1 >= hf->height)
                return 0.0;
        const int W = hf->width;
        double h0 = hf->height_mm[(size_t) v * W + u], h1 = hf->height_mm[(size_t) v * W + u1];
        double h2 = hf->height_mm[(size_t) v1 * W + u], h3 = hf->height_mm[(size_t) v1 * W + u1];
        if (!isfinite(h0) || !isfinite(h1) || !isfinite(h2) || !isfinite(h3))
                return 0.0;
        double a = fmax(0.0, fmax(h1 - h0, h3 - h2)), b = fmax(0.0, fmax(h2 - h0, h3 - h1));
        return sqrt(a * a + b * b);
}

/* dst[i] = max(a[i], b[i]), i < n (vector lanes). */
static void max_lanes(const float *restrict a, const float *restrict b, float *restrict dst, int n) {
#pragma omp simd
        for (int i = 0; i < n; i++)
                dst[i] = a[i] > b[i] ? a[i] : b[i];
}

/* dst = max of src over the box grown by q texels in quadrant qd's directions: along
 * rows then along columns (src at offsets 0 and q; indices clamped to the grid, which
 * only drops what lies outside it). tmp: scratch of the same size. A row's texels whose
 * offset stays in the grid run in lanes, the others take the clamped index. */
static void grow_box(const float *src, float *tmp, float *dst, int W, int H, int q, int qd) {
        int su = qd & 1 ? -q : q, sv = qd & 2 ? -q : q;
        /* u + su inside [0, W) for u in [lo, hi) */
        int lo = IMP_MAX(0, -su), hi = IMP_MIN(W, W - su);
        for (int v = 0; v < H; v++) {
                const float *row = src + (size_t) v * W;
                float *out = tmp + (size_t) v * W;
                for (int u = 0; u < W; u++) {
                        if (u == lo && hi > lo) {
                                max_lanes(row + lo, row + lo + su, out + lo, hi - lo);
                                u = hi - 1;
                                continue;
                        }
                        int u2 = IMP_MIN(IMP_MAX(u + su, 0), W - 1);
                        out[u] = row[u] > row[u2] ? row[u] : row[u2];
                }
        }
        for (int v = 0; v < H; v++) {
                int v2 = IMP_MIN(IMP_MAX(v + sv, 0), H - 1);
                max_lanes(tmp + (size_t) v * W, tmp + (size_t) v2 * W, dst + (size_t) v * W, W);
        }
}

/* One band's bound (M: its box maxima, run_mm: the run where it starts) raised into slope
 * where higher, in vector lanes (gcc 12 if-converts the select only with no-trapping-math;
 * the same operations, so the same values). */
__attribute__((optimize("no-trapping-math")))
static void band_bound(const float *height, const float *M, float *slope, size_t n, double bias_mm, double run_mm) {
#pragma omp simd
        for (size_t i = 0; i < n; i++) {
                double h = height[i];
                double g = ((double) M[i] - bias_mm + HZ_EPS_MM - h) / run_mm;
                float sq = slope[i];
                slope[i] = isfinite(h) && g > sq ? (float) g : sq;
        }
}

/* One quadrant into its planes of slope, near and far: the near band, then the boxes of
 * radius 2, 3, 4, 6, 9, 13, … (serial: the quadrants run in parallel, one parallel region
 * in all). */
static void quadrant_bound(const struct imp_btf_heightfield *hf, double bias_mm, int qd, float *M, float *tmp,
                           float *M2, float *near, float *far) {
        const int W = hf->width, H = hf->height;
        const size_t n = (size_t) W * H;
        const double ip = 1.0 / hf->pitch_mm;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        size_t i = (size_t) v * W + u;
                        near[i] = (float) (near_rise(hf, u, v, qd) * ip);
                        far[i] = 0.0f;
                        M[i] = ffinite(hf->height_mm[i]);
                }
        grow_box(M, tmp, M2, W, H, 1, qd);
        /* cur = Mq(r); the band (0, 1] is the near rise's. */
        float *cur = M2, *other = M;
        for (int r = 1, span = IMP_MAX(W, H); r < span; ) {
                int q = r < 4 ? 1 : r / 2;       /* r + q ≤ 1.5 r, and q ≤ r keeps the box gap-free */
                grow_box(cur, tmp, other, W, H, q, qd);
                float *t = cur;
                cur = other;
                other = t;
                /* cur = Mq(r + q): the band (r, r + q], near while r + q ≤ SPLIT. */
                band_bound(hf->height_mm, cur, r + q <= IMP_BTF_HORIZON_SPLIT ? near : far, n, bias_mm,
                           r * hf->pitch_mm);
                r += q;
        }
        /* Round each bound up to the next float: the comparison is in double. */
        for (size_t i = 0; i < n; i++) {
                near[i] = nextafterf(near[i], HUGE_VALF);
                far[i] = nextafterf(far[i], HUGE_VALF);
        }
}

int imp_btf_horizon_new(const struct imp_btf_heightfield *hf, double bias_mm, struct imp_btf_horizon **ret) {
        if (!hf || !ret || hf->width <= 0 || hf->height <= 0 || !hf->height_mm || !(hf->pitch_mm > 0.0) ||
            !isfinite(bias_mm))
                return -EINVAL;
        const size_t n = (size_t) hf->width * hf->height;
        struct imp_btf_horizon *hz = calloc(1, sizeof *hz);
        if (!hz || !(hz->slope = malloc(8 * n * sizeof *hz->slope))) {
                imp_btf_horizon_free(hz);
                return -ENOMEM;
        }
        hz->width = hf->width;
        hz->height = hf->height;
        bool oom = false;
#pragma omp parallel for schedule(dynamic, 1)
        for (int qd = 0; qd < 4; qd++) {
                float *M = malloc(n * sizeof *M), *tmp = malloc(n * sizeof *tmp), *M2 = malloc(n * sizeof *M2);
                if (M && tmp && M2)
                        quadrant_bound(hf, bias_mm, qd, M, tmp, M2, hz->slope + qd * n, hz->slope + (4 + qd) * n);
                else
#pragma omp atomic write
                        oom = true;
                free(M);
                free(tmp);
                free(M2);
        }
        if (oom) {
                imp_btf_horizon_free(hz);
                return -ENOMEM;
        }
        *ret = hz;
        return 0;
}

static float fmaxf_(float a, float b) {
        return a > b ? a : b;
}

bool imp_btf_horizon_clear(const struct imp_btf_horizon *hz, int u, int v, const double d[3]) {
        if (!hz || !(d[2] > 0.0))
                return false;
        int q = (d[0] < 0.0) | (d[1] < 0.0) << 1;
        double run = sqrt(d[0] * d[0] + d[1] * d[1]);
        return d[2] >= imp_btf_horizon_slope(hz, u, v, q) * run;
}

double imp_btf_horizon_slope(const struct imp_btf_horizon *hz, int u, int v, int q) {
        const size_t n = (size_t) hz->width * hz->height, i = (size_t) v * hz->width + u;
        return fmaxf_(hz->slope[(size_t) (q & 3) * n + i], hz->slope[(size_t) (4 + (q & 3)) * n + i]);
}

bool imp_btf_horizon_texel(const struct imp_btf_horizon *hz, int u, int v, float ret[4]) {
        float far[4];
        if (!imp_btf_horizon_split(hz, u, v, ret, far))
                return false;
        for (int q = 0; q < 4; q++)
                ret[q] = fmaxf_(ret[q], far[q]);
        return true;
}

bool imp_btf_horizon_split(const struct imp_btf_horizon *hz, int u, int v, float ret_near[4], float ret_far[4]) {
        if (!hz)
                return false;
        const size_t n = (size_t) hz->width * hz->height, i = (size_t) v * hz->width + u;
        for (int q = 0; q < 4; q++) {
                ret_near[q] = hz->slope[q * n + i];
                ret_far[q] = hz->slope[(4 + q) * n + i];
        }
        return true;
}
