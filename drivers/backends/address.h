/* Backend address strings: "MAIN[;key=value]..." (e.g. "127.0.0.1:1502;timeout_ms=200",
 * "gpiochip0;lines=4,5,6,7;active_low=1"). Tiny parser shared by the backends. */
#pragma once
#include <errno.h>
#include <limits.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>

/* Copy the main part (before the first ';') into buf. -ENAMETOOLONG / -EINVAL. */
static inline int address_main(const char *addr, char *buf, size_t size) {
        size_t n = strcspn(addr, ";");
        if (n == 0)
                return -EINVAL;
        if (n >= size)
                return -ENAMETOOLONG;
        memcpy(buf, addr, n);
        buf[n] = 0;
        return 0;
}

/* Value of option key into buf; 0 found, -ENOENT absent, -ENAMETOOLONG. */
static inline int address_option(const char *addr, const char *key, char *buf, size_t size) {
        size_t klen = strlen(key);
        for (const char *p = strchr(addr, ';'); p; p = strchr(p + 1, ';')) {
                if (strncmp(p + 1, key, klen) != 0 || p[1 + klen] != '=')
                        continue;
                const char *v = p + 2 + klen;
                size_t n = strcspn(v, ";");
                if (n >= size)
                        return -ENAMETOOLONG;
                memcpy(buf, v, n);
                buf[n] = 0;
                return 0;
        }
        return -ENOENT;
}

/* Unsigned option within [lo, hi]; absent leaves *ret untouched and returns 0. */
static inline int address_option_uint(const char *addr, const char *key, unsigned lo, unsigned hi,
                                      unsigned *ret) {
        char buf[32], *end;
        int r = address_option(addr, key, buf, sizeof buf);
        if (r == -ENOENT)
                return 0;
        if (r < 0)
                return r;
        errno = 0;
        unsigned long v = strtoul(buf, &end, 10);
        if (errno || end == buf || *end || v < lo || v > hi)
                return -EINVAL;
        *ret = (unsigned) v;
        return 0;
}
