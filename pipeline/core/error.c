/* struct imp_error helpers: see error.h. */
#include <stdio.h>
#include <string.h>
#include "error.h"

int imp_error_set(struct imp_error *err, int code, const char *fmt, ...) {
        if (err) {
                va_list ap;
                va_start(ap, fmt);
                vsnprintf(err->msg, sizeof err->msg, fmt, ap);
                va_end(ap);
                err->code = code;
        }
        return code;
}

int imp_error_prefix(struct imp_error *err, const char *fmt, ...) {
        if (!err)
                return 0;
        char prefix[sizeof err->msg], old[sizeof err->msg];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(prefix, sizeof prefix, fmt, ap);
        va_end(ap);
        memcpy(old, err->msg, sizeof old);
        size_t n = strnlen(prefix, sizeof err->msg - 1);
        memcpy(err->msg, prefix, n);
        size_t m = strnlen(old, sizeof err->msg - 1 - n);
        memcpy(err->msg + n, old, m);
        err->msg[n + m] = 0;
        return err->code;
}
