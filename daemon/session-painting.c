/* Sessions of a plan with a painting group (docs/painting.md, "The daemon's side"): the plan's
 * frames are one tile's; the session directory holds plan.cfg, rig.json, painting.json and
 * one capture set per tile (tiles/NNNN), so that `impasto mosaic SESSION` reads it as it reads
 * `impasto sim render --painting`. Before the first frame of a tile the stage moves there and
 * settles (tile-session.c); every frame records the commanded and read-back position; a
 * finished tile is marked done in painting.json and queued for processing at once, while the
 * next tile is captured. A stage fault pauses the session with a message naming the tile and
 * the remedy; resuming clears the fault, homes the stage when its position is not known, and
 * continues at the first frame not captured (after SIGKILL too: each tile set is crash-safe). */
#include <dirent.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "tile-session.h"

#define STAGE_HOME_TIMEOUT_MS 120000U   /* a homing cycle across a 2 m gantry, and some */

static void tile_dir(const struct session *s, size_t k, char *buf, size_t size) {
        snprintf(buf, size, "%.3900s/tiles/%04zu", s->dir, k);
}

/* painting.json or tiles/ (painting.json may be the damaged part), and no set.json. */
bool painting_session_dir(const char *dir) {
        char p[PATH_MAX + 32], t[PATH_MAX + 32];
        struct stat st;
        snprintf(p, sizeof p, "%.4000s/painting.json", dir);
        snprintf(t, sizeof t, "%.4000s/tiles", dir);
        if (access(p, F_OK) < 0 && !(lstat(t, &st) == 0 && S_ISDIR(st.st_mode)))
                return false;
        snprintf(p, sizeof p, "%.4000s/set.json", dir);
        return access(p, F_OK) < 0;
}

static struct imp_stage *stage_of(const struct session *s) {
        return s->d->rigcfg->stage.stage;
}

static void set_tiles(struct session *s) {
        s->tiles = imp_plan_tiles(s->plan);
        s->tile_frames = imp_plan_count(s->plan);
        s->frames_total = imp_tile_plan_count(s->tiles) * s->tile_frames;
        s->cs_tile = -1;
        s->at_tile = false;
}

/* SESSION/: plan.cfg (the bytes checked), rig.json, painting.json; no tile set yet. */
int painting_start(struct session *s, const char *plan_text, struct imp_proto_error *perr) {
        struct imp_error e = { 0 };
        set_tiles(s);
        int r = imp_mkdir_p(s->dir, 0750);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s: %s", s->dir, strerror(-r));
        char p[PATH_MAX + 32];
        snprintf(p, sizeof p, "%.4000s/plan.cfg", s->dir);
        _cleanup_fclose_ FILE *f = fopen(p, "wxe");
        if (!f || fputs(plan_text, f) < 0 || fflush(f) != 0 || fsync(fileno(f)) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, errno, NULL, "%s: %s", p, strerror(errno));
        snprintf(p, sizeof p, "%.4000s/rig.json", s->dir);
        if ((r = imp_rig_save(p, &s->rig, &e)) < 0 ||
            (r = tile_session_open(s->dir, s->tiles, s->d->rigcfg->stage.sigma_mm, s->d->rigcfg->stage.sigma_deg,
                                   &s->painting, &e)) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
        return 0;
}

/* Before capturing (start, resume): a latched fault cleared and the position known, homing
 * when needed (a restarted daemon, a limit switch, a lost position). The homing is started
 * here and polled by painting_step: the event loop does not wait for it. */
int painting_prepare_stage(struct session *s, struct imp_proto_error *perr) {
        struct dev_stage *ds = &s->d->rigcfg->stage;
        if (!ds->configured)
                return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, EINVAL, "args.plan",
                                           "%s: a plan with a painting group needs a stage in the rig config "
                                           "(rig.stage = { backend; address; }, docs/painting.md)", s->plan_path);
        if (!ds->stage)
                return imp_proto_error_set(perr, IMP_PROTO_E_DEVICE, ENODEV, ds->name, "stage %s: %s", ds->name,
                                           ds->detail);
        struct imp_stage_status st = { 0 };
        int r = imp_stage_get_status(ds->stage, &st);
        if (r >= 0 && st.fault != IMP_STAGE_FAULT_NONE) {
                log_notice("session %s: stage: clearing the latched fault (%s, code %u) to resume", s->id,
                           imp_stage_fault_name(st.fault), st.fault_code);
                r = imp_stage_clear_fault(ds->stage);
                if (r >= 0)
                        r = imp_stage_get_status(ds->stage, &st);
        }
        s->stage_op = STAGE_OP_NONE;
        if (r >= 0 && !(st.flags & IMP_STAGE_HOMED)) {
                log_notice("session %s: stage: position not known, homing", s->id);
                r = imp_stage_home(ds->stage);
                if (r >= 0) {
                        s->stage_op = STAGE_OP_HOMING;
                        s->stage_deadline_us = imp_stage_deadline_us(STAGE_HOME_TIMEOUT_MS);
                }
        }
        s->at_tile = false;
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_DEVICE, -r, ds->name,
                                           "stage %s: clearing faults and homing before the scan: %s (%s): check "
                                           "the gantry, then resume", ds->name, strerror(-r),
                                           imp_stage_last_error(ds->stage));
        return 0;
}

/* The homing started by painting_prepare_stage: PAINTING_POLL while it runs, 0 once homed. */
static int poll_homing(struct session *s, char *msg, size_t size) {
        struct dev_stage *ds = &s->d->rigcfg->stage;
        int r = imp_stage_poll_settled(ds->stage, s->stage_deadline_us, STAGE_HOME_TIMEOUT_MS, NULL);
        if (r == -EAGAIN)
                return PAINTING_POLL;
        s->stage_op = STAGE_OP_NONE;
        if (r < 0) {
                snprintf(msg, size, "stage %s: homing before the scan: %s (%s): check the gantry, then resume",
                         ds->name, strerror(-r), imp_stage_last_error(ds->stage));
                return r;
        }
        log_notice("session %s: stage: homed", s->id);
        return 0;
}

void painting_stop_stage(struct session *s) {
        if (s->stage_op == STAGE_OP_NONE)
                return;
        struct imp_stage *stage = stage_of(s);
        int r = stage ? imp_stage_soft_stop(stage) : -ENODEV;
        if (r < 0)
                log_warning("session %s: stage: soft-stopping the %s: %s (%s)", s->id,
                            s->stage_op == STAGE_OP_HOMING ? "homing" : "move", strerror(-r),
                            imp_stage_last_error(stage));
        else
                log_notice("session %s: stage: %s soft-stopped", s->id,
                           s->stage_op == STAGE_OP_HOMING ? "homing" : "move to the tile");
        s->stage_op = STAGE_OP_NONE;
        s->at_tile = false;
}

static void queue_tile(struct session *s, size_t k) {
        char id[200], set[PATH_MAX], out[PATH_MAX + 32];
        snprintf(id, sizeof id, "%.127s-tile%04zu", s->id, k);
        tile_dir(s, k, set, sizeof set);
        snprintf(out, sizeof out, "%.3900s/copies/%04zu", s->dir, k);
        int r = jobs_enqueue_set(s->d, s->id, id, set, out);
        if (r < 0 && r != -EEXIST)
                log_error_errno(r, "session %s: queueing tile %zu: %m", s->id, k);
}

/* Tile k captured: done in painting.json (with its read-back), then queued. */
static int tile_done(struct session *s, size_t k, const double readback_mm[3], struct imp_error *e) {
        int r = tile_session_record(s->dir, s->painting, k, readback_mm, true, e);
        if (r < 0)
                return r;
        log_info("session %s: tile %zu of %zu captured", s->id, k + 1, imp_tile_plan_count(s->tiles));
        queue_tile(s, k);
        return 0;
}

static void close_tile(struct session *s) {
        store_writer_free(s->writer);
        s->writer = NULL;
        imp_captureset_close(s->cs);
        s->cs = NULL;
        s->cs_tile = -1;
        s->at_tile = false;
}

/* The records of a tile set must be the plan's frames, in order. */
static int check_tile_records(const struct session *s, size_t k, char *msg, size_t size) {
        size_t n = imp_captureset_count(s->cs);
        if (n > s->tile_frames) {
                snprintf(msg, size, "%s/tiles/%04zu: %zu frames stored, a tile has %zu", s->dir, k, n, s->tile_frames);
                return -EBADMSG;
        }
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *a = imp_captureset_record(s->cs, i), *b = imp_plan_frame(s->plan, i);
                if (a->seq != (long long) i || a->light != b->light || a->exposure_us != b->exposure_us ||
                    strcmp(a->camera, b->camera) || a->tile != b->tile) {
                        snprintf(msg, size, "%s/tiles/%04zu: frame %zu does not match the plan", s->dir, k, i);
                        return -EBADMSG;
                }
        }
        return 0;
}

static bool access_tile(const struct session *s, size_t k) {
        char dir[PATH_MAX];
        tile_dir(s, k, dir, sizeof dir);
        return access(dir, F_OK) == 0;
}

/* Tile k's set, when there is one, must be a directory of the session: the daemon writes
 * there, and a symbolic link would send its frames (and repairs) elsewhere. */
static int check_tile_dir(const struct session *s, size_t k, char *msg, size_t size) {
        char dir[PATH_MAX];
        struct stat st;
        tile_dir(s, k, dir, sizeof dir);
        if (lstat(dir, &st) < 0 || S_ISDIR(st.st_mode))
                return 0;
        snprintf(msg, size, "%.400s: %s, not the tile's capture set (a directory of the session): the session is left as "
                 "it is; put tile %zu's set itself there (or remove it to capture the tile again), then resume", dir,
                 S_ISLNK(st.st_mode) ? "a symbolic link" : "not a directory", k);
        return -ENOTDIR;
}

/* Opens tile k's set (made when missing, repaired after a crash) as s->cs. */
static int open_tile(struct session *s, size_t k, char *msg, size_t size) {
        char dir[PATH_MAX];
        tile_dir(s, k, dir, sizeof dir);
        struct imp_error e = { 0 };
        int r;
        char set[PATH_MAX + 16];
        snprintf(set, sizeof set, "%.4000s/set.json", dir);
        if ((r = check_tile_dir(s, k, msg, size)) < 0)
                return r;
        if (access(dir, F_OK) == 0 && access(set, F_OK) < 0) {
                /* no set.json: a create cut short (by a SIGKILL), no frame in it; kept aside */
                char aside[PATH_MAX + 64];
                for (int n = 1; n < 1000; n++) {
                        snprintf(aside, sizeof aside, "%.4000s.interrupted-%d", dir, n);
                        if (access(aside, F_OK) < 0)
                                break;
                }
                if (rename(dir, aside) < 0) {
                        snprintf(msg, size, "%s: an interrupted create: moving it to %s: %s", dir, aside,
                                 strerror(errno));
                        return -errno;
                }
                log_warning("session %s: tile %zu: %s had no set.json (a create cut short): moved to %s", s->id,
                            k, dir, aside);
        }
        if (access(dir, F_OK) < 0) {
                char plan[PATH_MAX + 16];
                snprintf(plan, sizeof plan, "%.4000s/plan.cfg", s->dir);
                r = imp_captureset_create(dir, &s->rig, plan, &s->cs, &e);
        } else {
                json_t *report = NULL;
                r = imp_captureset_repair(dir, false, &report, &e);
                size_t i;
                json_t *item;
                json_array_foreach(report, i, item)
                        log_warning("session %s: tile %zu: moved %s to %s: %s", s->id, k,
                                    json_string_value(json_object_get(item, "path")),
                                    json_string_value(json_object_get(item, "moved_to")),
                                    json_string_value(json_object_get(item, "reason")));
                json_decref(report);
                if (r >= 0)
                        r = imp_captureset_open(dir, &s->cs, &e);
        }
        if (r < 0) {
                snprintf(msg, size, "%s", e.msg);
                return r;
        }
        s->cs_tile = (int) k;
        if ((r = check_tile_records(s, k, msg, size)) < 0)
                close_tile(s);
        return r;
}

/* The move to tile k (the open tile set's) is sent; painting_step polls it. */
static int start_move(struct session *s, size_t k, char *msg, size_t size) {
        const struct imp_tile *t = imp_tile_plan_tile(s->tiles, k);
        int r = tile_session_move_start(stage_of(s), t, msg, size);
        if (r < 0)
                return r;
        s->stage_op = STAGE_OP_MOVING;
        s->stage_deadline_us = imp_stage_deadline_us(s->d->rigcfg->stage.settle_timeout_ms);
        s->at_tile = false;
        log_info("session %s: stage: moving to tile %zu (col %u, row %u) at (%.3f, %.3f, %.3f) mm", s->id, k, t->col,
                 t->row, t->stage_mm[0], t->stage_mm[1], t->stage_mm[2]);
        return PAINTING_MOVE_STARTED;
}

/* One poll of the move to tile k: PAINTING_POLL while it goes on; 1 once settled and read
 * back (the read-back in painting.json at once): the tile's frames follow. */
static int poll_move(struct session *s, size_t k, char *msg, size_t size) {
        const struct imp_tile *t = imp_tile_plan_tile(s->tiles, k);
        double rb[3];
        int r = tile_session_move_poll(stage_of(s), t, s->stage_deadline_us, s->d->rigcfg->stage.settle_timeout_ms,
                                       rb, msg, size);
        if (r == 0)
                return PAINTING_POLL;
        s->stage_op = STAGE_OP_NONE;
        if (r < 0)
                return r;
        memcpy(s->stage_cmd_mm, t->stage_mm, sizeof s->stage_cmd_mm);
        memcpy(s->stage_rb_mm, rb, sizeof s->stage_rb_mm);
        s->at_tile = true;
        struct imp_error e = { 0 };
        if ((r = tile_session_record(s->dir, s->painting, k, rb, false, &e)) < 0) {
                snprintf(msg, size, "%s", e.msg);
                return r;
        }
        s->shown_pattern = -2;          /* settle at the tile's first frame */
        log_info("session %s: tile %zu of %zu at (%.3f, %.3f, %.3f) mm, frame %zu of %zu", s->id, k + 1,
                 imp_tile_plan_count(s->tiles), s->stage_rb_mm[0], s->stage_rb_mm[1], s->stage_rb_mm[2],
                 s->n_captured % s->tile_frames, s->tile_frames);
        return 1;
}

/* Between frames of a tile: the stage must still stand where the tile's frames were taken. */
static int check_stage(struct session *s, size_t k, size_t i, char *msg, size_t size) {
        struct imp_stage_status st = { 0 };
        struct imp_stage *stage = stage_of(s);
        int r = stage ? imp_stage_get_status(stage, &st) : -ENODEV;
        struct imp_stage_config cfg = { .tolerance_mm = IMP_STAGE_DEFAULT_TOLERANCE_MM };
        if (stage)
                (void) imp_stage_get_config(stage, &cfg);
        const char *why = r < 0 ? strerror(-r) : st.fault != IMP_STAGE_FAULT_NONE ? imp_stage_fault_name(st.fault)
                          : !(st.flags & IMP_STAGE_HOMED) ? "position lost" : NULL;
        for (int a = 0; !why && a < 2; a++)
                if (fabs(st.position_mm[a] - s->stage_rb_mm[a]) > cfg.tolerance_mm)
                        why = "the carriage moved away from the tile";
        if (!why)
                return 0;
        const struct imp_tile *t = imp_tile_plan_tile(s->tiles, k);
        snprintf(msg, size, "stage: %s during tile %zu (col %u, row %u) at its frame %zu of %zu: the frames "
                 "before it are kept; clear the fault, home the stage, then resume (the tile continues at frame "
                 "%zu)", why, k, t->col, t->row, i, s->tile_frames, i);
        return r < 0 ? r : -EIO;
}

int painting_check_frame(struct session *s, char *msg, size_t size) {
        size_t k = s->n_captured / s->tile_frames, i = s->n_captured % s->tile_frames;
        int r = check_stage(s, k, i, msg, size);
        if (r < 0)
                s->at_tile = false;
        return r;
}

int painting_step(struct session *s, store_done_fn done, const char **device, char *msg, size_t size) {
        size_t k = s->n_captured / s->tile_frames;
        struct imp_error e = { 0 };
        int r;
        msg[0] = 0;
        *device = s->d->rigcfg->stage.name;
        if (s->stage_op == STAGE_OP_HOMING && (r = poll_homing(s, msg, size)) != 0)
                return r;
        if (s->stage_op == STAGE_OP_MOVING)
                return poll_move(s, k, msg, size);
        if ((int) k == s->cs_tile && s->at_tile) {
                r = painting_check_frame(s, msg, size);
                return r < 0 ? r : 1;
        }
        if (s->n_frames < s->n_captured)
                return 0;               /* the last tile's frames are not all durable yet */
        if (s->cs_tile >= 0 && (size_t) s->cs_tile != k) {
                size_t prev = (size_t) s->cs_tile;
                double rb[3];
                memcpy(rb, s->stage_rb_mm, sizeof rb);
                close_tile(s);
                if ((r = tile_done(s, prev, rb, &e)) < 0) {
                        *device = NULL;
                        snprintf(msg, size, "%s", e.msg);
                        return r;
                }
        }
        if ((s->cs_tile < 0 && (r = open_tile(s, k, msg, size)) < 0) ||
            (!s->writer && (r = store_writer_new(s->d->event, s->cs, done, s, &s->writer)) < 0)) {
                if (!msg[0])
                        snprintf(msg, size, "tile %zu: starting the store writer: %s", k, strerror(-r));
                *device = NULL;
                return r;
        }
        return start_move(s, k, msg, size);
}

void painting_stamp(const struct session *s, struct imp_frame_record *rec) {
        if (!s->tiles)
                return;
        rec->has_stage = true;
        memcpy(rec->stage_commanded_mm, s->stage_cmd_mm, sizeof rec->stage_commanded_mm);
        memcpy(rec->stage_readback_mm, s->stage_rb_mm, sizeof rec->stage_readback_mm);
}

void painting_finish(struct session *s) {
        if (s->cs_tile < 0 || s->n_frames < s->frames_total)
                return;
        size_t k = (size_t) s->cs_tile;
        double rb[3];
        memcpy(rb, s->stage_rb_mm, sizeof rb);
        close_tile(s);
        struct imp_error e = { 0 };
        if (tile_done(s, k, rb, &e) < 0)
                log_error("session %s: %s", s->id, e.msg);
}

/* A tile painting.json marks captured: its set must hold the tile's frames. Read only (the
 * set is not repaired: a damage there is not a crash's, and nothing is written to it again). */
static int check_done_tile(const struct session *s, size_t k, char *msg, size_t size) {
        char dir[PATH_MAX];
        tile_dir(s, k, dir, sizeof dir);
        int r = check_tile_dir(s, k, msg, size);
        if (r < 0)
                return r;
        struct imp_error e = { 0 };
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        if (access(dir, F_OK) < 0)
                snprintf(e.msg, sizeof e.msg, "%.400s: missing", dir), r = -ENOENT;
        else if ((r = imp_captureset_open(dir, &cs, &e)) >= 0 && imp_captureset_count(cs) != s->tile_frames)
                snprintf(e.msg, sizeof e.msg, "%.400s: %zu of the tile's %zu frames", dir, imp_captureset_count(cs),
                         s->tile_frames), r = -EBADMSG;
        if (r < 0)
                snprintf(msg, size, "%.400s; but %.300s/painting.json marks tile %zu captured: its frames are not all "
                         "there; the session is left as it is: restore the tile's set (or mark the tile not done in "
                         "painting.json and remove the set to capture it again), then resume", e.msg, s->dir, k);
        return r;
}

/* No tile set beyond the plan's tiles (tiles/NNNN, NNNN ≥ the tile count), and none after
 * first_open, the first tile not captured (capture continues there: a later set means a set
 * before it went missing or was cut short). Reads only. */
static int check_tile_layout(const struct session *s, size_t first_open, char *msg, size_t size) {
        size_t n = imp_tile_plan_count(s->tiles);
        char tdir[PATH_MAX + 16];
        snprintf(tdir, sizeof tdir, "%.4000s/tiles", s->dir);
        DIR *d = opendir(tdir);
        if (!d)
                return 0;
        struct dirent *de;
        int r = 0;
        while (r == 0 && (de = readdir(d))) {
                size_t len = strlen(de->d_name);
                if (len == 0 || len > 9 || strspn(de->d_name, "0123456789") != len)
                        continue;       /* ".", "NNNN.interrupted-N" and the like */
                size_t k = (size_t) strtoul(de->d_name, NULL, 10);
                if (k >= n)
                        snprintf(msg, size, "%.300s/%.12s: a tile set beyond the plan's %zu tiles (0..%zu): not this "
                                 "painting's; the session is left as it is: move it away, then resume", tdir,
                                 de->d_name, n, n - 1), r = -EBADMSG;
                else if (k > first_open)
                        snprintf(msg, size, "%.300s/%.12s: tile %zu's set is there, but tile %zu before it is not complete "
                                 "(its set missing or cut short): capture would continue at tile %zu; the session is "
                                 "left as it is: restore the missing set (or move %.300s/%.12s away), then resume", tdir,
                                 de->d_name, k, first_open, first_open, tdir, de->d_name), r = -EBADMSG;
        }
        closedir(d);
        return r;
}

/* painting.json unreadable or damaged: kept aside and made anew from the plan; the loop in
 * painting_reopen marks the tiles whose set is complete done again, with their read-back. */
static int rebuild_painting_json(struct session *s, const struct imp_error *why, struct imp_proto_error *perr) {
        char aside[PATH_MAX + 64];
        struct imp_error e = { 0 };
        int r = tile_session_rebuild(s->dir, s->tiles, s->d->rigcfg->stage.sigma_mm, s->d->rigcfg->stage.sigma_deg,
                                     aside, sizeof aside, &s->painting, &e);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s (rebuilding it after: %s)", e.msg,
                                           why->msg);
        snprintf(s->rebuilt, sizeof s->rebuilt, "painting.json rebuilt from the plan and the tile sets: it was "
                 "damaged (%.500s); kept as %.300s", why->msg, aside);
        log_warning("session %s: %s", s->id, s->rebuilt);
        return 0;
}

/* After a pause, a restart or a SIGKILL (plan and rig loaded): tiles whose set is complete
 * are done (and queued, once), the first other one is opened; capture continues at its
 * first frame not stored. painting.json damaged: rebuilt; a tile set missing, cut short,
 * out of range or a symbolic link: an error naming it, nothing changed. */
int painting_reopen(struct session *s, struct imp_proto_error *perr) {
        struct imp_error e = { 0 };
        char msg[2048] = "";
        int r;
        if (!imp_plan_tiles(s->plan))
                return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, EINVAL, NULL,
                                           "%s/plan.cfg: no painting group, but the session holds painting.json",
                                           s->dir);
        close_tile(s);
        set_tiles(s);
        if (!s->painting && (r = tile_session_open(s->dir, s->tiles, s->d->rigcfg->stage.sigma_mm,
                                                   s->d->rigcfg->stage.sigma_deg, &s->painting, &e)) < 0) {
                if (r != -EBADMSG)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
                if ((r = rebuild_painting_json(s, &e, perr)) < 0)
                        return r;
        }
        size_t n = imp_tile_plan_count(s->tiles), k = tile_session_next(s->painting);
        size_t first_missing = k;
        while (first_missing < n && check_tile_dir(s, first_missing, msg, sizeof msg) == 0 &&
               access_tile(s, first_missing))
                first_missing++;
        for (size_t j = 0; j < k && j < n; j++)
                if ((r = check_done_tile(s, j, msg, sizeof msg)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", msg);
        if ((r = check_tile_layout(s, first_missing, msg, sizeof msg)) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", msg);
        for (; k < n; k++) {
                char dir[PATH_MAX];
                tile_dir(s, k, dir, sizeof dir);
                if (access(dir, F_OK) < 0)
                        break;
                if ((r = open_tile(s, k, msg, sizeof msg)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", msg);
                size_t have = imp_captureset_count(s->cs);
                if (have < s->tile_frames)
                        break;
                double rb[3];
                memcpy(rb, imp_captureset_record(s->cs, have - 1)->stage_readback_mm, sizeof rb);
                close_tile(s);
                if ((r = tile_done(s, k, rb, &e)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
        }
        if ((r = check_tile_layout(s, k, msg, sizeof msg)) < 0) {
                close_tile(s);
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", msg);
        }
        for (size_t j = 0; j < k && j < n; j++)
                queue_tile(s, j);       /* a kill between "done" and the queue: queued now */
        s->n_frames = k * s->tile_frames + (s->cs ? imp_captureset_count(s->cs) : 0);
        s->bytes = 0;
        return 0;
}

json_t *painting_progress_json(const struct session *s, double eta_s) {
        if (!s->tiles || !s->painting || s->tile_frames == 0)
                return NULL;
        size_t n = imp_tile_plan_count(s->tiles), done = tile_session_next(s->painting);
        size_t k = IMP_MIN(s->n_frames / s->tile_frames, n > 0 ? n - 1 : 0);
        size_t in_tile = s->n_frames - k * s->tile_frames;
        size_t left = s->frames_total - s->n_frames;
        double tile_eta = left > 0 && eta_s >= 0 ? eta_s * (double) (s->tile_frames - in_tile) / (double) left : 0;
        json_t *j = json_pack("{s:I, s:I, s:I, s:I, s:I, s:f}", "tiles", (json_int_t) n, "tiles_done",
                              (json_int_t) done, "tile", (json_int_t) k, "tile_frames", (json_int_t) s->tile_frames,
                              "tile_frames_done", (json_int_t) in_tile, "tile_eta_s", tile_eta);
        if (j && s->stage_op != STAGE_OP_NONE) {
                char what[200] = "homing";
                const struct imp_tile *t = s->cs_tile >= 0 ? imp_tile_plan_tile(s->tiles, (size_t) s->cs_tile) : NULL;
                if (s->stage_op == STAGE_OP_MOVING && t)
                        snprintf(what, sizeof what, "moving to tile %d (col %u, row %u) at (%.3f, %.3f, %.3f) mm",
                                 s->cs_tile, t->col, t->row, t->stage_mm[0], t->stage_mm[1], t->stage_mm[2]);
                json_object_set_new(j, "stage", json_string(what));
        }
        return j;
}
