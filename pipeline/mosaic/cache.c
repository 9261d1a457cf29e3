/* The bounded cache of tile copies (mosaic-internal.h). */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include "mosaic-internal.h"

static size_t copy_bytes(const struct imp_mosaic_tile *t) {
        /* height, normal x/y, σ, mask, flags, BRDF (imp_copy_load) */
        return (size_t) t->nx * t->ny * (4 * 4 + 1 + 4 + sizeof(struct imp_lafortune));
}

int mosaic_cache_init(struct mosaic_cache *c, struct imp_painting *p, size_t budget, const size_t *off,
                      const unsigned *tiles, size_t n_steps) {
        *c = (struct mosaic_cache) { .p = p, .budget = budget, .off = off, .tiles = tiles, .n_steps = n_steps };
        c->copies = calloc(p->n_tiles, sizeof *c->copies);
        c->last = malloc(p->n_tiles * sizeof *c->last);
        if (!c->copies || !c->last)
                return free(c->copies), free(c->last), -ENOMEM;
        for (size_t k = 0; k < p->n_tiles; k++)
                c->last[k] = SIZE_MAX;
        for (size_t s = 0; s < n_steps; s++)
                for (size_t i = off[s]; i < off[s + 1]; i++)
                        c->last[tiles[i]] = s;
        return 0;
}

void mosaic_cache_done(struct mosaic_cache *c) {
        if (!c->copies)
                return;
        for (size_t k = 0; k < c->p->n_tiles; k++)
                imp_copy_done(&c->copies[k]);
        free(c->copies);
        free(c->last);
        c->copies = NULL, c->last = NULL;
}

static bool needed_at(const struct mosaic_cache *c, size_t step, unsigned k) {
        for (size_t i = c->off[step]; i < c->off[step + 1]; i++)
                if (c->tiles[i] == k)
                        return true;
        return false;
}

static size_t next_use(const struct mosaic_cache *c, size_t step, unsigned k) {
        for (size_t s = step; s < c->n_steps; s++)
                if (needed_at(c, s, k))
                        return s;
        return SIZE_MAX;
}

static void evict(struct mosaic_cache *c, unsigned k) {
        c->bytes -= copy_bytes(&c->p->tiles[k]);
        c->resident--;
        imp_copy_done(&c->copies[k]);
}

/* Evicts until `need` more bytes fit, never a tile of this step. */
static void make_room(struct mosaic_cache *c, size_t step, size_t need) {
        while (c->bytes + need > c->budget) {
                size_t far = 0;
                long best = -1;
                for (unsigned k = 0; k < c->p->n_tiles; k++) {
                        if (c->copies[k].nx == 0 || needed_at(c, step, k))
                                continue;
                        size_t u = next_use(c, step, k);
                        if (best < 0 || u > far)
                                far = u, best = k;
                }
                if (best < 0)
                        return;         /* the step alone exceeds the budget: hold it anyway */
                evict(c, (unsigned) best);
        }
}

int mosaic_cache_step(struct mosaic_cache *c, size_t step, struct imp_error *err) {
        for (unsigned k = 0; k < c->p->n_tiles; k++)
                if (c->copies[k].nx > 0 && (c->last[k] == SIZE_MAX || c->last[k] < step))
                        evict(c, k);
        for (size_t i = c->off[step]; i < c->off[step + 1]; i++) {
                unsigned k = c->tiles[i];
                if (c->copies[k].nx > 0)
                        continue;
                const struct imp_mosaic_tile *t = &c->p->tiles[k];
                make_room(c, step, copy_bytes(t));
                int r = imp_copy_load(t->copy, &c->copies[k], err);
                if (r < 0) {
                        imp_copy_done(&c->copies[k]);
                        return r;
                }
                if (c->copies[k].nx != t->nx || c->copies[k].ny != t->ny) {
                        imp_copy_done(&c->copies[k]);
                        return imp_error_set(err, -EBADMSG, "%s: grid changed while the mosaic ran", t->copy);
                }
                c->bytes += copy_bytes(t);
                c->loads++;
                if (++c->resident > c->max_resident)
                        c->max_resident = c->resident;
        }
        return 0;
}
