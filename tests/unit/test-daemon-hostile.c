/* impastod under hostile clients: 1,000 malformed messages (random bytes, broken JSON, deep
 * nesting, lines over 64 KiB, wrong types, unknown commands and arguments) get error
 * replies and leave the daemon serving; 50 clients subscribed at once all receive every
 * event of a small session with no gap in seq; a connection beyond the limit gets busy. */
#define _GNU_SOURCE 1
#include "test-daemon-harness.c"

#define PORT 15853
#define N_LIGHTS 4
#define N_HOSTILE 1000
#define N_SUBSCRIBERS 50

static char *hostile_line(unsigned i) {
        static const char *const fixed[] = {
                "{", "}", "[]", "null", "42", "\"x\"", "{\"id\":1}", "{\"cmd\":\"status\"}",
                "{\"id\":1,\"cmd\":5}", "{\"id\":{},\"cmd\":\"status\"}", "{\"id\":1,\"cmd\":\"nope\"}",
                "{\"id\":1,\"cmd\":\"status\",\"args\":[]}", "{\"id\":1,\"cmd\":\"status\",\"extra\":1}",
                "{\"id\":1,\"cmd\":\"session.start\",\"args\":{\"plan\":5}}",
                "{\"id\":1,\"cmd\":\"session.start\",\"args\":{\"plan\":\"/etc/passwd\",\"name\":\"../x\"}}",
                "{\"id\":1,\"cmd\":\"session.show\",\"args\":{}}",
                "{\"id\":1,\"cmd\":\"session.abort\",\"args\":{\"session\":\"no-such\"}}",
                "{\"id\":1,\"cmd\":\"jobs.retry\",\"args\":{\"job\":\"..\"}}",
                "{\"id\":1,\"cmd\":\"session.list\",\"args\":{\"limit\":0}}",
                "{\"id\":1,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"bogus\"]}}",
                "{\"id\":1,\"cmd\":\"plan.validate\",\"args\":{\"plan\":\"/etc/passwd\"}}",
                "{\"id\":1,\"cmd\":\"plan.estimate\",\"args\":{\"plan\":\"/dev/null\"}}",
                "{\"id\":1e400,\"cmd\":\"status\"}", "{\"id\":1,\"id\":2,\"cmd\":\"status\"}",
                "{\"id\":1,\"cmd\":\"st\\u0000atus\"}", "\xff\xfe\xfd", "{\"id\":1,\"cmd\":\"status\"",
        };
        size_t nf = ARRAY_SIZE(fixed);
        char *s;
        if (i % 4 == 0 && i / 4 < nf)
                return strdup(fixed[i / 4]);
        switch (i % 5) {
        case 0: {                       /* random bytes without newline */
                size_t n = 1 + (size_t) (rand() % 300);
                s = malloc(n + 1);
                for (size_t k = 0; k < n; k++) {
                        s[k] = (char) (rand() % 256);
                        if (s[k] == '\n' || s[k] == 0)
                                s[k] = 'x';
                }
                s[n] = 0;
                return s;
        }
        case 1: {                       /* deep nesting */
                size_t depth = 33 + (size_t) (rand() % 2000);
                s = malloc(2 * depth + 1);
                memset(s, '[', depth);
                memset(s + depth, ']', depth);
                s[2 * depth] = 0;
                return s;
        }
        case 2: {                       /* over 64 KiB */
                size_t n = IMP_PROTO_REQUEST_MAX + 1 + (size_t) (rand() % 10000);
                s = malloc(n + 1);
                memset(s, 'a', n);
                s[0] = '{';
                s[n] = 0;
                return s;
        }
        case 3:                         /* a valid shape with a wrong-typed argument */
                if (asprintf(&s, "{\"id\":%u,\"cmd\":\"session.pause\",\"args\":{\"session\":%d}}", i, rand()) < 0)
                        return NULL;
                return s;
        default:
                return strdup(fixed[(size_t) rand() % nf]);
        }
}

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        srand(7);
        char plan[512];
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [1000.0, 2000.0]; };\n");
        const unsigned frames = N_LIGHTS * 2;
        h_start(&h, (const char *const[]) { "--worker-cmd", "/bin/true", "--min-free-bytes", "0",
                                            "--max-clients", "60", NULL });

        /* Hostile messages on one connection, each answered with an error. */
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, false));
        unsigned errors = 0;
        for (unsigned i = 0; i < N_HOSTILE && c.fd >= 0; i++) {
                char *line = hostile_line(i);
                if (!line)
                        break;
                int r = tc_send_raw(&c, line, strlen(line));
                free(line);
                if (r == 0)
                        r = tc_send_raw(&c, "\n", 1);
                if (r < 0) {
                        CHECK_MSG(0, "message %u: send: %s", i, strerror(-r));
                        break;
                }
                struct imp_proto_message m = { 0 };
                r = tc_read(&c, 10000, &m);
                if (r < 0) {
                        CHECK_MSG(0, "message %u: no reply (%s)", i, strerror(-r));
                        break;
                }
                errors += m.kind == IMP_PROTO_MSG_REPLY && !m.ok;
                imp_proto_message_done(&m);
        }
        CHECK_INT_GE(errors, N_HOSTILE - 10);   /* a few fixed lines are valid requests */
        json_t *r = tc_ok(&c, "status", NULL);
        CHECK(r != NULL);
        json_decref(r);
        /* A client that vanishes mid-line. */
        struct tclient q;
        CHECK_OK(tc_open(&q, h.socket, false));
        tc_send_raw(&q, "{\"id\":1,\"cmd\":\"sta", 18);
        tc_close(&q);

        /* 50 subscribers, one session. */
        static struct tclient subs[N_SUBSCRIBERS];
        for (int i = 0; i < N_SUBSCRIBERS; i++)
                CHECK_OK(tc_open(&subs[i], h.socket, true));
        r = tc_ok(&c, "session.start", json_pack("{s:s, s:s}", "plan", plan, "name", "many"));
        CHECK(r != NULL);
        json_decref(r);
        unsigned complete = 0;
        for (int i = 0; i < N_SUBSCRIBERS; i++) {
                if (subs[i].fd < 0)
                        continue;
                int k = tc_wait_done(&subs[i], 1, 30000);
                CHECK_MSG(k == 0, "subscriber %d: %s", i, strerror(-k));
                CHECK_INT_EQ(subs[i].n_frames, frames);
                CHECK(!subs[i].seq_gap);
                CHECK_STR_EQ(subs[i].done_state, "completed");
                complete += subs[i].n_frames == frames && !subs[i].seq_gap;
        }
        CHECK_INT_EQ(complete, N_SUBSCRIBERS);

        /* 52 connections are open (c, 50 subscribers, 1 closed): fill to the limit, then busy. */
        static struct tclient more[10];
        int opened = 0;
        for (; opened < 9; opened++)
                CHECK_OK(tc_open(&more[opened], h.socket, false));
        struct tclient over;
        CHECK_OK(tc_connect(&over, h.socket, 5000));
        struct imp_proto_message m = { 0 };
        if (tc_read(&over, 5000, &m) == 0) {
                CHECK(m.kind == IMP_PROTO_MSG_REPLY && !m.ok && m.error.code == IMP_PROTO_E_BUSY);
                imp_proto_message_done(&m);
        } else
                CHECK_MSG(0, "no busy line beyond the connection limit");
        tc_close(&over);

        r = tc_ok(&c, "status", NULL);
        CHECK(r != NULL);
        json_decref(r);
        for (int i = 0; i < N_SUBSCRIBERS; i++)
                tc_close(&subs[i]);
        for (int i = 0; i < opened; i++)
                tc_close(&more[i]);
        tc_close(&c);
        h_kill(&h, SIGTERM);
        int st = h_wait(&h, 10000);
        CHECK_MSG(st >= 0 && WIFEXITED(st) && WEXITSTATUS(st) == 0, "impastod exit status %d", st);
        if (h.pid > 0)
                h_kill(&h, SIGKILL);
        h_teardown(&h);
        return TEST_DONE();
}
