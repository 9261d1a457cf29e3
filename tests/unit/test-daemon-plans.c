/* Plans named by impastod's clients cannot reach outside the plan directory and cannot stall
 * the event loop: a plan that @includes a file outside (a config with a syntax error, a FIFO,
 * a missing file), a plan that is a FIFO, and a symlink to a file outside are each refused
 * with an answer that says nothing of the other file (not its name, existence or content),
 * promptly, while `status` keeps being answered; a 149-byte plan expanding to ~1e11 frames is
 * refused before anything is allocated (the daemon's peak RSS stays under 200 MB, and it runs
 * with a 2 GiB address-space cap outside ASan, so the unfixed daemon fails instead of taking
 * the machine's memory). Runs in a private network namespace (unshare -n) in CI. */
#define _GNU_SOURCE 1
#include <sys/resource.h>
#include "test-daemon-harness.c"

#define PORT 15917
#define N_LIGHTS 4

/* plan.validate of `plan` answered within `ms`: the error code (E_NONE when valid), its
 * message in msg; -1 when no answer came in time. */
static int validate(struct tclient *c, const char *plan, unsigned ms, char *msg, size_t size) {
        long long id = ++c->next_id;
        json_t *req = json_pack("{s:I, s:s, s:{s:s}}", "id", (json_int_t) id, "cmd", "plan.validate", "args", "plan",
                                plan);
        char *line = imp_proto_dump_line(req);
        json_decref(req);
        int r = tc_send_raw(c, line, strlen(line));
        free(line);
        if (r < 0)
                return -1;
        for (;;) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, ms, &m) < 0)
                        return -1;
                if (m.kind == IMP_PROTO_MSG_REPLY && json_integer_value(m.id) == id) {
                        int code = m.ok ? IMP_PROTO_E_NONE : (int) m.error.code;
                        snprintf(msg, size, "%s", m.ok ? "" : m.error.message);
                        imp_proto_message_done(&m);
                        return code;
                }
                imp_proto_message_done(&m);
        }
}

static long vm_hwm_kb(pid_t pid) {
        char p[64], line[256];
        snprintf(p, sizeof p, "/proc/%d/status", (int) pid);
        FILE *f = fopen(p, "re");
        long kb = -1;
        while (f && fgets(line, sizeof line, f))
                if (!strncmp(line, "VmHWM:", 6))
                        kb = atol(line + 6);
        if (f)
                fclose(f);
        return kb;
}

/* The message after "PATH: " or "PATH:LINE: ", so that answers about two paths can be compared. */
static const char *after_path(const char *msg) {
        const char *s = strstr(msg, ".cfg:");
        s = s ? strchr(s, ' ') : NULL;
        return s ? s + 1 : msg;
}

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        const unsigned ms = (unsigned) (5000 * test_timeout_scale());
        char plans[512], outside[512], p[1024], q[1024];
        snprintf(plans, sizeof plans, "%s/plans", h.dir);
        snprintf(outside, sizeof outside, "%s/outside", h.dir);
        CHECK_OK(mkdir(plans, 0755));
        CHECK_OK(mkdir(outside, 0755));
        snprintf(p, sizeof p, "%s/secret.cfg", outside);
        h_write(p, "root_password = hunter2 {\n");
        snprintf(p, sizeof p, "%s/fifo.cfg", outside);
        CHECK_OK(mkfifo(p, 0644));
        snprintf(p, sizeof p, "%s/fifo-plan.cfg", plans);
        CHECK_OK(mkfifo(p, 0644));
        static const char *const incs[] = { "secret", "fifo", "missing" };
        for (size_t i = 0; i < ARRAY_SIZE(incs); i++) {
                char text[512];
                snprintf(p, sizeof p, "%s/inc-%s.cfg", plans, incs[i]);
                snprintf(text, sizeof text, "@include \"../outside/%s.cfg\"\ndome = { exposures_us = [1000.0]; };\n",
                         incs[i]);
                h_write(p, text);
        }
        snprintf(p, sizeof p, "%s/link-secret.cfg", plans);
        CHECK_OK(symlink("../outside/secret.cfg", p));
        snprintf(p, sizeof p, "%s/link-missing.cfg", plans);
        CHECK_OK(symlink("../outside/missing.cfg", p));
        snprintf(p, sizeof p, "%s/bomb.cfg", plans);
        h_write(p, "tiles=100000;dome={lights=\"all\";repeat=10000;\n"
                   "exposures_us=[1.0,2.0,3.0,4.0,5.0,6.0,7.0,8.0];};\n");
        snprintf(p, sizeof p, "%s/good.cfg", plans);
        h_write(p, "dome = { lights = \"all\"; exposures_us = [1000.0]; };\n");

#if !defined(__SANITIZE_ADDRESS__)
        struct rlimit old, cap = { 2ULL << 30, 2ULL << 30 };
        getrlimit(RLIMIT_AS, &old);
        (void) setrlimit(RLIMIT_AS, &cap);
#endif
        h_start(&h, (const char *const[]) { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", "--plan-dir", plans,
                                            NULL });
#if !defined(__SANITIZE_ADDRESS__)
        (void) setrlimit(RLIMIT_AS, &old);
#endif
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, false));
        char msg[1024], msg2[1024];

        snprintf(p, sizeof p, "%s/good.cfg", plans);
        CHECK_INT_EQ(validate(&c, p, ms, msg, sizeof msg), IMP_PROTO_E_NONE);

        for (size_t i = 0; i < ARRAY_SIZE(incs); i++) {
                snprintf(p, sizeof p, "%s/inc-%s.cfg", plans, incs[i]);
                int code = validate(&c, p, ms, msg, sizeof msg);
                CHECK_MSG(code == IMP_PROTO_E_INVALID_PLAN, "inc-%s: %d (%s)", incs[i], code, msg);
                CHECK_STR_CONTAINS(msg, "@include");
                const char *rest = after_path(msg);   /* the plan's own name contains incs[i] */
                CHECK_MSG(!strstr(msg, "outside") && !strstr(msg, "hunter2") && !strstr(rest, incs[i]),
                          "inc-%s: the answer tells of the included file: %s", incs[i], msg);
                json_t *st = code >= 0 ? tc_ok(&c, "status", NULL) : NULL;
                CHECK_MSG(st != NULL, "inc-%s: status not answered", incs[i]);
                json_decref(st);
                if (code < 0)
                        goto out;       /* the loop is blocked: nothing more to learn */
        }
        snprintf(p, sizeof p, "%s/fifo-plan.cfg", plans);
        int code = validate(&c, p, ms, msg, sizeof msg);
        CHECK_MSG(code == IMP_PROTO_E_NOT_FOUND, "fifo plan: %d (%s)", code, msg);
        if (code < 0)
                goto out;

        /* A symlink to an existing file outside and one to a missing file get the same answer. */
        snprintf(p, sizeof p, "%s/link-secret.cfg", plans);
        snprintf(q, sizeof q, "%s/link-missing.cfg", plans);
        int c1 = validate(&c, p, ms, msg, sizeof msg), c2 = validate(&c, q, ms, msg2, sizeof msg2);
        CHECK_INT_EQ(c1, IMP_PROTO_E_NOT_FOUND);
        CHECK_INT_EQ(c1, c2);
        CHECK_STR_EQ(after_path(msg), after_path(msg2));
        snprintf(p, sizeof p, "%s/no-such-dir/x.cfg", outside);
        c2 = validate(&c, p, ms, msg2, sizeof msg2);
        CHECK_INT_EQ(c1, c2);
        CHECK_STR_EQ(after_path(msg), after_path(msg2));

        /* The memory bomb. */
        snprintf(p, sizeof p, "%s/bomb.cfg", plans);
        uint64_t t0 = h_now_ms();
        code = validate(&c, p, ms, msg, sizeof msg);
        uint64_t took = h_now_ms() - t0;
        CHECK_MSG(code == IMP_PROTO_E_INVALID_PLAN, "bomb: %d (%s)", code, msg);
        CHECK_STR_CONTAINS(msg, "dome (lights × exposures_us × repeat)");
        long hwm = vm_hwm_kb(h.pid);
        fprintf(stderr, "bomb answered in %llu ms; impastod peak RSS %ld kB\n", (unsigned long long) took, hwm);
        CHECK_MSG(hwm > 0 && hwm < 200 * 1024, "impastod peak RSS %ld kB", hwm);
        json_t *st = tc_ok(&c, "status", NULL);
        CHECK(st != NULL);
        json_decref(st);
out:
        tc_close(&c);
        h_kill(&h, SIGTERM);
        CHECK(h_wait(&h, 10000) == 0);
        h_teardown(&h);
        return TEST_DONE();
}
