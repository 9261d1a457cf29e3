/* A synthetic projector–camera rig for the joint-calibration tests (test-calib-ceres,
 * test-calib-joint-stability): exact projections (OpenCV's model) of chessboard corners
 * into a known camera and projector, plus Gaussian noise; and the per-device OpenCV +
 * stereoCalibrate start that `calibrate procam` gives the joint refinement. */
#pragma once
#include <math.h>
#include <string.h>
#include "calib.h"
#include "cv-calib.h"
#include "test.h"

#define PS_W 1280
#define PS_H 960
#define PS_PW 1024
#define PS_PH 768
#define PS_COLS 11
#define PS_ROWS 8
#define PS_NPTS (PS_COLS * PS_ROWS)
#define PS_SQ_MM 20.0
#define PS_MAXV 16

/* fx fy cx cy k1 k2 p1 p2 k3 (k3 0: both fits hold it) */
static const double PS_CAM[IMP_CALIB_N_INTR] = { 2400, 2396, 652.5, 471.2, -0.12, 0.09, 4e-4, -3e-4, 0 };
static const double PS_PROJ[IMP_CALIB_N_INTR] = { 1800, 1803, 515.0, 700.0, -0.06, 0.03, 2e-4, -1e-4, 0 };

struct ps_rig {
        int n_views;
        double ext_r[3], ext_t[3];              /* camera → projector (Rodrigues, mm) */
        double rv[PS_MAXV][3], tv[PS_MAXV][3];  /* true board poses, camera frame */
        double obj[PS_MAXV][3 * PS_NPTS], cam[PS_MAXV][2 * PS_NPTS];
        double obj_p[PS_MAXV][3 * PS_NPTS], proj[PS_MAXV][2 * PS_NPTS];
        struct imp_calib_view vc[PS_MAXV], vp[PS_MAXV];
};

static inline void ps_rotation(const double r[3], double R[9]) {
        double th = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]);
        double a[3] = { 1, 0, 0 };
        if (th > 0)
                for (int i = 0; i < 3; i++)
                        a[i] = r[i] / th;
        double c = cos(th), s = sin(th), C = 1 - c;
        const double m[9] = { c + a[0] * a[0] * C, a[0] * a[1] * C - a[2] * s, a[0] * a[2] * C + a[1] * s,
                              a[1] * a[0] * C + a[2] * s, c + a[1] * a[1] * C, a[1] * a[2] * C - a[0] * s,
                              a[2] * a[0] * C - a[1] * s, a[2] * a[1] * C + a[0] * s, c + a[2] * a[2] * C };
        memcpy(R, m, sizeof m);
}

/* Rodrigues vector of R (angles below π). */
static inline void ps_log(const double R[9], double r[3]) {
        double c = IMP_CLAMP(0.5 * (R[0] + R[4] + R[8] - 1), -1.0, 1.0), th = acos(c);
        double k = th > 1e-12 ? th / (2 * sin(th)) : 0.5;
        r[0] = k * (R[7] - R[5]);
        r[1] = k * (R[2] - R[6]);
        r[2] = k * (R[3] - R[1]);
}

/* q = projection of R X + t with intrinsics k; returns false behind the device. */
static inline bool ps_project(const double *k, const double R[9], const double t[3], const double X[3], double q[2]) {
        double p[3];
        for (int i = 0; i < 3; i++)
                p[i] = R[3 * i] * X[0] + R[3 * i + 1] * X[1] + R[3 * i + 2] * X[2] + t[i];
        if (!(p[2] > 0))
                return false;
        double x = p[0] / p[2], y = p[1] / p[2], r2 = x * x + y * y;
        double rad = 1 + r2 * (k[4] + r2 * (k[5] + r2 * k[8]));
        q[0] = k[0] * (x * rad + 2 * k[6] * x * y + k[7] * (r2 + 2 * x * x)) + k[2];
        q[1] = k[1] * (y * rad + k[6] * (r2 + 2 * y * y) + 2 * k[7] * x * y) + k[3];
        return true;
}

/* View v: board pose (r, t) in the camera frame; every corner into the camera, those inside
 * the projector's image into the projector; noise σ per coordinate. */
static inline void ps_view(struct ps_rig *g, int v, const double r[3], const double t[3], double noise_cam,
                           double noise_proj, uint64_t *seed) {
        double R[9], Re[9];
        ps_rotation(r, R);
        ps_rotation(g->ext_r, Re);
        memcpy(g->rv[v], r, sizeof g->rv[v]);
        memcpy(g->tv[v], t, sizeof g->tv[v]);
        int np = 0;
        for (int i = 0; i < PS_NPTS; i++) {
                double X[3] = { PS_SQ_MM * (i % PS_COLS), PS_SQ_MM * (i / PS_COLS), 0 }, pc[3], q[2];
                memcpy(&g->obj[v][3 * i], X, sizeof X);
                ps_project(PS_CAM, R, t, X, &g->cam[v][2 * i]);
                g->cam[v][2 * i] += noise_cam * test_nrand(seed);
                g->cam[v][2 * i + 1] += noise_cam * test_nrand(seed);
                for (int k = 0; k < 3; k++)
                        pc[k] = R[3 * k] * X[0] + R[3 * k + 1] * X[1] + t[k];
                if (!ps_project(PS_PROJ, Re, g->ext_t, pc, q) || q[0] < 0 || q[1] < 0 || q[0] > PS_PW - 1 ||
                    q[1] > PS_PH - 1)
                        continue;
                memcpy(&g->obj_p[v][3 * np], X, sizeof X);
                g->proj[v][2 * np] = q[0] + noise_proj * test_nrand(seed);
                g->proj[v][2 * np + 1] = q[1] + noise_proj * test_nrand(seed);
                np++;
        }
        g->vc[v] = (struct imp_calib_view) { PS_NPTS, g->obj[v], g->cam[v] };
        g->vp[v] = (struct imp_calib_view) { np, g->obj_p[v], g->proj[v] };
}

/* n tilted views (25–55°, every azimuth, 620–740 mm) of the rig with extrinsic (er, et). */
static inline void ps_tilted(struct ps_rig *g, int n, const double er[3], const double et[3], double noise_cam,
                             double noise_proj, uint64_t seed) {
        memcpy(g->ext_r, er, sizeof g->ext_r);
        memcpy(g->ext_t, et, sizeof g->ext_t);
        g->n_views = n;
        for (int i = 0; i < n; i++) {
                double tilt = (25 + 15 * (i % 3)) * M_PI / 180, az = 2 * M_PI * i / n;
                double r[3] = { tilt * cos(az), tilt * sin(az), 0.1 * (i % 2 ? 1 : -1) };
                double t[3] = { -0.5 * (PS_COLS - 1) * PS_SQ_MM + 25 * cos(3 * az),
                                -0.5 * (PS_ROWS - 1) * PS_SQ_MM + 20 * sin(2 * az), 620 + 40 * (i % 4) };
                ps_view(g, i, r, t, noise_cam, noise_proj, &seed);
        }
}

/* The start `calibrate procam` gives the joint fit: each device by calibrateCamera (k3 held),
 * the camera's board poses, stereoCalibrate's pose on the corners both devices see. */
static inline int ps_start(const struct ps_rig *g, struct imp_calib_intrinsics *cam,
                           struct imp_calib_intrinsics *proj, struct imp_calib_stereo *st, double *rv, double *tv,
                           struct imp_error *err) {
        static double obj_cp[PS_MAXV][3 * PS_NPTS], cam_cp[PS_MAXV][2 * PS_NPTS];
        struct imp_calib_view vcp[PS_MAXV];
        int r = imp_cv_calib_intrinsics_fit(g->vc, g->n_views, PS_W, PS_H, IMP_CALIB_FIT_FIX_K3, cam, rv, tv, err);
        if (r >= 0)
                r = imp_cv_calib_intrinsics_fit(g->vp, g->n_views, PS_PW, PS_PH, IMP_CALIB_FIT_FIX_K3, proj, NULL,
                                                NULL, err);
        if (r < 0)
                return r;
        for (int v = 0; v < g->n_views; v++) {     /* camera corners the projector saw too */
                int n = 0;
                for (int i = 0; i < PS_NPTS; i++)
                        for (int k = 0; k < g->vp[v].n; k++)
                                if (!memcmp(&g->obj[v][3 * i], &g->obj_p[v][3 * k], 3 * sizeof(double))) {
                                        memcpy(&obj_cp[v][3 * n], &g->obj[v][3 * i], 3 * sizeof(double));
                                        memcpy(&cam_cp[v][2 * n], &g->cam[v][2 * i], 2 * sizeof(double));
                                        n++;
                                        break;
                                }
                vcp[v] = (struct imp_calib_view) { n, obj_cp[v], cam_cp[v] };
        }
        return imp_cv_calib_stereo(vcp, g->vp, g->n_views, cam, proj, st, err);
}

/* |Δt| (mm) and rotation angle (deg) between a stereo result and the rig's truth. */
static inline void ps_pose_error(const struct ps_rig *g, const struct imp_calib_stereo *st, double *dt_mm,
                                 double *dR_deg) {
        double Rt[9], D[9], r[3];
        ps_rotation(g->ext_r, Rt);
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        D[3 * i + j] = 0;
                        for (int k = 0; k < 3; k++)
                                D[3 * i + j] += st->R[3 * i + k] * Rt[3 * j + k];
                }
        ps_log(D, r);
        *dR_deg = sqrt(r[0] * r[0] + r[1] * r[1] + r[2] * r[2]) * 180 / M_PI;
        *dt_mm = sqrt((st->t[0] - g->ext_t[0]) * (st->t[0] - g->ext_t[0]) +
                      (st->t[1] - g->ext_t[1]) * (st->t[1] - g->ext_t[1]) +
                      (st->t[2] - g->ext_t[2]) * (st->t[2] - g->ext_t[2]));
}
