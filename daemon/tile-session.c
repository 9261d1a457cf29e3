/* Whole-painting sessions: moving the gantry tile by tile and the painting's progress
 * (tile-session.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>
#include "json-util.h"
#include "tile-session.h"

static unsigned tile_mask(struct imp_stage *stage) {
        struct imp_stage_info info;
        return imp_stage_get_info(stage, &info) == 0 && info.n_axes >= 3 ? IMP_STAGE_XYZ : IMP_STAGE_XY;
}

/* What the operator reads when a move fails: the fault, the tile, and what to do next. */
static int move_failed(struct imp_stage *stage, const struct imp_tile *t, int r, const struct imp_stage_status *st,
                       char *msg, size_t size) {
        const char *detail = imp_stage_last_error(stage);
        char where[160];
        snprintf(where, sizeof where, "tile %u (col %u, row %u) at (%.3f, %.3f, %.3f) mm", t->index, t->col, t->row,
                 t->stage_mm[0], t->stage_mm[1], t->stage_mm[2]);
        if (r == -ESTALE)
                snprintf(msg, size, "stage: position not known (never homed, or lost) before %s: home the stage, "
                         "then resume", where);
        else if (r == -EIO && st && st->fault != IMP_STAGE_FAULT_NONE)
                snprintf(msg, size, "stage: %s (controller code %u) moving to %s: clear the fault, home the stage, "
                         "then resume (%s)", imp_stage_fault_name(st->fault), st->fault_code, where, detail);
        else if (r == -ETIMEDOUT)
                snprintf(msg, size, "stage: the move to %s did not settle (stopped): check the gantry, home it, "
                         "then resume (%s)", where, detail);
        else if (r == -ERANGE)
                snprintf(msg, size, "stage: %s lies outside the stage's soft limits: fix the plan's origin_mm or "
                         "the rig's limits (%s)", where, detail);
        else
                snprintf(msg, size, "stage: moving to %s: %s (%s)", where, strerror(-r), detail);
        return r;
}

int tile_session_move_start(struct imp_stage *stage, const struct imp_tile *t, char *msg, size_t size) {
        struct imp_stage_status st = { 0 };
        int r = imp_stage_move_to(stage, t->stage_mm, tile_mask(stage));
        if (r == -EIO)
                (void) imp_stage_get_status(stage, &st);
        return r < 0 ? move_failed(stage, t, r, &st, msg, size) : 0;
}

int tile_session_move_poll(struct imp_stage *stage, const struct imp_tile *t, uint64_t deadline_us,
                           unsigned settle_timeout_ms, double ret_readback_mm[3], char *msg, size_t size) {
        unsigned mask = tile_mask(stage);
        struct imp_stage_status st = { 0 };
        int r = imp_stage_poll_settled(stage, deadline_us, settle_timeout_ms, &st);
        if (r == -EAGAIN)
                return 0;
        if (r < 0)
                return move_failed(stage, t, r, &st, msg, size);
        for (int a = 0; a < 3; a++)
                ret_readback_mm[a] = a < 2 || (mask & IMP_STAGE_Z) ? st.position_mm[a] : t->stage_mm[a];
        return 1;
}

int tile_session_move(struct imp_stage *stage, const struct imp_tile *t, unsigned settle_timeout_ms,
                      double ret_readback_mm[3], char *msg, size_t size) {
        int r = tile_session_move_start(stage, t, msg, size);
        uint64_t deadline = imp_stage_deadline_us(settle_timeout_ms);
        while (r >= 0 && (r = tile_session_move_poll(stage, t, deadline, settle_timeout_ms, ret_readback_mm, msg,
                                                     size)) == 0)
                usleep(IMP_STAGE_POLL_INTERVAL_MS * 1000u);
        return r < 0 ? r : 0;
}

static int save(const char *dir, const json_t *painting, struct imp_error *err) {
        char path[4096];
        if (snprintf(path, sizeof path, "%s/painting.json", dir) >= (int) sizeof path)
                return imp_error_set(err, -ENAMETOOLONG, "%s: path too long", dir);
        return imp_json_save_atomic(path, painting, err);
}

/* A painting.json left by an earlier run must describe the same tiles. */
static int check_same(const json_t *j, const struct imp_tile_plan *tp, const char *path, struct imp_error *err) {
        const json_t *tiles = json_object_get(j, "tiles");
        if (!json_is_array(tiles) || json_array_size(tiles) != imp_tile_plan_count(tp))
                return imp_error_set(err, -EINVAL, "%s: tiles: expected %zu tiles (the plan's), got %zu", path,
                                     imp_tile_plan_count(tp), json_array_size(tiles));
        for (size_t k = 0; k < json_array_size(tiles); k++) {
                double c[3] = { 0 };
                int r = imp_json_get_doubles(json_array_get(tiles, k), "commanded_mm", true, 3, c, path, err);
                if (r < 0)
                        return r;
                for (int a = 0; a < 3; a++)
                        if (fabs(c[a] - imp_tile_plan_tile(tp, k)->stage_mm[a]) > 1e-6)
                                return imp_error_set(err, -EINVAL, "%s: tiles[%zu].commanded_mm: the plan's tile "
                                                     "is elsewhere (%.3f mm, not %.3f mm): another plan", path, k,
                                                     imp_tile_plan_tile(tp, k)->stage_mm[a], c[a]);
        }
        return 0;
}

static int make_new(const char *dir, const struct imp_tile_plan *tp, double stage_sigma_mm, double stage_sigma_deg,
                    json_t **ret, struct imp_error *err) {
        json_t *j = imp_tile_plan_painting_json(tp, stage_sigma_mm, stage_sigma_deg);
        if (!j)
                return imp_error_set(err, -ENOMEM, "%s/painting.json: out of memory", dir);
        int r = save(dir, j, err);
        if (r < 0) {
                json_decref(j);
                return r;
        }
        *ret = j;
        return 0;
}

int tile_session_rebuild(const char *dir, const struct imp_tile_plan *tp, double stage_sigma_mm,
                         double stage_sigma_deg, char *ret_aside, size_t aside_size, json_t **ret,
                         struct imp_error *err) {
        char path[4096];
        if (snprintf(path, sizeof path, "%s/painting.json", dir) >= (int) sizeof path)
                return imp_error_set(err, -ENAMETOOLONG, "%s: path too long", dir);
        for (int n = 1;; n++) {
                if (n > 1000)
                        return imp_error_set(err, -EEXIST, "%s: no free name to keep it aside", path);
                snprintf(ret_aside, aside_size, "%s.damaged-%d", path, n);
                if (access(ret_aside, F_OK) < 0 && errno == ENOENT)
                        break;
        }
        /* link + unlink, not rename: a name taken meanwhile is never overwritten */
        if (link(path, ret_aside) < 0 || unlink(path) < 0)
                return imp_error_set(err, -errno, "%s: keeping it aside as %s: %s", path, ret_aside, strerror(errno));
        return make_new(dir, tp, stage_sigma_mm, stage_sigma_deg, ret, err);
}

int tile_session_open(const char *dir, const struct imp_tile_plan *tp, double stage_sigma_mm, double stage_sigma_deg,
                      json_t **ret, struct imp_error *err) {
        char path[4096];
        if (snprintf(path, sizeof path, "%s/painting.json", dir) >= (int) sizeof path)
                return imp_error_set(err, -ENAMETOOLONG, "%s: path too long", dir);
        json_t *j = NULL;
        int r = imp_painting_json_load(path, &j, err);
        if (r == -ENOENT) {
                imp_error_clear(err);
                if ((r = make_new(dir, tp, stage_sigma_mm, stage_sigma_deg, &j, err)) < 0)
                        return r;
        } else if (r < 0) {
                return r;
        } else if ((r = check_same(j, tp, path, err)) < 0) {
                json_decref(j);
                return r;
        }
        *ret = j;
        return 0;
}

int tile_session_record(const char *dir, json_t *painting, size_t k, const double readback_mm[3], bool done,
                        struct imp_error *err) {
        int r = imp_painting_json_set_readback(painting, k, readback_mm);
        if (r < 0)
                return imp_error_set(err, r, "painting.json: tile %zu: %s", k, strerror(-r));
        json_object_set_new(json_array_get(json_object_get(painting, "tiles"), k), "done", json_boolean(done));
        return save(dir, painting, err);
}

size_t tile_session_next(const json_t *painting) {
        const json_t *tiles = json_object_get(painting, "tiles");
        size_t n = json_array_size(tiles);
        for (size_t k = 0; k < n; k++)
                if (!json_is_true(json_object_get(json_array_get(tiles, k), "done")))
                        return k;
        return n;
}

double tile_session_eta_s(const json_t *painting, size_t done_in_run, double elapsed_s) {
        size_t n = json_array_size(json_object_get(painting, "tiles"));
        size_t left = n - IMP_MIN(tile_session_next(painting), n);
        if (left == 0)
                return 0;
        if (done_in_run == 0 || !(elapsed_s > 0))
                return -1;
        return elapsed_s / (double) done_in_run * (double) left;
}
