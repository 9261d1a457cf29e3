/* impastod and a damaged state directory: a session whose session.json is damaged does not
 * vanish (it is listed, paused and marked damaged, and not resumed by itself), and
 * session.resume rebuilds it from its capture set's manifest and plan; a frame file the
 * crash left unrecorded is moved into quarantine/ on resume (reported as a fault event),
 * never deleted; the resumed set equals an uninterrupted one frame for frame. Modbus port
 * 15918; run in a private network namespace (unshare -n). */
#define _GNU_SOURCE 1
#include "test-daemon-harness.c"

#define PORT 15918
#define N_LIGHTS 4

static bool listed_damaged(struct tclient *c, const char *id) {
        json_t *r = tc_ok(c, "session.list", NULL);
        bool found = false;
        size_t i;
        json_t *s;
        json_array_foreach(json_object_get(r, "sessions"), i, s)
                found |= !strcmp(json_string_value(json_object_get(s, "session")), id) &&
                         json_string_value(json_object_get(s, "damaged")) != NULL;
        json_decref(r);
        return found;
}

static long long file_size(const char *p) {
        struct stat st;
        return stat(p, &st) == 0 ? (long long) st.st_size : -1;
}

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        char plan[512], p[1200], q[1200];
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [1000.0, 2000.0]; repeat = 3; };\n");
        const size_t frames = N_LIGHTS * 2 * 3;
        const char *const opts[] = { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", NULL };
        h_start(&h, opts);
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        char id[128], setdir[1024];
        tc_start_session(&c, plan, "recover", id, setdir);
        CHECK(id[0] != 0);
        while (c.n_frames < 3 && c.fd >= 0) {
                struct imp_proto_message m = { 0 };
                if (tc_read(&c, 20000, &m) < 0)
                        break;
                imp_proto_message_done(&m);
        }
        tc_close(&c);
        h_kill(&h, SIGTERM);
        CHECK(h_wait(&h, 10000) == 0);

        /* What a crash can leave: session.json cut short, a frame stored but not recorded. */
        snprintf(p, sizeof p, "%s/session.json", setdir);
        long long js = file_size(p);
        CHECK(js > 20);
        CHECK_OK(truncate(p, js / 2));
        snprintf(p, sizeof p, "%s/manifest.jsonl", setdir);
        FILE *f = fopen(p, "re");
        size_t stored = 0;
        int ch;
        while (f && (ch = fgetc(f)) != EOF)
                stored += ch == '\n';
        if (f)
                fclose(f);
        CHECK(stored >= 3 && stored < frames);
        snprintf(p, sizeof p, "%s/frames/000000.tiff", setdir);
        snprintf(q, sizeof q, "%s/frames/%06zu.tiff", setdir, stored);
        CHECK_OK(link(p, q));
        long long orphan_size = file_size(q);

        h_start(&h, opts);
        CHECK_OK(tc_open(&c, h.socket, true));
        if (c.fd < 0)
                goto out;
        CHECK_MSG(listed_damaged(&c, id), "session %s is not listed as damaged", id);
        json_t *r = tc_ok(&c, "session.show", h_arg("session", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "paused");
        CHECK(json_string_value(json_object_get(r, "damaged")) != NULL);
        CHECK(!json_is_true(json_object_get(r, "interrupted")));   /* never resumed by itself */
        json_decref(r);

        json_decref(tc_ok(&c, "session.resume", h_arg("session", id)));
        CHECK_OK(tc_wait_done(&c, 1, 60000));
        CHECK_STR_EQ(c.done_state, "completed");
        CHECK_INT_GE(c.n_faults, 1);   /* the quarantined frame, reported */
        snprintf(p, sizeof p, "%s/quarantine/%06zu.tiff", setdir, stored);
        CHECK_INT_EQ(file_size(p), orphan_size);
        CHECK(!listed_damaged(&c, id));
        /* session.json is whole again */
        snprintf(p, sizeof p, "%s/session.json", setdir);
        json_t *sj = NULL;
        struct imp_error e = { 0 };
        CHECK_OK(imp_json_load(p, &sj, &e));
        CHECK_STR_EQ(json_string_value(json_object_get(sj, "state")), "completed");
        json_decref(sj);
        h_check_completed(&h, &c, id, setdir, plan, frames);
out:
        if (h.pid > 0) {
                h_kill(&h, SIGTERM);
                h_wait(&h, 10000);
        }
        h_teardown(&h);
        return TEST_DONE();
}
