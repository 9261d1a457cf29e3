/* OpenCV's structured_light::GrayCodePattern behind a C API: the reference decoder that
 * tests and benchmarks compare impasto's structured-light decoder with. Not used by the
 * pipeline itself. OpenCV exceptions become -EINVAL / -ENOMEM with a message in err. */
#pragma once
#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif
/* The core headers have no C++ guards of their own. */
#include "image.h"

/* Number of Gray-code pattern images (without white and black) OpenCV uses for a
 * proj_w × proj_h projector, or a negative errno. */
int imp_cv_graycode_count(int proj_w, int proj_h);

/* OpenCV's generated patterns (u8, 1 channel, proj_w × proj_h) in OpenCV's order.
 * *ret_images is malloc'd; caller frees with imp_cv_graycode_images_free(). */
int imp_cv_graycode_generate(int proj_w, int proj_h, struct imp_image ***ret_images,
                             size_t *ret_n, struct imp_error *err);
void imp_cv_graycode_images_free(struct imp_image **images, size_t n);

/* Decodes every camera pixel the way OpenCV's users do (e.g. procam-calibration's
 * calibrate.py): a pixel is skipped unless white − black > black_threshold, then
 * GrayCodePattern::getProjPixel() with setWhiteThreshold(white_threshold) decides.
 * frames: the imp_cv_graycode_count() pattern frames in OpenCV's order, u8, 1 channel,
 * all the size of white and black. Outputs (caller-allocated, width × height, row-major):
 * proj_x / proj_y (−1 where not decoded), valid (0/1). *ret_n_valid: decoded pixels. */
int imp_cv_graycode_decode(int proj_w, int proj_h, const struct imp_image *const *frames,
                           size_t n_frames, const struct imp_image *white,
                           const struct imp_image *black, int black_threshold,
                           int white_threshold, int32_t *proj_x, int32_t *proj_y,
                           uint8_t *valid, size_t *ret_n_valid, struct imp_error *err);

#ifdef __cplusplus
}
#endif
