/* impastod killed with SIGKILL at ≥ 20 seeded random points of a capture (after 0–2 frame
 * events plus 0–30 ms, so kills land while devices are set up, between grab and store, in
 * the middle of the crash-safe write and during restarts), restarted with --resume each
 * time. At the end the capture set must equal an uninterrupted one frame for frame: the
 * plan's records in order, no duplicate or missing seq, every frame's pixels exactly what
 * the emulator produced for the light and exposure the record claims. */
#include "test-daemon-harness.c"

#define PORT 15852
/* 56 frames: room for MIN_KILLS kills with the store writer's pipelined capture, which
 * completes more frames between a restart and the next kill than a serial one did. */
#define N_LIGHTS 12
#define MIN_KILLS 20

int main(int argc, char **argv) {
        /* "repeat" (test-daemon-kill-repeat, tests/daemon-stream.cmake): a plan of streamed runs
         * of 6 frames, so that kills land inside runs, on port 15901. */
        bool repeat = argc > 1 && !strcmp(argv[1], "repeat");
        struct harness h;
        h_setup(&h, repeat ? 15901 : PORT, N_LIGHTS);
        char plan[512];
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        h_write(plan, repeat ? "dome = { lights = [0, 1, 2, 3]; exposures_us = [1000.0, 2000.0]; repeat = 6; };\n"
                               "dark = { count = 4; };\n"
                             : "dome = { lights = \"all\"; exposures_us = [1000.0, 1500.0, 2000.0, 2500.0]; };\n"
                               "dark = { count = 2; };\n");
        const size_t frames = repeat ? 4 * 2 * 6 + 4 * 2 : N_LIGHTS * 4 + 2 * 4;
        const char *const opts[] = { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", "--resume",
                                     "--device-timeout-ms", "400", NULL };
        unsigned seed = 20250301;
        const char *env = getenv("IMPASTO_TEST_SEED");
        if (env)
                seed = (unsigned) strtoul(env, NULL, 10);
        srand(seed);
        fprintf(stderr, "seed %u\n", seed);

        uint64_t t0 = h_now_ms();
        h_start(&h, opts);
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        char id[128], setdir[1024];
        tc_start_session(&c, plan, "kill", id, setdir);
        json_t *r;
        unsigned kills = 0;
        uint64_t deadline = h_deadline_ms(240000);   /* a hang guard, not a speed figure: ~70 s alone */
        bool done = false;
        while (!done && id[0] && h_now_ms() < deadline) {
                /* Let 0–2 frames pass (or the session end), then kill at a random instant. */
                unsigned wait_frames = kills < MIN_KILLS ? (unsigned) (rand() % 3) : 1000;
                unsigned start = c.n_frames;
                while (c.n_frames < start + wait_frames && !c.n_done) {
                        struct imp_proto_message m = { 0 };
                        int k = tc_read(&c, 2500, &m);   /* a stalled stream: kill anyway */
                        if (k < 0)
                                break;
                        imp_proto_message_done(&m);
                }
                if (c.n_done) {
                        CHECK_STR_EQ(c.done_state, "completed");
                        done = true;
                        break;
                }
                usleep((useconds_t) (rand() % 30000));
                h_kill(&h, SIGKILL);
                kills++;
                if (getenv("IMPASTO_TEST_VERBOSE"))
                        fprintf(stderr, "kill %u at %llu ms, %u frame events\n", kills,
                                (unsigned long long) (h_now_ms() - t0), c.n_frames);
                tc_close(&c);
                h_start(&h, opts);
                if (tc_open(&c, h.socket, true) < 0) {
                        CHECK_MSG(0, "impastod did not come back after kill %u", kills);
                        break;
                }
                /* It may have completed between the restart and the subscription. */
                r = tc_ok(&c, "session.show", h_arg("session", id));
                const char *st = json_string_value(json_object_get(r, "state"));
                if (st && !strcmp(st, "completed"))
                        done = true;
                else if (st && !strcmp(st, "paused")) {
                        /* Interrupted before --resume got to it (or a fault): resume by hand. */
                        struct imp_proto_message m = { 0 };
                        if (tc_call(&c, "session.resume", h_arg("session", id), &m) == 0)
                                imp_proto_message_done(&m);
                }
                json_decref(r);
        }
        fprintf(stderr, "%u kills\n", kills);
        CHECK_INT_GE(kills, MIN_KILLS);
        CHECK(done);
        h_check_completed(&h, &c, id, setdir, plan, frames);
        if (h.pid > 0)
                h_kill(&h, SIGKILL);
        h_teardown(&h);
        return TEST_DONE();
}
