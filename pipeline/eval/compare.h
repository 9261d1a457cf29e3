/* Digital copy versus simulator truth: height rmse, normal error, canvas-mask IoU, NaN
 * count. Library code: no logging.
 *
 * Heights: every copy texel with mask = 1 is mapped to the world through canvas_to_world;
 * the truth surface is intersected along the copy's canvas normal through that point
 * (fixed-point iteration on the truth's bilinear world-z heightfield), which gives the
 * truth height in the copy's frame. The copy's height origin is the PCA plane through its
 * canvas points, an arbitrary offset, so the median of (copy − truth) over the compared
 * texels is subtracted before the rmse (reported as height_offset_mm). Texels whose world
 * point falls outside the truth grid or on the truth frame (truth mask 0) are not compared.
 * Normals: the copy normal (nx, ny, √(1−nx²−ny²)) rotated to the world vs the truth normal
 * at the same point: the normalised bilinear blend of the four surrounding truth samples'
 * normals, the normal the simulator shades that point with (not the nearest sample, which
 * is up to half a truth sample off); mean angle over the compared texels.
 * Mask IoU: over the truth grid samples; A = truth canvas mask, B = copy mask at the copy
 * texel nearest to the sample's world point; IoU = |A∩B| / |A∪B| (frame excluded since A
 * excludes it and a copy texel on the frame counts against B). */
#pragma once
#include <stddef.h>
#include <jansson.h>
#include "error.h"

struct imp_compare_result {
        double height_rmse_um;
        double height_offset_mm;      /* median (copy − truth) removed */
        double height_max_abs_um;     /* after offset */
        double normal_err_deg_mean;
        /* The same against truth normals band-limited to the copy's sampling: the truth
         * canvas heights smoothed by a Gaussian of σ = 0.375 copy pitch (response ½ at
         * the copy's Nyquist frequency; canvas samples only), then central differences,
         * blended bilinearly like the raw ones. A copy sampled at pitch p cannot hold
         * detail finer than 2p; what it can hold (the demo's 0.2 mm bristle grooves at
         * 4 texels per period) is kept. */
        double normal_err_deg_mean_bandlimited;
        double mask_iou;
        /* IoU over the canvas the rig can measure: truth canvas samples that the projector
         * lights and the camera sees (truth/correspondence-CAM.exr valid, and the seen depth
         * is this sample's), against the copy mask. −1 when the truth has no
         * correspondence map. The gap to mask_iou is canvas no single shot can measure. */
        double mask_iou_observable;
        size_t nan_count;             /* non-finite samples over all copy EXR channels */
        size_t n_compared;            /* texels in the height/normal figures */
        /* The same figures split by the copy's mask value (heightfield.h): texels filled
         * from the normals in projector shadow (mask 2) and measured ones (mask 1); RMSE
         * about the common median offset. 0 when there is none of the kind. */
        size_t n_filled;
        double height_rmse_um_filled, normal_err_deg_mean_filled;
        double height_rmse_um_measured, normal_err_deg_mean_measured;
        /* Honesty figures (docs/hard-cases.md). Placement: angle between the copy's canvas
         * normal and the truth canvas's base plane (the median slope over its samples). Frame texels: copy mask texels whose
         * world point lies on the truth frame, as a fraction of the copy mask texels over
         * the truth grid. Over the compared texels whose heightfield.exr flags are 0 (all
         * of them when the copy has no flags channel): the fraction whose height error
         * (after the median offset) exceeds 3 σ, whose normal error exceeds 3 σ_n
         * (sigma_n_deg; −1 without that channel, 0 when no texel is unflagged), the
         * largest normal error and the count above 10°; flagged_fraction over the compared
         * texels. */
        double placement_deg;
        double frame_texel_fraction;
        size_t n_unflagged;
        double beyond_3sigma_height, beyond_3sigma_normal;
        double unflagged_normal_err_deg_max;
        size_t unflagged_normal_over_10deg;
        double flagged_fraction;
        /* The heights promised: over the measured texels (mask 1) without a height flag
         * (saturated, filled, frame_adjacent, phase_rejected), whatever their other flags
         * (a normal_uncertain texel's height is still within its σ_h), the fraction whose
         * height error (after the median offset) exceeds 3 σ_h (0 when there is none). */
        size_t n_height_promised;
        double beyond_3sigma_height_promised;
        /* Over every compared texel with a σ_n, flagged or not: the fraction whose normal
         * error exceeds 3 σ_n (−1 without sigma_n_deg): what σ_n says where no normal is
         * promised. */
        double beyond_3sigma_normal_all;
};

/* Reads COPY_DIR/{copy.json,heightfield.exr} and TRUTH_DIR/{truth.json,heightfield.exr}.
 * Returns 0; file errors as imp_json_load / imp_exr_read with err filled; -EBADMSG when a
 * required field or channel is missing; -ENODATA when no texel could be compared (the
 * figures are then left at 0 and the result is not written). */
/* The copy's grid (copy.json) and the truth's (truth.json): what both comparisons need to
 * map copy texels onto truth samples. Pitches are checked > 0. *ret_copy_json, when not
 * NULL, gets copy.json for further figures. */
struct imp_compare_grids {
        double canvas_to_world[16], copy_pitch;
        long long copy_nx, copy_ny;
        double truth_pitch, truth_origin[2];
        long long truth_nx, truth_ny;
};
int imp_compare_load_grids(const char *copy_dir, const char *truth_dir, json_t **ret_copy_json,
                           struct imp_compare_grids *ret, struct imp_error *err);

int imp_compare_dirs(const char *copy_dir, const char *truth_dir, struct imp_compare_result *ret,
                     struct imp_error *err);

json_t *imp_compare_result_to_json(const struct imp_compare_result *r);
