/* Dome backend "modbus": the LED driver and actuator controller over Modbus TCP or RTU
 * with libmodbus, register map in docs/dome-registers.md, through the shared link of
 * modbus-link.h (response timeout per request, bounded retries, reconnect after errors). */
#include <stdio.h>
#include <stdlib.h>
#include "dome.h"
#include "modbus-link.h"

#define DOME_REG_MAGIC          0x0000  /* RO, DOME_MAGIC */
#define DOME_REG_VERSION        0x0001  /* RO, map version */
#define DOME_REG_N_LIGHTS       0x0002  /* RO */
#define DOME_REG_N_AXES         0x0003  /* RO */
#define DOME_REG_STATUS         0x0004  /* RO, global status bits */
#define DOME_REG_COMMAND        0x0005  /* WO, DOME_CMD_* */
#define DOME_REG_LEVEL(i)       (0x0100 + (i))  /* RW, 0..1000 permille */
#define DOME_REG_AXIS(a)        (0x0200 + 0x10 * (a))   /* block of 16 per axis */
#define AXIS_TARGET_UM          0       /* RW, int32 high word first */
#define AXIS_POSITION_UM        2       /* RO, int32 */
#define AXIS_STATUS             4       /* RO, bits as enum imp_axis_flag */
#define AXIS_FAULT              5       /* RO, fault code */
#define AXIS_COMMAND            6       /* WO, AXIS_CMD_* */
#define AXIS_BLOCK_USED         10      /* registers read for a status */
#define DOME_MAGIC              0x494D
#define DOME_MAP_VERSION        1
#define DOME_CMD_ALL_OFF        1
#define AXIS_CMD_MOVE           1
#define AXIS_CMD_HOME           2
#define AXIS_CMD_STOP           3
#define AXIS_CMD_CLEAR_FAULT    4

struct dome_mb {
        struct mb_link link;
        unsigned n_lights, n_axes;
};

static int mb_xfer(struct dome_mb *m, bool write, int addr, int n, uint16_t *regs) {
        return mb_link_xfer(&m->link, write, addr, n, regs);
}

static int mb_write1(struct dome_mb *m, int addr, uint16_t v) {
        return mb_link_write1(&m->link, addr, v);
}

static void dome_mb_close(void *state) {
        struct dome_mb *m = state;
        if (!m)
                return;
        mb_link_close(&m->link);
        free(m);
}

static int dome_mb_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct dome_mb *m = calloc(1, sizeof *m);
        if (!m)
                return -ENOMEM;
        int r = mb_link_init(&m->link, address, timeout_ms);
        if (r < 0)
                goto fail;
        uint16_t id[4];
        r = mb_xfer(m, false, DOME_REG_MAGIC, 4, id);
        if (r < 0)
                goto fail;
        r = -ENODEV;            /* something answers, but it is not our controller */
        if (id[0] != DOME_MAGIC || id[1] != DOME_MAP_VERSION || id[2] == 0 ||
            id[2] > IMP_DOME_MAX_LIGHTS || id[3] > IMP_DOME_MAX_AXES)
                goto fail;
        m->n_lights = id[2];
        m->n_axes = id[3];
        *ret_state = m;
        return 0;
fail:
        dome_mb_close(m);
        return r;
}

static int dome_mb_get_info(void *state, struct imp_dome_info *ret) {
        struct dome_mb *m = state;
        snprintf(ret->model, sizeof ret->model, "modbus dome v%d at %.40s", DOME_MAP_VERSION, m->link.host);
        ret->n_lights = m->n_lights;
        ret->n_axes = m->n_axes;
        ret->dimmable = true;
        return 0;
}

static int dome_mb_set_light(void *state, unsigned id, unsigned level_permille) {
        struct dome_mb *m = state;
        if (id >= m->n_lights)
                return -EINVAL;
        return mb_write1(m, DOME_REG_LEVEL(id), (uint16_t) level_permille);
}

static int dome_mb_all_off(void *state) {
        return mb_write1(state, DOME_REG_COMMAND, DOME_CMD_ALL_OFF);
}

static int dome_mb_get_state(void *state, struct imp_dome_state *ret) {
        struct dome_mb *m = state;
        int r = mb_xfer(m, false, DOME_REG_LEVEL(0), (int) m->n_lights, ret->level_permille);
        if (r < 0)
                return r;
        ret->n_lights = m->n_lights;
        ret->n_on = 0;
        for (unsigned i = 0; i < m->n_lights; i++)
                ret->n_on += ret->level_permille[i] > 0;
        return 0;
}

static int axis_command(struct dome_mb *m, unsigned axis, uint16_t cmd) {
        if (axis >= m->n_axes)
                return -EINVAL;
        return mb_write1(m, DOME_REG_AXIS(axis) + AXIS_COMMAND, cmd);
}

static int dome_mb_move_to(void *state, unsigned axis, int32_t pos_um) {
        struct dome_mb *m = state;
        if (axis >= m->n_axes)
                return -EINVAL;
        uint16_t t[2] = { (uint16_t) ((uint32_t) pos_um >> 16), (uint16_t) pos_um };
        int r = mb_xfer(m, true, DOME_REG_AXIS(axis) + AXIS_TARGET_UM, 2, t);
        return r < 0 ? r : axis_command(m, axis, AXIS_CMD_MOVE);
}

static int dome_mb_home(void *state, unsigned axis) {
        return axis_command(state, axis, AXIS_CMD_HOME);
}

static int dome_mb_stop_axis(void *state, unsigned axis) {
        return axis_command(state, axis, AXIS_CMD_STOP);
}

static int dome_mb_clear_fault(void *state, unsigned axis) {
        return axis_command(state, axis, AXIS_CMD_CLEAR_FAULT);
}

static int dome_mb_get_axis_status(void *state, unsigned axis, struct imp_axis_status *ret) {
        struct dome_mb *m = state;
        if (axis >= m->n_axes)
                return -EINVAL;
        uint16_t b[AXIS_BLOCK_USED];
        int r = mb_xfer(m, false, DOME_REG_AXIS(axis), AXIS_BLOCK_USED, b);
        if (r < 0)
                return r;
        ret->target_um = (int32_t) ((uint32_t) b[AXIS_TARGET_UM] << 16 | b[AXIS_TARGET_UM + 1]);
        ret->position_um = (int32_t) ((uint32_t) b[AXIS_POSITION_UM] << 16 | b[AXIS_POSITION_UM + 1]);
        ret->flags = b[AXIS_STATUS] & (IMP_AXIS_MOVING | IMP_AXIS_HOMED | IMP_AXIS_FAULT | IMP_AXIS_IN_POSITION);
        ret->fault_code = b[AXIS_FAULT];
        return 0;
}

static const char *dome_mb_last_error(void *state) {
        struct dome_mb *m = state;
        return m->link.error;
}

const struct imp_dome_ops imp_dome_modbus_ops = {
        .name = "modbus",
        .open = dome_mb_open,                   /* "host:port" or "rtu:device", options: modbus-link.h */
        .close = dome_mb_close,                 /* closes the connection or serial port */
        .get_info = dome_mb_get_info,           /* counts read from the controller at open */
        .set_light = dome_mb_set_light,         /* one holding register per light */
        .all_off = dome_mb_all_off,             /* global command register, one request */
        .get_state = dome_mb_get_state,         /* reads every level register */
        .move_to = dome_mb_move_to,             /* target registers then move command */
        .home = dome_mb_home,                   /* home command */
        .stop_axis = dome_mb_stop_axis,         /* stop command */
        .clear_fault = dome_mb_clear_fault,     /* clear-fault command */
        .get_axis_status = dome_mb_get_axis_status, /* one read of the axis block */
        .last_error = dome_mb_last_error,       /* register, attempt and libmodbus' reason */
};
