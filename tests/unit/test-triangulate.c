/* Triangulation on a synthetic rig (camera above the canvas, projector at 20°, both with
 * Brown–Conrady distortion): exact decoder output for a plane and a sphere must give the
 * surface within 1 µm (both coordinates, column only); the reported σ must match the
 * scatter under projector-coordinate noise and grow as the triangulation angle closes;
 * validity masks, decoder flags and confidence are honoured. The rig maths of rig.c
 * (imp_pinhole_*) generates the data, so the two implementations check each other. */
#include <math.h>
#include <string.h>
#include "triangulate.h"
#include "unit/test.h"

static uint64_t rng_state = 12345;
static double urand(void) {
        uint64_t z = (rng_state += 0x9e3779b97f4a7c15ULL);
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
        z ^= z >> 31;
        return ((z >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}
static double nrand(void) { return sqrt(-2 * log(urand())) * cos(2 * M_PI * urand()); }

#define CW 320
#define CH 240

static void make_rig(struct imp_pinhole *cam, struct imp_pinhole *proj, double angle_deg) {
        *cam = (struct imp_pinhole) { .width = CW, .height = CH, .fx = 900, .fy = 900, .cx = 159.5, .cy = 119.5,
                                      .k1 = -0.08, .k2 = 0.02, .p1 = 2e-4, .p2 = -1e-4 };
        *proj = (struct imp_pinhole) { .width = 1280, .height = 800, .fx = 2200, .fy = 2200, .cx = 639.5, .cy = 399.5,
                                       .k1 = 0.05, .k2 = -0.01, .p1 = -3e-4, .p2 = 1e-4, .k3 = 0.001 };
        double target[3] = { 0, 0, 0 }, right[3] = { 1, 0, 0 };
        double eye_c[3] = { 0, 0, 600 };
        double a = angle_deg * M_PI / 180;
        double eye_p[3] = { 600 * sin(a), 0, 600 * cos(a) };
        imp_pinhole_look_at(cam, eye_c, target, right);
        imp_pinhole_look_at(proj, eye_p, target, right);
}

/* Surfaces: plane z = 0.2·x + 3 (tilted) or a sphere cap. Returns ray parameter. */
static bool hit(int shape, const double o[3], const double d[3], double ret_X[3]) {
        double lam;
        if (shape == 0) {
                /* z − 0.2x − 3 = 0 */
                double den = d[2] - 0.2 * d[0];
                lam = (0.2 * o[0] + 3 - o[2]) / den;
        } else {
                const double c[3] = { 10, 5, -80 }, R = 100;
                double oc[3] = { o[0] - c[0], o[1] - c[1], o[2] - c[2] };
                double b = oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2];
                double cc = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - R * R, disc = b * b - cc;
                if (disc < 0)
                        return false;
                lam = -b - sqrt(disc);
        }
        for (int k = 0; k < 3; k++)
                ret_X[k] = o[k] + lam * d[k];
        return lam > 0;
}

struct synth {
        float px[CW * CH], py[CW * CH];
        uint8_t vx[CW * CH], vy[CW * CH];
        double truth[CW * CH][3];
};

static void synthesize(const struct imp_pinhole *cam, const struct imp_pinhole *proj, int shape, double noise_px,
                       struct synth *s) {
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        size_t i = (size_t) y * CW + x;
                        double pix[2] = { x, y }, o[3], d[3], X[3], u[2];
                        imp_pinhole_ray_world(cam, pix, o, d);
                        s->vx[i] = s->vy[i] = 0;
                        s->px[i] = s->py[i] = -1;
                        if (!hit(shape, o, d, X) || !imp_pinhole_project(proj, X, u))
                                continue;
                        memcpy(s->truth[i], X, sizeof X);
                        s->px[i] = (float) (u[0] + 0.5 + noise_px * nrand());   /* decoder convention */
                        s->py[i] = (float) (u[1] + 0.5 + noise_px * nrand());
                        s->vx[i] = s->vy[i] = u[0] >= 0 && u[1] >= 0 && u[0] < proj->width && u[1] < proj->height;
                }
}

static double max_error_um(const struct imp_range_image *r, const struct synth *s, size_t *ret_n) {
        double mx = 0;
        size_t n = 0;
        for (size_t i = 0; i < (size_t) CW * CH; i++) {
                if (!r->valid[i])
                        continue;
                double e2 = 0;
                for (int k = 0; k < 3; k++)
                        e2 += pow(r->xyz[3 * i + k] - s->truth[i][k], 2);
                mx = fmax(mx, sqrt(e2) * 1000);
                n++;
        }
        *ret_n = n;
        return mx;
}

static void test_exact(int shape) {
        struct imp_pinhole cam, proj;
        make_rig(&cam, &proj, 20);
        static struct synth s;
        synthesize(&cam, &proj, shape, 0, &s);
        size_t n_in = 0;
        for (size_t i = 0; i < (size_t) CW * CH; i++)
                n_in += s.vx[i];
        for (int mode = 0; mode < 2; mode++) {
                struct imp_projector_coords pc = { .width = CW, .height = CH, .proj_x = s.px, .valid_x = s.vx,
                                                   .proj_y = mode == 0 ? s.py : NULL, .valid_y = s.vy };
                struct imp_range_image r = {};
                CHECK_OK(imp_triangulate(&cam, &proj, &pc, NULL, &r));
                size_t n;
                double e = max_error_um(&r, &s, &n);
                fprintf(stderr, "%s, %s: %zu/%zu points, max error %.4f µm\n", shape ? "sphere" : "tilted plane",
                        mode ? "column only" : "both coordinates", n, n_in, e);
                CHECK_INT_EQ(n, n_in);
                CHECK_LE(e, 1.0);
                CHECK_INT_EQ(r.n_valid, n);
                for (size_t i = 0; i < (size_t) CW * CH; i++) {
                        if (!r.valid[i])
                                continue;
                        CHECK_INT_EQ(r.valid[i], mode ? IMP_RANGE_COLUMN : IMP_RANGE_BOTH);
                        break;
                }
                double C[3];
                imp_pinhole_centre(&cam, C);
                CHECK_NEAR(r.camera_centre_mm[2], C[2], 1e-9);
                imp_range_image_done(&r);
        }
}

/* σ reported vs scatter under Gaussian noise of the projector coordinates. */
static void test_sigma_matches_noise(void) {
        struct imp_pinhole cam, proj;
        make_rig(&cam, &proj, 20);
        static struct synth s;
        const double sigma_px = 0.1;
        synthesize(&cam, &proj, 0, sigma_px, &s);
        for (int mode = 0; mode < 2; mode++) {
                struct imp_projector_coords pc = { .width = CW, .height = CH, .proj_x = s.px, .valid_x = s.vx,
                                                   .proj_y = mode == 0 ? s.py : NULL, .valid_y = s.vy };
                struct imp_triangulate_options o;
                imp_triangulate_options_default(&o);
                o.sigma_proj_px = sigma_px;
                struct imp_range_image r = {};
                CHECK_OK(imp_triangulate(&cam, &proj, &pc, &o, &r));
                /* Normalised error along the ray: (X − truth)·d / σ should have unit rms. */
                double ss = 0;
                size_t n = 0;
                for (size_t i = 0; i < (size_t) CW * CH; i++) {
                        if (!r.valid[i])
                                continue;
                        double e2 = 0;
                        for (int k = 0; k < 3; k++)
                                e2 += pow(r.xyz[3 * i + k] - s.truth[i][k], 2);
                        ss += e2 / pow(r.sigma_mm[i], 2);
                        n++;
                }
                double ratio = sqrt(ss / n);
                fprintf(stderr, "noise %.2f px, %s: rms(error/σ) = %.3f over %zu points\n", sigma_px,
                        mode ? "column only" : "both", ratio, n);
                CHECK_NEAR(ratio, 1.0, 0.05);
                imp_range_image_done(&r);
        }
}

static void test_sigma_grows_at_grazing_angle(void) {
        const double angles[] = { 30, 20, 10, 5 };
        double prev = 0;
        for (size_t k = 0; k < ARRAY_SIZE(angles); k++) {
                struct imp_pinhole cam, proj;
                make_rig(&cam, &proj, angles[k]);
                static struct synth s;
                synthesize(&cam, &proj, 0, 0, &s);
                struct imp_projector_coords pc = { .width = CW, .height = CH, .proj_x = s.px, .valid_x = s.vx };
                struct imp_triangulate_options o;
                imp_triangulate_options_default(&o);
                o.min_angle_rad = 1 * M_PI / 180;
                struct imp_range_image r = {};
                CHECK_OK(imp_triangulate(&cam, &proj, &pc, &o, &r));
                size_t c = (size_t) (CH / 2) * CW + CW / 2;
                CHECK(r.valid[c]);
                double sig_um = r.sigma_mm[c] * 1000;
                fprintf(stderr, "projector at %4.1f°: σ at the centre %.2f µm\n", angles[k], sig_um);
                CHECK_GE(sig_um, prev * 1.3);
                prev = sig_um;
                imp_range_image_done(&r);
        }
        /* A triangulation angle under min_angle_rad is invalid, not a huge number. */
        struct imp_pinhole cam, proj;
        make_rig(&cam, &proj, 1.5);
        static struct synth s;
        synthesize(&cam, &proj, 0, 0, &s);
        struct imp_projector_coords pc = { .width = CW, .height = CH, .proj_x = s.px, .valid_x = s.vx };
        struct imp_range_image r = {};
        CHECK_OK(imp_triangulate(&cam, &proj, &pc, NULL, &r));
        CHECK_INT_EQ(r.n_valid, 0);
        imp_range_image_done(&r);
}

static void test_masks_and_confidence(void) {
        struct imp_pinhole cam, proj;
        make_rig(&cam, &proj, 20);
        static struct synth s;
        synthesize(&cam, &proj, 1, 0, &s);
        static uint16_t flags[CW * CH];
        static uint16_t conf[CW * CH];
        size_t expect = 0;
        for (size_t i = 0; i < (size_t) CW * CH; i++) {
                flags[i] = (i % 3 == 0 ? 0 : IMP_SL_VALID_X) | (i % 5 == 0 ? 0 : IMP_SL_VALID_Y);
                if (!s.vx[i])
                        flags[i] = IMP_SL_SHADOW;
                conf[i] = imp_sl_conf16(i % 7 == 0 ? 0.01f : 0.5f);
                expect += (flags[i] & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) && imp_sl_conf(conf[i]) >= 0.05f &&
                          ((flags[i] & IMP_SL_VALID_X) || s.vy[i]);
        }
        struct imp_sl_result sl = { .width = CW, .height = CH, .proj_x = s.px, .proj_y = s.py, .confidence = conf,
                                    .flags = flags };
        struct imp_projector_coords pc;
        imp_projector_coords_from_sl(&sl, &pc);
        struct imp_range_image r = {};
        CHECK_OK(imp_triangulate(&cam, &proj, &pc, NULL, &r));
        size_t n_row = 0, n_col = 0, n_both = 0;
        for (size_t i = 0; i < (size_t) CW * CH; i++) {
                n_row += r.valid[i] == IMP_RANGE_ROW;
                n_col += r.valid[i] == IMP_RANGE_COLUMN;
                n_both += r.valid[i] == IMP_RANGE_BOTH;
                if (r.valid[i]) {
                        CHECK(imp_sl_conf(conf[i]) >= 0.05f);
                        CHECK_NEAR(r.sigma_mm[i] > 0, 1, 0);
                } else {
                        CHECK_NEAR(r.xyz[3 * i + 2], 0, 0);
                }
        }
        fprintf(stderr, "flags: both %zu, column %zu, row %zu (expected ≤ %zu valid)\n", n_both, n_col, n_row, expect);
        CHECK(n_both > 0 && n_col > 0);
        CHECK_LE(n_both + n_col + n_row, expect);
        imp_range_image_done(&r);

        /* Errors: *ret untouched. */
        struct imp_range_image keep = { .width = 77 };
        pc.width = 0;
        CHECK_ERR(imp_triangulate(&cam, &proj, &pc, NULL, &keep), -EINVAL);
        CHECK_INT_EQ(keep.width, 77);
        struct imp_pinhole bad = cam;
        bad.fx = 0;
        pc.width = CW;
        CHECK_ERR(imp_triangulate(&bad, &proj, &pc, NULL, &keep), -EINVAL);
}

/* The projection Jacobian against central differences. */
static void test_jacobian(void) {
        struct imp_pinhole cam, proj;
        make_rig(&cam, &proj, 20);
        double X[3] = { 30, -20, 5 }, u[2], J[6];
        CHECK(imp_triangulate_project(&proj, X, u, J));
        double u_ref[2];
        CHECK(imp_pinhole_project(&proj, X, u_ref));
        CHECK_NEAR(u[0], u_ref[0], 1e-9);
        CHECK_NEAR(u[1], u_ref[1], 1e-9);
        for (int c = 0; c < 3; c++) {
                double Xp[3] = { X[0], X[1], X[2] }, Xm[3] = { X[0], X[1], X[2] }, up[2], um[2];
                Xp[c] += 1e-4, Xm[c] -= 1e-4;
                imp_triangulate_project(&proj, Xp, up, NULL);
                imp_triangulate_project(&proj, Xm, um, NULL);
                CHECK_NEAR(J[c], (up[0] - um[0]) / 2e-4, 1e-5);
                CHECK_NEAR(J[3 + c], (up[1] - um[1]) / 2e-4, 1e-5);
        }
}

int main(void) {
        test_jacobian();
        test_exact(0);
        test_exact(1);
        test_sigma_matches_noise();
        test_sigma_grows_at_grazing_angle();
        test_masks_and_confidence();
        return TEST_DONE();
}
