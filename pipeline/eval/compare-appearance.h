/* Appearance accuracy of a digital copy against simulator truth (issue #5 acceptance):
 * diffuse albedo error, lobe exponent error, NaN count over the BRDF maps, and the
 * held-out re-render RMSE that `impasto process --holdout` stored in copy.json. Library
 * code: no logging.
 *
 * Mapping: copy texel (i, j) with height h goes to the world through canvas_to_world
 * (P = M·(i·pitch, j·pitch, h, 1)); the truth (world frame = truth canvas frame) is read at
 * (P.x, P.y) on its grid (origin_mm, pitch_mm) — the same mapping as compare.c, without
 * the along-normal refinement, which moves the point by less than a truth texel for the
 * slopes of a painting. Only copy texels with heightfield mask = 1 whose truth point is
 * canvas (truth mask 1 at the needed samples) are compared.
 * ρd: truth bilinear (all four corners canvas); per texel and channel |ρd_copy − ρd_truth| /
 * ρd_truth where ρd_truth ≥ 0.05; the median over all (texel, channel) pairs.
 * k: the lobe exponent is invariant under the gauge (C, ρs) → (s·C, s^−k·ρs), so k is
 * compared directly; the truth's specular strength is taken as its peak albedo
 * ρs·(max|C|)^k, the copy's normalisation (docs/btf-fit.md). Texels whose truth peak ρs
 * (mean over RGB) ≥ 0.1, nearest truth sample, copy texel not flagged (fit-flags.exr:
 * MATTE, FEW_SAMPLES, HIDDEN, FILLED, MASKED, K_BOUND or LOBE_UNCERTAIN; without the file
 * every texel counts); |k_copy − k_truth| / k_truth, median. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <jansson.h>
#include "error.h"

struct imp_compare_appearance {
        double rho_d_rel_err_median;
        bool mono;                    /* copy is grey (mono camera): ρd compared with luminance */
        double rho_d_rel_err_p90;
        size_t rho_d_samples;         /* (texel, channel) pairs */
        double lobe_k_rel_err_median;
        double lobe_k_rel_err_p90;
        double rho_s_rel_err_median;  /* peak specular albedo, same texels as k */
        size_t lobe_texels;           /* glossy texels compared */
        size_t lobe_flagged;          /* glossy texels skipped because the copy flags them */
        double rerender_rmse;         /* from copy.json stages.btf.validation; -1 if absent */
        size_t rerender_lights, rerender_texels;
        size_t nan_count;             /* non-finite samples in rho_d/rho_s/lobe.exr */
};

/* Reads COPY_DIR/{copy.json, heightfield.exr, rho_d.exr, rho_s.exr, lobe.exr,
 * fit-flags.exr (optional)} and TRUTH_DIR/{truth.json, heightfield.exr, rho_d.exr,
 * rho_s.exr, lobe.exr}. Returns 0; -ENOENT (err names the file) when the copy has no
 * rho_d.exr; file errors as imp_json_load / imp_exr_read; -EBADMSG for a missing field or
 * channel or a size mismatch; -ENODATA when no texel could be compared for ρd. Figures
 * with nothing to compare (no glossy texel) are -1 (null in the JSON). *ret is untouched on
 * failure. */
int imp_compare_appearance(const char *copy_dir, const char *truth_dir,
                           struct imp_compare_appearance *ret, struct imp_error *err);

/* Adds the figures to obj (rho_d_rel_err_median, lobe_k_rel_err_median, rerender_rmse, …). */
void imp_compare_appearance_to_json(const struct imp_compare_appearance *r, json_t *obj);
