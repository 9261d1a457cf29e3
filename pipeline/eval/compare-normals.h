/* Normals of a copy against reference normals on the same pixel grid (benchmarks with
 * reference normals, the simulator's truth rendered per camera pixel): angular error
 * statistics. Convention of every normal map here: x right, y up (image rows go down),
 * z towards the camera; unit vectors. Library code: no logging. */
#pragma once
#include <stdint.h>
#include "image.h"

/* Reads a normal map into an f32 3-channel image of unit vectors, NAN where a pixel holds
 * no normal (zero length or non-finite):
 *   - a directory: DIR/heightfield.exr of a copy (channels nx, ny and nz, or nz from
 *     √(1 − nx² − ny²) when absent);
 *   - .exr: channels nx, ny, nz (or X, Y, Z / R, G, B, or the first three);
 *   - .tif/.tiff: 3-channel float as is, or 8/16-bit as (n + 1) / 2;
 *   - .png: 8/16-bit as (n + 1) / 2 (the photometric-stereo benchmark convention).
 * Caller frees *ret. Errors name the file and what was expected. */
int imp_normals_read(const char *path, struct imp_image **ret, struct imp_error *err);

struct imp_normals_cmp {
        long n;                       /* pixels compared: both valid, inside the mask */
        double mean_deg, median_deg, rms_deg, p90_deg;
        double within_10deg, within_20deg;   /* fractions of n */
};

/* est and truth: f32 3-channel, the same size (else -EINVAL); mask (may be NULL): u8/u16
 * one channel of that size, non-zero = compared. -ENODATA when no pixel qualifies. */
int imp_normals_compare(const struct imp_image *est, const struct imp_image *truth, const struct imp_image *mask,
                        struct imp_normals_cmp *ret);
