/* impastod scanning a whole painting (daemon/session-painting.c, docs/painting.md) on the real
 * GRBL stage driver against the GRBL emulator on a pseudo-terminal (or, with "modbus", the
 * Modbus stage driver against the Modbus stage emulator on loopback), with the emulated GigE
 * camera and Modbus dome. The camera's frames carry where the emulated carriage stood when
 * they were filled (row 1, pixels 0..2: x, y, z in 10 µm), so a frame taken anywhere but at
 * its tile is seen.
 *   run:     a 3 × 2 tile painting: one capture set per tile (tiles/NNNN) whose every frame
 *            records the commanded and read-back pose and shows the carriage there; painting.json
 *            all done; a processing job per tile, the first queued before the scan ends;
 *            progress by tile; the plan with a painting group refused without a stage.
 *   faults:  a limit switch on the way to tile 2, a position lost inside tile 3, a drive
 *            alarm inside tile 4 and a move to tile 5 that never settles: each pauses the session with a message naming the tile and
 *            the remedy, keeps every frame, and `session.resume` (which clears and homes)
 *            continues at the first frame not captured; the final capture equals `run`'s.
 *            While the move to tile 5 is pending, another client's `status` is answered and
 *            says "moving to tile 5" (the event loop never waits on the stage), and a
 *            `session.pause` then soft-stops the stalled carriage without a fault.
 *   kill N:  SIGKILL at N random points (0–2 frame events plus 0–30 ms), impastod restarted with
 *            --resume each time; the final capture equals `run`'s: every frame's pixels
 *            byte-identical and its poses equal.
 * Modbus port 15931 (15932 for the slow variant; 15933 and the stage's 15934 for "modbus"); run
 * in a private network namespace. */
#define _GNU_SOURCE 1
#include <math.h>
#include "emu-stage.h"
#include "test-daemon-harness.c"

#define N_LIGHTS 4
#define FRAMES_PER_TILE (2 * N_LIGHTS + 2)     /* and a dark frame per exposure */
#define N_TILES 6
#define TOL_MM 0.010            /* IMP_STAGE_DEFAULT_TOLERANCE_MM: what "settled" means */

/* The default frame, and the carriage's position where the formula has its row 1. */
static int fill_at_stage(void *userdata, const struct imp_emu_camera_state *st, void *buf, int width, int height,
                         int bpp) {
        int r = imp_emu_fill_default(NULL, st, buf, width, height, bpp);
        double pos[3];
        imp_emu_stage_position(userdata, pos);
        if (bpp == 2 && height > 1 && width > 2)
                for (int a = 0; a < 3; a++)
                        ((uint16_t *) buf)[width + a] = (uint16_t) lround(pos[a] * 100);
        return r;
}

struct ctx {
        struct harness h;
        struct imp_emu_stage *emu;
        bool modbus;                    /* the Modbus stage instead of GRBL */
        struct tclient *watch;          /* a second client, not subscribed (test_faults) */
        bool saw_moving;                /* its status answered during the move to tile 5 */
        char plan[512];
        const char *const *opts;
};

static void setup(struct ctx *x, int port) {
        h_setup(&x->h, port, N_LIGHTS);
        struct imp_emu_stage_config cfg = { .port = (uint16_t) (port + 1), .travel_mm = { 400, 300, 50 } };
        int r = x->modbus ? imp_emu_stage_modbus_new(&cfg, &x->emu) : imp_emu_stage_grbl_new(&cfg, &x->emu);
        if (r == -EADDRINUSE) {
                fprintf(stderr, "TCP port %d on 127.0.0.1 is busy\n", port + 1);
                exit(77);
        }
        if (r < 0)
                exit(2);
        char stage[256];
        if (x->modbus)
                snprintf(stage, sizeof stage, "backend = \"modbus\"; address = \"127.0.0.1:%d;timeout_ms=1000\";",
                         port + 1);
        else
                snprintf(stage, sizeof stage, "backend = \"grbl\"; address = \"%s;baud=115200;timeout_ms=1000\";",
                         imp_emu_stage_device(x->emu));
        imp_emu_gige_free(x->h.gige);
        if (imp_emu_gige_new("127.0.0.1", "IMP-DAEMON", x->h.rig, fill_at_stage, x->emu, &x->h.gige) < 0)
                exit(2);
        char text[2048];
        snprintf(text, sizeof text,
                 "rig = {\n  name = \"test-rig\";\n  calibration = \"rig.json\";\n"
                 "  cameras = ( { name = \"cam0\"; backend = \"aravis\"; address = \"127.0.0.1\"; } );\n"
                 "  dome = { backend = \"modbus\"; address = \"127.0.0.1:%d\"; };\n"
                 "  stage = { %s sigma_mm = 0.02; settle_timeout_ms = 3000; };\n"
                 "};\n",
                 port, stage);
        h_write(x->h.rigcfg, text);
        snprintf(x->plan, sizeof x->plan, "%s/painting.cfg", x->h.dir);
        /* stage x of the tiles: 40, 70, 100; y: 35, 59 (test-painting-stage) */
        h_write(x->plan, "dome = { lights = \"all\"; exposures_us = [1000.0, 2000.0]; };\ndark = { count = 1; };\n"
                         "painting = { extent_mm = [100.0, 54.0]; fov_mm = [40.0, 30.0]; origin_mm = [20.0, 20.0];"
                         " z_mm = 10.0; };\n");
}

/* The client goes, impastod exits 0 on SIGTERM. */
static void stop(struct ctx *x, struct tclient *c) {
        tc_close(c);
        h_kill(&x->h, SIGTERM);
        CHECK(h_wait(&x->h, 10000) == 0);
}

static void start(struct ctx *x, struct tclient *c) {
        h_start(&x->h, x->opts);
        CHECK_OK(tc_open(c, x->h.socket, true));
}

/* Reads events until the session ends or pauses (a fault), or timeout. Returns the state
 * seen ("completed", "paused", ...), copies the last fault's message. Calls hook on every
 * progress event (for injecting faults at a tile). */
typedef void (*progress_hook)(struct ctx *x, const json_t *painting);
static const char *follow(struct ctx *x, struct tclient *c, progress_hook hook, char *fault, size_t size,
                          bool *job_before_done) {
        uint64_t end = h_deadline_ms(60000);
        static char state[32];
        bool seen_fault = false, paused = false;
        snprintf(state, sizeof state, "timeout");
        while (h_now_ms() < end) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, 5000, &m) < 0)
                        continue;
                if (m.kind != IMP_PROTO_MSG_EVENT) {
                        imp_proto_message_done(&m);
                        continue;
                }
                const char *st = json_string_value(json_object_get(m.root, "state"));
                bool stop = false;
                if (getenv("IMPASTO_TEST_VERBOSE") && strcmp(m.event, "frame") && strcmp(m.event, "job"))
                        fprintf(stderr, "event %s state %s\n", m.event, st ? st : "-");
                if (!strcmp(m.event, "fault") && fault) {
                        snprintf(fault, size, "%s", json_string_value(json_object_get(m.root, "message")));
                        seen_fault = true;
                        stop = paused;
                }
                else if (!strcmp(m.event, "job") && job_before_done && c->n_done == 0)
                        *job_before_done = true;
                else if (!strcmp(m.event, "done")) {
                        snprintf(state, sizeof state, "%s", st ? st : "");
                        stop = true;
                } else if (!strcmp(m.event, "progress")) {
                        const json_t *pj = json_object_get(m.root, "painting");
                        if (hook && pj)
                                hook(x, pj);
                        /* a pause flushes the frames in flight (their progress says paused)
                         * before the fault is announced: wait for the fault too */
                        if (st && !strcmp(st, "paused")) {
                                snprintf(state, sizeof state, "paused");
                                stop = !fault || seen_fault;
                                paused = true;
                        }
                }
                imp_proto_message_done(&m);
                if (stop)
                        break;
        }
        return state;
}

static void session_dir(struct tclient *c, const char *id, char *dir, size_t size) {
        json_t *r = tc_ok(c, "session.show", h_arg("session", id));
        snprintf(dir, size, "%s", json_string_value(json_object_get(r, "path")) ?: "");
        json_decref(r);
}

/* Every tile set complete, every frame at its tile: poses recorded, pixels showing it. */
static void check_painting(const char *sdir) {
        char p[1200];
        snprintf(p, sizeof p, "%s/painting.json", sdir);
        _cleanup_json_ json_t *pj = NULL;
        struct imp_error e = { 0 };
        CHECK_OK(imp_json_load(p, &pj, &e));
        json_t *tiles = json_object_get(pj, "tiles");
        CHECK_INT_EQ(json_array_size(tiles), N_TILES);
        /* the stage's prior as the rig config gives it (the mosaic refuses σ 0); 0.05° by default */
        CHECK_NEAR(json_number_value(json_object_get(pj, "stage_sigma_mm")), 0.02, 1e-12);
        CHECK_NEAR(json_number_value(json_object_get(pj, "stage_sigma_deg")), 0.05, 1e-12);
        for (size_t k = 0; k < json_array_size(tiles); k++) {
                json_t *t = json_array_get(tiles, k);
                CHECK_MSG(json_is_true(json_object_get(t, "done")), "tile %zu not done", k);
                double cmd[3], rb[3];
                CHECK_OK(imp_json_get_doubles(t, "commanded_mm", true, 3, cmd, p, &e));
                CHECK_OK(imp_json_get_doubles(t, "readback_mm", true, 3, rb, p, &e));
                snprintf(p, sizeof p, "%s/tiles/%04zu", sdir, k);
                _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
                CHECK_OK(imp_captureset_open(p, &cs, &e));
                if (!cs)
                        continue;
                CHECK_INT_EQ(imp_captureset_count(cs), FRAMES_PER_TILE);
                for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                        const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                        CHECK(rec->has_stage);
                        _cleanup_image_ struct imp_image *img = NULL;
                        CHECK_OK(imp_captureset_load_frame(cs, i, &img, &e));
                        for (int a = 0; a < 3 && img; a++) {
                                CHECK_NEAR(rec->stage_commanded_mm[a], cmd[a], 1e-9);
                                CHECK_NEAR(rec->stage_readback_mm[a], cmd[a], TOL_MM);
                                CHECK_NEAR(rec->stage_readback_mm[a], rb[a], 1e-9);
                                /* where the carriage was when the frame was filled: 10 µm units */
                                CHECK_NEAR(imp_image_u16(img, 0, 1)[a] / 100.0, cmd[a], 0.011);
                        }
                }
        }
}

/* The capture of session dir b equals a's: same frames, pixels byte for byte, same poses. */
static void check_same_capture(const char *a, const char *b) {
        struct imp_error e = { 0 };
        size_t same = 0;
        for (size_t k = 0; k < N_TILES; k++) {
                char pa[1200], pb[1200];
                snprintf(pa, sizeof pa, "%s/tiles/%04zu", a, k);
                snprintf(pb, sizeof pb, "%s/tiles/%04zu", b, k);
                _cleanup_(imp_captureset_closep) struct imp_captureset *ca = NULL, *cb = NULL;
                CHECK_OK(imp_captureset_open(pa, &ca, &e));
                CHECK_OK(imp_captureset_open(pb, &cb, &e));
                if (!ca || !cb)
                        return;
                CHECK_INT_EQ(imp_captureset_count(cb), imp_captureset_count(ca));
                for (size_t i = 0; i < imp_captureset_count(ca) && i < imp_captureset_count(cb); i++) {
                        const struct imp_frame_record *ra = imp_captureset_record(ca, i), *rb = imp_captureset_record(cb, i);
                        CHECK(ra->seq == rb->seq && ra->light == rb->light && ra->exposure_us == rb->exposure_us);
                        CHECK(rb->has_stage && !memcmp(ra->stage_commanded_mm, rb->stage_commanded_mm, sizeof ra->stage_commanded_mm) &&
                              !memcmp(ra->stage_readback_mm, rb->stage_readback_mm, sizeof ra->stage_readback_mm));
                        _cleanup_image_ struct imp_image *ia = NULL, *ib = NULL;
                        CHECK_OK(imp_captureset_load_frame(ca, i, &ia, &e));
                        CHECK_OK(imp_captureset_load_frame(cb, i, &ib, &e));
                        if (!ia || !ib)
                                continue;
                        CHECK(ia->width == ib->width && ia->height == ib->height);
                        bool eq = ia->width == ib->width && ia->height == ib->height &&
                                  !memcmp(ia->data, ib->data, (size_t) ia->width * (size_t) ia->height * 2);
                        CHECK_MSG(eq, "tile %zu frame %zu: pixels differ from the uninterrupted scan", k, i);
                        same += eq;
                }
        }
        CHECK_INT_EQ(same, N_TILES * FRAMES_PER_TILE);
}

/* The uninterrupted scan; its session directory in ref. */
static void test_run(struct ctx *x, char *ref, size_t size) {
        struct tclient c;
        start(x, &c);
        char id[128], sdir[1024], msg[1024] = "";
        tc_start_session(&c, x->plan, "run", id, sdir);
        bool job_early = false;
        CHECK_STR_EQ(follow(x, &c, NULL, msg, sizeof msg, &job_early), "completed");
        CHECK_MSG(job_early, "no tile job was queued before the scan ended");
        json_t *r = tc_ok(&c, "session.show", h_arg("session", id));
        json_t *pj = json_object_get(r, "painting");
        CHECK_INT_EQ(json_integer_value(json_object_get(pj, "tiles")), N_TILES);
        CHECK_INT_EQ(json_integer_value(json_object_get(pj, "tiles_done")), N_TILES);
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "frames")), N_TILES * FRAMES_PER_TILE);
        json_decref(r);
        r = tc_ok(&c, "jobs.list", json_pack("{s:i}", "limit", 1000));
        size_t tile_jobs = 0, i;
        json_t *j;
        json_array_foreach(json_object_get(r, "jobs"), i, j) {
                const char *jid = json_string_value(json_object_get(j, "job"));
                tile_jobs += jid && !strncmp(jid, id, strlen(id)) && strstr(jid, "-tile");
        }
        CHECK_INT_EQ(tile_jobs, N_TILES);
        json_decref(r);
        session_dir(&c, id, sdir, sizeof sdir);
        check_painting(sdir);
        snprintf(ref, size, "%s", sdir);
        stop(x, &c);
}

static unsigned hook_step;

/* Asks x->watch for `status` until the painting's stage says want (true) or the session is
 * no longer capturing (false: an answer that came only once the move was over). */
static bool status_shows(struct ctx *x, const char *want) {
        for (int tries = 0; tries < 500; tries++) {
                json_t *r = tc_ok(x->watch, "status", NULL);
                const json_t *sess = json_object_get(r, "session");
                const char *st = json_string_value(json_object_get(sess, "state"));
                const char *stage = json_string_value(json_object_get(json_object_get(sess, "painting"), "stage"));
                bool seen = stage && strstr(stage, want), capturing = st && !strcmp(st, "capturing");
                if (getenv("IMPASTO_TEST_VERBOSE"))
                        fprintf(stderr, "status: %s, stage %s\n", st ? st : "-", stage ? stage : "-");
                json_decref(r);
                if (seen || !capturing)
                        return seen;
                usleep(10000);
        }
        return false;
}

/* Tile 3: position lost after its first frame; tile 4: a drive alarm after its second, then
 * a stalling carriage (on the move to tile 5) near its end. */
static void inject(struct ctx *x, const json_t *pj) {
        json_int_t tile = json_integer_value(json_object_get(pj, "tile"));
        json_int_t done = json_integer_value(json_object_get(pj, "tile_frames_done"));
        if (hook_step == 0 && tile == 3 && done >= 1) {
                imp_emu_stage_lose_position(x->emu);
                hook_step = 1;
        } else if (hook_step == 1 && tile == 4 && done >= 2) {
                imp_emu_stage_alarm(x->emu, 3);
                hook_step = 2;
        } else if (hook_step == 2 && tile == 4 && done >= FRAMES_PER_TILE - 2) {
                imp_emu_stage_stall(x->emu, true);
                hook_step = 3;
        } else if (hook_step == 3 && tile == 5) {
                /* tile 4 stored: the (stalling) move to tile 5 comes next */
                hook_step = 4;
                x->saw_moving = status_shows(x, "moving to tile 5 (col 0, row 1)");
        }
}

static size_t frames_of(struct tclient *c, const char *id) {
        json_t *r = tc_ok(c, "session.show", h_arg("session", id));
        size_t n = (size_t) json_integer_value(json_object_get(r, "frames"));
        json_decref(r);
        return n;
}

static void resume(struct tclient *c, const char *id) {
        json_t *r = tc_ok(c, "session.resume", h_arg("session", id));
        json_decref(r);
}

static size_t faults_of(struct tclient *c, const char *id) {
        json_t *r = tc_ok(c, "session.show", h_arg("session", id));
        size_t n = json_array_size(json_object_get(r, "faults"));
        json_decref(r);
        return n;
}

/* The move to tile 5 still stalls: resumed, then paused while it is pending. The pause is
 * answered at once, stops the carriage (soft-stop) and records no fault; events up to the
 * pause are read off c. */
static void test_pause_moving(struct ctx *x, struct tclient *c, const char *id) {
        size_t faults = faults_of(c, id);
        resume(c, id);
        CHECK_MSG(status_shows(x, "moving to tile 5 (col 0, row 1)"), "status did not show the pending move");
        CHECK(imp_emu_stage_moving(x->emu));
        json_t *r = tc_ok(x->watch, "session.pause", h_arg("session", id));
        json_decref(r);
        CHECK_MSG(!imp_emu_stage_moving(x->emu), "the stalled carriage still moves after the pause");
        /* on the other client: a call on c would take the events follow() reads */
        r = tc_ok(x->watch, "session.show", h_arg("session", id));
        CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "paused");
        json_decref(r);
        CHECK_INT_EQ(faults_of(x->watch, id), faults);
        CHECK_INT_EQ(frames_of(x->watch, id), 5 * FRAMES_PER_TILE);
        CHECK_STR_EQ(follow(x, c, NULL, NULL, 0, NULL), "paused");
}

static void test_faults(struct ctx *x, const char *ref) {
        struct tclient c, w;
        start(x, &c);
        CHECK_OK(tc_open(&w, x->h.socket, false));
        x->watch = &w;
        char id[128], sdir[1024], msg[1024] = "";
        imp_emu_stage_limit_switch_at(x->emu, 0, 85);
        hook_step = 0;
        tc_start_session(&c, x->plan, "faults", id, sdir);
        CHECK_STR_EQ(follow(x, &c, NULL, msg, sizeof msg, NULL), "paused");
        CHECK_STR_CONTAINS(msg, "hard limit switch hit");
        CHECK_STR_CONTAINS(msg, "tile 2 (col 2, row 0)");
        CHECK_STR_CONTAINS(msg, "home the stage, then resume");
        CHECK_INT_EQ(frames_of(&c, id), 2 * FRAMES_PER_TILE);
        imp_emu_stage_limit_switch_at(x->emu, 0, NAN);

        msg[0] = 0;
        resume(&c, id);
        CHECK_STR_EQ(follow(x, &c, inject, msg, sizeof msg, NULL), "paused");
        CHECK_STR_CONTAINS(msg, "position lost during tile 3 (col 2, row 1) at its frame");
        CHECK_STR_CONTAINS(msg, "home the stage, then resume");
        size_t n = frames_of(&c, id);
        CHECK(n > 3 * FRAMES_PER_TILE && n < 4 * FRAMES_PER_TILE);

        msg[0] = 0;
        resume(&c, id);
        CHECK_STR_EQ(follow(x, &c, inject, msg, sizeof msg, NULL), "paused");
        CHECK_STR_CONTAINS(msg, "during tile 4 (col 1, row 1)");
        n = frames_of(&c, id);
        CHECK(n > 4 * FRAMES_PER_TILE + 1 && n < 5 * FRAMES_PER_TILE);

        /* the carriage stalls on its way to tile 5 (from the end of tile 4 on): stopped after
         * settle_timeout_ms (3 s) */
        msg[0] = 0;
        resume(&c, id);
        CHECK_STR_EQ(follow(x, &c, inject, msg, sizeof msg, NULL), "paused");
        CHECK_STR_CONTAINS(msg, "the move to tile 5 (col 0, row 1) at (40.000, 59.000, 10.000) mm did not settle");
        CHECK_MSG(x->saw_moving, "no status answer said \"moving to tile 5\" while the move was pending");
        CHECK_INT_EQ(frames_of(&c, id), 5 * FRAMES_PER_TILE);
        test_pause_moving(x, &c, id);
        imp_emu_stage_stall(x->emu, false);

        resume(&c, id);
        CHECK_STR_EQ(follow(x, &c, NULL, NULL, 0, NULL), "completed");
        session_dir(&c, id, sdir, sizeof sdir);
        check_painting(sdir);
        check_same_capture(ref, sdir);
        tc_close(&w);
        x->watch = NULL;
        stop(x, &c);
}

/* SIGKILL at n_kills random points, restarted with --resume. */
static void test_kills(struct ctx *x, const char *ref, unsigned n_kills) {
        unsigned seed = 20261126;
        const char *env = getenv("IMPASTO_TEST_SEED");
        if (env)
                seed = (unsigned) strtoul(env, NULL, 10);
        srand(seed);
        fprintf(stderr, "seed %u\n", seed);
        const char *const opts[] = { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", "--resume",
                                     "--device-timeout-ms", "400", NULL };
        x->opts = opts;
        struct tclient c;
        start(x, &c);
        char id[128], sdir[1024];
        tc_start_session(&c, x->plan, "kill", id, sdir);
        unsigned kills = 0;
        bool done = false;
        uint64_t deadline = h_deadline_ms(300000);      /* a hang guard */
        while (!done && id[0] && h_now_ms() < deadline) {
                unsigned wait_frames = kills < n_kills ? (unsigned) (rand() % 3) : 100000;
                unsigned first = c.n_frames;
                while (c.n_frames < first + wait_frames && !c.n_done) {
                        struct imp_proto_message m = { 0 };
                        if (tc_read(&c, 4000, &m) < 0)
                                break;
                        imp_proto_message_done(&m);
                }
                if (c.n_done) {
                        CHECK_STR_EQ(c.done_state, "completed");
                        done = true;
                        break;
                }
                usleep((useconds_t) (rand() % 30000));
                h_kill(&x->h, SIGKILL);
                kills++;
                tc_close(&c);
                start(x, &c);
                json_t *r = tc_ok(&c, "session.show", h_arg("session", id));
                const char *st = json_string_value(json_object_get(r, "state"));
                if (st && !strcmp(st, "completed"))
                        done = true;
                else if (st && !strcmp(st, "paused")) {
                        struct imp_proto_message m = { 0 };
                        if (tc_call(&c, "session.resume", h_arg("session", id), &m) == 0)
                                imp_proto_message_done(&m);
                }
                json_decref(r);
        }
        fprintf(stderr, "%u kills\n", kills);
        CHECK_INT_GE(kills, n_kills);
        CHECK(done);
        session_dir(&c, id, sdir, sizeof sdir);
        check_painting(sdir);
        check_same_capture(ref, sdir);
        stop(x, &c);
}

/* Reads events off c until n frames were stored in all, then SIGKILLs impastod. */
static void kill_at_frame(struct ctx *x, struct tclient *c, unsigned n) {
        uint64_t end = h_deadline_ms(120000);
        while (c->n_frames < n && !c->n_done && h_now_ms() < end) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, 4000, &m) == 0)
                        imp_proto_message_done(&m);
        }
        CHECK_MSG(c->n_frames >= n && !c->n_done, "the scan did not reach frame %u (%u frames)", n, c->n_frames);
        h_kill(&x->h, SIGKILL);
        tc_close(c);
}

/* session.resume after a SIGKILL: the camera emulator may still hold the killed daemon's
 * control channel for a while (a device error): tried again until it lets go. */
static void resume_after_kill(struct tclient *c, const char *id) {
        uint64_t end = h_deadline_ms(30000);
        char msg[1024] = "";
        enum imp_proto_errcode code;
        while ((code = tc_err(c, "session.resume", h_arg("session", id), msg, sizeof msg)) == IMP_PROTO_E_DEVICE &&
               h_now_ms() < end)
                usleep(300000);
        CHECK_MSG(code == IMP_PROTO_E_NONE, "session.resume: %s", msg);
}

/* A listed damaged session: paused, "damaged" naming session.json's fault and where the
 * painting stands (tile k of N), its frames counted from the tile sets. */
static void check_listed_damaged(struct tclient *c, const char *id, const char *why, unsigned tile) {
        json_t *r = tc_ok(c, "session.show", h_arg("session", id));
        const char *st = json_string_value(json_object_get(r, "state"));
        const char *dmg = json_string_value(json_object_get(r, "damaged"));
        size_t frames = (size_t) json_integer_value(json_object_get(r, "frames"));
        CHECK_STR_EQ(st ? st : "", "paused");
        CHECK_MSG(dmg && strstr(dmg, why), "damaged: %s, want %s", dmg ? dmg : "(none)", why);
        char want[100];
        snprintf(want, sizeof want, "frames: tile %u of %u at its frame %zu of %u", tile, N_TILES,
                 frames - tile * FRAMES_PER_TILE, FRAMES_PER_TILE);
        CHECK_MSG(dmg && strstr(dmg, want), "damaged: %s, want %s", dmg ? dmg : "(none)", want);
        CHECK_MSG(frames >= tile * FRAMES_PER_TILE + 1 && frames < (tile + 1) * FRAMES_PER_TILE,
                  "%zu frames listed, want some of tile %u", frames, tile);
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "steps")), N_TILES * FRAMES_PER_TILE);
        json_decref(r);
        /* status: the operator's attention list names it, with where it stands */
        r = tc_ok(c, "status", NULL);
        bool listed = false;
        size_t i;
        json_t *a;
        json_array_foreach(json_object_get(json_object_get(r, "attention"), "items"), i, a) {
                const char *kind = json_string_value(json_object_get(a, "kind"));
                const char *m = json_string_value(json_object_get(a, "message"));
                listed |= kind && !strcmp(kind, "session_damaged") && m && strstr(m, id) && strstr(m, want);
        }
        CHECK_MSG(listed, "status's attention list does not name the damaged session at %s", want);
        json_decref(r);
}

/* A painting session whose session.json is damaged (then missing) after a SIGKILL, and whose
 * painting.json is damaged too: listed paused at the right tile, rebuilt on resume from the
 * painting's tile sets (session.show says what was rebuilt and why; the damaged painting.json
 * kept aside byte for byte), and the final capture equals the uninterrupted one. */
static void test_damaged(struct ctx *x, const char *ref) {
        struct tclient c;
        start(x, &c);
        char id[128], sdir[1024], p[1200], q[1300];
        tc_start_session(&c, x->plan, "damaged", id, sdir);
        session_dir(&c, id, sdir, sizeof sdir);
        kill_at_frame(x, &c, 2 * FRAMES_PER_TILE + 4);
        snprintf(p, sizeof p, "%s/session.json", sdir);
        h_write(p, "{\"session\": \"trunc");
        snprintf(q, sizeof q, "%s/painting.json", sdir);
        static const char bad_painting[] = "{\"format\": \"impasto-painting\", \"tiles\": 7}\n";
        h_write(q, bad_painting);
        start(x, &c);
        check_listed_damaged(&c, id, "session.json", 2);
        resume_after_kill(&c, id);
        json_t *r = tc_ok(&c, "session.show", h_arg("session", id));
        const char *rb = json_string_value(json_object_get(r, "rebuilt"));
        CHECK_MSG(rb && strstr(rb, "session.json rebuilt from the painting's tile sets and plan") &&
                  strstr(rb, "painting.json rebuilt from the plan and the tile sets") &&
                  strstr(rb, "painting.json: extent_mm: missing") && strstr(rb, "painting.json.damaged-1"),
                  "rebuilt: %s", rb ? rb : "(none)");
        CHECK(!json_object_get(r, "damaged"));
        json_decref(r);
        /* the operator's `impasto scan show` says it too */
        CHECK_INT_EQ(test_sh("%s/cli/impasto scan show %s --socket %s | grep -q '^rebuilt  session.json rebuilt from the painting'",
                             IMPASTO_BINARY_DIR, id, x->h.socket), 0);
        snprintf(q, sizeof q, "%s/painting.json.damaged-1", sdir);
        char kept[200] = "";
        FILE *f = fopen(q, "re");
        size_t kept_n = f ? fread(kept, 1, sizeof kept - 1, f) : 0;
        if (f)
                fclose(f);
        CHECK_MSG(kept_n == strlen(bad_painting) && !memcmp(kept, bad_painting, kept_n), "%s: %s", q, kept);

        /* again, session.json gone altogether, in tile 4 */
        kill_at_frame(x, &c, 2 * FRAMES_PER_TILE + 1);  /* frames of this run: 2 more tiles */
        CHECK(unlink(p) == 0);
        start(x, &c);
        check_listed_damaged(&c, id, "session.json: No such file or directory", 4);
        resume_after_kill(&c, id);
        r = tc_ok(&c, "session.show", h_arg("session", id));
        rb = json_string_value(json_object_get(r, "rebuilt"));
        CHECK_MSG(rb && strstr(rb, "session.json rebuilt from the painting's tile sets and plan") &&
                  strstr(rb, "No such file"), "rebuilt: %s", rb ? rb : "(none)");
        json_decref(r);
        CHECK_STR_EQ(follow(x, &c, NULL, NULL, 0, NULL), "completed");
        check_painting(sdir);
        check_same_capture(ref, sdir);
        stop(x, &c);
}

/* Copies of a finished session with session.json removed and one more damage each: resuming
 * it fails with a message naming the tile set and what is wrong, changes nothing on disk
 * (tree and contents hashed before and after), and the daemon goes on answering. */
static void test_damaged_tiles(struct ctx *x, const char *ref) {
        static const char *const cases[][3] = {
                /* name, shell command in the copy, the message */
                { "t-symlink", "mv tiles/0003 ../../../outside-0003 && ln -s \"$(realpath ../../../outside-0003)\" tiles/0003",
                  "tiles/0003: a symbolic link, not the tile's capture set" },
                { "t-missing", "rm -r tiles/0002", "tiles/0002: missing; but" },
                { "t-range", "cp -a tiles/0005 tiles/0006", "tiles/0006: a tile set beyond the plan's 6 tiles" },
                { "t-cut", "truncate -s -7 tiles/0001/manifest.jsonl", "tiles/0001/manifest.jsonl:10: the last line" },
                { "t-gap", "sed -i 's/\"done\": true/\"done\": false/' painting.json && rm -r tiles/0001",
                  "'s set is there, but tile 1 before it is not complete" },
        };
        char sessions[400];
        snprintf(sessions, sizeof sessions, "%s/sessions", x->h.state);
        for (size_t i = 0; i < ARRAY_SIZE(cases); i++)
                CHECK_INT_EQ(test_sh("cd %s && cp -a %s %s && cd %s && rm session.json && %s", sessions, ref, cases[i][0],
                                     cases[i][0], cases[i][1]), 0);
        CHECK_INT_EQ(test_sh("cd %s && find t-* ../../outside-0003 -print0 | sort -z | xargs -0 stat -c '%%n %%s %%Y %%F' > ../before "
                             "&& find t-* ../../outside-0003 -type f -print0 | sort -z | xargs -0 md5sum >> ../before", sessions), 0);
        struct tclient c;
        start(x, &c);
        for (size_t i = 0; i < ARRAY_SIZE(cases); i++) {
                char msg[2048] = "";
                CHECK_INT_EQ(tc_err(&c, "session.resume", h_arg("session", cases[i][0]), msg, sizeof msg),
                             IMP_PROTO_E_IO);
                CHECK_MSG(strstr(msg, cases[i][2]), "%s: %s, want %s", cases[i][0], msg, cases[i][2]);
                json_t *r = tc_ok(&c, "session.show", h_arg("session", cases[i][0]));
                CHECK_STR_EQ(json_string_value(json_object_get(r, "state")), "paused");
                json_decref(r);
        }
        json_decref(tc_ok(&c, "status", NULL));
        stop(x, &c);
        CHECK_INT_EQ(test_sh("cd %s && find t-* ../../outside-0003 -print0 | sort -z | xargs -0 stat -c '%%n %%s %%Y %%F' > ../after "
                             "&& find t-* ../../outside-0003 -type f -print0 | sort -z | xargs -0 md5sum >> ../after && "
                             "cmp ../before ../after && rm -rf t-* ../../outside-0003", sessions), 0);
}

/* plan.estimate of the painting plan: the whole painting's figures, the very object the
 * offline `plan estimate` prints (imp_plan_painting_estimate_json on the same rig, plan and
 * tile bytes, the stage's feed), the options taken, and a painting the store cannot hold
 * refused. */
static void test_estimate(struct ctx *x) {
        struct tclient c;
        start(x, &c);
        struct imp_error e = { 0 };
        struct imp_rig rig = { 0 };
        CHECK_OK(imp_rig_load(x->h.rigjson, &rig, &e));
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        CHECK_OK(imp_plan_load(x->plan, &rig, &plan, &e));
        json_t *r = tc_ok(&c, "plan.estimate", h_arg("plan", x->plan));
        const json_t *got = json_object_get(r, "painting");
        CHECK_INT_EQ(json_integer_value(json_object_get(got, "tiles")), N_TILES);
        CHECK_INT_EQ(json_integer_value(json_object_get(got, "frames")), N_TILES * FRAMES_PER_TILE);
        double tile_bytes = (double) json_integer_value(json_object_get(r, "bytes"));
        CHECK_NEAR(json_number_value(json_object_get(got, "bytes")), N_TILES * tile_bytes, 1e-6);
        CHECK_INT_EQ(json_integer_value(json_object_get(r, "disk_needed")), (json_int_t) (N_TILES * tile_bytes));
        struct imp_plan_painting_opts o = { .speed_mm_s = IMP_PLAN_STAGE_SPEED_MM_S, .settle_s = IMP_PLAN_SETTLE_S,
                                            .process_s = -1, .workers = 1 };
        json_t *want = plan ? imp_plan_painting_estimate_json(plan, &rig, tile_bytes, &o) : NULL;
        CHECK_MSG(want && got && json_equal(want, (json_t *) got), "the daemon's painting figures differ from the offline ones");
        CHECK(json_number_value(json_object_get(got, "capture_s")) > json_number_value(json_object_get(got, "move_s")));
        json_decref(want);
        json_decref(r);
        /* the options */
        r = tc_ok(&c, "plan.estimate", json_pack("{s:s, s:{s:i, s:f, s:f}}", "plan", x->plan, "painting", "workers", 2,
                                                 "process_s", 7.5, "settle_s", 2.0));
        got = json_object_get(r, "painting");
        CHECK_INT_EQ(json_integer_value(json_object_get(got, "workers")), 2);
        CHECK_NEAR(json_number_value(json_object_get(got, "tile_process_s")), 7.5, 1e-12);
        CHECK_NEAR(json_number_value(json_object_get(got, "settle_s")), 2.0, 1e-12);
        CHECK_NEAR(json_number_value(json_object_get(got, "process_s")), 7.5 * N_TILES, 1e-9);
        json_decref(r);
        char msg[1024] = "";
        CHECK_INT_EQ(tc_err(&c, "plan.estimate", json_pack("{s:s, s:{s:i}}", "plan", x->plan, "painting", "workers", 0),
                            msg, sizeof msg), IMP_PROTO_E_BAD_ARGUMENT);
        CHECK_STR_CONTAINS(msg, "args.painting.workers");
        /* 313 × 313 tiles of 10 000 frames: terabytes */
        char huge[600];
        snprintf(huge, sizeof huge, "%s/huge-painting.cfg", x->h.dir);
        h_write(huge, "dome = { lights = \"all\"; exposures_us = [1000.0]; repeat = 2000; };\n"
                      "painting = { extent_mm = [5000.0, 5000.0]; fov_mm = [20.0, 20.0]; };\n");
        CHECK_INT_EQ(tc_err(&c, "plan.estimate", h_arg("plan", huge), msg, sizeof msg), IMP_PROTO_E_INVALID_PLAN);
        CHECK_STR_CONTAINS(msg, "the whole painting needs");
        CHECK_STR_CONTAINS(msg, "it will not fit");
        imp_rig_free(&rig);
        stop(x, &c);
}

static void test_no_stage(struct ctx *x) {
        /* the same rig without its stage line */
        char text[1024];
        snprintf(text, sizeof text,
                 "rig = {\n  name = \"test-rig\";\n  calibration = \"rig.json\";\n"
                 "  cameras = ( { name = \"cam0\"; backend = \"aravis\"; address = \"127.0.0.1\"; } );\n"
                 "  dome = { backend = \"modbus\"; address = \"127.0.0.1:%d\"; };\n};\n", x->h.port);
        char saved[300];
        snprintf(saved, sizeof saved, "%s", x->h.rigcfg);
        snprintf(x->h.rigcfg, sizeof x->h.rigcfg, "%s/rig-nostage.cfg", x->h.dir);
        h_write(x->h.rigcfg, text);
        struct tclient c;
        start(x, &c);
        char msg[1024] = "";
        CHECK_INT_EQ(tc_err(&c, "session.start", h_arg("plan", x->plan), msg, sizeof msg), IMP_PROTO_E_INVALID_PLAN);
        CHECK_STR_CONTAINS(msg, "painting.cfg: a plan with a painting group needs a stage in the rig config");
        stop(x, &c);
        snprintf(x->h.rigcfg, sizeof x->h.rigcfg, "%s", saved);
}

int main(int argc, char **argv) {
        /* "kill N" alone (the slow variant, on its own port): the reference run, then N kills */
        /* "modbus": the Modbus stage, run and faults (its own ports) */
        unsigned kills = argc > 2 && !strcmp(argv[1], "kill") ? (unsigned) atoi(argv[2]) : 3;
        bool only_kills = argc > 2;
        struct ctx x = { .modbus = argc > 1 && !strcmp(argv[1], "modbus") };
        const char *const opts[] = { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", NULL };
        x.opts = opts;
        setup(&x, x.modbus ? 15933 : only_kills ? 15932 : 15931);
        char ref[1024] = "";
        test_run(&x, ref, sizeof ref);
        if (!only_kills) {
                if (!x.modbus)
                        test_estimate(&x);
                test_no_stage(&x);
                test_faults(&x, ref);
                if (!x.modbus) {
                        test_damaged(&x, ref);
                        test_damaged_tiles(&x, ref);
                }
        }
        if (!x.modbus)
                test_kills(&x, ref, kills);
        if (x.h.pid > 0)
                h_kill(&x.h, SIGKILL);
        imp_emu_stage_free(x.emu);
        h_teardown(&x.h);
        return TEST_DONE();
}
