/* OpenCV's two-view triangulation (cv::undistortPoints then cv::triangulatePoints, the
 * linear DLT) behind a C API: the reference the import bench compares impasto's
 * triangulation with on the same correspondences. OpenCV exceptions become -EINVAL /
 * -ENOMEM with a message in err. */
#pragma once
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif
#include "error.h"
#include "rig.h"

/* Points seen at a_px in device a and b_px in device b (2n doubles each, OpenCV pixel
 * convention: pixel centres at integers), both undistorted with their model, triangulated
 * in the world frame of the models' poses: ret_xyz 3n doubles (mm). */
int imp_cv_triangulate(const struct imp_pinhole *a, const struct imp_pinhole *b, const double *a_px,
                       const double *b_px, size_t n, double *ret_xyz, struct imp_error *err);

#ifdef __cplusplus
}
#endif
