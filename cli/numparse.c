/* Strict number parsing of command-line options (cli/numparse.h). */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include "log.h"
#include "numparse.h"

static bool starts_like_number(const char *text) {
        return text && *text && !isspace((unsigned char) *text);
}

int imp_parse_double(const char *opt, const char *text, double min, double max, double *ret) {
        char *end = NULL;
        double v = NAN;
        if (starts_like_number(text)) {
                errno = 0;
                v = strtod(text, &end);
        }
        if (!end || end == text || *end || !isfinite(v) || v < min || v > max) {
                if (isinf(max))
                        log_error("%s: expected a number >= %g, got '%s'", opt, min, text ? text : "");
                else
                        log_error("%s: expected a number from %g to %g, got '%s'", opt, min, max, text ? text : "");
                return -EINVAL;
        }
        *ret = v;
        return 0;
}

int imp_parse_long(const char *opt, const char *text, long min, long max, long *ret) {
        char *end = NULL;
        long v = 0;
        if (starts_like_number(text)) {
                errno = 0;
                v = strtol(text, &end, 10);
        }
        if (!end || end == text || *end || errno == ERANGE || v < min || v > max) {
                log_error("%s: expected an integer from %ld to %ld, got '%s'", opt, min, max, text ? text : "");
                return -EINVAL;
        }
        *ret = v;
        return 0;
}

int imp_parse_int(const char *opt, const char *text, int min, int max, int *ret) {
        long v;
        int r = imp_parse_long(opt, text, min, max, &v);
        if (r == 0)
                *ret = (int) v;
        return r;
}
