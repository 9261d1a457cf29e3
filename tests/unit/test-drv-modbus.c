/* The "modbus" dome backend against the emulated controller (sim/emu/emu-modbus.c) on a
 * loopback port: lights (one at a time unless asked), actuator moves that take real time,
 * homing, axis faults and timeouts, and refusal of bad arguments. */
#include <time.h>
#include "dome.h"
#include "emu.h"
#include "unit/test.h"

#define PORT 15821
#define SPEED_MM_PER_S 50

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void test_lights(struct imp_dome *d, struct imp_emu_modbus *emu, struct imp_emu_rig *rig) {
        struct imp_dome_info info;
        CHECK_OK(imp_dome_get_info(d, &info));
        CHECK_INT_EQ(info.n_lights, 16);
        CHECK_INT_EQ(info.n_axes, 2);

        CHECK_OK(imp_dome_set_light(d, 3, 1000, 0));
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 3), 1000);
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), 3);
        CHECK_OK(imp_dome_set_light(d, 5, 500, 0));
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 3), 0);
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 5), 500);
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(rig), 1);

        CHECK_OK(imp_dome_set_light(d, 7, 250, IMP_DOME_LIGHT_MULTI));
        struct imp_dome_state st;
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_on, 2);
        CHECK_INT_EQ(st.level_permille[5], 500);
        CHECK_INT_EQ(st.level_permille[7], 250);
        /* Without the flag, both go off before the next one comes on. */
        CHECK_OK(imp_dome_set_light(d, 0, 1000, 0));
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_on, 1);
        CHECK_INT_EQ(st.level_permille[0], 1000);

        CHECK_OK(imp_dome_all_off(d));
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_on, 0);
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), -1);

        CHECK_ERR(imp_dome_set_light(d, 16, 1000, 0), -EINVAL);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "light 16");
        CHECK_ERR(imp_dome_set_light(d, 1, 1001, 0), -EINVAL);
}

static void test_axes(struct imp_dome *d) {
        struct imp_axis_status s;
        double t0 = now_s();
        CHECK_OK(imp_dome_move_to(d, 0, 20000, 5000));
        double dt = now_s() - t0;
        /* 20 mm at 50 mm/s: 0.4 s; the emulator moves in real time. */
        CHECK_GE(dt, 0.35);
        CHECK_LE(dt, 2.0);
        CHECK_OK(imp_dome_get_axis_status(d, 0, &s));
        CHECK_INT_EQ(s.position_um, 20000);
        CHECK_INT_EQ(s.target_um, 20000);
        CHECK(s.flags & IMP_AXIS_IN_POSITION);
        CHECK(!(s.flags & (IMP_AXIS_MOVING | IMP_AXIS_FAULT)));

        /* The other axis did not move. */
        CHECK_OK(imp_dome_get_axis_status(d, 1, &s));
        CHECK_INT_EQ(s.position_um, 0);

        CHECK_OK(imp_dome_home(d, 0, 5000));
        CHECK_OK(imp_dome_get_axis_status(d, 0, &s));
        CHECK_INT_EQ(s.position_um, 0);
        CHECK(s.flags & IMP_AXIS_HOMED);

        /* Beyond travel: the controller latches fault 1 and does not move. */
        CHECK_ERR(imp_dome_move_to(d, 1, 200000, 2000), -EIO);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "fault code 1");
        CHECK_OK(imp_dome_get_axis_status(d, 1, &s));
        CHECK(s.flags & IMP_AXIS_FAULT);
        CHECK_INT_EQ(s.fault_code, 1);
        CHECK_INT_EQ(s.position_um, 0);
        CHECK_OK(imp_dome_clear_fault(d, 1));
        CHECK_OK(imp_dome_get_axis_status(d, 1, &s));
        CHECK(!(s.flags & IMP_AXIS_FAULT));

        /* Too short a timeout: -ETIMEDOUT and the axis is stopped where it was. */
        t0 = now_s();
        CHECK_ERR(imp_dome_move_to(d, 1, 100000, 100), -ETIMEDOUT);
        CHECK_LE(now_s() - t0, 0.5);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "not in position");
        CHECK_OK(imp_dome_get_axis_status(d, 1, &s));
        CHECK(!(s.flags & IMP_AXIS_MOVING));
        int32_t stopped_at = s.position_um;
        CHECK(stopped_at > 0 && stopped_at < 100000);
        usleep(100000);
        CHECK_OK(imp_dome_get_axis_status(d, 1, &s));
        CHECK_INT_EQ(s.position_um, stopped_at);
        CHECK_OK(imp_dome_clear_fault(d, 1));
        CHECK_OK(imp_dome_home(d, 1, 5000));

        CHECK_ERR(imp_dome_move_to(d, 2, 0, 100), -EINVAL);
}

int main(void) {
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        _cleanup_(imp_emu_modbus_freep) struct imp_emu_modbus *emu = NULL;
        CHECK_OK(imp_emu_rig_new(16, &rig));
        struct imp_emu_modbus_config cfg = { .port = PORT, .n_lights = 16, .n_axes = 2,
                                             .speed_mm_per_s = SPEED_MM_PER_S, .travel_um = 100000 };
        int r = imp_emu_modbus_new(&cfg, rig, &emu);
        if (r == -EADDRINUSE)
                TEST_SKIP("TCP port %d on 127.0.0.1 is busy", PORT);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();

        CHECK_ERR(imp_dome_open("nonesuch", "127.0.0.1:1", 100, &(struct imp_dome *){ NULL }), -ENOENT);
        _cleanup_(imp_dome_closep) struct imp_dome *d = NULL;
        char addr[64];
        snprintf(addr, sizeof addr, "127.0.0.1:%d;timeout_ms=200;retries=3", PORT);
        CHECK_OK(imp_dome_open("modbus", addr, 0, &d));
        if (!d)
                return TEST_DONE();
        CHECK_STR_EQ(imp_dome_backend_name(d), "modbus");
        test_lights(d, emu, rig);
        test_axes(d);

        /* Nobody listening: open fails within the bounded retries. */
        double t0 = now_s();
        struct imp_dome *none = NULL;
        CHECK(imp_dome_open("modbus", "127.0.0.1:1;timeout_ms=100;retries=2", 0, &none) < 0);
        CHECK(none == NULL);
        CHECK_LE(now_s() - t0, 2.0);
        return TEST_DONE();
}
