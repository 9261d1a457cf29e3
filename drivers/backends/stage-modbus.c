/* Stage backend "modbus": a stepper/servo gantry controller over Modbus TCP or RTU with
 * libmodbus, register map in docs/stage-registers.md, through the shared link of
 * modbus-link.h (response timeout per request, bounded retries, reconnect after errors). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include "modbus-link.h"
#include "stage.h"

#define STAGE_REG_MAGIC         0x0000  /* RO, STAGE_MAGIC */
#define STAGE_REG_VERSION       0x0001  /* RO, map version */
#define STAGE_REG_N_AXES        0x0002  /* RO, 2 or 3 */
#define STAGE_REG_SPEED         0x0003  /* RW, mm/s, 1..1000 */
#define STAGE_REG_COMMAND       0x0004  /* WO, STAGE_CMD_* */
#define STAGE_REG_STATUS        0x0008  /* RO, STAGE_ST_* bits; first of the status block */
#define STAGE_REG_FAULT         0x0009  /* RO, STAGE_FAULT_* code */
#define STAGE_REG_FAULT_AXIS    0x000A  /* RO, axis or 0xFFFF */
#define STAGE_REG_LIMITS        0x000B  /* RO, bit a = limit switch of axis a pressed */
#define STAGE_REG_POSITION_UM(a) (0x000C + 2 * (a))     /* RO, µm, int32 high word first */
#define STAGE_REG_TARGET_UM(a)  (0x0012 + 2 * (a))      /* RW, µm, int32 */
#define STAGE_REG_TRAVEL_UM(a)  (0x0018 + 2 * (a))      /* RO, µm, int32 */
#define STAGE_STATUS_BLOCK      16      /* registers 0x0008..0x0017 */
#define STAGE_MAGIC             0x5354
#define STAGE_MAP_VERSION       1
#define STAGE_SPEED_MAX_MM_S    1000
#define STAGE_CMD_MOVE          1
#define STAGE_CMD_HOME          2
#define STAGE_CMD_STOP          3
#define STAGE_CMD_CLEAR_FAULT   4
#define STAGE_ST_MOVING         (1u << 0)
#define STAGE_ST_HOMING         (1u << 1)
#define STAGE_ST_HOMED          (1u << 2)
#define STAGE_ST_IN_POSITION    (1u << 3)
#define STAGE_ST_HELD           (1u << 4)
#define STAGE_ST_FAULT          (1u << 5)
#define UM_PER_MM               1000.0

struct stage_mb {
        struct mb_link link;
        unsigned n_axes;
        double travel_mm[IMP_STAGE_MAX_AXES];
};

static int32_t get32(const uint16_t *r) {
        return (int32_t) ((uint32_t) r[0] << 16 | r[1]);
}

static void put32(uint16_t *r, int32_t v) {
        r[0] = (uint16_t) ((uint32_t) v >> 16);
        r[1] = (uint16_t) v;
}

static void stage_mb_close(void *state) {
        struct stage_mb *m = state;
        if (!m)
                return;
        mb_link_close(&m->link);
        free(m);
}

static int stage_mb_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct stage_mb *m = calloc(1, sizeof *m);
        if (!m)
                return -ENOMEM;
        int r = mb_link_init(&m->link, address, timeout_ms);
        if (r < 0)
                goto fail;
        uint16_t id[3], travel[2 * IMP_STAGE_MAX_AXES];
        r = mb_link_xfer(&m->link, false, STAGE_REG_MAGIC, 3, id);
        if (r < 0)
                goto fail;
        r = -ENODEV;            /* something answers, but it is not our controller */
        if (id[0] != STAGE_MAGIC || id[1] != STAGE_MAP_VERSION || id[2] < 2 || id[2] > IMP_STAGE_MAX_AXES)
                goto fail;
        m->n_axes = id[2];
        r = mb_link_xfer(&m->link, false, STAGE_REG_TRAVEL_UM(0), 2 * (int) m->n_axes, travel);
        if (r < 0)
                goto fail;
        for (unsigned a = 0; a < m->n_axes; a++)
                m->travel_mm[a] = get32(&travel[2 * a]) / UM_PER_MM;
        *ret_state = m;
        return 0;
fail:
        stage_mb_close(m);
        return r;
}

static int stage_mb_get_info(void *state, struct imp_stage_info *ret) {
        struct stage_mb *m = state;
        snprintf(ret->model, sizeof ret->model, "modbus stage v%d at %.60s", STAGE_MAP_VERSION, m->link.host);
        ret->n_axes = m->n_axes;
        for (unsigned a = 0; a < IMP_STAGE_MAX_AXES; a++)
                ret->travel_mm[a] = a < m->n_axes ? m->travel_mm[a] : 0;
        return 0;
}

static int command(struct stage_mb *m, uint16_t cmd) {
        return mb_link_write1(&m->link, STAGE_REG_COMMAND, cmd);
}

/* Targets of the commanded axes in one request per contiguous run, then speed and the
 * move command together (the controller applies a write in address order). */
static int stage_mb_move_to(void *state, const double target_mm[IMP_STAGE_MAX_AXES], unsigned mask,
                            double speed_mm_s) {
        struct stage_mb *m = state;
        int r;
        for (unsigned a = 0; a < m->n_axes;) {
                if (!(mask & (1u << a))) {
                        a++;
                        continue;
                }
                unsigned first = a;
                uint16_t t[2 * IMP_STAGE_MAX_AXES];
                for (; a < m->n_axes && mask & (1u << a); a++)
                        put32(&t[2 * (a - first)], (int32_t) lround(target_mm[a] * UM_PER_MM));
                r = mb_link_xfer(&m->link, true, STAGE_REG_TARGET_UM(first), 2 * (int) (a - first), t);
                if (r < 0)
                        return r;
        }
        _Static_assert(STAGE_REG_COMMAND == STAGE_REG_SPEED + 1, "speed and command are adjacent");
        uint16_t go[2] = {
                (uint16_t) lround(IMP_CLAMP(speed_mm_s, 1.0, (double) STAGE_SPEED_MAX_MM_S)), STAGE_CMD_MOVE,
        };
        return mb_link_xfer(&m->link, true, STAGE_REG_SPEED, 2, go);
}

static int stage_mb_home(void *state) {
        return command(state, STAGE_CMD_HOME);
}

static int stage_mb_soft_stop(void *state) {
        return command(state, STAGE_CMD_STOP);
}

static int stage_mb_clear_fault(void *state) {
        return command(state, STAGE_CMD_CLEAR_FAULT);
}

/* The controller's fault code (docs/stage-registers.md) as the device class's fault. */
static enum imp_stage_fault fault_of_code(unsigned code) {
        switch (code) {
        case 0: return IMP_STAGE_FAULT_NONE;
        case 1: return IMP_STAGE_FAULT_LIMIT;
        case 2: return IMP_STAGE_FAULT_LOST_POSITION;
        case 4: return IMP_STAGE_FAULT_HOMING;
        case 5: return IMP_STAGE_FAULT_TRAVEL;
        case 6: return IMP_STAGE_FAULT_LOST_POSITION;   /* moved while not homed */
        default: return IMP_STAGE_FAULT_ALARM;          /* 3 drive alarm, and codes we do not know */
        }
}

static int stage_mb_get_status(void *state, struct imp_stage_status *ret) {
        struct stage_mb *m = state;
        uint16_t b[STAGE_STATUS_BLOCK];
        int r = mb_link_xfer(&m->link, false, STAGE_REG_STATUS, STAGE_STATUS_BLOCK, b);
        if (r < 0)
                return r;
        unsigned st = b[STAGE_REG_STATUS - STAGE_REG_STATUS];
        *ret = (struct imp_stage_status) {
                .flags = (st & STAGE_ST_MOVING ? IMP_STAGE_MOVING : 0) |
                         (st & STAGE_ST_HOMING ? IMP_STAGE_HOMING : 0) |
                         (st & STAGE_ST_HOMED ? IMP_STAGE_HOMED : 0) |
                         (st & STAGE_ST_IN_POSITION ? IMP_STAGE_IN_POSITION : 0) |
                         (st & STAGE_ST_HELD ? IMP_STAGE_HELD : 0),
                .fault_code = b[STAGE_REG_FAULT - STAGE_REG_STATUS],
                .limit_mask = b[STAGE_REG_LIMITS - STAGE_REG_STATUS] & ((1u << m->n_axes) - 1),
        };
        /* A fault bit without a code still refuses moves: report it as an alarm. */
        ret->fault = fault_of_code(ret->fault_code);
        if (st & STAGE_ST_FAULT && ret->fault == IMP_STAGE_FAULT_NONE)
                ret->fault = IMP_STAGE_FAULT_ALARM;
        for (unsigned a = 0; a < m->n_axes; a++)
                ret->position_mm[a] = get32(&b[STAGE_REG_POSITION_UM(a) - STAGE_REG_STATUS]) / UM_PER_MM;
        return 0;
}

static const char *stage_mb_last_error(void *state) {
        struct stage_mb *m = state;
        return m->link.error;
}

const struct imp_stage_ops imp_stage_modbus_ops = {
        .name = "modbus",
        .open = stage_mb_open,                  /* "host:port" or "rtu:device", options: modbus-link.h */
        .close = stage_mb_close,                /* closes the connection or serial port */
        .get_info = stage_mb_get_info,          /* axes and travel read from the controller at open */
        .move_to = stage_mb_move_to,            /* targets, then speed and move command in one write */
        .home = stage_mb_home,                  /* home command */
        .get_status = stage_mb_get_status,      /* one read of the 16-register status block */
        .soft_stop = stage_mb_soft_stop,        /* soft-stop command: decelerate, keep position */
        .clear_fault = stage_mb_clear_fault,    /* clear-fault command (homed is not restored) */
        .last_error = stage_mb_last_error,      /* register, attempt and libmodbus' reason */
};
