/* A projector–camera calibration in OpenCV's FileStorage form (XML or YAML), as
 * procam-calibration's calibrate.py writes it (calibration_result.xml): cam_int, cam_dist,
 * proj_int, proj_dist (3×3 and 1×N, N ≤ 5: k1 k2 p1 p2 k3), the camera → projector rotation
 * (key "roration", that script's spelling, or "rotation") and "translation". Read into a
 * rig (rig.h) whose world is the camera frame: camera "camera0" at the identity, the
 * projector "projector" posed by R, t. Image sizes are not in the file: left 0 for the
 * caller (import-sl.h fills them from the frames and --projector). */
#pragma once

#ifdef __cplusplus
extern "C" {
#endif
#include "error.h"
#include "rig.h"

/* -ENOENT (cannot open), -EBADMSG (a key missing or of the wrong shape: err names it).
 * Caller frees with imp_rig_free(). */
int imp_cv_procam_xml_rig(const char *path, struct imp_rig *ret, struct imp_error *err);

#ifdef __cplusplus
}
#endif
