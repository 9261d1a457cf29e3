/* The emulated rig's shared state (which lights are on, which pattern is projected) and
 * the default camera fill that encodes that state in the pixels, so tests can prove a
 * frame shows the light and pattern it claims. */
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include "emu.h"

struct imp_emu_rig {
        pthread_mutex_t lock;
        unsigned n_lights;
        uint16_t level[IMP_EMU_MAX_LIGHTS];
        unsigned max_on;
        int pattern;
        struct imp_pattern desc;        /* kind NONE when dark */
};

int imp_emu_rig_new(unsigned n_lights, struct imp_emu_rig **ret_rig) {
        if (!ret_rig || n_lights > IMP_EMU_MAX_LIGHTS)
                return -EINVAL;
        struct imp_emu_rig *r = calloc(1, sizeof *r);
        if (!r)
                return -ENOMEM;
        pthread_mutex_init(&r->lock, NULL);
        r->n_lights = n_lights;
        r->pattern = -1;
        *ret_rig = r;
        return 0;
}

void imp_emu_rig_free(struct imp_emu_rig *r) {
        if (!r)
                return;
        pthread_mutex_destroy(&r->lock);
        free(r);
}

unsigned imp_emu_rig_n_lights(const struct imp_emu_rig *r) {
        return r ? r->n_lights : 0;
}

static unsigned count_on_locked(const struct imp_emu_rig *r) {
        unsigned n = 0;
        for (unsigned i = 0; i < r->n_lights; i++)
                n += r->level[i] > 0;
        return n;
}

void imp_emu_rig_set_light(struct imp_emu_rig *r, unsigned id, unsigned level_permille) {
        if (!r || id >= r->n_lights)
                return;
        pthread_mutex_lock(&r->lock);
        r->level[id] = (uint16_t) IMP_MIN(level_permille, 1000u);
        unsigned on = count_on_locked(r);
        if (on > r->max_on)
                r->max_on = on;
        pthread_mutex_unlock(&r->lock);
}

unsigned imp_emu_rig_get_lights(struct imp_emu_rig *r, uint16_t *levels, unsigned n) {
        if (!r)
                return 0;
        pthread_mutex_lock(&r->lock);
        if (levels)
                for (unsigned i = 0; i < n; i++)
                        levels[i] = i < r->n_lights ? r->level[i] : 0;
        unsigned on = count_on_locked(r);
        pthread_mutex_unlock(&r->lock);
        return on;
}

int imp_emu_rig_lit_light(struct imp_emu_rig *r) {
        if (!r)
                return -1;
        int lit = -1;
        pthread_mutex_lock(&r->lock);
        for (unsigned i = 0; i < r->n_lights; i++)
                if (r->level[i] > 0)
                        lit = lit == -1 ? (int) i : -2;
        pthread_mutex_unlock(&r->lock);
        return lit;
}

unsigned imp_emu_rig_max_lights_on(struct imp_emu_rig *r) {
        if (!r)
                return 0;
        pthread_mutex_lock(&r->lock);
        unsigned m = r->max_on;
        pthread_mutex_unlock(&r->lock);
        return m;
}

void imp_emu_rig_reset_max_lights_on(struct imp_emu_rig *r) {
        if (!r)
                return;
        pthread_mutex_lock(&r->lock);
        r->max_on = count_on_locked(r);
        pthread_mutex_unlock(&r->lock);
}

void imp_emu_rig_set_pattern(struct imp_emu_rig *r, int pattern) {
        if (!r)
                return;
        pthread_mutex_lock(&r->lock);
        r->pattern = pattern;
        if (pattern < 0)
                r->desc = (struct imp_pattern) { .kind = IMP_PAT_NONE };
        pthread_mutex_unlock(&r->lock);
}

void imp_emu_rig_set_pattern_desc(struct imp_emu_rig *r, int index, const struct imp_pattern *desc) {
        if (!r)
                return;
        pthread_mutex_lock(&r->lock);
        if (index < 0 || !desc) {
                r->pattern = -1;
                r->desc = (struct imp_pattern) { .kind = IMP_PAT_NONE };
        } else {
                r->pattern = index;
                r->desc = *desc;
        }
        pthread_mutex_unlock(&r->lock);
}

int imp_emu_rig_get_pattern_desc(struct imp_emu_rig *r, struct imp_pattern *ret_desc) {
        if (!r) {
                if (ret_desc)
                        *ret_desc = (struct imp_pattern) { .kind = IMP_PAT_NONE };
                return -1;
        }
        pthread_mutex_lock(&r->lock);
        int p = r->pattern;
        if (ret_desc)
                *ret_desc = r->desc;
        pthread_mutex_unlock(&r->lock);
        return p;
}

int imp_emu_rig_get_pattern(struct imp_emu_rig *r) {
        if (!r)
                return -1;
        pthread_mutex_lock(&r->lock);
        int p = r->pattern;
        pthread_mutex_unlock(&r->lock);
        return p;
}

/* ---- default fill ------------------------------------------------------------------- */

#define FILL_HEADER_PIXELS 8
#define FILL_MAGIC8 0xA5u
#define FILL_MAGIC16 0xA55Au

static uint32_t fill_value(int x, int y, int light, int pattern, uint32_t exposure_us, uint32_t mask) {
        return ((uint32_t) x + 3u * (uint32_t) y + 17u * (uint32_t) (light + 2) +
                29u * (uint32_t) (pattern + 1) + exposure_us / 8u) & mask;
}

static void header_values(int bpp, int light, int pattern, uint32_t exposure_us, uint32_t h[FILL_HEADER_PIXELS]) {
        if (bpp == 1) {
                h[0] = FILL_MAGIC8;
                h[1] = (uint32_t) (light + 2) & 0xff;
                h[2] = (uint32_t) (pattern + 1) & 0xff;
                for (int i = 0; i < 4; i++)
                        h[3 + i] = (exposure_us >> (8 * i)) & 0xff;
                h[7] = 0x5A;
        } else {
                h[0] = FILL_MAGIC16;
                h[1] = (uint32_t) (light + 2) & 0xffff;
                h[2] = (uint32_t) (pattern + 1) & 0xffff;
                h[3] = exposure_us & 0xffff;
                h[4] = exposure_us >> 16;
                h[5] = h[6] = 0;
                h[7] = 0x5A5A;
        }
        for (int i = 0; i < 7; i++)
                h[7] ^= h[i];
}

static void put(void *buf, int bpp, size_t i, uint32_t v) {
        if (bpp == 1)
                ((uint8_t *) buf)[i] = (uint8_t) v;
        else
                ((uint16_t *) buf)[i] = (uint16_t) v;   /* little-endian host, as GigE Mono16 */
}

static uint32_t get(const void *buf, int bpp, size_t i) {
        return bpp == 1 ? ((const uint8_t *) buf)[i] : ((const uint16_t *) buf)[i];
}

int imp_emu_fill_default(void *userdata, const struct imp_emu_camera_state *st, void *buf,
                         int width, int height, int bpp) {
        if (!st || !buf || width < FILL_HEADER_PIXELS || height < 1 || (bpp != 1 && bpp != 2))
                return -EINVAL;
        uint32_t mask = bpp == 1 ? 0xffu : 0xffffu;
        for (int y = 0; y < height; y++)
                for (int x = 0; x < width; x++)
                        put(buf, bpp, (size_t) y * width + x,
                            fill_value(x, y, st->lit_light, st->pattern, st->exposure_us, mask));
        uint32_t h[FILL_HEADER_PIXELS];
        header_values(bpp, st->lit_light, st->pattern, st->exposure_us, h);
        for (int i = 0; i < FILL_HEADER_PIXELS; i++)
                put(buf, bpp, (size_t) i, h[i]);
        return 0;
}

int imp_emu_decode_default(const void *buf, int width, int height, int bpp,
                           int *ret_light, int *ret_pattern, uint32_t *ret_exposure_us) {
        if (!buf || width < FILL_HEADER_PIXELS || height < 1 || (bpp != 1 && bpp != 2))
                return -EINVAL;
        uint32_t magic = bpp == 1 ? FILL_MAGIC8 : FILL_MAGIC16;
        if (get(buf, bpp, 0) != magic)
                return -EBADMSG;
        int light = (int) get(buf, bpp, 1) - 2;
        int pattern = (int) get(buf, bpp, 2) - 1;
        uint32_t exposure_us = bpp == 1
                ? get(buf, 1, 3) | get(buf, 1, 4) << 8 | get(buf, 1, 5) << 16 | get(buf, 1, 6) << 24
                : get(buf, 2, 3) | get(buf, 2, 4) << 16;
        uint32_t h[FILL_HEADER_PIXELS];
        header_values(bpp, light, pattern, exposure_us, h);
        for (int i = 0; i < FILL_HEADER_PIXELS; i++)
                if (get(buf, bpp, (size_t) i) != h[i])
                        return -EBADMSG;
        uint32_t mask = bpp == 1 ? 0xffu : 0xffffu;
        for (int y = 0; y < height; y++)
                for (int x = y == 0 ? FILL_HEADER_PIXELS : 0; x < width; x++)
                        if (get(buf, bpp, (size_t) y * width + x) !=
                            fill_value(x, y, light, pattern, exposure_us, mask))
                                return -EBADMSG;
        if (ret_light)
                *ret_light = light;
        if (ret_pattern)
                *ret_pattern = pattern;
        if (ret_exposure_us)
                *ret_exposure_us = exposure_us;
        return 0;
}
