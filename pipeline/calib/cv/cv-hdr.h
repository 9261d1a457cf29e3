/* OpenCV's Debevec HDR merge (photo module: MergeDebevec, CalibrateDebevec) behind a C
 * API: the reference that bench-hdr compares impasto's noise-model merge (hdr.h) with.
 * Not used by the pipeline itself. OpenCV exceptions become -EINVAL / -ENOMEM with a
 * message in err. OpenCV 4.6's MergeDebevec and CalibrateDebevec accept only 8-bit
 * frames (CV_8UC1 / CV_8UC3; the u16 path came in later releases): u16 frames are passed
 * through so that the caller sees OpenCV's own refusal. */
#pragma once
#include <stdbool.h>
#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif
/* The core headers have no C++ guards of their own. */
#include "image.h"

/* Size of OpenCV's response table (LDR_SIZE): entries per channel. */
#define IMP_CV_HDR_LUT 256

/* cv::getNumThreads() / cv::setNumThreads() and the name of OpenCV's parallel backend
 * (cv::currentParallelFramework(), e.g. "pthreads", "tbb", "openmp"). */
int imp_cv_hdr_threads_get(void);
void imp_cv_hdr_threads_set(int n);
const char *imp_cv_hdr_parallel_framework(void);

/* cv::createMergeDebevec()->process(frames, out, times, response).
 * frames: n images of one layout, u8 (or u16: refused by OpenCV 4.6), 1 or 3 channels;
 * exposure_s: n exposure times; response: NULL (OpenCV's default linear response) or
 * IMP_CV_HDR_LUT × channels floats (interleaved, > 0): pixel value → exposure (radiance
 * × time, any unit). out: caller-allocated f32 image of the frames' size and channels;
 * receives the radiance in the response's units per second of exposure_s. */
int imp_cv_hdr_merge_debevec(const struct imp_image *const *frames, const double *exposure_s,
                             size_t n, const float *response, struct imp_image *out,
                             struct imp_error *err);

/* cv::createCalibrateDebevec(samples, lambda, random)->process(frames, response, times):
 * the estimated response (IMP_CV_HDR_LUT × channels floats, interleaved) into ret_response.
 * samples <= 0 and lambda <= 0 select OpenCV's defaults (70, 10). */
int imp_cv_hdr_calibrate_debevec(const struct imp_image *const *frames, const double *exposure_s,
                                 size_t n, int samples, float lambda, bool random,
                                 float *ret_response, struct imp_error *err);

#ifdef __cplusplus
}
#endif
