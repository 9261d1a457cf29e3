/* Ceres bundle refinement of a calibration (pipeline/calib/cv/ceres-calib.cpp) on
 * synthetic corners: known camera, 12 tilted board poses, Gaussian corner noise. Checks
 * that on clean data it agrees with OpenCV's calibrateCamera (the start) within a fraction
 * of σ, with a similar σ; that with a few corners moved 20 px the robust loss plus outlier
 * rejection keeps fx within 0.1 % and finds exactly those corners, where plain least squares
 * (OpenCV, or Ceres without loss) does not; and that the mrcal-style projection uncertainty
 * at the image centre is below the intrinsics-only bound. Skipped without Ceres. */
#include <math.h>
#include <stdlib.h>
#include "calib.h"
#include "ceres-calib.h"
#include "ceres-procam.h"
#include "cv-calib.h"
#include "procam-synth.h"
#include "test.h"

#define W 1280
#define H 960
#define COLS 11
#define ROWS 8
#define SQ_MM 20.0
#define N_VIEWS 12
#define NOISE_PX 0.1
#define N_OUTLIERS 8
#define OUTLIER_PX 20.0
#define F_REL_TOL 1e-3                  /* issue #8: 0.1 % */

/* fx fy cx cy k1 k2 p1 p2 k3 */
static const double TRUE_K[IMP_CALIB_N_INTR] = { 2400, 2396, 652.5, 471.2, -0.12, 0.09, 4e-4, -3e-4, 0 };

static double obj[N_VIEWS][3 * COLS * ROWS], img[N_VIEWS][2 * COLS * ROWS];

static unsigned short rng48[3] = { 0x1234, 0xabcd, 0x42 };
static double gaussian(void) {          /* Box–Muller on erand48 */
        double u = erand48(rng48), v = erand48(rng48);
        return sqrt(-2 * log(1 - u)) * cos(2 * M_PI * v);
}

/* X_cam = R(r) X + t, R from the Rodrigues vector r; OpenCV's distortion. */
static void project(const double *k, const double r[3], const double t[3], const double X[3], double q[2]) {
        double th = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]), a[3] = { r[0] / th, r[1] / th, r[2] / th };
        double c = cos(th), s = sin(th), d = a[0] * X[0] + a[1] * X[1] + a[2] * X[2], p[3];
        double ax[3] = { a[1] * X[2] - a[2] * X[1], a[2] * X[0] - a[0] * X[2], a[0] * X[1] - a[1] * X[0] };
        for (int i = 0; i < 3; i++)
                p[i] = X[i] * c + ax[i] * s + a[i] * d * (1 - c) + t[i];
        double x = p[0] / p[2], y = p[1] / p[2], r2 = x * x + y * y;
        double rad = 1 + r2 * (k[4] + r2 * (k[5] + r2 * k[8]));
        q[0] = k[0] * (x * rad + 2 * k[6] * x * y + k[7] * (r2 + 2 * x * x)) + k[2];
        q[1] = k[1] * (y * rad + k[6] * (r2 + 2 * y * y) + 2 * k[7] * x * y) + k[3];
}

static void make_views(struct imp_calib_view *v) {
        for (int i = 0; i < N_VIEWS; i++) {
                double tilt = (25 + 15 * (i % 3)) * M_PI / 180, az = 2 * M_PI * i / N_VIEWS;
                double r[3] = { tilt * cos(az), tilt * sin(az), 0.1 * (i % 2 ? 1 : -1) };
                double t[3] = { -0.5 * COLS * SQ_MM + 25 * cos(3 * az), -0.5 * ROWS * SQ_MM + 20 * sin(2 * az),
                                620 + 40 * (i % 4) };
                for (int p = 0; p < COLS * ROWS; p++) {
                        double *X = &obj[i][3 * p];
                        X[0] = SQ_MM * (p % COLS);
                        X[1] = SQ_MM * (p / COLS);
                        X[2] = 0;
                        project(TRUE_K, r, t, X, &img[i][2 * p]);
                        img[i][2 * p] += NOISE_PX * gaussian();
                        img[i][2 * p + 1] += NOISE_PX * gaussian();
                }
                v[i] = (struct imp_calib_view) { COLS * ROWS, obj[i], img[i] };
        }
}

static int opencv_fit(const struct imp_calib_view *v, struct imp_calib_intrinsics *in, double *rv, double *tv) {
        struct imp_error err = { 0 };
        int r = imp_cv_calib_intrinsics_fit(v, N_VIEWS, W, H, IMP_CALIB_FIT_FIX_K3, in, rv, tv, &err);
        if (r < 0)
                fprintf(stderr, "opencv: %s\n", err.msg);
        return r;
}

static void show(const char *who, const struct imp_calib_intrinsics *in) {
        fprintf(stderr, "%-18s fx %.3f ± %.3f (%+.4f %%) fy %.3f cx %.3f ± %.3f (true %.1f) cy %.3f ± %.3f "
                "(true %.1f) RMS %.4f px, projection 1σ centre %.3f corner %.3f px\n", who, in->fx, in->std[0],
                100 * (in->fx / TRUE_K[0] - 1), in->fy, in->cx, in->std[2], TRUE_K[2], in->cy, in->std[3],
                TRUE_K[3], in->rms_px, in->proj_unc_centre_px, in->proj_unc_corner_px);
}

/* ---- joint refinement of a projector–camera rig (ceres-procam.h) ---- */

#define JOINT_SEEDS 5
#define JOINT_VIEWS 12
#define JOINT_NOISE_CAM_PX 0.1
#define JOINT_NOISE_PROJ_PX 0.15        /* decoded projector corners are noisier */
#define JOINT_F_REL_TOL 4e-4
#define JOINT_PP_TOL_PX 5.0             /* ≈ 2.5σ: σ(cx) is 2.0 (camera), 2.6 px (projector) */
#define JOINT_T_TOL_MM 0.5
#define JOINT_R_TOL_DEG 0.15
#define JOINT_N_BAD 6
#define JOINT_BAD_PX 15.0
static const double EXT_R[3] = { 0.02, -0.25, 0.01 }, EXT_T[3] = { 160, -15, 20 };

/* Errors of the joint estimate over σ: fx fy cx cy of both devices, then the pose's Rodrigues
 * vector (deg) and translation (mm); z[] gets error / σ. */
static int joint_z(const struct ps_rig *g, const struct imp_calib_intrinsics *c, const struct imp_calib_intrinsics *p,
                   const struct imp_calib_stereo *st, double *z) {
        int n = 0;
        for (int i = 0; i < 4; i++) {
                z[n++] = ((&c->fx)[i] - PS_CAM[i]) / c->std[i];
                z[n++] = ((&p->fx)[i] - PS_PROJ[i]) / p->std[i];
        }
        double r[3];
        ps_log(st->R, r);
        for (int i = 0; i < 3; i++) {
                z[n++] = (r[i] - g->ext_r[i]) * 180 / M_PI / st->r_std_deg[i];
                z[n++] = (st->t[i] - g->ext_t[i]) / st->t_std[i];
        }
        return n;
}

static void joint_rig(void) {
        static struct ps_rig g;
        struct imp_error err = { 0 };
        struct imp_ceres_calib_opts co;
        imp_ceres_calib_opts_default(&co);
        double zs[JOINT_SEEDS * 14], zmax = 0, zss = 0;
        int nz = 0;
        for (int s = 0; s < JOINT_SEEDS; s++) {
                ps_tilted(&g, JOINT_VIEWS, EXT_R, EXT_T, JOINT_NOISE_CAM_PX, JOINT_NOISE_PROJ_PX, 1000 + 77 * s);
                struct imp_calib_intrinsics c0 = { 0 }, p0 = { 0 };
                struct imp_calib_stereo st0 = { 0 };
                double rv[3 * PS_MAXV], tv[3 * PS_MAXV];
                int r = ps_start(&g, &c0, &p0, &st0, rv, tv, &err);
                CHECK_MSG(r == 0, "seed %d: start: %s", s, err.msg);
                if (r < 0)
                        return;
                struct imp_calib_intrinsics c = c0, p = p0;
                struct imp_calib_stereo st = st0;
                struct imp_ceres_procam_report rep = { 0 };
                r = imp_ceres_procam_refine(g.vc, g.vp, g.n_views, &co, &c, &p, &st, rv, tv, &rep, &err);
                CHECK_MSG(r == 0, "seed %d: joint: %s", s, err.msg);
                if (r < 0)
                        return;
                double dt0, dR0, dt, dR;
                ps_pose_error(&g, &st0, &dt0, &dR0);
                ps_pose_error(&g, &st, &dt, &dR);
                fprintf(stderr, "joint seed %d: camera fx %+.4f %% cx %+.3f ± %.3f (alone ± %.3f) cy %+.3f; projector fx "
                        "%+.4f %% cx %+.3f ± %.3f (alone ± %.3f) cy %+.3f; pose |Δt| %.3f mm ± (%.3f %.3f %.3f), "
                        "ΔR %.4f° ± (%.4f %.4f %.4f) (stereoCalibrate %.3f mm, %.4f°); RMS %.4f / %.4f px, %d iterations\n", s,
                        100 * (c.fx / PS_CAM[0] - 1), c.cx - PS_CAM[2], c.std[2], c0.std[2], c.cy - PS_CAM[3],
                        100 * (p.fx / PS_PROJ[0] - 1), p.cx - PS_PROJ[2], p.std[2], p0.std[2], p.cy - PS_PROJ[3],
                        dt, st.t_std[0], st.t_std[1], st.t_std[2], dR, st.r_std_deg[0], st.r_std_deg[1],
                        st.r_std_deg[2], dt0, dR0, c.rms_px, p.rms_px, rep.iterations);
                CHECK(rep.converged);
                CHECK(!rep.rank_deficient);
                CHECK_INT_EQ(rep.n_outliers_cam + rep.n_outliers_proj, 0);
                CHECK(c.joint_refined && p.joint_refined && st.have_std);
                CHECK_INT_EQ(c.flags, 0);
                CHECK_INT_EQ(p.flags, 0);
                /* Tight recovery of the known rig. */
                CHECK_NEAR(c.fx / PS_CAM[0], 1.0, JOINT_F_REL_TOL);
                CHECK_NEAR(c.fy / PS_CAM[1], 1.0, JOINT_F_REL_TOL);
                CHECK_NEAR(p.fx / PS_PROJ[0], 1.0, JOINT_F_REL_TOL);
                CHECK_NEAR(p.fy / PS_PROJ[1], 1.0, JOINT_F_REL_TOL);
                for (int i = 2; i < 4; i++) {
                        CHECK_NEAR((&c.fx)[i], PS_CAM[i], JOINT_PP_TOL_PX);
                        CHECK_NEAR((&p.fx)[i], PS_PROJ[i], JOINT_PP_TOL_PX);
                }
                CHECK_LE(dt, JOINT_T_TOL_MM);
                CHECK_LE(dR, JOINT_R_TOL_DEG);
                CHECK_NEAR(c.rms_px, JOINT_NOISE_CAM_PX * sqrt(2), 0.02);
                CHECK_NEAR(p.rms_px, JOINT_NOISE_PROJ_PX * sqrt(2), 0.03);
                /* Shared board poses: the projector's corners pin the camera's too, and back. */
                CHECK_LE(c.std[2], c0.std[2]);
                CHECK_LE(p.std[2], p0.std[2]);
                CHECK(c.proj_unc_centre_px > 0 && p.proj_unc_centre_px > 0);
                CHECK(p.proj_unc_corner_px > p.proj_unc_centre_px);
                nz += joint_z(&g, &c, &p, &st, zs + nz);
        }
        for (int i = 0; i < nz; i++) {
                zmax = fmax(zmax, fabs(zs[i]));
                zss += zs[i] * zs[i];
        }
        /* Covariance consistent with the errors: none beyond 3σ over all seeds and parameters,
         * and the spread about what the convention predicts (σ² = Σ|r|² / (N − P) counts points,
         * not coordinates: σ is conservative by about √2, so RMS(z) ≈ 0.7). */
        fprintf(stderr, "joint: %d errors / σ: max %.2f, RMS %.3f\n", nz, zmax, sqrt(zss / nz));
        CHECK_LE(zmax, 3.0);
        CHECK_GE(sqrt(zss / nz), 0.4);
        CHECK_LE(sqrt(zss / nz), 1.0);

        /* Decoding errors: JOINT_N_BAD projector corners off by 15 px. stereoCalibrate takes them
         * in; the joint fit drops exactly those and its pose stays on the truth. */
        ps_tilted(&g, JOINT_VIEWS, EXT_R, EXT_T, JOINT_NOISE_CAM_PX, JOINT_NOISE_PROJ_PX, 1000);
        for (int k = 0; k < JOINT_N_BAD; k++) {
                double *q = &g.proj[(3 * k) % JOINT_VIEWS][2 * (7 * k % g.vp[(3 * k) % JOINT_VIEWS].n)];
                q[0] += JOINT_BAD_PX * (k % 2 ? 1 : -1);
                q[1] += 0.5 * JOINT_BAD_PX;
        }
        struct imp_calib_intrinsics c = { 0 }, p = { 0 };
        struct imp_calib_stereo st = { 0 }, st0;
        double rv[3 * PS_MAXV], tv[3 * PS_MAXV], dt0, dR0, dt, dR;
        CHECK_OK(ps_start(&g, &c, &p, &st, rv, tv, &err));
        st0 = st;
        struct imp_ceres_procam_report rep = { 0 };
        CHECK_OK(imp_ceres_procam_refine(g.vc, g.vp, g.n_views, &co, &c, &p, &st, rv, tv, &rep, &err));
        ps_pose_error(&g, &st0, &dt0, &dR0);
        ps_pose_error(&g, &st, &dt, &dR);
        fprintf(stderr, "joint, %d bad projector corners: dropped %d + %d; pose |Δt| %.3f mm, ΔR %.4f° "
                "(stereoCalibrate: %.3f mm, %.4f°); projector fx %+.4f %%\n", JOINT_N_BAD, rep.n_outliers_cam,
                rep.n_outliers_proj, dt, dR, dt0, dR0, 100 * (p.fx / PS_PROJ[0] - 1));
        CHECK_INT_EQ(rep.n_outliers_proj, JOINT_N_BAD);
        CHECK_INT_EQ(rep.n_outliers_cam, 0);
        CHECK_LE(dt, JOINT_T_TOL_MM);
        CHECK_LE(dR, JOINT_R_TOL_DEG);
        CHECK_NEAR(p.fx / PS_PROJ[0], 1.0, JOINT_F_REL_TOL);
        CHECK(dR0 > 2 * dR);

        /* One view's projector corners labelled the other way round (the board's 180°
         * ambiguity): each device alone fits it as a turned board and stereoCalibrate's pose goes
         * wrong; the joint fit drops that view's projector corners and keeps the pose. */
        ps_tilted(&g, JOINT_VIEWS, EXT_R, EXT_T, JOINT_NOISE_CAM_PX, JOINT_NOISE_PROJ_PX, 2000);
        int mv = 0;                     /* a view the projector sees whole */
        while (mv < JOINT_VIEWS - 1 && g.vp[mv].n != PS_NPTS)
                mv++;
        CHECK_INT_EQ(g.vp[mv].n, PS_NPTS);
        for (int i = 0; i < PS_NPTS / 2; i++)
                for (int k = 0; k < 2; k++) {
                        double t = g.proj[mv][2 * i + k];
                        g.proj[mv][2 * i + k] = g.proj[mv][2 * (PS_NPTS - 1 - i) + k];
                        g.proj[mv][2 * (PS_NPTS - 1 - i) + k] = t;
                }
        static struct imp_calib_procam pc;
        memset(&pc, 0, sizeof pc);
        CHECK_OK(ps_start(&g, &pc.camera, &pc.projector, &pc.stereo, rv, tv, &err));
        ps_pose_error(&g, &pc.stereo, &dt0, &dR0);
        CHECK_INT_EQ(imp_cv_calib_procam_joint(g.vc, g.vp, g.n_views, rv, tv, &pc), 1);
        ps_pose_error(&g, &pc.stereo, &dt, &dR);
        fprintf(stderr, "joint, view %d's projector corners mislabelled: dropped %d + %d; pose |Δt| %.3f mm, ΔR "
                "%.4f° (stereoCalibrate %.1f mm, %.2f°)\n", mv, pc.joint.outliers_camera,
                pc.joint.outliers_projector, dt, dR, dt0, dR0);
        CHECK_INT_EQ(pc.joint.outliers_projector, PS_NPTS);
        CHECK_LE(dt, 2 * JOINT_T_TOL_MM);       /* one view fewer for the projector, and a far start */
        CHECK_LE(dR, 2 * JOINT_R_TOL_DEG);
        CHECK_GE(dt0, 10 * JOINT_T_TOL_MM);
        CHECK_INT_EQ(pc.n_warnings, 1);
        CHECK_STR_CONTAINS(pc.warnings[0], "88 projector points dropped");

        /* The fallback: the board moved (3 mm, 1°) between the white frame and the Gray code in
         * every view, so the devices disagree about every board. Each alone fits its own
         * corners; the shared poses cannot, the joint fit is worse, and the per-device values
         * and stereoCalibrate's pose stay, with a warning. */
        static struct ps_rig moved;
        ps_tilted(&g, JOINT_VIEWS, EXT_R, EXT_T, JOINT_NOISE_CAM_PX, JOINT_NOISE_PROJ_PX, 3000);
        moved = g;
        uint64_t seed = 3001;
        for (int v = 0; v < JOINT_VIEWS; v++) {
                double r[3] = { g.rv[v][0] + 0.0175, g.rv[v][1], g.rv[v][2] };
                double t[3] = { g.tv[v][0] + 3, g.tv[v][1], g.tv[v][2] };
                ps_view(&moved, v, r, t, JOINT_NOISE_CAM_PX, JOINT_NOISE_PROJ_PX, &seed);
                memcpy(g.proj[v], moved.proj[v], sizeof g.proj[v]);
                memcpy(g.obj_p[v], moved.obj_p[v], sizeof g.obj_p[v]);
                g.vp[v] = (struct imp_calib_view) { moved.vp[v].n, g.obj_p[v], g.proj[v] };
        }
        memset(&pc, 0, sizeof pc);
        CHECK_OK(ps_start(&g, &pc.camera, &pc.projector, &pc.stereo, rv, tv, &err));
        struct imp_calib_procam before = pc;
        CHECK_INT_EQ(imp_cv_calib_procam_joint(g.vc, g.vp, g.n_views, rv, tv, &pc), 0);
        fprintf(stderr, "joint, boards moved: %s\n", pc.joint.why_not_used);
        CHECK(pc.joint.attempted && !pc.joint.used);
        CHECK_STR_CONTAINS(pc.joint.why_not_used, "joint refinement fits the");
        CHECK_INT_EQ(pc.n_warnings, 1);
        CHECK_STR_CONTAINS(pc.warnings[0], "keeping the per-device calibration");
        CHECK_NEAR(pc.camera.fx, before.camera.fx, 0);
        CHECK_NEAR(pc.projector.cx, before.projector.cx, 0);
        CHECK_NEAR(pc.stereo.t[0], before.stereo.t[0], 0);
        CHECK(!pc.stereo.have_std && !pc.camera.joint_refined);
        json_t *j = imp_calib_procam_to_json(&pc);
        CHECK_STR_CONTAINS(json_string_value(json_object_get(json_object_get(j, "joint"), "fallback")),
                           "joint refinement fits the");
        CHECK_STR_EQ(json_string_value(json_object_get(json_object_get(j, "camera"), "refinement")), "opencv");
        json_decref(j);

        /* Bad arguments leave the outputs alone. */
        struct imp_calib_intrinsics keep = c;
        CHECK_ERR(imp_ceres_procam_refine(g.vc, g.vp, 0, &co, &c, &p, &st, rv, tv, NULL, &err), -EINVAL);
        struct imp_calib_view tiny = { 3, g.obj[0], g.cam[0] };
        CHECK_ERR(imp_ceres_procam_refine(&tiny, g.vp, 1, &co, &c, &p, &st, rv, tv, NULL, &err), -EINVAL);
        CHECK_NEAR(c.fx, keep.fx, 0);
}

int main(void) {
        if (!imp_ceres_calib_available())
                TEST_SKIP("built without Ceres (IMPASTO_WITH_CERES off)");
        struct imp_calib_view v[N_VIEWS];
        make_views(v);
        struct imp_error err = { 0 };
        struct imp_ceres_calib_opts co;
        imp_ceres_calib_opts_default(&co);
        co.fix_k3 = true;

        /* Clean data: Ceres agrees with OpenCV (same model and convention). */
        struct imp_calib_intrinsics cv = { 0 }, ce;
        double rv[3 * N_VIEWS], tv[3 * N_VIEWS];
        CHECK_OK(opencv_fit(v, &cv, rv, tv));
        ce = cv;
        struct imp_ceres_calib_report rep = { 0 };
        CHECK_OK(imp_ceres_calib_refine(v, N_VIEWS, &co, &ce, rv, tv, NULL, &rep, &err));
        show("opencv, clean", &cv);
        show("ceres, clean", &ce);
        CHECK_INT_EQ(rep.n_outliers, 0);
        CHECK(rep.covariance_ok);
        for (int i = 0; i < 4; i++) {
                double e = (&ce.fx)[i], o = (&cv.fx)[i];
                CHECK_NEAR(e, o, 0.2 * cv.std[i]);
                CHECK_NEAR(ce.std[i] / cv.std[i], 1.0, 0.2);
                CHECK_NEAR(e, TRUE_K[i], 3 * ce.std[i]);
        }
        CHECK_LE(ce.rms_px, cv.rms_px + 1e-4);
        CHECK_NEAR(ce.rms_px, NOISE_PX * sqrt(2), 0.02);
        CHECK_NEAR(ce.dist[4], 0.0, 0.0);               /* k3 held */
        CHECK_NEAR(ce.std[8], 0.0, 0.0);
        /* mrcal-style: poses compensate a principal-point shift, so at the centre the figure
         * is well below the intrinsics-only bound (which is about σ(cx), σ(cy)). */
        CHECK(ce.proj_unc_centre_px > 0);
        CHECK_LE(ce.proj_unc_centre_px, 0.5 * cv.proj_unc_centre_px);
        CHECK_FINITE(ce.proj_unc_corner_px);
        CHECK(ce.proj_unc_corner_px > ce.proj_unc_centre_px);

        /* Outliers: N_OUTLIERS corners near the image border moved 20 px outwards. */
        int bad[N_OUTLIERS];
        for (int k = 0; k < N_OUTLIERS; k++) {
                int view = (k * 5) % N_VIEWS, p = (k % 2) ? COLS * ROWS - 1 : 0;
                double *q = &img[view][2 * p], dx = q[0] - TRUE_K[2], dy = q[1] - TRUE_K[3], n = hypot(dx, dy);
                q[0] += OUTLIER_PX * dx / n;
                q[1] += OUTLIER_PX * dy / n;
                bad[k] = view * COLS * ROWS + p;
        }
        struct imp_calib_intrinsics cv2 = { 0 }, ls, rb;
        CHECK_OK(opencv_fit(v, &cv2, rv, tv));
        double rv0[3 * N_VIEWS], tv0[3 * N_VIEWS];
        for (int i = 0; i < 3 * N_VIEWS; i++)
                rv0[i] = rv[i], tv0[i] = tv[i];
        struct imp_ceres_calib_opts plain = co;
        plain.loss = IMP_CERES_LOSS_NONE;
        plain.outlier_sigmas = 0;
        ls = cv2;
        CHECK_OK(imp_ceres_calib_refine(v, N_VIEWS, &plain, &ls, rv, tv, NULL, NULL, &err));
        static uint8_t inlier[N_VIEWS * COLS * ROWS];
        rb = cv2;
        CHECK_OK(imp_ceres_calib_refine(v, N_VIEWS, &co, &rb, rv0, tv0, inlier, &rep, &err));
        show("opencv, outliers", &cv2);
        show("ceres LS, outliers", &ls);
        show("ceres robust", &rb);
        CHECK(fabs(cv2.fx / TRUE_K[0] - 1) > F_REL_TOL);
        CHECK(fabs(ls.fx / TRUE_K[0] - 1) > F_REL_TOL);
        CHECK_NEAR(rb.fx / TRUE_K[0], 1.0, F_REL_TOL);
        CHECK_NEAR(rb.fy / TRUE_K[1], 1.0, F_REL_TOL);
        CHECK_NEAR(rb.fx, ce.fx, 0.2 * ce.std[0]);      /* as if the outliers were not there */
        CHECK_INT_EQ(rep.n_outliers, N_OUTLIERS);
        CHECK_INT_EQ(rb.n_points, N_VIEWS * COLS * ROWS - N_OUTLIERS);
        int found = 0;
        for (int k = 0; k < N_OUTLIERS; k++)
                found += !inlier[bad[k]];
        CHECK_INT_EQ(found, N_OUTLIERS);
        CHECK_LE(rb.rms_px, 1.2 * NOISE_PX * sqrt(2));

        /* Bad arguments. */
        co.loss_scale_px = 0;
        CHECK_ERR(imp_ceres_calib_refine(v, N_VIEWS, &co, &rb, rv0, tv0, NULL, NULL, &err), -EINVAL);
        CHECK_ERR(imp_ceres_calib_refine(v, 0, &plain, &rb, rv0, tv0, NULL, NULL, &err), -EINVAL);

        joint_rig();
        return TEST_DONE();
}
