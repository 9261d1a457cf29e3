/* The conservative horizon of btf-horizon.c, per octant of azimuth, on a synthetic relief
 * with cliffs (a raised plateau, a pit, a one-texel spike, a diagonal ridge, a hole of
 * non-finite heights) and on random reliefs (white noise, and one-texel walls and spikes
 * along the octants' diagonals and axes, where a wedge one texel too narrow would miss
 * them): (1) every bound equals a brute-force evaluation of its definition (a wedge one
 * texel too small or too large, a missing "+ 1" row above the diagonal, a wrong band run
 * or a wrong near cell changes it); (2) no ray the horizon clears is blocked for the
 * march (imp_btf_heightfield_ray), over every texel and 48 azimuths at 7 elevations plus
 * rays exactly at each texel's bound; (3) the horizon clears most rays above the relief
 * (it is not a bound that never clears), and at least every ray the quadrant's box bound
 * (the previous definition, evaluated here) cleared. */
#include <math.h>
#include <stdlib.h>

#include "btf.h"
#include "unit/test.h"

enum { W = 46, H = 38 };
#define PITCH 0.05
#define BIAS (0.05 * PITCH)
#define EPS_MM 1e-9                    /* the rounding margin of btf-horizon.c */

static float height[W * H], normal[3 * W * H];
static unsigned rng = 12345;

static double uniform(void) {
        rng = rng * 1103515245u + 12345u;
        return (rng >> 8) / 16777216.0;
}

static void set_hf(struct imp_btf_heightfield *hf) {
        for (int t = 0; t < W * H; t++)
                normal[3 * t + 2] = 1.0f;
        *hf = (struct imp_btf_heightfield) { .width = W, .height = H, .pitch_mm = PITCH, .height_mm = height,
                .normal = normal, .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 } };
}

/* kind 0: white noise of ±amp mm; kind 1: a low floor with one-texel walls along both
 * diagonals and both axes through random points, and sparse tall spikes. */
static void make_random(struct imp_btf_heightfield *hf, int kind, double amp) {
        for (int t = 0; t < W * H; t++)
                height[t] = (float) (kind == 0 ? amp * (2 * uniform() - 1) : 0.02 * amp * uniform());
        for (int k = 0; kind == 1 && k < 6; k++) {
                int u0 = (int) (uniform() * W), v0 = (int) (uniform() * H);
                for (int s = -W; s < W; s++) {
                        const int pts[4][2] = { { u0 + s, v0 + s }, { u0 + s, v0 - s }, { u0 + s, v0 }, { u0, v0 + s } };
                        for (int a = 0; a < 4; a++)
                                if (pts[a][0] >= 0 && pts[a][0] < W && pts[a][1] >= 0 && pts[a][1] < H && uniform() < 0.7)
                                        height[pts[a][1] * W + pts[a][0]] = (float) (amp * (0.3 + uniform()));
                }
        }
        for (int k = 0; kind == 1 && k < 20; k++)
                height[(int) (uniform() * H) * W + (int) (uniform() * W)] = (float) (2 * amp * uniform());
        set_hf(hf);
}

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
        set_hf(hf);
}

static double hat(int u, int v) {
        if (u < 0 || v < 0 || u >= W || v >= H)
                return NAN;
        return height[v * W + u];
}

/* Largest finite height in [u, u + su·r] × [v, v + sv·r] ∩ grid (the quadrant's box). */
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

/* The octant's axes: e_P = (pu, pv), e_S = (qu, qv) (btf-horizon.c). */
static void axes(int o, int ax[4]) {
        int su = o & 1 ? -1 : 1, sv = o & 2 ? -1 : 1;
        if (o & 4)
                ax[0] = 0, ax[1] = sv, ax[2] = su, ax[3] = 0;
        else
                ax[0] = su, ax[1] = 0, ax[2] = 0, ax[3] = sv;
}

/* Largest finite height in T(r) = {i·e_P + j·e_S : 0 ≤ i ≤ r, 0 ≤ j ≤ i + 1} ∩ grid. */
static double wedge_max(int u, int v, int o, int r) {
        int ax[4];
        axes(o, ax);
        double m = -HUGE_VAL;
        for (int i = 0; i <= r; i++)
                for (int j = 0; j <= i + 1; j++) {
                        double h = hat(u + i * ax[0] + j * ax[2], v + i * ax[1] + j * ax[3]);
                        if (isfinite(h) && h > m)
                                m = h;
                }
        return m;
}

/* The near cell's largest rise per texel along a direction of octant o (or of its whole
 * quadrant when o < 0 and q is given as −1 − q). */
static double near_bound(int u, int v, int o) {
        int q = o < 0 ? -1 - o : o & 3, su = q & 1 ? -1 : 1, sv = q & 2 ? -1 : 1;
        double h0 = hat(u, v), h1 = hat(u + su, v), h2 = hat(u, v + sv), h3 = hat(u + su, v + sv);
        if (!(isfinite(h0) && isfinite(h1) && isfinite(h2) && isfinite(h3)))
                return 0.0;
        double a = fmax(0.0, fmax(h1 - h0, h3 - h2)), b = fmax(0.0, fmax(h2 - h0, h3 - h1));
        if (o < 0)
                return sqrt(a * a + b * b) / PITCH;
        if (o & 4) {
                double t = a;
                a = b, b = t;
        }
        return (a >= b ? sqrt(a * a + b * b) : (a + b) / sqrt(2.0)) / PITCH;
}

/* The definition in btf-horizon.c's header comment, evaluated the slow way: bands (1, 2],
 * then (b, 3b/2] and (3b/2, 2b] for b = 2, 4, 8, … while b < max(W, H). */
static double reference_bound(int u, int v, int o) {
        double h0 = hat(u, v), g = near_bound(u, v, o);
        g = fmax(g, (wedge_max(u, v, o, 2) - BIAS + EPS_MM - h0) / PITCH);
        for (int b = 2; b < (W > H ? W : H); b *= 2) {
                g = fmax(g, (wedge_max(u, v, o, b + b / 2) - BIAS + EPS_MM - h0) / (b * PITCH));
                g = fmax(g, (wedge_max(u, v, o, 2 * b) - BIAS + EPS_MM - h0) / ((b + b / 2) * PITCH));
        }
        return g;
}

/* The previous definition, per quadrant: the box of radius r over the band run before it,
 * radii 1, 2, 3, 4, 6, 9, 13, …; for the comparison of what each clears. */
static double quadrant_bound(int u, int v, int q) {
        int su = q & 1 ? -1 : 1, sv = q & 2 ? -1 : 1;
        double h0 = hat(u, v), g = near_bound(u, v, -1 - q);
        for (int r = 1; r < (W > H ? W : H); ) {
                int step = r < 4 ? 1 : r / 2;
                g = fmax(g, (box_max(u, v, su, sv, r + step) - BIAS + EPS_MM - h0) / (r * PITCH));
                r += step;
        }
        return g;
}

static void test_bound_is_definition(const struct imp_btf_horizon *hz) {
        int bad = 0;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        if (!isfinite(hat(u, v)))
                                continue;
                        for (int o = 0; o < IMP_BTF_HORIZON_OCTANTS; o++) {
                                double ref = reference_bound(u, v, o), got = imp_btf_horizon_slope(hz, u, v, o);
                                /* rounded up to float, one float step above at most */
                                if (!(got >= ref && got <= ref + 3e-7 * fabs(ref) + 1e-30)) {
                                        if (bad++ < 5)
                                                fprintf(stderr, "texel (%d, %d) octant %d: bound %.9g, definition %.9g\n",
                                                        u, v, o, got, ref);
                                }
                        }
                }
        CHECK_INT_EQ(bad, 0);
}

struct ray_counts {
        long clear, wrong, free, quadrant;   /* cleared, cleared but blocked, unblocked, cleared by the box bound */
};

static void check_ray(const struct imp_btf_heightfield *hf, const struct imp_btf_horizon *hz,
                      const struct imp_btf_sample_params *sp, double hmax, int u, int v, const double d[3],
                      struct ray_counts *c) {
        const double o[3] = { u * PITCH, v * PITCH, hat(u, v) };
        bool clear = imp_btf_horizon_clear(hz, u, v, d);
        bool hit = imp_btf_heightfield_ray(hf, sp, hmax, o, d, 1e3, NULL);
        double qb = quadrant_bound(u, v, (d[0] < 0.0) | (d[1] < 0.0) << 1);
        c->quadrant += d[2] > 0 && d[2] >= (double) nextafterf((float) qb, HUGE_VALF) * hypot(d[0], d[1]);
        c->clear += clear;
        c->free += !hit;
        if (clear && hit && c->wrong++ < 5)
                fprintf(stderr, "texel (%d, %d) d (%.6f %.6f %.6f): horizon clear, march blocked\n", u, v, d[0], d[1],
                        d[2]);
}

/* Every texel, 96 azimuths (the axes, the diagonals and a hair either side of each
 * diagonal among them) at 7 elevations, plus each texel's rays exactly at its bound. */
static void test_against_march(const struct imp_btf_heightfield *hf, const struct imp_btf_horizon *hz, double frac) {
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        CHECK_NEAR(sp.shadow_bias_texels * PITCH, BIAS, 1e-15);
        const double hmax = imp_btf_heightfield_hmax(hf), elev_deg[7] = { 3, 8, 15, 25, 40, 60, 80 };
        struct ray_counts rc = {}, edge = {};
        long n = 0, n_edge = 0;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        if (!isfinite(hat(u, v)))
                                continue;
                        for (int a = 0; a < 96; a++) {
                                double phi = 2.0 * M_PI * a / 96.0;
                                if (a % 24 == 11 || a % 24 == 13)   /* 1e-6 rad off a diagonal */
                                        phi = 2.0 * M_PI * ((a + 1) / 24 * 24 + (a % 24 == 11 ? -12 : 12)) / 96.0 +
                                              (a % 24 == 11 ? -1e-6 : 1e-6);
                                double c = cos(phi), s = sin(phi);
                                if (a % 24 == 0)        /* exact axes */
                                        c = a == 0 ? 1 : a == 48 ? -1 : 0, s = a == 24 ? 1 : a == 72 ? -1 : 0;
                                for (int e = 0; e < 7; e++, n++) {
                                        double el = elev_deg[e] * M_PI / 180.0;
                                        const double d[3] = { cos(el) * c, cos(el) * s, sin(el) };
                                        check_ray(hf, hz, &sp, hmax, u, v, d, &rc);
                                }
                                /* Exactly at the bound of the ray's octant. */
                                const double d0[3] = { c, s, 0 };
                                double g = imp_btf_horizon_slope(hz, u, v, imp_btf_horizon_octant(d0));
                                double k = 1.0 / sqrt(1.0 + g * g);
                                const double d[3] = { k * c, k * s, g * k };
                                check_ray(hf, hz, &sp, hmax, u, v, d, &edge);
                                n_edge++;
                        }
                }
        fprintf(stderr, "%ld rays: %ld unblocked for the march, %ld cleared by the horizon (%ld by the quadrant's "
                "box bound), %ld wrongly; %ld of %ld at the bound cleared, %ld wrongly\n", n, rc.free, rc.clear,
                rc.quadrant, rc.wrong, edge.clear, n_edge, edge.wrong);
        CHECK_INT_EQ(rc.wrong + edge.wrong, 0);
        /* Rays at the bound are cleared (up to rounding of the direction). */
        CHECK_GE(edge.clear, 0.9 * n_edge);
        /* A good part of the rays the march finds unblocked are cleared without it, and
         * more than the quadrant's box cleared. */
        CHECK_GE(rc.clear, frac * rc.free);
        CHECK_GE(rc.clear, rc.quadrant + 1);
}

/* frac: the share of the unblocked rays the horizon must clear on this relief. */
static void check_relief(const struct imp_btf_heightfield *hf, const char *what, double frac) {
        fprintf(stderr, "%s:\n", what);
        struct imp_btf_horizon *hz = NULL;
        CHECK_OK(imp_btf_horizon_new(hf, BIAS, &hz));
        test_bound_is_definition(hz);
        test_against_march(hf, hz, frac);
        imp_btf_horizon_free(hz);
}

int main(void) {
        struct imp_btf_heightfield hf;
        make_relief(&hf);
        struct imp_btf_horizon *hz = NULL;
        CHECK_ERR(imp_btf_horizon_new(&hf, NAN, &hz), -EINVAL);
        check_relief(&hf, "cliffs, pit, spike, ridge, hole", 0.5);
        make_random(&hf, 0, 0.1);
        check_relief(&hf, "white noise ±0.1 mm", 0.4);
        make_random(&hf, 1, 0.5);
        check_relief(&hf, "one-texel walls along the diagonals and axes, spikes", 0.25);
        return TEST_DONE();
}
