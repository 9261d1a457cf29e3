/* Camera-only calibration (`impasto calibrate camera`): intrinsics and
 * distortion of one camera from chessboard views, with per-view residuals, views rejected
 * as outliers and the warnings. The fit itself is the OpenCV/Ceres code of the procam
 * calibration (pipeline/calib/cv/cv-calib-camera.h); this half is pure C: input images to 8-bit
 * grey, a capture set's calibration frame, JSON, a readable summary and rig.json output. */
#pragma once
#include "calib.h"

#ifdef __cplusplus
extern "C" {
#endif

struct imp_pinhole;
struct imp_rig;

#define IMP_CALIB_CAMERA_MAX_VIEWS      256
#define IMP_CALIB_CAMERA_NAME_LEN       512
/* A view whose RMS residual (its own pose, the common intrinsics) exceeds both this factor
 * times the median view RMS and IMP_CALIB_VIEW_REJECT_MIN_PX is dropped and the
 * intrinsics fitted again, once: a board mislabelled by the detector, a moved or
 * differently focused frame. Rendered views scatter within ×1.5 of the median. */
#define IMP_CALIB_VIEW_REJECT_FACTOR    4.0
#define IMP_CALIB_VIEW_REJECT_MIN_PX    0.5
/* Input normalisation to 8 bits: (v − black) · IMP_CALIB_U8_WHITE / (99th percentile − black),
 * clipped (headroom below 255 so that the white paper is not clipped flat). */
#define IMP_CALIB_U8_WHITE              200.0

struct imp_calib_camera_opts {
        int board_cols, board_rows;             /* inner corners */
        double square;                          /* square side; translations in this unit */
        int k3;                                 /* IMP_CALIB_K3_AUTO (default), _FIT, _FIX */
        int k2;                                 /* the same values (calib.h, IMP_CALIB_K2_MIN_FOV_DEG) */
        bool opencv_only;                       /* no Ceres refinement */
        /* Fewer usable views than this is an error (-EDOM); default IMP_CALIB_MIN_VIEWS.
         * Lower values let a 1- or 2-view calibration through, flagged few_views, with the
         * focal length and principal point σ inflated (see imp_cv_calib_camera). */
        int min_views;
};
static inline void imp_calib_camera_opts_default(struct imp_calib_camera_opts *o) {
        *o = (struct imp_calib_camera_opts) { .board_cols = 9, .board_rows = 7, .square = 1.0,
                                              .k3 = IMP_CALIB_K3_AUTO, .k2 = IMP_CALIB_K3_AUTO, .min_views = IMP_CALIB_MIN_VIEWS };
}

struct imp_calib_camera_view {
        char name[IMP_CALIB_CAMERA_NAME_LEN];   /* the image or capture set */
        bool found;                             /* board detected */
        bool used;                              /* in the final fit */
        double rms_px;                          /* RMS residual under the final intrinsics and
                                                   this view's own pose (found views) */
        double tilt_deg;                        /* board normal vs the optical axis */
        double rvec[3], tvec[3];                /* board pose: X_cam = R X_board + t */
        char why[IMP_CALIB_WARNING_LEN];        /* why not used */
};

struct imp_calib_camera {
        struct imp_calib_intrinsics camera;
        int n_views, n_found, n_used, n_rejected;
        struct imp_calib_camera_view views[IMP_CALIB_CAMERA_MAX_VIEWS];
        int n_warnings;
        char warnings[IMP_CALIB_MAX_WARNINGS][IMP_CALIB_WARNING_LEN];
};

/* Appends a warning (beyond IMP_CALIB_MAX_WARNINGS the last slot says some were dropped). */
void imp_calib_camera_warn(struct imp_calib_camera *r, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* 8-bit grey copy of any image the readers give (u8/u16/f32, 1–4 channels: Rec. 709 luma of
 * the first three): (v − black) · IMP_CALIB_U8_WHITE / (p99 − black), p99 the 99th
 * percentile. -EDOM (err says so) when the image is flat or dark (p99 ≤ black). Caller
 * frees with imp_image_free(). */
int imp_calib_image_to_u8(const struct imp_image *im, double black, struct imp_image **ret,
                          struct imp_error *err);

/* The calibration frame of capture set `dir` for camera `camera` (NULL: the set's first
 * camera), as 8-bit grey normalised with the camera's black level: the first white
 * projector frame if the set has one, else the first dome or flat frame, else the first
 * frame that is not dark. ret_record (may be NULL): that frame's index. Errors name the
 * set: -ENOENT no such camera or no lit frame. */
int imp_calib_camera_set_frame(const char *dir, const char *camera, struct imp_image **ret,
                               long *ret_record, struct imp_rig *ret_rig, struct imp_error *err);

/* JSON (new reference; NULL only when out of memory) and a readable summary. */
json_t *imp_calib_camera_to_json(const struct imp_calib_camera *r);
void imp_calib_camera_print(const struct imp_calib_camera *r, FILE *f);

/* The calibrated pinhole (intrinsics, distortion; pose untouched). */
void imp_calib_intrinsics_to_pinhole(const struct imp_calib_intrinsics *in, struct imp_pinhole *m);

/* rig.json for the calibration: a copy of `base` (may be NULL: a rig with this one camera
 * at the world origin and neutral 8-bit sensor placeholders) whose camera `name` (NULL: the
 * first) gets the calibrated intrinsics and distortion; its pose and sensor are kept (a
 * camera calibration does not fix the rig's world frame). -ENOENT: base has no such camera. */
int imp_calib_camera_rig(const struct imp_calib_camera *r, const char *name, const struct imp_rig *base,
                         struct imp_rig *ret, struct imp_error *err);

#ifdef __cplusplus
}
#endif
