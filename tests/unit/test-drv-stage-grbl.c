/* The "grbl" stage backend through the imp_stage wrapper against the GRBL 1.1 emulator on
 * a pseudo-terminal (sim/emu/emu-grbl.c): moves and read-back, soft limits, the faults of
 * stage-scenarios.h, and what is GRBL's own: the banner at open, alarms that lock it until
 * a reset, feed hold then reset as the soft-stop. */
#include "unit/stage-scenarios.h"

#define TIMEOUT_MS 300

/* Soft-stop is a feed hold, then a reset once the hold is complete: the reset must not
 * come during the motion (that would be ALARM:3, position lost). */
static void test_hold_then_reset(struct imp_stage *s, struct imp_emu_stage *emu) {
        unsigned resets = imp_emu_stage_n_resets(emu);
        double t[3] = { 150, 0, 0 };
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        usleep(100000);
        CHECK_OK(imp_stage_soft_stop(s));
        CHECK_INT_EQ(imp_emu_stage_n_resets(emu), resets + 1);
        struct imp_stage_status st;
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK_INT_EQ(st.fault, IMP_STAGE_FAULT_NONE);
        CHECK_INT_EQ(st.fault_code, 0);
        CHECK(imp_emu_stage_homed(emu));
        move_ok(s, 0, 0, 0, IMP_STAGE_XY);
}

/* A line lost on the way: its "ok" never comes. The move fails after the timeout, and the
 * next line must not take a later "ok" for its own: the backend resets at rest to count
 * answers afresh, and the position stays known. */
static void test_lost_line(struct imp_stage *s, struct imp_emu_stage *emu) {
        move_ok(s, 10, 10, 0, IMP_STAGE_XY);
        unsigned moves = imp_emu_stage_n_moves(emu), resets = imp_emu_stage_n_resets(emu);
        imp_emu_stage_lose_requests(emu, 1);
        double t[3] = { 20, 10, 0 };
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -ETIMEDOUT);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "no answer to G90G1X20.000Y10.000F12000 within 300 ms");
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), moves);
        move_ok(s, 20, 10, 0, IMP_STAGE_XY);
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), moves + 1);
        CHECK_INT_EQ(imp_emu_stage_n_resets(emu), resets + 1);
        struct imp_stage_status st;
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK(st.flags & IMP_STAGE_HOMED);
}

/* A 2-axis gantry (";axes=2"): z is not part of any move. */
static void test_two_axes(struct imp_stage **s, struct imp_emu_stage *emu) {
        imp_stage_close(*s);
        *s = NULL;
        char addr[128];
        snprintf(addr, sizeof addr, "%s;timeout_ms=%d;axes=2", imp_emu_stage_device(emu), TIMEOUT_MS);
        CHECK_OK(imp_stage_open("grbl", addr, 0, s));
        if (!*s)
                return;
        struct imp_stage_info info;
        CHECK_OK(imp_stage_get_info(*s, &info));
        CHECK_INT_EQ(info.n_axes, 2);
        double t[3] = { 10, 10, 5 };
        CHECK_ERR(imp_stage_move_to(*s, t, IMP_STAGE_XYZ), -EINVAL);
        CHECK_STR_CONTAINS(imp_stage_last_error(*s), "axis mask 0x7 on a 2-axis stage");
        home_ok(*s, emu);
        move_ok(*s, 10, 10, 0, IMP_STAGE_XY);
}

/* Stock GRBL (machine space −travel..0): with ";space=negative" the stage frame is 0..travel
 * again; without it the first move runs into GRBL's soft limit (ALARM:2). */
static void test_negative_space(void) {
        struct imp_emu_stage_config cfg = { .travel_mm = { 400, 300, 50 }, .grbl_negative_space = true };
        _cleanup_(imp_emu_stage_freep) struct imp_emu_stage *emu = NULL;
        CHECK_OK(imp_emu_stage_grbl_new(&cfg, &emu));
        if (!emu)
                return;
        char addr[128];
        snprintf(addr, sizeof addr, "%s;timeout_ms=%d;space=negative", imp_emu_stage_device(emu), TIMEOUT_MS);
        _cleanup_(imp_stage_closep) struct imp_stage *s = NULL;
        CHECK_OK(imp_stage_open("grbl", addr, 0, &s));
        if (!s)
                return;
        home_ok(s, emu);
        move_ok(s, 10, 20, 5, IMP_STAGE_XYZ);
        double truth[3];
        imp_emu_stage_position(emu, truth);
        CHECK_NEAR(truth[0], 10, TOL_MM);
        CHECK_NEAR(truth[1], 20, TOL_MM);
        imp_stage_close(TAKE_PTR(s));

        snprintf(addr, sizeof addr, "%s;timeout_ms=%d", imp_emu_stage_device(emu), TIMEOUT_MS);
        CHECK_OK(imp_stage_open("grbl", addr, 0, &s));
        if (!s)
                return;
        struct imp_stage_status st = {};
        CHECK_OK(imp_stage_home(s));
        CHECK_OK(imp_stage_wait_settled(s, SETTLE_MS, &st));
        CHECK_NEAR(st.position_mm[0], -400, TOL_MM);
        double t[3] = { 10, 20, 0 };
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        CHECK_ERR(imp_stage_wait_settled(s, SETTLE_MS, &st), -EIO);
        CHECK_INT_EQ(st.fault, IMP_STAGE_FAULT_TRAVEL);
        CHECK_INT_EQ(st.fault_code, 2);
        CHECK(imp_stage_get_status(s, &st) == 0 && (st.flags & IMP_STAGE_HOMED));  /* ALARM:2 keeps it */
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
        CHECK_INT_EQ(imp_emu_stage_n_resets(emu), 1);  /* open resets once, for a known state */
        /* GRBL: ALARM:1 raised with no switch pressed (noise on the limit input) is a hard
         * limit all the same: locked until a reset, position lost. */
        const struct stage_expect x = {
                .alarm_code = 1, .alarm_fault = IMP_STAGE_FAULT_LIMIT, .alarm_loses_position = true,
                .limit_code = 1,
        };
        /* A silent controller: one status query of TIMEOUT_MS. */
        run_stage_scenarios(s, emu, &cfg, &x, 1.0);
        test_hold_then_reset(s, emu);
        test_lost_line(s, emu);
        test_two_axes(&s, emu);
        test_negative_space();
        test_close_stops(&s, emu);
        return TEST_DONE();
}
