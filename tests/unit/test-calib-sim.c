/* Calibration of the simulated demo rig from simulated targets (issue #8): renders the
 * chessboard scenes config/scenes/target-{0..7}.cfg with config/plans/target.cfg, runs
 * `impasto calibrate procam --sets … --reference target-0 --out rig.json`, and compares
 * the result with the simulator's truth (truth/rig.json of a set). Tolerances are stated
 * below with the figures measured when they were set (docs/calibration.md, "Simulated rig").
 * About 3 minutes on 2 cores (rendering is most of it): labelled slow. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "json-util.h"
#include "rig.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define N_TARGETS 8

/* Measured when these were set (noise on, 8 targets, OpenCV 4.6): camera fx, fy −0.035 %,
 * cx +0.52 px, cy −0.32 px, RMS 0.208 px (the flat reference view alone: 0.036 px);
 * projector fx, fy −0.12 %, cx, cy +12.7 px (traded against the stereo rotation, 0.25°),
 * RMS 0.156 px; stereo |Δt| 0.60 mm; camera centre on the canvas 0.55 mm off.
 * Issue #8 asks for 0.1 % on f (met) and 0.5 px on the principal point (NOT met: the limits
 * below record what the method gives today, with about 2× room, so that a regression shows;
 * tighten them when the tilted views' 0.2 px residual is understood — docs/calibration.md). */
#define CAM_F_REL_TOL      1e-3        /* issue #8: 0.1 % */
#define CAM_PP_TOL_PX      2.0
#define CAM_RMS_MAX_PX     0.3
#define PROJ_F_REL_TOL     3e-3
#define PROJ_PP_TOL_PX     25.0
#define PROJ_RMS_MAX_PX    0.3
#define STEREO_T_TOL_MM    1.5         /* |t_est − t_true|, baseline ≈ 114 mm */
#define STEREO_R_TOL_DEG   0.5
#define CAM_CENTRE_TOL_MM  1.5         /* camera centre on the canvas, from the reference view */
#define CAM_AXIS_TOL_DEG   0.3

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static double num(json_t *j, const char *a, const char *b) {
        json_t *o = json_object_get(json_object_get(j, a), b);
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

static void check_intrinsics(const char *who, const struct imp_pinhole *e, const struct imp_pinhole *t,
                             double f_rel, double pp_px) {
        fprintf(stderr, "%s: fx %.3f (true %.3f, %+.4f %%), fy %.3f (%+.4f %%), cx %.3f (true %.3f), "
                "cy %.3f (true %.3f)\n", who, e->fx, t->fx, 100 * (e->fx / t->fx - 1), e->fy,
                100 * (e->fy / t->fy - 1), e->cx, t->cx, e->cy, t->cy);
        CHECK_NEAR(e->fx / t->fx, 1.0, f_rel);
        CHECK_NEAR(e->fy / t->fy, 1.0, f_rel);
        CHECK_NEAR(e->cx, t->cx, pp_px);
        CHECK_NEAR(e->cy, t->cy, pp_px);
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char cmd[4096], sets[2048] = "", path[1024];
        for (int i = 0; i < N_TARGETS; i++) {
                snprintf(cmd, sizeof cmd, "%s sim render --scene %s/config/scenes/target-%d.cfg --plan "
                         "%s/config/plans/target.cfg --out %s/t%d --threads 2 --quiet", IMPASTO,
                         IMPASTO_SOURCE_DIR, i, IMPASTO_SOURCE_DIR, tmp, i);
                CHECK_INT_EQ(run(cmd), 0);
                if (i > 0)   /* target-0 (flat) goes in as the reference */
                        snprintf(sets + strlen(sets), sizeof sets - strlen(sets), " %s/t%d", tmp, i);
        }
        snprintf(cmd, sizeof cmd, "%s calibrate procam --sets%s --reference %s/t0 --board-origin 9,9.5 "
                 "--board 15x8 --square 3 --json --out %s/rig.json > %s/calib.json", IMPASTO, sets, tmp,
                 tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);

        struct imp_error err = { 0 };
        snprintf(path, sizeof path, "%s/calib.json", tmp);
        json_error_t jerr;
        json_t *j = json_load_file(path, 0, &jerr);
        CHECK(j != NULL);
        struct imp_rig est = { 0 }, truth = { 0 };
        snprintf(path, sizeof path, "%s/rig.json", tmp);
        CHECK_OK(imp_rig_load(path, &est, &err));
        snprintf(path, sizeof path, "%s/t0/truth/rig.json", tmp);
        CHECK_OK(imp_rig_load(path, &truth, &err));
        if (!j || est.n_cameras < 1 || truth.n_cameras < 1)
                return TEST_DONE();

        CHECK_INT_EQ(json_integer_value(json_object_get(j, "captures_used")), N_TARGETS);
        double cam_rms = num(j, "camera", "rms_px"), proj_rms = num(j, "projector", "rms_px");
        fprintf(stderr, "RMS camera %.4f px, projector %.4f px, stereo %.4f px\n", cam_rms, proj_rms,
                num(j, "stereo", "rms_px"));
        CHECK_LE(cam_rms, CAM_RMS_MAX_PX);
        CHECK_LE(proj_rms, PROJ_RMS_MAX_PX);

        const struct imp_pinhole *ec = &est.cameras[0].model, *tc = &truth.cameras[0].model;
        const struct imp_pinhole *ep = &est.projector.model, *tp = &truth.projector.model;
        check_intrinsics("camera", ec, tc, CAM_F_REL_TOL, CAM_PP_TOL_PX);
        check_intrinsics("projector", ep, tp, PROJ_F_REL_TOL, PROJ_PP_TOL_PX);
        /* The full rig keeps what calibration does not measure (names, sensor, dome). */
        CHECK_STR_EQ(est.cameras[0].name, truth.cameras[0].name);
        CHECK_INT_EQ(est.n_lights, truth.n_lights);

        double Re[9], te[3], Rt[9], tt[3];
        relative(ec, ep, Re, te);
        relative(tc, tp, Rt, tt);
        double dt = sqrt((te[0] - tt[0]) * (te[0] - tt[0]) + (te[1] - tt[1]) * (te[1] - tt[1]) +
                         (te[2] - tt[2]) * (te[2] - tt[2]));
        double dR = rot_angle_deg(Re, Rt);
        fprintf(stderr, "stereo: t (%.3f %.3f %.3f) true (%.3f %.3f %.3f) mm, |Δt| %.4f mm, ΔR %.5f°\n",
                te[0], te[1], te[2], tt[0], tt[1], tt[2], dt, dR);
        CHECK_LE(dt, STEREO_T_TOL_MM);
        CHECK_LE(dR, STEREO_R_TOL_DEG);

        double Ce[3], Ct[3];
        imp_pinhole_centre(ec, Ce);
        imp_pinhole_centre(tc, Ct);
        double dC = sqrt((Ce[0] - Ct[0]) * (Ce[0] - Ct[0]) + (Ce[1] - Ct[1]) * (Ce[1] - Ct[1]) +
                         (Ce[2] - Ct[2]) * (Ce[2] - Ct[2]));
        double dRc = rot_angle_deg(ec->R, tc->R);
        fprintf(stderr, "camera on the canvas: centre (%.3f %.3f %.3f) true (%.3f %.3f %.3f) mm, "
                "|Δ| %.4f mm, ΔR %.5f°\n", Ce[0], Ce[1], Ce[2], Ct[0], Ct[1], Ct[2], dC, dRc);
        CHECK_LE(dC, CAM_CENTRE_TOL_MM);
        CHECK_LE(dRc, CAM_AXIS_TOL_DEG);

        json_decref(j);
        imp_rig_free(&est);
        imp_rig_free(&truth);
        return TEST_DONE();
}
