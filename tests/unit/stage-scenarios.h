/* Scenarios shared by the stage driver tests (test-drv-stage-modbus, test-drv-stage-grbl):
 * the real backend through the imp_stage wrapper against an emulator speaking the real
 * protocol. Each fault: what the caller sees, and that the stage is usable again after the
 * documented recovery (clear the fault; home when the position was lost). */
#pragma once
#include <math.h>
#include <time.h>
#include "emu-stage.h"
#include "stage.h"
#include "unit/test.h"

#define TOL_MM 0.0105                   /* the wrapper's 10 µm, plus GRBL's printed 1 µm */
#define SPEED_MM_S 200.0
#define SETTLE_MS 15000                 /* generous: sanitizers and a loaded machine */

/* How a backend reports the injected faults. */
struct stage_expect {
        unsigned alarm_code;                    /* injected by test_alarm */
        enum imp_stage_fault alarm_fault;       /* what the caller sees for it */
        bool alarm_loses_position;
        unsigned limit_code;                    /* GRBL ALARM:1, Modbus fault 1 */
};

static double stage_now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void move_ok(struct imp_stage *s, double x, double y, double z, unsigned mask) {
        double t[IMP_STAGE_MAX_AXES] = { x, y, z };
        struct imp_stage_status st = {};
        int r = imp_stage_move_to(s, t, mask);
        CHECK_MSG(r == 0, "move to %g %g %g: %s", x, y, z, imp_stage_last_error(s));
        r = imp_stage_wait_settled(s, SETTLE_MS, &st);
        CHECK_MSG(r == 0, "settle at %g %g %g: %s", x, y, z, imp_stage_last_error(s));
        for (unsigned a = 0; a < IMP_STAGE_MAX_AXES; a++)
                if (mask & (1u << a))
                        CHECK_NEAR(st.position_mm[a], t[a], TOL_MM);
}

static void home_ok(struct imp_stage *s, struct imp_emu_stage *emu) {
        struct imp_stage_status st = {};
        int r = imp_stage_home(s);
        CHECK_MSG(r == 0, "home: %s", imp_stage_last_error(s));
        r = imp_stage_wait_settled(s, SETTLE_MS, &st);
        CHECK_MSG(r == 0, "home settle: %s", imp_stage_last_error(s));
        CHECK(st.flags & IMP_STAGE_HOMED);
        CHECK(imp_emu_stage_homed(emu));
        for (unsigned a = 0; a < 3; a++)
                CHECK_NEAR(st.position_mm[a], 0, TOL_MM);
}

static void test_open(struct imp_stage *s, const struct imp_emu_stage_config *cfg) {
        struct imp_stage_info info;
        CHECK_OK(imp_stage_get_info(s, &info));
        CHECK_INT_EQ(info.n_axes, 3);
        for (unsigned a = 0; a < 3; a++)
                CHECK_NEAR(info.travel_mm[a], cfg->travel_mm[a], 1e-3);
        struct imp_stage_config c;
        CHECK_OK(imp_stage_get_config(s, &c));
        CHECK_NEAR(c.max_mm[0], cfg->travel_mm[0], 1e-9);
        c.speed_mm_s = SPEED_MM_S;
        CHECK_OK(imp_stage_configure(s, &c));
        /* Soft limits outside the travel are refused, and the old config stays. */
        struct imp_stage_config bad = c;
        bad.max_mm[1] = cfg->travel_mm[1] + 1;
        CHECK_ERR(imp_stage_configure(s, &bad), -ERANGE);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "soft limits of y");
        bad = c;
        bad.speed_mm_s = NAN;
        CHECK_ERR(imp_stage_configure(s, &bad), -EINVAL);
        struct imp_stage_config now;
        CHECK_OK(imp_stage_get_config(s, &now));
        CHECK_NEAR(now.max_mm[1], cfg->travel_mm[1], 1e-9);
        CHECK_NEAR(now.speed_mm_s, SPEED_MM_S, 1e-9);
}

/* Never homed through this handle: a move is refused before anything is sent. */
static void test_unhomed(struct imp_stage *s, struct imp_emu_stage *emu) {
        unsigned n0 = imp_emu_stage_n_moves(emu);
        double t[3] = { 10, 10, 0 };
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -ESTALE);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "home first");
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), n0);
        home_ok(s, emu);
}

static void test_moves(struct imp_stage *s, struct imp_emu_stage *emu) {
        static const double path[][3] = { { 10, 20, 0 }, { 42.125, 7.5, 3.25 }, { 60, 40, 12.5 }, { 0.5, 0.25, 0 } };
        for (size_t i = 0; i < ARRAY_SIZE(path); i++) {
                double t0 = stage_now_s();
                move_ok(s, path[i][0], path[i][1], path[i][2], IMP_STAGE_XYZ);
                double truth[3];
                imp_emu_stage_position(emu, truth);
                for (unsigned a = 0; a < 3; a++)
                        CHECK_NEAR(truth[a], path[i][a], TOL_MM);
                /* The commanded speed reached the controller: the move took its time. */
                if (i > 0) {
                        double d = 0;
                        for (unsigned a = 0; a < 3; a++)
                                d += (path[i][a] - path[i - 1][a]) * (path[i][a] - path[i - 1][a]);
                        CHECK_GE(stage_now_s() - t0, 0.9 * sqrt(d) / SPEED_MM_S);
                }
        }
        /* x and z without y: y stays (the Modbus backend writes two separate runs). */
        move_ok(s, 5, 0, 3, IMP_STAGE_XYZ);
        move_ok(s, 12, 77, 9, IMP_STAGE_X | IMP_STAGE_Z);
        double y[3];
        imp_emu_stage_position(emu, y);
        CHECK_NEAR(y[1], 0, TOL_MM);
        CHECK_NEAR(y[2], 9, TOL_MM);
        /* x and y only: z stays where it was. */
        move_ok(s, 0, 0, 7, IMP_STAGE_XYZ);
        move_ok(s, 30, 15, 99, IMP_STAGE_XY);
        double truth[3];
        imp_emu_stage_position(emu, truth);
        CHECK_NEAR(truth[2], 7, TOL_MM);
}

static void test_soft_limits(struct imp_stage *s, struct imp_emu_stage *emu) {
        struct imp_stage_config c, old;
        CHECK_OK(imp_stage_get_config(s, &old));
        c = old;
        c.min_mm[0] = 5;
        c.max_mm[0] = 100;
        CHECK_OK(imp_stage_configure(s, &c));
        unsigned n0 = imp_emu_stage_n_moves(emu);
        double t[3] = { 100.5, 10, 0 };
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -ERANGE);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "x outside the soft limits [5.000, 100.000] mm");
        t[0] = 4;
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -ERANGE);
        t[0] = NAN;
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -EINVAL);
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), n0);
        move_ok(s, 100, 10, 0, IMP_STAGE_XY);
        CHECK_OK(imp_stage_configure(s, &old));
}

/* Clear, then the position is unknown: -ESTALE until homed again. */
static void recover_lost(struct imp_stage *s, struct imp_emu_stage *emu) {
        struct imp_stage_status st;
        CHECK_OK(imp_stage_clear_fault(s));
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK_INT_EQ(st.fault, IMP_STAGE_FAULT_NONE);
        CHECK(!(st.flags & IMP_STAGE_HOMED));
        double t[3] = { 20, 20, 0 };
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -ESTALE);
        home_ok(s, emu);
        move_ok(s, 20, 20, 0, IMP_STAGE_XY);
}

static void test_limit_switch(struct imp_stage *s, struct imp_emu_stage *emu, const struct stage_expect *x) {
        move_ok(s, 10, 10, 0, IMP_STAGE_XYZ);
        imp_emu_stage_limit_switch_at(emu, 0, 50);
        double t[3] = { 90, 30, 0 };
        struct imp_stage_status st = {};
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        CHECK_ERR(imp_stage_wait_settled(s, SETTLE_MS, &st), -EIO);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "hard limit switch hit");
        CHECK_INT_EQ(st.fault, IMP_STAGE_FAULT_LIMIT);
        CHECK_INT_EQ(st.fault_code, x->limit_code);
        CHECK(!(st.flags & IMP_STAGE_HOMED));
        double truth[3];
        imp_emu_stage_position(emu, truth);
        CHECK_NEAR(truth[0], 50, 0.01);         /* stopped at the switch, not at 90 */
        /* Refused while latched, nothing sent. */
        unsigned n0 = imp_emu_stage_n_moves(emu);
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -EIO);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "clear it first");
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), n0);
        /* After the clear the switch is still pressed: reported as such. */
        CHECK_OK(imp_stage_clear_fault(s));
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK_INT_EQ(st.limit_mask, IMP_STAGE_X);
        CHECK_NEAR(st.position_mm[0], 50, TOL_MM);
        imp_emu_stage_limit_switch_at(emu, 0, NAN);
        recover_lost(s, emu);
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK_INT_EQ(st.limit_mask, 0);
}

/* An alarm raised while a move runs. */
static void test_alarm(struct imp_stage *s, struct imp_emu_stage *emu, const struct stage_expect *x) {
        move_ok(s, 10, 10, 0, IMP_STAGE_XYZ);
        double t[3] = { 150, 100, 0 };
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        usleep(100000);
        imp_emu_stage_alarm(emu, x->alarm_code);
        struct imp_stage_status st = {};
        CHECK_ERR(imp_stage_wait_settled(s, SETTLE_MS, &st), -EIO);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), imp_stage_fault_name(x->alarm_fault));
        CHECK_INT_EQ(st.fault, x->alarm_fault);
        CHECK_INT_EQ(st.fault_code, x->alarm_code);
        double truth[3];
        imp_emu_stage_position(emu, truth);
        CHECK(truth[0] > 10.5 && truth[0] < 149);       /* stopped on the way */
        if (x->alarm_loses_position) {
                recover_lost(s, emu);
                return;
        }
        CHECK_OK(imp_stage_clear_fault(s));
        move_ok(s, 20, 20, 0, IMP_STAGE_XY);
}

static void test_lost_position(struct imp_stage *s, struct imp_emu_stage *emu) {
        move_ok(s, 30, 30, 5, IMP_STAGE_XYZ);
        imp_emu_stage_lose_position(emu);
        struct imp_stage_status st;
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK_INT_EQ(st.fault, IMP_STAGE_FAULT_LOST_POSITION);
        CHECK(!(st.flags & IMP_STAGE_HOMED));
        double t[3] = { 40, 40, 0 };
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -EIO);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "position lost");
        CHECK_ERR(imp_stage_home(s), -EIO);      /* homing too waits for the clear */
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "home: position lost latched");
        recover_lost(s, emu);
}

/* The controller stops answering: bounded -ETIMEDOUT, then usable once it answers. */
static void test_timeout(struct imp_stage *s, struct imp_emu_stage *emu, double max_s) {
        move_ok(s, 10, 10, 0, IMP_STAGE_XY);
        imp_emu_stage_mute(emu, true);
        struct imp_stage_status st;
        double t0 = stage_now_s();
        CHECK_ERR(imp_stage_get_status(s, &st), -ETIMEDOUT);
        CHECK_LE(stage_now_s() - t0, max_s);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "reading status");
        double t[3] = { 30, 10, 0 };
        unsigned n0 = imp_emu_stage_n_moves(emu);
        CHECK_ERR(imp_stage_move_to(s, t, IMP_STAGE_XY), -ETIMEDOUT);
        imp_emu_stage_mute(emu, false);
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), n0);
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK(st.flags & IMP_STAGE_HOMED);      /* a silent controller did not lose the position */
        move_ok(s, 30, 10, 0, IMP_STAGE_XY);
}

/* A stalled axis: the wait ends with a clear error, the stage is stopped, position known. */
static void test_never_settles(struct imp_stage *s, struct imp_emu_stage *emu) {
        move_ok(s, 0, 0, 0, IMP_STAGE_XYZ);
        imp_emu_stage_stall(emu, true);
        double t[3] = { 40, 0, 0 };
        struct imp_stage_status st = {};
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        double t0 = stage_now_s();
        CHECK_ERR(imp_stage_wait_settled(s, 1000, &st), -ETIMEDOUT);
        CHECK_GE(stage_now_s() - t0, 1.0);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "not settled after 1000 ms (still moving)");
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "target (x 40.000,y 0.000) mm");
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK(!(st.flags & IMP_STAGE_MOVING));
        CHECK(st.flags & IMP_STAGE_HELD);
        CHECK(st.flags & IMP_STAGE_HOMED);
        CHECK_INT_EQ(st.fault, IMP_STAGE_FAULT_NONE);
        CHECK_NEAR(st.position_mm[0], 36, TOL_MM);      /* the stall point, 90 % of the way */
        imp_emu_stage_stall(emu, false);
        move_ok(s, 40, 0, 0, IMP_STAGE_XY);
}

/* The controller says "in position" short of the target: the read-back decides. */
static void test_off_target(struct imp_stage *s, struct imp_emu_stage *emu) {
        move_ok(s, 10, 10, 0, IMP_STAGE_XYZ);
        imp_emu_stage_arrive_short(emu, 0.05);
        double t[3] = { 20, 10, 0 };
        struct imp_stage_status st = {};
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        CHECK_ERR(imp_stage_wait_settled(s, 1000, &st), -ETIMEDOUT);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "(idle off target), stopped at (x 19.950,y 10.000,z 0.000) mm");
        CHECK(st.flags & IMP_STAGE_IN_POSITION);
        CHECK_NEAR(st.position_mm[0], 19.95, TOL_MM);
        imp_emu_stage_arrive_short(emu, 0);
        move_ok(s, 30, 10, 0, IMP_STAGE_XY);
}

static void test_soft_stop(struct imp_stage *s, struct imp_emu_stage *emu) {
        move_ok(s, 0, 0, 0, IMP_STAGE_XYZ);
        double t[3] = { 200, 0, 0 };
        CHECK_OK(imp_stage_move_to(s, t, IMP_STAGE_XY));
        /* One move at a time. */
        unsigned n0 = imp_emu_stage_n_moves(emu);
        double u[3] = { 100, 50, 0 };
        CHECK_ERR(imp_stage_move_to(s, u, IMP_STAGE_XY), -EBUSY);
        CHECK_STR_CONTAINS(imp_stage_last_error(s), "still moving");
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), n0);
        usleep(200000);
        CHECK_OK(imp_stage_soft_stop(s));
        double a[3], b[3];
        imp_emu_stage_position(emu, a);
        usleep(100000);
        imp_emu_stage_position(emu, b);
        CHECK(a[0] > 1 && a[0] < 199);
        CHECK_NEAR(a[0], b[0], 1e-9);           /* stopped, and stays */
        struct imp_stage_status st;
        CHECK_OK(imp_stage_get_status(s, &st));
        CHECK(st.flags & IMP_STAGE_HOMED);
        CHECK(st.flags & IMP_STAGE_HELD);
        CHECK_NEAR(st.position_mm[0], a[0], TOL_MM);
        move_ok(s, 5, 5, 0, IMP_STAGE_XY);
}

/* Closing the handle while the gantry moves stops it: nothing runs on unattended. */
static void test_close_stops(struct imp_stage **s, struct imp_emu_stage *emu) {
        move_ok(*s, 0, 0, 0, IMP_STAGE_XY);
        double t[3] = { 200, 0, 0 };
        CHECK_OK(imp_stage_move_to(*s, t, IMP_STAGE_XY));
        usleep(100000);
        imp_stage_close(TAKE_PTR(*s));
        double a[3], b[3];
        imp_emu_stage_position(emu, a);
        usleep(200000);
        imp_emu_stage_position(emu, b);
        CHECK(a[0] > 1 && a[0] < 150);
        CHECK_NEAR(b[0], a[0], 1e-9);
}

static void run_stage_scenarios(struct imp_stage *s, struct imp_emu_stage *emu, const struct imp_emu_stage_config *cfg,
                                const struct stage_expect *x, double timeout_max_s) {
        test_open(s, cfg);
        test_unhomed(s, emu);
        test_moves(s, emu);
        test_soft_limits(s, emu);
        test_limit_switch(s, emu, x);
        test_alarm(s, emu, x);
        test_lost_position(s, emu);
        test_timeout(s, emu, timeout_max_s);
        test_never_settles(s, emu);
        test_off_target(s, emu);
        test_soft_stop(s, emu);
}
