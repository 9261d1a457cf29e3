/* Calibration of the simulated demo rig from simulated targets: renders the
 * chessboard scenes config/scenes/target-{0..13}.cfg with config/plans/target.cfg, runs
 * `impasto calibrate procam --sets … --reference target-0 --out rig.json`, and compares
 * the result with the simulator's truth (truth/rig.json of a set). Tolerances are stated
 * below with the figures measured when they were set (docs/calibration.md, "Simulated rig").
 * About 6 minutes on 2 cores (rendering is most of it): labelled slow. */
#include <glob.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "calib.h"
#include "cv-calib.h"
#include "cv-graycode.h"
#include "json-util.h"
#include "rig.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"

/* Measured when these were set (noise on, 14 targets, bilinear BRDF lookup in the renderer,
 * k3 held at 0, OpenCV 4.6): camera fx, fy +0.021 %, cx −1.04 px (σ 5.8), cy +0.72 px (σ 3.3),
 * RMS 0.070 px; projector fx, fy −0.026 %, −0.022 %, cx +5.6 px (σ 8.4), cy +7.7 px (σ 4.7),
 * RMS 0.093 px; stereo |Δt| 0.30 mm, ΔR 0.14°; camera centre on the canvas 0.054 mm, axis
 * 0.020°; found − true corners ≤ 0.096 px RMS per target (worst corner 0.19 px).
 * The Ceres refinement (default when built with it) lands on the same optimum — no outlier
 * in rendered corners: camera fx, fy +0.021 %, cx −1.02, cy +0.76 px, projector −0.025 %,
 * −0.021 %, cx +5.7, cy +7.6 px, stereo |Δt| 0.30 mm — and its mrcal-style projection
 * uncertainty is 0.003 px (camera) / 0.014 px (projector) at the image centre.
 * Issue #8 asks for 0.1 % on f (met, both devices) and 0.5 px on the principal point: NOT
 * met and not determinable here — a 13° field of view leaves σ(cx, cy) at 3–8 px, so the
 * limits below record what the method gives with about 2× room (docs/calibration.md, which
 * also shows that other target poses cannot fix it). */
#define N_TARGETS 14
#define CAM_F_REL_TOL      1e-3        /* issue #8: 0.1 % */
#define CAM_PP_TOL_PX      2.5
#define CAM_RMS_MAX_PX     0.12
#define PROJ_F_REL_TOL     1e-3        /* issue #8: 0.1 % */
#define PROJ_PP_TOL_PX     15.0
#define PROJ_RMS_MAX_PX    0.15
#define STEREO_T_TOL_MM    0.75        /* |t_est − t_true|, baseline ≈ 114 mm */
#define STEREO_R_TOL_DEG   0.3
#define CAM_CENTRE_TOL_MM  0.2         /* camera centre on the canvas, from the reference view */
#define CAM_AXIS_TOL_DEG   0.1
#define CORNER_RMS_MAX_PX  0.15        /* found vs true corners, each target */
/* The joint refinement (the default since 2026-11-22; --no-joint is the per-device path with
 * stereoCalibrate's pose, measured as above). Measured on the same 14 targets: camera fx, fy
 * +0.024 %, cx −0.72 px (σ 5.6), cy +1.02 px (σ 3.1), RMS 0.071 px; projector fx, fy +0.0001 %,
 * +0.002 %, cx +1.9 px (σ 7.6), cy +5.4 px (σ 4.2), RMS 0.094 px; stereo |Δt| 0.13 mm (σ of t
 * 0.07, 0.03, 0.38 mm), ΔR 0.075° (σ 0.06–0.12°), RMS both devices 0.083 px; camera centre
 * on the canvas 0.049 mm, axis 0.017°. Limits: about 2× the measured error, as above. The
 * improvements over --no-joint (projector f −0.025 % → 0.000 %, |Δt| 0.30 → 0.13 mm, ΔR
 * 0.136° → 0.075°) are within 1–2σ, so they are printed, not asserted. */
#define JOINT_CAM_PP_TOL_PX     CAM_PP_TOL_PX
#define JOINT_PROJ_PP_TOL_PX    11.0
#define JOINT_STEREO_T_TOL_MM   0.3
#define JOINT_STEREO_R_TOL_DEG  0.15
#define JOINT_STEREO_RMS_MAX_PX 0.12

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

/* j.a.b (j.a when b is NULL) as a number, NAN when missing. */
static double num(json_t *j, const char *a, const char *b) {
        json_t *o = json_object_get(j, a);
        if (b)
                o = json_object_get(o, b);
        return o ? json_number_value(o) : NAN;
}

/* Angle between two rotations (deg). */
static double rot_angle_deg(const double *A, const double *B) {
        double tr = 0;   /* trace(A Bᵀ) */
        for (int i = 0; i < 3; i++)
                for (int k = 0; k < 3; k++)
                        tr += A[3 * i + k] * B[3 * i + k];
        double c = IMP_CLAMP(0.5 * (tr - 1), -1.0, 1.0);
        return acos(c) * 180 / M_PI;
}

/* Camera → projector: R = Rp Rcᵀ, t = tp − R tc. */
static void relative(const struct imp_pinhole *c, const struct imp_pinhole *p, double R[9], double t[3]) {
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        R[3 * i + j] = 0;
                        for (int q = 0; q < 3; q++)
                                R[3 * i + j] += p->R[3 * i + q] * c->R[3 * j + q];
                }
        for (int i = 0; i < 3; i++)
                t[i] = p->t[i] - (R[3 * i] * c->t[0] + R[3 * i + 1] * c->t[1] + R[3 * i + 2] * c->t[2]);
}

/* Corner bias: chessboard corners found on set `dir`'s white frame against the
 * true corners — the board of `cfg` (its plane, origin, turn; sim/painting.c's
 * checker frame) projected through the set's truth/rig.json. Each found corner is matched
 * to the nearest true one. Prints mean and RMS of found − true; returns the RMS (px), or
 * NAN when the board or the scene's numbers were not found. */
static double corner_bias(const char *cfg, const char *dir) {
        char text[16384], path[1100];
        FILE *f = fopen(cfg, "r");
        if (!f)
                return NAN;
        size_t n = fread(text, 1, sizeof text - 1, f);
        fclose(f);
        text[n] = 0;
        double a, b, c, ox, oy, ang, sq;
        int cols, rows;
        const char *p1 = strstr(text, "slope = ["), *p2 = strstr(text, "square_mm = "),
                   *p3 = strstr(text, "origin_mm = [");
        if (!p1 || !p2 || !p3 || sscanf(p1, "slope = [%lf, %lf]; offset_mm = %lf", &a, &b, &c) != 3 ||
            sscanf(p2, "square_mm = %lf; corners = [%d, %d]", &sq, &cols, &rows) != 3 ||
            sscanf(p3, "origin_mm = [%lf, %lf]; angle_deg = %lf", &ox, &oy, &ang) != 3 || cols * rows > 1024)
                return NAN;
        struct imp_error err = { 0 };
        struct imp_rig truth = { 0 };
        if (snprintf(path, sizeof path, "%s/truth/rig.json", dir) >= (int) sizeof path ||
            imp_rig_load(path, &truth, &err) < 0)
                return NAN;
        /* checker_frame(): e1 along x lifted onto the plane, n out of it, e2 = n × e1. */
        double l1 = sqrt(1 + a * a), ln = sqrt(1 + a * a + b * b);
        double nn[3] = { -a / ln, -b / ln, 1 / ln }, e1[3] = { 1 / l1, 0, a / l1 }, e2[3] = {
                nn[1] * e1[2] - nn[2] * e1[1], nn[2] * e1[0] - nn[0] * e1[2], nn[0] * e1[1] - nn[1] * e1[0] };
        double P0[3] = { ox, oy, a * ox + b * oy + c }, cs = cos(ang * M_PI / 180), sn = sin(ang * M_PI / 180);
        static double tru[2 * 1024], det[2 * 1024];
        for (int k = 0; k < cols * rows; k++) {
                double U = sq * (k % cols), V = sq * (k / cols), u = cs * U - sn * V, v = sn * U + cs * V, X[3];
                for (int q = 0; q < 3; q++)
                        X[q] = P0[q] + u * e1[q] + v * e2[q];
                imp_pinhole_project(&truth.cameras[0].model, X, tru + 2 * k);
        }
        int pw = truth.projector.model.width, ph = truth.projector.model.height;
        imp_rig_free(&truth);
        struct imp_calib_sets *sets = NULL;
        struct imp_image *white = NULL;
        const char *dirs[1] = { dir };
        if (imp_calib_sets_open(dirs, 1, pw, ph, &sets, &err) < 0)
                return NAN;
        int r = imp_calib_sets_load(sets, 0, imp_cv_graycode_count(pw, ph), &white, &err);
        imp_calib_sets_free(sets);
        if (r < 0)
                return NAN;
        r = imp_cv_calib_find_corners(white, cols, rows, det, &err);
        imp_image_free(white);
        if (r < 0)
                return NAN;
        double sx = 0, sy = 0, ss = 0, worst = 0;
        int m = cols * rows;
        for (int k = 0; k < m; k++) {
                int best = 0;
                double bd = INFINITY;
                for (int t = 0; t < m; t++) {
                        double d = hypot(det[2 * k] - tru[2 * t], det[2 * k + 1] - tru[2 * t + 1]);
                        if (d < bd) {
                                bd = d;
                                best = t;
                        }
                }
                sx += det[2 * k] - tru[2 * best];
                sy += det[2 * k + 1] - tru[2 * best + 1];
                ss += bd * bd;
                worst = fmax(worst, bd);
        }
        double rms = sqrt(ss / m), mx = sx / m, my = sy / m;
        fprintf(stderr, "corners %s: found − true: mean (%+.4f, %+.4f) px, RMS %.4f px (%.4f about the "
                "mean), worst %.4f px\n", dir, mx, my, rms, sqrt(fmax(ss / m - mx * mx - my * my, 0)), worst);
        return rms;
}

/* One calibration's figures against the truth. */
struct figs {
        double f_rel[2][2];             /* [camera, projector][fx, fy]: estimate / truth − 1 */
        double pp[2][2];                /* [device][cx, cy]: estimate − truth, px */
        double rms[3];                  /* camera, projector, stereo (px) */
        double dt_mm, dR_deg;           /* camera → projector pose */
        double dC_mm, dRc_deg;          /* camera on the canvas */
};

/* Loads rig_name (and json_name, may be NULL) from tmp and compares with the truth; prints a
 * line per quantity labelled who. Returns 0, or -1 when a file did not load. */
static int measure(const char *tmp, const char *truth_dir, const char *rig_name, const char *json_name,
                   const char *who, struct figs *F) {
        char path[1024];
        struct imp_error err = { 0 };
        struct imp_rig est = { 0 }, truth = { 0 };
        int r;
        snprintf(path, sizeof path, "%s/%s", tmp, rig_name);
        CHECK_OK(r = imp_rig_load(path, &est, &err));
        if (r < 0)
                return -1;
        snprintf(path, sizeof path, "%s/truth/rig.json", truth_dir);
        CHECK_OK(r = imp_rig_load(path, &truth, &err));
        if (r < 0 || est.n_cameras < 1 || truth.n_cameras < 1) {
                imp_rig_free(&est);
                return -1;
        }
        const struct imp_pinhole *m[2][2] = { { &est.cameras[0].model, &truth.cameras[0].model },
                                              { &est.projector.model, &truth.projector.model } };
        for (int d = 0; d < 2; d++) {
                const struct imp_pinhole *e = m[d][0], *t = m[d][1];
                F->f_rel[d][0] = e->fx / t->fx - 1;
                F->f_rel[d][1] = e->fy / t->fy - 1;
                F->pp[d][0] = e->cx - t->cx;
                F->pp[d][1] = e->cy - t->cy;
                fprintf(stderr, "%s %s: fx %.3f (true %.3f, %+.4f %%), fy %.3f (%+.4f %%), cx %.3f (%+.3f), "
                        "cy %.3f (%+.3f)\n", who, d ? "projector" : "camera", e->fx, t->fx, 100 * F->f_rel[d][0],
                        e->fy, 100 * F->f_rel[d][1], e->cx, F->pp[d][0], e->cy, F->pp[d][1]);
        }
        double Re[9], te[3], Rt[9], tt[3];
        relative(m[0][0], m[1][0], Re, te);
        relative(m[0][1], m[1][1], Rt, tt);
        F->dt_mm = sqrt((te[0] - tt[0]) * (te[0] - tt[0]) + (te[1] - tt[1]) * (te[1] - tt[1]) +
                        (te[2] - tt[2]) * (te[2] - tt[2]));
        F->dR_deg = rot_angle_deg(Re, Rt);
        double Ce[3], Ct[3];
        imp_pinhole_centre(m[0][0], Ce);
        imp_pinhole_centre(m[0][1], Ct);
        F->dC_mm = sqrt((Ce[0] - Ct[0]) * (Ce[0] - Ct[0]) + (Ce[1] - Ct[1]) * (Ce[1] - Ct[1]) +
                        (Ce[2] - Ct[2]) * (Ce[2] - Ct[2]));
        F->dRc_deg = rot_angle_deg(m[0][0]->R, m[0][1]->R);
        fprintf(stderr, "%s stereo: t (%.3f %.3f %.3f) true (%.3f %.3f %.3f) mm, |Δt| %.4f mm, ΔR %.5f°; "
                "camera on the canvas |Δ| %.4f mm, ΔR %.5f°\n", who, te[0], te[1], te[2], tt[0], tt[1], tt[2],
                F->dt_mm, F->dR_deg, F->dC_mm, F->dRc_deg);
        F->rms[0] = F->rms[1] = F->rms[2] = NAN;
        if (json_name) {
                json_error_t jerr;
                snprintf(path, sizeof path, "%s/%s", tmp, json_name);
                json_t *j = json_load_file(path, 0, &jerr);
                CHECK(j != NULL);
                F->rms[0] = num(j, "camera", "rms_px");
                F->rms[1] = num(j, "projector", "rms_px");
                F->rms[2] = num(j, "stereo", "rms_px");
                fprintf(stderr, "%s RMS camera %.4f px, projector %.4f px, stereo %.4f px\n", who, F->rms[0],
                        F->rms[1], F->rms[2]);
                json_decref(j);
        }
        imp_rig_free(&est);
        imp_rig_free(&truth);
        return 0;
}

static void check_figs(const struct figs *F, double cam_pp_px, double proj_pp_px, double dt_mm, double dR_deg) {
        for (int k = 0; k < 2; k++) {
                CHECK_NEAR(F->f_rel[0][k], 0.0, CAM_F_REL_TOL);
                CHECK_NEAR(F->f_rel[1][k], 0.0, PROJ_F_REL_TOL);
                CHECK_NEAR(F->pp[0][k], 0.0, cam_pp_px);
                CHECK_NEAR(F->pp[1][k], 0.0, proj_pp_px);
        }
        CHECK_LE(F->dt_mm, dt_mm);
        CHECK_LE(F->dR_deg, dR_deg);
        CHECK_LE(F->dC_mm, CAM_CENTRE_TOL_MM);
        CHECK_LE(F->dRc_deg, CAM_AXIS_TOL_DEG);
}

/* σ of the principal point as the calibration reports it (std.cx, std.cy). */
static void print_std(json_t *j, const char *who) {
        json_t *s = json_object_get(json_object_get(j, who), "std");
        fprintf(stderr, "%s: 1σ fx %.3f fy %.3f cx %.3f cy %.3f px; refinement %s, %lld outliers; projection "
                "uncertainty centre %.3f corner %.3f px\n", who, num(s, "fx", NULL), num(s, "fy", NULL),
                num(s, "cx", NULL), num(s, "cy", NULL),
                json_string_value(json_object_get(json_object_get(j, who), "refinement")),
                (long long) json_integer_value(json_object_get(json_object_get(j, who), "outliers")),
                num(json_object_get(j, who), "projection_uncertainty", "centre_px"),
                num(json_object_get(j, who), "projection_uncertainty", "corner_px"));
}

/* Set i: from $IMPASTO_TARGET_CACHE (scripts/demo's out/cache/targets: DIR/target-i-KEY with
 * DIR/target-i-KEY.complete) when given and present, else rendered into tmp/t<i>. */
static int target_set(const char *tmp, int i, char *dir, size_t size) {
        const char *cache = getenv("IMPASTO_TARGET_CACHE");
        char pat[1024], cmd[4096];
        glob_t g;
        snprintf(pat, sizeof pat, "%s/target-%d-*.complete", cache ? cache : "", i);
        if (cache && glob(pat, 0, NULL, &g) == 0) {
                size_t n = strlen(g.gl_pathv[0]) - strlen(".complete");
                snprintf(dir, size, "%.*s", (int) n, g.gl_pathv[0]);
                globfree(&g);
                fprintf(stderr, "target %d: cached %s\n", i, dir);
                return 0;
        }
        snprintf(dir, size, "%s/t%d", tmp, i);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s/config/scenes/target-%d.cfg --plan "
                 "%s/config/plans/target.cfg --out %s --threads 2 --quiet", IMPASTO, IMPASTO_SOURCE_DIR, i,
                 IMPASTO_SOURCE_DIR, dir);
        return run(cmd);
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char cmd[16384], sets[4096] = "", path[2048], t0[1024] = "";
        for (int i = 0; i < N_TARGETS; i++) {
                char cfg[1024], dir[1024];
                CHECK_INT_EQ(target_set(tmp, i, dir, sizeof dir), 0);
                snprintf(cfg, sizeof cfg, "%s/config/scenes/target-%d.cfg", IMPASTO_SOURCE_DIR, i);
                double rms = corner_bias(cfg, dir);
                CHECK_LE(rms, CORNER_RMS_MAX_PX);
                if (i > 0)   /* target-0 (flat) goes in as the reference */
                        snprintf(sets + strlen(sets), sizeof sets - strlen(sets), " %s", dir);
                else
                        snprintf(t0, sizeof t0, "%s", dir);
        }
        /* OpenCV alone (the method before the Ceres refinement), each device refined alone with
         * stereoCalibrate's pose (--no-joint), then the default (joint refinement). */
        static const char *const variant[3][3] = { { "--opencv-only", "cv", "opencv only" },
                                                   { "--no-joint", "nj", "per-device + stereoCalibrate" },
                                                   { "", "joint", "joint" } };
        struct figs F[3];
        for (int v = 0; v < 3; v++) {
                snprintf(cmd, sizeof cmd, "%s calibrate procam --sets%s %s --reference %s --board-origin 9,9.5 "
                         "--board 15x8 --square 3 --json %s --out %s/rig-%s.json > %s/calib-%s.json", IMPASTO,
                         sets, t0, t0, variant[v][0], tmp, variant[v][1], tmp, variant[v][1]);
                CHECK_INT_EQ(run(cmd), 0);
                char rig[64], js[64];
                snprintf(rig, sizeof rig, "rig-%s.json", variant[v][1]);
                snprintf(js, sizeof js, "calib-%s.json", variant[v][1]);
                if (measure(tmp, t0, rig, js, variant[v][2], &F[v]) < 0)
                        return TEST_DONE();
        }
        /* The earlier methods still meet what they met (the joint fit starts from them). */
        check_figs(&F[0], CAM_PP_TOL_PX, PROJ_PP_TOL_PX, STEREO_T_TOL_MM, STEREO_R_TOL_DEG);
        check_figs(&F[1], CAM_PP_TOL_PX, PROJ_PP_TOL_PX, STEREO_T_TOL_MM, STEREO_R_TOL_DEG);

        snprintf(path, sizeof path, "%s/calib-joint.json", tmp);
        json_error_t jerr;
        json_t *j = json_load_file(path, 0, &jerr);
        CHECK(j != NULL);
        if (!j)
                return TEST_DONE();
        CHECK_INT_EQ(json_integer_value(json_object_get(j, "captures_used")), N_TARGETS);
        json_t *jt = json_object_get(j, "joint");
        CHECK(json_is_true(json_object_get(jt, "used")));
        CHECK(json_is_true(json_object_get(jt, "converged")));
        CHECK_STR_EQ(json_string_value(json_object_get(json_object_get(j, "camera"), "refinement")), "joint");
        CHECK_LE(F[2].rms[0], CAM_RMS_MAX_PX);
        CHECK_LE(F[2].rms[1], PROJ_RMS_MAX_PX);
        CHECK_LE(F[2].rms[2], JOINT_STEREO_RMS_MAX_PX);
        print_std(j, "camera");
        print_std(j, "projector");
        json_t *ss = json_object_get(json_object_get(j, "stereo"), "std");
        json_t *rs = json_object_get(ss, "rotation_deg"), *ts = json_object_get(ss, "translation");
        fprintf(stderr, "joint stereo 1σ: rotation (%.4f %.4f %.4f)°, translation (%.4f %.4f %.4f) mm\n",
                json_number_value(json_array_get(rs, 0)), json_number_value(json_array_get(rs, 1)),
                json_number_value(json_array_get(rs, 2)), json_number_value(json_array_get(ts, 0)),
                json_number_value(json_array_get(ts, 1)), json_number_value(json_array_get(ts, 2)));
        CHECK_INT_EQ(json_array_size(ts), 3);
        /* Rendered corners have no gross errors: the refinement may drop a stray corner, not a
         * view's worth. */
        CHECK_LE(num(j, "camera", "outliers"), 20);
        CHECK_LE(num(j, "projector", "outliers"), 20);
        check_figs(&F[2], JOINT_CAM_PP_TOL_PX, JOINT_PROJ_PP_TOL_PX, JOINT_STEREO_T_TOL_MM, JOINT_STEREO_R_TOL_DEG);

        /* The full rig keeps what calibration does not measure (names, sensor, dome). */
        struct imp_error err = { 0 };
        struct imp_rig est = { 0 }, truth = { 0 };
        snprintf(path, sizeof path, "%s/rig-joint.json", tmp);
        CHECK_OK(imp_rig_load(path, &est, &err));
        snprintf(path, sizeof path, "%s/truth/rig.json", t0);
        CHECK_OK(imp_rig_load(path, &truth, &err));
        if (est.n_cameras > 0 && truth.n_cameras > 0) {
                CHECK_STR_EQ(est.cameras[0].name, truth.cameras[0].name);
                CHECK_INT_EQ(est.n_lights, truth.n_lights);
        }
        json_decref(j);
        imp_rig_free(&est);
        imp_rig_free(&truth);
        return TEST_DONE();
}
