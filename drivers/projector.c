/* Projector wrapper: backend lookup, argument checks, the sequence bookkeeping the daemon
 * relies on (show only what was uploaded), and the projector blanked on open, on close and
 * after any failure, so a failed step never leaves a pattern on the painting. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "projector.h"

#ifdef IMPASTO_HAVE_MODBUS
extern const struct imp_projector_ops imp_projector_modbus_ops;
#endif
#ifdef IMPASTO_HAVE_LIBUSB
extern const struct imp_projector_ops imp_projector_usb_dlp_ops;
#endif

static const struct imp_projector_ops *const projector_backends[] = {
#ifdef IMPASTO_HAVE_MODBUS
        &imp_projector_modbus_ops,
#endif
#ifdef IMPASTO_HAVE_LIBUSB
        &imp_projector_usb_dlp_ops,
#endif
        NULL,
};

struct imp_projector {
        const struct imp_projector_ops *ops;
        void *state;
        struct imp_projector_info info;
        unsigned n_uploaded;
        char error[512];
};

const struct imp_projector_ops *imp_projector_backend(const char *name) {
        if (!name)
                return NULL;
        for (size_t i = 0; projector_backends[i]; i++)
                if (strcmp(projector_backends[i]->name, name) == 0)
                        return projector_backends[i];
        return NULL;
}

_printf_(3, 4)
static int proj_fail(struct imp_projector *p, int r, const char *fmt, ...) {
        char what[256];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(what, sizeof what, fmt, ap);
        va_end(ap);
        const char *detail = p->ops->last_error ? p->ops->last_error(p->state) : NULL;
        snprintf(p->error, sizeof p->error, "projector %s: %s: %s%s%s", p->ops->name, what, strerror(-r),
                 detail && *detail ? ": " : "", detail ? detail : "");
        return r;
}

/* Best effort: blank after a failure (the error kept is the first one). */
static void proj_blank(struct imp_projector *p) {
        if (p->ops->dark)
                (void) p->ops->dark(p->state);
}

int imp_projector_open(const char *backend, const char *address, unsigned timeout_ms,
                       struct imp_projector **ret) {
        if (!backend || !address || !ret)
                return -EINVAL;
        const struct imp_projector_ops *ops = imp_projector_backend(backend);
        if (!ops)
                return -ENOENT;
        return imp_projector_open_ops(ops, address, timeout_ms, ret);
}

int imp_projector_open_ops(const struct imp_projector_ops *ops, const char *address, unsigned timeout_ms,
                           struct imp_projector **ret) {
        if (!ops || !ops->name || !ops->open || !ops->close || !address || !ret)
                return -EINVAL;
        struct imp_projector *p = calloc(1, sizeof *p);
        if (!p)
                return -ENOMEM;
        p->ops = ops;
        int r = ops->open(address, timeout_ms, &p->state);
        if (r < 0) {
                free(p);
                return r;
        }
        p->info.max_patterns = IMP_PROJECTOR_MAX_PATTERNS;
        r = ops->get_info ? ops->get_info(p->state, &p->info) : 0;
        if (r >= 0 && (p->info.max_patterns == 0 || p->info.max_patterns > IMP_PROJECTOR_MAX_PATTERNS))
                p->info.max_patterns = IMP_PROJECTOR_MAX_PATTERNS;
        if (r >= 0 && ops->dark)
                r = ops->dark(p->state);
        if (r < 0) {
                ops->close(p->state);
                free(p);
                return r;
        }
        *ret = p;
        return 0;
}

void imp_projector_close(struct imp_projector *p) {
        if (!p)
                return;
        proj_blank(p);
        p->ops->close(p->state);
        free(p);
}

const char *imp_projector_last_error(const struct imp_projector *p) {
        return p ? p->error : "";
}

int imp_projector_get_info(struct imp_projector *p, struct imp_projector_info *ret_info) {
        if (!p || !ret_info)
                return -EINVAL;
        *ret_info = p->info;
        return 0;
}

/* What a projector can show at all, whatever the backend. */
static const char *pattern_problem(const struct imp_pattern *pat) {
        switch (pat->kind) {
        case IMP_PAT_NONE:
        case IMP_PAT_WHITE:
        case IMP_PAT_BLACK:
                break;
        case IMP_PAT_GRAY:
                if (pat->nbits < 1 || pat->nbits > 16 || pat->bit < 0 || pat->bit >= pat->nbits)
                        return "Gray bit outside 0..nbits-1 (nbits 1..16)";
                break;
        case IMP_PAT_PHASE:
                if (!isfinite(pat->period_px) || pat->period_px <= 0)
                        return "phase period not a positive number";
                if (pat->steps < 1 || pat->step < 0 || pat->step >= pat->steps)
                        return "phase step outside 0..steps-1";
                break;
        default:
                return "unknown kind";
        }
        if (pat->axis != 0 && pat->axis != 1)
                return "axis not 0 (x) or 1 (y)";
        return NULL;
}

int imp_projector_upload(struct imp_projector *p, const struct imp_pattern *patterns, unsigned n) {
        if (!p || (n > 0 && !patterns))
                return -EINVAL;
        p->error[0] = 0;
        if (!p->ops->upload)
                return -EOPNOTSUPP;
        if (n > p->info.max_patterns)
                return proj_fail(p, -E2BIG, "upload of %u patterns: the projector holds %u", n,
                                 p->info.max_patterns);
        for (unsigned i = 0; i < n; i++) {
                const char *why = pattern_problem(&patterns[i]);
                if (why)
                        return proj_fail(p, -EINVAL, "upload: pattern %u: %s", i, why);
        }
        p->n_uploaded = 0;
        int r = p->ops->upload(p->state, patterns, n);
        if (r < 0) {
                proj_fail(p, r, "upload of %u patterns", n);
                proj_blank(p);
                return r;
        }
        p->n_uploaded = n;
        return 0;
}

int imp_projector_show(struct imp_projector *p, unsigned index) {
        if (!p)
                return -EINVAL;
        p->error[0] = 0;
        if (!p->ops->show)
                return -EOPNOTSUPP;
        if (index >= p->n_uploaded)
                return proj_fail(p, -EINVAL, "show pattern %u: the sequence holds %u", index, p->n_uploaded);
        int r = p->ops->show(p->state, index);
        if (r < 0) {
                proj_fail(p, r, "show pattern %u", index);
                proj_blank(p);
                return r;
        }
        return 0;
}

int imp_projector_dark(struct imp_projector *p) {
        if (!p)
                return -EINVAL;
        p->error[0] = 0;
        if (!p->ops->dark)
                return -EOPNOTSUPP;
        int r = p->ops->dark(p->state);
        return r < 0 ? proj_fail(p, r, "dark") : 0;
}

int imp_projector_trigger(struct imp_projector *p) {
        if (!p)
                return -EINVAL;
        p->error[0] = 0;
        if (!p->ops->trigger)
                return -EOPNOTSUPP;
        int r = p->ops->trigger(p->state);
        return r < 0 ? proj_fail(p, r, "trigger") : 0;
}

int imp_projector_get_status(struct imp_projector *p, struct imp_projector_status *ret_status) {
        if (!p || !ret_status)
                return -EINVAL;
        p->error[0] = 0;
        if (!p->ops->get_status)
                return -EOPNOTSUPP;
        struct imp_projector_status s = { .shown = -1 };
        int r = p->ops->get_status(p->state, &s);
        if (r < 0)
                return proj_fail(p, r, "reading status");
        *ret_status = s;
        return 0;
}
