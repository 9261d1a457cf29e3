/* Canvas extraction and heightfield (seed §4.2, §5): range image → robust canvas plane
 * (RANSAC, then PCA on its inliers, checked against the rig's canvas pose; the seed's first PCA
 * over every point is pulled off the canvas by deep frames, oblique walls and outliers)
 * → points far off that plane excluded (frame tops, walls) → Sobel of the height → seed fill
 * from the image centre stopped at high gradient → a flush frame cut off at its albedo step
 * (frame-edge.h, options.albedo) → erosion → the canvas points' base plane → resampling onto a regular grid in the canvas frame by rasterising
 * the range-image mesh (no invented surface across holes) → normals averaged over the
 * 8-neighbourhood triangles. Library code: no logging.
 *
 * Canvas frame: z = the normal of the canvas's base plane (the PCA plane of the canvas
 * points at or below their median height, twice: relief standing on the canvas does not
 * tilt it) turned towards the camera (height grows towards
 * the viewer), x = world x projected on the plane (world y when the plane is nearly
 * perpendicular to world x), y = z × x; origin = the canvas points' minimum corner in
 * (x, y), at height 0 = that plane through the canvas points' centroid. Texel (i, j)
 * sits at canvas (i·pitch, j·pitch); canvas_to_world maps (i·pitch, j·pitch, h, 1). */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <jansson.h>
#include "error.h"
#include "triangulate.h"

/* The automatic pitch is at most this × the camera footprint on the canvas plane: a grid
 * at the footprint itself beats with the range mesh's vertices (a 300 × 200 painting's tile
 * at 0.1 mm: 10.2 µm height RMSE at 1.00 ×, 8.6 µm at 1.01 × and 1.02 ×, 8.9 µm at 1.05 ×). */
#define IMP_HF_PITCH_NOISE_CAP 1.02

struct imp_heightfield_options {
        /* Seed fill stops at pixels whose Sobel gradient magnitude (height change per range
         * pixel, Sobel normalised by 1/8) exceeds gradient_rel × (h99 − h1), h1/h99 the 1st
         * and 99th percentiles of the first-PCA height over all valid points. A frame
         * standing a few mm off a canvas whose relief spans a fraction of that stops the
         * fill; paint relief does not. Default 0.25. */
        double gradient_rel;
        double gradient_floor_mm;     /* threshold never below this (noise-free flat data);
                                         default 1e-3 mm per pixel */
        int erode_px;                 /* erosion of the filled mask (8-neighbour steps); default 1 */
        double pitch_mm;              /* grid pitch; <= 0: the median 3-D distance between
                                         neighbouring canvas points, at most 1.02 × the camera
                                         footprint on the canvas plane (footprint_mm below;
                                         range noise grows the former, not the latter) */
        double max_edge_factor;       /* mesh triangles with an edge longer than this × the
                                         footprint are not rasterised (holes stay holes);
                                         default 4 */
        bool skip_extraction;         /* keep every valid point (no seed fill / erosion) */
        /* A painting's tile (docs/painting.md): the field of view lies inside the paint, no
         * frame can be in it, so the frame search is off: the canvas is every valid point
         * within relief_max_mm of the robust plane (outliers still dropped), with no seed
         * fill, gradient or slope barrier, albedo trim, erosion or shadow fill; the base
         * plane and the placement checks run as usual. Default false. */
        bool whole_field;
        /* Additions for issue #4 (docs/geometry.md has the measured trade-offs). */
        double slope_max;             /* the fill does not cross between 4-neighbours whose
                                         first-PCA height differs by more than step_min_mm
                                         and by more than slope_max × their in-plane
                                         distance: a frame wall seen obliquely spreads over
                                         many pixels (small Sobel value) but is near-vertical
                                         in the world. <= 0: off. Default 3 */
        double step_min_mm;           /* see slope_max; default 0.1 mm */
        bool keep_holes;              /* false (default): holes enclosed by the filled mask
                                         (shadow gaps behind steep relief) are filled before
                                         the erosion, so erosion eats only the outer rim; the
                                         holes themselves stay holes in the heightfield */
        int normal_radius;            /* 0: vertex normals from the 8-neighbourhood triangles
                                         of the range mesh (the seed's method); r > 0: normal
                                         of the least-squares plane through the heightfield
                                         texels of the (2r+1)² window (mask only), which
                                         averages height noise at the cost of detail finer
                                         than the window. Default 0: on the demo scene every
                                         r > 0 measured worse (docs/geometry.md) */
        /* Projector-shadow fill (docs/geometry.md "Shadow fill"). > 0: texels the
         * range mesh does not cover that lie between the measured canvas and the frame are
         * added to the mask with value IMP_HF_MASK_FILLED: the grid is padded by this many
         * texels, the frame is every non-canvas point higher than the canvas's 99th height
         * percentile plus its relief span (1st..99th), splatted and dilated by one texel;
         * uncovered texels not reachable from the padded grid's border without crossing the
         * canvas or the frame, in a region that touches the frame, within this many texels
         * (4-neighbour steps) of a measured texel, are filled. A frame with a gap (the region
         * reaches the border) or no frame fills nothing; holes inside the canvas away from
         * the frame stay holes. Filled texels get the height of the nearest measured texel,
         * normal (0, 0, 1) and σ = hypot(σ_nearest, d·pitch·tan 2°) (d in texels): their
         * shape has to come from normals (imp_fuse_heights with mask value 2). 0: off
         * (default; imp_process turns it on when photometric normals and fusion run). */
        int shadow_fill_px;
        /* Placement (robust plane and its checks). The canvas lies near the plane through
         * the rig's world origin with normal expected_normal (world = canvas frame in
         * rig.json: +z out of the paint); the camera looks at it from the front. */
        double expected_normal[3];    /* unit; default (0, 0, 1) */
        double max_tilt_deg;          /* refuse a canvas plane tilted more than this from
                                         expected_normal; default 40 */
        double max_view_deg;          /* refuse a canvas seen more obliquely than this (angle
                                         between its normal and the ray to the camera);
                                         default 75 */
        double plane_tol_mm;          /* RANSAC inlier band about the plane; default 0.5 */
        double relief_max_mm;         /* points farther than this from the robust plane are
                                         never canvas (frame tops, walls): they stop the fill;
                                         default 3 */
        double min_canvas_frac;       /* refuse when the canvas holds fewer than this
                                         fraction of the valid range points; default 0.02 */
        size_t min_canvas_points;     /* ... or fewer than this many; default 200 */
        /* Per range pixel (w·h) an albedo-like image of the scene (the structured-light
         * decoder's direct component) or NULL: with it, a frame flush with the canvas (or a
         * fraction of a millimetre off it), which the height cannot separate, is cut off
         * the seed fill at the straight albedo step along the canvas's sides
         * (frame-edge.h). Not owned; default NULL. */
        const float *albedo;
};
void imp_heightfield_options_default(struct imp_heightfield_options *opt);

/* Quality flags (bits). */
enum {
        IMP_HF_SEED_MOVED   = 1 << 0, /* the centre pixel was invalid or steep; nearest usable used */
        IMP_HF_PLANE_WEAK   = 1 << 1, /* the two smallest PCA eigenvalues are within 1 %:
                                         the plane orientation is not determined by the data
                                         (e.g. points along a line); the normal is still a unit
                                         vector */
        IMP_HF_STEP_RAISED  = 1 << 2, /* the seed fill reached fewer than 5 % of the valid
                                         points: step_min was doubled until it spread (a
                                         Gray-only staircase), or the slope barrier dropped */
        IMP_HF_PLANE_NO_CONSENSUS = 1 << 3, /* every RANSAC hypothesis was degenerate (points
                                         on a line): the first PCA plane was used */
        IMP_HF_FRAME_TRIMMED = 1 << 4, /* a flush frame band was cut off by its albedo step */
};

/* Mask values. */
enum {
        IMP_HF_MASK_MEASURED = 1,     /* covered by the triangulated range mesh */
        IMP_HF_MASK_FILLED   = 2,     /* shadow fill: no position, shape from the normals */
};

struct imp_heightfield {
        int nx, ny;                   /* texels */
        double pitch_mm;
        float *height_mm;             /* nx·ny, row-major (j·nx + i); 0 where mask = 0 */
        float *nx_, *ny_;             /* normal x, y in the canvas frame; 0 where mask = 0 */
        float *sigma_mm;              /* height σ (range σ projected on the normal); 0 off mask */
        uint8_t *mask;                /* 0 off the canvas; IMP_HF_MASK_MEASURED; IMP_HF_MASK_FILLED */
        uint16_t *texel_flags;        /* IMP_TEXEL_* bits (quality.h); 0 off the mask */
        float *sigma_n_deg;           /* normal σ, degrees (rms angle): range noise over the
                                         footprint and the spread of the mesh normals around
                                         the vertex (detail the footprint cannot resolve);
                                         0 off the mask */
        double canvas_to_world[16];   /* row-major 4×4 */
        /* figures */
        size_t n_range_points, n_canvas_points, n_mask_texels;
        size_t n_filled_texels;       /* of n_mask_texels, IMP_HF_MASK_FILLED */
        double frame_height_mm;       /* shadow fill: frame threshold used (0 when off) */
        double step_min_used_mm;      /* the slope barrier's step_min in the end (+inf: off) */
        double plane_rms_mm;          /* rms height about the canvas plane */
        double gradient_threshold_mm; /* the Sobel threshold that was used */
        double footprint_mm;          /* camera footprint on the canvas plane: median distance
                                         between neighbouring canvas pixels' viewing rays where
                                         they meet the plane (range noise does not grow it) */
        double neighbour_mm;          /* median 3-D distance between neighbouring canvas points
                                         (grows with range noise; the mesh's edge tests use it) */
        double plane_tilt_deg;        /* canvas normal to the rig's expected normal */
        double plane_view_deg;        /* canvas normal to the ray to the camera */
        double ransac_inlier_frac;    /* valid points within plane_tol_mm of the robust plane */
        size_t n_excluded_points;     /* valid points beyond relief_max_mm (frame, walls) */
        size_t n_frame_trimmed;       /* fill points cut off as a flush frame (albedo step) */
        size_t n_relief_points;       /* points the seed fill did not reach that joined the
                                         canvas: ground pockets between high paint and what
                                         lies inside their convex hull (high relief) */
        size_t n_outline_texels;      /* texels inside the convex hull of the mask: less
                                         n_mask_texels, the holes within the canvas's outline
                                         (shadowed or unmeasured relief) */
        double frame_trim_mm[4];      /* per side (−u, +u, −v, +v) the band cut off, mm */
        unsigned flags;               /* IMP_HF_* */
};

/* Builds the heightfield. Returns 0; -EINVAL on bad arguments; -ENODATA when fewer than 3
 * valid points, no usable seed or an empty canvas (the data cannot determine a canvas), or
 * the placement is not plausible (canvas plane more than max_tilt_deg off the rig's canvas
 * normal, seen more obliquely than max_view_deg, fewer canvas points than
 * min_canvas_frac / min_canvas_points): then err (may be NULL) names the cause;
 * -E2BIG when the grid would exceed 2^28 texels; -ENOMEM. On success the caller frees
 * *ret with imp_heightfield_done(); on failure *ret is untouched. */
int imp_heightfield_extract(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                            struct imp_heightfield *ret, struct imp_error *err);
/* The same without the message. */
int imp_heightfield_from_range(const struct imp_range_image *range,
                               const struct imp_heightfield_options *opt, struct imp_heightfield *ret);
void imp_heightfield_done(struct imp_heightfield *hf);   /* frees members; accepts zeroed */

/* The heightfield stage's figures as a JSON object (for copy.json "stages"). */
json_t *imp_heightfield_stage_json(const struct imp_heightfield *hf);

/* σ_h of heights another stage has moved (the fusion with photometric normals): a
 * measured texel whose height moved by Δ from `measured_mm` (the triangulated height, same
 * grid) gets σ_h = √(σ_h² + Δ²): either the positions or the stage that moved them may be
 * wrong by about Δ, and σ_h must cover both. Filled texels (their σ comes from the fill)
 * are left alone. */
void imp_heightfield_sigma_moved(struct imp_heightfield *hf, const float *measured_mm);

/* Removes the IMP_HF_MASK_FILLED texels whose drop[t] is nonzero (drop NULL: all of
 * them) and then the filled texels no longer 4-connected to a measured texel through
 * filled ones; their values are zeroed. Updates n_mask_texels, n_filled_texels. */
void imp_heightfield_drop_filled(struct imp_heightfield *hf, const uint8_t *drop);

/* Writes COPY_DIR/heightfield.exr (float channels height, nx, ny, sigma, mask, flags,
 * sigma_n_deg; mask holds the IMP_HF_MASK_* value: 1 measured, 2 filled from the normals,
 * with a larger sigma; flags the IMP_TEXEL_* bits, exact in float) and creates or updates
 * COPY_DIR/copy.json (units, pitch_mm, nx, ny, canvas_to_world, provenance {} kept,
 * stages.heightfield). Creates COPY_DIR. */
int imp_heightfield_save(const struct imp_heightfield *hf, const char *copy_dir, struct imp_error *err);
/* Only heightfield.exr (no copy.json). */
int imp_heightfield_write_exr(const struct imp_heightfield *hf, const char *copy_dir, struct imp_error *err);

/* The flags that follow from the heightfield itself, derived again from its current
 * state (a stage that changes the mask or σ_n calls it): IMP_TEXEL_FRAME_ADJACENT on the
 * mask texels within `px` texels (8-neighbour steps) of the mask's outer edge (holes
 * inside the canvas do not count), IMP_TEXEL_FILLED on the IMP_HF_MASK_FILLED ones,
 * IMP_TEXEL_NORMAL_UNCERTAIN where sigma_n_deg > IMP_TEXEL_NORMAL_SIGMA_MAX_DEG; the other
 * bits are kept; every flag is cleared off the mask. -ENOMEM. */
int imp_heightfield_flag_edges(struct imp_heightfield *hf, int px);
#define IMP_HF_FRAME_ADJACENT_PX 3    /* texels from the mask's outer edge flagged */

