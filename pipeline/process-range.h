/* `impasto process CAPSET --out DIR --range-only`: a capture set's structured-light frames
 * (impasto's own, or imported with `impasto import sl`) decoded (structured-light.h) and
 * triangulated (triangulate.h) into a range image on the camera's pixel grid, without the
 * heightfield, canvas extraction or dome stages. Library code: no logging. */
#pragma once
#include "error.h"
#include "structured-light.h"
#include "triangulate.h"

/* Decodes and triangulates camera 0's structured-light frames (first exposure of each
 * pattern). ret_range: caller frees with imp_range_image_done(); ret_sl (may be NULL): the
 * decoder's result, decoded with coords_only (no direct, global or modulation map: nothing
 * here reads them), caller frees with imp_sl_result_free(). -EINVAL for a set without a
 * projector or structured-light frames (message names it), I/O and memory errors. */
int imp_range_from_set(const char *capture_dir, struct imp_range_image *ret_range, struct imp_sl_result **ret_sl,
                       struct imp_error *err);

/* imp_range_from_set() and OUT/range.exr (channels X, Y, Z in the rig's world frame, mm;
 * sigma_mm; valid: IMP_RANGE_*; proj_x, proj_y: decoded projector coordinates, −1 where
 * none) with OUT/range.json (counts, seconds). */
int imp_process_range(const char *capture_dir, const char *out_dir, struct imp_error *err);
