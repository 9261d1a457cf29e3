/* The processing service's job: a capture set in, the digital copy out (see process.c).
 * Used by `impasto process` and by impasto-worker. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include "boxes.h"
#include "btf.h"
#include "error.h"
#include "fuse.h"
#include "heightfield.h"
#include "normal-trust.h"
#include "photometric.h"

/* Every stage's options, with the values imp_process_options_default() sets; a caller
 * changes the fields it means to. */
struct imp_process_options {
        struct imp_heightfield_options heightfield;   /* canvas extraction and grid (pitch_mm
                                         0: the camera footprint); shadow_fill_px defaults
                                         to 80 here and is used only when photometric
                                         normals and fusion run: texels in projector shadow
                                         between the measured canvas and the frame join the
                                         mask (value 2) with heights integrated from their
                                         photometric normals; those whose normal the dome
                                         cannot determine, or steeper than 60°, are dropped
                                         (docs/geometry.md "Shadow fill") */
        struct imp_boxes_options boxes;               /* relief boxes: cell_px, delta_frac */
        struct imp_btf_sample_params btf_samples;     /* samples of photometric normals and
                                         the fit; march_step_texels = 0 casts no shadow ray */
        struct imp_btf_fit_params btf_fit;            /* max_iter, robust_passes */
        struct imp_photometric_params photometric;
        struct imp_fuse_params fuse;
        struct imp_normal_trust_params normal_trust;  /* σ_n and flags of normals one texel
                                                          cannot represent (normal-trust.h) */
        bool btf;                     /* fit the BTF when the set holds a dome sweep */
        int holdout_every;            /* > 0: every Nth dome light (sweep positions N−1,
                                         2N−1, …) is left out of the fit and re-rendered
                                         with the fitted copy for validation; 0: none */
        bool sl_gray_only;            /* decode the Gray code alone, ignoring phase frames */
        int threads;                  /* OpenMP threads for every stage (the calling
                                         thread's setting, restored on return); 0: as is */
        bool allow_incomplete;        /* process a set missing frames of its plan (else
                                         refused, -ENODATA); copy.json provenance.incomplete
                                         then says what is missing */
        bool photometric_normals;     /* refine the heightfield normals by photometric
                                         stereo on the dome sweep (pipeline/appearance/photometric.h)
                                         when it has >= 8 fitted lights; the BTF fit and
                                         heightfield.exr's nx, ny use the refined normals.
                                         Default true; false: the geometric normals */
        bool fuse_heights;            /* with photometric normals: heights from the
                                         triangulated positions (low frequencies) and the
                                         normals (high ones), pipeline/geometry/fuse.h; copy.json
                                         stages.fusion. Default true */
        /* A painting's tile (process-painting.h): the heightfield's frame search is off
         * (heightfield.whole_field) unless frame_search says otherwise, and a heightfield
         * pitch_mm <= 0 becomes the painting's pitch; copy.json provenance.painting_tile
         * says what marked the set, the pitch and where it came from. */
        enum { IMP_FRAME_SEARCH_AUTO = 0,     /* off for a painting's tile, on otherwise (default) */
               IMP_FRAME_SEARCH_ON, IMP_FRAME_SEARCH_OFF } frame_search;
        /* Progress per stage (may be NULL); called from the calling thread. */
        void (*progress)(void *userdata, const char *stage, size_t done, size_t total);
        void *userdata;
};

void imp_process_options_default(struct imp_process_options *o);
/* The fraction of a whole imp_process_capture() run done once STAGE reports done of total
 * (each stage's span is its rough share of the time on the demo scenes), never below
 * previous; a stage it does not know keeps previous. For an overall ETA. */
double imp_process_fraction(double previous, const char *stage, size_t done, size_t total);
/* Writes COPY_DIR/{heightfield.exr, boxes.json, rho_d.exr, rho_s.exr, lobe.exr,
 * fit-flags.exr (channel "flags": enum imp_btf_flag per texel), copy.json, previews/}.
 * With photometric_normals (and >= 8 dome lights in the fit), heightfield.exr's nx, ny are
 * the photometric normals and copy.json stages.photometric = {lights, refined,
 * resampled_samples, lanczos, kept_*, dev_deg_mean, dev_deg_median, sigma_deg_median,
 * rms_median, seconds}; with fuse_heights too, the heights are fused with them and
 * stages.fusion = {lambda, texels, gradient_rows, iterations, residual_rel, change_rms_um,
 * normal_agreement_deg_before, normal_agreement_deg_after, seconds}.
 * With holdout_every > 0, copy.json stages.btf.validation = {lights, texels, rmse,
 * rmse_per_light[]}: the held-out frames against the copy shaded per texel
 * (V = E·cos θl·f(v, l)), over mask texels the camera sees that are lit, not
 * self-shadowed (ray cast on the heightfield), not saturated and not too dark; rmse of
 * V/E, so 1.0 = a white Lambertian at normal incidence (-1 when no sample qualified).
 * copy.json "quality" = {verdict ok|degraded|unusable, reasons[], flagged_fraction,
 * flags {name: fraction of the canvas texels}, texels} (docs/copy-quality.md).
 * -ENODATA when the data hold no plausible canvas (placement refused): copy.json is still
 * written, with quality.verdict "unusable" and the reason, and no heightfield.
 * -EINVAL/-EBADMSG for a capture set that cannot be processed (message names
 * the file and what is wrong; copy.json says "unusable" with that message too), other
 * negative errnos for I/O and memory. */
int imp_process_capture(const char *capture_dir, const char *copy_dir,
                        const struct imp_process_options *o, struct imp_error *err);
