/* Stage controller emulator over Modbus TCP: a libmodbus server thread on loopback that
 * implements docs/stage-registers.md (written from the document, independently of the
 * driver) on top of the shared motion model (emu-stage.c). */
#include <math.h>
#include <modbus.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <unistd.h>
#include "emu-modbus-pdu.h"
#include "emu-stage-internal.h"

/* Register map, version 1 (docs/stage-registers.md). */
#define REG_MAGIC       0x0000
#define REG_VERSION     0x0001
#define REG_N_AXES      0x0002
#define REG_SPEED       0x0003
#define REG_COMMAND     0x0004
#define REG_STATUS      0x0008
#define REG_FAULT       0x0009
#define REG_FAULT_AXIS  0x000A
#define REG_LIMITS      0x000B
#define REG_POSITION(a) (0x000C + 2 * (a))
#define REG_TARGET(a)   (0x0012 + 2 * (a))
#define REG_TRAVEL(a)   (0x0018 + 2 * (a))
#define N_REGISTERS     0x0020
#define MAGIC           0x5354
#define MAP_VERSION     1
#define SPEED_DEFAULT_MM_S 50
#define SPEED_MAX_MM_S  1000
#define NO_AXIS         0xFFFFu

#define ST_MOVING       (1u << 0)
#define ST_HOMING       (1u << 1)
#define ST_HOMED        (1u << 2)
#define ST_INPOS        (1u << 3)
#define ST_HELD         (1u << 4)
#define ST_FAULT        (1u << 5)

#define CMD_MOVE        1
#define CMD_HOME        2
#define CMD_STOP        3
#define CMD_CLEAR       4

#define FAULT_LIMIT      1
#define FAULT_LOST       2
#define FAULT_HOMING     4
#define FAULT_TRAVEL     5
#define FAULT_NOT_HOMED  6

#define MAX_CLIENTS 8

struct mb_server {
        modbus_t *ctx;
        modbus_mapping_t *map;
        int listen_fd;
        int clients[MAX_CLIENTS];
        unsigned fault, fault_axis;     /* latched, lock held */
};

static int32_t get32(const uint16_t *r) { return (int32_t) ((uint32_t) r[0] << 16 | r[1]); }
static void put32(uint16_t *r, int32_t v) { r[0] = (uint16_t) ((uint32_t) v >> 16); r[1] = (uint16_t) v; }

static int32_t mm_to_um(double mm) {
        return (int32_t) lround(mm * 1000.0);
}

/* Faults that make the position unknown (docs: "position afterwards: lost"). */
static bool fault_loses_position(unsigned code) {
        return code == FAULT_LIMIT || code == FAULT_LOST || code == FAULT_HOMING;
}

/* After homing, a stop or a fault the targets are the position: an axis not written
 * by the next move stays where it is. */
static void targets_to_position_locked(struct imp_emu_stage *e) {
        struct mb_server *s = e->proto_state;
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                put32(&s->map->tab_registers[REG_TARGET(a)], mm_to_um(e->motion.pos_mm[a]));
}

static void latch_fault_locked(struct imp_emu_stage *e, unsigned code, unsigned axis) {
        struct mb_server *s = e->proto_state;
        emu_motion_halt_locked(e);
        e->motion.held = false;
        if (fault_loses_position(code))
                e->motion.homed = false;
        s->fault = code;
        s->fault_axis = axis;
        targets_to_position_locked(e);
}

static void mb_event_locked(struct imp_emu_stage *e, enum emu_event ev) {
        if (ev == EMU_EVENT_LIMIT)
                latch_fault_locked(e, FAULT_LIMIT, e->motion.limit_axis);
        else if (ev == EMU_EVENT_HOMED)
                targets_to_position_locked(e);
}

static void mb_alarm_locked(struct imp_emu_stage *e, unsigned code) {
        latch_fault_locked(e, code, NO_AXIS);
}

static void mb_lose_position_locked(struct imp_emu_stage *e) {
        latch_fault_locked(e, FAULT_LOST, NO_AXIS);
}

/* Status, fault, limits, positions, and targets set to the position when not moving. */
static void publish_locked(struct imp_emu_stage *e) {
        struct mb_server *s = e->proto_state;
        (void) emu_motion_update_locked(e);
        const struct emu_motion *m = &e->motion;
        uint16_t *t = s->map->tab_registers;
        t[REG_STATUS] = (uint16_t) ((m->phase == EMU_PHASE_MOVING ? ST_MOVING : 0) |
                                    (m->phase == EMU_PHASE_HOMING ? ST_HOMING : 0) |
                                    (m->homed ? ST_HOMED : 0) | (m->in_position ? ST_INPOS : 0) |
                                    (m->held ? ST_HELD : 0) | (s->fault ? ST_FAULT : 0));
        t[REG_FAULT] = (uint16_t) s->fault;
        t[REG_FAULT_AXIS] = (uint16_t) (s->fault ? s->fault_axis : NO_AXIS);
        t[REG_LIMITS] = (uint16_t) emu_motion_limits_locked(e);
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                put32(&t[REG_POSITION(a)], mm_to_um(m->pos_mm[a]));
}

static void command_move_locked(struct imp_emu_stage *e) {
        struct mb_server *s = e->proto_state;
        const uint16_t *t = s->map->tab_registers;
        if (!e->motion.homed) {
                s->fault = FAULT_NOT_HOMED;
                s->fault_axis = NO_AXIS;
                return;
        }
        double target[IMP_EMU_STAGE_MAX_AXES] = { 0 };
        for (unsigned a = 0; a < e->cfg.n_axes; a++) {
                int32_t um = get32(&t[REG_TARGET(a)]);
                if (um < 0 || um > mm_to_um(e->cfg.travel_mm[a])) {
                        s->fault = FAULT_TRAVEL;
                        s->fault_axis = a;
                        return;
                }
                target[a] = um / 1000.0;
        }
        emu_motion_start_locked(e, target, t[REG_SPEED]);
}

static void command_locked(struct imp_emu_stage *e, unsigned cmd) {
        struct mb_server *s = e->proto_state;
        switch (cmd) {
        case CMD_MOVE:
                if (!s->fault)
                        command_move_locked(e);
                break;
        case CMD_HOME:
                if (!s->fault)
                        emu_motion_home_locked(e);
                break;
        case CMD_STOP:
                emu_motion_halt_locked(e);
                targets_to_position_locked(e);
                break;
        case CMD_CLEAR:
                s->fault = 0;
                s->fault_axis = NO_AXIS;
                break;
        }
}

/* Writable registers and their ranges: 0, or the exception to answer. */
static int check_write(const struct imp_emu_stage *e, unsigned addr, uint16_t v) {
        if (addr == REG_SPEED)
                return v >= 1 && v <= SPEED_MAX_MM_S ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr == REG_COMMAND)
                return v >= CMD_MOVE && v <= CMD_CLEAR ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr >= REG_TARGET(0) && addr < REG_TARGET(e->cfg.n_axes))
                return 0;
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
}

/* Checked as a whole, then applied in address order, before the answer: a client that has
 * its answer finds the command already acting. Commands read back 0. */
static void serve_request(struct imp_emu_stage *e, const uint8_t *q, int len) {
        struct mb_server *s = e->proto_state;
        pthread_mutex_lock(&e->lock);
        if (e->mute || (e->lose_requests && e->lose_requests-- > 0)) {
                pthread_mutex_unlock(&e->lock);
                return;
        }
        publish_locked(e);
        unsigned addr, n;
        uint16_t vals[64];
        n = emu_modbus_decode_write(q, modbus_get_header_length(s->ctx), &addr, vals, ARRAY_SIZE(vals));
        for (unsigned i = 0; i < n; i++) {
                int exc = check_write(e, addr + i, vals[i]);
                if (exc) {
                        modbus_reply_exception(s->ctx, q, (unsigned) exc);
                        pthread_mutex_unlock(&e->lock);
                        return;
                }
        }
        for (unsigned i = 0; i < n; i++) {
                s->map->tab_registers[addr + i] = vals[i];
                if (addr + i == REG_COMMAND)
                        command_locked(e, vals[i]);
        }
        publish_locked(e);
        modbus_reply(s->ctx, q, len, s->map);
        s->map->tab_registers[REG_COMMAND] = 0;
        pthread_mutex_unlock(&e->lock);
}

static void accept_client(struct mb_server *s) {
        int fd = accept(s->listen_fd, NULL, NULL);
        if (fd < 0)
                return;
        for (int i = 0; i < MAX_CLIENTS; i++)
                if (s->clients[i] < 0) {
                        s->clients[i] = fd;
                        return;
                }
        close(fd);
}

static void *mb_thread(void *arg) {
        struct imp_emu_stage *e = arg;
        struct mb_server *s = e->proto_state;
        uint8_t q[MODBUS_TCP_MAX_ADU_LENGTH];
        for (;;) {
                fd_set rfds;
                FD_ZERO(&rfds);
                FD_SET(e->wake[0], &rfds);
                FD_SET(s->listen_fd, &rfds);
                int maxfd = IMP_MAX(e->wake[0], s->listen_fd);
                for (int i = 0; i < MAX_CLIENTS; i++)
                        if (s->clients[i] >= 0) {
                                FD_SET(s->clients[i], &rfds);
                                maxfd = IMP_MAX(maxfd, s->clients[i]);
                        }
                struct timeval tv = { 0, EMU_STAGE_TICK_US };
                int n = select(maxfd + 1, &rfds, NULL, NULL, &tv);
                pthread_mutex_lock(&e->lock);
                (void) emu_motion_update_locked(e);     /* a limit latches even with no one asking */
                pthread_mutex_unlock(&e->lock);
                if (n < 0 && errno != EINTR)
                        break;
                if (n <= 0)
                        continue;
                if (FD_ISSET(e->wake[0], &rfds))
                        break;
                if (FD_ISSET(s->listen_fd, &rfds))
                        accept_client(s);
                for (int i = 0; i < MAX_CLIENTS; i++) {
                        if (s->clients[i] < 0 || !FD_ISSET(s->clients[i], &rfds))
                                continue;
                        modbus_set_socket(s->ctx, s->clients[i]);
                        int len = modbus_receive(s->ctx, q);
                        if (len < 0) {
                                close(s->clients[i]);
                                s->clients[i] = -1;
                        } else if (len > 0)
                                serve_request(e, q, len);
                }
        }
        return NULL;
}

static void mb_destroy(struct imp_emu_stage *e) {
        struct mb_server *s = e->proto_state;
        if (!s)
                return;
        for (int i = 0; i < MAX_CLIENTS; i++)
                if (s->clients[i] >= 0)
                        close(s->clients[i]);
        if (s->listen_fd >= 0)
                close(s->listen_fd);
        if (s->map)
                modbus_mapping_free(s->map);
        if (s->ctx) {
                modbus_set_socket(s->ctx, -1);
                modbus_free(s->ctx);
        }
        free(s);
        e->proto_state = NULL;
}

static const struct emu_stage_proto mb_proto = {
        .thread = mb_thread,
        .event_locked = mb_event_locked,
        .alarm_locked = mb_alarm_locked,
        .lose_position_locked = mb_lose_position_locked,
        .destroy = mb_destroy,
};

static void init_map(struct imp_emu_stage *e) {
        uint16_t *t = ((struct mb_server *) e->proto_state)->map->tab_registers;
        t[REG_MAGIC] = MAGIC;
        t[REG_VERSION] = MAP_VERSION;
        t[REG_N_AXES] = (uint16_t) e->cfg.n_axes;
        t[REG_SPEED] = SPEED_DEFAULT_MM_S;
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                put32(&t[REG_TRAVEL(a)], mm_to_um(e->cfg.travel_mm[a]));
        publish_locked(e);
}

int imp_emu_stage_modbus_new(const struct imp_emu_stage_config *cfg, struct imp_emu_stage **ret_emu) {
        if (!cfg || !ret_emu || cfg->port == 0)
                return -EINVAL;
        _cleanup_(imp_emu_stage_freep) struct imp_emu_stage *e = NULL;
        int r = emu_stage_new(cfg, &e);
        if (r < 0)
                return r;
        struct mb_server *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        s->listen_fd = -1;
        s->fault_axis = NO_AXIS;
        for (int i = 0; i < MAX_CLIENTS; i++)
                s->clients[i] = -1;
        e->proto = &mb_proto;
        e->proto_state = s;
        s->ctx = modbus_new_tcp(e->cfg.address, e->cfg.port);
        s->map = modbus_mapping_new(0, 0, N_REGISTERS, 0);
        if (!s->ctx || !s->map)
                return -ENOMEM;
        init_map(e);
        s->listen_fd = modbus_tcp_listen(s->ctx, 4);
        if (s->listen_fd < 0)
                return errno == EADDRINUSE ? -EADDRINUSE : negative_errno();
        r = emu_stage_start(e);
        if (r < 0)
                return r;
        *ret_emu = TAKE_PTR(e);
        return 0;
}
