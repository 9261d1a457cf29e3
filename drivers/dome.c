/* Dome wrapper: backend lookup, argument checks, the one-light-at-a-time rule, lights off
 * after any failure, and move/home completion by polling the axis status. */
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "dome.h"

#ifdef IMPASTO_HAVE_MODBUS
extern const struct imp_dome_ops imp_dome_modbus_ops;
#endif
#ifdef IMPASTO_HAVE_GPIOD
extern const struct imp_dome_ops imp_dome_gpiod_ops;
#endif

static const struct imp_dome_ops *const dome_backends[] = {
#ifdef IMPASTO_HAVE_MODBUS
        &imp_dome_modbus_ops,
#endif
#ifdef IMPASTO_HAVE_GPIOD
        &imp_dome_gpiod_ops,
#endif
        NULL,
};

#define DOME_POLL_INTERVAL_US 5000

struct imp_dome {
        const struct imp_dome_ops *ops;
        void *state;
        struct imp_dome_info info;
        uint16_t level[IMP_DOME_MAX_LIGHTS];    /* what the wrapper last set */
        bool lights_known;
        char error[512];
};

const struct imp_dome_ops *imp_dome_backend(const char *name) {
        if (!name)
                return NULL;
        for (size_t i = 0; dome_backends[i]; i++)
                if (strcmp(dome_backends[i]->name, name) == 0)
                        return dome_backends[i];
        return NULL;
}

_printf_(3, 4)
static int dome_fail(struct imp_dome *d, int r, const char *fmt, ...) {
        char what[256];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(what, sizeof what, fmt, ap);
        va_end(ap);
        const char *detail = d->ops->last_error ? d->ops->last_error(d->state) : NULL;
        snprintf(d->error, sizeof d->error, "dome %s: %s: %s%s%s", d->ops->name, what, strerror(-r),
                 detail && *detail ? ": " : "", detail ? detail : "");
        return r;
}

/* After a failure: everything off, so no light stays lit behind the caller's back. Light
 * by light only where the device has no all-off: when the link is down, each would wait
 * out its own retries and the caller would hang for nothing. */
static int dome_safe_off(struct imp_dome *d) {
        int r = d->ops->all_off ? d->ops->all_off(d->state) : -EOPNOTSUPP;
        if (r == -EOPNOTSUPP) {
                r = 0;
                for (unsigned i = 0; i < d->info.n_lights && r >= 0; i++)
                        r = d->ops->set_light(d->state, i, 0);
        }
        d->lights_known = r >= 0;
        memset(d->level, 0, sizeof d->level);
        return r < 0 ? r : 0;
}

int imp_dome_open(const char *backend, const char *address, unsigned timeout_ms,
                  struct imp_dome **ret_dome) {
        if (!backend || !address || !ret_dome)
                return -EINVAL;
        const struct imp_dome_ops *ops = imp_dome_backend(backend);
        if (!ops)
                return -ENOENT;
        struct imp_dome *d = calloc(1, sizeof *d);
        if (!d)
                return -ENOMEM;
        d->ops = ops;
        int r = ops->open(address, timeout_ms, &d->state);
        if (r < 0) {
                free(d);
                return r;
        }
        r = ops->get_info ? ops->get_info(d->state, &d->info) : -EOPNOTSUPP;
        if (r >= 0 && d->info.n_lights > IMP_DOME_MAX_LIGHTS)
                r = -ERANGE;
        if (r >= 0 && !ops->set_light)
                r = -EOPNOTSUPP;
        if (r >= 0)
                r = dome_safe_off(d);
        if (r < 0) {
                ops->close(d->state);
                free(d);
                return r;
        }
        d->lights_known = true;
        *ret_dome = d;
        return 0;
}

void imp_dome_close(struct imp_dome *d) {
        if (!d)
                return;
        (void) dome_safe_off(d);
        d->ops->close(d->state);
        free(d);
}

const char *imp_dome_backend_name(const struct imp_dome *d) {
        return d ? d->ops->name : NULL;
}

const char *imp_dome_last_error(const struct imp_dome *d) {
        return d ? d->error : "";
}

bool imp_dome_lights_known(const struct imp_dome *d) {
        return d && d->lights_known;
}

int imp_dome_get_info(struct imp_dome *d, struct imp_dome_info *ret_info) {
        if (!d || !ret_info)
                return -EINVAL;
        *ret_info = d->info;
        return 0;
}

int imp_dome_set_light(struct imp_dome *d, unsigned id, unsigned level_permille, unsigned flags) {
        if (!d)
                return -EINVAL;
        d->error[0] = 0;
        if (id >= d->info.n_lights || level_permille > IMP_DOME_LEVEL_FULL_PERMILLE)
                return dome_fail(d, -EINVAL, "light %u to %u permille: out of range (%u lights)",
                                 id, level_permille, d->info.n_lights);
        if (!d->ops->set_light)
                return -EOPNOTSUPP;
        int r;
        if (!(flags & IMP_DOME_LIGHT_MULTI) && level_permille > 0)
                for (unsigned i = 0; i < d->info.n_lights; i++) {
                        if (i == id || d->level[i] == 0)
                                continue;
                        r = d->ops->set_light(d->state, i, 0);
                        if (r < 0) {
                                dome_fail(d, r, "switching light %u off before light %u", i, id);
                                dome_safe_off(d);
                                return r;
                        }
                        d->level[i] = 0;
                }
        r = d->ops->set_light(d->state, id, level_permille);
        if (r < 0) {
                dome_fail(d, r, "set light %u to %u permille", id, level_permille);
                dome_safe_off(d);
                return r;
        }
        d->level[id] = (uint16_t) level_permille;
        d->lights_known = true;
        return 0;
}

int imp_dome_all_off(struct imp_dome *d) {
        if (!d)
                return -EINVAL;
        d->error[0] = 0;
        int r = dome_safe_off(d);
        return r < 0 ? dome_fail(d, r, "all lights off") : 0;
}

int imp_dome_get_state(struct imp_dome *d, struct imp_dome_state *ret_state) {
        if (!d || !ret_state)
                return -EINVAL;
        d->error[0] = 0;
        if (!d->ops->get_state)
                return -EOPNOTSUPP;
        struct imp_dome_state s = {};
        int r = d->ops->get_state(d->state, &s);
        if (r < 0)
                return dome_fail(d, r, "reading light state");
        *ret_state = s;
        return 0;
}

int imp_dome_get_axis_status(struct imp_dome *d, unsigned axis, struct imp_axis_status *ret_status) {
        if (!d || !ret_status || axis >= d->info.n_axes)
                return -EINVAL;
        if (!d->ops->get_axis_status)
                return -EOPNOTSUPP;
        struct imp_axis_status s = {};
        int r = d->ops->get_axis_status(d->state, axis, &s);
        if (r < 0)
                return dome_fail(d, r, "reading axis %u status", axis);
        *ret_status = s;
        return 0;
}

static uint64_t now_us(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000u + (uint64_t) ts.tv_nsec / 1000u;
}

/* Poll until the axis settles: in position and not moving. */
static int wait_axis(struct imp_dome *d, unsigned axis, unsigned timeout_ms, const char *what) {
        uint64_t deadline = now_us() + (uint64_t) timeout_ms * 1000u;
        for (;;) {
                struct imp_axis_status s;
                int r = d->ops->get_axis_status(d->state, axis, &s);
                if (r < 0)
                        return dome_fail(d, r, "%s: reading axis %u status", what, axis);
                if (s.flags & IMP_AXIS_FAULT)
                        return dome_fail(d, -EIO, "%s: axis %u fault code %u at %d um", what, axis,
                                         s.fault_code, s.position_um);
                if (!(s.flags & IMP_AXIS_MOVING) && (s.flags & IMP_AXIS_IN_POSITION))
                        return 0;
                if (now_us() >= deadline) {
                        if (d->ops->stop_axis)
                                (void) d->ops->stop_axis(d->state, axis);
                        return dome_fail(d, -ETIMEDOUT, "%s: axis %u not in position after %u ms (at %d um)",
                                         what, axis, timeout_ms, s.position_um);
                }
                usleep(DOME_POLL_INTERVAL_US);
        }
}

int imp_dome_move_to(struct imp_dome *d, unsigned axis, int32_t pos_um, unsigned timeout_ms) {
        if (!d || axis >= d->info.n_axes)
                return -EINVAL;
        d->error[0] = 0;
        if (!d->ops->move_to || !d->ops->get_axis_status)
                return -EOPNOTSUPP;
        char what[64];
        snprintf(what, sizeof what, "move axis %u to %d um", axis, pos_um);
        int r = d->ops->move_to(d->state, axis, pos_um);
        if (r < 0)
                return dome_fail(d, r, "%s", what);
        return wait_axis(d, axis, timeout_ms, what);
}

int imp_dome_home(struct imp_dome *d, unsigned axis, unsigned timeout_ms) {
        if (!d || axis >= d->info.n_axes)
                return -EINVAL;
        d->error[0] = 0;
        if (!d->ops->home || !d->ops->get_axis_status)
                return -EOPNOTSUPP;
        char what[64];
        snprintf(what, sizeof what, "home axis %u", axis);
        int r = d->ops->home(d->state, axis);
        if (r < 0)
                return dome_fail(d, r, "%s", what);
        return wait_axis(d, axis, timeout_ms, what);
}

int imp_dome_clear_fault(struct imp_dome *d, unsigned axis) {
        if (!d || axis >= d->info.n_axes)
                return -EINVAL;
        d->error[0] = 0;
        if (!d->ops->clear_fault)
                return -EOPNOTSUPP;
        int r = d->ops->clear_fault(d->state, axis);
        return r < 0 ? dome_fail(d, r, "clear fault on axis %u", axis) : 0;
}
