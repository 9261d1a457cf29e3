/* The "modbus" stage backend through the imp_stage wrapper against the emulated stage
 * controller (sim/emu/emu-stage-modbus.c, docs/stage-registers.md) on loopback: moves and
 * read-back, soft limits, and the faults of stage-scenarios.h. */
#include "emu.h"
#include "unit/stage-scenarios.h"

#define PORT 15861
#define PORT_DOME 15862
#define TIMEOUT_MS 100
#define RETRIES 2

/* A request lost on the way is sent again by the link (docs/dome-registers.md, "Client
 * policy"): the move happens once, and nothing reaches the caller. */
static void test_lost_request(struct imp_stage *s, struct imp_emu_stage *emu) {
        move_ok(s, 10, 10, 0, IMP_STAGE_XY);
        unsigned moves = imp_emu_stage_n_moves(emu);
        imp_emu_stage_lose_requests(emu, 1);
        move_ok(s, 20, 10, 0, IMP_STAGE_XY);
        CHECK_INT_EQ(imp_emu_stage_n_moves(emu), moves + 1);
        CHECK_STR_EQ(imp_stage_last_error(s), "");
}

/* Something else answers Modbus there (the dome controller): not taken for a stage. */
static void test_not_a_stage(void) {
        struct imp_emu_modbus_config dome = { .port = PORT_DOME, .n_lights = 4, .n_axes = 1 };
        _cleanup_(imp_emu_modbus_freep) struct imp_emu_modbus *emu = NULL;
        int r = imp_emu_modbus_new(&dome, NULL, &emu);
        if (r == -EADDRINUSE)
                return;
        CHECK_OK(r);
        char addr[64];
        snprintf(addr, sizeof addr, "127.0.0.1:%d;timeout_ms=%d", PORT_DOME, TIMEOUT_MS);
        struct imp_stage *s = NULL;
        CHECK_ERR(imp_stage_open("modbus", addr, 0, &s), -ENODEV);
        CHECK(s == NULL);
}

int main(void) {
        struct imp_emu_stage_config cfg = { .port = PORT, .travel_mm = { 400, 300, 50 } };
        _cleanup_(imp_emu_stage_freep) struct imp_emu_stage *emu = NULL;
        int r = imp_emu_stage_modbus_new(&cfg, &emu);
        if (r == -EADDRINUSE)
                TEST_SKIP("TCP port %d on 127.0.0.1 is busy", PORT);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        _cleanup_(imp_stage_closep) struct imp_stage *s = NULL;
        char addr[96];
        snprintf(addr, sizeof addr, "127.0.0.1:%d;timeout_ms=%d;retries=%d", PORT, TIMEOUT_MS, RETRIES);
        r = imp_stage_open("modbus", addr, 0, &s);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        CHECK_STR_EQ(imp_stage_backend_name(s), "modbus");
        /* Modbus faults: 1 limit, 3 drive alarm (position kept). */
        const struct stage_expect x = {
                .alarm_code = 3, .alarm_fault = IMP_STAGE_FAULT_ALARM, .alarm_loses_position = false,
                .limit_code = 1,
        };
        /* A silent controller: RETRIES attempts of TIMEOUT_MS plus a 10 ms backoff. */
        run_stage_scenarios(s, emu, &cfg, &x, 1.0);
        test_lost_request(s, emu);
        test_not_a_stage();
        test_close_stops(&s, emu);
        return TEST_DONE();
}
