/* Stage backend "grbl": a GRBL 1.1-class gantry controller speaking G-code over a serial
 * line (termios, raw 8N1). Lines are answered "ok" or "error:N" in order; '?' asks for a
 * status report "<State|MPos:x,y,z|...|Pn:XYZ>"; "ALARM:N" and the banner come unasked.
 * Moves are "G90 G1 X Y Z F" (mm, mm/min), homing "$H" (its "ok" comes when homing ends),
 * soft-stop a feed hold '!' then, once the hold is complete, a soft reset (Ctrl-X), which
 * GRBL documents as keeping the position; clear_fault a reset where the alarm locks GRBL
 * (ALARM:1, ALARM:2) and "$X". Position is known only after a "$H" through this handle:
 * GRBL does not say whether it was homed before we connected. Stage coordinates are
 * 0..travel ($130..$132): GRBL's machine coordinates where it was built with
 * HOMING_FORCE_SET_ORIGIN, else (";space=negative", GRBL's default) machine −travel..0,
 * shifted by the travel. */
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>
#include "address.h"
#include "stage.h"

#define GRBL_DEFAULT_BAUD       115200
#define GRBL_DEFAULT_TIMEOUT_MS 500     /* an answer to a line or to '?' */
#define GRBL_HOLD_TIMEOUT_MS    5000    /* a feed hold decelerates at $120..$122 mm/s² */
#define GRBL_CH_RESET           "\x18"
#define GRBL_BANNER             "Grbl "
#define GRBL_SETTING_TRAVEL     130     /* $130..$132: max travel x, y, z, mm */
#define MM_S_TO_MM_MIN          60.0

enum grbl_state { GS_UNKNOWN, GS_IDLE, GS_RUN, GS_HOLD, GS_HOLD_DONE, GS_JOG, GS_ALARM, GS_DOOR, GS_CHECK,
                  GS_HOME, GS_SLEEP };

struct grbl {
        int fd;
        char device[128];
        unsigned timeout_ms, hold_timeout_ms, n_axes;
        double travel_mm[IMP_STAGE_MAX_AXES];
        bool negative_space;            /* machine coordinates −travel..0 */
        char rx[512];
        size_t rx_len;
        /* What the controller told us. */
        enum grbl_state state;
        double mpos_mm[IMP_STAGE_MAX_AXES];     /* stage coordinates of the last report */
        unsigned pins;                  /* limit pins X Y Z of the last report */
        unsigned pending_ok;            /* lines sent whose "ok"/"error" has not come */
        int line_error;                 /* error:N of the last answered line, 0 = ok */
        bool homing;                    /* "$H" sent, its answer not yet come */
        bool homed;                     /* homed through this handle, not lost since */
        bool held;                      /* the last move was soft-stopped */
        unsigned alarm;                 /* ALARM:N latched, 0 = none */
        bool locked;                    /* ALARM:1/2: GRBL hears nothing but a reset */
        bool restarted;                 /* a banner we did not ask for: the firmware restarted */
        bool expect_banner;             /* we sent a reset */
        char error[320];
};

static uint64_t now_us(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000u + (uint64_t) ts.tv_nsec / 1000u;
}

/* GRBL 1.1 alarm codes (doc/csv/alarm_codes_en_US.csv). */
static const char *alarm_text(unsigned code) {
        static const char *const t[] = {
                [1] = "hard limit triggered", [2] = "soft limit: target exceeds machine travel",
                [3] = "reset while in motion", [4] = "probe fail: not in initial state",
                [5] = "probe fail: no contact", [6] = "homing fail: reset during homing",
                [7] = "homing fail: door opened", [8] = "homing fail: pull-off did not clear the switch",
                [9] = "homing fail: switch not found",
        };
        return code < ARRAY_SIZE(t) && t[code] ? t[code] : "alarm";
}

static const char *error_text(int code) {
        switch (code) {
        case 2: return "bad number format";
        case 3: return "invalid $ statement";
        case 8: return "$ command only when idle";
        case 9: return "G-code locked out during alarm";
        case 15: return "travel exceeded";
        case 20: return "unsupported command";
        case 22: return "feed rate not set";
        default: return "G-code error";
        }
}

static enum imp_stage_fault fault_of_alarm(unsigned code) {
        switch (code) {
        case 1: return IMP_STAGE_FAULT_LIMIT;
        case 2: return IMP_STAGE_FAULT_TRAVEL;
        case 3: return IMP_STAGE_FAULT_LOST_POSITION;
        case 6: case 7: case 8: case 9: return IMP_STAGE_FAULT_HOMING;
        default: return IMP_STAGE_FAULT_ALARM;
        }
}

static bool alarm_loses_position(unsigned code) {
        return code == 1 || code == 3 || (code >= 6 && code <= 9);
}

/* ---- the line ------------------------------------------------------------------------ */

static speed_t baud_constant(unsigned baud) {
        switch (baud) {
        case 9600: return B9600;
        case 19200: return B19200;
        case 38400: return B38400;
        case 57600: return B57600;
        case 115200: return B115200;
        case 230400: return B230400;
        case 250000: return 0;          /* needs termios2; not offered */
        default: return 0;
        }
}

static int open_line(struct grbl *g, unsigned baud) {
        speed_t speed = baud_constant(baud);
        if (!speed)
                return -EINVAL;
        g->fd = open(g->device, O_RDWR | O_NOCTTY | O_NONBLOCK | O_CLOEXEC);
        if (g->fd < 0)
                return negative_errno();
        struct termios t;
        if (tcgetattr(g->fd, &t) < 0)
                return negative_errno();
        cfmakeraw(&t);                  /* 8N1, no echo, no CR/LF translation */
        t.c_cflag |= CLOCAL | CREAD;
        t.c_cflag &= (tcflag_t) ~CRTSCTS;
        if (cfsetispeed(&t, speed) < 0 || cfsetospeed(&t, speed) < 0 || tcsetattr(g->fd, TCSANOW, &t) < 0)
                return negative_errno();
        (void) tcflush(g->fd, TCIOFLUSH);
        return 0;
}

static int send_bytes(struct grbl *g, const char *s, size_t n) {
        uint64_t deadline = now_us() + (uint64_t) g->timeout_ms * 1000u;
        while (n > 0) {
                ssize_t w = write(g->fd, s, n);
                if (w > 0) {
                        s += w;
                        n -= (size_t) w;
                        continue;
                }
                if (w < 0 && errno != EAGAIN && errno != EINTR)
                        return negative_errno();
                if (now_us() >= deadline) {
                        snprintf(g->error, sizeof g->error, "%s: write blocked for %u ms", g->device, g->timeout_ms);
                        return -ETIMEDOUT;
                }
                struct pollfd p = { .fd = g->fd, .events = POLLOUT };
                (void) poll(&p, 1, 5);
        }
        return 0;
}

/* The next line (without CR/LF) into line, or -ETIMEDOUT at deadline_us. */
static int read_line(struct grbl *g, uint64_t deadline_us, char *line, size_t size) {
        for (;;) {
                char *nl = memchr(g->rx, '\n', g->rx_len);
                if (nl) {
                        size_t n = (size_t) (nl - g->rx);
                        size_t k = IMP_MIN(n, size - 1);
                        memcpy(line, g->rx, k);
                        line[k] = 0;
                        if (k && line[k - 1] == '\r')
                                line[--k] = 0;
                        memmove(g->rx, nl + 1, g->rx_len - n - 1);
                        g->rx_len -= n + 1;
                        return 0;
                }
                if (g->rx_len == sizeof g->rx)
                        g->rx_len = 0;  /* a line longer than any GRBL sends: drop it */
                uint64_t now = now_us();
                if (now >= deadline_us)
                        return -ETIMEDOUT;
                struct pollfd p = { .fd = g->fd, .events = POLLIN };
                int r = poll(&p, 1, (int) IMP_MIN((deadline_us - now + 999) / 1000, 1000u));
                if (r < 0 && errno != EINTR)
                        return negative_errno();
                if (r <= 0)
                        continue;
                ssize_t n = read(g->fd, g->rx + g->rx_len, sizeof g->rx - g->rx_len);
                if (n < 0 && errno != EAGAIN && errno != EINTR)
                        return negative_errno();
                if (n > 0)
                        g->rx_len += (size_t) n;
        }
}

/* ---- what the controller says ---------------------------------------------------------- */

static enum grbl_state parse_state(const char *s, size_t n) {
        static const struct { const char *name; enum grbl_state state; } names[] = {
                { "Idle", GS_IDLE }, { "Run", GS_RUN }, { "Hold:0", GS_HOLD_DONE }, { "Hold", GS_HOLD },
                { "Jog", GS_JOG }, { "Alarm", GS_ALARM }, { "Door", GS_DOOR }, { "Check", GS_CHECK },
                { "Home", GS_HOME }, { "Sleep", GS_SLEEP },
        };
        for (size_t i = 0; i < ARRAY_SIZE(names); i++)
                if (strncmp(s, names[i].name, strlen(names[i].name)) == 0 && strlen(names[i].name) <= n)
                        return names[i].state;
        return GS_UNKNOWN;
}

/* "<Idle|MPos:1.000,2.000,0.000|FS:0,0|Pn:X>": state, machine position, limit pins. */
static int parse_report(struct grbl *g, const char *l) {
        size_t len = strlen(l);
        if (len < 3 || l[len - 1] != '>')
                return -EBADMSG;
        const char *field = l + 1;
        g->state = parse_state(field, strcspn(field, "|>"));
        unsigned pins = 0;
        bool have_pos = false;
        while ((field = strchr(field, '|'))) {
                field++;
                if (strncmp(field, "MPos:", 5) == 0) {
                        double v[3];
                        if (sscanf(field + 5, "%lf,%lf,%lf", &v[0], &v[1], &v[2]) != 3)
                                return -EBADMSG;
                        for (unsigned a = 0; a < IMP_STAGE_MAX_AXES; a++)
                                g->mpos_mm[a] = v[a] + (g->negative_space ? g->travel_mm[a] : 0);
                        have_pos = true;
                } else if (strncmp(field, "Pn:", 3) == 0)
                        for (const char *c = field + 3; *c && *c != '|' && *c != '>'; c++)
                                if (*c >= 'X' && *c <= 'Z')
                                        pins |= 1u << (*c - 'X');
        }
        g->pins = pins;
        return have_pos ? 0 : -EBADMSG;
}

enum line_kind { LINE_OK, LINE_ERROR, LINE_ALARM, LINE_REPORT, LINE_BANNER, LINE_OTHER };

/* Every line read goes through here, whatever the caller waits for. */
static enum line_kind take_line(struct grbl *g, const char *l) {
        if (strcmp(l, "ok") == 0 || strncmp(l, "error:", 6) == 0) {
                bool ok = l[0] == 'o';
                g->line_error = ok ? 0 : atoi(l + 6);
                if (g->pending_ok)
                        g->pending_ok--;
                if (g->homing && g->pending_ok == 0) {
                        g->homing = false;
                        g->homed = ok;
                }
                return ok ? LINE_OK : LINE_ERROR;
        }
        if (strncmp(l, "ALARM:", 6) == 0) {
                g->alarm = (unsigned) atoi(l + 6);
                g->locked = g->alarm == 1 || g->alarm == 2;
                if (alarm_loses_position(g->alarm))
                        g->homed = false;
                g->homing = false;
                g->state = GS_ALARM;
                return LINE_ALARM;
        }
        if (l[0] == '<')
                return parse_report(g, l) < 0 ? LINE_OTHER : LINE_REPORT;
        if (strncmp(l, GRBL_BANNER, strlen(GRBL_BANNER)) == 0) {
                /* A restart drops every line GRBL had: no answer will come for them. */
                if (!g->expect_banner && !g->alarm) {
                        g->restarted = true;
                        g->homed = false;
                }
                g->expect_banner = g->locked = g->homing = false;
                g->pending_ok = 0;
                return LINE_BANNER;
        }
        return LINE_OTHER;              /* [MSG:...], settings, echoes */
}

/* Reads lines until one of a kind in want_mask arrives (returns its enum line_kind), an
 * alarm interrupts (-EIO unless an alarm is wanted), or the deadline (-ETIMEDOUT).
 * ret_line (may be NULL) gets the last line read. */
static int wait_line(struct grbl *g, unsigned want_mask, unsigned timeout_ms, const char *what,
                     char *ret_line, size_t size) {
        uint64_t deadline = now_us() + (uint64_t) timeout_ms * 1000u;
        char line[256];
        for (;;) {
                int r = read_line(g, deadline, line, sizeof line);
                if (r == -ETIMEDOUT) {
                        snprintf(g->error, sizeof g->error, "%s: no answer to %s within %u ms", g->device, what,
                                 timeout_ms);
                        return r;
                }
                if (r < 0) {
                        snprintf(g->error, sizeof g->error, "%s: reading: %s", g->device, strerror(-r));
                        return r;
                }
                enum line_kind k = take_line(g, line);
                if (ret_line)
                        snprintf(ret_line, size, "%s", line);
                if (want_mask & (1u << k))
                        return (int) k;
                if (k == LINE_ALARM) {
                        snprintf(g->error, sizeof g->error, "%s: %s: ALARM:%u (%s)", g->device, what, g->alarm,
                                 alarm_text(g->alarm));
                        return -EIO;
                }
        }
}

/* Takes what has arrived unasked (alarms, a banner, late answers) without waiting. */
static int drain(struct grbl *g) {
        char line[256];
        int r;
        while ((r = read_line(g, 0, line, sizeof line)) == 0)
                (void) take_line(g, line);
        if (r == -ETIMEDOUT)
                return 0;
        snprintf(g->error, sizeof g->error, "%s: reading: %s", g->device, strerror(-r));
        return r;
}

static int resync(struct grbl *g);

/* One line and its answer: 0 on "ok", -EIO on "error:N" or an alarm. */
static int command(struct grbl *g, const char *line) {
        char buf[160];
        int n = snprintf(buf, sizeof buf, "%s\n", line);
        int r = resync(g);
        if (r >= 0)
                r = send_bytes(g, buf, (size_t) n);
        if (r < 0)
                return r;
        g->pending_ok++;
        while (g->pending_ok > 0) {
                r = wait_line(g, 1u << LINE_OK | 1u << LINE_ERROR, g->timeout_ms, line, NULL, 0);
                if (r < 0)
                        return r;
                if (g->pending_ok == 0 && g->line_error) {
                        snprintf(g->error, sizeof g->error, "%s: \"%s\": error:%d (%s)", g->device, line,
                                 g->line_error, error_text(g->line_error));
                        return -EIO;
                }
        }
        return 0;
}

/* Soft reset and its banner. GRBL drops its input buffer and planner. */
static int soft_reset(struct grbl *g) {
        g->expect_banner = true;
        int r = send_bytes(g, GRBL_CH_RESET, 1);
        if (r < 0)
                return r;
        r = wait_line(g, 1u << LINE_BANNER | 1u << LINE_ALARM, g->timeout_ms, "soft reset", NULL, 0);
        if (r >= 0 && g->expect_banner)      /* an alarm came first (reset in motion): the banner follows */
                r = wait_line(g, 1u << LINE_BANNER, g->timeout_ms, "soft reset", NULL, 0);
        return r < 0 ? r : 0;
}

/* '?' and its report. GRBL locked by an alarm reports nothing: the last report stands. */
static int query_status(struct grbl *g) {
        int r = drain(g);
        if (r < 0 || g->locked)
                return r;
        r = send_bytes(g, "?", 1);
        while (r >= 0) {
                r = wait_line(g, 1u << LINE_REPORT | 1u << LINE_ALARM, g->timeout_ms, "status query '?'", NULL, 0);
                if (r == LINE_REPORT || (r >= 0 && g->locked))
                        return 0;
        }
        return r;
}

/* Answers still owed (a line timed out, the controller may have dropped it) would be taken
 * for the next line's. Late ones are taken first; if some are still owed and the stage is
 * not moving, a reset (which keeps the position at rest) starts the count afresh. */
static int resync(struct grbl *g) {
        int r = drain(g);
        if (r < 0 || g->pending_ok == 0 || g->homing)
                return r;
        r = query_status(g);
        if (r < 0)
                return r;
        if (g->state != GS_IDLE && g->state != GS_ALARM) {
                snprintf(g->error, sizeof g->error, "%s: %u answers owed while the stage moves", g->device,
                         g->pending_ok);
                return -EBUSY;
        }
        return soft_reset(g);
}

/* ---- operations -------------------------------------------------------------------------- */

static void grbl_close(void *state) {
        struct grbl *g = state;
        if (!g)
                return;
        if (g->fd >= 0)
                close(g->fd);
        free(g);
}

/* "$$": the travel of each axis ($130..$132). */
static int read_travel(struct grbl *g) {
        char line[256];
        int r = send_bytes(g, "$$\n", 3);
        if (r < 0)
                return r;
        g->pending_ok++;
        for (;;) {
                r = wait_line(g, 1u << LINE_OK | 1u << LINE_ERROR | 1u << LINE_OTHER, g->timeout_ms, "\"$$\"",
                              line, sizeof line);
                if (r < 0)
                        return r;
                unsigned id;
                double v;
                if (sscanf(line, "$%u=%lf", &id, &v) == 2 && id >= GRBL_SETTING_TRAVEL &&
                    id < GRBL_SETTING_TRAVEL + IMP_STAGE_MAX_AXES)
                        g->travel_mm[id - GRBL_SETTING_TRAVEL] = v;
                if (strcmp(line, "ok") == 0)
                        return 0;
                if (strncmp(line, "error:", 6) == 0)
                        return -EIO;
        }
}

/* ";space=positive" (default) or ";space=negative". */
static int parse_space(const char *address, bool *ret_negative) {
        char v[16];
        int r = address_option(address, "space", v, sizeof v);
        if (r == -ENOENT)
                return 0;
        if (r < 0 || (strcmp(v, "positive") != 0 && strcmp(v, "negative") != 0))
                return -EINVAL;
        *ret_negative = strcmp(v, "negative") == 0;
        return 0;
}

static int grbl_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct grbl *g = calloc(1, sizeof *g);
        if (!g)
                return -ENOMEM;
        g->fd = -1;
        g->timeout_ms = timeout_ms ? timeout_ms : GRBL_DEFAULT_TIMEOUT_MS;
        g->hold_timeout_ms = GRBL_HOLD_TIMEOUT_MS;
        g->n_axes = IMP_STAGE_MAX_AXES;
        unsigned baud = GRBL_DEFAULT_BAUD;
        int r = address_main(address, g->device, sizeof g->device);
        if (r >= 0 && ((r = address_option_uint(address, "baud", 1200, 4000000, &baud)) < 0 ||
                       (r = address_option_uint(address, "timeout_ms", 1, 60000, &g->timeout_ms)) < 0 ||
                       (r = address_option_uint(address, "hold_timeout_ms", 1, 600000, &g->hold_timeout_ms)) < 0 ||
                       (r = address_option_uint(address, "axes", 2, IMP_STAGE_MAX_AXES, &g->n_axes)) < 0))
                goto fail;
        if (r >= 0)
                r = parse_space(address, &g->negative_space);
        if (r < 0 || (r = open_line(g, baud)) < 0)
                goto fail;
        /* A reset gives a known state and proves it is GRBL (the banner). */
        r = soft_reset(g);
        if (r == -ETIMEDOUT)
                r = -ENODEV;
        if (r < 0 || (r = read_travel(g)) < 0 || (r = query_status(g)) < 0)
                goto fail;
        *ret_state = g;
        return 0;
fail:
        grbl_close(g);
        return r;
}

static int grbl_get_info(void *state, struct imp_stage_info *ret) {
        struct grbl *g = state;
        snprintf(ret->model, sizeof ret->model, "GRBL on %.80s", g->device);
        ret->n_axes = g->n_axes;
        for (unsigned a = 0; a < IMP_STAGE_MAX_AXES; a++)
                ret->travel_mm[a] = a < g->n_axes ? g->travel_mm[a] : 0;
        return 0;
}

static int grbl_move_to(void *state, const double target_mm[IMP_STAGE_MAX_AXES], unsigned mask, double speed_mm_s) {
        struct grbl *g = state;
        char line[160];
        int n = snprintf(line, sizeof line, "G90G1");
        for (unsigned a = 0; a < g->n_axes; a++)
                if (mask & (1u << a))
                        n += snprintf(line + n, sizeof line - (size_t) n, "%c%.3f", "XYZ"[a],
                                      target_mm[a] - (g->negative_space ? g->travel_mm[a] : 0));
        snprintf(line + n, sizeof line - (size_t) n, "F%.0f", speed_mm_s * MM_S_TO_MM_MIN);
        int r = command(g, line);
        if (r >= 0) {
                g->held = false;
                g->state = GS_RUN;      /* until a report says otherwise: the move is queued */
        }
        return r;
}

static int grbl_home(void *state) {
        struct grbl *g = state;
        int r = resync(g);
        if (r < 0)
                return r;
        r = send_bytes(g, "$H\n", 3);
        if (r < 0)
                return r;
        g->pending_ok++;
        g->homing = true;
        g->homed = g->held = false;
        return 0;
}

static int grbl_get_status(void *state, struct imp_stage_status *ret) {
        struct grbl *g = state;
        int r = query_status(g);
        if (r < 0)
                return r;
        bool moving = g->state == GS_RUN || g->state == GS_JOG || g->state == GS_HOLD || g->state == GS_HOLD_DONE;
        bool homing = g->homing || g->state == GS_HOME;
        *ret = (struct imp_stage_status) {
                .flags = (moving ? IMP_STAGE_MOVING : 0) | (homing ? IMP_STAGE_HOMING : 0) |
                         (g->homed ? IMP_STAGE_HOMED : 0) | (g->held ? IMP_STAGE_HELD : 0) |
                         (g->state == GS_IDLE && !g->pending_ok && !g->held && !homing ? IMP_STAGE_IN_POSITION : 0),
                .fault = g->alarm ? fault_of_alarm(g->alarm) :
                         g->restarted ? IMP_STAGE_FAULT_LOST_POSITION : IMP_STAGE_FAULT_NONE,
                .fault_code = g->alarm,
                .limit_mask = g->pins & ((1u << g->n_axes) - 1),
        };
        for (unsigned a = 0; a < g->n_axes; a++)
                ret->position_mm[a] = g->mpos_mm[a];
        if (g->restarted && !g->alarm)
                snprintf(g->error, sizeof g->error, "%s: the controller restarted (banner unasked): position lost",
                         g->device);
        return 0;
}

/* Feed hold, wait until the hold is complete, then a reset drops the rest of the move. */
static int grbl_soft_stop(void *state) {
        struct grbl *g = state;
        int r = query_status(g);
        if (r < 0)
                return r;
        if (g->state == GS_IDLE || g->state == GS_ALARM || g->locked)
                return 0;
        bool was_moving = g->state != GS_HOME;
        if (was_moving && (r = send_bytes(g, "!", 1)) < 0)
                return r;
        uint64_t deadline = now_us() + (uint64_t) g->hold_timeout_ms * 1000u;
        while (was_moving && g->state != GS_HOLD_DONE && g->state != GS_IDLE && g->state != GS_ALARM) {
                if (now_us() >= deadline) {
                        snprintf(g->error, sizeof g->error, "%s: feed hold not complete after %u ms", g->device,
                                 g->hold_timeout_ms);
                        return -ETIMEDOUT;
                }
                usleep(5000);
                if ((r = query_status(g)) < 0)
                        return r;
        }
        /* Homing ignores a feed hold: the reset stops it (ALARM:6, not homed). */
        r = soft_reset(g);
        if (r < 0 && !(r == -EIO && g->alarm))
                return r;
        g->held = was_moving && !g->alarm;
        return query_status(g);
}

static int grbl_clear_fault(void *state) {
        struct grbl *g = state;
        int r = drain(g);
        if (r >= 0 && g->locked)
                r = soft_reset(g);
        if (r >= 0)
                r = query_status(g);
        if (r >= 0 && g->state == GS_ALARM)
                r = command(g, "$X");
        if (r < 0)
                return r;
        g->alarm = 0;
        g->restarted = false;
        return query_status(g);
}

static const char *grbl_last_error(void *state) {
        struct grbl *g = state;
        return g->error;
}

const struct imp_stage_ops imp_stage_grbl_ops = {
        .name = "grbl",
        .open = grbl_open,                      /* "/dev/ttyUSB0[;baud=N][;timeout_ms=N][;axes=2|3][;space=negative]…" */
        .close = grbl_close,                    /* closes the line; no reset */
        .get_info = grbl_get_info,              /* axes from the address, travel from $130..$132 */
        .move_to = grbl_move_to,                /* "G90G1X..Y..F..", waits for its "ok" (queued, not done) */
        .home = grbl_home,                      /* "$H"; its "ok" is taken when homing ends */
        .get_status = grbl_get_status,          /* '?' and the report; alarms and banners on the way */
        .soft_stop = grbl_soft_stop,            /* '!', wait for Hold:0, Ctrl-X: position kept */
        .clear_fault = grbl_clear_fault,        /* Ctrl-X if locked, then "$X" */
        .last_error = grbl_last_error,          /* the line, the code and GRBL's meaning */
};
