/* One digital copy of a whole painting from the copies of its tiles (docs/mosaic.md): each
 * tile placed in the painting frame from its stage pose, refined by registering the overlaps
 * of neighbouring tiles (heights, robust Gauss-Newton), one global least-squares adjustment
 * of every tile pose (pose graph: pairwise measurements + stage priors with their σ), then
 * heights, normals, σ, flags and BRDF blended across the seams into output tiles written one
 * after the other with only the input tiles they overlap in memory, relief boxes classified
 * with global thresholds and a multi-resolution pyramid. Library code: no logging.
 *
 * Frames (painting-contract.md): a tile copy's texel (i, j) sits at canvas (i·p, j·p, h);
 * its copy.json canvas_to_world M maps that to the rig's world at the stage position
 * (x, y along the painting's axes, z up). The painting position of world point w is
 *     P = n_k + t_k + R(θ_k)·w_xy,   z = w_z + dz_k,
 * n_k = readback_xy − origin_mm (the nominal placement), (t_k, θ_k, dz_k) the tile's pose
 * correction (0 for the stage prior). The world x, y of a texel is taken from M at h = 0
 * (a copy's canvas plane is within a fraction of a degree of the world's xy plane: the
 * height's share of x, y is below a µm for the reliefs of a painting). */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "error.h"
#include "image.h"

struct imp_mosaic_tile {
        unsigned index, col, row;
        char copy[4096];              /* copy dir (absolute or relative to the cwd) */
        double nominal_mm[2];         /* n_k: readback_xy − origin_mm */
        int nx, ny;                   /* copy grid (from copy.json) */
        double pitch_mm;
        double c2w[16];               /* canvas_to_world */
        double pose[4];               /* t_x, t_y (mm), θ (rad), dz (mm): the correction */
        double prior_sd[4];           /* stage prior σ of each */
        bool has_truth;
        double truth[3];              /* truth/tile-poses.json: painting x, y of the tile's
                                         world origin (mm) and θ (rad) */
        double bbox[4];               /* painting x0, y0, x1, y1 under the current pose */
};

struct imp_painting {
        char dir[4096];
        double extent_mm[2], fov_mm[2], overlap, origin_mm[2];
        double sigma_mm, sigma_deg, sigma_z_mm;
        size_t n_tiles;
        struct imp_mosaic_tile *tiles;
        bool has_truth;               /* truth/tile-poses.json read */
};

/* Reads DIR/painting.json and each tile's copy.json (grid and canvas_to_world), and
 * DIR/truth/tile-poses.json when present. Tiles without "copy" are an error (the scan is not
 * processed yet). Messages name the file and the field. Frees with imp_painting_done(). */
int imp_painting_load(const char *dir, struct imp_painting *ret, struct imp_error *err);
void imp_painting_done(struct imp_painting *p);

/* Tile k: painting position of its texel (fi, fj) (fractional) under its current pose, and
 * the inverse (false when M is singular). */
void imp_mosaic_tile_to_painting(const struct imp_mosaic_tile *t, double fi, double fj, double ret_xy[2]);
bool imp_mosaic_painting_to_tile(const struct imp_mosaic_tile *t, double x, double y, double ret_ij[2]);
/* Updates every tile's bbox from its pose. */
void imp_painting_update_bboxes(struct imp_painting *p);

struct imp_mosaic_options {
        bool prior_only;              /* stage priors only: no registration, no adjustment */
        double search_sigma;          /* coarse search ± this many σ of the relative pose; 4 */
        int sample_step;              /* texel stride of the registration samples; 1 */
        double huber_k;               /* Huber threshold in robust σ (1.4826·MAD); 1.5 */
        double min_overlap_mm;        /* pairs overlapping less (either axis) are skipped; 1 */
        int out_tile_px;              /* side of an output tile in texels; 512 */
        double feather_mm;            /* blend ramp from a tile's edge; 0 = half the overlap */
        size_t cache_bytes;           /* input tiles held at once; 1 GiB (at least the tiles
                                         one output tile needs) */
        int box_cell_px;              /* relief box cell; 20 (divides out_tile_px or not) */
        double box_delta_frac, box_noise_k, box_ref_percentile;   /* as imp_boxes_options */
        unsigned reg_channels;        /* what pairs are registered on: IMP_MOSAIC_REG_*; heights
                                         (the copies' photometric normals are ~2·10⁻⁴ too small
                                         about the field centre: docs/mosaic.md) */
        double reg_smooth_px;         /* pairs registered on heights low-passed by a Gaussian of
                                         this σ in texels (masked); 0.5 (the pixel-scale detail's
                                         bias, docs/mosaic.md); 0: as they are */
};
enum { IMP_MOSAIC_REG_HEIGHT = 1 << 0, IMP_MOSAIC_REG_NORMALS = 1 << 1 };
void imp_mosaic_options_default(struct imp_mosaic_options *o);

struct imp_mosaic_pair {
        unsigned a, b;                /* tile indices (into p->tiles), a < b */
        bool ok;                      /* registered (false: too small or no texture) */
        char why[96];                 /* why not, when !ok */
        double c_mm[2];               /* overlap centre (rotation centre of the measurement) */
        double meas[4];               /* d_x, d_y (mm), dθ (rad), dz (mm): b relative to a */
        double info[16];              /* its information (inverse covariance), 4×4 */
        size_t n_samples;
        double inlier_frac;           /* samples with Huber weight 1 */
        double rms_before_um, rms_after_um;   /* height residual RMS at the prior, after */
        double sd_um[2];              /* 1σ of d_x, d_y */
};

/* Registers every overlapping pair under the current poses (tile copies read through a
 * bounded cache). *ret (malloc'd) and *ret_n: the pairs. */
int imp_mosaic_register(struct imp_painting *p, const struct imp_mosaic_options *o,
                        struct imp_mosaic_pair **ret, size_t *ret_n, struct imp_error *err);

struct imp_mosaic_adjust_stats {
        size_t n_pairs_used;
        double change_rms_um;         /* in-plane change from the prior at the tiles' corners */
        double change_max_um;
        double theta_change_rms_deg;
        double chi2_pairs, chi2_priors;   /* weighted squared residuals after the solve */
        double pair_resid_rms_um;     /* pair measurements' in-plane misfit after the solve */
        double variance_factor;       /* the pairs' information divided by this (≥ 1) */
};
/* Global least squares over the pose graph: every pair's measurement with its information,
 * every tile's stage prior with its σ; the priors fix the gauge. Updates p's poses. */
int imp_mosaic_adjust(struct imp_painting *p, const struct imp_mosaic_pair *pairs, size_t n_pairs,
                      struct imp_mosaic_adjust_stats *ret, struct imp_error *err);

/* Seam step: RMS over every overlap of the difference of the two tiles' heights under the
 * current poses, each averaged over 5×5 texels (so that the noise of a texel is not counted
 * as a step), mm → µm. */
int imp_mosaic_seam_step(struct imp_painting *p, const struct imp_mosaic_options *o,
                         double *ret_rms_um, size_t *ret_n, struct imp_error *err);

/* Truth of the painting's heights, painting frame (for the score). */
struct imp_mosaic_truth {
        double (*height)(void *ctx, double x_mm, double y_mm);   /* NAN: unknown */
        void *ctx;
};

/* Why an output texel is not covered (docs/mosaic.md, "Coverage"): beyond every copy's grid
 * within the edge band of the painting's border (the outer tiles do not reach the extent:
 * plan an edge margin), beyond every copy's grid farther in (a gap between the copies),
 * inside a copy's grid within 2 texels of its edge but off its mask (the copy's ragged
 * edge), inside a copy's grid farther in but off its mask (a hole in the copy). */
enum imp_mosaic_uncovered {
        IMP_MOSAIC_UNCOVERED_EDGE,
        IMP_MOSAIC_UNCOVERED_GAP,
        IMP_MOSAIC_UNCOVERED_COPY_EDGE,
        IMP_MOSAIC_UNCOVERED_HOLE,
        IMP_MOSAIC_UNCOVERED_N
};
const char *imp_mosaic_uncovered_name(enum imp_mosaic_uncovered c);

struct imp_mosaic_figures {
        size_t out_nx, out_ny, out_tiles_x, out_tiles_y, texels_written, texels_covered;
        size_t uncovered[IMP_MOSAIC_UNCOVERED_N];   /* texels not covered, by cause */
        double edge_band_mm;          /* IMP_MOSAIC_UNCOVERED_EDGE: within this of the border */
        double edge_depth_mm;         /* farthest from the border of those texels (0: none) */
        size_t texels_doubled;        /* written by more than one output tile (must be 0) */
        size_t input_loads;           /* tile copies read (a tile read again after eviction counts) */
        size_t max_resident;          /* most input tiles held at once */
        double h_ref_mm, delta0_mm, H_mm;
        size_t n_boxes;
        int pyramid_levels;
        double height_rmse_um;        /* vs truth (NAN without) */
        size_t height_n;
        /* The seam step of the output, with truth (NAN without; docs/mosaic.md): for every
         * seam of two neighbouring tiles, segments of 2 mm along it, the mean height error
         * of the mosaic over a 1 mm band just outside the overlap on one side minus that on
         * the other (jump, RMS over the segments); the same over as wide a gap about the
         * tile's centre (ref: the copies' own error over that distance, no seam); step =
         * √(jump² − ref²), 0 when the jump is not above the reference. Unlike the seam step
         * of imp_mosaic_seam_step (the two copies before blending), this is what the one
         * copy shows from one tile to the next. */
        double seam_out_step_um, seam_out_jump_um, seam_out_ref_um;
        size_t seam_out_n;            /* segments in the jump */
};

/* Blends the tiles under their current poses into OUT: OUT/mosaic.json (the index),
 * OUT/tiles/R-C/ (each an ordinary copy of out_tile_px² texels, canvas_to_world placing it in
 * the painting frame), OUT/pyramid/L/R-C.exr. truth may be NULL. */
int imp_mosaic_write(struct imp_painting *p, const struct imp_mosaic_options *o, const char *out,
                     const struct imp_mosaic_truth *truth, struct imp_mosaic_figures *ret,
                     struct imp_error *err);

/* In-plane registration error against truth/tile-poses.json at the 4 corners and the centre
 * of every tile: RMS absolute; RMS after removing the common rigid motion of the whole
 * mosaic (the gauge the data cannot see: σ/√N of the priors); mean and far-corner errors
 * (the painting corner farthest from the first tile's), both after the gauge. -ENODATA
 * without truth. */
struct imp_mosaic_reg_error {
        double abs_rms_um, rms_um, mean_um, far_corner_um, max_um;
};
int imp_mosaic_registration_error(const struct imp_painting *p, struct imp_mosaic_reg_error *ret);

/* Synthetic painting for tests and benches: an analytic relief (strokes and ripples) over
 * extent_mm, tiles of fov_mm with the overlap, true poses drawn with sigma_mm / sigma_deg
 * (and 5 µm in z), height noise noise_um; each tile written as an ordinary copy dir with
 * painting.json and truth/tile-poses.json (truth/height.exr too when truth_exr). */
struct imp_mosaic_synth {
        double extent_mm[2], fov_mm[2], overlap, pitch_mm;
        double edge_margin_mm;        /* the tile plan's (tiles.h): outer fields pass the extent; 0 */
        double sigma_mm, sigma_deg, noise_um;
        unsigned seed;
        bool truth_exr;
        bool brdf;                    /* write rho_d/rho_s/lobe (else the copy is not loadable) */
        double normal_scale;          /* s: a tile's normal at w is the relief's at (1 + s)·w (w
                                         from the field centre), as a copy whose normal map is
                                         too small by s; 0 */
};
void imp_mosaic_synth_default(struct imp_mosaic_synth *s);
double imp_mosaic_synth_height(const struct imp_mosaic_synth *s, double x_mm, double y_mm);
int imp_mosaic_synth_write(const struct imp_mosaic_synth *s, const char *dir, struct imp_error *err);

/* DIR/truth/height.exr or heightfield.exr (channel "height", mm, painting frame; sample
 * (I, J) at truth/truth.json's origin_mm + (I, J)·pitch_mm when that file is there (the
 * simulator's), else at (I·extent_x/W, J·extent_y/H)) as a truth for imp_mosaic_write: -ENOENT when absent.
 * The sampler is bilinear; NAN outside. Free with imp_mosaic_truth_done(). */
struct imp_mosaic_truth_exr {
        struct imp_image *img;
        int channel;
        double pitch_mm[2], origin_mm[2];   /* sample (I, J) at origin + (I·pitch_x, J·pitch_y) */
};
int imp_mosaic_truth_load(const struct imp_painting *p, struct imp_mosaic_truth_exr *ret, struct imp_mosaic_truth *ret_truth,
                          struct imp_error *err);
void imp_mosaic_truth_done(struct imp_mosaic_truth_exr *t);
