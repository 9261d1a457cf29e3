/* Camera-only calibration over OpenCV (and Ceres): the camera half of the projector–camera
 * procedure (cv-calib.h) on chessboard views with per-view residuals and rejection of
 * outlying views (calib-camera.h). Library code: no logging. */
#pragma once

#ifdef __cplusplus
extern "C" {
#endif
#include "calib-camera.h"

/* Calibrates from views[0 .. io->n_views): io->views[i] (name, found, why) is filled by the
 * caller, views[i] holds view i's board corners when io->views[i].found (board frame,
 * square units; n ≥ 4), else n = 0. Steps: imp_cv_calib_device() on the found views;
 * each view's pose by solvePnP under the fitted intrinsics, its RMS and tilt; views above
 * IMP_CALIB_VIEW_REJECT_FACTOR × the median view RMS (and IMP_CALIB_VIEW_REJECT_MIN_PX)
 * dropped and the intrinsics fitted once more; then the flags (calib.h) as warnings.
 * With fewer than IMP_CALIB_MIN_VIEWS views used (possible when o->min_views allows it)
 * the result is flagged few_views and σ of fx, fy, cx, cy is raised to at least
 * IMP_CALIB_FEW_VIEWS_STD_REL × f and IMP_CALIB_FEW_VIEWS_STD_PP × the image size: a
 * board seen once or twice confounds focal length, principal point, distortion and
 * pose, and the local covariance says less than that.
 * Errors: -EDOM when fewer than o->min_views views have the board (err lists the views and
 * why) or the fit fails; -EINVAL on bad arguments. io->camera, io->views[].used/rms_px/
 * tilt_deg/pose, n_found, n_used, n_rejected and warnings are written. */
#define IMP_CALIB_FEW_VIEWS_STD_REL     1.0
#define IMP_CALIB_FEW_VIEWS_STD_PP      0.1
int imp_cv_calib_camera(const struct imp_calib_view *views, int width, int height,
                        const struct imp_calib_camera_opts *o, struct imp_calib_camera *io,
                        struct imp_error *err);

#ifdef __cplusplus
}
#endif
