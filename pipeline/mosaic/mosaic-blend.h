/* Inside the mosaic library: the output grid and one output tile. */
#pragma once
#include <stdint.h>
#include <jansson.h>
#include "lafortune.h"
#include "mosaic-internal.h"

/* Output texel (I, J) sits at painting (I·pitch, J·pitch); output tile (C, R) holds texels
 * [C·tile_px, …) × [R·tile_px, …), clipped to the grid. */
struct mosaic_grid {
        int nx, ny, tile_px, tiles_x, tiles_y;
        double pitch_mm, feather_mm;
        double extent_mm[2], edge_band_mm;   /* the painting; IMP_MOSAIC_UNCOVERED_EDGE's band */
};

struct mosaic_out {
        int nx, ny, i0, j0;
        double origin_mm[2];          /* canvas_to_world translation: texel (0, 0) in the painting */
        float *height, *nx_, *ny_, *sigma;
        uint8_t *mask;
        uint16_t *flags;              /* texel flags (quality.h): heightfield.exr */
        uint16_t *fit_flags;          /* the BRDF fit's flags (btf.h): fit-flags.exr */
        struct imp_lafortune *brdf;
        size_t uncovered[IMP_MOSAIC_UNCOVERED_N];   /* texels left off the mask, by cause */
        double edge_depth_mm;         /* farthest of the EDGE ones from the painting's border */
};
int mosaic_out_alloc(struct mosaic_out *t, int nx, int ny);   /* zeroed arrays */
void mosaic_out_done(struct mosaic_out *t);
/* Blends output tile (col, row) from the input tiles in[0..n_in) (loaded in c). */
int mosaic_blend_tile(const struct imp_painting *p, const struct mosaic_cache *c, const unsigned *in, size_t n_in,
                      const struct mosaic_grid *g, int col, int row, struct mosaic_out *o);
/* DIR/heightfield.exr, the BRDF maps, fit-flags.exr and copy.json (placed in the painting). */
int mosaic_out_write(const struct mosaic_out *o, const struct mosaic_grid *g, const char *dir, struct imp_error *err);
/* Pass 2: boxes.json of every output tile with global h_ref, δ0 (cells aligned to the grid). */
int mosaic_boxes_write(const struct mosaic_grid *g, const char *out, double h_ref, double delta0, double H, int cell_px,
                       size_t *ret_boxes, struct imp_error *err);
/* Pass 3: the pyramid OUT/pyramid/L/R-C.exr; returns the number of levels written (≥ 0). */
int mosaic_pyramid_write(const struct mosaic_grid *g, const char *out, json_t **ret_levels, struct imp_error *err);
