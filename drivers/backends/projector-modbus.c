/* Projector backend "modbus": the pattern sequencer on the rig's Modbus TCP controller
 * (docs/dome-registers.md, "Projector sequencer"), over libmodbus with the shared client
 * policy of modbus-link.h. Descriptors are uploaded as registers; show(i) writes the show
 * register and reads the shown register back, so it returns with the pattern on. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "macro.h"
#include "modbus-link.h"
#include "projector.h"

#define REG_MAGIC               0x0000
#define REG_PROJ_CAPACITY       0x0300
#define PROJ_IDENT_USED         3       /* capacity, width, height */
#define REG_PROJ_COUNT          0x0303
#define REG_PROJ_SHOW           0x0304
#define REG_PROJ_SHOWN          0x0305
#define PROJ_STATUS_USED        5       /* count, show, shown, fault, fault index */
#define REG_PROJ_COMMAND        0x0308
#define REG_PROJ_DESC(i)        (0x0400 + 8 * (i))
#define PROJ_DESC_STRIDE        8
#define PROJ_DESCS_PER_WRITE    (MB_LINK_MAX_WRITE / PROJ_DESC_STRIDE)
#define PROJ_DARK               0xFFFFu
#define PROJ_CMD_TRIGGER        2
#define MAGIC                   0x494D
#define MAP_VERSION             1

struct proj_mb {
        struct mb_link link;
        unsigned capacity, width, height;
        unsigned n_uploaded;
        uint64_t shown_at_ns;
        char error[384];
};

static uint64_t mono_ns(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000000u + (uint64_t) ts.tv_nsec;
}

static void proj_mb_close(void *state) {
        struct proj_mb *m = state;
        if (!m)
                return;
        mb_link_close(&m->link);
        free(m);
}

static int proj_mb_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct proj_mb *m = calloc(1, sizeof *m);
        if (!m)
                return -ENOMEM;
        int r = mb_link_init(&m->link, address, timeout_ms);
        if (r < 0)
                goto fail;
        uint16_t id[2], p[PROJ_IDENT_USED];
        if ((r = mb_link_xfer(&m->link, false, REG_MAGIC, 2, id)) < 0 ||
            (r = mb_link_xfer(&m->link, false, REG_PROJ_CAPACITY, PROJ_IDENT_USED, p)) < 0)
                goto fail;
        r = -ENODEV;            /* something answers, but it is not a controller with a sequencer */
        if (id[0] != MAGIC || id[1] != MAP_VERSION || p[0] == 0 || p[0] > IMP_PROJECTOR_MAX_PATTERNS)
                goto fail;
        m->capacity = p[0];
        m->width = p[1];
        m->height = p[2];
        *ret_state = m;
        return 0;
fail:
        proj_mb_close(m);
        return r;
}

static int proj_mb_get_info(void *state, struct imp_projector_info *ret) {
        struct proj_mb *m = state;
        snprintf(ret->model, sizeof ret->model, "modbus sequencer v%d at %.40s", MAP_VERSION, m->link.host);
        ret->serial[0] = 0;
        ret->width = (int) m->width;
        ret->height = (int) m->height;
        ret->max_patterns = m->capacity;
        return 0;
}

static bool fits_u16(int v) {
        return v >= 0 && v <= 0xFFFF;
}

/* One descriptor as registers; -EINVAL (with the reason) when a field does not fit. */
static int encode(struct proj_mb *m, unsigned i, const struct imp_pattern *p, uint16_t d[PROJ_DESC_STRIDE]) {
        double period100 = p->kind == IMP_PAT_PHASE ? p->period_px * 100.0 : 0.0;
        double rounded = nearbyint(period100);
        if (!isfinite(period100) || rounded < 0 || rounded > 0xFFFF || fabs(period100 - rounded) > 1e-6) {
                snprintf(m->error, sizeof m->error,
                         "pattern %u: period %g px is not a multiple of 0.01 px up to 655.35 px", i, p->period_px);
                return -EINVAL;
        }
        bool gray = p->kind == IMP_PAT_GRAY, phase = p->kind == IMP_PAT_PHASE;
        int bit = gray ? p->bit : 0, nbits = gray ? p->nbits : 0;
        int step = phase ? p->step : 0, steps = phase ? p->steps : 0;
        if (p->kind < IMP_PAT_NONE || p->kind > IMP_PAT_PHASE || (p->axis != 0 && p->axis != 1) ||
            !fits_u16(bit) || !fits_u16(nbits) || !fits_u16(step) || !fits_u16(steps)) {
                snprintf(m->error, sizeof m->error, "pattern %u: a field is outside the register range", i);
                return -EINVAL;
        }
        d[0] = (uint16_t) p->kind;
        d[1] = (uint16_t) p->axis;
        d[2] = (uint16_t) bit;
        d[3] = (uint16_t) nbits;
        d[4] = gray && p->inverse;
        d[5] = (uint16_t) rounded;
        d[6] = (uint16_t) step;
        d[7] = (uint16_t) steps;
        return 0;
}

static int proj_mb_upload(void *state, const struct imp_pattern *patterns, unsigned n) {
        struct proj_mb *m = state;
        m->error[0] = 0;
        if (n > m->capacity) {
                snprintf(m->error, sizeof m->error, "%u patterns, the sequencer holds %u", n, m->capacity);
                return -E2BIG;
        }
        m->n_uploaded = 0;
        uint16_t regs[PROJ_DESCS_PER_WRITE * PROJ_DESC_STRIDE];
        for (unsigned first = 0; first < n; first += PROJ_DESCS_PER_WRITE) {
                unsigned k = IMP_MIN(n - first, (unsigned) PROJ_DESCS_PER_WRITE);
                for (unsigned j = 0; j < k; j++) {
                        int r = encode(m, first + j, &patterns[first + j], &regs[j * PROJ_DESC_STRIDE]);
                        if (r < 0)
                                return r;
                }
                int r = mb_link_xfer(&m->link, true, REG_PROJ_DESC(first), (int) (k * PROJ_DESC_STRIDE), regs);
                if (r < 0)
                        return r;
        }
        int r = mb_link_write1(&m->link, REG_PROJ_COUNT, (uint16_t) n);
        if (r < 0)
                return r;
        uint16_t count;
        if ((r = mb_link_xfer(&m->link, false, REG_PROJ_COUNT, 1, &count)) < 0)
                return r;
        if (count != n) {
                snprintf(m->error, sizeof m->error, "sequencer holds %u patterns after an upload of %u", count, n);
                return -EIO;
        }
        m->n_uploaded = n;
        return 0;
}

static int proj_mb_show(void *state, unsigned index) {
        struct proj_mb *m = state;
        m->error[0] = 0;
        if (index >= m->n_uploaded || index >= PROJ_DARK)
                return -EINVAL;
        int r = mb_link_write1(&m->link, REG_PROJ_SHOW, (uint16_t) index);
        if (r < 0)
                return r;
        uint16_t shown;
        if ((r = mb_link_xfer(&m->link, false, REG_PROJ_SHOWN, 1, &shown)) < 0)
                return r;
        if (shown != index) {
                snprintf(m->error, sizeof m->error, "asked for pattern %u, the sequencer shows %s%u", index,
                         shown == PROJ_DARK ? "dark " : "", shown == PROJ_DARK ? 0u : shown);
                return -EIO;
        }
        m->shown_at_ns = mono_ns();
        return 0;
}

static int proj_mb_dark(void *state) {
        struct proj_mb *m = state;
        m->error[0] = 0;
        return mb_link_write1(&m->link, REG_PROJ_SHOW, PROJ_DARK);
}

static int proj_mb_trigger(void *state) {
        struct proj_mb *m = state;
        m->error[0] = 0;
        return mb_link_write1(&m->link, REG_PROJ_COMMAND, PROJ_CMD_TRIGGER);
}

static int proj_mb_get_status(void *state, struct imp_projector_status *ret) {
        struct proj_mb *m = state;
        m->error[0] = 0;
        uint16_t s[PROJ_STATUS_USED];
        int r = mb_link_xfer(&m->link, false, REG_PROJ_COUNT, PROJ_STATUS_USED, s);
        if (r < 0)
                return r;
        ret->n_uploaded = s[0];
        ret->shown = s[2] == PROJ_DARK ? -1 : (int) s[2];
        ret->fault = s[3] != 0;
        ret->fault_code = s[3];
        ret->shown_at_ns = m->shown_at_ns;
        return 0;
}

static const char *proj_mb_last_error(void *state) {
        struct proj_mb *m = state;
        return m->error[0] ? m->error : m->link.error;
}

const struct imp_projector_ops imp_projector_modbus_ops = {
        .name = "modbus",
        .open = proj_mb_open,                   /* "host:port[;timeout_ms=][;retries=][;unit=]" */
        .close = proj_mb_close,                 /* closes the TCP connection */
        .get_info = proj_mb_get_info,           /* capacity and resolution read at open */
        .upload = proj_mb_upload,               /* descriptors in 15-pattern writes, then COUNT */
        .show = proj_mb_show,                   /* SHOW write, SHOWN read back */
        .dark = proj_mb_dark,                   /* SHOW = 0xFFFF */
        .trigger = proj_mb_trigger,             /* COMMAND 2 */
        .get_status = proj_mb_get_status,       /* one read of COUNT..FAULT_INDEX */
        .last_error = proj_mb_last_error,       /* encoding detail or register/attempt/reason */
};
