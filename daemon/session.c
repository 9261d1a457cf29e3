/* Capture sessions: the state machine (idle → preparing → capturing ⇄ paused → completed |
 * aborted | failed) and the capture loop, driven one step at a time from the event loop so
 * that the socket stays responsive. A frame: (tile move) → projector pattern or dark →
 * light → settle (timer) → exposure/gain (when changed) → trigger → grab → light off when
 * the next frame needs another → store writer (store.c) → next frame. The writer thread makes
 * each frame durable in order while the next one is exposed; `frame` and `progress` events
 * follow its results, so they name durable frames only. Device failures are retried a bounded
 * number of times, then the session pauses with a fault, lights off and projector dark.
 * A run of frames in one state (repeats, dark frames) is streamed: set up once, the camera
 * switched to free running, one frame taken per step, then back to triggers ("Streamed runs"
 * in docs/daemon.md). */
#include <math.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"

#define RETRY_DELAY_US 50000ULL         /* first retry after a failed step; grows linearly */
#define GRAB_MARGIN_MS 2000U            /* beyond the exposure, before a grab times out */
#define AXIS_MOVE_TIMEOUT_MS 60000U
/* Accuracy of the step timer. 0 would mean sd-event's default of 250 ms, within which it
 * coalesces wake-ups: the settle time of every frame became ~180 ms. */
#define STEP_ACCURACY_US 1ULL
/* Streamed runs: the shortest run worth switching the camera for, the wait for a free-running
 * frame beyond the exposure (the camera's frame period is its own), incomplete frames in a
 * row before the run counts as a failed step. */
#define STREAM_MIN_FRAMES 2U
#define STREAM_GRAB_MARGIN_MS 5000U
#define STREAM_MAX_BAD 8U

static const char *const state_names[_SESSION_STATE_MAX] = {
        [SESSION_IDLE] = "idle",
        [SESSION_PREPARING] = "preparing",
        [SESSION_CAPTURING] = "running",
        [SESSION_PAUSED] = "paused",
        [SESSION_ABORTED] = "aborted",
        [SESSION_FAILED] = "failed",
        [SESSION_COMPLETED] = "completed",
};

const char *session_state_name(enum session_state s) {
        return state_names[s];
}

int session_state_from_name(const char *s) {
        for (int i = 0; i < _SESSION_STATE_MAX; i++)
                if (!strcmp(s, state_names[i]))
                        return i;
        if (!strcmp(s, "capturing"))
                return SESSION_CAPTURING;
        return -EINVAL;
}

static uint64_t now_ns(clockid_t clk) {
        struct timespec ts;
        clock_gettime(clk, &ts);
        return (uint64_t) ts.tv_sec * 1000000000ULL + (uint64_t) ts.tv_nsec;
}

/* Frame g of the session: of a painting, frame g mod tile_frames of the plan (one tile's). */
static const struct imp_frame_record *plan_at(const struct session *s, size_t g) {
        return imp_plan_frame(s->plan, s->tiles && s->tile_frames ? g % s->tile_frames : g);
}

struct session *session_find(struct daemon *d, const char *id) {
        for (struct session *s = d->sessions; s; s = s->next)
                if (!strcmp(s->id, id))
                        return s;
        return NULL;
}

void session_free(struct session *s) {
        if (!s)
                return;
        json_decref(s->painting);
        sd_event_source_disable_unref(s->step_source);
        store_writer_free(s->writer);
        imp_captureset_close(s->cs);
        imp_plan_free(s->plan);
        if (s->have_rig)
                imp_rig_free(&s->rig);
        json_decref(s->faults);
        free(s->patterns);
        free(s);
}

static void pattern_name(const struct imp_pattern *p, char *buf, size_t size) {
        static const char *const kinds[] = { "dark", "white", "black", "gray", "phase" };
        if (p->kind == IMP_PAT_GRAY)
                snprintf(buf, size, "gray-%c-%d%s", p->axis ? 'y' : 'x', p->bit, p->inverse ? "-inv" : "");
        else if (p->kind == IMP_PAT_PHASE)
                snprintf(buf, size, "phase-%c-%g-%d/%d", p->axis ? 'y' : 'x', p->period_px, p->step, p->steps);
        else
                snprintf(buf, size, "%s", kinds[p->kind]);
}

static bool same_pattern(const struct imp_pattern *a, const struct imp_pattern *b) {
        return a->kind == b->kind && a->axis == b->axis && a->bit == b->bit && a->nbits == b->nbits &&
               a->inverse == b->inverse && a->period_px == b->period_px && a->step == b->step &&
               a->steps == b->steps;
}

/* The distinct projector patterns of the plan, in first-use order: the upload sequence. */
static int collect_patterns(struct session *s) {
        free(s->patterns);
        s->patterns = NULL;
        s->n_patterns = 0;
        size_t n = imp_plan_count(s->plan);
        for (size_t i = 0; i < n; i++) {
                const struct imp_pattern *p = &imp_plan_frame(s->plan, i)->pattern;
                if (p->kind == IMP_PAT_NONE)
                        continue;
                unsigned k;
                for (k = 0; k < s->n_patterns; k++)
                        if (same_pattern(&s->patterns[k], p))
                                break;
                if (k < s->n_patterns)
                        continue;
                struct imp_pattern *np = realloc(s->patterns, (s->n_patterns + 1) * sizeof *np);
                if (!np)
                        return -ENOMEM;
                s->patterns = np;
                s->patterns[s->n_patterns++] = *p;
        }
        return 0;
}

static int pattern_index(const struct session *s, const struct imp_pattern *p) {
        for (unsigned k = 0; k < s->n_patterns; k++)
                if (same_pattern(&s->patterns[k], p))
                        return (int) k;
        return -1;
}

int plan_check(struct daemon *d, const char *path, struct imp_plan **ret, struct imp_proto_error *perr) {
        return plan_load_text(d, path, ret, NULL, perr);
}

/* ---- events ---------------------------------------------------------------------------- */

/* From this run's rate (a painting's: tile moves included), else from the plan's estimate. */
static double eta_now(const struct session *s) {
        size_t remaining = s->frames_total - s->n_frames;
        size_t done_run = s->n_frames - s->run_started_frames;
        if (done_run > 0 && s->state == SESSION_CAPTURING) {
                double el_s = (double) (now_ns(CLOCK_MONOTONIC) / 1000 - s->run_started_us) / 1e6;
                return el_s / (double) done_run * (double) remaining;
        }
        double est = s->tiles ? s->estimate_s * (double) imp_tile_plan_count(s->tiles) : s->estimate_s;
        return s->frames_total ? est * (double) remaining / (double) s->frames_total : 0;
}

static void emit_progress(struct session *s) {
        double eta_s = eta_now(s);
        const char *st = s->state == SESSION_PAUSED ? "paused" : "running";
        json_t *ev = json_pack("{s:s, s:I, s:I, s:I, s:I, s:I, s:f, s:s}", "session", s->id,
                               "step", (json_int_t) s->n_frames, "steps", (json_int_t) s->frames_total,
                               "frames", (json_int_t) s->n_frames,
                               "frames_total", (json_int_t) s->frames_total, "bytes",
                               (json_int_t) s->bytes, "eta_s", eta_s, "state", st);
        json_t *pj = painting_progress_json(s, eta_s);
        if (ev && pj)
                json_object_set_new(ev, "painting", pj);
        server_broadcast(s->d, "progress", ev);
}

static void emit_fault(struct session *s, const char *device, enum imp_proto_errcode code, int err,
                       bool fatal, const char *msg) {
        char ts[32];
        rfc3339_now(ts);
        json_t *f = json_pack("{s:s?, s:s, s:i, s:s, s:b, s:s, s:I}", "device", device, "code",
                              imp_proto_error_code_name(code), "errno", err, "message", msg, "fatal", fatal,
                              "time", ts, "frame", (json_int_t) s->n_captured);
        if (f)
                json_array_append(s->faults, f);
        json_t *ev = json_deep_copy(f);
        if (ev) {
                json_object_del(ev, "time");
                json_object_set_new(ev, "session", json_string(s->id));
        }
        json_decref(f);
        server_broadcast(s->d, "fault", ev);
        if (device)
                server_broadcast(s->d, "device", json_pack("{s:s, s:s, s:s}", "device", device, "class",
                                                          !strcmp(device, "dome") ? "dome" :
                                                          !strcmp(device, "projector") ? "projector" :
                                                          !strcmp(device, s->d->rigcfg->stage.name) ? "stage" : "camera",
                                                          "state", "fault"));
}

static void save(struct session *s) {
        struct imp_error e = { 0 };
        int r = store_session_save(s, &e);
        if (r < 0)
                log_error_errno(r, "session %s: saving state: %s", s->id, e.msg);
        daemon_notify_status(s->d);
}

/* ---- the loop ---------------------------------------------------------------------------- */

static int step_cb(sd_event_source *src, uint64_t usec, void *userdata);

static int schedule(struct session *s, uint64_t delay_us) {
        int r;
        if (!s->step_source) {
                r = sd_event_add_time_relative(s->d->event, &s->step_source, CLOCK_MONOTONIC, delay_us,
                                               STEP_ACCURACY_US, step_cb, s);
                if (r >= 0)
                        r = sd_event_source_set_enabled(s->step_source, SD_EVENT_ONESHOT);
                return r;
        }
        r = sd_event_source_set_time_relative(s->step_source, delay_us);
        if (r >= 0)
                r = sd_event_source_set_enabled(s->step_source, SD_EVENT_ONESHOT);
        return r;
}

static void stop_stepping(struct session *s) {
        if (s->step_source)
                (void) sd_event_source_set_enabled(s->step_source, SD_EVENT_OFF);
        s->phase = 0;
        s->attempt = 0;
}

static void forget_exposures(struct rigcfg *rc);

/* Back to triggers after a streamed run (or out of one cut short): frames still in flight
 * are discarded by the camera layer (imp_camera_set_free_run). A camera that cannot go back
 * is closed and opened again (in trigger mode, on a new stream). */
static void stream_stop(struct session *s) {
        struct dev_camera *cam = s->stream_cam;
        if (!cam)
                return;
        s->stream_cam = NULL;
        int r = cam->cam ? imp_camera_set_free_run(cam->cam, false) : 0;
        if (r < 0) {
                log_warning("session %s: camera %s: back to triggers: %s (%s); reopening it", s->id, cam->name,
                            strerror(-r), imp_camera_last_error(cam->cam));
                rigcfg_drop_camera(cam);
                (void) rigcfg_open_devices(s->d->rigcfg, &s->rig, NULL);
        }
}

static void release_rig(struct session *s) {
        if (s->tiles)
                painting_stop_stage(s);
        stream_stop(s);
        rigcfg_safe_state(s->d->rigcfg);
        forget_exposures(s->d->rigcfg);
        s->shown_pattern = -1;
        s->current_tile = -1;
}

/* Stops capturing in state st: no further step, the rig safe, then every frame the writer
 * holds durable (or failed) before this returns, so that nothing is in flight once the
 * session is paused or ended. The state changes first: results delivered meanwhile only
 * count frames (or record a fault) and do not step on. */
static void halt(struct session *s, enum session_state st) {
        stop_stepping(s);
        s->state = st;
        release_rig(s);
        store_writer_flush(s->writer);
}

static void finish(struct session *s, enum session_state st) {
        halt(s, st);
        rfc3339_now(s->ended);
        store_writer_free(s->writer);
        s->writer = NULL;
        imp_captureset_close(s->cs);
        s->cs = NULL;
        if (s->d->active == s)
                s->d->active = NULL;
        if (st == SESSION_COMPLETED)
                painting_finish(s);     /* its last tile done and queued (each tile is a job) */
        save(s);
        log_info("session %s: %s, %zu of %zu frames; streamed %zu frames in %zu runs, %zu lost and re-captured, "
                 "%zu stale discarded, %zu runs cut by a full store queue", s->id, session_state_name(st), s->n_frames,
                 s->frames_total, s->streamed.frames, s->streamed.runs, s->streamed.lost, s->streamed.stale,
                 s->streamed.stops);
        server_broadcast(s->d, "done", json_pack("{s:s, s:s, s:I, s:s}", "session", s->id, "state",
                                                 session_state_name(st), "frames", (json_int_t) s->n_frames,
                                                 "path", s->dir));
        /* a session's end is what a calibration waits for (after the event is queued) */
        calibrations_session_ended(s->d, s->id, session_state_name(st));
        if (st == SESSION_COMPLETED && !s->tiles)
                (void) jobs_enqueue(s->d, s);
}

static void pause_with_fault(struct session *s, const char *device, enum imp_proto_errcode code, int r,
                             const char *msg) {
        halt(s, SESSION_PAUSED);
        log_error("session %s: frame %zu: %s; pausing", s->id, s->n_captured, msg);
        emit_fault(s, device, code, r < 0 ? -r : r, false, msg);
        save(s);
        emit_progress(s);
}

static int check_disk(struct session *s, uint64_t need, char *msg, size_t size) {
        uint64_t free_b = 0;
        int r = store_free_bytes(s->dir[0] ? s->dir : s->d->state_dir, &free_b);
        if (r < 0) {
                snprintf(msg, size, "statvfs %.300s: %s", s->dir, strerror(-r));
                return r;
        }
        if (free_b < need + s->d->min_free_bytes) {
                snprintf(msg, size, "%.300s: %llu bytes free, %llu needed plus a margin of %llu",
                         s->dir[0] ? s->dir : s->d->state_dir, (unsigned long long) free_b,
                         (unsigned long long) need, (unsigned long long) s->d->min_free_bytes);
                return -ENOSPC;
        }
        return 0;
}

/* Device failure: retry the frame from its set-up, or pause once the attempts are spent. */
static void step_failed(struct session *s, const char *device, int r, const char *what) {
        char msg[512];
        /* %.300s: a long session path must not push the reason out of the message */
        snprintf(msg, sizeof msg, "%s %.300s: %s: %s", device ? "device" : "store",
                 device ? device : s->dir, what, strerror(-r));
        release_rig(s);
        s->phase = 0;
        /* A camera that stopped answering is closed, to be opened afresh by the next attempt or
         * by the resume: also one the driver gave up on (-ENODEV: it released the stream; every
         * later trigger would then be -ENOTCONN, for ever, without a reopen), and one whose
         * frames stopped coming (-ETIMEDOUT: its handle may stream to nowhere, e.g. after a
         * controller change; a resume on the same handle timed out again, every time). */
        struct dev_camera *cam = device ? rigcfg_camera(s->d->rigcfg, device) : NULL;
        bool drop = cam && cam->cam && (r == -ETIMEDOUT || r == -EIO || r == -ENODEV || r == -ENOTCONN);
        if (drop)
                rigcfg_drop_camera(cam);
        if (++s->attempt < (int) s->d->retries) {
                log_warning("session %s: frame %zu: %s (attempt %d of %u), retrying", s->id, s->n_captured, msg,
                            s->attempt, s->d->retries);
                if (drop)
                        (void) rigcfg_open_devices(s->d->rigcfg, &s->rig, NULL);
                (void) schedule(s, RETRY_DELAY_US * (uint64_t) s->attempt);
                return;
        }
        pause_with_fault(s, device, device ? IMP_PROTO_E_DEVICE : IMP_PROTO_E_IO, r, msg);
}

static int frame_to_image(const struct imp_frame *f, struct imp_image **ret) {
        struct imp_image *img = NULL;
        int r = imp_image_new((int) f->width, (int) f->height, 1, IMP_PIX_U16, &img);
        if (r < 0)
                return r;
        for (unsigned y = 0; y < f->height; y++) {
                const uint8_t *src = (const uint8_t *) f->data + (size_t) y * f->stride_bytes;
                uint16_t *dst = imp_image_u16(img, 0, (int) y);
                if (f->pixel_format == IMP_PIXEL_MONO8)
                        for (unsigned x = 0; x < f->width; x++)
                                dst[x] = src[x];
                else if (__BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__)
                        memcpy(dst, src, (size_t) f->width * 2);       /* GigE Mono16 is little-endian */
                else
                        for (unsigned x = 0; x < f->width; x++)
                                dst[x] = (uint16_t) (src[2 * x] | src[2 * x + 1] << 8);
        }
        *ret = img;
        return 0;
}

/* Phase 0: put the rig in the state the frame needs; returns the settle time to wait. */
static int setup_frame(struct session *s, const struct imp_frame_record *rec, uint64_t *ret_settle_us) {
        struct rigcfg *rc = s->d->rigcfg;
        const struct imp_frame_record *prev = s->n_captured > 0 ? plan_at(s, s->n_captured - 1) : NULL;
        bool changed = !prev || s->shown_pattern == -2;
        int r;
        if (rec->tile != s->current_tile && rc->tile_pitch_um > 0 && rc->dome.dome) {
                r = imp_dome_move_to(rc->dome.dome, 0, rec->tile * rc->tile_pitch_um, AXIS_MOVE_TIMEOUT_MS);
                if (r < 0) {
                        step_failed(s, rc->dome.name, r, "moving to tile");
                        return r;
                }
                changed = true;
        }
        s->current_tile = rec->tile;
        int want = rec->pattern.kind == IMP_PAT_NONE ? -1 : pattern_index(s, &rec->pattern);
        if (rc->projector.proj && want != s->shown_pattern) {
                r = want < 0 ? imp_projector_dark(rc->projector.proj)
                             : imp_projector_show(rc->projector.proj, (unsigned) want);
                if (r < 0) {
                        step_failed(s, rc->projector.name, r, want < 0 ? "blanking" : "showing a pattern");
                        return r;
                }
                changed = true;
        }
        s->shown_pattern = want;
        if (rc->dome.dome) {
                r = rec->light >= 0 ? imp_dome_set_light(rc->dome.dome, (unsigned) rec->light,
                                                          IMP_DOME_LEVEL_FULL_PERMILLE, 0)
                                    : imp_dome_all_off(rc->dome.dome);
                if (r < 0) {
                        step_failed(s, rc->dome.name, r, rec->light >= 0 ? "switching a light on" : "lights off");
                        return r;
                }
        }
        if (prev && prev->light != rec->light)
                changed = true;
        s->t_light_on_ns = now_ns(CLOCK_REALTIME);
        *ret_settle_us = changed ? (uint64_t) llround(s->rig.settle_us) : 0;
        return 0;
}

/* Exposure and gain, written only when they differ from what this camera was last given:
 * each is a GenICam register round trip, and plans repeat the same values frame after
 * frame. The cache is cleared by forget_exposures() whenever the camera may have lost them. */
static int apply_exposure(struct dev_camera *cam, double exposure_us, double gain_db) {
        int r;
        bool valid = cam->applied_valid;
        cam->applied_valid = false;     /* until both are written: a failure forgets both */
        if (!valid || cam->applied_exposure_us != exposure_us) {
                if ((r = imp_camera_set_exposure_us(cam->cam, exposure_us)) < 0)
                        return r;
                cam->applied_exposure_us = exposure_us;
        }
        if (!cam->gain_unsupported && (!valid || cam->applied_gain_db != gain_db)) {
                r = imp_camera_set_gain_db(cam->cam, gain_db);
                if (r == -EOPNOTSUPP)
                        cam->gain_unsupported = true;
                else if (r < 0)
                        return r;
        }
        cam->applied_gain_db = gain_db;
        cam->applied_valid = true;
        return 0;
}

/* Reopened, faulted, paused or stopped cameras may hold other values (a power cycle, another
 * client, a reset on reconnect): the next frame writes both again. */
static void forget_exposures(struct rigcfg *rc) {
        for (int i = 0; i < rc->n_cameras; i++) {
                rc->cameras[i].applied_valid = false;
                rc->cameras[i].gain_unsupported = false;
        }
}

/* The next frame as a 16-bit image: a 16-bit little-endian frame of the calibrated size is
 * grabbed straight into it (one of the writer's spares when it has one: no copy out of the
 * camera's buffer, no fresh pages to fault in), others through the camera's buffer. */
static int grab_image(struct session *s, struct dev_camera *cam, unsigned timeout_ms, struct imp_frame_meta *ret_meta,
                      struct imp_image **ret) {
        const struct imp_rig_camera *model = NULL;
        int r;
        for (int i = 0; i < s->rig.n_cameras; i++)
                if (!strcmp(s->rig.cameras[i].name, cam->name))
                        model = &s->rig.cameras[i];
        if (!model || imp_pixel_format_bytes(cam->format) != 2 || __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__) {
                const struct imp_frame *f;
                if ((r = imp_camera_grab(cam->cam, timeout_ms, &f)) < 0)
                        return r;
                *ret_meta = f->meta;
                return frame_to_image(f, ret);
        }
        int w = model->model.width, h = model->model.height;
        _cleanup_image_ struct imp_image *img = store_writer_spare_image(s->writer, w, h);
        if (!img && (r = imp_image_new(w, h, 1, IMP_PIX_U16, &img)) < 0)
                return r;
        struct imp_frame f;
        if ((r = imp_camera_grab_into(cam->cam, timeout_ms, img->data, (size_t) w * (size_t) h * 2, &f)) < 0)
                return r;
        *ret_meta = f.meta;
        if (f.width == (unsigned) w && f.height == (unsigned) h && f.stride_bytes == (unsigned) w * 2 &&
            imp_pixel_format_bytes(f.pixel_format) == 2) {
                *ret = TAKE_PTR(img);
                return 0;
        }
        return frame_to_image(&f, ret);         /* another size than calibrated: as it came */
}

/* A grabbed frame of record rec (img taken): the light off when the next frame needs another
 * (after a streamed run has ended, so that no stored frame saw it go), queued for the writer. */
static int store_frame(struct session *s, const struct imp_frame_record *rec, struct imp_image *img) {
        struct rigcfg *rc = s->d->rigcfg;
        int r;
        char msg[1024];
        if (s->tiles && (r = painting_check_frame(s, msg, sizeof msg)) < 0) {
                imp_image_free(img);    /* taken maybe elsewhere: taken again on resume */
                pause_with_fault(s, s->d->rigcfg->stage.name, IMP_PROTO_E_DEVICE, r, msg);
                return r;
        }
        if (s->stream_cam && s->n_captured + 1 >= s->stream_end)
                stream_stop(s);
        /* The light stays on through an exposure stack; off before anything else. */
        const struct imp_frame_record *next = s->n_captured + 1 < s->frames_total ?
                                              plan_at(s, s->n_captured + 1) : NULL;
        if (rc->dome.dome && rec->light >= 0 && (!next || next->light != rec->light) &&
            (r = imp_dome_all_off(rc->dome.dome)) < 0) {
                imp_image_free(img);
                step_failed(s, rc->dome.name, r, "lights off");
                return r;
        }
        /* Stored by the writer thread while the next frame is exposed (on_stored follows).
         * -EIO: an earlier frame failed to store; its result pauses the session. */
        if ((r = store_writer_push(s->writer, rec, img)) < 0)
                return r;
        s->n_captured++;
        s->attempt = 0;
        return 0;
}

/* Switches the camera to free running for the run of frames in rec's state that starts here,
 * when it is long enough and the camera may stream. 1: streaming, 0: capture it triggered. */
static int stream_start(struct session *s, struct dev_camera *cam) {
        size_t n = imp_plan_run_length(s->plan, s->tiles ? s->n_captured % s->tile_frames : s->n_captured);
        if (!cam->stream || n < STREAM_MIN_FRAMES)
                return 0;
        s->stream_t0_ns = now_ns(CLOCK_REALTIME);
        int r = imp_camera_set_free_run(cam->cam, true);
        if (r == -EOPNOTSUPP || r == -EINVAL) {
                log_warning("session %s: camera %s cannot run free (%s): every frame triggered", s->id, cam->name,
                            strerror(-r));
                cam->stream = false;
                return 0;
        }
        if (r < 0) {
                step_failed(s, cam->name, r, "free running");
                return r;
        }
        s->stream_cam = cam;
        s->stream_end = s->n_captured + n;
        s->stream_last_id = 0;
        s->stream_bad = 0;
        s->streamed.runs++;
        return 1;
}

/* One frame of a streamed run. Frames received before the switch are discarded; a frame the
 * stream lost (a gap in the camera's ids, or incomplete) is replaced by the next one, as
 * they all show the same state; every seq still gets exactly one frame. */
static int stream_frame(struct session *s, const struct imp_frame_record *plan_rec) {
        struct dev_camera *cam = s->stream_cam;
        struct imp_frame_meta meta;
        _cleanup_image_ struct imp_image *img = NULL;
        int r = grab_image(s, cam, (unsigned) (plan_rec->exposure_us / 1000) + STREAM_GRAB_MARGIN_MS, &meta, &img);
        if (r == -EIO && ++s->stream_bad < STREAM_MAX_BAD)
                return 0;       /* the id gap counts it as lost */
        if (r < 0) {
                if (r == -ETIMEDOUT && s->stream_last_id == 0) {
                        log_warning("session %s: camera %s gave no frame running free: every frame triggered",
                                    s->id, cam->name);
                        cam->stream = false;
                }
                step_failed(s, cam->name, r, "grab (free running)");
                return r;
        }
        s->stream_bad = 0;
        if (meta.system_timestamp_ns > 0 && meta.system_timestamp_ns < s->stream_t0_ns) {
                s->streamed.stale++;
                return 0;
        }
        if (s->stream_last_id)
                s->streamed.lost += imp_camera_frames_skipped(s->stream_last_id, meta.frame_id);
        s->stream_last_id = meta.frame_id;
        struct imp_frame_record rec = *plan_rec;
        painting_stamp(s, &rec);
        rec.t_light_on_ns = (long long) s->t_light_on_ns;
        rec.t_trigger_ns = (long long) s->stream_t0_ns;         /* the run's start: no trigger per frame */
        rec.t_frame_ns = (long long) now_ns(CLOCK_REALTIME);
        if ((r = store_frame(s, &rec, TAKE_PTR(img))) < 0)
                return r;
        s->streamed.frames++;
        /* A full store queue ends the run: triggered (or a new run) once it has room. */
        if (s->stream_cam && store_writer_full(s->writer)) {
                s->streamed.stops++;
                stream_stop(s);
        }
        return 0;
}

/* Phase 1: expose, grab, switch off, store; or start a streamed run and take its first frame. */
static int expose_frame(struct session *s, const struct imp_frame_record *plan_rec) {
        struct rigcfg *rc = s->d->rigcfg;
        struct dev_camera *cam = rigcfg_camera(rc, plan_rec->camera);
        int r;
        if (!cam || !cam->cam) {
                step_failed(s, plan_rec->camera, -ENODEV, "camera not open");
                return -ENODEV;
        }
        struct imp_frame_record rec = *plan_rec;
        painting_stamp(s, &rec);
        if ((r = apply_exposure(cam, rec.exposure_us, rec.gain_db)) < 0) {
                step_failed(s, cam->name, r, "exposure or gain");
                return r;
        }
        if ((r = stream_start(s, cam)) != 0)
                return r < 0 ? r : stream_frame(s, plan_rec);
        rec.t_light_on_ns = (long long) s->t_light_on_ns;
        rec.t_trigger_ns = (long long) now_ns(CLOCK_REALTIME);
        if ((r = imp_camera_trigger_software(cam->cam)) < 0) {
                step_failed(s, cam->name, r, "trigger");
                return r;
        }
        struct imp_frame_meta meta;
        struct imp_image *img = NULL;
        r = grab_image(s, cam, (unsigned) (rec.exposure_us / 1000) + GRAB_MARGIN_MS, &meta, &img);
        if (r < 0) {
                step_failed(s, cam->name, r, "grab");
                return r;
        }
        rec.t_frame_ns = (long long) now_ns(CLOCK_REALTIME);
        return store_frame(s, &rec, img);
}

/* Steps on unless the writer is full or holds the last frames (its results call this
 * again), or a step is already due (a settle or retry timer must not be cut short). */
static void next_step(struct session *s) {
        if (s->state != SESSION_CAPTURING || s->d->stopping)
                return;
        if (s->n_frames >= s->frames_total) {
                finish(s, SESSION_COMPLETED);
                return;
        }
        if (s->n_captured >= s->frames_total || (s->writer && store_writer_full(s->writer)))
                return;
        int enabled = SD_EVENT_OFF;
        if (s->step_source && sd_event_source_get_enabled(s->step_source, &enabled) >= 0 &&
            enabled != SD_EVENT_OFF)
                return;
        (void) schedule(s, 0);
}

/* A result of the store writer, in frame order: the frame is durable and in the manifest
 * (events follow), or storing it failed and the writer dropped the frames behind it. */
static void on_stored(void *userdata, const struct imp_frame_record *rec, long long pixel_bytes, int r,
                      const char *what) {
        struct session *s = userdata;
        if (r < 0) {
                char msg[1100];
                snprintf(msg, sizeof msg, "storing frame %lld: %s", rec->seq, what);
                s->n_captured = s->n_frames;    /* capture resumes at the failed frame */
                if (s->state == SESSION_CAPTURING) {
                        s->attempt = (int) s->d->retries;     /* storage errors are not retried */
                        pause_with_fault(s, NULL, IMP_PROTO_E_IO, r, msg);
                } else {
                        /* Already pausing or ending: the fault is recorded all the same. */
                        log_error("session %s: %s", s->id, msg);
                        emit_fault(s, NULL, IMP_PROTO_E_IO, -r, false, msg);
                        save(s);
                }
                return;
        }
        s->n_frames++;
        s->bytes += pixel_bytes;
        char pat[64];
        pattern_name(&rec->pattern, pat, sizeof pat);
        server_broadcast(s->d, "frame", json_pack("{s:s, s:I, s:s, s:s, s:i, s:f, s:s}", "session", s->id,
                                                  "step", (json_int_t) rec->seq, "camera", rec->camera,
                                                  "pattern", pat, "light", rec->light, "exposure_us",
                                                  rec->exposure_us, "file", rec->file));
        emit_progress(s);
        next_step(s);
}

static int step_cb(sd_event_source *src, uint64_t usec, void *userdata) {
        struct session *s = userdata;
        if (s->state != SESSION_CAPTURING)
                return 0;
        if (s->n_frames >= s->frames_total) {
                finish(s, SESSION_COMPLETED);
                return 0;
        }
        /* Every frame captured, or the writer's queue full: its results step on. */
        if (s->n_captured >= s->frames_total || store_writer_full(s->writer))
                return 0;
        const struct imp_frame_record *rec = plan_at(s, s->n_captured);
        int r;
        if (s->tiles && !s->stream_cam && s->phase == 0) {
                char msg[1024];
                const char *device = NULL;
                r = painting_step(s, on_stored, &device, msg, sizeof msg);
                if (r < 0)
                        pause_with_fault(s, device, device ? IMP_PROTO_E_DEVICE : IMP_PROTO_E_IO, r, msg);
                if (r == PAINTING_POLL || r == PAINTING_MOVE_STARTED) {
                        /* the stage homes or moves: clients are served meanwhile */
                        if (r == PAINTING_MOVE_STARTED)
                                emit_progress(s);       /* "painting": {"stage": "moving to tile …"} */
                        (void) schedule(s, PAINTING_POLL_US);
                        return 0;
                }
                if (r <= 0)
                        return 0;
        }
        if (s->stream_cam || s->phase == 0) {
                char msg[512];
                /* This frame and those the writer still holds. */
                uint64_t need = store_frame_bytes(&s->rig, rec->camera) * (1 + s->n_captured - s->n_frames);
                r = check_disk(s, need, msg, sizeof msg);
                if (r < 0) {
                        pause_with_fault(s, NULL, IMP_PROTO_E_IO, r, msg);
                        return 0;
                }
        }
        if (s->stream_cam)      /* a streamed run: one frame a step, clients served in between */
                r = stream_frame(s, rec);
        else if (s->phase == 0) {
                uint64_t settle_us = 0;
                if (setup_frame(s, rec, &settle_us) < 0)
                        return 0;
                s->phase = 1;
                (void) schedule(s, settle_us);
                return 0;
        } else {
                s->phase = 0;
                r = expose_frame(s, rec);
        }
        if (r < 0)
                return 0;
        if (s->pause_requested) {
                s->pause_requested = false;
                halt(s, SESSION_PAUSED);
                save(s);
                emit_progress(s);
        } else
                next_step(s);
        return 0;
}

/* ---- commands ------------------------------------------------------------------------------ */

static int begin_capture(struct session *s, struct imp_proto_error *perr) {
        struct daemon *d = s->d;
        struct imp_error e = { 0 };
        int r = rigcfg_open_devices(d->rigcfg, &s->rig, &e);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_DEVICE, -r, NULL, "%s", e.msg);
        forget_exposures(d->rigcfg);
        if (s->tiles && (r = painting_prepare_stage(s, perr)) < 0)
                return r;
        if (s->n_patterns > 0) {
                if (!d->rigcfg->projector.proj)
                        return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, EINVAL, "args.plan",
                                                   "%s: the plan projects patterns but the rig has no projector",
                                                   s->plan_path);
                r = imp_projector_upload(d->rigcfg->projector.proj, s->patterns, s->n_patterns);
                if (r < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_DEVICE, -r, d->rigcfg->projector.name,
                                                   "projector %s: uploading %u patterns: %s",
                                                   d->rigcfg->projector.name, s->n_patterns, strerror(-r));
        }
        /* a painting's writer is its tile's (painting_step) */
        if (!s->tiles && !s->writer && (r = store_writer_new(d->event, s->cs, on_stored, s, &s->writer)) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, -r, NULL, "starting the store writer: %s",
                                           strerror(-r));
        s->n_captured = s->n_frames;    /* the writer holds nothing between runs */
        s->stream_cam = NULL;
        s->shown_pattern = -2;          /* unknown: the first frame sets it */
        s->current_tile = -1;
        s->phase = 0;
        s->attempt = 0;
        s->pause_requested = false;
        s->run_started_us = now_ns(CLOCK_MONOTONIC) / 1000;
        s->run_started_frames = s->n_frames;
        s->state = SESSION_CAPTURING;
        s->interrupted = false;
        d->active = s;
        save(s);
        r = schedule(s, 0);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, -r, NULL, "scheduling the capture: %s",
                                           strerror(-r));
        emit_progress(s);
        return 0;
}

static void make_id(struct daemon *d, const char *name, char *buf, size_t size) {
        char ts[32];
        time_t t = time(NULL);
        struct tm tm;
        gmtime_r(&t, &tm);
        strftime(ts, sizeof ts, "%Y%m%d-%H%M%S", &tm);
        snprintf(buf, size, "%s-%s", ts, name);
        for (int k = 2; k < 1000; k++) {
                char p[PATH_MAX + 200];
                snprintf(p, sizeof p, "%s/sessions/%s", d->state_dir, buf);
                if (access(p, F_OK) < 0 && !session_find(d, buf))
                        return;
                snprintf(buf, size, "%s-%s-%d", ts, name, k);
        }
}

int session_start(struct daemon *d, const char *plan_path, const char *name, struct session **ret,
                  struct imp_proto_error *perr) {
        if (d->stopping)
                return imp_proto_error_set(perr, IMP_PROTO_E_SHUTTING_DOWN, ESHUTDOWN, NULL, "the daemon is stopping");
        if (d->active)
                return imp_proto_error_set(perr, IMP_PROTO_E_BUSY, EBUSY, NULL, "session %s holds the rig (%s)",
                                           d->active->id, session_state_name(d->active->state));
        struct imp_plan *plan = NULL;
        _cleanup_free_ char *plan_text = NULL;
        int r = plan_load_text(d, plan_path, &plan, &plan_text, perr);
        if (r < 0)
                return r;
        struct session *s = calloc(1, sizeof *s);
        if (!s) {
                imp_plan_free(plan);
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
        }
        s->d = d;
        s->plan = plan;
        s->faults = json_array();
        s->frames_total = imp_plan_count(plan);
        s->tile_frames = s->frames_total;
        s->cs_tile = -1;
        s->tiles = imp_plan_tiles(plan);
        if (s->tiles)
                s->frames_total *= imp_tile_plan_count(s->tiles);
        if (s->tiles && !d->rigcfg->stage.configured) {
                session_free(s);
                return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, EINVAL, "args.plan",
                                           "%s: a plan with a painting group needs a stage in the rig config "
                                           "(rig.stage = { backend; address; }, docs/painting.md)", plan_path);
        }
        snprintf(s->name, sizeof s->name, "%s", name ? name : "session");
        snprintf(s->plan_path, sizeof s->plan_path, "%s", plan_path);
        make_id(d, s->name, s->id, sizeof s->id);
        if ((r = imp_rig_copy(&d->rig, &s->rig)) < 0) {
                session_free(s);
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, -r, NULL, "out of memory");
        }
        s->have_rig = true;
        s->estimate_s = imp_plan_estimate_s(plan, &s->rig);
        if ((r = collect_patterns(s)) < 0) {
                session_free(s);
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, -r, NULL, "out of memory");
        }
        uint64_t need = 0;
        for (size_t i = 0; i < s->frames_total; i++)
                need += store_frame_bytes(&s->rig, plan_at(s, i)->camera);
        char msg[512];
        if ((r = check_disk(s, need, msg, sizeof msg)) < 0) {
                session_free(s);
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "not enough disk space: %s", msg);
        }
        snprintf(s->dir, sizeof s->dir, "%s/sessions/%s", d->state_dir, s->id);
        s->state = SESSION_PREPARING;
        rfc3339_now(s->started);
        struct imp_error e = { 0 };
        if (imp_plan_tiles(plan)) {
                if ((r = painting_start(s, plan_text, perr)) < 0) {
                        session_free(s);
                        return r;
                }
        } else if ((r = imp_captureset_create_with_plan(s->dir, &s->rig, plan_text, strlen(plan_text), &s->cs, &e)) < 0) {
                session_free(s);
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
        }
        s->next = d->sessions;
        d->sessions = s;
        save(s);
        log_info("session %s: started, plan %s, %zu frames, about %.0f s", s->id, plan_path, s->frames_total,
                 s->estimate_s);
        if ((r = begin_capture(s, perr)) < 0) {
                /* Nothing captured yet: the session fails and keeps its (empty) set. */
                emit_fault(s, perr->field[0] ? perr->field : NULL, perr->code, -r, true, perr->message);
                finish(s, SESSION_FAILED);
                return r;
        }
        *ret = s;
        return 0;
}

int session_pause(struct session *s, struct imp_proto_error *perr) {
        if (s->state == SESSION_PAUSED)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EALREADY, "args.session",
                                           "session %s is already paused", s->id);
        if (s->state != SESSION_CAPTURING)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EINVAL, "args.session",
                                           "session %s is %s", s->id, session_state_name(s->state));
        /* The frames the writer holds are stored before the pause is answered. */
        halt(s, SESSION_PAUSED);
        save(s);
        emit_progress(s);
        return 0;
}

/* What a crash left in the set (a torn last line, a frame stored but not yet recorded, a
 * .tmp) is moved into quarantine/ by the library's repair, each item logged and reported to
 * the clients as a non-fatal fault: resuming is the operator's request (session.resume, or
 * --resume), and nothing is deleted. */
static int repair_for_resume(struct session *s, struct imp_proto_error *perr) {
        struct imp_error e = { 0 };
        json_t *report = NULL;
        int r = imp_captureset_repair(s->dir, false, &report, &e);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
        size_t i;
        json_t *item;
        json_array_foreach(report, i, item) {
                char msg[1024];
                snprintf(msg, sizeof msg, "resume: moved %s to %s: %s", json_string_value(json_object_get(item, "path")),
                         json_string_value(json_object_get(item, "moved_to")),
                         json_string_value(json_object_get(item, "reason")));
                log_warning("session %s: %s", s->id, msg);
                emit_fault(s, NULL, IMP_PROTO_E_IO, EUCLEAN, false, msg);
        }
        json_decref(report);
        return 0;
}

/* Reopen the set (after repair_for_resume), reload rig and plan from it, check the records
 * already there against the plan: capture continues at the first missing seq. */
static int load_plan(struct session *s, struct imp_proto_error *perr) {
        struct imp_error e = { 0 };
        int r;
        if (!s->plan) {
                char p[PATH_MAX + 16];
                snprintf(p, sizeof p, "%s/plan.cfg", s->dir);
                _cleanup_free_ char *text = NULL;
                if ((r = plan_read(p, &text, perr)) < 0)
                        return r;
                if ((r = imp_plan_load_string(text, p, &s->rig, &s->plan, &e)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_INVALID_PLAN, -r, NULL, "%s", e.msg);
                if ((r = collect_patterns(s)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, -r, NULL, "out of memory");
                s->estimate_s = imp_plan_estimate_s(s->plan, &s->rig);
        }
        return 0;
}

/* A painting's session directory: rig.json and plan.cfg beside painting.json and its tiles. */
static int reopen_painting(struct session *s, struct imp_proto_error *perr) {
        struct imp_error e = { 0 };
        int r;
        if (!s->have_rig) {
                char p[PATH_MAX + 16];
                snprintf(p, sizeof p, "%s/rig.json", s->dir);
                if ((r = imp_rig_load(p, &s->rig, &e)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
                s->have_rig = true;
        }
        if ((r = load_plan(s, perr)) < 0)
                return r;
        return painting_reopen(s, perr);
}

static int reopen(struct session *s, struct imp_proto_error *perr) {
        struct imp_error e = { 0 };
        if (s->tiles || painting_session_dir(s->dir))
                return reopen_painting(s, perr);
        int r = repair_for_resume(s, perr);
        if (r < 0)
                return r;
        r = imp_captureset_open(s->dir, &s->cs, &e);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s", e.msg);
        if (!s->have_rig) {
                if ((r = imp_rig_copy(imp_captureset_rig(s->cs), &s->rig)) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, -r, NULL, "out of memory");
                s->have_rig = true;
        }
        if ((r = load_plan(s, perr)) < 0)
                return r;
        s->frames_total = imp_plan_count(s->plan);
        size_t n = imp_captureset_count(s->cs);
        if (n > s->frames_total)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, EBADMSG, NULL,
                                           "%s: %zu frames stored, the plan has %zu", s->dir, n, s->frames_total);
        s->bytes = 0;
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *a = imp_captureset_record(s->cs, i), *b = imp_plan_frame(s->plan, i);
                if (a->seq != (long long) i || a->light != b->light || a->exposure_us != b->exposure_us ||
                    strcmp(a->camera, b->camera) || a->tile != b->tile)
                        return imp_proto_error_set(perr, IMP_PROTO_E_IO, EBADMSG, NULL,
                                                   "%s: frame %zu does not match the plan", s->dir, i);
                s->bytes += (long long) store_frame_bytes(&s->rig, a->camera) - 4096;
        }
        s->n_frames = n;
        return 0;
}

int session_resume(struct session *s, struct imp_proto_error *perr) {
        struct daemon *d = s->d;
        if (d->stopping)
                return imp_proto_error_set(perr, IMP_PROTO_E_SHUTTING_DOWN, ESHUTDOWN, NULL, "the daemon is stopping");
        if (s->state == SESSION_CAPTURING || s->state == SESSION_PREPARING)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EALREADY, "args.session",
                                           "session %s is already running", s->id);
        if (s->state != SESSION_PAUSED)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EINVAL, "args.session",
                                           "session %s is %s", s->id, session_state_name(s->state));
        if (d->active && d->active != s)
                return imp_proto_error_set(perr, IMP_PROTO_E_BUSY, EBUSY, NULL, "session %s holds the rig",
                                           d->active->id);
        int r;
        if (!s->cs && (r = reopen(s, perr)) < 0) {
                imp_captureset_close(s->cs);
                s->cs = NULL;
                return r;
        }
        if (s->damaged[0]) {
                char also[sizeof s->rebuilt];
                snprintf(also, sizeof also, "%s", s->rebuilt);  /* a painting.json rebuilt by the reopen */
                snprintf(s->rebuilt, sizeof s->rebuilt, "session.json rebuilt from %s (%zu of %zu frames): it was "
                         "damaged (%.500s)%s%.1300s", s->tiles ? "the painting's tile sets and plan" :
                         "its capture set's manifest and plan", s->n_frames, s->frames_total, s->damaged,
                         also[0] ? "; " : "", also);
                log_notice("session %s: %s", s->id, s->rebuilt);
                s->damaged[0] = 0;
                save(s);
        }
        char msg[512];
        uint64_t need = 0;
        for (size_t i = s->n_frames; i < s->frames_total; i++)
                need += store_frame_bytes(&s->rig, plan_at(s, i)->camera);
        if ((r = check_disk(s, need, msg, sizeof msg)) < 0) {
                d->active = s;
                pause_with_fault(s, NULL, IMP_PROTO_E_IO, r, msg);
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "not enough disk space: %s", msg);
        }
        d->active = s;
        if ((r = begin_capture(s, perr)) < 0) {
                s->state = SESSION_PAUSED;
                save(s);
                return r;
        }
        log_info("session %s: resumed at frame %zu of %zu", s->id, s->n_frames, s->frames_total);
        return 0;
}

int session_abort(struct session *s, struct imp_proto_error *perr) {
        if (session_state_final(s->state))
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EINVAL, "args.session",
                                           "session %s is already %s", s->id, session_state_name(s->state));
        if (s->d->active && s->d->active != s) {
                /* An interrupted session not holding the rig: no devices to touch. */
                s->state = SESSION_ABORTED;
                rfc3339_now(s->ended);
                save(s);
                return 0;
        }
        finish(s, SESSION_ABORTED);
        return 0;
}

void session_shutdown(struct session *s) {
        stop_stepping(s);
        release_rig(s);
        /* The frames already grabbed become durable (d->stopping: no step follows). */
        store_writer_free(s->writer);
        s->writer = NULL;
        imp_captureset_close(s->cs);
        s->cs = NULL;
}

/* A session whose session.json was unreadable says so: {"damaged": why}; once a resume
 * rebuilt it (or a painting's painting.json): {"rebuilt": what and why}. */
static json_t *with_damage(json_t *j, const struct session *s) {
        if (j && s->damaged[0])
                json_object_set_new(j, "damaged", json_string(s->damaged));
        if (j && s->rebuilt[0])
                json_object_set_new(j, "rebuilt", json_string(s->rebuilt));
        return j;
}

json_t *session_summary_json(const struct session *s) {
        return with_damage(json_pack("{s:s, s:s, s:s, s:s, s:I}", "session", s->id, "name", s->name, "state",
                                     session_state_name(s->state), "started", s->started, "frames",
                                     (json_int_t) s->n_frames),
                           s);
}

json_t *session_show_json(const struct session *s) {
        /* Counts of this daemon process (a restart starts them again). */
        json_t *streamed = json_pack("{s:I, s:I, s:I, s:I, s:I}", "runs", (json_int_t) s->streamed.runs, "frames",
                                     (json_int_t) s->streamed.frames, "lost", (json_int_t) s->streamed.lost,
                                     "stale", (json_int_t) s->streamed.stale, "stops", (json_int_t) s->streamed.stops);
        json_t *j = with_damage(json_pack("{s:s, s:s, s:s, s:s, s:s, s:s, s:s?, s:I, s:I, s:I, s:b, s:O, s:o}", "session", s->id,
                         "name", s->name, "state", session_state_name(s->state), "plan", s->plan_path, "path",
                         s->dir, "started", s->started, "ended", s->ended[0] ? s->ended : NULL, "step",
                         (json_int_t) s->n_frames, "steps", (json_int_t) s->frames_total, "frames",
                         (json_int_t) s->n_frames, "interrupted", s->interrupted, "faults", s->faults,
                         "streamed", streamed), s);
        json_t *pj = j ? session_painting_json(s) : NULL;
        if (pj)
                json_object_set_new(j, "painting", pj);
        return j;
}

json_t *session_painting_json(const struct session *s) {
        json_t *pj = painting_progress_json(s, eta_now(s));
        if (pj)
                json_object_set_new(pj, "eta_s", json_real(eta_now(s)));
        return pj;
}
