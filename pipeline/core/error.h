/* Error detail for bad input: library code does not log (STYLE.md rule 7), so readers of
 * files and messages return a negative errno *and* fill a human message naming the file,
 * the line or field, and what was expected. The caller logs it once. */
#pragma once
#include <stdarg.h>
#include "macro.h"

struct imp_error {
        int code;              /* negative errno, 0 when no error was recorded */
        char msg[1024];        /* "scene.cfg:14: camera.fx: expected a number > 0, got -3" */
};

/* Record an error (err may be NULL) and return code, so that callers can write
 * `return imp_error_set(err, -EINVAL, "%s:%d: ...", path, line);`. */
int imp_error_set(struct imp_error *err, int code, const char *fmt, ...) _printf_(3, 4);
/* Prefix an existing message ("capture set X: " + msg) keeping the code. */
int imp_error_prefix(struct imp_error *err, const char *fmt, ...) _printf_(2, 3);
static inline void imp_error_clear(struct imp_error *err) { if (err) { err->code = 0; err->msg[0] = 0; } }
