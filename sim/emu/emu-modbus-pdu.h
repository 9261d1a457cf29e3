/* Request decoding shared by the Modbus emulators (emu-modbus.c, emu-stage-modbus.c). */
#pragma once
#include <modbus.h>
#include <stdint.h>
#include "macro.h"

/* A write request (0x06, 0x10) as (addr, n, values) from the ADU q whose header is hl
 * bytes long. Returns n, at most max; 0 for any other function. */
static inline unsigned emu_modbus_decode_write(const uint8_t *q, int hl, unsigned *addr, uint16_t *vals,
                                               unsigned max) {
        uint8_t fc = q[hl];
        *addr = (unsigned) q[hl + 1] << 8 | q[hl + 2];
        if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER) {
                vals[0] = (uint16_t) (q[hl + 3] << 8 | q[hl + 4]);
                return 1;
        }
        if (fc != MODBUS_FC_WRITE_MULTIPLE_REGISTERS)
                return 0;
        unsigned n = IMP_MIN((unsigned) q[hl + 3] << 8 | q[hl + 4], max);
        for (unsigned i = 0; i < n; i++)
                vals[i] = (uint16_t) (q[hl + 6 + 2 * i] << 8 | q[hl + 7 + 2 * i]);
        return n;
}
