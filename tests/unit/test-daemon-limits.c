/* impastod's socket against clients that would take it over or wear it down (docs/security.md),
 * one part per argument, each against a fresh daemon on the emulated rig's files:
 *
 *   roles      the role comes from the kernel's credentials at connect(), not /proc/<pid>: a
 *              client whose /proc status shows the operator group by the time the daemon
 *              accepts (it gained the group after connecting, as a recycled pid would show
 *              another process's) stays an observer; a real member is an operator
 *   pidns      impastod in its own PID namespace sees peer pid 0: the plan readability check
 *              still applies, and an operator-group member is still an operator
 *   slowreader a client pipelining requests without reading its replies: impastod's memory
 *              stays bounded and others are served
 *   slots      per-uid limit, slots kept for operators, idle and slowloris timeouts, and the
 *              CLI saying "too many connections"
 *   devices    `devices` never stalls the loop on an absent camera: root's status answers
 *              within 1 s while an observer and an operator each pipeline 10 of them
 *   instance   a second impastod on the same state directory or socket is refused and leaves
 *              the first one's socket alone
 *   verdict    jobs.list/jobs.show/status carry the copy's quality.verdict, and only then
 *
 * Needs root (it runs clients as other uids and bind-mounts an /etc/group with the operator
 * group in a private mount namespace); skipped (77) otherwise. */
#define _GNU_SOURCE 1
#include "test-daemon-harness.c"
#include <grp.h>
#include <sched.h>
#include <linux/capability.h>
#include <sys/mount.h>
#include <sys/prctl.h>
#include <sys/syscall.h>

#define PORT 15871
#define N_LIGHTS 2
#define OP_GID 4242
#define NOBODY 65534
/* a prompt answer, for status while others abuse the socket (× IMPASTO_TIMEOUT_SCALE) */
#define PROMPT_MS ((uint64_t) (1000 * test_timeout_scale()))
#define OTHER_UID 65533
#define THIRD_UID 65532

/* ---- set-up ------------------------------------------------------------------------------- */

/* A private mount namespace whose /etc/group has impasto-operators (gid OP_GID). */
static void operator_group(const struct harness *h) {
        if (geteuid() != 0)
                TEST_SKIP("needs root (clients as other uids, a private /etc/group)");
        if (unshare(CLONE_NEWNS) < 0 || mount(NULL, "/", NULL, MS_REC | MS_PRIVATE, NULL) < 0)
                TEST_SKIP("no private mount namespace: %s", strerror(errno));
        char p[512], line[1024];
        snprintf(p, sizeof p, "%s/group", h->dir);
        FILE *in = fopen("/etc/group", "re"), *out = fopen(p, "we");
        if (!out)
                exit(2);
        while (in && fgets(line, sizeof line, in))
                if (strncmp(line, IMP_PROTO_OPERATOR_GROUP ":", strlen(IMP_PROTO_OPERATOR_GROUP) + 1))
                        fputs(line, out);
        fprintf(out, "%s:x:%d:\n", IMP_PROTO_OPERATOR_GROUP, OP_GID);
        if (in)
                fclose(in);
        fclose(out);
        if (mount(p, "/etc/group", NULL, MS_BIND, NULL) < 0)
                TEST_SKIP("bind-mounting /etc/group: %s", strerror(errno));
        struct group *g = getgrnam(IMP_PROTO_OPERATOR_GROUP);
        if (!g || g->gr_gid != OP_GID)
                TEST_SKIP("the bind-mounted /etc/group is not used by NSS here");
        /* other uids must reach the socket and the plans */
        chmod(h->dir, 0755);
}

/* With IMPASTO_TEST_IMPASTOD (an older impastod, to see the tests fail without the fixes), the
 * limit options it does not know are left out, so that it runs with its own behaviour. */
static void start(struct harness *h, const char *const *extra) {
        static const char *const new_opts[] = { "--max-clients-per-uid", "--reserved-slots", "--idle-timeout-s",
                                                "--request-timeout-s", "--device-probe-interval-s", NULL };
        const char *kept[32];
        int n = 0;
        for (; extra && *extra && n < 30; extra++) {
                bool drop = false;
                for (int i = 0; getenv("IMPASTO_TEST_IMPASTOD") && new_opts[i]; i++)
                        drop |= !strcmp(*extra, new_opts[i]);
                if (drop)
                        extra++;        /* and its value */
                else
                        kept[n++] = *extra;
        }
        kept[n] = NULL;
        h->roles_from_credentials = true;
        h_start(h, kept);
        struct tclient c;
        CHECK_OK(tc_open(&c, h->socket, false));
        tc_close(&c);
        chmod(h->socket, 0666);         /* (a real socket is 0660 root:impasto) */
}

static void stop(struct harness *h) {
        if (h->pid > 0) {
                h_kill(h, SIGTERM);
                int st = h_wait(h, 10000);
                CHECK_MSG(st >= 0 && WIFEXITED(st) && WEXITSTATUS(st) == 0, "impastod on SIGTERM: wait status %d "
                          "(a sanitizer report makes it non-zero)", st);
        }
}

/* In a child: drop to uid/gid with exactly these supplementary groups. */
static void become(uid_t uid, gid_t gid, const gid_t *groups, size_t n) {
        if (setgroups(n, groups) < 0 || setresgid(gid, gid, gid) < 0 || setresuid(uid, uid, uid) < 0) {
                perror("dropping privileges");
                _exit(90);
        }
}

static int child_status(pid_t pid) {
        int st;
        if (waitpid(pid, &st, 0) != pid)
                return -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

/* The role in the banner of a fresh connection, as uid with groups (a child); -1 on error. */
static int role_as(const struct harness *h, uid_t uid, const gid_t *groups, size_t n) {
        pid_t pid = fork();
        if (pid == 0) {
                become(uid, uid, groups, n);
                struct tclient c;
                if (tc_open(&c, h->socket, false) < 0)
                        _exit(99);
                _exit(c.role == IMP_PROTO_ROLE_OPERATOR ? 1 : 0);
        }
        int st = child_status(pid);
        return st == 0 || st == 1 ? st : -1;
}

/* ms for a status call on c */
static uint64_t status_once_ms(struct tclient *c) {
        uint64_t t0 = h_now_ms();
        json_t *r = tc_ok(c, "status", NULL);
        json_decref(r);
        return h_now_ms() - t0;
}

/* The quickest of up to 3 `status` round trips (stopping at the first within PROMPT_MS): a loop
 * stalled by a client is slow every time, a loaded host (CI beside other work) only once. */
static uint64_t status_ms(struct tclient *c) {
        uint64_t best = UINT64_MAX;
        for (int i = 0; i < 3 && best > PROMPT_MS; i++) {
                uint64_t ms = status_once_ms(c);
                best = ms < best ? ms : best;
        }
        return best;
}

/* ---- roles -------------------------------------------------------------------------------- */

static int capset_setgid(void) {
        struct __user_cap_header_struct hdr = { .version = _LINUX_CAPABILITY_VERSION_3 };
        struct __user_cap_data_struct data[2] = { 0 };
        data[0].effective = data[0].permitted = 1u << CAP_SETGID;
        return (int) syscall(SYS_capset, &hdr, data);
}

/* A uid-nobody client without the group connects while impastod is stopped, then gains the
 * operator group (so /proc/<its pid>/status lists it when impastod accepts), and reports the
 * role it got (exit 1: operator) and whether jobs.retry was refused (exit 2 if not). */
static void part_roles(struct harness *h) {
        start(h, NULL);
        gid_t op = OP_GID;
        CHECK_INT_EQ(role_as(h, NOBODY, &op, 1), 1);          /* a member: operator */
        CHECK_INT_EQ(role_as(h, NOBODY, NULL, 0), 0);         /* not a member: observer */
        CHECK_INT_EQ(role_as(h, 0, NULL, 0), 1);              /* root */

        int go[2], ready[2];
        if (pipe(go) < 0 || pipe(ready) < 0)
                exit(2);
        pid_t pid = fork();
        if (pid == 0) {
                prctl(PR_SET_KEEPCAPS, 1);
                become(NOBODY, NOBODY, NULL, 0);
                if (capset_setgid() < 0)
                        _exit(91);
                struct tclient c;
                if (tc_connect(&c, h->socket, 5000) < 0)
                        _exit(92);
                /* connected with no group; now the group, as /proc will show it */
                if (setgroups(1, &op) < 0)
                        _exit(93);
                char b = 1;
                (void) !write(ready[1], &b, 1);
                (void) !read(go[0], &b, 1);
                struct imp_proto_message m = { 0 };
                if (tc_read(&c, 10000, &m) < 0 || m.kind != IMP_PROTO_MSG_BANNER)
                        _exit(94);
                imp_proto_message_done(&m);
                if (c.role == IMP_PROTO_ROLE_OPERATOR)
                        _exit(1);
                enum imp_proto_errcode e = tc_err(&c, "jobs.retry", h_arg("job", "x"), NULL, 0);
                _exit(e == IMP_PROTO_E_PERMISSION_DENIED ? 0 : 2);
        }
        /* impastod stopped before the connection, resumed once the group is there */
        kill(h->pid, SIGSTOP);
        char b;
        CHECK(read(ready[0], &b, 1) == 1);
        kill(h->pid, SIGCONT);
        CHECK(write(go[1], &b, 1) == 1);
        int st = child_status(pid);
        CHECK_MSG(st == 0, "a client whose /proc status gained the operator group after connect(): %s (exit %d)",
                  st == 1 ? "got the operator role" : st == 2 ? "jobs.retry not refused" : "failed", st);
        stop(h);
}

/* ---- pidns -------------------------------------------------------------------------------- */

static void part_pidns(struct harness *h) {
        char plan[512];
        snprintf(plan, sizeof plan, "%s/secret-plan.cfg", h->dir);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [1000.0]; };\n");
        chmod(plan, 0600);              /* root's own: not readable by nobody */
        h->new_pid_namespace = true;
        start(h, NULL);
        gid_t op = OP_GID;
        CHECK_MSG(role_as(h, NOBODY, &op, 1) == 1, "an operator-group member seen as pid 0 is not an operator");
        pid_t pid = fork();
        if (pid == 0) {
                become(NOBODY, NOBODY, NULL, 0);
                struct tclient c;
                if (tc_open(&c, h->socket, false) < 0)
                        _exit(99);
                char msg[512] = "";
                enum imp_proto_errcode e = tc_err(&c, "plan.validate", h_arg("plan", plan), msg, sizeof msg);
                if (e == IMP_PROTO_E_NONE)
                        _exit(1);       /* read for a client that cannot read it */
                _exit(e == IMP_PROTO_E_NOT_FOUND && strstr(msg, "not readable by the client") ? 0 : 2);
        }
        int st = child_status(pid);
        CHECK_MSG(st == 0, "plan.validate of a plan the peer (pid 0) cannot read: %s (exit %d)",
                  st == 1 ? "validated" : "wrong error", st);
        /* (PID 1 of its namespace: SIGTERM from outside is not guaranteed to reach it) */
        h_kill(h, SIGKILL);
}

/* ---- slowreader --------------------------------------------------------------------------- */

#define SLOW_SEND_MAX (16u << 20)       /* bytes of requests offered; the replies are ~6× */
/* growth allowed: 1 MiB soft + 4 MiB queue + buffers; under ASan, whose quarantine keeps
 * freed memory resident (256 MiB by default), what was taken is the check that counts */
#if defined(__SANITIZE_ADDRESS__)
#define SLOW_RSS_BOUND_KIB (160u << 10)
#else
#define SLOW_RSS_BOUND_KIB (24u << 10)
#endif

static void part_slowreader(struct harness *h) {
        start(h, NULL);
        struct tclient c, other;
        CHECK_OK(tc_open(&c, h->socket, false));
        CHECK_OK(tc_open(&other, h->socket, false));
        uint64_t rss0 = rss_kib(h->pid);
        static const char req[] = "{\"id\":1,\"cmd\":\"status\"}\n";
        static char block[64 * 1024];
        size_t per = sizeof req - 1, nreq = sizeof block / per;
        for (size_t i = 0; i < nreq; i++)
                memcpy(block + i * per, req, per);
        size_t sent = 0;
        uint64_t last_progress = h_now_ms();
        while (sent < SLOW_SEND_MAX && h_now_ms() - last_progress < 1500) {
                ssize_t n = send(c.fd, block, nreq * per, MSG_DONTWAIT | MSG_NOSIGNAL);
                if (n > 0) {
                        sent += (size_t) n;
                        last_progress = h_now_ms();
                } else if (n < 0 && errno != EAGAIN)
                        break;          /* closed by the daemon: also bounded */
                else
                        usleep(20000);
        }
        usleep(500000);
        uint64_t rss1 = rss_kib(h->pid);
        fprintf(stderr, "slow reader: %zu bytes of requests taken, impastod RSS %llu -> %llu KiB\n", sent,
                (unsigned long long) rss0, (unsigned long long) rss1);
        CHECK_MSG(rss1 < rss0 + SLOW_RSS_BOUND_KIB, "impastod grew by %llu KiB for a client that does not read",
                  (unsigned long long) (rss1 - rss0));
        CHECK_MSG(sent < SLOW_SEND_MAX, "impastod took all %u bytes of requests from a client that reads nothing",
                  SLOW_SEND_MAX);
        CHECK_LE(status_ms(&other), PROMPT_MS);
        tc_close(&c);
        CHECK_LE(status_ms(&other), PROMPT_MS);
        tc_close(&other);
        stop(h);
}

/* ---- slots --------------------------------------------------------------------------------- */

/* A child as uid that opens n connections and reports how many got a banner (exit code),
 * then holds them until `hold` is closed. */
static pid_t hold_connections(const struct harness *h, uid_t uid, int n, const int hold[2], int *ret_report) {
        int rep[2];
        if (pipe(rep) < 0)
                exit(2);
        pid_t pid = fork();
        if (pid == 0) {
                close(hold[1]);
                become(uid, uid, NULL, 0);
                static struct tclient cs[32];
                unsigned char got = 0;
                for (int i = 0; i < n && i < 32; i++)
                        got += tc_open(&cs[i], h->socket, true) == 0;  /* subscribed: not idle */
                (void) !write(rep[1], &got, 1);
                char b;
                (void) !read(hold[0], &b, 1);
                _exit(0);
        }
        close(rep[1]);
        unsigned char got = 0;
        if (read(rep[0], &got, 1) != 1)
                got = 255;
        close(rep[0]);
        *ret_report = got;
        return pid;
}

/* `impasto status` as uid: its exit code, standard error in err. */
static int cli_status_as(const struct harness *h, uid_t uid, char *err, size_t size) {
        char out[600];
        snprintf(out, sizeof out, "%s/cli-err.txt", h->dir);
        pid_t pid = fork();
        if (pid == 0) {
                int fd = open(out, O_WRONLY | O_CREAT | O_TRUNC, 0666);
                become(uid, uid, NULL, 0);
                if (fd >= 0)
                        dup2(fd, 2);
                execl(IMPASTO_BINARY_DIR "/cli/impasto", "impasto", "status", "--socket", h->socket, (char *) NULL);
                _exit(127);
        }
        int st = child_status(pid);
        FILE *f = fopen(out, "re");
        size_t n = f ? fread(err, 1, size - 1, f) : 0;
        err[n] = 0;
        if (f)
                fclose(f);
        return st;
}

static void part_slots(struct harness *h) {
        start(h, (const char *const[]) { "--max-clients", "12", "--reserved-slots", "4", "--max-clients-per-uid", "4",
                                          "--idle-timeout-s", "2", "--request-timeout-s", "2", NULL });
        int hold[2];
        if (pipe(hold) < 0)
                exit(2);
        int got1, got2;
        pid_t a = hold_connections(h, NOBODY, 5, hold, &got1);
        CHECK_MSG(got1 == 4, "uid %d opened %d of 5 connections; the per-uid limit is 4", NOBODY, got1);
        pid_t b = hold_connections(h, OTHER_UID, 4, hold, &got2);
        CHECK_INT_EQ(got2, 4);
        /* 8 observer connections = 12 - 4 kept for operators: a third observer uid is refused,
         * saying why, and the CLI says so */
        char err[2048];
        int st = cli_status_as(h, THIRD_UID, err, sizeof err);
        CHECK_MSG(st != 0, "impasto status as a third observer succeeded beyond the observers' slots");
        CHECK_STR_CONTAINS(err, "too many connections");
        CHECK_MSG(!strstr(err, "not a banner"), "the CLI misreports the refusal: %s", err);
        /* root still gets in */
        struct tclient root;
        CHECK_OK(tc_open(&root, h->socket, false));
        CHECK_LE(status_ms(&root), PROMPT_MS);

        /* idle: root's connection is closed after --idle-timeout-s 2 without requests */
        struct imp_proto_message m = { 0 };
        uint64_t t0 = h_now_ms();
        int r = tc_read(&root, 8000, &m);
        CHECK_MSG(r == -ECONNRESET, "an idle connection was not closed within 8 s (%s)", strerror(-r));
        CHECK_LE(h_now_ms() - t0, 6000);
        if (r == 0)
                imp_proto_message_done(&m);
        tc_close(&root);

        /* slowloris: one byte every 300 ms of a request that never ends */
        struct tclient slow;
        CHECK_OK(tc_open(&slow, h->socket, false));
        t0 = h_now_ms();
        bool closed = false;
        for (int i = 0; i < 40 && !closed; i++) {
                if (tc_send_raw(&slow, i == 0 ? "{" : " ", 1) < 0)
                        closed = true;
                struct pollfd pfd = { .fd = slow.fd, .events = POLLIN };
                if (poll(&pfd, 1, 300) > 0) {
                        char buf[4096];
                        closed = recv(slow.fd, buf, sizeof buf, MSG_DONTWAIT) == 0;
                }
        }
        CHECK_MSG(closed, "a request line trickled for 12 s was not cut (--request-timeout-s 2)");
        CHECK_LE(h_now_ms() - t0, 8000);
        tc_close(&slow);

        close(hold[1]);
        child_status(a);
        child_status(b);
        close(hold[0]);
        stop(h);
}

/* ---- devices ------------------------------------------------------------------------------- */

/* n pipelined `devices` on c; the replies read later. */
static void send_devices(struct tclient *c, int n) {
        for (int i = 0; i < n; i++) {
                char line[64];
                snprintf(line, sizeof line, "{\"id\":%d,\"cmd\":\"devices\"}\n", 1000 + i);
                CHECK_OK(tc_send_raw(c, line, strlen(line)));
        }
}

/* The n replies, in order, each a devices list naming the camera absent. */
static void read_devices(struct tclient *c, int n, unsigned timeout_ms) {
        for (int i = 0; i < n; i++) {
                struct imp_proto_message m = { 0 };
                int r = tc_read(c, timeout_ms, &m);
                CHECK_MSG(r == 0, "devices reply %d: %s", i, strerror(-r));
                if (r < 0)
                        return;
                CHECK(m.kind == IMP_PROTO_MSG_REPLY && m.ok && json_integer_value(m.id) == 1000 + i);
                const json_t *cam = json_array_get(json_object_get(m.result, "devices"), 0);
                CHECK_STR_EQ(json_string_value(json_object_get(cam, "class")), "camera");
                imp_proto_message_done(&m);
        }
}

static void part_devices(struct harness *h) {
        /* the camera at an address where nothing answers (loopback) */
        h_write(h->rigcfg, "rig = {\n  name = \"absent\";\n  calibration = \"rig.json\";\n"
                           "  cameras = ( { name = \"cam0\"; backend = \"aravis\"; address = \"127.0.0.9\"; } );\n};\n");
        start(h, (const char *const[]) { "--device-timeout-ms", "1500", "--device-probe-interval-s", "60", NULL });
        struct tclient root;
        CHECK_OK(tc_open(&root, h->socket, false));
        /* an observer pipelines 10: answered from what is known, never reopening */
        pid_t pid = fork();
        if (pid == 0) {
                become(NOBODY, NOBODY, NULL, 0);
                struct tclient c;
                if (tc_open(&c, h->socket, false) < 0)
                        _exit(99);
                send_devices(&c, 10);
                read_devices(&c, 10, 20000);
                _exit(test_failures_ ? 1 : 0);
        }
        usleep(100000);
        uint64_t ms = status_ms(&root);
        CHECK_MSG(ms <= PROMPT_MS, "root's status took %llu ms while an observer ran 10 devices", (unsigned long long) ms);
        CHECK_INT_EQ(child_status(pid), 0);
        /* an operator pipelines 10: one probe (1.5 s timeout) off the loop, the rest wait in order */
        struct tclient op;
        CHECK_OK(tc_open(&op, h->socket, false));
        send_devices(&op, 10);
        usleep(100000);
        ms = status_ms(&root);
        CHECK_MSG(ms <= PROMPT_MS, "root's status took %llu ms while an operator ran 10 devices", (unsigned long long) ms);
        uint64_t t0 = h_now_ms();
        read_devices(&op, 10, 20000);
        fprintf(stderr, "devices: status %llu ms; the operator's 10 devices in %llu ms\n", (unsigned long long) ms,
                (unsigned long long) (h_now_ms() - t0));
        /* the probe ran once: 10 more within the interval are answered at once */
        send_devices(&op, 10);
        t0 = h_now_ms();
        read_devices(&op, 10, 20000);
        CHECK_LE(h_now_ms() - t0, PROMPT_MS);
        tc_close(&op);
        tc_close(&root);
        stop(h);
}

/* ---- instance ------------------------------------------------------------------------------ */

static long long status_pid(const char *socket) {
        struct tclient c;
        if (tc_open(&c, socket, false) < 0)
                return -1;
        json_t *r = tc_ok(&c, "status", NULL);
        long long pid = json_integer_value(json_object_get(json_object_get(r, "daemon"), "pid"));
        json_decref(r);
        tc_close(&c);
        return pid;
}

static void part_instance(struct harness *h) {
        start(h, NULL);
        struct harness second = *h;
        char errfile[600];
        snprintf(errfile, sizeof errfile, "%s/second.err", h->dir);
        second.stderr_path = errfile;
        second.keep_socket = true;
        /* same state directory and socket */
        h_start(&second, NULL);
        int st = h_wait(&second, 10000);
        CHECK_MSG(st >= 0 && WIFEXITED(st) && WEXITSTATUS(st) == 1, "a second impastod on the same state: status %d",
                  st);
        char err[4096] = "";
        FILE *f = fopen(errfile, "re");
        if (f) {
                err[fread(err, 1, sizeof err - 1, f)] = 0;
                fclose(f);
        }
        CHECK_STR_CONTAINS(err, "refusing to start a second one");
        CHECK_INT_EQ(status_pid(h->socket), h->pid);
        /* same socket, another state directory */
        snprintf(second.state, sizeof second.state, "%.250s/state2", h->dir);
        h_start(&second, NULL);
        st = h_wait(&second, 10000);
        CHECK_MSG(st >= 0 && WIFEXITED(st) && WEXITSTATUS(st) == 1, "a second impastod on the same socket: status %d",
                  st);
        CHECK_INT_EQ(status_pid(h->socket), h->pid);
        struct stat sst;
        CHECK(stat(h->socket, &sst) == 0 && S_ISSOCK(sst.st_mode));
        stop(h);
        CHECK(stat(h->socket, &sst) < 0);       /* the first one removes its own socket */
        /* and the lock is free again once it is gone */
        start(h, NULL);
        CHECK_INT_EQ(status_pid(h->socket), h->pid);
        stop(h);
}

/* ---- verdict ------------------------------------------------------------------------------- */

static void write_job(const struct harness *h, const char *id, const char *copy_json) {
        char p[1024], copy[700];
        snprintf(copy, sizeof copy, "%s/outputs/%s", h->state, id);
        snprintf(p, sizeof p, "mkdir -p %s/jobs %s", h->state, copy);
        CHECK(system(p) == 0);
        if (copy_json) {
                snprintf(p, sizeof p, "%s/copy.json", copy);
                h_write(p, copy_json);
        }
        json_t *j = json_pack("{s:s, s:s, s:s, s:s, s:i, s:i, s:s, s:s, s:f}", "id", id, "capture", "/nonexistent",
                              "copy", copy, "state", "done", "attempts", 1, "max_attempts", 3, "session", id,
                              "queued", "2026-01-01T00:00:00Z", "progress", 1.0);
        snprintf(p, sizeof p, "%s/jobs/%s.json", h->state, id);
        struct imp_error e = { 0 };
        CHECK_OK(imp_json_save_atomic(p, j, &e));
        json_decref(j);
}

static void part_verdict(struct harness *h) {
        write_job(h, "20260101-000001-plain", "{\"stages\": {}}\n");
        write_job(h, "20260101-000002-good", "{\"quality\": {\"verdict\": \"degraded\", \"reasons\": [\"x\"]}}\n");
        start(h, (const char *const[]) { "--no-spawn-workers", NULL });
        struct tclient c;
        CHECK_OK(tc_open(&c, h->socket, false));
        json_t *r = tc_ok(&c, "jobs.list", NULL);
        json_t *list = json_object_get(r, "jobs");
        CHECK_INT_EQ(json_array_size(list), 2);
        for (size_t i = 0; i < json_array_size(list); i++) {
                const json_t *j = json_array_get(list, i);
                const char *id = json_string_value(json_object_get(j, "job"));
                const json_t *v = json_object_get(j, "verdict");
                if (strstr(id, "good"))
                        CHECK_STR_EQ(json_string_value(v), "degraded");
                else
                        CHECK_MSG(v == NULL, "a copy without quality.verdict shows one");
        }
        json_decref(r);
        r = tc_ok(&c, "jobs.show", h_arg("job", "20260101-000002-good"));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "verdict")), "degraded");
        json_decref(r);
        r = tc_ok(&c, "status", NULL);
        const json_t *last = json_object_get(json_object_get(r, "jobs"), "last_done");
        CHECK_STR_EQ(json_string_value(json_object_get(last, "verdict")), "degraded");
        json_decref(r);
        tc_close(&c);
        char cmd[1200], out[4096] = "";
        snprintf(cmd, sizeof cmd, "%s/cli/impasto jobs --socket %s", IMPASTO_BINARY_DIR, h->socket);
        FILE *p = popen(cmd, "r");
        if (p) {
                out[fread(out, 1, sizeof out - 1, p)] = 0;
                pclose(p);
        }
        CHECK_STR_CONTAINS(out, "VERDICT");
        CHECK_STR_CONTAINS(out, "degraded");
        stop(h);
}

int main(int argc, char **argv) {
        static const struct { const char *name; void (*fn)(struct harness *h); } parts[] = {
                { "roles", part_roles }, { "pidns", part_pidns }, { "slowreader", part_slowreader },
                { "slots", part_slots }, { "devices", part_devices }, { "instance", part_instance },
                { "verdict", part_verdict },
        };
        if (argc != 2) {
                fprintf(stderr, "usage: %s PART\n", argv[0]);
                return 2;
        }
        for (size_t i = 0; i < ARRAY_SIZE(parts); i++) {
                if (strcmp(argv[1], parts[i].name))
                        continue;
                struct harness h;
                h_setup(&h, PORT, N_LIGHTS);
                operator_group(&h);
                parts[i].fn(&h);
                if (h.pid > 0)
                        h_kill(&h, SIGKILL);
                h_teardown(&h);
                return TEST_DONE();
        }
        fprintf(stderr, "unknown part %s\n", argv[1]);
        return 2;
}
