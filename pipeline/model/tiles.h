/* Tile plans for a whole painting: the area to scan (the painting's extent), the camera's
 * field of view on the canvas, the overlap of neighbouring tiles (default 20 %), the order
 * the gantry visits them (serpentine: no return run across the painting), and per tile the
 * stage target and a focus/height offset. Shared by the daemon (where to move), the
 * simulator (what each tile sees) and the estimate. Library code: no logging.
 *
 * Frames: the painting frame has its origin at the scan area's corner, x along the rows,
 * y along the columns, mm. The stage frame is the gantry's machine coordinates; the stage
 * target of a tile is origin_mm + the tile's centre (origin_mm: the stage x, y that puts
 * the field of view's centre over the painting's corner (0, 0)). The z target is
 * z_mm + the height offset of the tile: a bilinear surface through the four corners'
 * offsets (a canvas that sags or leans), evaluated at the tile's centre, plus a per-tile
 * correction where one was set.
 *
 * Spacing: the scanned area is the extent grown by edge_margin_mm m on every side (what a
 * tile's copy really covers stops short of its field, and the stage lands within its
 * repeatability of the target: docs/painting.md, "The edge margin"); n = 1 + ceil((extent +
 * 2m − fov) / (fov · (1 − overlap))) tiles per axis, spread evenly from fov/2 − m to
 * extent + m − fov/2, so the first and last tiles' fields pass the area's edges by m and the
 * overlap is at least the one asked for (the actual one is reported). An axis whose grown
 * area fits in the field has one tile, centred.
 *
 * As a group of a plan file (imp_tile_plan_from_conf):
 *   painting = {
 *     extent_mm = [300.0, 200.0];       # required
 *     fov_mm = [60.0, 40.0];            # required
 *     overlap = 0.2;                    # default 0.2
 *     edge_margin_mm = 1.0;             # default 0: fields end at the extent's edges
 *     order = "rows";                   # or "columns"; default "rows"
 *     origin_mm = [10.0, 5.0];          # default [0, 0]
 *     z_mm = 20.0;                      # default 0
 *     corner_z_mm = [0.0, 0.4, -0.2, 0.1];   # default all 0
 *     z_corrections = ( { tile = [2, 1]; z_mm = 0.3; } );   # [col, row]; optional
 *   }; */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <jansson.h>
#include "conf.h"
#include "error.h"

#define IMP_TILES_DEFAULT_OVERLAP 0.20
#define IMP_TILES_MAX_OVERLAP 0.80      /* more: tiles mostly repeat each other */
#define IMP_TILES_MAX 100000            /* 2 m × 2 m at 6 mm fields; anything above is a typo */

enum imp_tile_order {
        IMP_TILE_ORDER_ROWS,            /* serpentine along x: row 0 left to right, row 1 back, ... */
        IMP_TILE_ORDER_COLUMNS,         /* serpentine along y */
};

struct imp_tile_options {
        double extent_mm[2];            /* scan area, x and y, > 0 */
        double fov_mm[2];               /* field of view on the canvas, x and y, > 0 */
        double overlap;                 /* fraction of the field shared by neighbours, 0..IMP_TILES_MAX_OVERLAP */
        double edge_margin_mm;          /* the outer tiles' fields pass the extent by this, ≥ 0 */
        enum imp_tile_order order;
        double origin_mm[2];            /* stage x, y of the painting's corner (0, 0), see above */
        double z_mm;                    /* stage z in focus at a height offset of 0 */
        double corner_z_mm[4];          /* height offsets at (0,0), (X,0), (0,Y), (X,Y); X, Y the extent */
};

struct imp_tile {
        unsigned index;                 /* scan order, 0 first */
        unsigned col, row;              /* grid position: col along x, row along y */
        double center_mm[2];            /* painting frame */
        double rect_mm[4];              /* x0, y0, x1, y1 in the painting frame (passes the area by
                                         * the edge margin, or more when the field is larger) */
        double z_offset_mm;             /* height offset: the corners' surface plus any correction */
        double stage_mm[3];             /* stage target x, y, z */
};

struct imp_tile_plan;

/* Overlap 20 %, serpentine rows, everything else 0 (extent and field must be set). */
void imp_tile_options_default(struct imp_tile_options *ret);
/* Lays out the tiles. -EINVAL with "tiles: FIELD: expected …, got …" for a bad option,
 * -E2BIG beyond IMP_TILES_MAX tiles. Caller frees with imp_tile_plan_free(). */
int imp_tile_plan_new(const struct imp_tile_options *o, struct imp_tile_plan **ret, struct imp_error *err);
/* The same from a plan file's group (the format above), per-tile corrections included;
 * messages name FILE:LINE: FIELD. Defaults from imp_tile_options_default(). */
int imp_tile_plan_from_conf(const struct imp_conf *c, const config_setting_t *group, struct imp_tile_plan **ret,
                            struct imp_error *err);
void imp_tile_plan_free(struct imp_tile_plan *p);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_tile_plan *, imp_tile_plan_free);

const struct imp_tile_options *imp_tile_plan_options(const struct imp_tile_plan *p);
size_t imp_tile_plan_count(const struct imp_tile_plan *p);
/* Tile i in scan order; NULL past the end. */
const struct imp_tile *imp_tile_plan_tile(const struct imp_tile_plan *p, size_t i);
/* Tile at grid position (col, row); NULL outside the grid. */
const struct imp_tile *imp_tile_plan_at(const struct imp_tile_plan *p, unsigned col, unsigned row);
void imp_tile_plan_grid(const struct imp_tile_plan *p, unsigned *ret_cols, unsigned *ret_rows);
/* Centre-to-centre spacing and the overlap it gives, per axis (x, y); an axis of one tile
 * reports spacing 0 and overlap 0. */
void imp_tile_plan_spacing(const struct imp_tile_plan *p, double ret_step_mm[2], double ret_overlap[2]);

/* Adds a focus correction to tile (col, row) on top of the corners' surface (a measured
 * bulge, a stretcher bar). -ERANGE outside the grid, -EINVAL when not finite. */
int imp_tile_plan_set_z_correction(struct imp_tile_plan *p, unsigned col, unsigned row, double z_mm);
/* 0 when every stage target lies within [min_mm, max_mm] (x, y, z), else -ERANGE naming the
 * first tile in scan order that does not and the axis. */
int imp_tile_plan_check_limits(const struct imp_tile_plan *p, const double min_mm[3], const double max_mm[3],
                               struct imp_error *err);
/* Length of the gantry's path through the tiles in scan order (x, y, and z), mm. */
double imp_tile_plan_path_mm(const struct imp_tile_plan *p);
/* Time the gantry spends moving between tiles: each move's length at speed_mm_s plus
 * settle_s per move (n − 1 moves), s. Acceleration is folded into settle_s. */
double imp_tile_plan_move_s(const struct imp_tile_plan *p, double speed_mm_s, double settle_s);

/* What one tile costs, the same for every tile (the per-tile scan plan is one plan). */
struct imp_tile_cost {
        size_t frames;                  /* frames captured per tile */
        double bytes;                   /* bytes written per tile (frames and manifest) */
        double capture_s;               /* capture time of one tile, moves excluded */
        double process_s;               /* processing time of one tile on one worker */
        unsigned workers;               /* tiles processed at once, ≥ 1 */
        double speed_mm_s, settle_s;    /* the gantry, as imp_tile_plan_move_s() */
};

struct imp_tile_estimate {
        size_t tiles, frames;
        double bytes;
        double move_s;                  /* gantry moves between tiles */
        double capture_s;               /* moves + every tile's capture, back to back */
        double process_s;               /* Σ processing, worker-seconds */
        double wall_s;                  /* start of the first capture to the end of the last
                                         * processing, processing overlapping capture: a
                                         * tile is handed to a free worker once captured */
};

/* Whole-painting figures from per-tile costs, the overlap of capture and processing played
 * through tile by tile in scan order. -EINVAL for a negative or non-finite cost or no worker. */
int imp_tile_plan_estimate(const struct imp_tile_plan *p, const struct imp_tile_cost *cost,
                           struct imp_tile_estimate *ret);

/* painting.json (docs/painting.md, format "impasto-painting" version 1): extent, field,
 * overlap, edge margin, origin, the stage's prior σ and per tile its index, grid cell, nominal centre,
 * commanded stage target, read-back (the target until set), capture "tiles/NNNN" and copy
 * "copies/NNNN". NULL when out of memory. */
json_t *imp_tile_plan_painting_json(const struct imp_tile_plan *p, double stage_sigma_mm, double stage_sigma_deg);
/* painting.json as read by anyone but its writer (the daemon's resume, `impasto process`,
 * `impasto mosaic`): at most IMP_PAINTING_JSON_MAX_BYTES, then imp_painting_json_check().
 * Its JSON values are counted before the parse: at most IMP_PAINTING_JSON_MAX_VALUES (what
 * the parse allocates stays near 220 MB whatever the document). -EBADMSG with err naming the
 * file and field for anything damaged or out of range; other
 * negative errnos for I/O (-ENOENT when absent). Caller owns *ret. */
#define IMP_PAINTING_JSON_MAX_BYTES (64u << 20)        /* 100 000 tiles take ~40 MiB */
#define IMP_PAINTING_JSON_MAX_VALUES (40u * IMP_TILES_MAX)   /* JSON values (~32 a tile): ~55 B each parsed */
#define IMP_PAINTING_MAX_MM 1e5                         /* extent and field: 100 m, anything above is a typo */
int imp_painting_json_load(const char *path, json_t **ret, struct imp_error *err);
/* The bounded read alone (size, regular file, JSON: -EBADMSG), for a reader that checks its
 * own fields first and then calls imp_painting_json_check(). */
int imp_painting_json_read(const char *path, json_t **ret, struct imp_error *err);
/* The header (format "impasto-painting", version 1 when given, extent_mm and fov_mm in
 * (0, IMP_PAINTING_MAX_MM], finite origin_mm, overlap in [0, 1), stage σ finite ≥ 0,
 * pitch_mm in [0.001, 1000] when given (a copy grid of 1 µm at the finest), cols and rows ≥ 1
 * when given) and every tile (1..IMP_TILES_MAX of them): index 0..n−1 and unique, col < cols
 * and row < rows, finite center_mm, readback_mm (and commanded_mm when given), capture and
 * copy strings that do not leave the painting's directory (no ".." component; an absolute
 * path is the writer's choice: the Slurm finish writes them). Unknown keys are ignored.
 * what names the document in messages. */
int imp_painting_json_check(const json_t *j, const char *what, struct imp_error *err);
/* Sets tile k's read-back position. -ERANGE for a tile it does not hold. */
int imp_painting_json_set_readback(json_t *painting, size_t k, const double readback_mm[3]);
