/* Thin layer between the gpiod dome backend and libgpiod, so that libgpiod 2 (request
 * objects, line settings) can replace 1.6 (line bulks) by writing the #else branch only.
 * All calls return 0 or a negative errno. Values are logical (active-low applied below). */
#pragma once
#include <errno.h>
#include <gpiod.h>
#include <stdbool.h>
#include <stdlib.h>
#include "macro.h"

#define GPIO_COMPAT_MAX_LINES 64

#ifndef IMPASTO_GPIOD_V2        /* libgpiod 1.x: chip + line bulk, GPIO uAPI v1 underneath */

struct gpio_compat_lines {
        struct gpiod_chip *chip;
        struct gpiod_line_bulk bulk;
        unsigned n;
};

static inline void gpio_compat_release(struct gpio_compat_lines *l) {
        if (!l)
                return;
        if (l->chip) {
                if (l->n)
                        gpiod_line_release_bulk(&l->bulk);
                gpiod_chip_close(l->chip);
        }
        free(l);
}

/* Request n lines of chip (name, number or path) as outputs, all driven inactive. */
static inline int gpio_compat_request_outputs(const char *chip, const unsigned *offsets, unsigned n,
                                              bool active_low, const char *consumer,
                                              struct gpio_compat_lines **ret) {
        if (n == 0 || n > GPIO_COMPAT_MAX_LINES || n > GPIOD_LINE_BULK_MAX_LINES)
                return -EINVAL;
        struct gpio_compat_lines *l = calloc(1, sizeof *l);
        if (!l)
                return -ENOMEM;
        int r;
        l->chip = gpiod_chip_open_lookup(chip);
        if (!l->chip) {
                r = negative_errno();
                goto fail;
        }
        if (gpiod_chip_get_lines(l->chip, (unsigned int *) offsets, n, &l->bulk) < 0) {
                r = negative_errno();
                goto fail;
        }
        int zeros[GPIO_COMPAT_MAX_LINES] = {};
        if (gpiod_line_request_bulk_output_flags(&l->bulk, consumer,
                                                 active_low ? GPIOD_LINE_REQUEST_FLAG_ACTIVE_LOW : 0,
                                                 zeros) < 0) {
                r = negative_errno();
                goto fail;
        }
        l->n = n;
        *ret = l;
        return 0;
fail:
        gpio_compat_release(l);
        return r;
}

/* Set all requested lines at once (one ioctl). */
static inline int gpio_compat_set_values(struct gpio_compat_lines *l, const int *values) {
        return gpiod_line_set_value_bulk(&l->bulk, (int *) values) < 0 ? negative_errno() : 0;
}

static inline int gpio_compat_get_values(struct gpio_compat_lines *l, int *values) {
        return gpiod_line_get_value_bulk(&l->bulk, values) < 0 ? negative_errno() : 0;
}

#else
#error "libgpiod 2: implement gpio_compat_* with gpiod_chip_request_lines() / gpiod_line_request_set_values()"
#endif
