/* The emulated GigE camera of the Aravis driver tests (test-drv-aravis, -replug, -takeover):
 * a rig of n_lights lights and the fake camera at address (GVCP, UDP port 3956) with the
 * default fill. Exits 77 (skipped) when another camera holds the port, before or while the
 * emulator binds it. Returns 0, or a negative errno with a test failure recorded (the caller
 * then ends with TEST_DONE()). */
#pragma once
#include <errno.h>
#include "emu.h"
#include "unit/test.h"

static inline int gige_emu_setup(const char *address, const char *serial, unsigned n_lights,
                                 struct imp_emu_rig **ret_rig, struct imp_emu_gige **ret_emu) {
        if (!imp_emu_gige_port_free(address))
                TEST_SKIP("UDP %s:3956 (GVCP) is taken by another camera", address);
        int r = imp_emu_rig_new(n_lights, ret_rig);
        CHECK_OK(r);
        if (r < 0)
                return r;
        r = imp_emu_gige_new(address, serial, *ret_rig, NULL, NULL, ret_emu);
        if (r == -EADDRINUSE)
                TEST_SKIP("UDP %s:3956 (GVCP) is taken by another camera", address);
        CHECK_OK(r);
        return r;
}
