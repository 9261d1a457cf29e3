/* HDR merge of an exposure stack of raw frames into linear radiance values with their
 * variance, after the sensor model of rig.h (struct imp_sensor):
 *   DN = e / g + black,  g = gain_e_per_dn · 10^(−gain_db/20) electrons per DN,
 *   e  = V · quantum_scale · exposure_s (+ dark current), shot noise Poisson, read noise
 *   Gaussian, DN clipped at 2^bits − 1 and at full well.
 * Samples that are saturated or under-exposed are excluded (not down-weighted); the rest
 * are combined with inverse-variance weights from the noise model. Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "image.h"
#include "rig.h"

/* Per-sample flags of the merged result (bit set). A flagged pixel still has a finite
 * value and variance, described below. */
enum {
        IMP_HDR_SATURATED = 1 << 0,   /* saturated in every exposure: value is the lower bound
                                         (saturation level of the shortest exposure), variance
                                         = value² (100 % relative) */
        IMP_HDR_DARK      = 1 << 1,   /* under-exposed in every exposure: value 0, variance =
                                         (detection limit of the longest exposure)² */
        IMP_HDR_INTERPOLATED_FLAGGED = 1 << 2, /* Bayer: a neighbour used by the demosaic for
                                         this colour was SATURATED or DARK */
};

struct imp_hdr_exposure {
        const struct imp_image *frame;   /* u16 raw DN; 1 channel (grey or RGGB Bayer when
                                            sensor->bayer) or 3 channels (RGB) */
        double exposure_us;              /* > 0 */
        double gain_db;
        /* Frames of this exposure averaged into `frame` (the mean DN, rounded), e.g. the
         * repeats of a plan's `repeat`: their noise is divided by it. 0 or 1: one frame.
         * Separate equal exposures in the stack are also right (weighted equally, i.e.
         * averaged); this only saves holding them all at once. */
        unsigned n_frames;
};

struct imp_hdr_result;

struct imp_hdr_options {
        /* Per-pixel offset in DN (u16 or f32, same size and channel count as the frames),
         * replacing sensor->black_level_dn: the mean of closed-shutter frames at a short
         * exposure. NULL: black_level_dn everywhere. */
        const struct imp_image *dark;
        /* Per-pixel relative response (f32, same layout, mean ≈ 1: PRNU × vignetting).
         * V and its variance are divided by flat and flat². NULL: 1 everywhere. Values
         * <= 0 or non-finite count as 1. */
        const struct imp_image *flat;
        /* Inverse camera response: 2^bits entries mapping raw DN → linear DN. NULL: linear. */
        const float *response;
        /* Under-exposure: a sample whose signal is below dark_k · read_noise_e electrons is
         * excluded. 0 selects the default 3. */
        double dark_k;
        /* Saturation: a sample at or above (clip − saturation_margin_dn) is excluded, clip
         * being the lower of 2^bits − 1 and the full well in DN. < 0 selects the default,
         * 2 % of the clip level (so a Poisson tail does not reach the clip unseen). */
        double saturation_margin_dn;
        /* Bayer input (sensor->bayer with 1-channel frames): demosaic the merged values
         * (bilinear, RGGB) into 3 channels. false keeps the mosaic (1 channel). */
        bool demosaic;
        /* An earlier result whose variance and flags images are written into instead of
         * allocating new ones (their pages are mapped already: a loop over stacks keeps one
         * spare per thread). Each moves into the new result when it has the result's layout
         * (no demosaic) and is left where it is otherwise; every sample is overwritten, so
         * the result is byte for byte that of a fresh merge. The value image is always new.
         * NULL: allocate. */
        struct imp_hdr_result *recycle;
        /* The value image is allocated in this arena (image.h) instead of the heap: for a
         * stage that keeps every merge's values until it ends. NULL: the heap. */
        struct imp_image_arena *arena;
};

/* Fills the defaults above (all fields). */
void imp_hdr_options_default(struct imp_hdr_options *opt);

struct imp_hdr_result {
        struct imp_image *value;         /* f32, C channels: V, radiance units */
        struct imp_image *variance;      /* f32, C channels: var(V) */
        struct imp_image *flags;         /* u8, C channels: IMP_HDR_* bits */
        size_t n_saturated, n_dark;      /* samples (pixel × channel) flagged */
};

/* Merges n >= 1 exposures (all the same size and channel count). Returns 0, -EINVAL on
 * bad arguments (sizes, exposure <= 0, unsupported pixel type), -ENOMEM. On success the
 * caller frees *ret with imp_hdr_result_done(); on failure *ret is untouched. */
int imp_hdr_merge(const struct imp_hdr_exposure *stack, size_t n, const struct imp_sensor *sensor,
                  const struct imp_hdr_options *opt, struct imp_hdr_result *ret);
void imp_hdr_result_done(struct imp_hdr_result *r);   /* frees members; accepts zeroed */

/* A u8 1-channel image, 1 where any channel of the merge's flags (u8, as in
 * imp_hdr_result.flags) has IMP_HDR_SATURATED, else 0: the saturation mask a decoder of
 * the merged values needs (structured-light.h imp_sl_frames.saturated). Caller frees *ret
 * with imp_image_free(). -EINVAL, -ENOMEM. */
int imp_hdr_saturated_mask(const struct imp_image *flags, struct imp_image **ret);

/* Electrons per DN at gain_db: gain_e_per_dn · 10^(−gain_db/20). */
double imp_hdr_e_per_dn(const struct imp_sensor *sensor, double gain_db);
