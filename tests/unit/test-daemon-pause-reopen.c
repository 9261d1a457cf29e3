/* A camera whose fault paused a session is closed by impastod, so that `session.resume`
 * opens it afresh (daemon/session.c step_failed → rigcfg_drop_camera). The emulated GigE
 * camera stalls once while the daemon waits for a frame: its thread blocks (no frame, no
 * answer to GVCP) past the frame timeout and past the heartbeat, so the camera forgets its
 * controller and its stream. With one attempt per step the session pauses at that frame
 * with a device fault; after the stall the resume must capture the rest on a new handle,
 * and the set must equal an uninterrupted one frame for frame (h_verify_set: the emulator's
 * pixel formula, every byte). On the handle the fault left, every frame of the resume timed
 * out and the session paused again. */
#include <stdatomic.h>
#include "test-daemon-harness.c"

#define PORT 15904
#define N_LIGHTS 12
#define STALL_US 4000000        /* past the 400 ms frame timeout and the GVCP heartbeat */

static atomic_int stall_armed;
static atomic_int stalls;

/* The default fill, blocking the camera's thread once when armed. */
static int stall_fill(void *userdata, const struct imp_emu_camera_state *st, void *buf, int width, int height,
                      int bytes_per_pixel) {
        if (atomic_exchange(&stall_armed, 0)) {
                atomic_fetch_add(&stalls, 1);
                usleep(STALL_US);
        }
        return imp_emu_fill_default(userdata, st, buf, width, height, bytes_per_pixel);
}

/* session.show's state and frames. */
static void show(struct tclient *c, const char *id, char *state, size_t size, size_t *frames) {
        json_t *r = tc_ok(c, "session.show", h_arg("session", id));
        snprintf(state, size, "%s", json_string_value(json_object_get(r, "state")) ?: "");
        *frames = (size_t) json_integer_value(json_object_get(r, "frames"));
        json_decref(r);
}

/* Reads events until session id is in `want` (false at once when it is in `not`, or when
 * timeout_ms passes). */
static bool wait_state(struct tclient *c, const char *id, const char *want, const char *not, unsigned timeout_ms) {
        uint64_t end = h_deadline_ms(timeout_ms);
        while (h_now_ms() < end) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, 200, &m) == 0)
                        imp_proto_message_done(&m);
                char st[32];
                size_t n;
                show(c, id, st, sizeof st, &n);
                if (!strcmp(st, want))
                        return true;
                if (not && !strcmp(st, not))
                        return false;
        }
        return false;
}

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        imp_emu_gige_free(h.gige);
        h.gige = NULL;
        CHECK_OK(imp_emu_gige_new("127.0.0.1", "IMP-DAEMON", h.rig, stall_fill, NULL, &h.gige));
        char plan[512];
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        /* one frame per light at a short exposure: the daemon triggers each and waits for it */
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [2000.0]; };\n");
        const char *const opts[] = { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", "--retries", "1",
                                     "--device-timeout-ms", "400", NULL };
        h_start(&h, opts);
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        char id[128], setdir[1024];
        tc_start_session(&c, plan, "pause-reopen", id, setdir);
        CHECK(id[0] != 0);
        tc_wait_frames(&c, 3, 10000);
        CHECK_MSG(c.n_frames >= 3 && !c.n_done, "%u frames before the stall", c.n_frames);
        atomic_store(&stall_armed, 1);
        /* One attempt per step: the first timed-out frame pauses the session. */
        CHECK_MSG(wait_state(&c, id, "paused", NULL, 60000), "the session did not pause when its camera stalled");
        CHECK_INT_EQ(atomic_load(&stalls), 1);
        CHECK_INT_GE(c.n_faults, 1);
        char st[32];
        size_t kept = 0;
        show(&c, id, st, sizeof st, &kept);
        CHECK(kept >= 3 && kept < N_LIGHTS);
        CHECK_INT_EQ(h_verify_set(setdir, plan, false), kept);
        usleep(STALL_US + 1000000);     /* the camera is back (it never left the network) */
        fprintf(stderr, "paused after %zu frames; resuming\n", kept);
        json_decref(tc_ok(&c, "session.resume", h_arg("session", id)));
        CHECK_MSG(wait_state(&c, id, "completed", "paused", 60000),
                  "the resume did not complete the session (on the handle the fault left, it pauses again)");
        CHECK_INT_EQ(atomic_load(&stalls), 1);
        h_check_completed(&h, &c, id, setdir, plan, N_LIGHTS);
        h_teardown(&h);
        return TEST_DONE();
}
