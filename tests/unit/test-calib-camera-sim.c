/* Camera calibration of the simulated wide-field camera: renders the target set
 * config/scenes/calib-wide-{0..19}.cfg with config/plans/camera-target.cfg, runs
 * `impasto calibrate camera --sets …`, and compares with the simulator's truth (truth/rig.json
 * of each set). The noise floor is measured here: the RMS distance between the corners the
 * detector finds and the true corners (the board projected through the TRUE intrinsics and
 * TRUE camera pose of each set). The fit has 9 + 6·20 parameters more freedom than that, so
 * its RMS must lie just below the floor: ≤ floor (it cannot do worse than the truth, which is
 * one of its candidates) and ≥ RMS_FLOOR_MIN × floor (no over-fitting: white errors would
 * give √(1 − P/2N) ≈ 0.98). Tolerances below carry the figures measured when they were set
 * (docs/calibration.md, "Wide-field camera target set"). 2.5 min on 2 cores shared with
 * other jobs (load 11; 20 renders of 4–7 s): labelled slow. OpenCV inside, so not under
 * ASan (calib.cmake). */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "calib-camera.h"
#include "ceres-calib.h"
#include "cv-calib.h"
#include "rig.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define N_TARGETS 20

/* Measured when set (20 targets, OpenCV 4.6 + Ceres, noise on): fx +0.0033 %, fy +0.0032 %
 * (σ 0.14, 0.13 px), cx +0.22 px (σ 0.24), cy +0.18 px (σ 0.19); k1, p1, p2 within 0.9σ;
 * true vs fitted pixel of a ray ≤ 0.34 px inside the corners' box; RMS 0.0429 px against a
 * floor of 0.0438 px (ratio 0.981; √(1 − P/2N) = √(1 − 129/3520) = 0.982 for white errors);
 * found − true corners 0.025–0.054 px per view. With 14 of the targets: cx +0.21 (σ 0.28),
 * cy +0.21 (σ 0.21) — the principal point limit is met at about 1σ, not with a wide margin. */
#define F_REL_TOL        1e-3          /* issue #8: 0.1 % */
#define PP_TOL_PX        0.5           /* issue #8: 0.5 px */
#define N_SIGMA          3.0           /* errors within 3σ of the reported uncertainty */
#define FLOOR_MAX_PX     0.06          /* the rendered corners themselves: found − true RMS */
#define RMS_FLOOR_MIN    0.93          /* fitted RMS ≥ this × floor (no over-fitting) */
#define RMS_FLOOR_MAX    1.0           /* fitted RMS ≤ this × floor */
#define MAP_TOL_PX       0.5           /* true vs fitted pixel of one ray, inside the corners' hull */

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

/* The number at dotted path `path` ("std.fx") under j; NAN when missing. */
static double field(json_t *j, const char *path) {
        char key[64];
        for (const char *p = path; j && *p;) {
                size_t n = strcspn(p, ".");
                snprintf(key, sizeof key, "%.*s", (int) n, p);
                j = json_object_get(j, key);
                p += n + (p[n] == '.');
        }
        return j ? json_number_value(j) : NAN;
}

/* The board of scene `cfg` (flat on z = 0, sim/scene.h's imp_checker) seen by the set's true
 * camera against the corners the detector finds in the set's frame: adds the squared
 * distances (each found corner to the nearest true one) to *ss, the count to *n; also
 * tracks the box the true corners cover. -1 when something is missing. */
static int floor_of(const char *cfg, const char *dir, double *ss, int *n, double box[4]) {
        char text[16384], path[1100];
        FILE *f = fopen(cfg, "r");
        if (!f)
                return -1;
        size_t len = fread(text, 1, sizeof text - 1, f);
        fclose(f);
        text[len] = 0;
        double sq, ox, oy, ang;
        int cols, rows;
        const char *p2 = strstr(text, "square_mm = "), *p3 = strstr(text, "origin_mm = [");
        if (!p2 || !p3 || sscanf(p2, "square_mm = %lf; corners = [%d, %d]", &sq, &cols, &rows) != 3 ||
            sscanf(p3, "origin_mm = [%lf, %lf]; angle_deg = %lf", &ox, &oy, &ang) != 3 || cols * rows > 1024)
                return -1;
        struct imp_error err = { 0 };
        struct imp_rig truth = { 0 };
        snprintf(path, sizeof path, "%s/truth/rig.json", dir);
        if (imp_rig_load(path, &truth, &err) < 0)
                return -1;
        static double tru[2 * 1024], det[2 * 1024];
        double c = cos(ang * M_PI / 180), s = sin(ang * M_PI / 180);
        for (int k = 0; k < cols * rows; k++) {
                double U = sq * (k % cols), V = sq * (k / cols);
                double X[3] = { ox + c * U - s * V, oy + s * U + c * V, 0 };
                imp_pinhole_project(&truth.cameras[0].model, X, tru + 2 * k);
                box[0] = fmin(box[0], tru[2 * k]);
                box[1] = fmax(box[1], tru[2 * k]);
                box[2] = fmin(box[2], tru[2 * k + 1]);
                box[3] = fmax(box[3], tru[2 * k + 1]);
        }
        imp_rig_free(&truth);
        struct imp_image *u8 = NULL;
        if (imp_calib_camera_set_frame(dir, NULL, &u8, NULL, NULL, &err) < 0)
                return -1;
        int r = imp_cv_calib_find_corners(u8, cols, rows, det, &err);
        imp_image_free(u8);
        if (r < 0)
                return -1;
        double vs = 0;
        for (int k = 0; k < cols * rows; k++) {
                double bd = INFINITY;
                for (int t = 0; t < cols * rows; t++)
                        bd = fmin(bd, hypot(det[2 * k] - tru[2 * t], det[2 * k + 1] - tru[2 * t + 1]));
                vs += bd * bd;
        }
        fprintf(stderr, "%s: found − true corners RMS %.4f px\n", dir, sqrt(vs / (cols * rows)));
        *ss += vs;
        *n += cols * rows;
        return 0;
}

/* Largest distance between where the true and the fitted camera put the same ray, over a
 * grid inside box (the area the board covered). */
static double map_error(const struct imp_pinhole *t, const struct imp_pinhole *e, const double box[4]) {
        struct imp_pinhole T = *t, E = *e;
        static const double I[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };
        memcpy(T.R, I, sizeof I);
        memcpy(E.R, I, sizeof I);
        memset(T.t, 0, sizeof T.t);
        memset(E.t, 0, sizeof E.t);
        double worst = 0;
        for (int j = 0; j <= 20; j++)
                for (int i = 0; i <= 20; i++) {
                        double px[2] = { box[0] + (box[1] - box[0]) * i / 20, box[2] + (box[3] - box[2]) * j / 20 };
                        double d[3], q[2];
                        imp_pinhole_ray_device(&T, px, d);
                        if (imp_pinhole_project(&E, d, q))
                                worst = fmax(worst, hypot(q[0] - px[0], q[1] - px[1]));
                }
        return worst;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char cmd[8192], sets[4096] = "", path[1024];
        for (int i = 0; i < N_TARGETS; i++) {
                snprintf(cmd, sizeof cmd, "%s sim render --scene %s/config/scenes/calib-wide-%d.cfg --plan "
                         "%s/config/plans/camera-target.cfg --out %s/w%d --threads 2 --quiet > /dev/null",
                         IMPASTO, IMPASTO_SOURCE_DIR, i, IMPASTO_SOURCE_DIR, tmp, i);
                CHECK_INT_EQ(run(cmd), 0);
                snprintf(sets + strlen(sets), sizeof sets - strlen(sets), " %s/w%d", tmp, i);
        }
        snprintf(cmd, sizeof cmd, "%s calibrate camera --sets%s --board 11x8 --square 15 --json --out %s/rig.json "
                 "> %s/calib.json", IMPASTO, sets, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);

        /* The floor, over every set. */
        double ss = 0, box[4] = { INFINITY, -INFINITY, INFINITY, -INFINITY };
        int n = 0;
        for (int i = 0; i < N_TARGETS; i++) {
                char cfg[1024], dir[1024];
                snprintf(cfg, sizeof cfg, "%s/config/scenes/calib-wide-%d.cfg", IMPASTO_SOURCE_DIR, i);
                snprintf(dir, sizeof dir, "%s/w%d", tmp, i);
                CHECK_INT_EQ(floor_of(cfg, dir, &ss, &n, box), 0);
        }
        double floor_px = n ? sqrt(ss / n) : NAN;

        json_error_t jerr;
        snprintf(path, sizeof path, "%s/calib.json", tmp);
        json_t *j = json_load_file(path, 0, &jerr);
        CHECK(j != NULL);
        struct imp_error err = { 0 };
        struct imp_rig est = { 0 }, truth = { 0 };
        snprintf(path, sizeof path, "%s/rig.json", tmp);
        CHECK_OK(imp_rig_load(path, &est, &err));
        snprintf(path, sizeof path, "%s/w0/truth/rig.json", tmp);
        CHECK_OK(imp_rig_load(path, &truth, &err));
        if (!j || est.n_cameras < 1 || truth.n_cameras < 1)
                return TEST_DONE();
        json_t *cam = json_object_get(j, "camera");
        const struct imp_pinhole *t = &truth.cameras[0].model, *e = &est.cameras[0].model;
        double fx = field(cam, "fx"), fy = field(cam, "fy"), cx = field(cam, "cx"),
               cy = field(cam, "cy"), rms = field(cam, "rms_px");
        double sfx = field(cam, "std.fx"), sfy = field(cam, "std.fy"), scx = field(cam, "std.cx"),
               scy = field(cam, "std.cy");
        fprintf(stderr, "fx %.3f (true %.3f, %+.4f %%, σ %.3f)  fy %.3f (%+.4f %%, σ %.3f)\n"
                "cx %.3f (true %.3f, %+.3f px, σ %.3f)  cy %.3f (true %.3f, %+.3f px, σ %.3f)\n"
                "RMS %.4f px, floor %.4f px (ratio %.3f), %d corners; projection uncertainty centre %.3f, "
                "corner %.3f px\n", fx, t->fx, 100 * (fx / t->fx - 1), sfx, fy, 100 * (fy / t->fy - 1), sfy,
                cx, t->cx, cx - t->cx, scx, cy, t->cy, cy - t->cy, scy, rms, floor_px, rms / floor_px, n,
                field(cam, "projection_uncertainty.centre_px"), field(cam, "projection_uncertainty.corner_px"));
        CHECK_INT_EQ(json_integer_value(json_object_get(j, "views_used")), N_TARGETS);
        CHECK_INT_EQ(json_integer_value(json_object_get(j, "views_rejected")), 0);
        CHECK(json_is_true(json_object_get(cam, "confident")));
        CHECK_STR_EQ(json_string_value(json_object_get(cam, "refinement")),
                     imp_ceres_calib_available() ? "ceres" : "opencv");
        /* issue #8's limits */
        CHECK_NEAR(fx / t->fx, 1.0, F_REL_TOL);
        CHECK_NEAR(fy / t->fy, 1.0, F_REL_TOL);
        CHECK_NEAR(cx, t->cx, PP_TOL_PX);
        CHECK_NEAR(cy, t->cy, PP_TOL_PX);
        /* the reported σ are consistent with the errors */
        CHECK_LE(fabs(fx - t->fx), N_SIGMA * sfx);
        CHECK_LE(fabs(fy - t->fy), N_SIGMA * sfy);
        CHECK_LE(fabs(cx - t->cx), N_SIGMA * scx);
        CHECK_LE(fabs(cy - t->cy), N_SIGMA * scy);
        /* distortion: the coefficients within 3σ where they are separable (k1, p1, p2), and
         * the whole mapping (which k2, k3 trade against each other) within MAP_TOL_PX */
        json_t *dist = json_object_get(cam, "dist"), *sdist = json_object_get(json_object_get(cam, "std"), "dist");
        const double td[5] = { t->k1, t->k2, t->p1, t->p2, t->k3 };
        static const char *const dn[5] = { "k1", "k2", "p1", "p2", "k3" };
        for (int k = 0; k < 5; k++) {
                double v = json_number_value(json_array_get(dist, (size_t) k)),
                       s = json_number_value(json_array_get(sdist, (size_t) k));
                fprintf(stderr, "%s %.6f (true %.6f, σ %.6f)\n", dn[k], v, td[k], s);
                if (k != 1 && k != 4)
                        CHECK_LE(fabs(v - td[k]), N_SIGMA * s);
        }
        double map = map_error(t, e, box);
        fprintf(stderr, "true vs fitted pixel of a ray, corners' box x %.0f..%.0f y %.0f..%.0f: worst %.3f px\n",
                box[0], box[1], box[2], box[3], map);
        CHECK_LE(map, MAP_TOL_PX);
        /* at the noise floor */
        CHECK_LE(floor_px, FLOOR_MAX_PX);
        CHECK_LE(rms, RMS_FLOOR_MAX * floor_px);
        CHECK_GE(rms, RMS_FLOOR_MIN * floor_px);
        /* rig.json carries the fit */
        CHECK_NEAR(e->fx, fx, 1e-6 * fx);
        CHECK_NEAR(e->cy, cy, 1e-6);
        imp_rig_free(&est);
        imp_rig_free(&truth);
        json_decref(j);
        int failed = TEST_DONE();
        if (!failed) {   /* 20 sets of 2.5 MB: kept only when something failed */
                snprintf(cmd, sizeof cmd, "rm -rf %s", tmp);
                run(cmd);
        }
        return failed;
}
