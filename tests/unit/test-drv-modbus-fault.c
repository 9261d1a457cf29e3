/* Fault injection between the "modbus" dome backend and the emulated controller: a Modbus
 * exception, answers later than the response timeout, a dropped connection, a controller
 * that goes away and comes back. Each time: the error the caller sees, and the lights. */
#include <modbus.h>
#include <time.h>
#include "dome.h"
#include "emu.h"
#include "unit/test.h"

#define PORT 15822
#define TIMEOUT_MS 100
#define RETRIES 3

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + ts.tv_nsec * 1e-9;
}

static struct imp_emu_modbus_config cfg = { .port = PORT, .n_lights = 8, .n_axes = 1 };

static void test_exception(struct imp_dome *d, struct imp_emu_modbus *emu, struct imp_emu_rig *rig) {
        /* The request that switches light 4 on is refused. */
        imp_emu_modbus_fail_nth(emu, 1, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
        CHECK_ERR(imp_dome_set_light(d, 4, 1000, 0), -EIO);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "set light 4");
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "0x0104");
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "exception");
        CHECK(imp_dome_lights_known(d));
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), -1);

        /* Light 2 is on; switching it off works, switching 4 on fails: all off after. */
        CHECK_OK(imp_dome_set_light(d, 2, 1000, 0));
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 2), 1000);
        imp_emu_modbus_fail_nth(emu, 2, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
        CHECK_ERR(imp_dome_set_light(d, 4, 1000, 0), -EIO);
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 2), 0);
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 4), 0);
        CHECK(imp_dome_lights_known(d));
        struct imp_dome_state st;
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_on, 0);
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(rig), 1);
}

static void test_timeout(struct imp_dome *d, struct imp_emu_modbus *emu, struct imp_emu_rig *rig) {
        CHECK_OK(imp_dome_set_light(d, 1, 1000, 0));
        unsigned conn0 = imp_emu_modbus_n_connections(emu);
        imp_emu_modbus_delay(emu, 1000, 3 * TIMEOUT_MS);
        double t0 = now_s();
        int r = imp_dome_set_light(d, 3, 1000, 0);
        double dt = now_s() - t0;
        CHECK_ERR(r, -ETIMEDOUT);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "attempt 3 of 3");
        /* The call and the wrapper's lights-off both give up after RETRIES attempts of
         * TIMEOUT_MS plus backoff (10 + 20 ms): about 0.7 s, far from unbounded. */
        CHECK_GE(dt, 2 * RETRIES * TIMEOUT_MS / 1000.0 * 0.9);
        CHECK_LE(dt, 2.0);
        /* Nothing could be switched off: the wrapper says so instead of pretending. */
        CHECK(!imp_dome_lights_known(d));
        imp_emu_modbus_delay(emu, 0, 0);
        usleep(4 * 3 * TIMEOUT_MS * 1000);     /* let the server finish the late answers */
        unsigned reconnects = imp_emu_modbus_n_connections(emu) - conn0;
        CHECK_INT_GE(reconnects, RETRIES);
        CHECK(reconnects <= 2 * RETRIES);
        /* The controller answers again: the next call reconnects and works. */
        CHECK_OK(imp_dome_all_off(d));
        CHECK(imp_dome_lights_known(d));
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), -1);
}

static void test_drop(struct imp_dome *d, struct imp_emu_modbus *emu) {
        unsigned conn0 = imp_emu_modbus_n_connections(emu);
        imp_emu_modbus_drop_nth(emu, 1);
        CHECK_OK(imp_dome_set_light(d, 6, 1000, 0));
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 6), 1000);
        CHECK_INT_EQ(imp_emu_modbus_n_connections(emu) - conn0, 1);
        CHECK_STR_EQ(imp_dome_last_error(d), "");
}

static void test_restart(struct imp_dome *d, struct imp_emu_modbus **emu, struct imp_emu_rig *rig) {
        imp_emu_modbus_free(*emu);
        *emu = NULL;
        double t0 = now_s();
        CHECK(imp_dome_set_light(d, 5, 1000, 0) < 0);
        CHECK_LE(now_s() - t0, 2.0);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "connect 127.0.0.1");
        CHECK(!imp_dome_lights_known(d));
        CHECK_OK(imp_emu_modbus_new(&cfg, rig, emu));
        if (!*emu)
                return;
        CHECK_OK(imp_dome_set_light(d, 5, 1000, 0));
        CHECK(imp_dome_lights_known(d));
        CHECK_INT_EQ(imp_emu_modbus_light(*emu, 5), 1000);
}

int main(void) {
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        _cleanup_(imp_emu_modbus_freep) struct imp_emu_modbus *emu = NULL;
        CHECK_OK(imp_emu_rig_new(8, &rig));
        int r = imp_emu_modbus_new(&cfg, rig, &emu);
        if (r == -EADDRINUSE)
                TEST_SKIP("TCP port %d on 127.0.0.1 is busy", PORT);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        _cleanup_(imp_dome_closep) struct imp_dome *d = NULL;
        char addr[64];
        snprintf(addr, sizeof addr, "127.0.0.1:%d;timeout_ms=%d;retries=%d", PORT, TIMEOUT_MS, RETRIES);
        CHECK_OK(imp_dome_open("modbus", addr, 0, &d));
        if (!d)
                return TEST_DONE();
        test_exception(d, emu, rig);
        test_timeout(d, emu, rig);
        test_drop(d, emu);
        test_restart(d, &emu, rig);
        return TEST_DONE();
}
