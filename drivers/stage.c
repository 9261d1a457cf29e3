/* Stage wrapper: backend lookup, argument checks, soft limits, the rules "no move with a
 * fault latched" and "no move without a known position", and settling by polling the
 * status, with a soft-stop when a move does not settle in time. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "stage.h"

#ifdef IMPASTO_HAVE_MODBUS
extern const struct imp_stage_ops imp_stage_modbus_ops;
#endif
extern const struct imp_stage_ops imp_stage_grbl_ops;

static const struct imp_stage_ops *const stage_backends[] = {
#ifdef IMPASTO_HAVE_MODBUS
        &imp_stage_modbus_ops,
#endif
        &imp_stage_grbl_ops,
        NULL,
};

/* Status polls while waiting (IMP_STAGE_POLL_INTERVAL_MS). GRBL's own guidance is at most 5
 * to 10 reports a second on a slow line; 10 ms is fine on USB and loopback and keeps the
 * settle latency small. */

struct imp_stage {
        const struct imp_stage_ops *ops;
        void *state;
        struct imp_stage_info info;
        struct imp_stage_config config;
        double target_mm[IMP_STAGE_MAX_AXES];   /* of the last move; 0 after homing */
        unsigned target_mask;                   /* axes the settle check compares */
        char error[512];
};

static const char *const fault_names[_IMP_STAGE_FAULT_MAX] = {
        [IMP_STAGE_FAULT_NONE] = "no fault",
        [IMP_STAGE_FAULT_LIMIT] = "hard limit switch hit",
        [IMP_STAGE_FAULT_LOST_POSITION] = "position lost",
        [IMP_STAGE_FAULT_ALARM] = "controller alarm",
        [IMP_STAGE_FAULT_HOMING] = "homing failed",
        [IMP_STAGE_FAULT_TRAVEL] = "target outside travel",
};

const char *imp_stage_fault_name(enum imp_stage_fault f) {
        return (unsigned) f < _IMP_STAGE_FAULT_MAX ? fault_names[f] : "unknown fault";
}

const struct imp_stage_ops *imp_stage_backend(const char *name) {
        if (!name)
                return NULL;
        for (size_t i = 0; stage_backends[i]; i++)
                if (strcmp(stage_backends[i]->name, name) == 0)
                        return stage_backends[i];
        return NULL;
}

_printf_(3, 4)
static int stage_fail(struct imp_stage *s, int r, const char *fmt, ...) {
        char what[320];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(what, sizeof what, fmt, ap);
        va_end(ap);
        const char *detail = s->ops->last_error ? s->ops->last_error(s->state) : NULL;
        snprintf(s->error, sizeof s->error, "stage %s: %s: %s%s%s", s->ops->name, what, strerror(-r),
                 detail && *detail ? ": " : "", detail ? detail : "");
        return r;
}

/* "(10.000, 20.000) mm" for the axes of mask, or of the stage when mask is 0. */
static const char *pose_str(const struct imp_stage *s, const double mm[IMP_STAGE_MAX_AXES], unsigned mask,
                            char *buf, size_t size) {
        size_t n = 0;
        buf[0] = 0;
        for (unsigned a = 0; a < s->info.n_axes && n < size; a++)
                if (!mask || mask & (1u << a))
                        n += (size_t) snprintf(buf + n, size - n, "%s%c %.3f", n ? "," : "(", "xyz"[a], mm[a]);
        if (n < size)
                snprintf(buf + n, size - n, ") mm");
        return buf;
}

void imp_stage_default_config(const struct imp_stage_info *info, struct imp_stage_config *ret) {
        *ret = (struct imp_stage_config) {
                .speed_mm_s = IMP_STAGE_DEFAULT_SPEED_MM_S,
                .tolerance_mm = IMP_STAGE_DEFAULT_TOLERANCE_MM,
        };
        for (unsigned a = 0; a < IMP_STAGE_MAX_AXES; a++)
                ret->max_mm[a] = a < info->n_axes ? info->travel_mm[a] : 0;
}

int imp_stage_open(const char *backend, const char *address, unsigned timeout_ms,
                   struct imp_stage **ret_stage) {
        if (!backend || !address || !ret_stage)
                return -EINVAL;
        const struct imp_stage_ops *ops = imp_stage_backend(backend);
        if (!ops)
                return -ENOENT;
        struct imp_stage *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        s->ops = ops;
        int r = ops->open(address, timeout_ms, &s->state);
        if (r < 0) {
                free(s);
                return r;
        }
        r = ops->get_info(s->state, &s->info);
        if (r >= 0 && (s->info.n_axes < 2 || s->info.n_axes > IMP_STAGE_MAX_AXES))
                r = -ERANGE;
        for (unsigned a = 0; r >= 0 && a < s->info.n_axes; a++)
                if (!isfinite(s->info.travel_mm[a]) || s->info.travel_mm[a] <= 0)
                        r = -ERANGE;
        if (r < 0) {
                ops->close(s->state);
                free(s);
                return r;
        }
        imp_stage_default_config(&s->info, &s->config);
        *ret_stage = s;
        return 0;
}

void imp_stage_close(struct imp_stage *s) {
        if (!s)
                return;
        struct imp_stage_status st;
        if (s->ops->soft_stop && s->ops->get_status(s->state, &st) >= 0 &&
            st.flags & (IMP_STAGE_MOVING | IMP_STAGE_HOMING))
                (void) s->ops->soft_stop(s->state);
        s->ops->close(s->state);
        free(s);
}

const char *imp_stage_backend_name(const struct imp_stage *s) {
        return s ? s->ops->name : NULL;
}

const char *imp_stage_last_error(const struct imp_stage *s) {
        return s ? s->error : "";
}

int imp_stage_get_info(struct imp_stage *s, struct imp_stage_info *ret_info) {
        if (!s || !ret_info)
                return -EINVAL;
        *ret_info = s->info;
        return 0;
}

int imp_stage_configure(struct imp_stage *s, const struct imp_stage_config *c) {
        if (!s || !c)
                return -EINVAL;
        s->error[0] = 0;
        if (!isfinite(c->speed_mm_s) || c->speed_mm_s <= 0 || !isfinite(c->tolerance_mm) || c->tolerance_mm <= 0)
                return stage_fail(s, -EINVAL, "config: speed %g mm/s and tolerance %g mm must be positive",
                                  c->speed_mm_s, c->tolerance_mm);
        for (unsigned a = 0; a < s->info.n_axes; a++)
                if (!(c->min_mm[a] >= 0 && c->min_mm[a] <= c->max_mm[a] && c->max_mm[a] <= s->info.travel_mm[a]))
                        return stage_fail(s, -ERANGE, "config: soft limits of %c [%g, %g] mm outside the travel [0, %g] mm",
                                          "xyz"[a], c->min_mm[a], c->max_mm[a], s->info.travel_mm[a]);
        s->config = *c;
        return 0;
}

int imp_stage_get_config(struct imp_stage *s, struct imp_stage_config *ret_config) {
        if (!s || !ret_config)
                return -EINVAL;
        *ret_config = s->config;
        return 0;
}

int imp_stage_get_status(struct imp_stage *s, struct imp_stage_status *ret_status) {
        if (!s || !ret_status)
                return -EINVAL;
        s->error[0] = 0;
        struct imp_stage_status st = {};
        int r = s->ops->get_status(s->state, &st);
        if (r < 0)
                return stage_fail(s, r, "reading status");
        *ret_status = st;
        return 0;
}

/* The status before a command that needs an idle stage: refuses on a fault or a running motion. */
static int ready_status(struct imp_stage *s, const char *what, struct imp_stage_status *ret) {
        int r = s->ops->get_status(s->state, ret);
        if (r < 0)
                return stage_fail(s, r, "%s: reading status", what);
        if (ret->fault != IMP_STAGE_FAULT_NONE)
                return stage_fail(s, -EIO, "%s: %s latched (controller code %u), clear it first", what,
                                  imp_stage_fault_name(ret->fault), ret->fault_code);
        if (ret->flags & (IMP_STAGE_MOVING | IMP_STAGE_HOMING))
                return stage_fail(s, -EBUSY, "%s: the stage is still %s", what,
                                  ret->flags & IMP_STAGE_HOMING ? "homing" : "moving");
        return 0;
}

int imp_stage_home(struct imp_stage *s) {
        if (!s)
                return -EINVAL;
        s->error[0] = 0;
        if (!s->ops->home)
                return -EOPNOTSUPP;
        struct imp_stage_status st;
        int r = ready_status(s, "home", &st);
        if (r < 0)
                return r;
        r = s->ops->home(s->state);
        if (r < 0)
                return stage_fail(s, r, "home");
        memset(s->target_mm, 0, sizeof s->target_mm);
        s->target_mask = 0;     /* homing ends where the switches are: HOMED is the test */
        return 0;
}

/* Argument and soft-limit checks; nothing is sent. */
static int check_target(struct imp_stage *s, const double *t, unsigned mask, const char *what) {
        unsigned all = (1u << s->info.n_axes) - 1;
        if (!mask || mask & ~all)
                return stage_fail(s, -EINVAL, "%s: axis mask 0x%x on a %u-axis stage", what, mask, s->info.n_axes);
        for (unsigned a = 0; a < s->info.n_axes; a++) {
                if (!(mask & (1u << a)))
                        continue;
                if (!isfinite(t[a]))
                        return stage_fail(s, -EINVAL, "%s: %c is not a finite number", what, "xyz"[a]);
                if (t[a] < s->config.min_mm[a] || t[a] > s->config.max_mm[a])
                        return stage_fail(s, -ERANGE, "%s: %c outside the soft limits [%.3f, %.3f] mm", what,
                                          "xyz"[a], s->config.min_mm[a], s->config.max_mm[a]);
        }
        return 0;
}

int imp_stage_move_to(struct imp_stage *s, const double target_mm[IMP_STAGE_MAX_AXES], unsigned mask) {
        if (!s || !target_mm)
                return -EINVAL;
        s->error[0] = 0;
        char what[160], pose[128];
        snprintf(what, sizeof what, "move to %s", pose_str(s, target_mm, mask, pose, sizeof pose));
        int r = check_target(s, target_mm, mask, what);
        if (r < 0)
                return r;
        if (!s->ops->move_to)
                return -EOPNOTSUPP;
        struct imp_stage_status st;
        r = ready_status(s, what, &st);
        if (r < 0)
                return r;
        if (!(st.flags & IMP_STAGE_HOMED))
                return stage_fail(s, -ESTALE, "%s: position not known (never homed, or lost since), home first", what);
        r = s->ops->move_to(s->state, target_mm, mask, s->config.speed_mm_s);
        if (r < 0)
                return stage_fail(s, r, "%s", what);
        for (unsigned a = 0; a < s->info.n_axes; a++)
                if (mask & (1u << a))
                        s->target_mm[a] = target_mm[a];
        s->target_mask = mask;
        return 0;
}

static uint64_t now_us(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000u + (uint64_t) ts.tv_nsec / 1000u;
}

/* Settled: idle, in position, homed, and the read-back of each commanded axis on target. */
static bool settled(const struct imp_stage *s, const struct imp_stage_status *st) {
        if (st->flags & (IMP_STAGE_MOVING | IMP_STAGE_HOMING) || !(st->flags & IMP_STAGE_IN_POSITION) ||
            !(st->flags & IMP_STAGE_HOMED))
                return false;
        for (unsigned a = 0; a < s->info.n_axes; a++)
                if (s->target_mask & (1u << a) &&
                    !(fabs(st->position_mm[a] - s->target_mm[a]) <= s->config.tolerance_mm))
                        return false;
        return true;
}

uint64_t imp_stage_deadline_us(unsigned timeout_ms) {
        return now_us() + (uint64_t) timeout_ms * 1000u;
}

int imp_stage_poll_settled(struct imp_stage *s, uint64_t deadline_us, unsigned timeout_ms,
                           struct imp_stage_status *ret_status) {
        if (!s)
                return -EINVAL;
        s->error[0] = 0;
        char pose[128], target[128];
        struct imp_stage_status st = {};
        int r = s->ops->get_status(s->state, &st);
        if (r < 0)
                return stage_fail(s, r, "waiting to settle: reading status");
        if (ret_status)
                *ret_status = st;
        if (st.fault != IMP_STAGE_FAULT_NONE)
                return stage_fail(s, -EIO, "waiting to settle: %s (controller code %u) at %s",
                                  imp_stage_fault_name(st.fault), st.fault_code,
                                  pose_str(s, st.position_mm, 0, pose, sizeof pose));
        if (settled(s, &st))
                return 0;
        if (now_us() < deadline_us)
                return -EAGAIN;
        if (s->ops->soft_stop)
                (void) s->ops->soft_stop(s->state);
        return stage_fail(s, -ETIMEDOUT, "not settled after %u ms (%s%s), stopped at %s, target %s",
                          timeout_ms, st.flags & IMP_STAGE_HOMING ? "homing" :
                          st.flags & IMP_STAGE_MOVING ? "still moving" : "idle off target",
                          st.flags & IMP_STAGE_HOMED ? "" : ", not homed",
                          pose_str(s, st.position_mm, 0, pose, sizeof pose),
                          s->target_mask ? pose_str(s, s->target_mm, s->target_mask, target, sizeof target)
                                         : "home");
}

int imp_stage_wait_settled(struct imp_stage *s, unsigned timeout_ms, struct imp_stage_status *ret_status) {
        uint64_t deadline = imp_stage_deadline_us(timeout_ms);
        int r;
        while ((r = imp_stage_poll_settled(s, deadline, timeout_ms, ret_status)) == -EAGAIN)
                usleep(IMP_STAGE_POLL_INTERVAL_MS * 1000u);
        return r;
}

int imp_stage_soft_stop(struct imp_stage *s) {
        if (!s)
                return -EINVAL;
        s->error[0] = 0;
        if (!s->ops->soft_stop)
                return -EOPNOTSUPP;
        int r = s->ops->soft_stop(s->state);
        return r < 0 ? stage_fail(s, r, "soft stop") : 0;
}

int imp_stage_clear_fault(struct imp_stage *s) {
        if (!s)
                return -EINVAL;
        s->error[0] = 0;
        if (!s->ops->clear_fault)
                return -EOPNOTSUPP;
        int r = s->ops->clear_fault(s->state);
        return r < 0 ? stage_fail(s, r, "clear fault") : 0;
}
