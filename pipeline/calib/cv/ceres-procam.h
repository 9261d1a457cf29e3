/* Joint refinement of a projector–camera pair with Ceres: one problem over the
 * camera's intrinsics and distortion, the projector's, one board pose per view (camera
 * frame) and the camera → projector pose, on the corners both devices observe. Moreno &
 * Taubin (2012) calibrate the pair in steps: each device alone (§3.3 camera, §3.4 projector
 * from the local homographies), then §3.5 "stereo system calibration", the pose by
 * stereoCalibrate with both intrinsics held fixed and the world frame = the camera's. This
 * replaces that last step by a bundle adjustment of everything at once (same model, same
 * world frame), with the robust loss, outlier rejection and covariance of ceres-calib.h.
 * Library code: no logging. Without Ceres the entry point returns -EOPNOTSUPP. */
#pragma once
#include <stdbool.h>

#ifdef __cplusplus
extern "C" {
#endif
#include "calib.h"
#include "ceres-calib.h"

struct imp_ceres_procam_report {
        bool converged;                 /* the last solve ended by Ceres' convergence test */
        int iterations;                 /* both solves */
        int n_outliers_cam, n_outliers_proj;
        double initial_rms_cam_px, initial_rms_proj_px;   /* at the start, all points */
        double sigma_cam_px, sigma_proj_px;  /* per-device residual scale that weighs the
                                                final solve (RMS norm over the inliers) */
        bool rank_deficient;            /* normal matrix floored: σ are placeholders */
};

/* Refines, in place, io_cam and io_proj (width, height, fx … dist, k3_fixed, k2_fixed read), the per-view
 * board poses io_rvecs / io_tvecs (3·n_views each, X_cam = R X_board + t) and io_stereo's R, t
 * (X_proj = R X_cam + t), on cam[v] (every corner the camera found in view v) and proj[v] (the
 * corners with a projector coordinate; board points in the same board frame).
 *
 * Parameterisation: 9 intrinsics per device (OpenCV's order; k3, k2 held where k3_fixed, k2_fixed), Rodrigues
 * vector + translation per pose. Residuals: camera corner − projection of R_v X + t_v; projector
 * corner − projection of R (R_v X + t_v) + t, each weighted by 1/σ of its device. Solve:
 * Levenberg–Marquardt with opts' loss (scale in pixels for both devices), then opts' outlier
 * rejection per device (σ_robust of that device), σ per device from the inliers, and a second
 * solve with the weights. Covariance: σ_w² (JᵀWJ)⁻¹ of all parameters on the inliers, without
 * the loss (J column-scaled, eigenvalues below 1e-12 of the largest floored: rank_deficient),
 * σ_w² = Σ(w r)² / (N − P) with N points (OpenCV's convention, as ceres-calib.h).
 *
 * Writes into both intrinsics what imp_ceres_calib_refine does (rms, worst, n_points, std, cov
 * — blocks of the joint covariance —, sigma_px, mrcal-style proj_unc_* from the joint
 * covariance, max_tilt_deg, n_views, n_outliers) and recomputes flags: FOCAL_UNDETERMINED
 * (σ(f)/f > 1 % or no board tilted > IMP_CALIB_MIN_TILT_DEG from that device's axis, σ(f) then
 * inflated to |f|), PP_UNDETERMINED, FEW_VIEWS, RANK_DEFICIENT; joint_refined set. io_stereo:
 * R, t, rms_px (both devices, inliers), worst view, have_std, r_std_deg, t_std, cov.
 * Everything untouched on failure: -EDOM when a solve fails or gives non-finite values or a
 * view keeps fewer than 4 camera corners, -EINVAL on bad arguments, -EOPNOTSUPP without Ceres. */
int imp_ceres_procam_refine(const struct imp_calib_view *cam, const struct imp_calib_view *proj, int n_views,
                            const struct imp_ceres_calib_opts *opts, struct imp_calib_intrinsics *io_cam,
                            struct imp_calib_intrinsics *io_proj, struct imp_calib_stereo *io_stereo,
                            double *io_rvecs, double *io_tvecs, struct imp_ceres_procam_report *ret_report,
                            struct imp_error *err);

#ifdef __cplusplus
}
#endif
