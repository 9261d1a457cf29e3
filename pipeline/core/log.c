/* Program logging: plain lines on a terminal, <N>-prefixed lines for journald. */
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "log.h"

static enum imp_log_level max_level = IMP_LOG_INFO;
static const char *ident = "impasto";

void imp_log_set_level(enum imp_log_level max) { max_level = max; }
enum imp_log_level imp_log_get_level(void) { return max_level; }
void imp_log_set_ident(const char *s) { ident = s; }

static const char *level_name(enum imp_log_level l) {
        switch (l) {
        case IMP_LOG_ERR:     return "error";
        case IMP_LOG_WARNING: return "warning";
        case IMP_LOG_NOTICE:  return "notice";
        case IMP_LOG_INFO:    return "info";
        default:              return "debug";
        }
}

int imp_log_internal(enum imp_log_level level, int error, const char *file, int line,
                     const char *fmt, ...) {
        if (level > max_level)
                return error;
        int saved = errno;
        if (error != 0)
                errno = error < 0 ? -error : error;   /* for %m */
        char buf[4096];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(buf, sizeof buf, fmt, ap);
        va_end(ap);
        if (getenv("JOURNAL_STREAM"))
                fprintf(stderr, "<%d>%s\n", (int) level, buf);
        else if (level == IMP_LOG_DEBUG)
                fprintf(stderr, "%s: debug: %s (%s:%d)\n", ident, buf, file, line);
        else
                fprintf(stderr, "%s: %s: %s\n", ident, level_name(level), buf);
        errno = saved;
        return error;
}
