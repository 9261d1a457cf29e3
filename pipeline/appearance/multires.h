/* Multi-resolution, view-dependent texture of a canvas captured in several shots at
 * different distances (seed 003, Grimm & Kowalski, §4–7): hierarchical cell layers, the
 * depth of each view, view-independent colour per cell per layer, n×n hemisphere arrays of
 * view-dependent colour per cell, the fill/filter rules, hat-function reconstruction, and
 * the EXR pyramid on disk. Library code: no logging. See docs/multires.md.
 *
 * Canvas frame (pipeline/model/rig.h): x along the width, y along the height, z out of the paint.
 * For this stage the canvas is the plane z = 0 over [0, width_mm] × [0, height_mm].
 *
 * Cells: layer L splits the canvas into square cells of side base_cell_mm / 2^L, cell (i, j)
 * covering x ∈ [i·c, (i+1)·c), y ∈ [j·c, (j+1)·c); layer 0 has ceil(W/c0) × ceil(H/c0)
 * cells and every layer doubles both counts, so a cell of layer L is exactly the union of
 * four cells of layer L+1 (seed §4.1). Cells reaching past the canvas edge hold only the
 * part inside it.
 *
 * Depth of a view (seed §4.2): the (fractional) layer whose cells cover exactly one pixel,
 * d = log2(base_cell_mm / p), p = the RMS side of the view's pixel footprints on the canvas
 * (sqrt of the mean footprint area over the pixels that see the canvas).
 *
 * Hemisphere parameterisation (seed appendix B): ω = unit vector from the surface point
 * towards the viewer (canvas frame, ω_z > 0 in front of the paint). The seed's local frame
 * has the normal along +y and the s-derivative along +x; the rotation taking the canvas
 * frame onto it maps (x, y, z)_canvas → (x, z, −y)_seed, so
 *     (s, t) = (x_seed, z_seed) · (−1 / (y_seed + 1)) = (−ω_x, ω_y) / (1 + ω_z),
 * a stereographic projection: the upper hemisphere fills the unit disc, ω = +z maps to
 * (0, 0). Element (a, b) of an n×n array is centred at s = −1 + (a + ½)·2/n,
 * t = −1 + (b + ½)·2/n. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include "image.h"
#include "error.h"
#include "rig.h"

#define IMP_MULTIRES_MAX_LAYERS 16
#define IMP_MULTIRES_MAX_HEMI_N 32

struct imp_multires_options {
        double width_mm, height_mm;   /* canvas extent; required, > 0 */
        double base_cell_mm;          /* layer-0 cell side; default 25 */
        int n_layers;                 /* 0 = auto: ceil(finest view depth) + 1 */
        int supersample;              /* k×k sub-pixels per pixel when mapping pixels to
                                         cells (seed: double-size id image, k = 2); default 2 */
        double feather_px;            /* mask fades from 0 at the image border to 1 this many
                                         pixels inside, so overlapping views blend without a
                                         seam (seed: alpha mask); default 16 */
        int hemi_n;                   /* n of the n×n hemisphere arrays; 0 = none; default 8 */
        int hemi_layer;               /* finest layer carrying hemisphere arrays; -1 = auto:
                                         the finest whose arrays (layers 0..L) fit the budget */
        size_t hemi_budget_bytes;     /* default 16 MiB */
        double fade_radius;           /* reach of a view's fade hat in (s, t); default 0.35 */
        float empty_value;            /* colour of cells no view reaches (seed: grey); 0.5 */
        int block_cells;              /* side of the cell blocks worked on at once; 256 */
};
void imp_multires_options_default(struct imp_multires_options *opt);

/* One shot. The image is linear f32 with 1 (mono, replicated to RGB) or 3 channels; the
 * optional mask is f32 with 1 channel, 0..1, same size (0 = ignore the pixel). Non-finite
 * pixels are ignored and counted. The camera is the view's pinhole with its pose. */
struct imp_multires_view {
        const struct imp_image *image;
        const struct imp_image *mask;
        struct imp_pinhole camera;
};

/* The depth metric alone: fills *ret_depth and *ret_footprint_mm (the RMS pixel side on the
 * canvas). -EINVAL on bad arguments, -ENODATA when no pixel of the view sees the canvas. */
int imp_multires_view_depth(const struct imp_multires_options *opt,
                            const struct imp_multires_view *view, double *ret_depth,
                            double *ret_footprint_mm);

struct imp_multires;   /* opaque */

/* Builds the pyramid (seed §6): every view deposits into the two layers bracketing its
 * depth (weights 1−(d−i) and d−i), hemisphere arrays at min(d, hemi_layer); one-cell holes
 * are filled from their neighbours; missing data in a layer is filled from the filtered
 * finer layer (seed §6.2), then what is still missing from the coarser layer through the
 * hat function (seed footnote 2); cells no view reaches keep empty_value with coverage 0.
 * Memory: the layers themselves plus one block of block_cells² accumulators.
 * Returns 0; -EINVAL on bad options or views; -ENODATA when no view sees the canvas;
 * -ENOMEM. Caller frees *ret with imp_multires_free(); *ret untouched on failure. */
int imp_multires_build(const struct imp_multires_options *opt,
                       const struct imp_multires_view *views, int n_views,
                       struct imp_multires **ret);
void imp_multires_free(struct imp_multires *mr);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_multires *, imp_multires_free);
#define _cleanup_multires_ _cleanup_(imp_multires_freep)

struct imp_multires_layer_info {
        int nx, ny;                   /* cells */
        double cell_mm;
        size_t n_direct;              /* cells with data deposited by a view at this layer */
        size_t n_filled;              /* cells whose data came only from other layers/holes */
        size_t n_empty;               /* coverage 0 */
        bool has_hemi;
};
int imp_multires_n_layers(const struct imp_multires *mr);
int imp_multires_hemi_n(const struct imp_multires *mr);
int imp_multires_hemi_layer(const struct imp_multires *mr);   /* -1 when none */
int imp_multires_layer_info(const struct imp_multires *mr, int layer,
                            struct imp_multires_layer_info *ret);
/* Depth and footprint computed for view v at build time (not kept by load). */
int imp_multires_view_stats(const struct imp_multires *mr, int v, double *ret_depth,
                            double *ret_footprint_mm);
size_t imp_multires_nonfinite_px(const struct imp_multires *mr);
size_t imp_multires_bytes(const struct imp_multires *mr);     /* resident data */

/* One cell: view-independent colour, coverage (0 = no data reached it; otherwise the best
 * mask value of the data it holds) and direct weight (sum of depth·mask weights deposited
 * at this layer, clamped to 1; 0 when its value was filled). NULL out-params are skipped. */
int imp_multires_cell(const struct imp_multires *mr, int layer, int i, int j,
                      float ret_rgb[3], float *ret_coverage, float *ret_direct);
/* One hemisphere element (a, b) of a cell: colour (the independent colour blended in where
 * the view weight α < 1, seed §6.1) and α-weight before clamping. -ENODATA when the layer has
 * no hemisphere arrays. */
int imp_multires_hemi(const struct imp_multires *mr, int layer, int i, int j, int a, int b,
                      float ret_rgb[3], float *ret_weight);

/* ω (unit, towards the viewer, canvas frame) → (s, t); ω_z ≤ 0 is clamped to the rim. */
void imp_multires_dir_to_st(const double omega[3], double ret_st[2]);

/* Reconstruction (seed §7): the colour at canvas point (x, y) for an image of depth `depth`
 * seen from `eye_mm` (NULL = view-independent). Hat functions over the cells of the two
 * bracketing layers (weighted by coverage), blended linearly by depth; within a cell, hat
 * functions over the hemisphere elements at (s, t) of the direction to the eye, clamped to
 * the array edge. Depths finer than the hemisphere layer use its arrays. Returns 0 and the
 * colour (empty_value and coverage 0 where nothing reached); -EINVAL on bad arguments. */
int imp_multires_sample(const struct imp_multires *mr, double x_mm, double y_mm,
                        const double eye_mm[3], double depth, float ret_rgb[3],
                        float *ret_coverage);

/* The pyramid on disk: DIR/index.json, DIR/layer-L.exr (float; channels R, G, B, coverage,
 * direct; row j = cell row j, y growing with the row) and DIR/hemi-L.exr for the layers with
 * hemisphere arrays ((nx·n) × (ny·n) pixels, cell (i, j) element (a, b) at pixel
 * (i·n + a, j·n + b); channels R, G, B, weight). DIR is created. */
int imp_multires_save(const struct imp_multires *mr, const char *dir, struct imp_error *err);
/* -ENOENT when DIR/index.json is missing, -EBADMSG on an inconsistent pyramid. */
int imp_multires_load(const char *dir, struct imp_multires **ret, struct imp_error *err);
