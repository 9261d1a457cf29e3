/* The control socket: accepting clients (the kernel's credentials decide the role), reading
 * request lines through the shared codec (proto/protocol.h), dispatching commands through one
 * table that also says which role each needs, and queueing replies and events per client
 * within the bounds of PROTOCOL.md §6 and docs/security.md. Malformed input gets an error
 * reply; nothing a client sends can stop the daemon or grow its memory without bound. */
#define _GNU_SOURCE 1
#include <fcntl.h>
#include <grp.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "night.h"
#include "version.h"

#define READ_CHUNK 16384
#define LIST_DEFAULT 100
#define SWEEP_US 1000000ULL             /* the timeouts are checked once a second */
#define OUT_KEEP (256 * 1024)           /* a drained output buffer larger than this is freed */

struct client {
        struct client *next;
        struct daemon *d;
        int fd;
        sd_event_source *io;
        struct imp_linebuf *lb;
        enum imp_proto_role role;
        struct daemon_peer peer;        /* from the kernel at connect() */
        char *out;                      /* queued output */
        size_t out_len, out_off, out_cap;
        unsigned long long seq;         /* last event sequence number sent */
        unsigned events;                /* bit i: imp_proto_event_types[i] subscribed */
        bool closing;
        uint64_t last_active_us;        /* last request handled or bytes sent (monotonic) */
        uint64_t partial_since_us;      /* first byte of an unfinished request line, 0 none */
        json_t *wait_id;                /* a reply deferred (devices): later lines wait for it */
        bool waiting;
};

static uint64_t now_us(struct daemon *d) {
        uint64_t t = 0;
        (void) sd_event_now(d->event, CLOCK_MONOTONIC, &t);
        return t;
}

static size_t client_queued(const struct client *c) {
        return c->out_len - c->out_off;
}

static void client_free(struct client *c) {
        struct daemon *d = c->d;
        for (struct client **p = &d->clients; *p; p = &(*p)->next)
                if (*p == c) {
                        *p = c->next;
                        break;
                }
        d->n_clients--;
        sd_event_source_disable_unref(c->io);
        close(c->fd);
        imp_linebuf_free(c->lb);
        json_decref(c->wait_id);
        free(c->out);
        free(c);
}

/* Requests are read only while the client reads its replies (its queue under the soft bound)
 * and no reply of its is deferred: a client that pipelines without reading stops being read,
 * and its memory is its socket buffer, not ours. */
static bool client_readable(const struct client *c) {
        return !c->closing && !c->waiting && client_queued(c) <= DAEMON_OUT_SOFT_MAX;
}

static void client_update_io(struct client *c) {
        (void) sd_event_source_set_io_events(c->io, (client_readable(c) ? EPOLLIN : 0) |
                                                    (client_queued(c) > 0 ? EPOLLOUT : 0));
}

/* Drops the client: its queue is discarded, it is freed from its own I/O callback, which the
 * hang-up wakes. */
static void client_close(struct client *c, const char *why) {
        if (c->closing)
                return;
        log_warning("client fd %d (uid %u, pid %d): %s, closing", c->fd, (unsigned) c->peer.uid, (int) c->peer.pid,
                    why);
        c->closing = true;
        c->out_off = c->out_len = 0;
        (void) shutdown(c->fd, SHUT_RDWR);
        client_update_io(c);
}

/* Returns -EPIPE when the client was dropped for a full queue. */
static int client_queue(struct client *c, const char *line) {
        size_t n = strlen(line);
        if (c->closing)
                return -EPIPE;
        if (client_queued(c) + n > c->d->client_queue_max) {
                char why[96];
                snprintf(why, sizeof why, "%zu bytes unread", client_queued(c) + n);
                client_close(c, why);
                return -EPIPE;
        }
        if (c->out_off > 0 && c->out_off == c->out_len)
                c->out_off = c->out_len = 0;
        if (c->out_len + n > c->out_cap) {
                if (c->out_off > 0) {
                        memmove(c->out, c->out + c->out_off, c->out_len - c->out_off);
                        c->out_len -= c->out_off;
                        c->out_off = 0;
                }
                if (c->out_len + n > c->out_cap) {
                        /* (out_len + n is within client_queue_max here) */
                        size_t cap = IMP_MIN(IMP_MAX(c->out_cap * 2, c->out_len + n + 4096),
                                             (size_t) c->d->client_queue_max + 4096);
                        char *o = realloc(c->out, cap);
                        if (!o)
                                return -ENOMEM;
                        c->out = o;
                        c->out_cap = cap;
                }
        }
        memcpy(c->out + c->out_len, line, n);
        c->out_len += n;
        client_update_io(c);
        return 0;
}

static void client_send(struct client *c, json_t *msg) {
        if (!msg)
                return;
        _cleanup_free_ char *line = imp_proto_dump_line(msg);
        json_decref(msg);
        if (line)
                (void) client_queue(c, line);
}

static void reply_error(struct client *c, const json_t *id, struct imp_proto_error *e) {
        client_send(c, imp_proto_reply_error(id, e));
}

void server_broadcast(struct daemon *d, const char *type, json_t *fields) {
        night_event(d, type, fields);   /* session.log and the hook (hooks.c) */
        int ti = -1;
        for (int i = 0; imp_proto_event_types[i]; i++)
                if (!strcmp(imp_proto_event_types[i], type))
                        ti = i;
        bool droppable = !strcmp(type, "progress") || !strcmp(type, "frame");
        for (struct client *c = d->clients, *next; c; c = next) {
                next = c->next;
                if (ti < 0 || !(c->events & (1u << ti)) || c->closing)
                        continue;
                c->seq++;       /* a dropped event leaves a gap in seq */
                if (droppable && client_queued(c) > DAEMON_OUT_SOFT_MAX)
                        continue;
                /* beyond --client-queue-max, client_queue() closes the client */
                client_send(c, imp_proto_event(type, c->seq, fields ? json_deep_copy(fields) : NULL));
        }
        json_decref(fields);
}

static int arg_limit(const json_t *args) {
        json_t *l = json_object_get(args, "limit");
        return json_is_integer(l) ? (int) json_integer_value(l) : LIST_DEFAULT;
}

static const char *arg_str(const json_t *args, const char *key) {
        return json_string_value(json_object_get(args, key));
}

/* args.plan, confined (planpath.c) and checked against the peer's own rights. */
static int client_plan(struct client *c, const json_t *args, char ret[static PATH_MAX], struct imp_proto_error *e) {
        return plan_path_resolve(c->d, &c->peer, arg_str(args, "plan"), "args.plan", ret, e);
}

/* The new set names the calibration it is captured with; the set is usable without it. */
static void reference_calibration(struct daemon *d, const struct session *s) {
        struct imp_error err = { 0 };
        int r = calibration_reference_set(d, s->dir, &err);
        if (r < 0)
                log_warning_errno(r, "session %s: %s, ignoring", s->id, err.msg);
}

/* While a device probe runs in its thread the loop leaves the devices alone. */
static int rig_free_of_probe(struct daemon *d, struct imp_proto_error *e) {
        if (d->probe)
                return imp_proto_error_set(e, IMP_PROTO_E_BUSY, EBUSY, NULL,
                                           "the devices are being probed (a `devices` request); retry in a moment");
        return 0;
}

/* ---- commands: one handler per protocol command ----------------------------------------- */

/* A handler's answer that is not ready yet (devices): the reply is sent later, in order. */
static json_t deferred_reply;
#define DEFERRED (&deferred_reply)

typedef json_t *(*command_fn)(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e);

static json_t *cmd_status(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        unsigned queued = 0, running = 0;
        const struct job *last = NULL;  /* the list is newest first */
        for (struct job *j = d->jobs; j; j = j->next) {
                queued += j->state == IMP_JOB_QUEUED;
                running += j->state == IMP_JOB_RUNNING;
                if (!last && j->state == IMP_JOB_DONE)
                        last = j;
        }
        json_t *lastj = last ? json_pack("{s:s, s:s*}", "job", last->id, "verdict",
                                         last->verdict[0] ? last->verdict : NULL) : NULL;
        json_t *sess = json_null();
        if (d->active)
                sess = json_pack("{s:s, s:s, s:I, s:I}", "session", d->active->id, "state",
                                 session_state_name(d->active->state), "step", (json_int_t) d->active->n_frames,
                                 "steps", (json_int_t) d->active->frames_total);
        json_t *painting = d->active ? session_painting_json(d->active) : NULL;
        if (painting && sess)
                json_object_set_new(sess, "painting", painting);
        else
                json_decref(painting);
        unsigned failed = 0;
        for (struct job *j = d->jobs; j; j = j->next)
                failed += j->state == IMP_JOB_FAILED;
        _cleanup_json_ json_t *queue = queue_list_json(d);
        return json_pack("{s:{s:s, s:f, s:i}, s:{s:s, s:b, s:i}, s:o, s:{s:i, s:i, s:i, s:o?}, s:{s:I, s:O?}, s:o}",
                         "daemon", "version", imp_version(), "uptime_s", (double) (now_us(d) - d->started_us) / 1e6,
                         "pid", (int) getpid(), "rig", "name", d->rigcfg->name, "calibrated", d->have_rig,
                         "calibration", d->calib_version, "session", sess, "jobs", "queued", queued, "running",
                         running, "failed", failed, "last_done", lastj, "queue", "entries",
                         (json_int_t) json_array_size(json_object_get(queue, "queue")), "waiting_for",
                         json_object_get(queue, "waiting_for"), "attention", night_attention_json(d));
}

static json_t *cmd_rig(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        json_t *calj = d->have_rig ? calibration_current_json(d) : json_null();
        return json_pack("{s:s, s:O, s:o}", "name", d->rigcfg->name, "config", d->rigcfg->config, "calibration", calj);
}

static void devices_probed(struct daemon *d, json_t *devices);

/* Observers see the devices as they are known; an operator's request on a free rig also
 * opens what is not open yet, in a thread, at most once per --device-probe-interval-s; the
 * reply then waits for the probe (later requests of that client wait behind it). */
static json_t *cmd_devices(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        uint64_t now = now_us(d);
        bool due = !d->probe_last_us || now - d->probe_last_us >= (uint64_t) d->device_probe_interval_s * 1000000ULL;
        if (c->role == IMP_PROTO_ROLE_OPERATOR && !d->active && (d->probe || due) &&
            (d->probe || device_probe_start(d, devices_probed) == 0)) {
                if (!d->probe_last_us || due)
                        d->probe_last_us = now;
                return DEFERRED;
        }
        /* as last known: how old that is (null: never probed since impastod started) */
        json_t *age = d->probe_last_us ? json_real((double) (now - d->probe_last_us) / 1e6) : json_null();
        return json_pack("{s:o, s:b, s:o}", "devices", device_probe_snapshot(d), "probed", 0, "age_s", age);
}

static json_t *cmd_plan_validate(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        char planp[PATH_MAX];
        struct imp_plan *plan = NULL;
        if (client_plan(c, req->args, planp, e) < 0 || plan_check(c->d, planp, &plan, e) < 0)
                return NULL;
        json_t *v = json_pack("{s:b, s:I, s:I}", "valid", 1, "steps", (json_int_t) imp_plan_count(plan), "frames",
                              (json_int_t) imp_plan_count(plan));
        imp_plan_free(plan);
        return v;
}

/* args.painting of plan.estimate: {"workers","stage_speed_mm_s","settle_s","process_s"}, each
 * optional; the defaults are the rig's (the stage's feed as configured, one job at a time). */
static int estimate_opts(struct daemon *d, const json_t *args, struct imp_plan_painting_opts *o,
                         struct imp_proto_error *e) {
        struct imp_stage_config sc;
        *o = (struct imp_plan_painting_opts) { .speed_mm_s = IMP_PLAN_STAGE_SPEED_MM_S, .settle_s = IMP_PLAN_SETTLE_S,
                                               .process_s = -1, .workers = 1 };
        if (d->rigcfg->stage.stage && imp_stage_get_config(d->rigcfg->stage.stage, &sc) == 0)
                o->speed_mm_s = sc.speed_mm_s;
        const json_t *p = json_object_get(args, "painting");
        static const struct { const char *key; double lo, hi; } f[] = {
                { "workers", 1, 256 }, { "stage_speed_mm_s", 1e-3, 1e4 }, { "settle_s", 0, 3600 },
                { "process_s", 0, 1e6 },
        };
        double *dst[] = { NULL, &o->speed_mm_s, &o->settle_s, &o->process_s };
        for (size_t i = 0; i < ARRAY_SIZE(f); i++) {
                const json_t *v = json_object_get(p, f[i].key);
                if (!v)
                        continue;
                double x = json_number_value(v);
                if (!json_is_number(v) || !(x >= f[i].lo && x <= f[i].hi) || (i == 0 && !json_is_integer(v)))
                        return imp_proto_error_set(e, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, "args.painting",
                                                   "args.painting.%s: expected a number in [%g, %g]%s", f[i].key,
                                                   f[i].lo, f[i].hi, i == 0 ? " (an integer)" : "");
                if (i == 0)
                        o->workers = (unsigned) x;
                else
                        *dst[i] = x;
        }
        return 0;
}

static json_t *cmd_plan_estimate(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        char planp[PATH_MAX];
        struct imp_plan_painting_opts po;
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        if (client_plan(c, req->args, planp, e) < 0 || estimate_opts(d, req->args, &po, e) < 0 ||
            plan_check(d, planp, &plan, e) < 0)
                return NULL;
        uint64_t bytes = 0, free_b = 0;
        size_t n = imp_plan_count(plan);
        for (size_t i = 0; i < n; i++)
                bytes += store_frame_bytes(&d->rig, imp_plan_frame(plan, i)->camera);
        (void) store_free_bytes(d->state_dir, &free_b);
        /* a painting's: every tile's, as the offline estimate (imp_plan_painting_estimate_json) */
        json_t *painting = imp_plan_tiles(plan) ? imp_plan_painting_estimate_json(plan, &d->rig, (double) bytes, &po)
                                                : NULL;
        double need = (painting ? json_number_value(json_object_get(painting, "bytes")) : (double) bytes) +
                      (double) d->min_free_bytes;
        if (need > (double) free_b) {
                json_decref(painting);
                return imp_proto_error_set(e, IMP_PROTO_E_INVALID_PLAN, ENOSPC, "args.plan",
                                           "%s: %s %.0f bytes with the %llu kept free, the store %s has %llu free: "
                                           "it will not fit", planp, imp_plan_tiles(plan) ? "the whole painting needs"
                                           : "needs", need, (unsigned long long) d->min_free_bytes, d->state_dir,
                                           (unsigned long long) free_b), NULL;
        }
        return json_pack("{s:I, s:I, s:I, s:f, s:I, s:I, s:o*}", "steps", (json_int_t) n, "frames", (json_int_t) n,
                         "bytes", (json_int_t) bytes, "duration_s", imp_plan_estimate_s(plan, &d->rig), "disk_needed",
                         (json_int_t) need, "disk_free", (json_int_t) free_b, "painting", painting);
}

static json_t *cmd_session_start(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        char planp[PATH_MAX];
        struct session *s;
        if (rig_free_of_probe(d, e) < 0 || client_plan(c, req->args, planp, e) < 0 ||
            session_start(d, planp, arg_str(req->args, "name"), &s, e) < 0)
                return NULL;
        reference_calibration(d, s);
        return json_pack("{s:s, s:s, s:s}", "session", s->id, "path", s->dir, "state", session_state_name(s->state));
}

static struct session *arg_session(struct client *c, const json_t *args, struct imp_proto_error *e) {
        struct session *s = session_find(c->d, arg_str(args, "session"));
        if (!s)
                imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.session", "no session %s",
                                    arg_str(args, "session"));
        return s;
}

/* pause, resume, abort */
static json_t *cmd_session_control(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct session *s = arg_session(c, req->args, e);
        if (!s)
                return NULL;
        enum imp_proto_cmd cmd = req->command->cmd;
        int r = cmd == IMP_PROTO_CMD_SESSION_PAUSE ? session_pause(s, e)
                : cmd == IMP_PROTO_CMD_SESSION_RESUME ? (rig_free_of_probe(c->d, e) ?: session_resume(s, e))
                                                      : session_abort(s, e);
        if (r < 0)
                return NULL;
        return json_pack("{s:s, s:s, s:I, s:I}", "session", s->id, "state", session_state_name(s->state), "step",
                         (json_int_t) s->n_frames, "frames", (json_int_t) s->n_frames);
}

static json_t *cmd_session_show(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct session *s = arg_session(c, req->args, e);
        return s ? session_show_json(s) : NULL;
}

static json_t *cmd_session_list(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        json_t *a = json_array();
        int lim = arg_limit(req->args);
        for (struct session *s = c->d->sessions; s && lim-- > 0; s = s->next)
                json_array_append_new(a, session_summary_json(s));
        return json_pack("{s:o}", "sessions", a);
}

static json_t *cmd_calibrate(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        const json_t *args = req->args;
        struct calibration *cal;
        if (rig_free_of_probe(d, e) < 0 ||
            calibration_start(d, arg_str(args, "routine"), json_object_get(args, "args"), arg_str(args, "plan"),
                              arg_str(args, "name"), &c->peer, &cal, e) < 0)
                return NULL;
        struct session *s = session_find(d, cal->session);
        if (s)
                reference_calibration(d, s);
        return json_pack("{s:s, s:s, s:s, s:s, s:s, s:s}", "routine", cal->routine, "calibration", cal->id,
                         "session", cal->session, "path", cal->set_dir, "plan", cal->plan, "state", "capturing");
}

static json_t *cmd_jobs_list(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        json_t *a = json_array();
        int lim = arg_limit(req->args);
        for (struct job *j = c->d->jobs; j && lim-- > 0; j = j->next)
                json_array_append_new(a, job_json(j, false));
        return json_pack("{s:o}", "jobs", a);
}

static struct job *arg_job(struct client *c, const json_t *args, struct imp_proto_error *e) {
        struct job *j = jobs_find(c->d, arg_str(args, "job"));
        if (!j)
                imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.job", "no job %s", arg_str(args, "job"));
        return j;
}

static json_t *cmd_jobs_show(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct job *j = arg_job(c, req->args, e);
        return j ? job_json(j, true) : NULL;
}

static json_t *cmd_jobs_retry(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct job *j = arg_job(c, req->args, e);
        if (!j || jobs_retry(c->d, j, e) < 0)
                return NULL;
        return json_pack("{s:s, s:s}", "job", j->id, "state", imp_job_state_name(j->state));
}

static json_t *cmd_subscribe(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        json_t *ev = json_object_get(req->args, "events");
        json_t *out = json_array();
        c->events = 0;
        for (int i = 0; imp_proto_event_types[i]; i++) {
                bool want = !json_is_array(ev);
                size_t k;
                json_t *v;
                json_array_foreach(ev, k, v)
                        if (!strcmp(json_string_value(v), imp_proto_event_types[i]))
                                want = true;
                if (want) {
                        c->events |= 1u << i;
                        json_array_append_new(out, json_string(imp_proto_event_types[i]));
                }
        }
        return json_pack("{s:o, s:I}", "events", out, "seq", (json_int_t) c->seq);
}

static json_t *cmd_unsubscribe(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        c->events = 0;
        return json_object();
}

static json_t *cmd_calibration_list(struct client *c, const struct imp_proto_request *req,
                                    struct imp_proto_error *e) {
        json_t *a = json_array();
        int lim = arg_limit(req->args);
        for (struct calibration *cal = c->d->calibrations; cal && lim-- > 0; cal = cal->next)
                json_array_append_new(a, calibration_json(cal, false));
        return json_pack("{s:o, s:o}", "calibrations", a, "current", calibration_current_json(c->d));
}

static json_t *cmd_calibration_show(struct client *c, const struct imp_proto_request *req,
                                    struct imp_proto_error *e) {
        struct calibration *cal = calibration_find(c->d, arg_str(req->args, "calibration"));
        if (!cal)
                imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.calibration", "no calibration %s",
                                    arg_str(req->args, "calibration"));
        return cal ? calibration_json(cal, true) : NULL;
}

static json_t *cmd_queue_add(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        return queue_add(c->d, &c->peer, arg_str(req->args, "plan"), arg_str(req->args, "name"), e);
}

static json_t *cmd_queue_list(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        return queue_list_json(c->d);
}

static json_t *cmd_queue_move(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        json_t *pos = json_object_get(req->args, "position");
        return queue_move(c->d, arg_str(req->args, "id"), json_is_integer(pos) ? (int) json_integer_value(pos) : 1, e);
}

static json_t *cmd_queue_cancel(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        return queue_cancel(c->d, arg_str(req->args, "id"), e);
}

static json_t *cmd_report(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        return night_report_json(c->d, arg_str(req->args, "since"), e);
}

/* Who may run what, and the handler, per command; indexed by the protocol's enum (like
 * proto/protocol.c's table, and Redis's command table). A row left out is zero: ACCESS_NONE
 * and no handler, which refuses the command for everyone. */
enum access {
        ACCESS_NONE = 0,                /* nobody (fail closed) */
        ACCESS_OBSERVER,                /* every client that can open the socket */
        ACCESS_OPERATOR,                /* root, the impasto-operators group, --operators-all */
};

struct command_row {
        enum access access;
        command_fn fn;
};

static const struct command_row command_table[] = {
#define R(id, acc, f) [IMP_PROTO_CMD_##id] = { .access = ACCESS_##acc, .fn = f }
        R(STATUS,           OBSERVER, cmd_status),
        R(RIG,              OBSERVER, cmd_rig),
        R(DEVICES,          OBSERVER, cmd_devices),         /* observers never (re)open devices */
        R(PLAN_VALIDATE,    OBSERVER, cmd_plan_validate),
        R(PLAN_ESTIMATE,    OBSERVER, cmd_plan_estimate),
        R(SESSION_START,    OPERATOR, cmd_session_start),
        R(SESSION_PAUSE,    OPERATOR, cmd_session_control),
        R(SESSION_RESUME,   OPERATOR, cmd_session_control),
        R(SESSION_ABORT,    OPERATOR, cmd_session_control),
        R(SESSION_LIST,     OBSERVER, cmd_session_list),
        R(SESSION_SHOW,     OBSERVER, cmd_session_show),
        R(CALIBRATE,        OPERATOR, cmd_calibrate),
        R(JOBS_LIST,        OBSERVER, cmd_jobs_list),
        R(JOBS_SHOW,        OBSERVER, cmd_jobs_show),
        R(JOBS_RETRY,       OPERATOR, cmd_jobs_retry),
        R(SUBSCRIBE,        OBSERVER, cmd_subscribe),
        R(UNSUBSCRIBE,      OBSERVER, cmd_unsubscribe),
        R(CALIBRATION_LIST, OBSERVER, cmd_calibration_list),
        R(CALIBRATION_SHOW, OBSERVER, cmd_calibration_show),
        R(QUEUE_ADD,        OPERATOR, cmd_queue_add),
        R(QUEUE_LIST,       OBSERVER, cmd_queue_list),
        R(QUEUE_MOVE,       OPERATOR, cmd_queue_move),
        R(QUEUE_CANCEL,     OPERATOR, cmd_queue_cancel),
        R(REPORT,           OBSERVER, cmd_report),
#undef R
};
_Static_assert(ARRAY_SIZE(command_table) == _IMP_PROTO_CMD_MAX, "one row per protocol command");

bool server_commands_check(void) {
        size_t n;
        const struct imp_proto_command *cmds = imp_proto_commands(&n);
        bool ok = true;
        for (size_t i = 0; i < n; i++) {
                const struct command_row *row = &command_table[cmds[i].cmd];
                enum access want = cmds[i].operator_only ? ACCESS_OPERATOR : ACCESS_OBSERVER;
                if (!row->fn || row->access != want) {
                        log_error("command %s: the daemon's table says %s, the protocol %s", cmds[i].name,
                                  row->fn ? (row->access == ACCESS_OPERATOR ? "operator" : "observer") : "nothing",
                                  cmds[i].operator_only ? "operator" : "observer");
                        ok = false;
                }
        }
        return ok;
}

/* The one access decision: the row's role against the client's; anything unknown refused. */
static bool may_run(const struct command_row *row, enum imp_proto_role role) {
        switch (row->access) {
        case ACCESS_OBSERVER: return role == IMP_PROTO_ROLE_OBSERVER || role == IMP_PROTO_ROLE_OPERATOR;
        case ACCESS_OPERATOR: return role == IMP_PROTO_ROLE_OPERATOR;
        default: return false;
        }
}

static json_t *dispatch(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        enum imp_proto_cmd cmd = req->command->cmd;
        const struct command_row *row = (unsigned) cmd < ARRAY_SIZE(command_table) ? &command_table[cmd] : NULL;
        if (!row || !row->fn) {
                imp_proto_error_set(e, IMP_PROTO_E_UNKNOWN_COMMAND, EOPNOTSUPP, "cmd",
                                    "%s is not implemented by this impastod", req->command->name);
                return NULL;
        }
        if (!may_run(row, c->role)) {
                imp_proto_error_set(e, IMP_PROTO_E_PERMISSION_DENIED, EPERM, "cmd", "%s needs the operator role; "
                                    "this connection (uid %u) is an %s", req->command->name, (unsigned) c->peer.uid,
                                    imp_proto_role_name(c->role));
                return NULL;
        }
        return row->fn(c, req, e);
}

static void handle_line(struct client *c, const char *line, size_t len) {
        _cleanup_proto_request_ struct imp_proto_request req = { 0 };
        _cleanup_proto_error_ struct imp_proto_error e = { 0 };
        /* (the codec refuses operator commands to observers too; dispatch() decides for the
         * daemon, from its table) */
        if (imp_proto_parse_request(line, len, c->role, &req, &e) < 0) {
                reply_error(c, NULL, &e);
                return;
        }
        json_t *result = dispatch(c, &req, &e);
        if (result == DEFERRED) {
                c->waiting = true;
                c->wait_id = json_incref(req.id);
                return;
        }
        if (!result) {
                if (e.code == IMP_PROTO_E_NONE)
                        imp_proto_error_set(&e, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
                reply_error(c, req.id, &e);
                return;
        }
        client_send(c, imp_proto_reply_ok(req.id, result));
}

/* Handles the complete lines held, while the client may be read (client_readable). */
static void client_process(struct client *c) {
        while (client_readable(c)) {
                char *line;
                size_t len;
                int r = imp_linebuf_next(c->lb, &line, &len);
                if (r == 0)
                        break;
                if (r == -E2BIG) {
                        _cleanup_proto_error_ struct imp_proto_error e = { 0 };
                        imp_proto_error_set(&e, IMP_PROTO_E_TOO_LONG, E2BIG, NULL, "request longer than %d bytes",
                                            IMP_PROTO_REQUEST_MAX);
                        reply_error(c, NULL, &e);
                        continue;
                }
                if (r < 0)
                        break;
                c->last_active_us = now_us(c->d);
                handle_line(c, line, len);
        }
        c->partial_since_us = imp_linebuf_pending(c->lb) == 0 ? 0 : c->partial_since_us ?: now_us(c->d);
        client_update_io(c);
}

/* 0, or -ECONNRESET when the client is gone (freed). */
static int client_flush(struct client *c) {
        while (c->out_off < c->out_len) {
                ssize_t n = send(c->fd, c->out + c->out_off, c->out_len - c->out_off, MSG_NOSIGNAL | MSG_DONTWAIT);
                if (n < 0) {
                        if (errno == EAGAIN || errno == EINTR)
                                break;
                        client_free(c);
                        return -ECONNRESET;
                }
                c->out_off += (size_t) n;
                c->last_active_us = now_us(c->d);
        }
        if (c->closing && c->out_off == c->out_len) {
                client_free(c);
                return -ECONNRESET;
        }
        if (c->out_off == c->out_len && c->out_cap > OUT_KEEP) {
                /* drained after a burst: give the memory back */
                free(c->out);
                c->out = NULL;
                c->out_cap = c->out_len = c->out_off = 0;
        }
        return 0;
}

static int client_io(sd_event_source *src, int fd, uint32_t revents, void *userdata) {
        struct client *c = userdata;
        if (c->closing && c->out_off >= c->out_len) {
                client_free(c);
                return 0;
        }
        if (revents & EPOLLOUT) {
                if (client_flush(c) < 0)
                        return 0;
                client_process(c);     /* lines held back while the queue was full */
                if (c->closing)
                        return 0;
        }
        if (revents & (EPOLLIN | EPOLLHUP | EPOLLERR)) {
                if (!client_readable(c)) {
                        /* gone for good (a half-close is EPOLLRDHUP): nothing to answer */
                        if (revents & (EPOLLHUP | EPOLLERR))
                                client_free(c);
                        return 0;
                }
                char buf[READ_CHUNK];
                ssize_t n = recv(fd, buf, sizeof buf, MSG_DONTWAIT);
                if (n < 0 && (errno == EAGAIN || errno == EINTR))
                        return 0;
                if (n <= 0 || imp_linebuf_feed(c->lb, buf, (size_t) n) < 0) {
                        client_free(c);
                        return 0;
                }
                client_process(c);
        }
        return 0;
}

/* ---- the deferred `devices` reply ---------------------------------------------------------- */

static void devices_probed(struct daemon *d, json_t *devices) {
        for (struct client *c = d->clients, *next; c; c = next) {
                next = c->next;
                if (!c->waiting)
                        continue;
                json_t *id = TAKE_PTR(c->wait_id);
                c->waiting = false;
                client_send(c, imp_proto_reply_ok(id, json_pack("{s:O, s:b, s:f}", "devices", devices, "probed", 1,
                                                                 "age_s", 0.0)));
                json_decref(id);
                client_process(c);
        }
        json_decref(devices);
}

/* ---- credentials, roles and admission ------------------------------------------------------- */

bool daemon_peer_in_group(const struct daemon_peer *p, gid_t gid) {
        if (p->gid == gid)
                return true;
        for (int i = 0; i < p->n_groups; i++)
                if (p->groups[i] == gid)
                        return true;
        return false;
}

/* uid, gid, pid from SO_PEERCRED and the supplementary groups from SO_PEERGROUPS, both as the
 * kernel recorded them at connect(). Without credentials there is no connection; without the
 * groups (a kernel before 4.13, or more than DAEMON_PEER_GROUPS_MAX) the peer has its
 * primary group only, so it can lose a role, never gain one. */
static int peer_read(int fd, struct daemon_peer *p) {
        struct ucred cred = { 0 };
        socklen_t len = sizeof cred;
        if (getsockopt(fd, SOL_SOCKET, SO_PEERCRED, &cred, &len) < 0)
                return negative_errno();
        if (len != sizeof cred || cred.uid == (uid_t) -1)
                return -EPERM;
        *p = (struct daemon_peer) { .uid = cred.uid, .gid = cred.gid, .pid = cred.pid };
        socklen_t glen = sizeof p->groups;
        if (getsockopt(fd, SOL_SOCKET, SO_PEERGROUPS, p->groups, &glen) < 0) {
                log_debug("SO_PEERGROUPS: %m; the peer (uid %u) has its primary group only", (unsigned) cred.uid);
                p->n_groups = 0;
        } else
                p->n_groups = (int) (glen / sizeof(gid_t));
        return 0;
}

static enum imp_proto_role peer_role(const struct daemon *d, const struct daemon_peer *p) {
        if (p->uid == 0 || d->operators_all)
                return IMP_PROTO_ROLE_OPERATOR;
        struct group *g = getgrnam(IMP_PROTO_OPERATOR_GROUP);
        return g && daemon_peer_in_group(p, g->gr_gid) ? IMP_PROTO_ROLE_OPERATOR : IMP_PROTO_ROLE_OBSERVER;
}

/* The connection limits (docs/security.md): 0 to admit, else e says why not. */
static int admit(struct daemon *d, const struct daemon_peer *p, enum imp_proto_role role, struct imp_proto_error *e) {
        if (d->stopping)
                return imp_proto_error_set(e, IMP_PROTO_E_SHUTTING_DOWN, ESHUTDOWN, NULL, "the daemon is stopping");
        if (d->n_clients >= d->max_clients)
                return imp_proto_error_set(e, IMP_PROTO_E_BUSY, EBUSY, NULL, "too many connections (%u)",
                                           d->max_clients);
        if (role == IMP_PROTO_ROLE_OPERATOR)
                return 0;
        unsigned reserved = IMP_MIN(d->reserved_slots, d->max_clients - 1);
        if (d->n_clients >= d->max_clients - reserved)
                return imp_proto_error_set(e, IMP_PROTO_E_BUSY, EBUSY, NULL, "too many connections (%u; the last %u "
                                           "are kept for operators)", d->n_clients, reserved);
        unsigned mine = 0;
        for (struct client *c = d->clients; c; c = c->next)
                mine += !c->closing && c->peer.uid == p->uid;
        if (mine >= d->max_clients_per_uid)
                return imp_proto_error_set(e, IMP_PROTO_E_BUSY, EBUSY, NULL, "too many connections from uid %u (%u)",
                                           (unsigned) p->uid, d->max_clients_per_uid);
        return 0;
}

static void refuse(int cfd, const struct imp_proto_error *e) {
        json_t *m = imp_proto_reply_error(NULL, e);
        _cleanup_free_ char *line = m ? imp_proto_dump_line(m) : NULL;
        json_decref(m);
        if (line)
                (void) send(cfd, line, strlen(line), MSG_NOSIGNAL | MSG_DONTWAIT);
        close(cfd);
}

static int on_accept(sd_event_source *src, int fd, uint32_t revents, void *userdata) {
        struct daemon *d = userdata;
        int cfd = accept4(fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (cfd < 0)
                return 0;
        _cleanup_proto_error_ struct imp_proto_error e = { 0 };
        struct daemon_peer peer;
        int r = peer_read(cfd, &peer);
        if (r < 0) {
                imp_proto_error_set(&e, IMP_PROTO_E_PERMISSION_DENIED, -r, NULL, "no peer credentials: %s",
                                    strerror(-r));
                refuse(cfd, &e);
                return 0;
        }
        enum imp_proto_role role = peer_role(d, &peer);
        if (admit(d, &peer, role, &e) < 0) {
                log_debug("connection of uid %u refused: %s", (unsigned) peer.uid, e.message);
                refuse(cfd, &e);
                return 0;
        }
        struct client *c = calloc(1, sizeof *c);
        if (!c || imp_linebuf_new(IMP_PROTO_REQUEST_MAX, &c->lb) < 0 ||
            sd_event_add_io(d->event, &c->io, cfd, EPOLLIN, client_io, c) < 0) {
                if (c) {
                        imp_linebuf_free(c->lb);
                        free(c);
                }
                close(cfd);
                return 0;
        }
        c->d = d;
        c->fd = cfd;
        c->role = role;
        c->peer = peer;
        c->last_active_us = now_us(d);
        c->next = d->clients;
        d->clients = c;
        d->n_clients++;
        client_send(c, imp_proto_banner(role));
        return 0;
}

/* ---- timeouts ------------------------------------------------------------------------------- */

static int on_sweep(sd_event_source *src, uint64_t usec, void *userdata) {
        struct daemon *d = userdata;
        uint64_t now = now_us(d);
        for (struct client *c = d->clients; c; c = c->next) {
                if (c->closing || c->waiting)
                        continue;
                char why[128];
                if (d->request_timeout_s && c->partial_since_us &&
                    now - c->partial_since_us > (uint64_t) d->request_timeout_s * 1000000ULL) {
                        snprintf(why, sizeof why, "a request line unfinished for %u s", d->request_timeout_s);
                        client_close(c, why);
                } else if (d->idle_timeout_s && !c->events &&
                           now - c->last_active_us > (uint64_t) d->idle_timeout_s * 1000000ULL) {
                        snprintf(why, sizeof why, "idle for %u s", d->idle_timeout_s);
                        client_close(c, why);
                }
        }
        (void) sd_event_source_set_time_relative(src, SWEEP_US);
        (void) sd_event_source_set_enabled(src, SD_EVENT_ONESHOT);
        return 0;
}

int server_start(struct daemon *d) {
        int fd = d->listen_fd;
        if (fd < 0) {
                struct sockaddr_un sa = { .sun_family = AF_UNIX };
                if (strlen(d->socket_path) >= sizeof sa.sun_path)
                        return -ENAMETOOLONG;
                strcpy(sa.sun_path, d->socket_path);
                fd = socket(AF_UNIX, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
                if (fd < 0)
                        return negative_errno();
                (void) unlink(d->socket_path);
                mode_t old = umask(0117);       /* the socket file is 0660 */
                int r = bind(fd, (struct sockaddr *) &sa, sizeof sa);
                umask(old);
                if (r < 0 || listen(fd, 64) < 0) {
                        r = negative_errno();
                        close(fd);
                        return r;
                }
                (void) chmod(d->socket_path, 0660);
                struct stat st;
                if (stat(d->socket_path, &st) == 0)
                        d->socket_ino = st.st_ino;
                d->listen_fd = fd;
        } else
                (void) fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
        int r = sd_event_add_time_relative(d->event, &d->client_timer, CLOCK_MONOTONIC, SWEEP_US, 0, on_sweep, d);
        if (r < 0)
                return r;
        return sd_event_add_io(d->event, &d->listen_source, fd, EPOLLIN, on_accept, d);
}

void server_stop(struct daemon *d) {
        d->listen_source = sd_event_source_disable_unref(d->listen_source);
        d->client_timer = sd_event_source_disable_unref(d->client_timer);
        /* Best effort: flush what is queued, then close. */
        while (d->clients) {
                struct client *c = d->clients;
                if (c->out_len > c->out_off)
                        (void) send(c->fd, c->out + c->out_off, c->out_len - c->out_off, MSG_NOSIGNAL | MSG_DONTWAIT);
                client_free(c);
        }
}
