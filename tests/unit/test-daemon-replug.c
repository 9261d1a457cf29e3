/* A GigE camera unplugged in the middle of a capture and plugged back: impastod retries the
 * step, pauses the session with a device fault once its attempts are spent (nothing stored
 * meanwhile is lost), and after the camera is back, `session.resume` reopens it and the
 * set completes equal to an uninterrupted one frame for frame. Before the fix the driver
 * had released its stream (-ENODEV after the timed-out grab) while the daemon kept the
 * handle: every later trigger answered -ENOTCONN, through retries and resumes, for ever.
 * Unplugged while streaming a run of repeats and while triggering a sweep; then a camera
 * that stalls (its thread busy for 6 s: no frame and no answer to GVCP, as a loaded host
 * made it under ASan) and comes back by itself — the session must complete, resuming once
 * if it paused. Only the stall reproduced the old bug (the others took paths that already
 * reopened); it fails without the fix. While the triggered sweep's camera is away, another
 * camera (another serial) at the address must be refused, not used: frames of two cameras
 * never mix in one set. */
#include <stdatomic.h>
#include "test-daemon-harness.c"

#define PORT 15902
#define N_LIGHTS 24

/* Reads events until session `id` is in `state` (checked with session.show every 200 ms). */
static bool wait_state(struct tclient *c, const char *id, const char *state, unsigned timeout_ms) {
        uint64_t end = h_deadline_ms(timeout_ms);
        while (h_now_ms() < end) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, 200, &m) == 0)
                        imp_proto_message_done(&m);
                json_t *r = tc_ok(c, "session.show", h_arg("session", id));
                const char *st = json_string_value(json_object_get(r, "state"));
                bool ok = st && !strcmp(st, state);
                json_decref(r);
                if (ok)
                        return true;
        }
        return false;
}

/* A fill that blocks the fake camera's thread (frames and GVCP) once, when armed. */
static atomic_int stall_armed;

static int stall_fill(void *userdata, const struct imp_emu_camera_state *st, void *buf, int width, int height,
                      int bytes_per_pixel) {
        if (atomic_exchange(&stall_armed, 0))
                usleep(6000000);
        return imp_emu_fill_default(userdata, st, buf, width, height, bytes_per_pixel);
}

static bool resume(struct tclient *c, const char *id) {
        struct imp_proto_message m = { 0 };
        /* A resume may be refused while the camera is still being found: try a few times. */
        for (int k = 0; k < 10; k++) {
                bool ok = false;
                if (tc_call(c, "session.resume", h_arg("session", id), &m) == 0) {
                        ok = m.kind == IMP_PROTO_MSG_REPLY && m.ok;
                        imp_proto_message_done(&m);
                }
                if (ok)
                        return true;
                usleep(500000);
        }
        return false;
}

static void unplug_and_back(struct harness *h, const char *plan, size_t frames, const char *name, bool stall,
                            bool swap) {
        const char *const opts[] = { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", "--retries", "2",
                                     "--device-timeout-ms", "400", NULL };
        h_start(h, opts);
        struct tclient c;
        CHECK_OK(tc_open(&c, h->socket, true));
        char id[128], setdir[1024];
        tc_start_session(&c, plan, name, id, setdir);
        CHECK(id[0] != 0);
        /* Three frames in, the camera goes. */
        tc_wait_frames(&c, 3, 10000);
        CHECK_MSG(c.n_frames >= 3 && !c.n_done, "%s: %u frames before the unplug", name, c.n_frames);
        if (stall) {
                atomic_store(&stall_armed, 1);
                fprintf(stderr, "%s: camera stalls after %u frame events\n", name, c.n_frames);
                /* It comes back by itself: the session completes, or pauses and resumes. */
                uint64_t end = h_deadline_ms(90000);
                bool completed = false, resumed_once = false;
                while (!completed && h_now_ms() < end) {
                        completed = wait_state(&c, id, "completed", 1000);
                        json_t *r = tc_ok(&c, "session.show", h_arg("session", id));
                        const char *st = json_string_value(json_object_get(r, "state"));
                        bool paused = st && !strcmp(st, "paused");
                        if (paused && resumed_once) {
                                json_decref(r);
                                break;          /* paused again after the camera was back: the bug */
                        }
                        if (paused) {
                                usleep(7000000);        /* the stall is over */
                                CHECK_MSG(resume(&c, id), "%s: session.resume refused after the stall", name);
                                resumed_once = true;
                        }
                        json_decref(r);
                }
                CHECK_MSG(completed, "%s: the session did not complete after the camera came back", name);
        } else {
                usleep(150000);
                CHECK_OK(imp_emu_gige_unplug(h->gige));
                fprintf(stderr, "%s: camera unplugged after %u frame events\n", name, c.n_frames);
                CHECK_MSG(wait_state(&c, id, "paused", 60000), "%s: the session did not pause without its camera",
                          name);
                CHECK_INT_GE(c.n_faults, 1);
                json_t *r = tc_ok(&c, "session.show", h_arg("session", id));
                size_t kept = (size_t) json_integer_value(json_object_get(r, "frames"));
                json_decref(r);
                CHECK(kept >= 3 && kept < frames);
                /* What is stored so far is intact while the camera is away. */
                CHECK_INT_EQ(h_verify_set(setdir, plan, false), kept);
                if (swap) {
                        /* Another camera at the address: refused by its serial, the set kept. */
                        struct imp_emu_gige *other = NULL;
                        CHECK_OK(imp_emu_gige_new("127.0.0.1", "IMP-OTHER", h->rig, NULL, NULL, &other));
                        char msg[512] = "";
                        CHECK_INT_EQ(tc_err(&c, "session.resume", h_arg("session", id), msg, sizeof msg),
                                     IMP_PROTO_E_DEVICE);
                        CHECK_STR_CONTAINS(msg, "IMP-OTHER");
                        CHECK_STR_CONTAINS(msg, "IMP-DAEMON");
                        usleep(300000);
                        r = tc_ok(&c, "session.show", h_arg("session", id));
                        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "paused");
                        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), kept);
                        json_decref(r);
                        imp_emu_gige_free(other);
                }
                CHECK_OK(imp_emu_gige_replug(h->gige));
                CHECK_MSG(resume(&c, id), "%s: session.resume refused after the camera came back", name);
                CHECK_MSG(wait_state(&c, id, "completed", 60000), "%s: the session did not complete after the replug",
                          name);
        }
        h_check_completed(h, &c, id, setdir, plan, frames);
}

int main(void) {
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        char plan[512];
        /* Streamed: runs of 8 repeats (free-running camera when it goes). */
        snprintf(plan, sizeof plan, "%s/repeat.cfg", h.dir);
        h_write(plan, "dome = { lights = [0, 1, 2, 3, 4, 5]; exposures_us = [2000.0]; repeat = 8; };\n");
        unplug_and_back(&h, plan, 6 * 8, "streamed", false, false);
        /* Triggered: a sweep, one frame per light, then darks; one long exposure (nothing
         * written to the camera between frames), so that the camera goes while the daemon
         * waits for a frame: the grab times out, the driver finds the camera gone and
         * releases it — the path of the old bug. */
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [400000.0]; };\ndark = { count = 2; };\n");
        unplug_and_back(&h, plan, N_LIGHTS + 2, "triggered", false, true);
        /* Stalled: the same sweep at a short exposure, from a camera whose thread blocks. */
        imp_emu_gige_free(h.gige);
        h.gige = NULL;
        CHECK_OK(imp_emu_gige_new("127.0.0.1", "IMP-DAEMON", h.rig, stall_fill, NULL, &h.gige));
        snprintf(plan, sizeof plan, "%s/stall.cfg", h.dir);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [2000.0]; };\n");
        unplug_and_back(&h, plan, N_LIGHTS, "stalled", true, false);
        if (h.pid > 0)
                h_kill(&h, SIGKILL);
        h_teardown(&h);
        return TEST_DONE();
}
