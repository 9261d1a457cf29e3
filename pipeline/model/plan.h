/* Scan plans: a libconfig file saying what to capture (cameras, tiles, structured-light
 * patterns, exposure stacks, dome sweep, dark frames), expanded against a rig into the
 * ordered frame list that the daemon captures and the simulator renders. Shared by both;
 * library code: no logging, errors name FILE:LINE: FIELD.
 *
 * File format (every group optional unless noted):
 *   cameras = ["cam0"];                 # default: every camera of the rig
 *   tiles = 1;                          # gantry positions (frames repeat per tile)
 *   gain_db = 0.0;
 *   structured_light = {
 *     gray_bits = 10;                   # default per axis: ceil(log2(projector size))
 *     inverse = true;                   # each Gray bit followed by its inverse
 *     axes = ["x", "y"];
 *     phase = { periods_px = [16.0, 64.0]; steps = 4; };   # omit for none
 *     white = true; black = true;
 *     exposures_us = [5000.0, 20000.0]; # the stack; required when the group is present
 *   };
 *   dome = { lights = "all";            # or [0, 3, 7] (rig light ids)
 *            exposures_us = [10000.0];
 *            repeat = 1; };              # frames per light × exposure (1..IMP_PLAN_MAX_REPEAT):
 *                                        # for averaging (dark paintings, photon-transfer pairs)
 *   dark = { count = 4; };              # per distinct exposure of the plan
 *   painting = { extent_mm = [300.0, 200.0]; fov_mm = [60.0, 40.0]; ... };
 *                                       # a whole painting on a gantry (tiles.h for the
 *                                       # group): the frames above are ONE tile's, all with
 *                                       # tile 0 (each tile is its own capture set, see
 *                                       # docs/painting.md); `tiles` may not be given with it
 *
 * Frame order (per tile, per camera): structured light exposure-major (white, black, then
 * per axis the Gray bits MSB first, each followed by its inverse, then the phase shifts
 * period by period, step by step), then the dome light-major (a light's exposure stack
 * is contiguous, so a light is switched once; the `repeat` frames of one light × exposure
 * follow each other), then the dark frames. Consecutive frames of the same state (see
 * imp_plan_same_state: repeats, dark frames of one exposure) form a run that the daemon
 * captures with the camera free-running (docs/daemon.md, "Streamed runs"). */
#pragma once
#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include "captureset.h"
#include "error.h"
#include "rig.h"
#include "tiles.h"

#define IMP_PLAN_MAX_EXPOSURES 8
#define IMP_PLAN_MAX_PERIODS 8
#define IMP_PLAN_MAX_REPEAT 10000
/* Caps on the expanded plan, checked from the counts before anything is allocated (every
 * factor is capped, their product is not): a million frames is ~100 tiles of the archival
 * plan; a frame record takes ~250 bytes in memory. Bytes are raw 16-bit pixels on disk. */
#define IMP_PLAN_MAX_FRAMES 1000000
#define IMP_PLAN_MAX_BYTES (64ULL << 40)

struct imp_plan;   /* opaque: the parsed settings and the expanded frame list */

/* Loads and expands a plan against `rig` (needed for projector size, light ids and camera
 * names). Caller frees with imp_plan_free(). -EINVAL/-ENOENT with "FILE:LINE: FIELD: …";
 * -E2BIG when the expansion exceeds IMP_PLAN_MAX_FRAMES or IMP_PLAN_MAX_BYTES. */
int imp_plan_load(const char *path, const struct imp_rig *rig, struct imp_plan **ret,
                  struct imp_error *err);
/* The same from text; `name` stands for the file name in messages. Text may not use
 * `@include` (refused with -EINVAL before libconfig reads it): nothing but the text is read. */
int imp_plan_load_string(const char *text, const char *name, const struct imp_rig *rig,
                         struct imp_plan **ret, struct imp_error *err);
void imp_plan_free(struct imp_plan *p);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_plan *, imp_plan_free);

size_t imp_plan_count(const struct imp_plan *p);
/* Frame i (seq == i), with file, crc32 and timestamps empty. */
const struct imp_frame_record *imp_plan_frame(const struct imp_plan *p, size_t i);
/* The tile layout of the painting group, NULL for a plan of one field of view. Owned by
 * the plan. */
const struct imp_tile_plan *imp_plan_tiles(const struct imp_plan *p);
/* Gray bits used for axis 0 (x) / 1 (y); 0 when that axis is not scanned. */
int imp_plan_gray_bits(const struct imp_plan *p, int axis);

/* True when two frames need the same rig and camera state: camera, tile, projector pattern
 * (or dark), light, exposure and gain. A frame in the same state as the one before it is a
 * repeat (dome `repeat`, dark `count`), captured without setting anything up. */
bool imp_plan_same_state(const struct imp_frame_record *a, const struct imp_frame_record *b);
/* Frames from i on (i included) in the same state as frame i: 1 for a frame of its own,
 * 0 past the end. */
size_t imp_plan_run_length(const struct imp_plan *p, size_t i);

/* Capture-time estimate in seconds: Σ over frames (exposure + camera readout + rig
 * settle) + one extra settle per light or pattern switch (a change of light id or of
 * projector pattern between consecutive frames). Repeats count as frames (the simulator's
 * clock charges them the same). Cameras absent from the rig count a readout of 0. */
double imp_plan_estimate_s(const struct imp_plan *p, const struct imp_rig *rig);

/* The whole-painting estimate of a plan with a painting group (`impasto plan estimate`
 * offline and impastod's plan.estimate give the same object, docs/painting.md). Processing
 * one tile on one worker costs, per frame-megapixel captured, what one tile of
 * config/scenes/painting-small.cfg (50 frames of 0.03 Mpix) took: 3.9 s on a loaded 2-core
 * machine; process_s gives a measured figure instead. */
#define IMP_PLAN_PROCESS_S_PER_FRAME_MPIX 2.6
#define IMP_PLAN_STAGE_SPEED_MM_S 50.0  /* drivers/stage.h IMP_STAGE_DEFAULT_SPEED_MM_S */
#define IMP_PLAN_SETTLE_S 0.5           /* a gantry move's acceleration and settling, beyond speed */
struct imp_plan_painting_opts {
        double speed_mm_s, settle_s;    /* the gantry's feed and per-move settle */
        double process_s;               /* one tile on one worker; < 0: from the frames */
        unsigned workers;               /* tiles processed at once, ≥ 1 */
};
/* {"tiles","cols","rows","overlap":[x,y],"frames","bytes","move_s","capture_s","process_s",
 * "wall_s","tile_process_s","workers","stage_speed_mm_s","settle_s"} for tile_bytes bytes per
 * tile; NULL without a painting group, for a bad option, or out of memory. */
json_t *imp_plan_painting_estimate_json(const struct imp_plan *p, const struct imp_rig *rig, double tile_bytes,
                                        const struct imp_plan_painting_opts *o);
