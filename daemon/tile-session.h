/* Whole-painting sessions, the part that moves the gantry (tile-session.c): per tile, move
 * the stage to the tile's target, wait until it settles, read the position back, and keep
 * the painting's progress in painting.json (docs/painting.md) so that a session resumes at
 * the first tile not done. A stage fault (limit switch, alarm, lost position, a move that
 * never settles) is answered with a message the operator can act on; the caller pauses the
 * session and resumes after re-homing. Depends on the stage driver and the tile plan only. */
#pragma once
#include <jansson.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "error.h"
#include "stage.h"
#include "tiles.h"

#define TILE_SETTLE_TIMEOUT_MS 60000U   /* the longest move across a 2 m gantry at 50 mm/s, and some */

/* Moves to tile t and waits until settled (settle_timeout_ms), then reads back. On success
 * ret_readback_mm holds the read-back position (z = the target on a 2-axis stage). On failure
 * a negative errno and msg: what happened, where (tile, grid cell, target) and what to do. */
int tile_session_move(struct imp_stage *stage, const struct imp_tile *t, unsigned settle_timeout_ms,
                      double ret_readback_mm[3], char *msg, size_t size);

/* The same in two halves for an event loop: _start sends the move (0, or a negative errno
 * and msg as above); _poll reads the status once: 0 not settled yet (poll again), 1 settled
 * (ret_readback_mm filled), negative with msg once it failed or deadline_us
 * (imp_stage_deadline_us(settle_timeout_ms)) has passed (the stage then soft-stopped). */
int tile_session_move_start(struct imp_stage *stage, const struct imp_tile *t, char *msg, size_t size);
int tile_session_move_poll(struct imp_stage *stage, const struct imp_tile *t, uint64_t deadline_us,
                           unsigned settle_timeout_ms, double ret_readback_mm[3], char *msg, size_t size);
/* DIR/painting.json: loaded when it exists (imp_painting_json_load: -EBADMSG naming the
 * file and field when it is damaged; then checked against the plan: same tile count and
 * targets, -EINVAL when another plan's), otherwise made from the plan. Tiles carry "done":
 * true once captured. Caller owns *ret (json_decref). */
int tile_session_open(const char *dir, const struct imp_tile_plan *tp, double stage_sigma_mm, double stage_sigma_deg,
                      json_t **ret, struct imp_error *err);
/* DIR/painting.json found damaged (tile_session_open's -EBADMSG): moved aside to
 * painting.json.damaged-N (ret_aside, never overwritten) and made anew from the plan, as
 * tile_session_open makes it (no tile done yet). Caller owns *ret. */
int tile_session_rebuild(const char *dir, const struct imp_tile_plan *tp, double stage_sigma_mm,
                         double stage_sigma_deg, char *ret_aside, size_t aside_size, json_t **ret,
                         struct imp_error *err);
/* Tile k's read-back position and whether it is captured, saved atomically at once. */
int tile_session_record(const char *dir, json_t *painting, size_t k, const double readback_mm[3], bool done,
                        struct imp_error *err);
/* The first tile not done (the tile count when all are). */
size_t tile_session_next(const json_t *painting);
/* Progress and ETA: tiles done, and the remaining time from the mean time per tile so far
 * (elapsed_s over done_now tiles captured in this run); -1 when nothing was timed yet. */
double tile_session_eta_s(const json_t *painting, size_t done_in_run, double elapsed_s);
