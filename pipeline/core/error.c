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
        char old[sizeof err->msg];
        memcpy(old, err->msg, sizeof old);
        old[sizeof old - 1] = 0;
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(err->msg, sizeof err->msg, fmt, ap);
        va_end(ap);
        if (n < 0)
                n = 0;
        if ((size_t) n >= sizeof err->msg - 1)
                return err->code;
        size_t room = sizeof err->msg - 1 - (size_t) n, len = strlen(old);
        if (len > room)
                len = room;
        memcpy(err->msg + n, old, len);
        err->msg[n + len] = 0;
        return err->code;
}
