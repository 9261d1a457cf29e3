/* Whole-painting sessions on the gantry (daemon/tile-session.c) against the GRBL emulator
 * on a pseudo-terminal: every tile of a painting plan reached and read back within the
 * stage's tolerance and recorded in painting.json; a hard limit switch on the way to a tile
 * gives a message naming the fault, the tile and the remedy, keeps the tiles done before it,
 * and after clearing and re-homing the scan resumes at that tile; a stage that lost its
 * position is refused until homed; a painting.json of another plan is refused. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "emu-stage.h"
#include "json-util.h"
#include "tile-session.h"
#include "unit/test.h"

#define TIMEOUT_MS 300
#define SETTLE_MS 20000U
#define TOL_MM 0.010            /* IMP_STAGE_DEFAULT_TOLERANCE_MM: what "settled" means */

static struct imp_tile_plan *painting_small(double origin_x) {
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        o.extent_mm[0] = 100, o.extent_mm[1] = 54, o.fov_mm[0] = 40, o.fov_mm[1] = 30;
        o.origin_mm[0] = origin_x, o.origin_mm[1] = 20, o.z_mm = 10;
        struct imp_tile_plan *tp = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_tile_plan_new(&o, &tp, &err));
        return tp;
}

static void home(struct imp_stage *s) {
        CHECK_OK(imp_stage_clear_fault(s));
        CHECK_OK(imp_stage_home(s));
        CHECK_OK(imp_stage_wait_settled(s, SETTLE_MS, NULL));
}

/* Runs tiles from painting.json's next one until done or a move fails; returns the last r. */
static int scan(struct imp_stage *s, const char *dir, const struct imp_tile_plan *tp, json_t *pj, char *msg,
                size_t size) {
        struct imp_error err = {};
        for (size_t k = tile_session_next(pj); k < imp_tile_plan_count(tp); k++) {
                double rb[3];
                int r = tile_session_move(s, imp_tile_plan_tile(tp, k), SETTLE_MS, rb, msg, size);
                if (r < 0)
                        return r;
                for (int a = 0; a < 3; a++)
                        CHECK_NEAR(rb[a], imp_tile_plan_tile(tp, k)->stage_mm[a], TOL_MM);
                CHECK_OK(tile_session_record(dir, pj, k, rb, true, &err));
        }
        return 0;
}

static void test_scan_and_limit(struct imp_stage *s, struct imp_emu_stage *emu) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *tp = painting_small(20);
        if (!tp)
                return;
        char dir[512], msg[1024] = "";
        snprintf(dir, sizeof dir, "%s", test_tmpdir());
        struct imp_error err = {};
        _cleanup_json_ json_t *pj = NULL;
        CHECK_OK(tile_session_open(dir, tp, 0.05, 0.05, &pj, &err));
        if (!pj)
                return;
        CHECK_INT_EQ(tile_session_next(pj), 0);
        CHECK_NEAR(tile_session_eta_s(pj, 0, 0), -1, 0);
        home(s);
        /* stage x of the tiles: 40, 70, 100; a switch at 85 mm stops the move to tile 2 */
        imp_emu_stage_limit_switch_at(emu, 0, 85);
        int r = scan(s, dir, tp, pj, msg, sizeof msg);
        CHECK_ERR(r, -EIO);
        CHECK_STR_CONTAINS(msg, "hard limit switch hit");
        CHECK_STR_CONTAINS(msg, "tile 2 (col 2, row 0)");
        CHECK_STR_CONTAINS(msg, "home the stage, then resume");
        CHECK_INT_EQ(tile_session_next(pj), 2);
        CHECK_NEAR(tile_session_eta_s(pj, 2, 10.0), 20.0, 1e-9);     /* 4 tiles left at 5 s each */
        /* what a restarted daemon finds: two tiles done */
        _cleanup_json_ json_t *again = NULL;
        CHECK_OK(tile_session_open(dir, tp, 0.05, 0.05, &again, &err));
        CHECK(again && tile_session_next(again) == 2);
        /* refused until homed: the switch lost the position */
        imp_emu_stage_limit_switch_at(emu, 0, NAN);
        CHECK_OK(imp_stage_clear_fault(s));
        double rb[3];
        CHECK_ERR(tile_session_move(s, imp_tile_plan_tile(tp, 2), SETTLE_MS, rb, msg, sizeof msg), -ESTALE);
        CHECK_STR_CONTAINS(msg, "position not known");
        home(s);
        CHECK_OK(scan(s, dir, tp, again, msg, sizeof msg));
        CHECK_INT_EQ(tile_session_next(again), 6);
        CHECK_NEAR(tile_session_eta_s(again, 4, 10.0), 0, 0);
        /* another plan's painting.json is refused */
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *other = painting_small(25);
        json_t *bad = NULL;
        CHECK_ERR(tile_session_open(dir, other, 0.05, 0.05, &bad, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "another plan");
        json_decref(bad);
}

int main(void) {
        struct imp_emu_stage_config cfg = { .travel_mm = { 400, 300, 50 } };
        _cleanup_(imp_emu_stage_freep) struct imp_emu_stage *emu = NULL;
        int r = imp_emu_stage_grbl_new(&cfg, &emu);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        _cleanup_(imp_stage_closep) struct imp_stage *s = NULL;
        char addr[128];
        snprintf(addr, sizeof addr, "%s;baud=115200;timeout_ms=%d", imp_emu_stage_device(emu), TIMEOUT_MS);
        r = imp_stage_open("grbl", addr, 0, &s);
        CHECK_MSG(r == 0, "open %s: %s", addr, strerror(-r));
        if (r < 0)
                return TEST_DONE();
        struct imp_stage_config sc;
        CHECK_OK(imp_stage_get_config(s, &sc));
        sc.speed_mm_s = 400;    /* the emulator moves in real time: keep the test short */
        CHECK_OK(imp_stage_configure(s, &sc));
        test_scan_and_limit(s, emu);
        return TEST_DONE();
}
