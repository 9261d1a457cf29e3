/* The client side of the control protocol: one connection to impastod, requests with ids,
 * replies matched by id, events handed to the caller; plus the small output helpers the
 * daemon commands (status, devices, scan, jobs, plan --daemon) share. */
#include <getopt.h>
#include <errno.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <time.h>
#include <unistd.h>
#include "client.h"
#include "json-util.h"
#include "log.h"
#include "numparse.h"

struct imp_client {
        int fd;
        struct imp_linebuf *lb;
        long long next_id;
        enum imp_proto_role role;
        char version[64];
};

const char *imp_client_socket_path(const char *arg) {
        if (arg && *arg)
                return arg;
        const char *env = getenv("IMPASTO_SOCKET");
        return env && *env ? env : IMP_CLIENT_DEFAULT_SOCKET;
}

void imp_client_free(struct imp_client *c) {
        if (!c)
                return;
        if (c->fd >= 0)
                close(c->fd);
        imp_linebuf_free(c->lb);
        free(c);
}

enum imp_proto_role imp_client_role(const struct imp_client *c) { return c->role; }
const char *imp_client_daemon_version(const struct imp_client *c) { return c->version; }

static long long now_ms(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec * 1000LL + ts.tv_nsec / 1000000;
}

/* The next message of any kind. 1 and *ret, 0 on timeout, negative errno. */
static int read_message(struct imp_client *c, int timeout_ms, struct imp_proto_message *ret,
                        struct imp_error *err) {
        long long deadline = timeout_ms < 0 ? -1 : now_ms() + timeout_ms;
        for (;;) {
                char *line;
                size_t len;
                int r = imp_linebuf_next(c->lb, &line, &len);
                if (r == -E2BIG)
                        return imp_error_set(err, -EBADMSG, "the daemon sent a line longer than %d bytes",
                                             IMP_PROTO_MESSAGE_MAX);
                if (r < 0)
                        return imp_error_set(err, r, "reading from the daemon: %s", strerror(-r));
                if (r > 0) {
                        _cleanup_proto_error_ struct imp_proto_error pe = {};
                        r = imp_proto_parse_reply(line, len, ret, &pe);
                        if (r < 0)
                                return imp_error_set(err, r == -ENOMEM ? r : -EBADMSG,
                                                     "malformed line from the daemon: %s%s%s", pe.message,
                                                     pe.field[0] ? ", field " : "", pe.field);
                        return 1;
                }
                int wait_ms = -1;
                if (deadline >= 0) {
                        long long left = deadline - now_ms();
                        if (left <= 0)
                                return 0;
                        wait_ms = (int) left;
                }
                struct pollfd p = { .fd = c->fd, .events = POLLIN };
                r = poll(&p, 1, wait_ms);
                if (r < 0) {
                        if (errno == EINTR)
                                continue;
                        return imp_error_set(err, negative_errno(), "poll: %m");
                }
                if (r == 0)
                        return 0;
                char buf[65536];
                ssize_t n = read(c->fd, buf, sizeof buf);
                if (n < 0) {
                        if (errno == EINTR || errno == EAGAIN)
                                continue;
                        return imp_error_set(err, negative_errno(), "reading from the daemon: %m");
                }
                if (n == 0)
                        return imp_error_set(err, -ECONNRESET, "the daemon closed the connection%s",
                                             imp_linebuf_pending(c->lb) ? " in the middle of a line" : "");
                if ((r = imp_linebuf_feed(c->lb, buf, (size_t) n)) < 0)
                        return imp_error_set(err, r, "out of memory");
        }
}

int imp_client_open(const char *path, struct imp_client **ret, struct imp_error *err) {
        struct sockaddr_un sa = { .sun_family = AF_UNIX };
        if (strlen(path) >= sizeof sa.sun_path)
                return imp_error_set(err, -ENAMETOOLONG, "%s: socket path too long", path);
        strcpy(sa.sun_path, path);
        struct imp_client *c = calloc(1, sizeof *c);
        if (!c)
                return imp_error_set(err, -ENOMEM, "out of memory");
        _cleanup_client_ struct imp_client *cc = c;
        c->next_id = 1;
        c->fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
        if (c->fd < 0)
                return imp_error_set(err, negative_errno(), "socket: %m");
        if (connect(c->fd, (struct sockaddr *) &sa, sizeof sa) < 0)
                return imp_error_set(err, negative_errno(), "cannot connect to impastod at %s: %m", path);
        int r = imp_linebuf_new(IMP_PROTO_MESSAGE_MAX, &c->lb);
        if (r < 0)
                return imp_error_set(err, r, "out of memory");
        _cleanup_proto_message_ struct imp_proto_message m = {};
        r = read_message(c, IMP_CLIENT_REPLY_TIMEOUT_MS, &m, err);
        if (r == 0)
                return imp_error_set(err, -ETIMEDOUT, "impastod at %s sent no banner within %d s", path,
                                     IMP_CLIENT_REPLY_TIMEOUT_MS / 1000);
        if (r < 0)
                return imp_error_prefix(err, "%s: ", path);
        /* A daemon that cannot take the connection says why instead of a banner (busy: too
         * many connections; shutting_down). */
        if (m.kind == IMP_PROTO_MSG_REPLY && !m.ok)
                return imp_error_set(err, m.error.code == IMP_PROTO_E_BUSY ? -EBUSY
                                          : m.error.sys_errno > 0 ? -m.error.sys_errno : -ECONNREFUSED,
                                     "impastod at %s refused the connection: %s (%s)", path, m.error.message,
                                     imp_proto_error_code_name(m.error.code));
        if (m.kind != IMP_PROTO_MSG_BANNER)
                return imp_error_set(err, -EBADMSG, "%s: the first line from the daemon is not a banner", path);
        if (m.protocol != IMP_PROTO_VERSION)
                return imp_error_set(err, -EPROTO,
                                     "%s: the daemon speaks protocol %lld, this client protocol %d; "
                                     "use an impasto client of the daemon's release (%s)",
                                     path, m.protocol, IMP_PROTO_VERSION, m.version ? m.version : "?");
        c->role = m.role;
        snprintf(c->version, sizeof c->version, "%s", m.version ? m.version : "");
        *ret = TAKE_PTR(cc);
        return 0;
}

static int write_all(int fd, const char *s, size_t n) {
        while (n > 0) {
                ssize_t w = send(fd, s, n, MSG_NOSIGNAL);
                if (w < 0) {
                        if (errno == EINTR)
                                continue;
                        return negative_errno();
                }
                s += w;
                n -= (size_t) w;
        }
        return 0;
}

int imp_client_call(struct imp_client *c, const char *cmd, json_t *args, imp_client_event_fn on_event,
                    void *userdata, struct imp_proto_message *ret, struct imp_error *err) {
        long long id = c->next_id++;
        _cleanup_json_ json_t *req = json_pack("{s:I,s:s}", "id", (json_int_t) id, "cmd", cmd);
        if (!req || (args && json_object_set_new(req, "args", args) < 0)) {
                if (!req)
                        json_decref(args);
                return imp_error_set(err, -ENOMEM, "out of memory");
        }
        _cleanup_free_ char *line = imp_proto_dump_line(req);
        if (!line)
                return imp_error_set(err, -ENOMEM, "out of memory");
        int r = write_all(c->fd, line, strlen(line));
        if (r < 0)
                return imp_error_set(err, r, "sending %s to the daemon: %s", cmd, strerror(-r));
        long long deadline = now_ms() + IMP_CLIENT_REPLY_TIMEOUT_MS;
        for (;;) {
                long long left = deadline - now_ms();
                struct imp_proto_message m = {};
                r = left > 0 ? read_message(c, (int) left, &m, err) : 0;
                if (r == 0)
                        return imp_error_set(err, -ETIMEDOUT, "no reply to %s within %d s", cmd,
                                             IMP_CLIENT_REPLY_TIMEOUT_MS / 1000);
                if (r < 0)
                        return r;
                if (m.kind == IMP_PROTO_MSG_REPLY && json_is_integer(m.id) &&
                    json_integer_value(m.id) == id) {
                        *ret = m;
                        return 0;
                }
                if (m.kind == IMP_PROTO_MSG_REPLY && json_is_null(m.id) && !m.ok) {
                        /* the daemon could not read our request's id: this is our answer */
                        *ret = m;
                        return 0;
                }
                if (m.kind == IMP_PROTO_MSG_EVENT && on_event)
                        on_event(userdata, &m);
                imp_proto_message_done(&m);
        }
}

int imp_client_next_event(struct imp_client *c, int timeout_ms, struct imp_proto_message *ret,
                          struct imp_error *err) {
        long long deadline = timeout_ms < 0 ? -1 : now_ms() + timeout_ms;
        for (;;) {
                int left = -1;
                if (deadline >= 0) {
                        long long l = deadline - now_ms();
                        if (l <= 0)
                                return 0;
                        left = (int) l;
                }
                struct imp_proto_message m = {};
                int r = read_message(c, left, &m, err);
                if (r <= 0)
                        return r;
                if (m.kind == IMP_PROTO_MSG_EVENT) {
                        *ret = m;
                        return 1;
                }
                imp_proto_message_done(&m);
        }
}

int imp_client_exit_for_errno(int r) {
        switch (-r) {
        case ENOENT: case ECONNREFUSED: case EACCES: case EPERM: case ECONNRESET: case EPIPE:
        case ENOTSOCK: case ENOTDIR: case ETIMEDOUT: case ENAMETOOLONG: case ENXIO: case ENOTCONN:
                return IMP_EXIT_UNREACHABLE;
        default:
                return IMP_EXIT_FAILURE;
        }
}

/* ---- helpers for the commands ---- */

int imp_client_connect_or_log(const struct imp_client_opts *o, struct imp_client **ret) {
        const char *path = imp_client_socket_path(o->socket);
        struct imp_error err = {};
        int r = imp_client_open(path, ret, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                if (r == -ENOENT || r == -ECONNREFUSED)
                        log_notice("is impastod running? (systemctl status impastod; "
                                   "--socket PATH or $IMPASTO_SOCKET name another socket)");
                else if (r == -EACCES)
                        log_notice("the socket belongs to group impasto: add your user to it");
                return imp_client_exit_for_errno(r);
        }
        return 0;
}

int imp_client_report_error(const char *cmd, const struct imp_proto_message *reply) {
        const struct imp_proto_error *e = &reply->error;
        const json_t *err = json_object_get(reply->root, "error");
        const char *code = imp_client_str(err, "code");
        log_error("%s: %s: %s%s%s%s", cmd, code[0] ? code : imp_proto_error_code_name(e->code), e->message,
                  e->field[0] ? " (" : "", e->field, e->field[0] ? ")" : "");
        if (e->code == IMP_PROTO_E_PERMISSION_DENIED)
                log_notice("%s needs the operator role: add your user to group %s", cmd, IMP_PROTO_OPERATOR_GROUP);
        else if (e->code == IMP_PROTO_E_UNKNOWN_COMMAND)
                log_notice("the daemon is older than this client and has no %s", cmd);
        return imp_proto_exit_status(e->code);
}

static void print_json(const json_t *j) {
        _cleanup_free_ char *s = json_dumps(j, JSON_INDENT(2) | JSON_PRESERVE_ORDER);
        if (s)
                puts(s);
}

int imp_client_simple(const struct imp_client_opts *o, const char *cmd, json_t *args,
                      void (*human)(const json_t *result)) {
        _cleanup_json_ json_t *a = args;
        _cleanup_client_ struct imp_client *c = NULL;
        int rc = imp_client_connect_or_log(o, &c);
        if (rc)
                return rc;
        struct imp_error err = {};
        _cleanup_proto_message_ struct imp_proto_message reply = {};
        int r = imp_client_call(c, cmd, TAKE_PTR(a), NULL, NULL, &reply, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!reply.ok)
                return imp_client_report_error(cmd, &reply);
        if (o->json) {
                _cleanup_free_ char *s = json_dumps(reply.result, JSON_COMPACT | JSON_PRESERVE_ORDER);
                if (s)
                        puts(s);
        } else if (human)
                human(reply.result);
        else
                print_json(reply.result);
        return fflush(stdout) == 0 ? 0 : IMP_EXIT_FAILURE;
}

const char *imp_client_str(const json_t *obj, const char *key) {
        const char *s = json_string_value(json_object_get(obj, key));
        return s ? s : "";
}

long long imp_client_int(const json_t *obj, const char *key) {
        const json_t *v = json_object_get(obj, key);
        return json_is_integer(v) ? json_integer_value(v) : json_is_real(v) ? (long long) json_real_value(v) : 0;
}

double imp_client_num(const json_t *obj, const char *key) {
        const json_t *v = json_object_get(obj, key);
        return json_is_number(v) ? json_number_value(v) : NAN;
}

const char *imp_client_fmt_bytes(double bytes, char *buf, size_t size) {
        static const char *const units[] = { "B", "kB", "MB", "GB", "TB" };
        int u = 0;
        while (bytes >= 1000 && u < 4) {
                bytes /= 1000;
                u++;
        }
        snprintf(buf, size, u ? "%.1f %s" : "%.0f %s", bytes, units[u]);
        return buf;
}

const char *imp_client_fmt_duration(double s, char *buf, size_t size) {
        if (!isfinite(s) || s < 0)
                snprintf(buf, size, "?");
        else if (s < 60)
                snprintf(buf, size, "%.1f s", s);
        else if (s < 3600)
                snprintf(buf, size, "%d min %02d s", (int) s / 60, (int) s % 60);
        else
                snprintf(buf, size, "%d h %02d min", (int) s / 3600, ((int) s % 3600) / 60);
        return buf;
}

int imp_client_main_simple(int argc, char **argv, const char *cmd, void (*human)(const json_t *result)) {
        struct imp_client_opts o = {};
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' }, { "socket", required_argument, NULL, 'S' },
                { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'h': printf("usage: impasto %s [--json] [--socket PATH]\n", cmd); return 0;
                default:
                        fprintf(stderr, "usage: impasto %s [--json] [--socket PATH]\n", cmd);
                        return IMP_EXIT_USAGE;
                }
        if (optind != argc) {
                fprintf(stderr, "impasto %s: unexpected argument '%s'\nusage: impasto %s [--json] [--socket PATH]\n",
                        cmd, argv[optind], cmd);
                return IMP_EXIT_USAGE;
        }
        return imp_client_simple(&o, cmd, NULL, human);
}

int imp_client_subscribe(struct imp_client *c, json_t *events, unsigned long long *ret_seq) {
        struct imp_error err = {};
        _cleanup_proto_message_ struct imp_proto_message reply = {};
        int r = imp_client_call(c, "subscribe", json_pack("{s:o}", "events", events), NULL, NULL, &reply, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!reply.ok)
                return imp_client_report_error("subscribe", &reply);
        *ret_seq = (unsigned long long) imp_client_int(reply.result, "seq");
        return IMP_EXIT_OK;
}

int imp_client_parse_limit(const char *arg, long *ret) {
        return imp_parse_long("--limit", arg, 1, 1000, ret) < 0 ? IMP_EXIT_USAGE : 0;
}

void imp_client_print_table(const json_t *rows, const struct imp_client_column *cols, size_t n_cols,
                            const char *empty) {
        if (!json_array_size(rows)) {
                printf("%s\n", empty);
                return;
        }
        for (size_t k = 0; k < n_cols; k++)
                printf("%-*s%s", cols[k].width, cols[k].title, k + 1 < n_cols ? " " : "\n");
        size_t i;
        const json_t *row;
        json_array_foreach(rows, i, row)
                for (size_t k = 0; k < n_cols; k++) {
                        const json_t *v = json_object_get(row, cols[k].key);
                        char num[32];
                        if (json_is_integer(v))
                                snprintf(num, sizeof num, "%lld", (long long) json_integer_value(v));
                        printf("%-*s%s", cols[k].width, json_is_integer(v) ? num : imp_client_str(row, cols[k].key),
                               k + 1 < n_cols ? " " : "\n");
                }
}

void imp_client_count_gap(unsigned long long *last_seq, unsigned long long *dropped, unsigned long long seq) {
        if (*last_seq && seq > *last_seq + 1)
                *dropped += seq - *last_seq - 1;
        *last_seq = seq;
}
