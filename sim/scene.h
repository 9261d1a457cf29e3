/* The simulator's scene: a painting (procedural or loaded heightfield, per-texel Lafortune
 * BRDF by paint region, optional varnish, a frame raised around the canvas), the rig that
 * looks at it (cameras, projector, dome lights — the TRUE calibration), and the explicit
 * list of effects to simulate. Nothing the list does not name is computed.
 * Loaded from a libconfig file (the files in config/scenes/ document the format). */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "error.h"
#include "lafortune.h"
#include "rig.h"
#include "indirect.h"
#include "surface.h"

enum imp_sim_effect {
        IMP_FX_DIRECT,          /* light from the dome light or the projector, BRDF shading */
        IMP_FX_SHADOWS,         /* cast shadows: rays marched towards the light */
        IMP_FX_PROJECTOR,       /* projector pattern illumination */
        IMP_FX_INDIRECT,        /* interreflection via irradiance-vector grids (sim/indirect.h) */
        IMP_FX_AMBIENT,         /* constant ambient term */
        IMP_FX_NOISE,           /* shot, read, dark-current noise and PRNU */
        IMP_FX_BAYER,           /* RGGB mosaic */
        IMP_FX_DISTORTION,      /* Brown–Conrady lens distortion (camera and projector) */
        IMP_FX_VIGNETTING,      /* cos⁴ fall-off */
        IMP_FX_DEFOCUS,         /* Gaussian blur (camera image and projector pattern) */
        IMP_FX_DROPPED_FRAME,   /* the scene's dropped_frames produce no frame */
        IMP_FX_HOT_PIXELS,      /* a fixed sparse set of pixels with a large dark current */
        IMP_FX_STAGE_ERROR,     /* gantry scenes: the stage lands off its read-back (sim/gantry.h) */
        IMP_FX_COUNT
};

const char *imp_sim_effect_name(enum imp_sim_effect fx);
/* -EINVAL for an unknown name. */
int imp_sim_effect_from_name(const char *name);

#define IMP_SCENE_MAX_REGIONS 16

/* A paint region: its BRDF (after the varnish is applied) and how much ρd varies from
 * texel to texel (relative rms of a smooth pigment-density noise). */
struct imp_scene_region {
        char name[32];
        struct imp_lafortune brdf;
        double tint_variation;
};

/* Per-camera rendering options beyond the rig's sensor model. */
struct imp_scene_camera_opts {
        bool colour;                  /* 3-channel RGB frames (else mono, see render.h) */
        double defocus_px;            /* Gaussian sigma of the image blur (effect defocus) */
};

struct imp_scene;   /* opaque */
struct imp_painting_place;      /* below */

/* Loads a scene; all errors name FILE:LINE: FIELD. Caller frees with imp_scene_free(). */
int imp_scene_load(const char *path, struct imp_scene **ret, struct imp_error *err);
int imp_scene_load_string(const char *text, const char *name, struct imp_scene **ret,
                          struct imp_error *err);
void imp_scene_free(struct imp_scene *s);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_scene *, imp_scene_free);

const char *imp_scene_name(const struct imp_scene *s);
uint64_t imp_scene_seed(const struct imp_scene *s);
void imp_scene_set_seed(struct imp_scene *s, uint64_t seed);
bool imp_scene_has_effect(const struct imp_scene *s, enum imp_sim_effect fx);
/* For tests and benchmarks: switch an effect on or off after loading. Turning on
 * `indirect` allocates the albedo plane; -ENOMEM otherwise 0. */
int imp_scene_set_effect(struct imp_scene *s, enum imp_sim_effect fx, bool on);

/* The true rig (distortion included whether or not `distortion` is listed). */
const struct imp_rig *imp_scene_rig(const struct imp_scene *s);
const struct imp_scene_camera_opts *imp_scene_camera_opts(const struct imp_scene *s, int cam);
/* Index of the camera named `name` or -ENOENT; of the light with id `id` or -ENOENT. */
int imp_scene_camera_index(const struct imp_scene *s, const char *name);
int imp_scene_light_index(const struct imp_scene *s, int id);

/* The sampled surface (canvas + frame). The albedo plane is set only with `indirect`. */
const struct imp_sim_surface *imp_scene_surface(const struct imp_scene *s);
/* Unit normals of the samples, ny × nx × 3 (central differences of the heights). */
const float *imp_scene_normals(const struct imp_scene *s);
/* Per-sample paint region (index into the region table) and ρd multiplier. */
const uint8_t *imp_scene_region_map(const struct imp_scene *s);
const float *imp_scene_tint(const struct imp_scene *s);
const struct imp_scene_region *imp_scene_regions(const struct imp_scene *s, int *ret_n);
/* The BRDF of sample i (= y·nx + x): region BRDF with ρd scaled by the tint. */
void imp_scene_texel_brdf(const struct imp_scene *s, size_t i, struct imp_lafortune *ret);
double imp_scene_max_height_mm(const struct imp_scene *s);
double imp_scene_min_height_mm(const struct imp_scene *s);
double imp_scene_frame_height_mm(const struct imp_scene *s);

/* Effect parameters. */
double imp_scene_ambient(const struct imp_scene *s);            /* irradiance, linear units */
bool imp_scene_frame_dropped(const struct imp_scene *s, long long seq);
double imp_scene_hot_pixel_fraction(const struct imp_scene *s);
double imp_scene_hot_pixel_e_per_s(const struct imp_scene *s);
/* Interreflection grid parameters (seed taken from the scene seed). */
void imp_scene_indirect_params(const struct imp_scene *s, struct imp_indirect_params *ret);

/* ---- gantry scenes: a painting larger than the field of view (docs/painting.md) ----
 * A scene with a top-level `gantry` group never samples its whole painting: its surface is
 * a window around the field of view (world x, y, the rig's frame at the current stage
 * position), rebuilt for each placement of the painting under the rig (imp_scene_place).
 *   gantry = {
 *     window_mm = [70.0, 50.0];   # sampled window centred on world (0, 0); default: what the
 *                                 # cameras see on z = 0 plus margin_mm on every side
 *     margin_mm = 2.0;
 *     truth_pitch_mm = 0.1;       # whole-painting truth pitch; default 2 × painting.pitch_mm
 *     speed_mm_s = 50.0; accel_mm_s2 = 500.0; settle_s = 0.3;   # the simulated gantry's clock
 *   };
 *   scene.stage_error = { sigma_mm = 0.05; backlash_mm = 0.02; sigma_deg = 0.05; };
 *                                 # read only when `stage_error` is in scene.effects */
struct imp_scene_gantry {
        double window_mm[2];
        double margin_mm;
        double truth_pitch_mm;
        double speed_mm_s, accel_mm_s2, settle_s;
};
struct imp_stage_error {
        double sigma_mm;              /* repeatability: σ of the landing position, per axis */
        double backlash_mm;           /* lost motion at a reversal: lands backlash/2 short of the target */
        double sigma_deg;             /* σ of the small rotation about z per move */
};
bool imp_scene_is_gantry(const struct imp_scene *s);
const struct imp_scene_gantry *imp_scene_gantry(const struct imp_scene *s);
/* The stage error of a scene that lists `stage_error`, NULL otherwise. */
const struct imp_stage_error *imp_scene_stage_error(const struct imp_scene *s);
/* The painting's canvas, mm (its frame: [0, W] × [0, H]). */
void imp_scene_canvas_size(const struct imp_scene *s, double ret_mm[2]);
/* Gantry scenes: rebuild the surface as the window the rig sees with the painting placed at
 * `place`: the painting's own lattice (one surface for every tile) under the window, seen
 * through the pose (imp_sim_surface.placed). Any renderer of the scene must be rebuilt.
 * -EINVAL for a scene without a gantry group. */
int imp_scene_place(struct imp_scene *s, const struct imp_painting_place *place, struct imp_error *err);
/* Gantry scenes: world x0, y0, x1, y1 of the window the rig sees (its tile truth's extent). */
void imp_scene_window(const struct imp_scene *s, double ret_mm[4]);
/* Gantry scenes: rebuild the surface as the whole painting in its own frame at pitch_mm
 * (the truth; memory grows with the painting). */
int imp_scene_place_whole(struct imp_scene *s, double pitch_mm, struct imp_error *err);

/* One printable summary (for `impasto sim info`); malloc'd. */
char *imp_scene_describe(const struct imp_scene *s);

/* ---- procedural painting (sim/painting.c), used by the scene loader ---- */

/* A heightfield layer; params in mm. Layers add up in list order over the canvas. */
enum imp_layer_kind { IMP_LAYER_WEAVE, IMP_LAYER_STROKES, IMP_LAYER_RIDGE, IMP_LAYER_CRAQUELURE,
                      IMP_LAYER_STEP, IMP_LAYER_FILE, IMP_LAYER_PLANE, IMP_LAYER_SPHERE,
                      IMP_LAYER_COUNT };
struct imp_layer {
        enum imp_layer_kind kind;
        double amplitude_mm;          /* WEAVE, STROKES: peak height; RIDGE: crest height;
                                         CRAQUELURE: crack depth; STEP: step height; FILE: scale */
        double period_mm;             /* WEAVE: thread spacing; CRAQUELURE: cell size */
        double width_mm;              /* STROKES: max stroke width; RIDGE: ramp width;
                                         CRAQUELURE: crack width */
        double length_mm;             /* STROKES: max stroke length */
        double cliff_mm;              /* RIDGE: horizontal extent of the steep side */
        double start_mm[2], end_mm[2];/* RIDGE: crest from start to end */
        double at_mm;                 /* STEP: position of the edge along `axis` */
        int axis;                     /* STEP: 0 = x (raised where x < at), 1 = y */
        int count;                    /* STROKES */
        uint64_t seed;
        char path[512];               /* FILE: EXR/PNG/TIFF, first channel, spans the canvas */
        double slope[2];              /* PLANE: z += slope[0]·x + slope[1]·y + offset_mm (a flat
                                         board tilted by atan(|slope|) about the axis ⟂ slope) */
        double offset_mm;             /* PLANE; SPHERE: centre height over the surface (≤ 0: a
                                         buried centre leaves a spherical cap whose rim meets
                                         the surface at a slant instead of vertically) */
        double centre_mm[2];          /* SPHERE: centre above canvas point (x, y) */
        double radius_mm;             /* SPHERE: z += √(r² − d²) for d < r, the upper half of
                                         a sphere whose centre lies on the surface below it
                                         (a heightfield cannot hold the lower half) */
};

/* Adds `layer` to the canvas part of `h` (samples with is_frame 0). -errno on a file
 * error (message in err). */
int imp_painting_add_layer(const struct imp_sim_surface *surf, float *h, const struct imp_layer *layer,
                           struct imp_error *err);

/* Where a sampled surface lies on a larger painting (a tile's window on a gantry): the
 * painting-frame point of world (x, y) is R(theta)·(x, y) + offset; the painting's canvas is
 * [0, canvas_mm[0]] × [0, canvas_mm[1]] in its frame. Samples off that canvas stay flat. */
struct imp_painting_place {
        double theta_rad;
        double offset_mm[2];
        double canvas_mm[2];
};
/* imp_painting_add_layer with the layer evaluated in the painting frame of `place` (NULL:
 * the identity over the surface's own canvas, exactly imp_painting_add_layer). */
int imp_painting_add_layer_placed(const struct imp_sim_surface *surf, const struct imp_painting_place *place, float *h,
                                  const struct imp_layer *L, struct imp_error *err);

/* Region shapes for the BRDF map. */
enum imp_shape_kind { IMP_SHAPE_ALL, IMP_SHAPE_BLOB, IMP_SHAPE_STRIPE, IMP_SHAPE_RECT, IMP_SHAPE_CHECKER,
                       IMP_SHAPE_DISC };

/* A printed chessboard (region shape CHECKER). Measured on the surface of the scene's
 * (last) plane layer — or on z = 0 without one — so that it is a true chessboard in 3D
 * whatever the tilt. Board frame: origin at inner corner (0, 0), which lies above canvas
 * point origin_mm; u along the plane's x direction (1, 0, slope x)/‖·‖, v = n × u with n the
 * plane normal pointing out of the paint, then rotated by angle about n. Inner corner (i, j) is at u = i·square,
 * v = j·square; square (i, j) = [i, i+1)×[j, j+1) squares is black when i + j is even,
 * for i in [−1, cols − 1], j in [−1, rows − 1]; a white margin of one square surrounds
 * the (cols + 1) × (rows + 1) squares, then the region ends. Texels carry the black
 * fraction of a filter_mm box around them (anti-aliased edges: the renderer samples the
 * nearest texel), as a ρd multiplier: white 1, black `black`. */
struct imp_checker {
        double square_mm;
        int cols, rows;               /* inner corners */
        double origin_mm[2];          /* canvas x, y below inner corner (0, 0) */
        double black;                 /* ink ρd as a fraction of the region's (paper) ρd */
        double filter_mm;             /* box filter width; ≤ pitch means the pitch */
        double angle_rad;             /* board rotated by this about n, from u towards v (keeps
                                         its edges off the texel grid, whose nearest-sample
                                         steps would otherwise bias whole edges alike) */
        double slope[2], offset_mm;   /* the plane it is printed on (copied from the layer) */
};
/* Board coordinates (u, v) of canvas point (x, y) on the checker's plane, mm. */
void imp_checker_board_uv(const struct imp_checker *ck, double x_mm, double y_mm, double ret_uv[2]);
/* Black fraction in [0, 1] of the box of side `box_mm` (board units) around board point
 * (u, v); 0 outside the squares. */
double imp_checker_black_fraction(const struct imp_checker *ck, double u, double v, double box_mm);
struct imp_shape {
        enum imp_shape_kind kind;
        double centre_mm[2];          /* BLOB, STRIPE (a point on the centre line), DISC */
        double radius_mm;             /* BLOB, DISC (a true circle: d ≤ radius) */
        double wobble;                /* BLOB: relative radius modulation */
        double width_mm, angle_rad;   /* STRIPE */
        double min_mm[2], max_mm[2];  /* RECT */
        struct imp_checker checker;   /* CHECKER: contains the board and its margin */
        uint64_t seed;
};
bool imp_shape_contains(const struct imp_shape *sh, double x_mm, double y_mm);
/* Smooth value noise in [-1, 1] with feature size `scale_mm`, deterministic in seed. */
double imp_value_noise(uint64_t seed, double x_mm, double y_mm, double scale_mm);
/* splitmix64-style mixer used by every deterministic random choice of the simulator. */
static inline uint64_t imp_mix64(uint64_t z) {
        z += 0x9e3779b97f4a7c15ull;
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
        return z ^ (z >> 31);
}
/* Uniform in [0, 1) from a 64-bit hash. */
static inline double imp_u01(uint64_t h) { return (double) (h >> 11) * (1.0 / 9007199254740992.0); }
