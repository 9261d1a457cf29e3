/* Degenerate light calibrations: a saturated highlight (flagged, centroid still within
 * 0.3 px, σ ≥ 0.25 px, and that σ carried into the reflected ray with the sphere centre's),
 * nearly and exactly parallel rays (IMP_LIGHT_ILL_CONDITIONED, σ larger than the
 * well-conditioned case, finite values), one ray, NaN refused. */
#include <math.h>
#include <stdint.h>
#include "calib-lights.h"
#include "test.h"

static uint64_t rng_state = 0x853c49e6748fea9bull;
static double urand(void) {
        rng_state ^= rng_state << 13; rng_state ^= rng_state >> 7; rng_state ^= rng_state << 17;
        return ((rng_state >> 11) + 0.5) / 9007199254740992.0;
}
static double nrand(void) { return sqrt(-2 * log(urand())) * cos(2 * M_PI * urand()); }

static void check_finite(const struct imp_light_estimate *e) {
        for (int k = 0; k < 3; k++) CHECK_FINITE(e->pos_mm[k]);
        for (int k = 0; k < 9; k++) CHECK_FINITE(e->cov_mm2[k]);
        CHECK_FINITE(e->sigma_mm);
        CHECK_FINITE(e->cond);
        CHECK_FINITE(e->rms_mm);
}

static void test_saturated(void) {
        /* a sphere disc of radius 150 px at (200, 200) of a 400×400 view; spot at a sub-pixel spot */
        struct imp_image *img = NULL;
        CHECK_OK(imp_image_new(400, 400, 1, IMP_PIX_F32, &img));
        const double spot[2] = { 231.37, 168.81 }, sat = 4095;
        for (int y = 0; y < 400; y++)
                for (int x = 0; x < 400; x++) {
                        double r2 = (x - 200.0) * (x - 200.0) + (y - 200.0) * (y - 200.0);
                        double v = r2 < 150 * 150 ? 40 : 1000, dx = x - spot[0], dy = y - spot[1];
                        v += 40000 * exp(-(dx * dx + dy * dy) / (2 * 1.3 * 1.3)) + 2 * nrand();
                        *imp_image_f32(img, x, y) = (float) fmin(v, sat);
                }
        struct imp_sphere s = { .radius_mm = 10, .image_centre_px = { 200, 200 }, .image_radius_px = 150 };
        struct imp_frame_view v = { img, 0, 0 };
        struct imp_highlight h;
        CHECK_OK(imp_lights_highlight(&v, &s, sat, &h));
        fprintf(stderr, "saturated: error %.4f px, σ %.3f px, %d pixels\n", hypot(h.px[0] - spot[0], h.px[1] - spot[1]),
                h.sigma_px, h.n_pixels);
        CHECK(h.saturated);
        CHECK_LE(hypot(h.px[0] - spot[0], h.px[1] - spot[1]), 0.3);
        CHECK_GE(h.sigma_px, 0.25);
        /* the same spot unsaturated has a smaller σ */
        for (int y = 0; y < 400; y++)
                for (int x = 0; x < 400; x++) {
                        float *p = imp_image_f32(img, x, y);
                        double dx = x - spot[0], dy = y - spot[1];
                        *p = (float) ((((x - 200.0) * (x - 200.0) + (y - 200.0) * (y - 200.0)) < 150 * 150 ? 40 : 1000) +
                                      3000 * exp(-(dx * dx + dy * dy) / (2 * 1.3 * 1.3)) + 2 * nrand());
                }
        struct imp_highlight h2;
        CHECK_OK(imp_lights_highlight(&v, &s, sat, &h2));
        CHECK(!h2.saturated);
        CHECK_LE(h2.sigma_px, h.sigma_px);
        CHECK_LE(hypot(h2.px[0] - spot[0], h2.px[1] - spot[1]), 0.05);
        /* no highlight at all: -ENOENT */
        for (int y = 0; y < 400; y++)
                for (int x = 0; x < 400; x++)
                        *imp_image_f32(img, x, y) = (float) (40 + 2 * nrand());
        CHECK_ERR(imp_lights_highlight(&v, &s, sat, &h2), -ENOENT);
        imp_image_free(img);
}

/* Two rays from origins a baseline apart along x towards L, with 0.1 mrad noise. */
static void rays(double baseline_mm, const double L[3], double o[2][3], double d[2][3]) {
        for (int i = 0; i < 2; i++) {
                o[i][0] = i ? baseline_mm / 2 : -baseline_mm / 2;
                o[i][1] = 0;
                o[i][2] = 10;
                double n = 0;
                for (int k = 0; k < 3; k++) { d[i][k] = L[k] - o[i][k] + 0.05 * nrand(); n += d[i][k] * d[i][k]; }
                for (int k = 0; k < 3; k++) d[i][k] /= sqrt(n);
        }
}

static void test_collinear(void) {
        const double L[3] = { 0, 250, 433 }, sg[2] = { 1e-4, 1e-4 };
        double o[2][3], d[2][3];
        struct imp_light_estimate good, bad, par, one;
        rays(220, L, o, d);
        CHECK_OK(imp_lights_triangulate(2, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &good));
        check_finite(&good);
        CHECK_INT_EQ(good.flags, 0);
        /* spheres 5 mm apart: the rays meet at 0.6°; the light is almost on their line */
        rays(5, L, o, d);
        CHECK_OK(imp_lights_triangulate(2, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &bad));
        check_finite(&bad);
        fprintf(stderr, "collinear: good σ %.3f mm cond %.1f; 5 mm baseline σ %.1f mm cond %.3g flags %#x\n",
                good.sigma_mm, good.cond, bad.sigma_mm, bad.cond, bad.flags);
        CHECK(bad.flags & IMP_LIGHT_ILL_CONDITIONED);
        CHECK_GE(bad.sigma_mm, 100 * good.sigma_mm);
        CHECK_GE(bad.sigma_mm, 500);     /* inflated to the prior along the weak direction */
        /* exactly parallel rays: finite, flagged */
        for (int k = 0; k < 3; k++) d[1][k] = d[0][k];
        CHECK_OK(imp_lights_triangulate(2, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &par));
        check_finite(&par);
        CHECK(par.flags & IMP_LIGHT_ILL_CONDITIONED);
        /* one ray: flagged few rays, finite */
        CHECK_OK(imp_lights_triangulate(1, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &one));
        check_finite(&one);
        CHECK(one.flags & IMP_LIGHT_FEW_RAYS);
        CHECK(one.flags & IMP_LIGHT_ILL_CONDITIONED);
        /* NaN refused, output untouched */
        struct imp_light_estimate keep = { .sigma_mm = -7 };
        d[0][1] = NAN;
        CHECK_ERR(imp_lights_triangulate(2, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &keep), -EINVAL);
        CHECK_NEAR(keep.sigma_mm, -7, 0);
}

/* A saturated highlight's σ and the sphere centre's σ both reach the reflected ray. */
static void test_ray_sigma(void) {
        struct imp_pinhole cam = { .width = 1400, .height = 1000, .fx = 6000, .fy = 6000, .cx = 699.5, .cy = 499.5 };
        double eye[3] = { 0, 0, 300 }, at[3] = { 0, 0, 0 }, right[3] = { 1, 0, 0 }, o[3], d[3];
        imp_pinhole_look_at(&cam, eye, at, right);
        struct imp_sphere s = { .centre_mm = { 0, 0, 10 }, .radius_mm = 10, .cut_mm = NAN };
        const double px[2] = { 760.3, 470.8 };
        double s_sharp, s_sat, s_centre;
        CHECK_OK(imp_lights_reflect(&cam, &s, px, 0.02, o, d, &s_sharp));
        CHECK_OK(imp_lights_reflect(&cam, &s, px, 0.25, o, d, &s_sat));
        s.centre_sigma_mm = 0.005;
        CHECK_OK(imp_lights_reflect(&cam, &s, px, 0.02, o, d, &s_centre));
        fprintf(stderr, "ray σ: %.2e rad (0.02 px), %.2e (saturated, 0.25 px), %.2e (+ 5 µm centre)\n", s_sharp, s_sat,
                s_centre);
        CHECK_NEAR(s_sat / s_sharp, 12.5, 1.0);
        CHECK_NEAR(s_centre, hypot(s_sharp, 2 * 0.005 / 10), 1e-6);
        /* a pixel off the sphere: no ray */
        const double off[2] = { 1300, 900 };
        CHECK_ERR(imp_lights_reflect(&cam, &s, off, 0.02, o, d, &s_sharp), -EDOM);
}

int main(void) {
        test_saturated();
        test_collinear();
        test_ray_sigma();
        return TEST_DONE();
}
