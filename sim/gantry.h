/* A whole painting scanned tile by tile on a simulated gantry (docs/painting.md): where the
 * stage really lands for each tile (the `stage_error` effect), the simulated clock with the
 * gantry's moves, and `sim render` of a plan with a painting group: painting.json, one
 * capture set per tile (tiles/NNNN) and the truth in the painting frame. Each tile renders
 * only its window of the painting (imp_scene_place), never the whole painting at full
 * resolution. */
#pragma once
#include <stdbool.h>
#include "captureset.h"
#include "plan.h"
#include "scene.h"
#include "tiles.h"

struct imp_sim_tile_pose {
        double commanded_mm[3];         /* the stage target of the tile */
        double readback_mm[3];          /* what the stage reports: the target (it counts its steps) */
        double true_mm[3];              /* where the carriage really is */
        double theta_rad;               /* its rotation about z, painting frame from the rig's */
};

/* The pose of tile k. Without `stage_error` the carriage is where it is told (no random
 * draw). With it: true = commanded − backlash/2 · (direction of the last move on that axis,
 * + from home) + N(0, σ) per axis x, y; θ ~ N(0, σ_deg); deterministic in (seed, k), so a
 * tile scanned again lands the same way. */
void imp_sim_tile_pose(const struct imp_scene *s, const struct imp_tile_plan *tp, size_t k,
                       struct imp_sim_tile_pose *ret);
/* The painting's placement under the rig for a pose: painting_xy = R(θ)·world_xy +
 * (true_xy − origin_mm). */
void imp_sim_tile_place(const struct imp_tile_plan *tp, const struct imp_sim_tile_pose *pose,
                        struct imp_painting_place *ret);
/* Time of a gantry move, s: each axis a trapezoidal profile (accel, speed), the slowest
 * axis, then the settle time. 0 for no move. */
double imp_sim_move_s(const struct imp_scene_gantry *g, const double from_mm[3], const double to_mm[3]);
/* The simulated timeline of one frame after `prev` (NULL: the first): a settle before each
 * light or pattern change, then settle, exposure and readout back to back. */
void imp_sim_stamp(struct imp_frame_record *rec, const struct imp_frame_record *prev, const struct imp_rig *rig,
                   long long *t_ns);

/* The simulated clock of the whole painting's scan (what imp_sim_render_painting reports)
 * without rendering a frame; 0 without a painting group or a gantry scene. */
double imp_sim_painting_clock_s(const struct imp_scene *scene, const struct imp_plan *plan, double *ret_move_s);

/* OUT/truth/ of the painting `plan` scans, as imp_sim_render_painting writes it (the whole
 * painting at gantry.truth_pitch_mm, truth/tile-poses.json), without rendering a frame: what
 * `sim serve --truth-out` writes for a gantry scene, whose frames take the same poses. The
 * scene's surface is left as the whole painting (serve a scene loaded apart). */
int imp_sim_write_painting_truth_plan(struct imp_scene *scene, const struct imp_plan *plan, const char *out,
                                      struct imp_error *err);

struct imp_sim_painting_result {
        size_t tiles, frames, dropped;
        double clock_s;                 /* the simulated clock: first frame to the last */
        double move_s;                  /* of which gantry moves */
};
typedef void (*imp_sim_progress_fn)(void *userdata, size_t tile, size_t n_tiles, size_t frames);

/* Renders every tile of `plan` (which must have a painting group) into OUT: OUT/painting.json,
 * OUT/tiles/NNNN (capture sets of the per-tile plan, frames with tile 0, plus each tile's
 * own truth/ in its world frame), OUT/truth/ (truth.json, heightfield.exr, rho_d.exr,
 * rho_s.exr, lobe.exr over the whole painting at gantry.truth_pitch_mm) and
 * OUT/truth/tile-poses.json. The scene must be a gantry scene; its surface is left as the
 * whole-painting truth. */
int imp_sim_render_painting(struct imp_scene *scene, const struct imp_plan *plan, const char *plan_path,
                            const char *out, imp_sim_progress_fn progress, void *userdata,
                            struct imp_sim_painting_result *ret, struct imp_error *err);
