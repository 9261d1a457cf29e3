/* Dome backend "gpiod": one GPIO line per LED through libgpiod (behind gpio-compat.h),
 * all lines requested together and set in one bulk call, optional active-low wiring.
 * Lights only (no actuators), not dimmable: any level > 0 is on. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "address.h"
#include "dome.h"
#include "gpio-compat.h"

#define CONSUMER "impasto-dome"

struct dome_gpio {
        struct gpio_compat_lines *lines;
        unsigned n;
        int values[GPIO_COMPAT_MAX_LINES];      /* logical, as last set */
        char chip[64];
        char error[160];
};

/* "4-11" or "3,5,7" or a mix: offsets into ret (at most max), returns how many or -EINVAL. */
static int parse_lines(const char *s, unsigned *ret, unsigned max) {
        unsigned n = 0;
        while (*s) {
                char *end;
                unsigned long a = strtoul(s, &end, 10), b = a;
                if (end == s)
                        return -EINVAL;
                if (*end == '-') {
                        s = end + 1;
                        b = strtoul(s, &end, 10);
                        if (end == s || b < a)
                                return -EINVAL;
                }
                if (b >= GPIO_COMPAT_MAX_LINES || n + (b - a + 1) > max)
                        return -EINVAL;
                for (unsigned long v = a; v <= b; v++)
                        ret[n++] = (unsigned) v;
                if (*end == ',')
                        end++;
                else if (*end)
                        return -EINVAL;
                s = end;
        }
        return n ? (int) n : -EINVAL;
}

static void dome_gpio_close(void *state) {
        struct dome_gpio *g = state;
        if (!g)
                return;
        gpio_compat_release(g->lines);
        free(g);
}

static int dome_gpio_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct dome_gpio *g = calloc(1, sizeof *g);
        if (!g)
                return -ENOMEM;
        char buf[256];
        unsigned offsets[GPIO_COMPAT_MAX_LINES], active_low = 0;
        int r = address_main(address, g->chip, sizeof g->chip);
        if (r < 0)
                goto fail;
        r = address_option(address, "lines", buf, sizeof buf);
        if (r < 0)
                goto fail;
        r = parse_lines(buf, offsets, IMP_MIN(GPIO_COMPAT_MAX_LINES, IMP_DOME_MAX_LIGHTS));
        if (r < 0)
                goto fail;
        g->n = (unsigned) r;
        r = address_option_uint(address, "active_low", 0, 1, &active_low);
        if (r < 0)
                goto fail;
        r = gpio_compat_request_outputs(g->chip, offsets, g->n, active_low, CONSUMER, &g->lines);
        if (r < 0)
                goto fail;
        *ret_state = g;
        return 0;
fail:
        dome_gpio_close(g);
        return r;
}

static int dome_gpio_get_info(void *state, struct imp_dome_info *ret) {
        struct dome_gpio *g = state;
        snprintf(ret->model, sizeof ret->model, "gpio LEDs on %.40s", g->chip);
        ret->n_lights = g->n;
        ret->n_axes = 0;
        ret->dimmable = false;
        return 0;
}

/* Apply a whole new set of values; the cache changes only when the lines did. */
static int apply(struct dome_gpio *g, const int *values, const char *what) {
        int r = gpio_compat_set_values(g->lines, values);
        if (r < 0) {
                snprintf(g->error, sizeof g->error, "%s: bulk set of %u lines on %.40s failed", what, g->n, g->chip);
                return r;
        }
        memcpy(g->values, values, sizeof g->values);
        return 0;
}

static int dome_gpio_set_light(void *state, unsigned id, unsigned level_permille) {
        struct dome_gpio *g = state;
        if (id >= g->n)
                return -EINVAL;
        int v[GPIO_COMPAT_MAX_LINES];
        memcpy(v, g->values, sizeof v);
        v[id] = level_permille > 0;
        return apply(g, v, "set light");
}

static int dome_gpio_all_off(void *state) {
        int v[GPIO_COMPAT_MAX_LINES] = {};
        return apply(state, v, "all off");
}

static int dome_gpio_get_state(void *state, struct imp_dome_state *ret) {
        struct dome_gpio *g = state;
        int v[GPIO_COMPAT_MAX_LINES] = {};
        int r = gpio_compat_get_values(g->lines, v);
        if (r < 0)
                return r;
        ret->n_lights = g->n;
        ret->n_on = 0;
        for (unsigned i = 0; i < g->n; i++) {
                ret->level_permille[i] = v[i] ? IMP_DOME_LEVEL_FULL_PERMILLE : 0;
                ret->n_on += v[i] != 0;
        }
        return 0;
}

static const char *dome_gpio_last_error(void *state) {
        struct dome_gpio *g = state;
        return g->error;
}

const struct imp_dome_ops imp_dome_gpiod_ops = {
        .name = "gpiod",
        .open = dome_gpio_open,                 /* "gpiochip0;lines=4-11[;active_low=1]" */
        .close = dome_gpio_close,               /* releases the lines */
        .get_info = dome_gpio_get_info,         /* one light per line, no axes */
        .set_light = dome_gpio_set_light,       /* bulk set with one line changed */
        .all_off = dome_gpio_all_off,           /* bulk set, all inactive */
        .get_state = dome_gpio_get_state,       /* bulk get (logical values) */
        .move_to = NULL,                        /* no actuators on GPIO */
        .home = NULL,
        .stop_axis = NULL,
        .clear_fault = NULL,
        .get_axis_status = NULL,
        .last_error = dome_gpio_last_error,     /* which bulk operation failed */
};
