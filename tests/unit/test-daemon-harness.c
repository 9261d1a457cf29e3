/* Shared by the impastod tests (#included, not a test itself): the emulated rig in-process
 * (GigE camera with the default fill, Modbus dome), the files impastod needs (rig config,
 * rig.json, plan), impastod as a child process, and a blocking protocol client built on
 * the shared codec. */
#include <fcntl.h>
#include <linux/sched.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/un.h>
#include <sys/syscall.h>
#include <sys/wait.h>
#include <time.h>
#include "captureset.h"
#include "emu.h"
#include "json-util.h"
#include "plan.h"
#include "protocol.h"
#include "rig.h"
#include "unit/test.h"

#define H_WIDTH 64
#define H_HEIGHT 32

struct harness {
        char dir[256];
        char socket[300], state[300], rigcfg[300], rigjson[300];
        int port;
        unsigned n_lights;
        struct imp_emu_rig *rig;
        struct imp_emu_modbus *mb;
        struct imp_emu_gige *gige;
        pid_t pid;
        /* h_start options */
        bool roles_from_credentials;    /* no --operators-all: roles as the kernel says */
        bool new_pid_namespace;         /* impastod as PID 1 of a new PID namespace */
        const char *stderr_path;        /* impastod's standard error into this file */
        bool keep_socket;               /* leave a socket file at h->socket (another daemon's) */
};

_unused_ static uint64_t h_now_ms(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000 + (uint64_t) ts.tv_nsec / 1000000;
}

/* A deadline `ms` from now, scaled for sanitizer builds and loaded machines. */
_unused_ static uint64_t h_deadline_ms(unsigned ms) {
        return h_now_ms() + (uint64_t) (ms * test_timeout_scale());
}

_unused_ static void h_write(const char *path, const char *text) {
        FILE *f = fopen(path, "we");
        if (!f) {
                perror(path);
                exit(2);
        }
        fputs(text, f);
        fclose(f);
}

/* Emulators and files; exits 77 when the GVCP port or the Modbus port is taken. */
_unused_ static void h_setup(struct harness *h, int port, unsigned n_lights) {
        memset(h, 0, sizeof *h);
        snprintf(h->dir, sizeof h->dir, "%s", test_tmpdir());
        snprintf(h->socket, sizeof h->socket, "%s/control.sock", h->dir);
        snprintf(h->state, sizeof h->state, "%s/state", h->dir);
        snprintf(h->rigcfg, sizeof h->rigcfg, "%s/rig.cfg", h->dir);
        snprintf(h->rigjson, sizeof h->rigjson, "%s/rig.json", h->dir);
        h->port = port;
        h->n_lights = n_lights;
        if (!imp_emu_gige_port_free("127.0.0.1"))
                TEST_SKIP("UDP 127.0.0.1:3956 (GVCP) is taken by another camera");
        if (imp_emu_rig_new(n_lights, &h->rig) < 0)
                exit(2);
        struct imp_emu_modbus_config cfg = { .port = (uint16_t) port, .n_lights = n_lights, .n_axes = 1 };
        int r = imp_emu_modbus_new(&cfg, h->rig, &h->mb);
        if (r == -EADDRINUSE)
                TEST_SKIP("TCP port %d on 127.0.0.1 is busy", port);
        if (r < 0)
                exit(2);
        r = imp_emu_gige_new("127.0.0.1", "IMP-DAEMON", h->rig, NULL, NULL, &h->gige);
        if (r == -EADDRINUSE)
                TEST_SKIP("UDP 127.0.0.1:3956 (GVCP) is taken by another camera");
        if (r < 0)
                exit(2);

        struct imp_rig rig = { .n_cameras = 1, .settle_us = 1000 };
        struct imp_rig_camera *c = &rig.cameras[0];
        snprintf(c->name, sizeof c->name, "cam0");
        c->model = (struct imp_pinhole) { .width = H_WIDTH, .height = H_HEIGHT, .fx = 100, .fy = 100,
                                          .cx = H_WIDTH / 2.0, .cy = H_HEIGHT / 2.0,
                                          .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }, .t = { 0, 0, 500 } };
        c->sensor = (struct imp_sensor) { .bits = 16, .gain_e_per_dn = 1, .full_well_e = 60000,
                                          .quantum_scale = 1, .readout_us = 1000 };
        rig.n_lights = (int) n_lights;
        rig.lights = calloc(n_lights, sizeof *rig.lights);
        for (unsigned i = 0; i < n_lights; i++)
                rig.lights[i] = (struct imp_rig_light) { .id = (int) i, .pos_mm = { 100.0 * i, 0, 500 },
                                                         .intensity = 1, .colour = { 1, 1, 1 }, .axis = { 0, 0, -1 } };
        struct imp_error e = { 0 };
        if (imp_rig_save(h->rigjson, &rig, &e) < 0) {
                fprintf(stderr, "rig.json: %s\n", e.msg);
                exit(2);
        }
        imp_rig_free(&rig);
        char cfgtext[1024];
        snprintf(cfgtext, sizeof cfgtext,
                 "rig = {\n  name = \"test-rig\";\n  calibration = \"rig.json\";\n"
                 "  cameras = ( { name = \"cam0\"; backend = \"aravis\"; address = \"127.0.0.1\"; } );\n"
                 "  dome = { backend = \"modbus\"; address = \"127.0.0.1:%d\"; };\n};\n", port);
        h_write(h->rigcfg, cfgtext);
}

_unused_ static void h_teardown(struct harness *h) {
        imp_emu_gige_free(h->gige);
        imp_emu_modbus_free(h->mb);
        imp_emu_rig_free(h->rig);
}

struct h_exec {
        const struct harness *h;
        const char *const *argv;
};

static int h_exec_child(void *userdata) {
        const struct h_exec *x = userdata;
        const char *err = x->h->stderr_path ? x->h->stderr_path : getenv("IMPASTO_TEST_VERBOSE") ? NULL : "/dev/null";
        if (err) {
                int fd = open(err, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
                if (fd >= 0)
                        dup2(fd, 2);
        }
        execv(x->argv[0], (char **) x->argv);
        _exit(127);
}

/* fork, or (new_pid_namespace, needs root) the raw clone(2) that is fork into a new PID
 * namespace, then exec argv. */
static pid_t h_spawn(const struct harness *h, const char *const *argv) {
        struct h_exec x = { h, argv };
        pid_t pid = h->new_pid_namespace ? (pid_t) syscall(SYS_clone, CLONE_NEWPID | SIGCHLD, NULL, NULL, NULL, NULL)
                                         : fork();
        if (pid < 0) {
                perror(h->new_pid_namespace ? "clone(CLONE_NEWPID)" : "fork");
                exit(2);
        }
        if (pid == 0)
                h_exec_child(&x);
        return pid;
}

/* Starts impastod with the harness paths and extra options (NULL-terminated). */
_unused_ static void h_start(struct harness *h, const char *const *extra) {
        const char *argv[32];
        int n = 0;
        /* IMPASTO_TEST_IMPASTOD: another impastod binary (e.g. an older one, to see a test fail) */
        argv[n++] = getenv("IMPASTO_TEST_IMPASTOD") ?: IMPASTO_BINARY_DIR "/daemon/impastod";
        argv[n++] = "--rig";
        argv[n++] = h->rigcfg;
        argv[n++] = "--socket";
        argv[n++] = h->socket;
        argv[n++] = "--state-dir";
        argv[n++] = h->state;
        if (!h->roles_from_credentials)
                argv[n++] = "--operators-all";
        for (; extra && *extra && n < 30; extra++)
                argv[n++] = *extra;
        argv[n] = NULL;
        if (!h->keep_socket)
                unlink(h->socket);
        h->pid = h_spawn(h, argv);
}

/* Waits for exit; returns the wait status, or -1 after timeout_ms (then kills). */
_unused_ static int h_wait(struct harness *h, unsigned timeout_ms) {
        uint64_t end = h_deadline_ms(timeout_ms);
        int st;
        while (h_now_ms() < end) {
                pid_t r = waitpid(h->pid, &st, WNOHANG);
                if (r == h->pid) {
                        h->pid = 0;
                        return st;
                }
                usleep(5000);
        }
        kill(h->pid, SIGKILL);
        waitpid(h->pid, &st, 0);
        h->pid = 0;
        return -1;
}

_unused_ static void h_kill(struct harness *h, int sig) {
        if (h->pid > 0) {
                kill(h->pid, sig);
                if (sig == SIGKILL)
                        (void) h_wait(h, 5000);
        }
}

/* ---- client ------------------------------------------------------------------------------ */

struct tclient {
        int fd;
        struct imp_linebuf *lb;
        long long next_id;
        enum imp_proto_role role;
        /* events seen while waiting for replies */
        unsigned n_events, n_frames, n_done, n_faults, n_jobs;
        unsigned long long last_seq;
        bool seq_gap;
        char done_state[32], job_state[32];
        /* job events of a running job that named the worker's stage (progress events) */
        unsigned n_job_progress;
        char job_stage[64];
        double job_progress;
};

_unused_ static int tc_connect(struct tclient *c, const char *path, unsigned timeout_ms) {
        memset(c, 0, sizeof *c);
        c->fd = -1;
        struct sockaddr_un sa = { .sun_family = AF_UNIX };
        if (strlen(path) >= sizeof sa.sun_path)
                return -ENAMETOOLONG;
        memcpy(sa.sun_path, path, strlen(path) + 1);
        uint64_t end = h_deadline_ms(timeout_ms);
        for (;;) {
                int fd = socket(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0);
                if (connect(fd, (struct sockaddr *) &sa, sizeof sa) == 0) {
                        c->fd = fd;
                        break;
                }
                close(fd);
                if (h_now_ms() > end)
                        return -ETIMEDOUT;
                usleep(10000);
        }
        if (imp_linebuf_new(IMP_PROTO_MESSAGE_MAX, &c->lb) < 0)
                return -ENOMEM;
        return 0;
}

_unused_ static void tc_close(struct tclient *c) {
        if (c->fd >= 0)
                close(c->fd);
        c->fd = -1;
        imp_linebuf_free(c->lb);
        c->lb = NULL;
}

_unused_ static int tc_send_raw(struct tclient *c, const void *data, size_t n) {
        const char *p = data;
        while (n > 0) {
                ssize_t k = send(c->fd, p, n, MSG_NOSIGNAL);
                if (k < 0) {
                        if (errno == EINTR)
                                continue;
                        return -errno;
                }
                p += k;
                n -= (size_t) k;
        }
        return 0;
}

/* Next message within timeout_ms: 0, -ETIMEDOUT, -ECONNRESET at EOF, -EBADMSG. Events are
 * counted in c as they pass. */
_unused_ static int tc_read(struct tclient *c, unsigned timeout_ms, struct imp_proto_message *ret) {
        uint64_t end = h_deadline_ms(timeout_ms);
        for (;;) {
                char *line;
                size_t len;
                int r = imp_linebuf_next(c->lb, &line, &len);
                if (r == 1) {
                        struct imp_proto_error e = { 0 };
                        r = imp_proto_parse_reply(line, len, ret, &e);
                        imp_proto_error_done(&e);
                        if (r < 0)
                                return r;
                        if (ret->kind == IMP_PROTO_MSG_EVENT) {
                                c->n_events++;
                                if (c->last_seq && ret->seq != c->last_seq + 1)
                                        c->seq_gap = true;
                                c->last_seq = ret->seq;
                                const char *ev = ret->event;
                                const char *st = json_string_value(json_object_get(ret->root, "state"));
                                if (!strcmp(ev, "frame"))
                                        c->n_frames++;
                                else if (!strcmp(ev, "done")) {
                                        c->n_done++;
                                        snprintf(c->done_state, sizeof c->done_state, "%s", st ? st : "");
                                } else if (!strcmp(ev, "fault"))
                                        c->n_faults++;
                                else if (!strcmp(ev, "job")) {
                                        c->n_jobs++;
                                        snprintf(c->job_state, sizeof c->job_state, "%s", st ? st : "");
                                        const char *stage = json_string_value(json_object_get(ret->root, "stage"));
                                        if (st && !strcmp(st, "running") && stage) {
                                                c->n_job_progress++;
                                                snprintf(c->job_stage, sizeof c->job_stage, "%s", stage);
                                                c->job_progress = json_number_value(json_object_get(ret->root,
                                                                                                    "progress"));
                                        }
                                }
                        } else if (ret->kind == IMP_PROTO_MSG_BANNER)
                                c->role = ret->role;
                        return 0;
                }
                if (r < 0 && r != -E2BIG)
                        return r;
                int64_t left = (int64_t) end - (int64_t) h_now_ms();
                if (left <= 0)
                        return -ETIMEDOUT;
                struct pollfd pfd = { .fd = c->fd, .events = POLLIN };
                if (poll(&pfd, 1, (int) left) <= 0)
                        continue;
                char buf[65536];
                ssize_t n = recv(c->fd, buf, sizeof buf, 0);
                if (n <= 0)
                        return -ECONNRESET;
                if (imp_linebuf_feed(c->lb, buf, (size_t) n) < 0)
                        return -ENOMEM;
        }
}

/* Reads (and counts) messages until n frame events have come, a session ended (a done
 * event) or nothing came for timeout_ms. */
_unused_ static void tc_wait_frames(struct tclient *c, unsigned n, unsigned timeout_ms) {
        while (c->n_frames < n && !c->n_done) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, timeout_ms, &m) < 0)
                        break;
                imp_proto_message_done(&m);
        }
}

/* Sends {"id","cmd","args"} and returns its reply in *ret (events before it are counted).
 * args is stolen. */
_unused_ static int tc_call(struct tclient *c, const char *cmd, json_t *args, struct imp_proto_message *ret) {
        long long id = ++c->next_id;
        json_t *req = json_pack("{s:I, s:s}", "id", (json_int_t) id, "cmd", cmd);
        if (args)
                json_object_set_new(req, "args", args);
        char *line = imp_proto_dump_line(req);
        json_decref(req);
        int r = tc_send_raw(c, line, strlen(line));
        free(line);
        if (r < 0)
                return r;
        for (;;) {
                struct imp_proto_message m = { 0 };
                if ((r = tc_read(c, 20000, &m)) < 0)
                        return r;
                if (m.kind == IMP_PROTO_MSG_REPLY && json_is_integer(m.id) && json_integer_value(m.id) == id) {
                        *ret = m;
                        return 0;
                }
                imp_proto_message_done(&m);
        }
}

/* A call expected to succeed: the result (a new reference), or NULL with a test failure. */
_unused_ static json_t *tc_ok(struct tclient *c, const char *cmd, json_t *args) {
        struct imp_proto_message m = { 0 };
        int r = tc_call(c, cmd, args, &m);
        if (r < 0) {
                CHECK_MSG(0, "%s: no reply (%s)", cmd, strerror(-r));
                return NULL;
        }
        json_t *res = NULL;
        if (!m.ok)
                CHECK_MSG(0, "%s: %s: %s", cmd, imp_proto_error_code_name(m.error.code), m.error.message);
        else
                res = json_incref((json_t *) m.result);
        imp_proto_message_done(&m);
        return res;
}

/* The error code of a call expected to fail (IMP_PROTO_E_NONE when it succeeded). */
_unused_ static enum imp_proto_errcode tc_err(struct tclient *c, const char *cmd, json_t *args, char *msg, size_t size) {
        struct imp_proto_message m = { 0 };
        if (tc_call(c, cmd, args, &m) < 0)
                return IMP_PROTO_E_INTERNAL;
        enum imp_proto_errcode code = m.ok ? IMP_PROTO_E_NONE : m.error.code;
        if (msg)
                snprintf(msg, size, "%s", m.ok ? "" : m.error.message);
        imp_proto_message_done(&m);
        return code;
}

/* Connect, read the banner and subscribe to every event. */
_unused_ static int tc_open(struct tclient *c, const char *path, bool subscribe) {
        int r = tc_connect(c, path, 10000);
        if (r < 0)
                return r;
        struct imp_proto_message m = { 0 };
        if ((r = tc_read(c, 10000, &m)) < 0)
                return r;
        bool banner = m.kind == IMP_PROTO_MSG_BANNER;
        imp_proto_message_done(&m);
        if (!banner)
                return -EBADMSG;
        if (subscribe) {
                json_t *res = tc_ok(c, "subscribe", NULL);
                if (!res)
                        return -EIO;
                json_decref(res);
        }
        return 0;
}

/* Reads until n_done reaches `done` (or a job event in state `job_state` when given). */
_unused_ static int tc_wait_done(struct tclient *c, unsigned done, unsigned timeout_ms) {
        uint64_t end = h_deadline_ms(timeout_ms);
        while (c->n_done < done) {
                int64_t left = (int64_t) end - (int64_t) h_now_ms();
                if (left <= 0)
                        return -ETIMEDOUT;
                struct imp_proto_message m = { 0 };
                int r = tc_read(c, (unsigned) left, &m);
                if (r < 0)
                        return r;
                imp_proto_message_done(&m);
        }
        return 0;
}

_unused_ static int tc_wait_job(struct tclient *c, const char *state, unsigned timeout_ms) {
        uint64_t end = h_deadline_ms(timeout_ms);
        while (strcmp(c->job_state, state)) {
                int64_t left = (int64_t) end - (int64_t) h_now_ms();
                if (left <= 0)
                        return -ETIMEDOUT;
                struct imp_proto_message m = { 0 };
                int r = tc_read(c, (unsigned) left, &m);
                if (r < 0)
                        return r;
                imp_proto_message_done(&m);
        }
        return 0;
}

_unused_ static json_t *h_arg(const char *key, const char *value) {
        return json_pack("{s:s}", key, value);
}

/* The end of a capture test: the session says completed with every frame, the client goes,
 * impastod exits 0 on SIGTERM, and the set equals an uninterrupted one frame for frame with
 * never two lights on at once. */
_unused_ static size_t h_verify_set(const char *dir, const char *plan_path, bool expect_complete);
_unused_ static void h_check_completed(struct harness *h, struct tclient *c, const char *id, const char *setdir,
                                       const char *plan, size_t frames) {
        json_t *r = tc_ok(c, "session.show", h_arg("session", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "completed");
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), frames);
        json_decref(r);
        tc_close(c);
        h_kill(h, SIGTERM);
        CHECK(h_wait(h, 10000) == 0);
        CHECK_INT_EQ(h_verify_set(setdir, plan, true), frames);
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(h->rig), 1);
}

/* session.start of plan as name: the session id and its set's path ("" when refused). */
_unused_ static void tc_start_session(struct tclient *c, const char *plan, const char *name, char id[static 128],
                                      char setdir[static 1024]) {
        json_t *r = tc_ok(c, "session.start", json_pack("{s:s, s:s}", "plan", plan, "name", name));
        const char *i = json_string_value(json_object_get(r, "session"));
        const char *p = json_string_value(json_object_get(r, "path"));
        snprintf(id, 128, "%s", i ? i : "");
        snprintf(setdir, 1024, "%s", p ? p : "");
        json_decref(r);
}

/* Checks a finished capture set against the plan and the emulator's pixel formula. Returns
 * the number of frames. */
_unused_ static size_t h_verify_set(const char *dir, const char *plan_path, bool expect_complete) {
        struct imp_error e = { 0 };
        struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(dir, &cs, &e);
        CHECK_MSG(r == 0, "open %s: %s", dir, e.msg);
        if (r < 0)
                return 0;
        struct imp_plan *plan = NULL;
        r = imp_plan_load(plan_path, imp_captureset_rig(cs), &plan, &e);
        CHECK_MSG(r == 0, "plan %s: %s", plan_path, e.msg);
        size_t n = imp_captureset_count(cs);
        if (plan && expect_complete)
                CHECK_INT_EQ(n, (size_t) imp_plan_count(plan));
        static uint16_t expected[H_WIDTH * H_HEIGHT];
        for (size_t i = 0; plan && i < n && i < imp_plan_count(plan); i++) {
                const struct imp_frame_record *a = imp_captureset_record(cs, i), *b = imp_plan_frame(plan, i);
                CHECK_INT_EQ(a->seq, (long long) i);
                CHECK_INT_EQ(a->light, b->light);
                CHECK_INT_EQ(a->exposure_index, b->exposure_index);
                CHECK_NEAR(a->exposure_us, b->exposure_us, 0);
                CHECK_STR_EQ(a->camera, b->camera);
                CHECK_STR_EQ(a->step, b->step);
                CHECK(a->t_light_on_ns > 0 && a->t_trigger_ns >= a->t_light_on_ns && a->t_frame_ns >= a->t_trigger_ns);
                struct imp_image *img = NULL;
                r = imp_captureset_load_frame(cs, i, &img, &e);
                CHECK_MSG(r == 0, "frame %zu: %s", i, e.msg);
                if (r < 0)
                        continue;
                int light = -9, pattern = -9;
                uint32_t exp_us = 0;
                CHECK_INT_EQ(img->width, H_WIDTH);
                CHECK_INT_EQ(img->height, H_HEIGHT);
                r = imp_emu_decode_default(img->data, img->width, img->height, 2, &light, &pattern, &exp_us);
                CHECK_MSG(r == 0, "frame %zu: not an emulator frame (%s)", i, strerror(-r));
                CHECK_MSG(light == b->light, "frame %zu claims light %d, shows %d", i, b->light, light);
                CHECK_INT_EQ(exp_us, (uint32_t) b->exposure_us);
                struct imp_emu_camera_state st = { .exposure_us = (uint32_t) b->exposure_us, .lit_light = b->light,
                                                   .pattern = -1 };
                imp_emu_fill_default(NULL, &st, expected, H_WIDTH, H_HEIGHT, 2);
                CHECK_MSG(memcmp(expected, img->data, sizeof expected) == 0, "frame %zu: pixels differ", i);
                imp_image_free(img);
        }
        imp_plan_free(plan);
        imp_captureset_close(cs);
        return n;
}

/* The resident set of a process in KiB (VmRSS of /proc/PID/status); 0 when unreadable. */
static inline uint64_t rss_kib(pid_t pid) {
        char p[64], line[256];
        snprintf(p, sizeof p, "/proc/%d/status", (int) pid);
        FILE *f = fopen(p, "re");
        uint64_t v = 0;
        while (f && fgets(line, sizeof line, f))
                if (!strncmp(line, "VmRSS:", 6))
                        v = strtoull(line + 6, NULL, 10);
        if (f)
                fclose(f);
        return v;
}
