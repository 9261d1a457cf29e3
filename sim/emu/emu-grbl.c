/* GRBL 1.1 gantry controller emulator on a pseudo-terminal, written from GRBL's interface
 * documentation (doc/markdown/interface.md, commands.md): lines answered "ok" or
 * "error:N"; the real-time characters '?' (status report "<State|MPos:x,y,z|FS:f,0|Pn:XYZ>"),
 * '!' (feed hold), '~' (cycle start) and 0x18 (soft reset, answered by the banner);
 * "ALARM:N" pushed when an alarm is raised; $H homing, $X unlock, $$ settings; G0/G1 in
 * G90/G91 with X Y Z F. Alarms 1 (hard limit) and 2 (soft limit) lock it until a reset:
 * nothing but real-time characters is read meanwhile and '?' is not answered. The planner
 * holds one block: a motion line waits, unanswered, until the running move has ended. */
#define _GNU_SOURCE             /* ptsname_r */
#include <ctype.h>
#include <fcntl.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <termios.h>
#include <unistd.h>
#include "emu-stage-internal.h"

#define GRBL_BANNER             "\r\nGrbl 1.1h ['$' for help]\r\n"
#define GRBL_MSG_LOCKED         "[MSG:'$H'|'$X' to unlock]\r\n"
#define GRBL_MSG_RESET          "[MSG:Reset to continue]\r\n"
#define GRBL_MSG_UNLOCKED       "[MSG:Caution: Unlocked]\r\n"
#define CH_RESET                0x18
#define HOLD_DECEL_US           20000   /* feed hold: Hold:1 this long, then Hold:0 */
#define LINE_MAX                128     /* GRBL's LINE_BUFFER_SIZE is 80; ours is generous */
#define QUEUE_LINES             8
#define ERR_BAD_NUMBER          2       /* error codes of GRBL 1.1 (doc/csv/error_codes_en_US.csv) */
#define ERR_INVALID_STATEMENT   3
#define ERR_IDLE_ONLY           8
#define ERR_ALARM_LOCK          9
#define ERR_UNSUPPORTED         20
#define ERR_UNDEFINED_FEED      22
#define ALARM_HARD_LIMIT        1
#define ALARM_SOFT_LIMIT        2
#define ALARM_ABORT_CYCLE       3
#define ALARM_HOMING_RESET      6

enum grbl_state { ST_IDLE, ST_RUN, ST_HOLD_DECEL, ST_HOLD, ST_HOME, ST_ALARM };
static const char *const state_names[] = {
        [ST_IDLE] = "Idle", [ST_RUN] = "Run", [ST_HOLD_DECEL] = "Hold:1", [ST_HOLD] = "Hold:0",
        [ST_HOME] = "Home", [ST_ALARM] = "Alarm",
};

struct grbl {
        int master, hold_slave;
        char path[64];
        enum grbl_state state;
        bool locked;                    /* alarm 1 or 2: only a reset is heard */
        bool relative;                  /* G91 */
        double feed_mm_min;             /* modal F, 0 = none yet */
        uint64_t hold_t0_us;
        double hold_target_mm[IMP_EMU_STAGE_MAX_AXES];  /* the held block's target, for '~' */
        char line[LINE_MAX];
        size_t line_len;
        char queue[QUEUE_LINES][LINE_MAX];
        unsigned q_head, q_len;
};

/* Output never blocks the emulator: a client that does not read loses what does not fit. */
_printf_(2, 3)
static void say_locked(struct imp_emu_stage *e, const char *fmt, ...) {
        struct grbl *g = e->proto_state;
        char buf[256];
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(buf, sizeof buf, fmt, ap);
        va_end(ap);
        if (n > 0)
                (void) !write(g->master, buf, (size_t) IMP_MIN(n, (int) sizeof buf - 1));
}

static bool alarm_loses_position(unsigned code) {
        return code == ALARM_HARD_LIMIT || code == ALARM_ABORT_CYCLE || (code >= 6 && code <= 9);
}

static void raise_alarm_locked(struct imp_emu_stage *e, unsigned code) {
        struct grbl *g = e->proto_state;
        emu_motion_halt_locked(e);
        e->motion.held = false;
        if (alarm_loses_position(code))
                e->motion.homed = false;
        g->state = ST_ALARM;
        say_locked(e, "ALARM:%u\r\n", code);
        if (code == ALARM_HARD_LIMIT || code == ALARM_SOFT_LIMIT) {
                g->locked = true;
                say_locked(e, GRBL_MSG_RESET);
        }
}

static void grbl_event_locked(struct imp_emu_stage *e, enum emu_event ev) {
        struct grbl *g = e->proto_state;
        if (ev == EMU_EVENT_LIMIT)
                raise_alarm_locked(e, ALARM_HARD_LIMIT);
        else if (ev == EMU_EVENT_HOMED) {
                g->state = ST_IDLE;
                say_locked(e, "ok\r\n");        /* the answer to $H comes when homing ends */
        } else if (ev == EMU_EVENT_ARRIVED && g->state == ST_RUN)
                g->state = ST_IDLE;
}

static void grbl_alarm_locked(struct imp_emu_stage *e, unsigned code) {
        raise_alarm_locked(e, code);
}

static void forget_input_locked(struct grbl *g) {
        g->line_len = 0;
        g->q_head = g->q_len = 0;
}

/* A brown-out: the firmware restarts, counts from 0 and locks itself until $H or $X. */
static void grbl_lose_position_locked(struct imp_emu_stage *e) {
        struct grbl *g = e->proto_state;
        emu_motion_halt_locked(e);
        memset(e->motion.pos_mm, 0, sizeof e->motion.pos_mm);
        memset(e->motion.target_mm, 0, sizeof e->motion.target_mm);
        e->motion.homed = e->motion.held = e->motion.in_position = false;
        forget_input_locked(g);
        g->state = ST_ALARM;
        g->locked = g->relative = false;
        g->feed_mm_min = 0;
        say_locked(e, GRBL_BANNER GRBL_MSG_LOCKED);
}

/* Machine coordinate of a physical position on axis a (the axes' own frame is 0..travel). */
static double mpos(const struct imp_emu_stage *e, unsigned a, double pos_mm) {
        return e->cfg.grbl_negative_space ? pos_mm - e->cfg.travel_mm[a] : pos_mm;
}

static void report_locked(struct imp_emu_stage *e) {
        struct grbl *g = e->proto_state;
        double p[IMP_EMU_STAGE_MAX_AXES] = { 0 };
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                p[a] = mpos(e, a, e->motion.pos_mm[a]);
        unsigned pins = emu_motion_limits_locked(e);
        char pn[8] = "";
        size_t k = 0;
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                if (pins & (1u << a))
                        pn[k++] = "XYZ"[a];
        bool running = g->state == ST_RUN || g->state == ST_HOME || g->state == ST_HOLD_DECEL;
        say_locked(e, "<%s|MPos:%.3f,%.3f,%.3f|FS:%.0f,0%s%s>\r\n", state_names[g->state], p[0], p[1], p[2], running ? e->motion.speed_mm_s * 60 : 0.0,
                   k ? "|Pn:" : "", pn);
}

/* Ctrl-X: stops everything and restarts the protocol. Reset during motion loses the
 * position (ALARM:3; during homing ALARM:6); after a completed feed hold it does not. */
static void soft_reset_locked(struct imp_emu_stage *e) {
        struct grbl *g = e->proto_state;
        e->n_resets++;
        if (g->state == ST_RUN || g->state == ST_HOLD_DECEL || g->state == ST_HOME)
                raise_alarm_locked(e, g->state == ST_HOME ? ALARM_HOMING_RESET : ALARM_ABORT_CYCLE);
        emu_motion_halt_locked(e);
        e->motion.held = g->state == ST_HOLD;
        if (g->state != ST_ALARM)
                g->state = ST_IDLE;
        g->locked = false;
        forget_input_locked(g);
        say_locked(e, GRBL_BANNER);
        if (g->state == ST_ALARM)
                say_locked(e, GRBL_MSG_LOCKED);
}

static void realtime_locked(struct imp_emu_stage *e, char c) {
        struct grbl *g = e->proto_state;
        if (c == CH_RESET) {
                soft_reset_locked(e);
        } else if (c == '?') {
                if (!g->locked)
                        report_locked(e);
        } else if (c == '!' && g->state == ST_RUN) {
                memcpy(g->hold_target_mm, e->motion.target_mm, sizeof g->hold_target_mm);
                emu_motion_halt_locked(e);
                g->state = ST_HOLD_DECEL;
                g->hold_t0_us = emu_stage_now_us();
        } else if (c == '~' && g->state == ST_HOLD) {
                /* Resume: the held block is still in the planner. */
                emu_motion_start_locked(e, g->hold_target_mm, e->motion.speed_mm_s);
                g->state = ST_RUN;
        }
}

/* "$$": the settings a sender reads (travel $130..$132, rates, homing and limits on). */
static void settings_locked(struct imp_emu_stage *e) {
        say_locked(e, "$20=1\r\n$21=1\r\n$22=1\r\n$110=%.3f\r\n$111=%.3f\r\n$112=%.3f\r\n",
                   e->cfg.rapid_speed_mm_s * 60, e->cfg.rapid_speed_mm_s * 60, e->cfg.rapid_speed_mm_s * 60);
        for (unsigned a = 0; a < 3; a++)
                say_locked(e, "$%u=%.3f\r\n", 130 + a, a < e->cfg.n_axes ? e->cfg.travel_mm[a] : 0.0);
        say_locked(e, "ok\r\n");
}

/* A '$' line: 0 for ok (already said when it has output), or an error code. */
static int dollar_locked(struct imp_emu_stage *e, const char *l) {
        struct grbl *g = e->proto_state;
        bool idle = g->state == ST_IDLE || g->state == ST_ALARM;
        if (!idle)
                return ERR_IDLE_ONLY;
        if (strcmp(l, "$H") == 0) {
                g->state = ST_HOME;
                emu_motion_home_locked(e);
                return -1;              /* ok when homing ends */
        }
        if (strcmp(l, "$X") == 0) {
                if (g->state == ST_ALARM)
                        say_locked(e, GRBL_MSG_UNLOCKED);
                g->state = ST_IDLE;
                return 0;
        }
        if (strcmp(l, "$$") == 0) {
                settings_locked(e);
                return -1;
        }
        return ERR_INVALID_STATEMENT;
}

/* The words of a G-code line: G0/G1, G90/G91, G21, X Y Z F. 0 or an error code. */
static int parse_gcode(struct imp_emu_stage *e, const char *l, int *ret_motion, double *xyz, unsigned *ret_mask) {
        struct grbl *g = e->proto_state;
        *ret_motion = -1;
        *ret_mask = 0;
        while (*l) {
                char letter = (char) toupper((unsigned char) *l++);
                char *end;
                double v = strtod(l, &end);
                if (end == l || !isfinite(v))
                        return ERR_BAD_NUMBER;
                l = end;
                if (letter == 'G' && (v == 0 || v == 1))
                        *ret_motion = (int) v;
                else if (letter == 'G' && (v == 90 || v == 91))
                        g->relative = v == 91;
                else if (letter == 'G' && v == 21)
                        ;                       /* mm: the only unit here */
                else if (letter == 'F' && v > 0)
                        g->feed_mm_min = v;
                else if (letter >= 'X' && letter <= 'Z' && (unsigned) (letter - 'X') < e->cfg.n_axes) {
                        xyz[letter - 'X'] = v;
                        *ret_mask |= 1u << (letter - 'X');
                } else
                        return ERR_UNSUPPORTED;
        }
        return 0;
}

/* A G-code line: 0 for ok, an error code, or -1 when it must wait for the running move. */
static int gcode_locked(struct imp_emu_stage *e, const char *l) {
        struct grbl *g = e->proto_state;
        if (g->state == ST_ALARM)
                return ERR_ALARM_LOCK;
        if (g->state != ST_IDLE)
                return -1;
        double xyz[IMP_EMU_STAGE_MAX_AXES] = { 0 };
        int motion;
        unsigned mask;
        int r = parse_gcode(e, l, &motion, xyz, &mask);
        if (r || !mask)
                return r;
        if (motion == 1 && g->feed_mm_min <= 0)
                return ERR_UNDEFINED_FEED;
        double target[IMP_EMU_STAGE_MAX_AXES];
        for (unsigned a = 0; a < IMP_EMU_STAGE_MAX_AXES; a++) {
                target[a] = e->motion.pos_mm[a];
                if (mask & (1u << a))
                        target[a] = g->relative ? target[a] + xyz[a] : xyz[a] - mpos(e, a, 0);
                if (a < e->cfg.n_axes && (target[a] < 0 || target[a] > e->cfg.travel_mm[a])) {
                        say_locked(e, "ok\r\n");        /* the line was taken, then the planner refused it */
                        raise_alarm_locked(e, ALARM_SOFT_LIMIT);
                        return -2;
                }
        }
        emu_motion_start_locked(e, target, motion == 1 ? g->feed_mm_min / 60 : e->cfg.rapid_speed_mm_s);
        g->state = ST_RUN;
        return 0;
}

/* Runs queued lines while they can run. */
static void run_queue_locked(struct imp_emu_stage *e) {
        struct grbl *g = e->proto_state;
        while (g->q_len && !g->locked) {
                const char *l = g->queue[g->q_head];
                int r = !*l ? 0 : *l == '$' ? dollar_locked(e, l) : gcode_locked(e, l);
                if (r == -1 && *l != '$')
                        return;                 /* waits for the planner */
                g->q_head = (g->q_head + 1) % QUEUE_LINES;
                g->q_len--;
                if (r == 0)
                        say_locked(e, "ok\r\n");
                else if (r > 0)
                        say_locked(e, "error:%d\r\n", r);
        }
}

static void take_byte_locked(struct imp_emu_stage *e, char c) {
        struct grbl *g = e->proto_state;
        if (c == '?' || c == '!' || c == '~' || c == CH_RESET) {
                realtime_locked(e, c);
                return;
        }
        if (g->locked)
                return;                 /* a locked GRBL reads nothing until the reset */
        if (c != '\n' && c != '\r') {
                if (c != ' ' && g->line_len + 1 < LINE_MAX)
                        g->line[g->line_len++] = c;
                return;
        }
        if (e->lose_requests) {
                e->lose_requests--;
        } else if (g->q_len < QUEUE_LINES) {
                char *slot = g->queue[(g->q_head + g->q_len++) % QUEUE_LINES];
                memcpy(slot, g->line, g->line_len);
                slot[g->line_len] = 0;
        }
        g->line_len = 0;
}

static void *grbl_thread(void *arg) {
        struct imp_emu_stage *e = arg;
        struct grbl *g = e->proto_state;
        for (;;) {
                fd_set rfds;
                FD_ZERO(&rfds);
                FD_SET(e->wake[0], &rfds);
                FD_SET(g->master, &rfds);
                struct timeval tv = { 0, EMU_STAGE_TICK_US };
                int n = select(IMP_MAX(e->wake[0], g->master) + 1, &rfds, NULL, NULL, &tv);
                if (n < 0 && errno != EINTR)
                        break;
                if (n > 0 && FD_ISSET(e->wake[0], &rfds))
                        break;
                char buf[256];
                ssize_t len = n > 0 && FD_ISSET(g->master, &rfds) ? read(g->master, buf, sizeof buf) : 0;
                pthread_mutex_lock(&e->lock);
                (void) emu_motion_update_locked(e);
                if (g->state == ST_HOLD_DECEL && emu_stage_now_us() - g->hold_t0_us >= HOLD_DECEL_US)
                        g->state = ST_HOLD;
                for (ssize_t i = 0; i < len && !e->mute; i++)
                        take_byte_locked(e, buf[i]);
                run_queue_locked(e);
                pthread_mutex_unlock(&e->lock);
        }
        return NULL;
}

static void grbl_destroy(struct imp_emu_stage *e) {
        struct grbl *g = e->proto_state;
        if (!g)
                return;
        if (g->hold_slave >= 0)
                close(g->hold_slave);
        if (g->master >= 0)
                close(g->master);
        free(g);
        e->proto_state = NULL;
}

static const struct emu_stage_proto grbl_proto = {
        .thread = grbl_thread,
        .event_locked = grbl_event_locked,
        .alarm_locked = grbl_alarm_locked,
        .lose_position_locked = grbl_lose_position_locked,
        .destroy = grbl_destroy,
};

/* The pty pair in raw mode. The emulator holds the slave open too, so that a client closing
 * and reopening it neither hangs up the line nor resets its settings. */
static int open_pty(struct grbl *g) {
        g->master = posix_openpt(O_RDWR | O_NOCTTY | O_CLOEXEC | O_NONBLOCK);
        if (g->master < 0 || grantpt(g->master) < 0 || unlockpt(g->master) < 0)
                return negative_errno();
        if (ptsname_r(g->master, g->path, sizeof g->path) != 0)
                return -ENAMETOOLONG;
        g->hold_slave = open(g->path, O_RDWR | O_NOCTTY | O_CLOEXEC);
        if (g->hold_slave < 0)
                return negative_errno();
        struct termios t;
        if (tcgetattr(g->hold_slave, &t) < 0)
                return negative_errno();
        cfmakeraw(&t);
        return tcsetattr(g->hold_slave, TCSANOW, &t) < 0 ? negative_errno() : 0;
}

int imp_emu_stage_grbl_new(const struct imp_emu_stage_config *cfg, struct imp_emu_stage **ret_emu) {
        if (!cfg || !ret_emu)
                return -EINVAL;
        _cleanup_(imp_emu_stage_freep) struct imp_emu_stage *e = NULL;
        int r = emu_stage_new(cfg, &e);
        if (r < 0)
                return r;
        struct grbl *g = calloc(1, sizeof *g);
        if (!g)
                return -ENOMEM;
        g->master = g->hold_slave = -1;
        g->state = ST_ALARM;            /* homing enabled: GRBL powers up locked */
        e->proto = &grbl_proto;
        e->proto_state = g;
        if ((r = open_pty(g)) < 0 || (r = emu_stage_start(e)) < 0)
                return r;
        *ret_emu = TAKE_PTR(e);
        return 0;
}

const char *imp_emu_stage_device(const struct imp_emu_stage *e) {
        return e && e->proto == &grbl_proto ? ((const struct grbl *) e->proto_state)->path : NULL;
}
