/* Dome controller emulator: a libmodbus server thread, TCP on loopback or RTU on a
 * pseudo-terminal, implementing docs/dome-registers.md (written from the document,
 * independently of the driver), with actuators that take real time to move and faults
 * injected on demand: an exception for the Nth request, answers delayed past the client's
 * timeout, a dropped connection. */
#define _GNU_SOURCE             /* ptsname_r */
#include <arpa/inet.h>
#include <fcntl.h>
#include <modbus.h>
#include <stdio.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>
#include "emu.h"
#include "emu-modbus-pdu.h"

/* Register map, version 1 (docs/dome-registers.md). */
#define REG_MAGIC       0x0000
#define REG_VERSION     0x0001
#define REG_N_LIGHTS    0x0002
#define REG_N_AXES      0x0003
#define REG_STATUS      0x0004
#define REG_COMMAND     0x0005
#define REG_LEVEL0      0x0100
#define REG_AXIS0       0x0200
#define AXIS_STRIDE     0x10
#define AX_TARGET       0       /* +0 high, +1 low */
#define AX_POSITION     2
#define AX_STATUS       4
#define AX_FAULT        5
#define AX_COMMAND      6
#define AX_SPEED        7
#define AX_TRAVEL       8
/* Projector sequencer block (map version 1 addition). */
#define REG_PROJ_CAPACITY       0x0300  /* RO */
#define REG_PROJ_WIDTH          0x0301  /* RO */
#define REG_PROJ_HEIGHT         0x0302  /* RO */
#define REG_PROJ_COUNT          0x0303  /* RW, commits the sequence */
#define REG_PROJ_SHOW           0x0304  /* RW, index or 0xFFFF dark */
#define REG_PROJ_SHOWN          0x0305  /* RO */
#define REG_PROJ_FAULT          0x0306  /* RO */
#define REG_PROJ_FAULT_INDEX    0x0307  /* RO */
#define REG_PROJ_COMMAND        0x0308  /* WO */
#define REG_PROJ_TRIGGERS       0x0309  /* RO */
#define REG_PROJ_SHOWS          0x030A  /* RO */
#define REG_PROJ_DESC0          0x0400
#define PROJ_DESC_STRIDE        8
#define PD_KIND 0
#define PD_AXIS 1
#define PD_BIT 2
#define PD_NBITS 3
#define PD_INVERSE 4
#define PD_PERIOD 5
#define PD_STEP 6
#define PD_STEPS 7
#define PROJ_MAX_PATTERNS       256
#define PROJ_DARK               0xFFFFu
#define PROJ_FAULT_DESCRIPTOR   1u
#define PROJ_FAULT_INDEX        2u
#define PROJ_CMD_CLEAR_FAULT    1
#define PROJ_CMD_TRIGGER        2
#define N_REGISTERS     (REG_PROJ_DESC0 + PROJ_MAX_PATTERNS * PROJ_DESC_STRIDE)
#define MAGIC           0x494D
#define MAP_VERSION     1

#define ST_MOVING 1u
#define ST_HOMED  2u
#define ST_FAULT  4u
#define ST_INPOS  8u
#define FAULT_TRAVEL  1u
#define FAULT_STOPPED 3u

#define MAX_AXES 8
#define MAX_CLIENTS 16
#define SELECT_TICK_US 20000

struct axis {
        int32_t start_um, target_um, position_um;
        uint64_t t0_us;
        unsigned status, fault;
};

struct imp_emu_modbus {
        struct imp_emu_modbus_config cfg;
        struct imp_emu_rig *rig;
        modbus_t *ctx;
        modbus_mapping_t *map;
        int listen_fd;
        int pty_master;                 /* RTU: the server's end of the line */
        int pty_hold;                   /* RTU: keeps the slave open between client opens */
        char pty_path[64];
        int wake[2];
        int clients[MAX_CLIENTS];
        pthread_t thread;
        bool running;

        pthread_mutex_t lock;           /* everything below and the map */
        struct axis axes[MAX_AXES];
        unsigned fail_countdown;
        uint8_t fail_exception;
        unsigned delay_n, delay_ms;
        unsigned drop_countdown;
        uint64_t n_requests;
        unsigned n_connections;
};

static uint64_t mono_us(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000u + (uint64_t) ts.tv_nsec / 1000u;
}

static uint16_t *axreg(struct imp_emu_modbus *e, unsigned a, unsigned off) {
        return &e->map->tab_registers[REG_AXIS0 + a * AXIS_STRIDE + off];
}

static int32_t get32(const uint16_t *r) { return (int32_t) ((uint32_t) r[0] << 16 | r[1]); }
static void put32(uint16_t *r, int32_t v) { r[0] = (uint16_t) ((uint32_t) v >> 16); r[1] = (uint16_t) v; }

/* Advance every axis to now and publish position/status/global status in the map. */
static void update_locked(struct imp_emu_modbus *e) {
        uint64_t now = mono_us();
        unsigned global = 1;            /* ready */
        for (unsigned a = 0; a < e->cfg.n_axes; a++) {
                struct axis *x = &e->axes[a];
                if (x->status & ST_MOVING) {
                        int64_t dist = (int64_t) x->target_um - x->start_um;
                        int64_t done = (int64_t) *axreg(e, a, AX_SPEED) * (int64_t) (now - x->t0_us) / 1000;
                        if (done >= llabs(dist)) {
                                x->position_um = x->target_um;
                                x->status &= ~ST_MOVING;
                                x->status |= ST_INPOS;
                                if (x->target_um == 0)
                                        x->status |= ST_HOMED;
                        } else
                                x->position_um = x->start_um + (int32_t) (dist < 0 ? -done : done);
                }
                put32(axreg(e, a, AX_POSITION), x->position_um);
                *axreg(e, a, AX_STATUS) = (uint16_t) x->status;
                *axreg(e, a, AX_FAULT) = (uint16_t) x->fault;
                if (x->status & ST_MOVING)
                        global |= 4;
                if (x->status & ST_FAULT)
                        global |= 8;
        }
        for (unsigned i = 0; i < e->cfg.n_lights; i++)
                if (e->map->tab_registers[REG_LEVEL0 + i])
                        global |= 2;
        e->map->tab_registers[REG_STATUS] = (uint16_t) global;
}

static void axis_command_locked(struct imp_emu_modbus *e, unsigned a, unsigned cmd) {
        struct axis *x = &e->axes[a];
        uint64_t now = mono_us();
        switch (cmd) {
        case 1:                 /* move to target */
        case 2: {               /* home */
                int32_t target = cmd == 2 ? 0 : get32(axreg(e, a, AX_TARGET));
                if (x->status & ST_FAULT)
                        break;
                if (target < 0 || target > e->cfg.travel_um) {
                        x->status |= ST_FAULT;
                        x->status &= ~ST_INPOS;
                        x->fault = FAULT_TRAVEL;
                        break;
                }
                x->start_um = x->position_um;
                x->target_um = target;
                x->t0_us = now;
                x->status = (x->status | ST_MOVING) & ~ST_INPOS;
                break;
        }
        case 3:                 /* stop */
                if (x->status & ST_MOVING) {
                        x->status &= ~ST_MOVING;
                        x->status |= ST_FAULT;
                        x->fault = FAULT_STOPPED;
                }
                break;
        case 4:                 /* clear fault */
                x->status &= ~ST_FAULT;
                x->fault = 0;
                break;
        }
}

/* Writable registers and their value ranges; 0 = ok, else the exception to answer. */
static int check_write(struct imp_emu_modbus *e, unsigned addr, uint16_t v) {
        if (addr == REG_COMMAND)
                return v <= 1 ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr >= REG_LEVEL0 && addr < REG_LEVEL0 + e->cfg.n_lights)
                return v <= 1000 ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr == REG_PROJ_COUNT)
                return v <= e->cfg.max_patterns ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr == REG_PROJ_SHOW)
                return 0;               /* range and faults are checked when applied */
        if (addr == REG_PROJ_COMMAND)
                return v == PROJ_CMD_CLEAR_FAULT || v == PROJ_CMD_TRIGGER ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        if (addr >= REG_PROJ_DESC0 && addr < REG_PROJ_DESC0 + e->cfg.max_patterns * PROJ_DESC_STRIDE) {
                switch ((addr - REG_PROJ_DESC0) % PROJ_DESC_STRIDE) {
                case PD_KIND: return v <= IMP_PAT_PHASE ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
                case PD_AXIS:
                case PD_INVERSE: return v <= 1 ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
                default: return 0;
                }
        }
        if (addr >= REG_AXIS0 && addr < REG_AXIS0 + e->cfg.n_axes * AXIS_STRIDE) {
                unsigned off = (addr - REG_AXIS0) % AXIS_STRIDE;
                if (off == AX_TARGET || off == AX_TARGET + 1)
                        return 0;
                if (off == AX_COMMAND)
                        return v >= 1 && v <= 4 ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
                if (off == AX_SPEED)
                        return v >= 1 && v <= 1000 ? 0 : MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
        }
        return MODBUS_EXCEPTION_ILLEGAL_DATA_ADDRESS;
}

static struct imp_pattern proj_desc_locked(struct imp_emu_modbus *e, unsigned i) {
        const uint16_t *d = &e->map->tab_registers[REG_PROJ_DESC0 + i * PROJ_DESC_STRIDE];
        return (struct imp_pattern) {
                .kind = (enum imp_pattern_kind) d[PD_KIND], .axis = d[PD_AXIS], .bit = d[PD_BIT],
                .nbits = d[PD_NBITS], .inverse = d[PD_INVERSE] != 0, .period_px = d[PD_PERIOD] / 100.0,
                .step = d[PD_STEP], .steps = d[PD_STEPS],
        };
}

/* The sequencer's own consistency rules for one descriptor. */
static bool proj_desc_valid(const struct imp_pattern *p) {
        switch (p->kind) {
        case IMP_PAT_NONE:
        case IMP_PAT_WHITE:
        case IMP_PAT_BLACK:
                return true;
        case IMP_PAT_GRAY:
                return p->nbits >= 1 && p->nbits <= 16 && p->bit >= 0 && p->bit < p->nbits;
        case IMP_PAT_PHASE:
                return p->period_px > 0 && p->steps >= 1 && p->step >= 0 && p->step < p->steps;
        }
        return false;
}

static void proj_dark_locked(struct imp_emu_modbus *e) {
        e->map->tab_registers[REG_PROJ_SHOWN] = PROJ_DARK;
        e->map->tab_registers[REG_PROJ_SHOW] = PROJ_DARK;
        imp_emu_rig_set_pattern_desc(e->rig, -1, NULL);
}

static void proj_latch_fault_locked(struct imp_emu_modbus *e, unsigned code, unsigned index) {
        e->map->tab_registers[REG_PROJ_FAULT] = (uint16_t) code;
        e->map->tab_registers[REG_PROJ_FAULT_INDEX] = (uint16_t) index;
        proj_dark_locked(e);
}

/* Semantic checks of a projector write before it is answered: 0 or the exception. A
 * refusal also latches the fault (the controller's record of why). */
static int proj_check_locked(struct imp_emu_modbus *e, unsigned addr, uint16_t v) {
        uint16_t *t = e->map->tab_registers;
        if (addr == REG_PROJ_COUNT) {
                for (unsigned i = 0; i < v; i++) {
                        struct imp_pattern p = proj_desc_locked(e, i);
                        if (!proj_desc_valid(&p)) {
                                t[REG_PROJ_COUNT] = 0;
                                proj_latch_fault_locked(e, PROJ_FAULT_DESCRIPTOR, i);
                                return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
                        }
                }
        } else if (addr == REG_PROJ_SHOW && v != PROJ_DARK) {
                if (t[REG_PROJ_FAULT])
                        return MODBUS_EXCEPTION_SLAVE_OR_SERVER_FAILURE;
                if (v >= t[REG_PROJ_COUNT]) {
                        proj_latch_fault_locked(e, PROJ_FAULT_INDEX, v);
                        return MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE;
                }
        }
        return 0;
}

static void apply_write_locked(struct imp_emu_modbus *e, unsigned addr, unsigned n, const uint16_t *v) {
        for (unsigned i = 0; i < n; i++) {
                unsigned r = addr + i;
                if (r == REG_COMMAND && v[i] == 1) {
                        for (unsigned l = 0; l < e->cfg.n_lights; l++) {
                                e->map->tab_registers[REG_LEVEL0 + l] = 0;
                                imp_emu_rig_set_light(e->rig, l, 0);
                        }
                        e->map->tab_registers[REG_COMMAND] = 0;
                } else if (r >= REG_LEVEL0 && r < REG_LEVEL0 + e->cfg.n_lights)
                        imp_emu_rig_set_light(e->rig, r - REG_LEVEL0, v[i]);
                else if (r == REG_PROJ_COUNT)
                        proj_dark_locked(e);    /* a new sequence starts dark */
                else if (r == REG_PROJ_SHOW) {
                        uint16_t *t = e->map->tab_registers;
                        if (v[i] == PROJ_DARK)
                                proj_dark_locked(e);
                        else {
                                struct imp_pattern p = proj_desc_locked(e, v[i]);
                                t[REG_PROJ_SHOWN] = v[i];
                                imp_emu_rig_set_pattern_desc(e->rig, v[i], &p);
                        }
                        t[REG_PROJ_SHOWS]++;
                } else if (r == REG_PROJ_COMMAND) {
                        uint16_t *t = e->map->tab_registers;
                        if (v[i] == PROJ_CMD_CLEAR_FAULT)
                                t[REG_PROJ_FAULT] = t[REG_PROJ_FAULT_INDEX] = 0;
                        else if (v[i] == PROJ_CMD_TRIGGER)
                                t[REG_PROJ_TRIGGERS]++;
                        t[REG_PROJ_COMMAND] = 0;
                } else if (r >= REG_AXIS0 && r < REG_AXIS0 + MAX_AXES * AXIS_STRIDE &&
                           (r - REG_AXIS0) % AXIS_STRIDE == AX_COMMAND) {
                        axis_command_locked(e, (r - REG_AXIS0) / AXIS_STRIDE, v[i]);
                        e->map->tab_registers[r] = 0;
                }
        }
}

static void drop_client(struct imp_emu_modbus *e, int slot) {
        if (slot < 0)
                return;         /* RTU: a serial line cannot be dropped, the answer just never comes */
        close(e->clients[slot]);
        e->clients[slot] = -1;
}

static void serve_request(struct imp_emu_modbus *e, int slot, const uint8_t *q, int len) {
        int hl = modbus_get_header_length(e->ctx);
        pthread_mutex_lock(&e->lock);
        e->n_requests++;
        if (e->drop_countdown && --e->drop_countdown == 0) {
                drop_client(e, slot);
                pthread_mutex_unlock(&e->lock);
                return;
        }
        if (e->fail_countdown && --e->fail_countdown == 0) {
                modbus_reply_exception(e->ctx, q, e->fail_exception);
                pthread_mutex_unlock(&e->lock);
                return;
        }
        if (e->delay_n) {
                e->delay_n--;
                unsigned ms = e->delay_ms;
                pthread_mutex_unlock(&e->lock);
                usleep(ms * 1000u);
                pthread_mutex_lock(&e->lock);
        }
        update_locked(e);
        unsigned addr;
        uint16_t vals[128];
        unsigned n = emu_modbus_decode_write(q, hl, &addr, vals, ARRAY_SIZE(vals));
        for (unsigned i = 0; i < n; i++) {
                int exc = check_write(e, addr + i, vals[i]);
                if (!exc)
                        exc = proj_check_locked(e, addr + i, vals[i]);
                if (exc) {
                        modbus_reply_exception(e->ctx, q, (unsigned) exc);
                        pthread_mutex_unlock(&e->lock);
                        return;
                }
        }
        /* Like a real controller, act on a write before answering it: a client that has its
         * answer must find the lights and the projector already changed. modbus_reply()
         * stores the written values itself, so what the write's side effects left in those
         * registers (commands reading back 0) is put back after it. */
        bool in_map = n && addr + n <= N_REGISTERS;
        uint16_t after[ARRAY_SIZE(vals)];
        if (in_map) {
                memcpy(&e->map->tab_registers[addr], vals, n * sizeof *vals);
                apply_write_locked(e, addr, n, vals);
        }
        update_locked(e);
        if (in_map)
                memcpy(after, &e->map->tab_registers[addr], n * sizeof *after);
        modbus_reply(e->ctx, q, len, e->map);
        if (in_map)
                memcpy(&e->map->tab_registers[addr], after, n * sizeof *after);
        pthread_mutex_unlock(&e->lock);
}

/* One RTU frame from the line. libmodbus filters frames for other units (length 0) and
 * checks the CRC; a bad frame is flushed, as a real controller resynchronises on silence. */
static void serve_rtu(struct imp_emu_modbus *e, uint8_t *q) {
        modbus_set_socket(e->ctx, e->pty_master);
        int len = modbus_receive(e->ctx, q);
        if (len > 0)
                serve_request(e, -1, q, len);
        else if (len < 0)
                (void) modbus_flush(e->ctx);
}

static void *server_thread(void *arg) {
        struct imp_emu_modbus *e = arg;
        uint8_t q[MODBUS_TCP_MAX_ADU_LENGTH];
        for (;;) {
                fd_set rfds;
                FD_ZERO(&rfds);
                FD_SET(e->wake[0], &rfds);
                int maxfd = e->wake[0];
                if (e->listen_fd >= 0) {
                        FD_SET(e->listen_fd, &rfds);
                        maxfd = IMP_MAX(maxfd, e->listen_fd);
                }
                if (e->pty_master >= 0) {
                        FD_SET(e->pty_master, &rfds);
                        maxfd = IMP_MAX(maxfd, e->pty_master);
                }
                for (int i = 0; i < MAX_CLIENTS; i++)
                        if (e->clients[i] >= 0) {
                                FD_SET(e->clients[i], &rfds);
                                maxfd = IMP_MAX(maxfd, e->clients[i]);
                        }
                struct timeval tv = { 0, SELECT_TICK_US };
                int n = select(maxfd + 1, &rfds, NULL, NULL, &tv);
                if (n < 0 && errno != EINTR)
                        break;
                if (n <= 0)
                        continue;
                if (FD_ISSET(e->wake[0], &rfds))
                        break;
                if (e->pty_master >= 0 && FD_ISSET(e->pty_master, &rfds))
                        serve_rtu(e, q);
                if (e->listen_fd >= 0 && FD_ISSET(e->listen_fd, &rfds)) {
                        int fd = accept(e->listen_fd, NULL, NULL);
                        int slot = -1;
                        for (int i = 0; i < MAX_CLIENTS && fd >= 0; i++)
                                if (e->clients[i] < 0) {
                                        slot = i;
                                        break;
                                }
                        if (slot < 0 && fd >= 0)
                                close(fd);
                        else if (fd >= 0) {
                                e->clients[slot] = fd;
                                pthread_mutex_lock(&e->lock);
                                e->n_connections++;
                                pthread_mutex_unlock(&e->lock);
                        }
                }
                for (int i = 0; i < MAX_CLIENTS; i++) {
                        if (e->clients[i] < 0 || !FD_ISSET(e->clients[i], &rfds))
                                continue;
                        modbus_set_socket(e->ctx, e->clients[i]);
                        int len = modbus_receive(e->ctx, q);
                        if (len < 0)
                                drop_client(e, i);
                        else if (len > 0)
                                serve_request(e, i, q, len);
                }
        }
        return NULL;
}

/* A pseudo-terminal pair in raw mode: the server keeps the master, clients open the slave
 * by path. The emulator holds the slave open too, so that a client closing it (to reopen
 * after an error) does not hang up the line (the master would read EIO) nor reset its
 * settings; it never reads from that descriptor. */
static int open_pty(struct imp_emu_modbus *e) {
        e->pty_master = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC);
        if (e->pty_master < 0 || grantpt(e->pty_master) < 0 || unlockpt(e->pty_master) < 0)
                return negative_errno();
        if (ptsname_r(e->pty_master, e->pty_path, sizeof e->pty_path) != 0)
                return -ENAMETOOLONG;
        e->pty_hold = open(e->pty_path, O_RDWR | O_NOCTTY | O_CLOEXEC);
        if (e->pty_hold < 0)
                return negative_errno();
        struct termios t;
        if (tcgetattr(e->pty_hold, &t) < 0)
                return negative_errno();
        cfmakeraw(&t);          /* no echo of answers back into the server, no CR/LF games */
        if (tcsetattr(e->pty_hold, TCSANOW, &t) < 0)
                return negative_errno();
        return 0;
}

int imp_emu_modbus_new(const struct imp_emu_modbus_config *cfg, struct imp_emu_rig *rig,
                       struct imp_emu_modbus **ret_emu) {
        if (!cfg || !ret_emu || (cfg->port == 0 && !cfg->rtu) || cfg->rtu_unit > 247)
                return -EINVAL;
        struct imp_emu_modbus *e = calloc(1, sizeof *e);
        if (!e)
                return -ENOMEM;
        e->cfg = *cfg;
        if (!e->cfg.address)
                e->cfg.address = "127.0.0.1";
        if (!e->cfg.n_lights)
                e->cfg.n_lights = 16;
        if (!e->cfg.n_axes)
                e->cfg.n_axes = 2;
        if (!e->cfg.speed_mm_per_s)
                e->cfg.speed_mm_per_s = 50;
        if (!e->cfg.travel_um)
                e->cfg.travel_um = 100000;
        if (!e->cfg.projector_width)
                e->cfg.projector_width = 1024;
        if (!e->cfg.projector_height)
                e->cfg.projector_height = 768;
        if (!e->cfg.max_patterns)
                e->cfg.max_patterns = PROJ_MAX_PATTERNS;
        if (!e->cfg.rtu_unit)
                e->cfg.rtu_unit = 1;
        e->rig = rig;
        e->listen_fd = e->pty_master = e->pty_hold = e->wake[0] = e->wake[1] = -1;
        for (int i = 0; i < MAX_CLIENTS; i++)
                e->clients[i] = -1;
        pthread_mutex_init(&e->lock, NULL);
        int r = -EINVAL;
        if (e->cfg.n_lights > IMP_EMU_MAX_LIGHTS || e->cfg.n_axes > MAX_AXES ||
            e->cfg.max_patterns > PROJ_MAX_PATTERNS || e->cfg.projector_width > 65535 ||
            e->cfg.projector_height > 65535)
                goto fail;
        r = -ENOMEM;
        if (e->cfg.rtu) {
                if ((r = open_pty(e)) < 0)
                        goto fail;
                r = -ENOMEM;
                /* The device path and line settings only matter to modbus_connect(), which
                 * the server never calls: it reads and writes the pty master directly. */
                e->ctx = modbus_new_rtu(e->pty_path, 19200, 'E', 8, 1);
                if (e->ctx)
                        modbus_set_slave(e->ctx, (int) e->cfg.rtu_unit);
        } else
                e->ctx = modbus_new_tcp(e->cfg.address, e->cfg.port);
        e->map = modbus_mapping_new(0, 0, N_REGISTERS, 0);
        if (!e->ctx || !e->map)
                goto fail;
        uint16_t *t = e->map->tab_registers;
        t[REG_MAGIC] = MAGIC;
        t[REG_VERSION] = MAP_VERSION;
        t[REG_N_LIGHTS] = (uint16_t) e->cfg.n_lights;
        t[REG_N_AXES] = (uint16_t) e->cfg.n_axes;
        for (unsigned a = 0; a < e->cfg.n_axes; a++) {
                *axreg(e, a, AX_SPEED) = (uint16_t) e->cfg.speed_mm_per_s;
                put32(axreg(e, a, AX_TRAVEL), e->cfg.travel_um);
                e->axes[a].status = ST_INPOS;
        }
        t[REG_PROJ_CAPACITY] = (uint16_t) e->cfg.max_patterns;
        t[REG_PROJ_WIDTH] = (uint16_t) e->cfg.projector_width;
        t[REG_PROJ_HEIGHT] = (uint16_t) e->cfg.projector_height;
        t[REG_PROJ_SHOW] = t[REG_PROJ_SHOWN] = PROJ_DARK;
        update_locked(e);
        if (!e->cfg.rtu)
                e->listen_fd = modbus_tcp_listen(e->ctx, 8);
        if (!e->cfg.rtu && e->listen_fd < 0) {
                r = errno == EADDRINUSE ? -EADDRINUSE : negative_errno();
                goto fail;
        }
        if (pipe(e->wake) < 0) {
                r = negative_errno();
                goto fail;
        }
        r = -pthread_create(&e->thread, NULL, server_thread, e);
        if (r < 0)
                goto fail;
        e->running = true;
        *ret_emu = e;
        return 0;
fail:
        imp_emu_modbus_free(e);
        return r;
}

void imp_emu_modbus_free(struct imp_emu_modbus *e) {
        if (!e)
                return;
        if (e->running) {
                (void) !write(e->wake[1], "x", 1);
                pthread_join(e->thread, NULL);
        }
        for (int i = 0; i < MAX_CLIENTS; i++)
                if (e->clients[i] >= 0)
                        close(e->clients[i]);
        if (e->listen_fd >= 0)
                close(e->listen_fd);
        if (e->pty_hold >= 0)
                close(e->pty_hold);
        if (e->pty_master >= 0)
                close(e->pty_master);
        if (e->wake[0] >= 0) {
                close(e->wake[0]);
                close(e->wake[1]);
        }
        if (e->map)
                modbus_mapping_free(e->map);
        if (e->ctx) {
                modbus_set_socket(e->ctx, -1);
                modbus_free(e->ctx);
        }
        pthread_mutex_destroy(&e->lock);
        free(e);
}

const char *imp_emu_modbus_rtu_device(const struct imp_emu_modbus *e) {
        return e && e->cfg.rtu ? e->pty_path : NULL;
}

void imp_emu_modbus_fail_nth(struct imp_emu_modbus *e, unsigned nth, uint8_t exception_code) {
        pthread_mutex_lock(&e->lock);
        e->fail_countdown = nth;
        e->fail_exception = exception_code;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_modbus_delay(struct imp_emu_modbus *e, unsigned n_requests, unsigned delay_ms) {
        pthread_mutex_lock(&e->lock);
        e->delay_n = n_requests;
        e->delay_ms = delay_ms;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_modbus_drop_nth(struct imp_emu_modbus *e, unsigned nth) {
        pthread_mutex_lock(&e->lock);
        e->drop_countdown = nth;
        pthread_mutex_unlock(&e->lock);
}

uint64_t imp_emu_modbus_n_requests(struct imp_emu_modbus *e) {
        pthread_mutex_lock(&e->lock);
        uint64_t n = e->n_requests;
        pthread_mutex_unlock(&e->lock);
        return n;
}

unsigned imp_emu_modbus_n_connections(struct imp_emu_modbus *e) {
        pthread_mutex_lock(&e->lock);
        unsigned n = e->n_connections;
        pthread_mutex_unlock(&e->lock);
        return n;
}

unsigned imp_emu_modbus_light(struct imp_emu_modbus *e, unsigned id) {
        if (id >= e->cfg.n_lights)
                return 0;
        pthread_mutex_lock(&e->lock);
        unsigned v = e->map->tab_registers[REG_LEVEL0 + id];
        pthread_mutex_unlock(&e->lock);
        return v;
}

void imp_emu_modbus_projector_fault(struct imp_emu_modbus *e, unsigned code) {
        pthread_mutex_lock(&e->lock);
        proj_latch_fault_locked(e, code, 0);
        pthread_mutex_unlock(&e->lock);
}

int imp_emu_modbus_projector_shown(struct imp_emu_modbus *e) {
        pthread_mutex_lock(&e->lock);
        uint16_t v = e->map->tab_registers[REG_PROJ_SHOWN];
        pthread_mutex_unlock(&e->lock);
        return v == PROJ_DARK ? -1 : (int) v;
}

unsigned imp_emu_modbus_projector_count(struct imp_emu_modbus *e) {
        pthread_mutex_lock(&e->lock);
        unsigned v = e->map->tab_registers[REG_PROJ_COUNT];
        pthread_mutex_unlock(&e->lock);
        return v;
}

unsigned imp_emu_modbus_projector_triggers(struct imp_emu_modbus *e) {
        pthread_mutex_lock(&e->lock);
        unsigned v = e->map->tab_registers[REG_PROJ_TRIGGERS];
        pthread_mutex_unlock(&e->lock);
        return v;
}
