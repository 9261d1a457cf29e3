/* The control socket: accepting clients (SO_PEERCRED decides the role), reading request
 * lines through the shared codec (proto/protocol.h), dispatching commands, and queueing
 * replies and events per client with the bounds of PROTOCOL.md §6. Malformed input gets an
 * error reply; nothing a client sends can stop the daemon. */
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
#include "version.h"

#define READ_CHUNK 16384
#define LIST_DEFAULT 100

struct client {
        struct client *next;
        struct daemon *d;
        int fd;
        sd_event_source *io;
        struct imp_linebuf *lb;
        enum imp_proto_role role;
        struct ucred cred;              /* the peer's, for the plan paths it names */
        bool have_cred;
        char *out;                      /* queued output */
        size_t out_len, out_off, out_cap;
        unsigned long long seq;         /* last event sequence number sent */
        unsigned events;                /* bit i: imp_proto_event_types[i] subscribed */
        bool closing;
};

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
        free(c->out);
        free(c);
}

static void client_update_io(struct client *c) {
        (void) sd_event_source_set_io_events(c->io, EPOLLIN | (c->out_len > c->out_off ? EPOLLOUT : 0));
}

/* Returns -EPIPE when the client was dropped for a full queue. */
static int client_queue(struct client *c, const char *line) {
        size_t n = strlen(line);
        if (c->out_off > 0 && c->out_off == c->out_len)
                c->out_off = c->out_len = 0;
        if (c->out_len + n > c->out_cap) {
                if (c->out_off > 0) {
                        memmove(c->out, c->out + c->out_off, c->out_len - c->out_off);
                        c->out_len -= c->out_off;
                        c->out_off = 0;
                }
                if (c->out_len + n > c->out_cap) {
                        size_t cap = IMP_MAX(c->out_cap * 2, c->out_len + n + 4096);
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
        /* A session's end is what a calibration waits for (after the event is queued). */
        char ended[128] = "", ended_state[32] = "";
        if (!strcmp(type, "done") && json_is_string(json_object_get(fields, "session"))) {
                snprintf(ended, sizeof ended, "%s", json_string_value(json_object_get(fields, "session")));
                snprintf(ended_state, sizeof ended_state, "%s",
                         json_string_value(json_object_get(fields, "state")) ?: "");
        }
        int ti = -1;
        for (int i = 0; imp_proto_event_types[i]; i++)
                if (!strcmp(imp_proto_event_types[i], type))
                        ti = i;
        bool droppable = !strcmp(type, "progress") || !strcmp(type, "frame");
        for (struct client *c = d->clients, *next; c; c = next) {
                next = c->next;
                if (ti < 0 || !(c->events & (1u << ti)) || c->closing)
                        continue;
                size_t queued = c->out_len - c->out_off;
                c->seq++;       /* a dropped event leaves a gap in seq */
                if (droppable && queued > DAEMON_OUT_SOFT_MAX)
                        continue;
                if (queued > DAEMON_OUT_HARD_MAX) {
                        log_warning("client fd %d: %zu bytes of events unread, closing", c->fd, queued);
                        /* Freed from its own I/O callback, which the hang-up wakes. */
                        c->closing = true;
                        c->out_off = c->out_len = 0;
                        (void) shutdown(c->fd, SHUT_RDWR);
                        continue;
                }
                json_t *ev = imp_proto_event(type, c->seq, fields ? json_deep_copy(fields) : NULL);
                client_send(c, ev);
        }
        json_decref(fields);
        if (ended[0])
                calibrations_session_ended(d, ended, ended_state);
}

/* ---- commands -------------------------------------------------------------------------- */

static json_t *cmd_status(struct daemon *d) {
        unsigned queued = 0, running = 0;
        for (struct job *j = d->jobs; j; j = j->next) {
                queued += j->state == JOB_QUEUED;
                running += j->state == JOB_RUNNING;
        }
        json_t *sess = json_null();
        if (d->active)
                sess = json_pack("{s:s, s:s, s:I, s:I}", "session", d->active->id, "state",
                                 session_state_name(d->active->state), "step", (json_int_t) d->active->n_frames,
                                 "steps", (json_int_t) d->active->frames_total);
        uint64_t now;
        sd_event_now(d->event, CLOCK_MONOTONIC, &now);
        return json_pack("{s:{s:s, s:f, s:i}, s:{s:s, s:b, s:i}, s:o, s:{s:i, s:i}}", "daemon", "version",
                         imp_version(), "uptime_s", (double) (now - d->started_us) / 1e6, "pid", (int) getpid(),
                         "rig", "name", d->rigcfg->name, "calibrated", d->have_rig, "calibration",
                         d->calib_version, "session", sess, "jobs", "queued", queued, "running", running);
}

static int arg_limit(const json_t *args) {
        json_t *l = json_object_get(args, "limit");
        return json_is_integer(l) ? (int) json_integer_value(l) : LIST_DEFAULT;
}

static const char *arg_str(const json_t *args, const char *key) {
        return json_string_value(json_object_get(args, key));
}

/* args.plan, confined (planpath.c). */
static int client_plan(struct client *c, const json_t *args, char ret[static PATH_MAX], struct imp_proto_error *e) {
        return plan_path_resolve(c->d, c->have_cred ? &c->cred : NULL, arg_str(args, "plan"), "args.plan", ret, e);
}

/* The new set names the calibration it is captured with; the set is usable without it. */
static void reference_calibration(struct daemon *d, const struct session *s) {
        struct imp_error err = { 0 };
        int r = calibration_reference_set(d, s->dir, &err);
        if (r < 0)
                log_warning_errno(r, "session %s: %s, ignoring", s->id, err.msg);
}

static json_t *cmd_calibrate(struct client *c, const json_t *args, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        struct calibration *cal;
        if (calibration_start(d, arg_str(args, "routine"), json_object_get(args, "args"), arg_str(args, "plan"),
                              arg_str(args, "name"), c->have_cred ? &c->cred : NULL, &cal, e) < 0)
                return NULL;
        struct session *s = session_find(d, cal->session);
        if (s)
                reference_calibration(d, s);
        return json_pack("{s:s, s:s, s:s, s:s, s:s, s:s}", "routine", cal->routine, "calibration", cal->id,
                         "session", cal->session, "path", cal->set_dir, "plan", cal->plan, "state", "capturing");
}

static json_t *dispatch(struct client *c, const struct imp_proto_request *req, struct imp_proto_error *e) {
        struct daemon *d = c->d;
        const json_t *args = req->args;
        struct session *s;
        struct job *j;
        struct imp_plan *plan = NULL;
        struct calibration *cal;
        char planp[PATH_MAX];
        int r;
        switch (req->command->cmd) {
        case IMP_PROTO_CMD_STATUS:
                return cmd_status(d);
        case IMP_PROTO_CMD_RIG: {
                json_t *calj = d->have_rig ? calibration_current_json(d) : json_null();
                return json_pack("{s:s, s:O, s:o}", "name", d->rigcfg->name, "config", d->rigcfg->config,
                                 "calibration", calj);
        }
        case IMP_PROTO_CMD_DEVICES:
                /* Enumerating opens what is not open yet; only when the rig is free. */
                if (!d->active)
                        (void) rigcfg_open_devices(d->rigcfg, d->have_rig ? &d->rig : NULL, NULL);
                return json_pack("{s:o}", "devices", rigcfg_devices_json(d->rigcfg));
        case IMP_PROTO_CMD_PLAN_VALIDATE:
                if (client_plan(c, args, planp, e) < 0 || (r = plan_check(d, planp, &plan, e)) < 0)
                        return NULL;
                json_t *v = json_pack("{s:b, s:I, s:I}", "valid", 1, "steps", (json_int_t) imp_plan_count(plan),
                                      "frames", (json_int_t) imp_plan_count(plan));
                imp_plan_free(plan);
                return v;
        case IMP_PROTO_CMD_PLAN_ESTIMATE: {
                if (client_plan(c, args, planp, e) < 0 || (r = plan_check(d, planp, &plan, e)) < 0)
                        return NULL;
                uint64_t bytes = 0, free_b = 0;
                size_t n = imp_plan_count(plan);
                for (size_t i = 0; i < n; i++)
                        bytes += store_frame_bytes(&d->rig, imp_plan_frame(plan, i)->camera);
                (void) store_free_bytes(d->state_dir, &free_b);
                json_t *v2 = json_pack("{s:I, s:I, s:I, s:f, s:I, s:I}", "steps", (json_int_t) n, "frames",
                                       (json_int_t) n, "bytes", (json_int_t) bytes, "duration_s",
                                       imp_plan_estimate_s(plan, &d->rig), "disk_needed",
                                       (json_int_t) (bytes + d->min_free_bytes), "disk_free", (json_int_t) free_b);
                imp_plan_free(plan);
                return v2;
        }
        case IMP_PROTO_CMD_SESSION_START:
                if (client_plan(c, args, planp, e) < 0 || session_start(d, planp, arg_str(args, "name"), &s, e) < 0)
                        return NULL;
                reference_calibration(d, s);
                return json_pack("{s:s, s:s, s:s}", "session", s->id, "path", s->dir, "state",
                                 session_state_name(s->state));
        case IMP_PROTO_CMD_SESSION_PAUSE:
        case IMP_PROTO_CMD_SESSION_RESUME:
        case IMP_PROTO_CMD_SESSION_ABORT:
        case IMP_PROTO_CMD_SESSION_SHOW:
                s = session_find(d, arg_str(args, "session"));
                if (!s) {
                        imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.session", "no session %s",
                                            arg_str(args, "session"));
                        return NULL;
                }
                if (req->command->cmd == IMP_PROTO_CMD_SESSION_SHOW)
                        return session_show_json(s);
                r = req->command->cmd == IMP_PROTO_CMD_SESSION_PAUSE ? session_pause(s, e)
                    : req->command->cmd == IMP_PROTO_CMD_SESSION_RESUME ? session_resume(s, e)
                                                                         : session_abort(s, e);
                if (r < 0)
                        return NULL;
                return json_pack("{s:s, s:s, s:I, s:I}", "session", s->id, "state", session_state_name(s->state),
                                 "step", (json_int_t) s->n_frames, "frames", (json_int_t) s->n_frames);
        case IMP_PROTO_CMD_SESSION_LIST: {
                json_t *a = json_array();
                int lim = arg_limit(args);
                for (s = d->sessions; s && lim-- > 0; s = s->next)
                        json_array_append_new(a, session_summary_json(s));
                return json_pack("{s:o}", "sessions", a);
        }
        case IMP_PROTO_CMD_JOBS_LIST: {
                json_t *a = json_array();
                int lim = arg_limit(args);
                for (j = d->jobs; j && lim-- > 0; j = j->next)
                        json_array_append_new(a, job_json(j, false));
                return json_pack("{s:o}", "jobs", a);
        }
        case IMP_PROTO_CMD_JOBS_SHOW:
        case IMP_PROTO_CMD_JOBS_RETRY:
                j = jobs_find(d, arg_str(args, "job"));
                if (!j) {
                        imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.job", "no job %s",
                                            arg_str(args, "job"));
                        return NULL;
                }
                if (req->command->cmd == IMP_PROTO_CMD_JOBS_SHOW)
                        return job_json(j, true);
                if (jobs_retry(d, j, e) < 0)
                        return NULL;
                return json_pack("{s:s, s:s}", "job", j->id, "state", job_state_name(j->state));
        case IMP_PROTO_CMD_SUBSCRIBE: {
                json_t *ev = json_object_get(args, "events");
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
        case IMP_PROTO_CMD_UNSUBSCRIBE:
                c->events = 0;
                return json_object();
        case IMP_PROTO_CMD_CALIBRATE:
                return cmd_calibrate(c, args, e);
        case IMP_PROTO_CMD_CALIBRATION_LIST: {
                json_t *a = json_array();
                int lim = arg_limit(args);
                for (cal = d->calibrations; cal && lim-- > 0; cal = cal->next)
                        json_array_append_new(a, calibration_json(cal, false));
                return json_pack("{s:o, s:o}", "calibrations", a, "current", calibration_current_json(d));
        }
        case IMP_PROTO_CMD_CALIBRATION_SHOW:
                cal = calibration_find(d, arg_str(args, "calibration"));
                if (!cal) {
                        imp_proto_error_set(e, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.calibration", "no calibration %s",
                                            arg_str(args, "calibration"));
                        return NULL;
                }
                return calibration_json(cal, true);
        default:
                imp_proto_error_set(e, IMP_PROTO_E_UNKNOWN_COMMAND, EOPNOTSUPP, "cmd",
                                    "%s is not implemented by this impastod", req->command->name);
                return NULL;
        }
}

static void handle_line(struct client *c, const char *line, size_t len) {
        _cleanup_proto_request_ struct imp_proto_request req = { 0 };
        _cleanup_proto_error_ struct imp_proto_error e = { 0 };
        if (imp_proto_parse_request(line, len, c->role, &req, &e) < 0) {
                reply_error(c, NULL, &e);
                return;
        }
        json_t *result = dispatch(c, &req, &e);
        if (!result) {
                if (e.code == IMP_PROTO_E_NONE)
                        imp_proto_error_set(&e, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
                reply_error(c, req.id, &e);
                return;
        }
        client_send(c, imp_proto_reply_ok(req.id, result));
}

static int client_io(sd_event_source *src, int fd, uint32_t revents, void *userdata) {
        struct client *c = userdata;
        if (c->closing && c->out_off >= c->out_len) {
                client_free(c);
                return 0;
        }
        if (revents & EPOLLOUT) {
                while (c->out_off < c->out_len) {
                        ssize_t n = send(fd, c->out + c->out_off, c->out_len - c->out_off, MSG_NOSIGNAL | MSG_DONTWAIT);
                        if (n < 0) {
                                if (errno == EAGAIN || errno == EINTR)
                                        break;
                                client_free(c);
                                return 0;
                        }
                        c->out_off += (size_t) n;
                }
                if (c->closing && c->out_off == c->out_len) {
                        client_free(c);
                        return 0;
                }
                client_update_io(c);
        }
        if (revents & (EPOLLIN | EPOLLHUP | EPOLLERR)) {
                char buf[READ_CHUNK];
                ssize_t n = recv(fd, buf, sizeof buf, MSG_DONTWAIT);
                if (n < 0 && (errno == EAGAIN || errno == EINTR))
                        return 0;
                if (n <= 0) {
                        client_free(c);
                        return 0;
                }
                if (imp_linebuf_feed(c->lb, buf, (size_t) n) < 0) {
                        client_free(c);
                        return 0;
                }
                for (;;) {
                        char *line;
                        size_t len;
                        int r = imp_linebuf_next(c->lb, &line, &len);
                        if (r == 0)
                                break;
                        if (r == -E2BIG) {
                                _cleanup_proto_error_ struct imp_proto_error e = { 0 };
                                imp_proto_error_set(&e, IMP_PROTO_E_TOO_LONG, E2BIG, NULL,
                                                    "request longer than %d bytes", IMP_PROTO_REQUEST_MAX);
                                reply_error(c, NULL, &e);
                                continue;
                        }
                        if (r < 0)
                                break;
                        handle_line(c, line, len);
                }
        }
        return 0;
}

static bool in_operator_group(pid_t pid, gid_t gid) {
        struct group *g = getgrnam(IMP_PROTO_OPERATOR_GROUP);
        if (!g)
                return false;
        if (gid == g->gr_gid)
                return true;
        char p[64];
        snprintf(p, sizeof p, "/proc/%d/status", (int) pid);
        _cleanup_fclose_ FILE *f = fopen(p, "re");
        char line[4096];
        while (f && fgets(line, sizeof line, f))
                if (!strncmp(line, "Groups:", 7)) {
                        char *s = line + 7, *end;
                        for (;;) {
                                unsigned long v = strtoul(s, &end, 10);
                                if (end == s)
                                        break;
                                if ((gid_t) v == g->gr_gid)
                                        return true;
                                s = end;
                        }
                }
        return false;
}

static int on_accept(sd_event_source *src, int fd, uint32_t revents, void *userdata) {
        struct daemon *d = userdata;
        int cfd = accept4(fd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
        if (cfd < 0)
                return 0;
        if (d->n_clients >= d->max_clients || d->stopping) {
                _cleanup_proto_error_ struct imp_proto_error e = { 0 };
                if (d->stopping)
                        imp_proto_error_set(&e, IMP_PROTO_E_SHUTTING_DOWN, ESHUTDOWN, NULL, "the daemon is stopping");
                else
                        imp_proto_error_set(&e, IMP_PROTO_E_BUSY, EBUSY, NULL, "too many connections (%u)",
                                            d->max_clients);
                json_t *m = imp_proto_reply_error(NULL, &e);
                _cleanup_free_ char *line = m ? imp_proto_dump_line(m) : NULL;
                json_decref(m);
                if (line)
                        (void) send(cfd, line, strlen(line), MSG_NOSIGNAL | MSG_DONTWAIT);
                close(cfd);
                return 0;
        }
        struct ucred cred = { 0 };
        socklen_t len = sizeof cred;
        enum imp_proto_role role = IMP_PROTO_ROLE_OBSERVER;
        if (getsockopt(cfd, SOL_SOCKET, SO_PEERCRED, &cred, &len) == 0 &&
            (cred.uid == 0 || d->operators_all || in_operator_group(cred.pid, cred.gid)))
                role = IMP_PROTO_ROLE_OPERATOR;
        else if (d->operators_all)
                role = IMP_PROTO_ROLE_OPERATOR;
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
        c->cred = cred;
        c->have_cred = len == sizeof cred && cred.pid > 0;
        c->next = d->clients;
        d->clients = c;
        d->n_clients++;
        client_send(c, imp_proto_banner(role));
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
                d->listen_fd = fd;
        } else
                (void) fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
        return sd_event_add_io(d->event, &d->listen_source, fd, EPOLLIN, on_accept, d);
}

void server_stop(struct daemon *d) {
        d->listen_source = sd_event_source_disable_unref(d->listen_source);
        /* Best effort: flush what is queued, then close. */
        while (d->clients) {
                struct client *c = d->clients;
                if (c->out_len > c->out_off)
                        (void) send(c->fd, c->out + c->out_off, c->out_len - c->out_off, MSG_NOSIGNAL | MSG_DONTWAIT);
                client_free(c);
        }
}
