/* Relief classification into boxes (seed §4.3): heights above δ0 are significant relief;
 * small connected components of it are dropped as noise; the heightfield grid is cut into
 * n×n-texel cells and every cell holding at least one significant texel gets a box, with
 * the height hmax and texel (umax, vmax) of its highest point. Library code: no logging.
 *
 * Heights are taken relative to the canvas base h_ref = the 5th percentile (ref_percentile)
 * of the heights over the canvas mask — robust to a few deep holes, unlike the minimum, and
 * not pulled up by the relief, unlike the mean or the PCA plane (height 0). H = max height −
 * h_ref; δ0 = max(delta_frac · H, noise_k · σ̃) with σ̃ the median height σ of the measured
 * texels, so that relief within the noise (a flat canvas: H is then only the noise's
 * extreme) makes no boxes; a texel is significant when height − h_ref > δ0. In file
 * units: the bump plane sits at h_ref + δ0, boxes span [h_ref + δ0, h_ref + H]. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <jansson.h>
#include "error.h"
#include "heightfield.h"

struct imp_boxes_options {
        double delta_frac;            /* δ0 / H; default 0.3 (seed: 0.2–0.4) */
        int cell_px;                  /* n, texels per cell side; default 20 */
        size_t min_component_px;      /* 8-connected components smaller than this are
                                         dropped; default 8 */
        double ref_percentile;        /* h_ref percentile; default 5 */
        double noise_k;               /* δ0 floor in median height σ; default 6 (h_ref, the 5th
                                         percentile, sits ≈ 1.6σ below a flat canvas: a texel
                                         of pure noise is then > 4σ above its mean) */
};
void imp_boxes_options_default(struct imp_boxes_options *opt);

struct imp_box {
        int cell_u, cell_v;           /* cell indices */
        int u0, v0, w, h;             /* texel rectangle of the cell (clipped to the grid) */
        float hmax_mm;                /* highest canvas height in the cell (file units) */
        int umax, vmax;               /* its texel */
        size_t n_significant;         /* significant texels in the cell */
};

struct imp_boxes {
        int cell_px, cells_u, cells_v;
        int nx, ny;                   /* grid the boxes refer to */
        double pitch_mm;
        double h_ref_mm, H_mm, delta0_mm;   /* see above; H and δ0 relative to h_ref */
        double delta0_floor_mm;       /* noise_k · σ̃ (0 without σ) */
        bool below_noise;             /* the floor, not delta_frac · H, set δ0 */
        size_t n_significant;         /* texels left after component removal */
        size_t n_components, n_components_removed;
        size_t n_boxes;
        struct imp_box *boxes;        /* owned, row-major by cell */
        uint8_t *significant;         /* nx·ny: the cleaned mask Mv (owned) */
};

/* Classifies. Returns 0; -EINVAL on bad arguments; -ENODATA when the mask is empty;
 * -ENOMEM. A canvas with H = 0 (perfectly flat) yields zero boxes, not an error. On success
 * the caller frees *ret with imp_boxes_done(); on failure *ret is untouched. */
int imp_boxes_classify(const struct imp_heightfield *hf, const struct imp_boxes_options *opt,
                       struct imp_boxes *ret);
void imp_boxes_done(struct imp_boxes *b);   /* frees members; accepts zeroed */

json_t *imp_boxes_to_json(const struct imp_boxes *b);
/* Writes boxes.json crash-safely. */
int imp_boxes_save(const struct imp_boxes *b, const char *path, struct imp_error *err);
