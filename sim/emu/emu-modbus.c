/* Dome controller emulator: a libmodbus TCP server thread on loopback implementing
 * docs/dome-registers.md (written from the document, independently of the driver), with
 * actuators that take real time to move and faults injected on demand: an exception for
 * the Nth request, answers delayed past the client's timeout, a dropped connection. */
#include <arpa/inet.h>
#include <modbus.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>
#include "emu.h"

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
#define N_REGISTERS     0x0300
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

/* Decode a write request into (addr, n, values). Returns n, 0 for a non-write. */
static unsigned decode_write(const uint8_t *q, int hl, unsigned *addr, uint16_t *vals, unsigned max) {
        uint8_t fc = q[hl];
        *addr = (unsigned) q[hl + 1] << 8 | q[hl + 2];
        if (fc == MODBUS_FC_WRITE_SINGLE_REGISTER) {
                vals[0] = (uint16_t) (q[hl + 3] << 8 | q[hl + 4]);
                return 1;
        }
        if (fc == MODBUS_FC_WRITE_MULTIPLE_REGISTERS) {
                unsigned n = (unsigned) q[hl + 3] << 8 | q[hl + 4];
                n = IMP_MIN(n, max);
                for (unsigned i = 0; i < n; i++)
                        vals[i] = (uint16_t) (q[hl + 6 + 2 * i] << 8 | q[hl + 7 + 2 * i]);
                return n;
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
                else if (r >= REG_AXIS0 && (r - REG_AXIS0) % AXIS_STRIDE == AX_COMMAND) {
                        axis_command_locked(e, (r - REG_AXIS0) / AXIS_STRIDE, v[i]);
                        e->map->tab_registers[r] = 0;
                }
        }
}

static void drop_client(struct imp_emu_modbus *e, int slot) {
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
        unsigned n = decode_write(q, hl, &addr, vals, ARRAY_SIZE(vals));
        for (unsigned i = 0; i < n; i++) {
                int exc = check_write(e, addr + i, vals[i]);
                if (exc) {
                        modbus_reply_exception(e->ctx, q, (unsigned) exc);
                        pthread_mutex_unlock(&e->lock);
                        return;
                }
        }
        if (modbus_reply(e->ctx, q, len, e->map) >= 0 && n)
                apply_write_locked(e, addr, n, vals);
        update_locked(e);
        pthread_mutex_unlock(&e->lock);
}

static void *server_thread(void *arg) {
        struct imp_emu_modbus *e = arg;
        uint8_t q[MODBUS_TCP_MAX_ADU_LENGTH];
        for (;;) {
                fd_set rfds;
                FD_ZERO(&rfds);
                FD_SET(e->wake[0], &rfds);
                FD_SET(e->listen_fd, &rfds);
                int maxfd = IMP_MAX(e->wake[0], e->listen_fd);
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
                if (FD_ISSET(e->listen_fd, &rfds)) {
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

int imp_emu_modbus_new(const struct imp_emu_modbus_config *cfg, struct imp_emu_rig *rig,
                       struct imp_emu_modbus **ret_emu) {
        if (!cfg || !ret_emu || cfg->port == 0)
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
        e->rig = rig;
        e->listen_fd = e->wake[0] = e->wake[1] = -1;
        for (int i = 0; i < MAX_CLIENTS; i++)
                e->clients[i] = -1;
        pthread_mutex_init(&e->lock, NULL);
        int r = -EINVAL;
        if (e->cfg.n_lights > IMP_EMU_MAX_LIGHTS || e->cfg.n_axes > MAX_AXES)
                goto fail;
        r = -ENOMEM;
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
        update_locked(e);
        e->listen_fd = modbus_tcp_listen(e->ctx, 8);
        if (e->listen_fd < 0) {
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
