/* The "modbus" dome backend over Modbus RTU: the emulated controller serves RTU on a
 * pseudo-terminal and the real backend opens its slave side as a serial port through
 * modbus_new_rtu. Lights set and read back, state, an exception answer, a timeout (the
 * late answers flushed so the next call works), a wrong unit id, and the address syntax. */
#include <modbus.h>
#include <time.h>
#include "dome.h"
#include "emu.h"
#include "unit/test.h"

#define TIMEOUT_MS 100
#define RETRIES 3
#define UNIT 7

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* The emulator answers, then applies the write to the rig, holding its lock throughout:
 * taking that lock once (any getter) orders the rig read after the apply. */
static int lit_light(struct imp_emu_modbus *emu, struct imp_emu_rig *rig) {
        (void) imp_emu_modbus_n_requests(emu);
        return imp_emu_rig_lit_light(rig);
}

static void test_lights(struct imp_dome *d, struct imp_emu_modbus *emu, struct imp_emu_rig *rig) {
        struct imp_dome_info info;
        CHECK_OK(imp_dome_get_info(d, &info));
        CHECK_INT_EQ(info.n_lights, 8);
        CHECK_INT_EQ(info.n_axes, 1);
        CHECK_STR_CONTAINS(info.model, "rtu:/dev/");
        CHECK_OK(imp_dome_set_light(d, 3, 1000, 0));
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 3), 1000);
        CHECK_INT_EQ(lit_light(emu, rig), 3);
        CHECK_OK(imp_dome_set_light(d, 5, 250, 0));
        struct imp_dome_state st;
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_lights, 8);
        CHECK_INT_EQ(st.n_on, 1);
        CHECK_INT_EQ(st.level_permille[5], 250);
        CHECK_INT_EQ(st.level_permille[3], 0);
        CHECK_OK(imp_dome_all_off(d));
        CHECK_INT_EQ(lit_light(emu, rig), -1);
        CHECK_STR_EQ(imp_dome_last_error(d), "");
}

static void test_exception(struct imp_dome *d, struct imp_emu_modbus *emu) {
        imp_emu_modbus_fail_nth(emu, 1, MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE);
        uint64_t n0 = imp_emu_modbus_n_requests(emu);
        CHECK_ERR(imp_dome_set_light(d, 4, 1000, 0), -EIO);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "0x0104");
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "exception");
        CHECK_INT_EQ(imp_emu_modbus_light(emu, 4), 0);
        /* Not retried; the wrapper's lights-off follows it. */
        CHECK_INT_EQ(imp_emu_modbus_n_requests(emu) - n0, 2);
        CHECK(imp_dome_lights_known(d));
}

/* A serial line has no transaction id: an answer later than the timeout is taken as the
 * answer to an identical retry (and truly is one: the same write was executed). So the
 * controller is made slower than all the attempts together (3 × 100 ms + 30 ms backoff). */
#define LATE_MS (5 * TIMEOUT_MS)

static void test_timeout(struct imp_dome *d, struct imp_emu_modbus *emu, struct imp_emu_rig *rig) {
        CHECK_OK(imp_dome_set_light(d, 1, 1000, 0));
        imp_emu_modbus_delay(emu, 1000, LATE_MS);
        double t0 = now_s();
        int r = imp_dome_set_light(d, 2, 1000, 0);
        double dt = now_s() - t0;
        CHECK_ERR(r, -ETIMEDOUT);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "attempt 3 of 3");
        CHECK_GE(dt, 2 * RETRIES * TIMEOUT_MS / 1000.0 * 0.9);
        CHECK_LE(dt, 2.0);
        CHECK(!imp_dome_lights_known(d));
        imp_emu_modbus_delay(emu, 0, 0);
        /* The server still answers the queued requests, late: the line carries those
         * answers after the client gave up. Reopening flushes them, so the next calls
         * read their own answers, not stale ones. */
        usleep(2 * RETRIES * LATE_MS * 1000);
        CHECK_OK(imp_dome_all_off(d));
        CHECK(imp_dome_lights_known(d));
        CHECK_INT_EQ(lit_light(emu, rig), -1);
        CHECK_OK(imp_dome_set_light(d, 6, 1000, 0));
        struct imp_dome_state st;
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_on, 1);
        CHECK_INT_EQ(st.level_permille[6], 1000);
        CHECK_OK(imp_dome_all_off(d));
}

/* Nobody answers a frame for another unit: a timeout, not a wrong answer. */
static void test_wrong_unit(const char *dev) {
        char addr[160];
        snprintf(addr, sizeof addr, "rtu:%s;unit=%d;timeout_ms=%d;retries=1", dev, UNIT + 1, TIMEOUT_MS);
        struct imp_dome *d = NULL;
        double t0 = now_s();
        CHECK_ERR(imp_dome_open("modbus", addr, 0, &d), -ETIMEDOUT);
        CHECK_LE(now_s() - t0, 1.0);
        CHECK(!d);
}

static void test_syntax(const char *dev) {
        /* after "rtu:DEV" (NULL: "rtu:" alone, no device) */
        static const char *const bad[] = {
                NULL, ";parity=X", ";parity=EE", ";baud=0", ";data_bits=9", ";stop_bits=3", ";unit=248",
        };
        for (size_t i = 0; i < ARRAY_SIZE(bad); i++) {
                char addr[160];
                if (bad[i])
                        snprintf(addr, sizeof addr, "rtu:%s%s", dev, bad[i]);
                else
                        snprintf(addr, sizeof addr, "rtu:");
                struct imp_dome *d = NULL;
                CHECK_MSG(imp_dome_open("modbus", addr, 0, &d) == -EINVAL, "\"%s\" accepted", addr);
                imp_dome_close(d);
        }
        struct imp_dome *d = NULL;
        CHECK_ERR(imp_dome_open("modbus", "rtu:/nonexistent/ttyX;retries=1", 0, &d), -ENOENT);
        imp_dome_close(d);
}

int main(void) {
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        _cleanup_(imp_emu_modbus_freep) struct imp_emu_modbus *emu = NULL;
        CHECK_OK(imp_emu_rig_new(8, &rig));
        struct imp_emu_modbus_config cfg = { .rtu = true, .rtu_unit = UNIT, .n_lights = 8, .n_axes = 1 };
        int r = imp_emu_modbus_new(&cfg, rig, &emu);
        if (r == -ENOENT || r == -EACCES)
                TEST_SKIP("no pseudo-terminals here (%s)", strerror(-r));
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        const char *dev = imp_emu_modbus_rtu_device(emu);
        CHECK(dev && strncmp(dev, "/dev/", 5) == 0);
        _cleanup_(imp_dome_closep) struct imp_dome *d = NULL;
        char addr[160];
        snprintf(addr, sizeof addr, "rtu:%s;baud=115200;parity=N;data_bits=8;stop_bits=2;unit=%d;"
                 "timeout_ms=%d;retries=%d", dev, UNIT, TIMEOUT_MS, RETRIES);
        CHECK_OK(imp_dome_open("modbus", addr, 0, &d));
        if (!d)
                return TEST_DONE();
        test_lights(d, emu, rig);
        test_exception(d, emu);
        test_timeout(d, emu, rig);
        test_wrong_unit(dev);
        test_syntax(dev);
        return TEST_DONE();
}
