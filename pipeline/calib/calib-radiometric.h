/* Radiometric calibration: the camera's photon transfer (black level, linearity,
 * gain, read noise, saturation, full well) from flat-field and dark frames, and the
 * projector's gamma from phase-shift frames. Method: docs/calibration-lights.md.
 * Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <jansson.h>
#include "error.h"
#include "image.h"
#include "rig.h"

#define IMP_PTC_MAX_LEVELS 64

/* One exposure of a photon-transfer sequence: two flat frames (same exposure, same gain)
 * so that their difference removes the fixed pattern (PRNU, shading). */
struct imp_ptc_level {
        double exposure_us;
        const struct imp_image *a, *b;
};

struct imp_ptc_input {
        int bits;                     /* ADC bits (for the clip code 2^bits − 1) */
        double gain_db;               /* the frames' analogue gain; results are for 0 dB */
        int n_levels;
        const struct imp_ptc_level *levels;
        int n_darks;                  /* ≥ 1; ≥ 2 also gives read noise from the dark pair */
        const struct imp_image *const *darks;
        int roi[4];                   /* x, y, w, h; w = 0 → whole frame */
};

enum {
        IMP_PTC_SATURATION_FOUND = 1 << 0,   /* a level at or beyond saturation was seen */
        IMP_PTC_FEW_LEVELS = 1 << 1,         /* < 3 unsaturated levels: gain undetermined */
        IMP_PTC_READ_FROM_INTERCEPT = 1 << 2,/* no dark pair: read noise from the fit intercept */
        IMP_PTC_NONLINEAR = 1 << 3,          /* max nonlinearity > 1 % */
};

struct imp_ptc_point {
        double exposure_us, mean_dn, var_dn2;   /* mean above black; temporal variance */
        double clip_fraction;                   /* pixels at the ADC clip code */
        bool used;                              /* in the gain fit */
        bool saturated;
};

struct imp_ptc_result {
        struct imp_sensor sensor;     /* bits, black_level_dn, gain_e_per_dn (0 dB),
                                         read_noise_e, full_well_e filled; others 0 */
        double gain_sigma_e_per_dn;   /* 1σ of the gain from the fit */
        double read_noise_dark_e;     /* from the dark pair (NAN-free: 0 when absent) */
        double read_noise_fit_e;      /* from the mean–variance intercept (0 when negative) */
        double response_dn_per_us;    /* linear fit of mean vs exposure (unsaturated levels) */
        double response_offset_dn;
        double max_nonlinearity_pct;  /* max |residual| / max mean × 100 */
        double saturation_dn;         /* mean DN above black where saturation sets in; 0 if none */
        unsigned flags;               /* IMP_PTC_* */
        int n_points;
        struct imp_ptc_point points[IMP_PTC_MAX_LEVELS];
};

/* Photon transfer. Per level: mean of (a + b)/2 − black over the ROI, temporal variance
 * var(a − b)/2 (fixed pattern cancels). Black = mean of the dark frames. Saturation: the
 * first level (by exposure) whose variance falls below half the largest variance so far,
 * or with > 0.1 % of pixels at the clip code. Fit levels: exposure below the saturated one
 * and mean + 4 σ_spatial below the saturation mean. Model var = q + mean/g (quantisation
 * q₀ = 1/12 DN² included in q), weighted least squares with weights 1/var² (the sampling
 * variance of a variance), closed form. g = 1/slope (×10^(gain_db/20) to 0 dB);
 * read noise = g √(var_dark − 1/12) from the dark pair (var(d₁ − d₂)/2), else from the
 * intercept. Full well = saturation mean × g (ADC clip ⇒ a lower bound). When fewer than
 * 3 levels are usable, or the slope is ≤ 0, the flag IMP_PTC_FEW_LEVELS is set and the
 * gain is 1 with σ = ∞ → reported as 1e30 (finite). -EINVAL for mismatched frames.
 * *ret untouched on failure. */
int imp_radiometric_ptc(const struct imp_ptc_input *in, struct imp_ptc_result *ret, struct imp_error *err);

/* Photon transfer of camera `cam` (a camera of cs's rig) from cs: each flat frame paired
 * with the next unused one taken in the same light (camera, light, exposure, gain, pattern,
 * step), sorted by exposure; the dark frames ("dark" step) of the shortest dark exposure
 * (at most 64). Then imp_radiometric_ptc() over roi (x, y, w, h; w = 0: the whole frame).
 * ret_levels, ret_darks: the pairs and darks used (may be NULL). -ENODATA (err says how
 * many were found) without a pair or a dark, -EINVAL for pairs at different gains, the
 * reader's errors; *ret untouched on failure. */
struct imp_captureset;
int imp_radiometric_ptc_measure(const struct imp_captureset *cs, const char *cam, const int roi[4],
                                struct imp_ptc_result *ret, int *ret_levels, int *ret_darks, struct imp_error *err);

/* DN → radiometric value V (1.0 = white Lambertian at the reference irradiance): the
 * inverse of the simulator's sensor model, ignoring noise: (dn − black)·g_eff /
 * (quantum_scale · t). */
double imp_radiometric_dn_to_value(const struct imp_sensor *s, double exposure_us, double gain_db, double dn);

/* Projector gamma from phase-shift frames of one period: per camera pixel with white −
 * black > min_contrast, n_k = (I_k − black)/(white − black) = c_k^γ with c_k = (1 + cos(θ +
 * 2πk/N))/2, for the projector model emitted = b + (1 − b)·value^γ (b, the camera's gain and
 * black level, ambient light and albedo cancel). θ per pixel from the first Fourier
 * coefficient of the n_k, the N-step phase-shifting phase (c^γ is even about the crest, so
 * its fundamental keeps the phase). γ solves Σ n_k = Σ c_k^γ over all kept pixels and steps:
 * the data enter linearly, so zero-mean pixel noise does not bias γ (the former estimator,
 * mean_k n_k^{1/γ} = ½, did: n^{1/γ} is steepest in the pattern's troughs, −0.5 % on the
 * demo target). The right side falls with γ: bisection on [0.3, 5], 60 steps. N ≥ 3.
 * Returns 0, or 1 (a flag, not an error) with *ret_gamma the nearer bound when the root
 * lies outside; -ENOENT when no pixel has contrast, -EINVAL for bad arguments, -ENOMEM
 * (then the outputs are untouched). */
int imp_radiometric_projector_gamma(const struct imp_image *white, const struct imp_image *black,
                                    const struct imp_image *const *steps, int n_steps, double min_contrast,
                                    double *ret_gamma, int *ret_pixels);

/* The JSON report ("sensor" as in rig.json, the figures, flags, per-level points). */
json_t *imp_radiometric_ptc_to_json(const struct imp_ptc_result *r);
