/* Inside the mosaic library: the bounded cache of tile copies and the samplers. */
#pragma once
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include "copy-load.h"
#include "mosaic.h"

/* The input tiles each step of a pass needs (CSR: tiles of step s at tiles[off[s] .. off[s+1])).
 * The cache loads a step's tiles and, over budget, evicts the loaded tile whose next use is
 * farthest ahead (the order of the steps is known: Belady's rule), so a pass reads each tile
 * as few times as the budget allows; a tile is dropped after the last step that needs it, so
 * memory follows the working set (a band of tiles), not the painting. */
struct mosaic_cache {
        struct imp_painting *p;
        struct imp_copy *copies;      /* n_tiles; loaded ones have nx > 0 */
        size_t *last;                 /* n_tiles: the last step needing the tile (SIZE_MAX: none) */
        size_t budget, bytes;
        size_t loads, resident, max_resident;
        const size_t *off;
        const unsigned *tiles;
        size_t n_steps;
};
int mosaic_cache_init(struct mosaic_cache *c, struct imp_painting *p, size_t budget, const size_t *off,
                      const unsigned *tiles, size_t n_steps);
int mosaic_cache_step(struct mosaic_cache *c, size_t step, struct imp_error *err);
void mosaic_cache_done(struct mosaic_cache *c);

/* Height of tile t (copy c) at painting (x, y): bilinear over the mask (all four texels on
 * it), painting z (world z + dz). ret_ij: the fractional texel. false outside or off the mask. */
bool mosaic_height(const struct imp_mosaic_tile *t, const struct imp_copy *c, double x, double y, double *ret_h,
                   double ret_ij[2]);
/* Painting z of tile t's height h (copy frame) at its texel (fi, fj): the canvas-to-world z
 * plus the tile's offset. */
double mosaic_painting_z(const struct imp_mosaic_tile *t, double fi, double fj, double h);
/* The same averaged over (2r+1)² points one texel apart; false when any is missing. */
bool mosaic_height_box(const struct imp_mosaic_tile *t, const struct imp_copy *c, double x, double y, int r,
                       double *ret_h);
/* Overlap of the bboxes of tiles a and b shrunk by margin_mm: false when empty. */
bool mosaic_overlap(const struct imp_mosaic_tile *a, const struct imp_mosaic_tile *b, double margin_mm, double ret[4]);
/* Pairs of tiles whose bboxes overlap by at least min_mm in both axes, a < b. */
int mosaic_pairs(const struct imp_painting *p, double min_mm, unsigned (**ret)[2], size_t *ret_n);

/* The seam step the output mosaic shows, with truth (imp_mosaic_figures.seam_out_*; score.c,
 * docs/mosaic.md): bands just outside each neighbours' overlap, the jump of the mean height
 * error from one side to the other, against the same jump about a tile's centre. new() lays
 * the bands out from the tiles' bboxes under their current poses; add() takes every output
 * texel's error (mm) at painting (x, y); finish() sets the figures. */
struct mosaic_seam_score;
int mosaic_seam_score_new(const struct imp_painting *p, double pitch_mm, struct mosaic_seam_score **ret);
void mosaic_seam_score_add(struct mosaic_seam_score *s, double x, double y, double err_mm);
void mosaic_seam_score_finish(const struct mosaic_seam_score *s, struct imp_mosaic_figures *f);
void mosaic_seam_score_free(struct mosaic_seam_score *s);
