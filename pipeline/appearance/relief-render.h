/* Hybrid rendering of a digital copy (seed §5): the negligible relief as a bump-mapped
 * plane shifted to δ0 (§5.1), the significant relief by relief mapping inside the boxes
 * with a linear then a binary search (§5.2), chosen per box by the view-dependent α of
 * §5.3 and blended, shaded with the per-texel Lafortune BRDF under a near-field point
 * light (§5.4). CPU, one ray per camera pixel. Library code: no logging.
 *
 * Frames: the copy lives in its canvas frame (texel (i, j) at (i·pitch, j·pitch), height z
 * towards the viewer); canvas_to_world must be rigid. Texel (i, j) owns the square
 * [(i − ½)·pitch, (i + ½)·pitch) × [(j − ½)·pitch, (j + ½)·pitch). Normals and BRDFs are
 * looked up at the nearest texel; heights inside a box are bilinear, clamped to the box's
 * texels and to the box floor δ0. A box spans its texel squares in x, y and [δ0, top] in z,
 * top = the highest height among its texels (at least its hmax_mm). */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include "image.h"
#include "lafortune.h"
#include "rig.h"

enum imp_relief_mode {
        IMP_RELIEF_BUMP_ONLY,         /* plane at δ0 only (α = 0 for every box) */
        IMP_RELIEF_RELIEF_ALL,        /* every box relief-mapped (α = 1) */
        IMP_RELIEF_ADAPTIVE,          /* α per box from eq. 2 */
};

struct imp_relief_box {
        int u0, v0, w, h;             /* texel rectangle, inside the grid; boxes must not
                                         overlap (imp_boxes cells do not) */
        float hmax_mm;                /* height of the box's highest point I (canvas frame) */
        int umax, vmax;               /* texel of I */
};

/* The copy in memory. Arrays are borrowed: they must outlive any scene built on them. */
struct imp_relief_copy {
        int nx, ny;                   /* texels */
        double pitch_mm;
        const float *height_mm;       /* nx·ny, row-major (j·nx + i), canvas frame */
        const float *normal_x, *normal_y;   /* nx·ny; nz = √(1 − nx² − ny²) recomputed
                                         (a longer (nx, ny) is renormalised, nz = 0) */
        const struct imp_lafortune *brdf;   /* nx·ny */
        const struct imp_relief_box *boxes; /* may be NULL when n_boxes = 0 */
        size_t n_boxes;
        double delta0_mm;             /* bump plane height δ0 (canvas frame) */
        double canvas_to_world[16];   /* row-major 4×4, maps (i·pitch, j·pitch, h, 1) */
};

struct imp_relief_options {
        enum imp_relief_mode mode;
        /* eq. 2: α = 0 if K·r < εmin, 1 if K·r > εmax, linear between. K <= 0 means
         * "K = the view's fx", which makes K·r roughly the box's parallax in pixels. */
        double K, eps_min, eps_max;   /* defaults 0 (→ fx), 0.5, 2.0 */
        bool shadows;                 /* march towards the light over the relief; default off */
        double linear_step_texels;    /* linear search step, in texels along the ray's
                                         footprint; default 1 (0.05..16) */
        int binary_steps;             /* binary refinement iterations; default 8 (0..30) */
};
void imp_relief_options_default(struct imp_relief_options *opt);

/* Render flags (bits of imp_relief_stats.flags). */
enum {
        IMP_RELIEF_CAMERA_BELOW = 1 << 0,   /* the camera is on or below the bump plane: the
                                               frame is all zeros (α 0), nothing is rendered */
};

struct imp_relief_stats {
        unsigned flags;
        size_t n_boxes_drawn;         /* boxes with α > 0 */
        size_t n_boxes_blended;       /* boxes with 0 < α < 1 */
        size_t n_pixels_relief;       /* pixels whose ray hit the relief of a drawn box */
        size_t n_pixels_hit;          /* pixels that see the copy at all */
};

struct imp_relief_scene;

/* Validates the copy and builds the lookup structures (box cell grid, box tops). Returns
 * -EINVAL for bad sizes, a non-rigid transform, a box outside the grid or overlapping
 * another, or a non-finite/negative value (height, normal, BRDF, δ0); -ENOMEM. The scene
 * borrows the copy's arrays. Caller frees *ret with imp_relief_scene_free(). */
int imp_relief_scene_new(const struct imp_relief_copy *copy, struct imp_relief_scene **ret);
void imp_relief_scene_free(struct imp_relief_scene *s);   /* accepts NULL */

/* α of every box (n_boxes floats) for this view and mode (eq. 2 with r = |IB| / |CI|, B the
 * projection of I along the view direction onto the bump plane). A box whose I is seen
 * parallel to the plane gets α = 1; a camera on or below the plane gives 0 everywhere and
 * returns IMP_RELIEF_CAMERA_BELOW. Returns flags >= 0, or -EINVAL on bad options. */
int imp_relief_box_alpha(const struct imp_relief_scene *s, const struct imp_pinhole *view,
                         const struct imp_relief_options *opt, float *ret_alpha);

/* Renders V = E·cos θl·f(v, l) per pixel into out (caller-allocated f32, the view's size, 1
 * or 3 channels; 1 channel renders the BRDF's and light's channel 0). Pixels that miss the
 * copy are 0. ret_alpha (NULL or f32, 1 channel, the view's size) receives the α of the box
 * whose relief the pixel's ray hit (0 when none). Every output value is finite. Returns 0 or
 * -EINVAL (bad options, sizes or types); ret_stats (may be NULL) gets the figures. */
int imp_relief_render(const struct imp_relief_scene *s, const struct imp_pinhole *view,
                      const struct imp_rig_light *light, const struct imp_relief_options *opt,
                      struct imp_image *out, struct imp_image *ret_alpha,
                      struct imp_relief_stats *ret_stats);
