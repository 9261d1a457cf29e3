/* Projector–camera calibration over OpenCV (Moreno & Taubin, "Simple, accurate, and robust
 * projector-camera calibration", 3DIMPVT 2012) behind a C API: chessboard corners on the
 * white frame, Gray code decoded around each corner, a local homography per corner giving
 * its sub-pixel projector coordinate, then calibrateCamera for each device and
 * stereoCalibrate (intrinsics fixed) for the pose. Library code: no logging; OpenCV
 * exceptions stop here and become negative errnos with a message in err. */
#pragma once
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif
#include "image.h"
#include "calib.h"

/* Inner chessboard corners (cols × rows, row-major from the first found corner) on a u8
 * grey image, refined by cornerSubPix. ret_px: 2·cols·rows doubles, untouched on failure.
 * -ENOENT: the board of that size was not found (err says so). */
int imp_cv_calib_find_corners(const struct imp_image *img, int cols, int rows, double *ret_px,
                              struct imp_error *err);

/* Projector coordinates of camera points by local homographies (Moreno & Taubin §3):
 * around each point, camera pixels within ±half_px whose white − black > black_threshold
 * are decoded with GrayCodePattern::getProjPixel (white_threshold); at least half_px²
 * decoded pixels are needed, then a RANSAC homography camera→projector maps the point.
 * frames: imp_cv_graycode_count(proj_w, proj_h) pattern frames, u8 grey, size of white.
 * ret_proj: 2n doubles; ret_ok[i] = 1 when point i got one (else its coords are -1).
 * *ret_n_decoded: decoded pixels in all windows (may be NULL). */
int imp_cv_calib_points_to_projector(int proj_w, int proj_h, const struct imp_image *const *frames,
                                     size_t n_frames, const struct imp_image *white,
                                     const struct imp_image *black, int black_threshold,
                                     int white_threshold, int half_px, const double *cam_px,
                                     int n, double *ret_proj, uint8_t *ret_ok, int *ret_n_decoded,
                                     struct imp_error *err);

/* cv::calibrateCamera (5 distortion terms, default flags: k3 estimated) on planar views, then the
 * first-order covariance and projection uncertainty (see calib.h), then
 * imp_calib_intrinsics_assess(). ret_rvecs / ret_tvecs (3·n_views each) may be NULL.
 * -EDOM with a message when the data do not determine a finite result (OpenCV gave
 * non-finite values or threw on degenerate input); -EINVAL on bad arguments. */
int imp_cv_calib_intrinsics(const struct imp_calib_view *views, int n_views, int width, int height,
                            struct imp_calib_intrinsics *ret, double *ret_rvecs, double *ret_tvecs,
                            struct imp_error *err);
/* The same with IMP_CALIB_FIT_* flags (calib.h): IMP_CALIB_FIT_FIX_K3 holds k3 at 0
 * (CALIB_FIX_K3) and leaves it out of the covariance (ret->k3_fixed; std and cov of k3 0);
 * IMP_CALIB_FIT_FIX_K2 likewise k2 (CALIB_FIX_K2, ret->k2_fixed). */
int imp_cv_calib_intrinsics_fit(const struct imp_calib_view *views, int n_views, int width, int height,
                                unsigned fit, struct imp_calib_intrinsics *ret, double *ret_rvecs,
                                double *ret_tvecs, struct imp_error *err);

/* cv::stereoCalibrate with CALIB_FIX_INTRINSIC: views_a / views_b share object points
 * (views_a[i].obj is used; the n of both must agree). */
int imp_cv_calib_stereo(const struct imp_calib_view *views_a, const struct imp_calib_view *views_b,
                        int n_views, const struct imp_calib_intrinsics *a,
                        const struct imp_calib_intrinsics *b, struct imp_calib_stereo *ret,
                        struct imp_error *err);

/* The joint refinement step of the procedure (ceres-procam.h), on io's per-device results
 * (io->camera, io->projector: each refined alone) and stereoCalibrate's io->stereo, with the
 * camera's board poses rvecs / tvecs (3·n_views each) and the views both fits used (proj[v]:
 * the corners of view v with a projector coordinate). Returns 1 when the joint values replaced
 * io's camera, projector and stereo (io->joint says how it went); 0 when io keeps its values
 * — the per-device fits flag the views as undetermined, the joint solve failed, or it fits a
 * device clearly worse (RMS above 1.25 × alone + 0.02 px: the devices disagree about the
 * boards) — with io->joint.why_not_used and, but for the first case, a warning in io;
 * -EINVAL / -ENOMEM. Does not check that Ceres is available (-EOPNOTSUPP becomes a warning). */
int imp_cv_calib_procam_joint(const struct imp_calib_view *cam, const struct imp_calib_view *proj, int n_views,
                              const double *rvecs, const double *tvecs, struct imp_calib_procam *io);

/* The whole procedure on capture directories DIR/graycode_00.png … graycode_NN.png
 * (NN+1 = Gray-code frames + white + black, OpenCV's order). A capture whose board is not
 * found, or with fewer than 3 corners mapped, is skipped with a warning in ret; fewer than
 * IMP_CALIB_MIN_VIEWS usable captures is -EDOM. Missing/unreadable images: the reader's
 * errno, err naming the file. ret is written only on success. */
int imp_cv_calib_procam(const char *const *dirs, int n_dirs, const struct imp_calib_procam_opts *opts,
                        struct imp_calib_procam *ret, struct imp_error *err);

/* The same procedure on frames from `load` (calib.h; e.g. imp_calib_sets_load over capture
 * sets); names[i] names capture i in messages. With opts->orient_board the corners are
 * labelled consistently (calib.h); with opts->reference >= 0 the camera's pose in the
 * canvas frame comes from that capture (solvePnP, estimated intrinsics): -EDOM when its
 * board was not found. */
int imp_cv_calib_procam_source(const char *const *names, int n, imp_calib_frame_loader load, void *user,
                               const struct imp_calib_procam_opts *opts, struct imp_calib_procam *ret,
                               struct imp_error *err);

/* One device's intrinsics from planar views, as the procam procedure computes the camera's
 * (calibrateCamera with opts.k3 and k2 — IMP_CALIB_K3_AUTO, _FIT or _FIX — then, built with Ceres
 * and unless opencv_only, the robust refinement on views that determine the focal length);
 * used by the camera-only calibration (cv-calib-camera.h). Its warnings (prefixed `who`)
 * are appended to ret_warnings while *ret_n_warnings < max_warnings. Errors as
 * imp_cv_calib_intrinsics_fit; ret untouched on failure. */
int imp_cv_calib_device(const struct imp_calib_view *views, int n_views, int width, int height, int k3,
                        int k2, bool opencv_only, const char *who, struct imp_calib_intrinsics *ret,
                        char (*ret_warnings)[IMP_CALIB_WARNING_LEN], int max_warnings, int *ret_n_warnings,
                        struct imp_error *err);

#ifdef __cplusplus
}
#endif
