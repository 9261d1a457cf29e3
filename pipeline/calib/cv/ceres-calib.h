/* Bundle refinement of one device's intrinsics, distortion and per-view board poses with
 * Ceres: robust loss, outlier rejection, covariance by ceres::Covariance and an
 * mrcal-style projection uncertainty. Starts from OpenCV's estimate (cv-calib.h); the model
 * is OpenCV's (fx fy cx cy k1 k2 p1 p2 k3, poses as Rodrigues vector + translation), so the
 * results drop into struct imp_calib_intrinsics unchanged. Library code: no logging.
 * Without Ceres (IMPASTO_WITH_CERES off) the entry point returns -EOPNOTSUPP. */
#pragma once
#include <stdbool.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif
#include "calib.h"

enum imp_ceres_loss { IMP_CERES_LOSS_NONE = 0, IMP_CERES_LOSS_HUBER, IMP_CERES_LOSS_CAUCHY };

struct imp_ceres_calib_opts {
        enum imp_ceres_loss loss;
        double loss_scale_px;           /* where the loss turns robust (residual norm, px) */
        /* Outlier rejection after the first robust solve: a point whose residual exceeds
         * max(outlier_sigmas · σ_robust, outlier_min_px) is dropped and the problem solved
         * again; σ_robust = 1.4826 · median of the residual norms / √(ln 4) (the median of
         * a 2-D Gaussian's norm is σ√(2 ln 2)). outlier_sigmas 0: no rejection. */
        double outlier_sigmas;
        double outlier_min_px;
        bool fix_k3;                    /* hold k3 where it is (a narrow field of view) */
        bool fix_k2;                    /* hold k2 where it is (a narrower one, calib.h) */
        int max_iterations;
};
static inline void imp_ceres_calib_opts_default(struct imp_ceres_calib_opts *o) {
        *o = (struct imp_ceres_calib_opts) { .loss = IMP_CERES_LOSS_CAUCHY, .loss_scale_px = 1.0,
                .outlier_sigmas = 6.0, .outlier_min_px = 1.0, .max_iterations = 200 };
}

struct imp_ceres_calib_report {
        int n_outliers;                 /* points dropped by the rejection */
        int iterations;                 /* both solves */
        double initial_rms_px;          /* the start (OpenCV's estimate), all points */
        bool covariance_ok;             /* false: Ceres found the Jacobian rank deficient; the
                                           caller's (OpenCV) covariance is kept, flagged */
};

/* True when built with Ceres. */
bool imp_ceres_calib_available(void);

/* Refines *io (width, height, fx … dist, k3_fixed, k2_fixed read; everything else written) and the
 * per-view poses io_rvecs / io_tvecs (3·n_views each, OpenCV's convention X_cam = R X + t),
 * in place, on views (calib.h). Fills in io: rms_px, worst_*, n_points (inliers), std, cov
 * (σ² (JᵀJ)⁻¹ of the inliers, OpenCV's σ² = Σr² / (N − P) with N points), sigma_px,
 * proj_unc_centre_px / proj_unc_corner_px (mrcal-style, see docs/calibration.md); keeps
 * n_views, max_tilt_deg and flags (adds IMP_CALIB_RANK_DEFICIENT when the covariance
 * cannot be computed). ret_inlier (total points, may be NULL): 1 for points kept.
 * Untouched on failure: -EDOM when the solve fails or gives non-finite values, -EINVAL on
 * bad arguments, -EOPNOTSUPP without Ceres. */
int imp_ceres_calib_refine(const struct imp_calib_view *views, int n_views,
                           const struct imp_ceres_calib_opts *opts, struct imp_calib_intrinsics *io,
                           double *io_rvecs, double *io_tvecs, uint8_t *ret_inlier,
                           struct imp_ceres_calib_report *ret_report, struct imp_error *err);

#ifdef __cplusplus
}
#endif
