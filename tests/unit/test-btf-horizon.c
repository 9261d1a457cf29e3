/* The conservative horizon of btf-horizon.c on a synthetic relief with cliffs (a raised
 * plateau, a pit, a one-texel spike, a diagonal ridge, a hole of non-finite heights):
 * (1) every bound equals a brute-force evaluation of its definition (a box one texel too
 * small or too large, a wrong band run or a wrong near cell changes it); (2) no ray the
 * horizon clears is blocked for the march (imp_btf_heightfield_ray), over every texel and
 * 48 azimuths at 7 elevations plus rays exactly at each texel's bound; (3) the horizon
 * clears most rays above the relief (it is not a bound that never clears). */
#include <math.h>
#include <stdlib.h>

#include "btf.h"
#include "unit/test.h"

enum { W = 46, H = 38 };
#define PITCH 0.05
#define BIAS (0.05 * PITCH)
#define EPS_MM 1e-9                    /* the rounding margin of btf-horizon.c */

static float height[W * H], normal[3 * W * H];

static void make_relief(struct imp_btf_heightfield *hf) {
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        double h = 0.15 * sin(0.31 * u) * cos(0.23 * v) + 0.05 * sin(0.9 * u + 0.4 * v);
                        if (u >= 12 && u < 24 && v >= 8 && v < 20)
                                h += 0.6;                      /* plateau: cliffs on four sides */
                        if (u >= 30 && u < 34 && v >= 24 && v < 28)
                                h -= 0.5;                      /* pit */
                        if (u + v == 50)
                                h += 0.3;                      /* diagonal ridge, one texel wide */
                        height[v * W + u] = (float) h;
                        normal[3 * (v * W + u) + 2] = 1.0f;
                }
        height[30 * W + 8] += 1.0f;                            /* spike */
        for (int v = 3; v < 6; v++)
                for (int u = 36; u < 39; u++)
                        height[v * W + u] = NAN;               /* hole */
        *hf = (struct imp_btf_heightfield) { .width = W, .height = H, .pitch_mm = PITCH, .height_mm = height,
                .normal = normal, .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 } };
}

static double hat(int u, int v) {
        if (u < 0 || v < 0 || u >= W || v >= H)
                return NAN;
        return height[v * W + u];
}

/* Largest finite height in [u, u + su·r] × [v, v + sv·r] ∩ grid. */
static double box_max(int u, int v, int su, int sv, int r) {
        double m = -HUGE_VAL;
        for (int j = 0; j <= r; j++)
                for (int i = 0; i <= r; i++) {
                        double h = hat(u + su * i, v + sv * j);
                        if (isfinite(h) && h > m)
                                m = h;
                }
        return m;
}

/* The definition in btf-horizon.c's header comment, evaluated the slow way: its near part
 * (the near cell and the bands up to IMP_BTF_HORIZON_SPLIT texels of run) into *ret_near,
 * its far part (the bands beyond) into *ret_far; the bound is their maximum. */
static double reference_bound_split(int u, int v, int q, double *ret_near, double *ret_far) {
        int su = q & 1 ? -1 : 1, sv = q & 2 ? -1 : 1;
        double h0 = hat(u, v), h1 = hat(u + su, v), h2 = hat(u, v + sv), h3 = hat(u + su, v + sv), g = 0.0, f = 0.0;
        if (isfinite(h0) && isfinite(h1) && isfinite(h2) && isfinite(h3)) {
                double a = fmax(0.0, fmax(h1 - h0, h3 - h2)), b = fmax(0.0, fmax(h2 - h0, h3 - h1));
                g = sqrt(a * a + b * b) / PITCH;
        }
        for (int r = 1; r < (W > H ? W : H); ) {
                int step = r < 4 ? 1 : r / 2;
                double b = (box_max(u, v, su, sv, r + step) - BIAS + EPS_MM - h0) / (r * PITCH);
                if (r + step <= IMP_BTF_HORIZON_SPLIT)
                        g = fmax(g, b);
                else
                        f = fmax(f, b);
                r += step;
        }
        *ret_near = g;
        *ret_far = f;
        return fmax(g, f);
}

/* got is ref rounded up to float: one float step above at most. */
static bool bound_equal(double got, double ref) {
        return got >= ref && got <= ref + 3e-7 * fabs(ref) + 1e-30;
}

static void test_bound_is_definition(const struct imp_btf_horizon *hz) {
        int bad = 0, near_wins = 0, far_wins = 0;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        if (!isfinite(hat(u, v)))
                                continue;
                        float near[4], far[4];
                        CHECK(imp_btf_horizon_split(hz, u, v, near, far));
                        for (int q = 0; q < 4; q++) {
                                double rn, rf, ref = reference_bound_split(u, v, q, &rn, &rf);
                                double got = imp_btf_horizon_slope(hz, u, v, q);
                                if (!bound_equal(got, ref) || !bound_equal(near[q], rn) || !bound_equal(far[q], rf)) {
                                        if (bad++ < 5)
                                                fprintf(stderr, "texel (%d, %d) quadrant %d: bound %.9g (near %.9g, "
                                                        "far %.9g), definition %.9g (%.9g, %.9g)\n", u, v, q, got,
                                                        near[q], far[q], ref, rn, rf);
                                }
                                near_wins += rn > rf;
                                far_wins += rf > rn;
                        }
                }
        CHECK_INT_EQ(bad, 0);
        /* Both parts decide the bound somewhere (a split that put every band in one part
         * would not be tested here). */
        fprintf(stderr, "bounds decided by the near part: %d, by the far part: %d\n", near_wins, far_wins);
        CHECK_INT_GE(near_wins, 100);
        CHECK_INT_GE(far_wins, 100);
}

static void check_ray(const struct imp_btf_heightfield *hf, const struct imp_btf_horizon *hz,
                      const struct imp_btf_sample_params *sp, double hmax, int u, int v, const double d[3],
                      long *n_clear, long *n_wrong, long *n_free) {
        const double o[3] = { u * PITCH, v * PITCH, hat(u, v) };
        bool clear = imp_btf_horizon_clear(hz, u, v, d);
        bool hit = imp_btf_heightfield_ray(hf, sp, hmax, o, d, 1e3, NULL);
        *n_clear += clear;
        *n_free += !hit;
        if (clear && hit && (*n_wrong)++ < 5)
                fprintf(stderr, "texel (%d, %d) d (%.6f %.6f %.6f): horizon clear, march blocked\n", u, v, d[0], d[1],
                        d[2]);
}

static void test_against_march(const struct imp_btf_heightfield *hf, const struct imp_btf_horizon *hz) {
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        CHECK_NEAR(sp.shadow_bias_texels * PITCH, BIAS, 1e-15);
        const double hmax = imp_btf_heightfield_hmax(hf), elev_deg[7] = { 3, 8, 15, 25, 40, 60, 80 };
        long n = 0, n_clear = 0, n_wrong = 0, n_edge = 0, n_edge_clear = 0, n_free = 0, n_edge_free = 0;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        if (!isfinite(hat(u, v)))
                                continue;
                        for (int a = 0; a < 48; a++) {
                                double phi = 2.0 * M_PI * a / 48.0, c = cos(phi), s = sin(phi);
                                if (a % 12 == 0)        /* exact axes */
                                        c = a == 0 ? 1 : a == 24 ? -1 : 0, s = a == 12 ? 1 : a == 36 ? -1 : 0;
                                for (int e = 0; e < 7; e++, n++) {
                                        double el = elev_deg[e] * M_PI / 180.0;
                                        const double d[3] = { cos(el) * c, cos(el) * s, sin(el) };
                                        check_ray(hf, hz, &sp, hmax, u, v, d, &n_clear, &n_wrong, &n_free);
                                }
                                /* Exactly at the bound of the ray's quadrant. */
                                int q = (c < 0.0) | (s < 0.0) << 1;
                                double g = imp_btf_horizon_slope(hz, u, v, q), k = 1.0 / sqrt(1.0 + g * g);
                                const double d[3] = { k * c, k * s, g * k };
                                long before = n_clear;
                                check_ray(hf, hz, &sp, hmax, u, v, d, &n_clear, &n_wrong, &n_edge_free);
                                n_edge++;
                                n_edge_clear += n_clear - before;
                        }
                }
        fprintf(stderr, "%ld rays: %ld unblocked for the march, %ld cleared by the horizon, %ld wrongly; "
                "%ld of %ld at the bound cleared\n", n, n_free, n_clear - n_edge_clear, n_wrong, n_edge_clear, n_edge);
        CHECK_INT_EQ(n_wrong, 0);
        /* Rays at the bound are cleared (up to rounding of the direction). */
        CHECK_GE(n_edge_clear, 0.9 * n_edge);
        /* A good part of the rays the march finds unblocked are cleared without it. */
        CHECK_GE(n_clear - n_edge_clear, 0.4 * n_free);
}

int main(void) {
        struct imp_btf_heightfield hf;
        make_relief(&hf);
        struct imp_btf_horizon *hz = NULL;
        CHECK_ERR(imp_btf_horizon_new(&hf, NAN, &hz), -EINVAL);
        CHECK_OK(imp_btf_horizon_new(&hf, BIAS, &hz));
        test_bound_is_definition(hz);
        test_against_march(&hf, hz);
        imp_btf_horizon_free(hz);
        return TEST_DONE();
}
