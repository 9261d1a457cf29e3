/* Camera backend "libcamera": the C face of a thin C++ shim over libcamera 0.0.3 (Debian 12).
 * The ops table is the backend; the probe lets a test tell "libcamera cannot run here"
 * (skip) from "it runs and sees no camera". */
#pragma once

#ifdef __cplusplus
extern "C" {
#endif

#include "camera.h"     /* a C header: C linkage from the C++ shim too */

extern const struct imp_camera_ops imp_camera_libcamera_ops;

/* Start libcamera's camera manager and count the cameras it sees. Negative errno when the
 * manager cannot start (no media devices, no permission to enumerate them). */
int imp_camera_libcamera_probe(unsigned *ret_n_cameras);

#ifdef __cplusplus
}
#endif
