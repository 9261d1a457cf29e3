/* A conservative horizon of a heightfield, per texel and per octant of azimuth: an
 * upper bound on the slope (rise over horizontal run) at which any ray leaving the texel
 * into that octant can still pass below the surface by more than the shadow bias. A
 * shadow or visibility ray whose slope is at least the bound cannot be blocked, so the
 * march (seed 000 §5.2's linear-then-binary search) is skipped for it; other rays are
 * marched as before. Every decision is therefore the march's own.
 *
 * The bound (horizon-map idea of Max, "Horizon mapping", 1988, made conservative and
 * light-independent so that it is built once per heightfield for every light and the
 * camera; Max samples the horizon in azimuth, here eight sectors bound it from above).
 * Octant o of a ray d from texel P = (u, v): its quadrant (su = +1 when du ≥ 0, sv when
 * dv ≥ 0) and its major axis (u when |du| ≥ |dv|, else v). In the octant's own axes
 * (e_P the major axis' sign, e_S the other's) a point Q of the ray at horizontal
 * distance s (texels) is P + a·e_P + b·e_S with 0 ≤ b ≤ a ≤ s. The bilinear surface at Q
 * never exceeds the largest finite height of its cell's corners (i, j) ∈ {⌊a⌋, ⌈a⌉} ×
 * {⌊b⌋, ⌈b⌉}, which lie in T(r) = {0 ≤ i ≤ r, 0 ≤ j ≤ i + 1} for any integer r ≥ s (the
 * corner (⌊a⌋, ⌈b⌉) may be one above the diagonal). Mo(r) is the largest finite height
 * in T(r): the quadrant's box holds the octant's wedge and the other octant's too, the
 * wedge only about half of it. Radii r_0 = 1 < r_1 < … (1, 2, 3, 4, 6, 8, 12, 16, …,
 * growth ≤ 1.5×) run until the wedge covers the grid. A hit at s ∈ (r_{k-1}, r_k] needs
 * Mo(r_k) − bias − h(P) > m·s·pitch > m·r_{k-1}·pitch (m: the ray's slope), so the ray is
 * clear in that band when m ≥ (Mo(r_k) − bias − h(P)) / (r_{k-1}·pitch). For s ≤ 1 the ray
 * stays in P's cell of the quadrant, where the bilinear surface rises along a direction
 * a·e_P + b·e_S (a ≥ b ≥ 0, unit) by at most a·A⁺ + b·B⁺ per texel (A⁺, B⁺: the largest
 * rises of the cell's edges along e_P and e_S, or 0), at most √(A⁺² + B⁺²) when A⁺ ≥ B⁺
 * and (A⁺ + B⁺)/√2 (the diagonal) otherwise: clear when m·pitch ≥ that. The bound is the
 * largest of these; a cell with a non-finite corner never occludes (the march reads its
 * heights as −∞), so it adds nothing.
 *
 * Building it: with b a power of two, D(r) = max over T(r), B(r) = max over the square
 * [0, r]² (both in the octant's axes, −∞ outside the grid), and D, B on heights already
 * maxed with the texel one step along e_S (the "+ 1" of T):
 *   D(2b)  = D(b) ∪ B(b) at (b, 0) ∪ D(b) at (b, b),
 *   D(3b/2) = D(b) ∪ B(b/2) at (b, 0) ∪ B(b/2) at (b, b/2) ∪ D(b/2) at (b, b),
 *   B(2b)  = B(b) at (0, 0), (b, 0), (0, b), (b, b);
 * each a few shifted maxima over the grid, O(texels · log size) for an octant. */
#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdlib.h>

#include "btf.h"

struct imp_btf_horizon {
        int width, height;
        float *slope;                 /* IMP_BTF_HORIZON_OCTANTS planes of width·height (imp_btf_horizon_octant()) */
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

/* The octant's axes in texels: e_P = (ax[0], ax[1]), e_S = (ax[2], ax[3]). */
static void octant_axes(int o, int ax[4]) {
        int su = o & 1 ? -1 : 1, sv = o & 2 ? -1 : 1;
        if (o & 4) {
                ax[0] = 0, ax[1] = sv, ax[2] = su, ax[3] = 0;
        } else {
                ax[0] = su, ax[1] = 0, ax[2] = 0, ax[3] = sv;
        }
}

/* The near band (s ≤ 1) of octant o at texel (u, v): the largest rise per texel of the
 * bilinear surface over P's cell along a direction of the octant; 0 outside the grid or
 * when a corner is not finite (the cell never occludes). */
static double near_rise(const struct imp_btf_heightfield *hf, int u, int v, int o) {
        int su = o & 1 ? -1 : 1, sv = o & 2 ? -1 : 1, u1 = u + su, v1 = v + sv;
        if (u1 < 0 || v1 < 0 || u1 >= hf->width || v1 >= hf->height)
                return 0.0;
        const int W = hf->width;
        double h0 = hf->height_mm[(size_t) v * W + u], h1 = hf->height_mm[(size_t) v * W + u1];
        double h2 = hf->height_mm[(size_t) v1 * W + u], h3 = hf->height_mm[(size_t) v1 * W + u1];
        if (!isfinite(h0) || !isfinite(h1) || !isfinite(h2) || !isfinite(h3))
                return 0.0;
        double a = fmax(0.0, fmax(h1 - h0, h3 - h2)), b = fmax(0.0, fmax(h2 - h0, h3 - h1));
        if (o & 4) {            /* major axis v */
                double t = a;
                a = b;
                b = t;
        }
        return a >= b ? sqrt(a * a + b * b) : (a + b) * M_SQRT1_2;
}

/* One term of a shifted maximum: src read at the texel + i·e_P + j·e_S. */
struct hz_tap {
        const float *src;
        int i, j;
};

/* dst's row v = the largest of the taps (−∞ where a tap falls outside the grid). */
static void taps_row(float *restrict dst, const struct hz_tap *t, int nt, const int ax[4], int W, int H, int v) {
        for (int u = 0; u < W; u++)
                dst[u] = -HUGE_VALF;
        for (int k = 0; k < nt; k++) {
                int du = t[k].i * ax[0] + t[k].j * ax[2], dv = t[k].i * ax[1] + t[k].j * ax[3];
                if (v + dv < 0 || v + dv >= H || du >= W || -du >= W)
                        continue;
                const float *restrict s = t[k].src + (ptrdiff_t) (v + dv) * W + du;
                for (int u = IMP_MAX(0, -du), e = IMP_MIN(W, W - du); u < e; u++)
                        dst[u] = s[u] > dst[u] ? s[u] : dst[u];
        }
}

/* slope's row v = max(slope, (Mo − bias − h) / run) over the texels with a finite height
 * (branch-free, in vector lanes; 1/run instead of a division: the bound is rounded up to
 * the next float at the end, far more than the product's rounding). */
static void band_row(float *restrict slope, const float *restrict mo, const float *restrict h, int W, double bias_mm,
                     double run_mm) {
        const double c = HZ_EPS_MM - bias_mm, irun = 1.0 / run_mm;
        for (int u = 0; u < W; u++) {
                double g = ((double) mo[u] + c - h[u]) * irun;
                bool up = isfinite(h[u]) & (g > slope[u]);
                slope[u] = up ? (float) g : slope[u];
        }
}

/* dst = the taps' maximum over the whole grid (row v at dst + v·stride: stride 0 keeps
 * only one row); with slope, also the band of run run_mm. */
static void taps_grid(float *dst, size_t stride, const struct hz_tap *t, int nt, const int ax[4],
                      const struct imp_btf_heightfield *hf, float *slope, double bias_mm, double run_mm) {
        const int W = hf->width, H = hf->height;
        for (int v = 0; v < H; v++) {
                float *row = dst + v * stride;
                taps_row(row, t, nt, ax, W, H, v);
                if (slope)
                        band_row(slope + (size_t) v * W, row, hf->height_mm + (size_t) v * W, W, bias_mm, run_mm);
        }
}

/* One octant into its plane of slope (serial: the octants run in parallel, one parallel
 * region in all). buf: 4 planes of width·height and one row of scratch. */
static void octant_bound(const struct imp_btf_heightfield *hf, double bias_mm, int o, float *buf, float *slope) {
        const int W = hf->width, H = hf->height;
        const size_t n = (size_t) W * H;
        const double ip = 1.0 / hf->pitch_mm, p = hf->pitch_mm;
        int ax[4];
        octant_axes(o, ax);
        float *base = buf, *D = buf + n, *B = buf + 2 * n, *X = buf + 3 * n, *row = buf + 4 * n;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        size_t i = (size_t) v * W + u;
                        int u2 = u + ax[2], v2 = v + ax[3];
                        float h = ffinite(hf->height_mm[i]);
                        if (u2 >= 0 && v2 >= 0 && u2 < W && v2 < H)
                                h = fmaxf(h, ffinite(hf->height_mm[(size_t) v2 * W + u2]));
                        base[i] = h;     /* the "+ 1" of T: the texel one step along e_S */
                        slope[i] = (float) (near_rise(hf, u, v, o) * ip);
                }
        /* D(1), B(1); then D(2) (band (1, 2]) into base's plane and B(2) into X */
        const struct hz_tap d1[3] = { { base, 0, 0 }, { base, 1, 0 }, { base, 1, 1 } };
        const struct hz_tap b1[4] = { { base, 0, 0 }, { base, 1, 0 }, { base, 0, 1 }, { base, 1, 1 } };
        taps_grid(D, (size_t) W, d1, 3, ax, hf, NULL, 0, 0);
        taps_grid(B, (size_t) W, b1, 4, ax, hf, NULL, 0, 0);
        const struct hz_tap d2[3] = { { D, 0, 0 }, { B, 1, 0 }, { D, 1, 1 } };
        const struct hz_tap b2[4] = { { B, 0, 0 }, { B, 1, 0 }, { B, 0, 1 }, { B, 1, 1 } };
        taps_grid(base, (size_t) W, d2, 3, ax, hf, slope, bias_mm, p);
        taps_grid(X, (size_t) W, b2, 4, ax, hf, NULL, 0, 0);
        /* now D(b/2) = D, B(b/2) = B, D(b) = base, B(b) = X with b = 2 */
        float *Dh = D, *Bh = B, *Db = base, *Bb = X;
        for (int b = 2, span = IMP_MAX(W, H); b < span; b *= 2) {
                const int h = b / 2;
                /* D(3b/2): the band (b, 3b/2], one row at a time */
                const struct hz_tap d15[4] = { { Db, 0, 0 }, { Bh, b, 0 }, { Bh, b, h }, { Dh, b, b } };
                taps_grid(row, 0, d15, 4, ax, hf, slope, bias_mm, b * p);
                /* D(2b) (the band (3b/2, 2b]) and B(2b), into the planes of D(b/2) and B(b/2) */
                const struct hz_tap d22[3] = { { Db, 0, 0 }, { Bb, b, 0 }, { Db, b, b } };
                const struct hz_tap b22[4] = { { Bb, 0, 0 }, { Bb, b, 0 }, { Bb, 0, b }, { Bb, b, b } };
                taps_grid(Dh, (size_t) W, d22, 3, ax, hf, slope, bias_mm, (b + h) * p);
                taps_grid(Bh, (size_t) W, b22, 4, ax, hf, NULL, 0, 0);
                float *t = Dh;
                Dh = Db, Db = t;
                t = Bh;
                Bh = Bb, Bb = t;
        }
        /* Round each bound up to the next float: the comparison is in double. */
        for (size_t i = 0; i < n; i++)
                slope[i] = nextafterf(slope[i], HUGE_VALF);
}

int imp_btf_horizon_new(const struct imp_btf_heightfield *hf, double bias_mm, struct imp_btf_horizon **ret) {
        if (!hf || !ret || hf->width <= 0 || hf->height <= 0 || !hf->height_mm || !(hf->pitch_mm > 0.0) ||
            !isfinite(bias_mm))
                return -EINVAL;
        const size_t n = (size_t) hf->width * hf->height;
        struct imp_btf_horizon *hz = calloc(1, sizeof *hz);
        if (!hz || !(hz->slope = malloc(IMP_BTF_HORIZON_OCTANTS * n * sizeof *hz->slope))) {
                imp_btf_horizon_free(hz);
                return -ENOMEM;
        }
        hz->width = hf->width;
        hz->height = hf->height;
        bool oom = false;
#pragma omp parallel for schedule(dynamic, 1)
        for (int o = 0; o < IMP_BTF_HORIZON_OCTANTS; o++) {
                float *buf = malloc((4 * n + (size_t) hf->width) * sizeof *buf);
                if (buf)
                        octant_bound(hf, bias_mm, o, buf, hz->slope + o * n);
                else
#pragma omp atomic write
                        oom = true;
                free(buf);
        }
        if (oom) {
                imp_btf_horizon_free(hz);
                return -ENOMEM;
        }
        *ret = hz;
        return 0;
}

bool imp_btf_horizon_clear(const struct imp_btf_horizon *hz, int u, int v, const double d[3]) {
        if (!hz || !(d[2] > 0.0))
                return false;
        int o = imp_btf_horizon_octant(d);
        double run = sqrt(d[0] * d[0] + d[1] * d[1]);
        return d[2] >= (double) hz->slope[(size_t) o * hz->width * hz->height + (size_t) v * hz->width + u] * run;
}

double imp_btf_horizon_slope(const struct imp_btf_horizon *hz, int u, int v, int o) {
        return hz->slope[(size_t) (o & 7) * hz->width * hz->height + (size_t) v * hz->width + u];
}

bool imp_btf_horizon_texel(const struct imp_btf_horizon *hz, int u, int v, float ret[IMP_BTF_HORIZON_OCTANTS]) {
        if (!hz)
                return false;
        const size_t n = (size_t) hz->width * hz->height, i = (size_t) v * hz->width + u;
        for (int o = 0; o < IMP_BTF_HORIZON_OCTANTS; o++)
                ret[o] = hz->slope[o * n + i];
        return true;
}
