/* The projector's gamma and black level from a capture set of a flat white target under
 * white, black and N-step phase-shift frames: which frames to use, binning, the contrast
 * threshold, the estimate (imp_radiometric_projector_gamma()), its spread over blocks.
 * Method and measured accuracy: docs/calibration-lights.md. Library code: no logging. */
#pragma once
#include "captureset.h"
#include "error.h"

#define IMP_GAMMA_MIN_BLOCKS 4        /* fewer usable blocks: σ not measured (few_blocks) */
#define IMP_GAMMA_SIGMA_NONE 1e30     /* "infinite", finite in JSON */

struct imp_projector_gamma {
        double gamma, gamma_sigma, period_px, exposure_us, gain_db, min_contrast_dn;
        /* b of the projector model emitted = b + (1 − b)·value^γ: the median over the kept
         * bins of (black − s)/(white − s), s = sensor_black_dn */
        double black_level, sensor_black_dn;
        int status;                   /* imp_radiometric_projector_gamma(): 0, or 1 at the bound */
        int pixels, steps, axis, tile, blocks, clipped_px;
        int bin;                      /* pixels averaged bin × bin before the estimate */
};

/* Measures the gamma of the rig's projector seen by camera `cam` (a camera of cs's rig)
 * from the longest phase-shift period in cs; its black level above sensor_black_dn (NAN:
 * the rig's camera black level). Errors, with err naming what is wrong:
 * -ENOENT/-EINVAL/-ENODATA and the capture set's reader errors when the set lacks what is
 * needed (no projector, no phase set, frames missing, mismatched, colour, the projector
 * does not light the target); -ENOMEM; -EDOM when the estimate itself fails. *ret
 * untouched on failure. */
int imp_projector_gamma_measure(const struct imp_captureset *cs, const char *cam, double sensor_black_dn,
                                struct imp_projector_gamma *ret, struct imp_error *err);
