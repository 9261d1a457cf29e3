/* Blending the registered tiles into output tiles (mosaic.h): every output texel gets one
 * value, the feathered average of the tiles that see it (weight rising from a tile's edge
 * over feather_mm, lowered for flagged texels and by σ), written output tile by output tile
 * with only the input tiles that overlap it in memory (mosaic_cache). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "heightfield.h"
#include "image.h"
#include "json-util.h"
#include "macro.h"
#include "mosaic-blend.h"
#include "quality.h"

/* Flags that make a texel a poor contributor where another tile sees the same point. */
#define POOR_FLAGS (IMP_TEXEL_SATURATED | IMP_TEXEL_SHADOWED | IMP_TEXEL_INTERREFLECTION | IMP_TEXEL_FILLED | \
                    IMP_TEXEL_FIT_FAILED | IMP_TEXEL_FRAME_ADJACENT)

void mosaic_out_done(struct mosaic_out *t) {
        free(t->height), free(t->nx_), free(t->ny_), free(t->sigma), free(t->mask), free(t->flags), free(t->fit_flags),
                free(t->brdf);
        memset(t, 0, sizeof *t);
}

int mosaic_out_alloc(struct mosaic_out *t, int nx, int ny) {
        size_t n = (size_t) nx * ny;
        t->nx = nx, t->ny = ny;
        t->height = calloc(n, sizeof(float)), t->nx_ = calloc(n, sizeof(float)), t->ny_ = calloc(n, sizeof(float));
        t->sigma = calloc(n, sizeof(float)), t->mask = calloc(n, 1), t->flags = calloc(n, sizeof(uint16_t));
        t->fit_flags = calloc(n, sizeof(uint16_t)), t->brdf = calloc(n, sizeof *t->brdf);
        return t->height && t->nx_ && t->ny_ && t->sigma && t->mask && t->flags && t->fit_flags && t->brdf ? 0 : -ENOMEM;
}

/* Accumulator of one output texel. */
struct acc {
        double w, h, n[2], s2, rd[3], rs[3], lobe[4], wmax;
        uint16_t flags_best, fit_flags_best;  /* the heaviest contributor's texel and fit flags */
        uint8_t mask;
};

static double smooth(double x) {
        x = IMP_CLAMP(x, 0.0, 1.0);
        return x * x * (3 - 2 * x);
}

/* Where the bilinear sample of tile t at its fractional texel ij misses (a neighbour off the
 * mask, or within half a texel outside the grid), the nearest texel on the mask: its weights
 * b and indices k (b[0] = 1), its height in *ret_h. A copy's mask ends a texel or two early at
 * its field's edge and around holes; without this such a point only one copy has would be
 * left uncovered. */
static bool nearest(const struct imp_mosaic_tile *t, const struct imp_copy *c, double ij[2], size_t k[4], double b[4],
                    double *ret_h) {
        if (!(ij[0] > -0.5 && ij[1] > -0.5 && ij[0] < t->nx - 0.5 && ij[1] < t->ny - 0.5))
                return false;
        long i = lround(ij[0]), j = lround(ij[1]);
        if (i < 0 || j < 0 || i >= t->nx || j >= t->ny)
                return false;
        size_t q = (size_t) j * t->nx + (size_t) i;
        if (!c->mask[q])
                return false;
        ij[0] = (double) i, ij[1] = (double) j;
        *ret_h = mosaic_painting_z(t, ij[0], ij[1], c->height[q]);
        k[0] = k[1] = k[2] = k[3] = q;
        b[0] = 1, b[1] = b[2] = b[3] = 0;
        return true;
}

/* Weight of a nearest-texel sample against a bilinear one: used only where no copy has more. */
#define NEAREST_WEIGHT 1e-6

/* Tile k's contribution at painting (x, y). */
static void contribute(const struct imp_mosaic_tile *t, const struct imp_copy *c, double x, double y, double feather,
                       struct acc *a) {
        double ij[2] = { NAN, NAN }, h, b[4], fallback = 1;
        size_t k[4], near;
        if (mosaic_height(t, c, x, y, &h, ij)) {
                int i = IMP_MIN((int) ij[0], t->nx - 2), j = IMP_MIN((int) ij[1], t->ny - 2);
                double fx = ij[0] - i, fy = ij[1] - j;
                k[0] = (size_t) j * t->nx + i, k[1] = k[0] + 1, k[2] = k[0] + t->nx, k[3] = k[2] + 1;
                b[0] = (1 - fx) * (1 - fy), b[1] = fx * (1 - fy), b[2] = (1 - fx) * fy, b[3] = fx * fy;
                near = k[(fx >= 0.5) + 2 * (fy >= 0.5)];
        } else if (nearest(t, c, ij, k, b, &h))      /* ij: from mosaic_height (NAN if it had none) */
                near = k[0], fallback = NEAREST_WEIGHT;
        else
                return;
        double edge = fmin(fmin(ij[0], t->nx - 1 - ij[0]), fmin(ij[1], t->ny - 1 - ij[1])) * t->pitch_mm;
        double sg = 0, nx = 0, ny = 0;
        for (int q = 0; q < 4; q++)
                sg += b[q] * c->sigma[k[q]], nx += b[q] * c->normal_x[k[q]], ny += b[q] * c->normal_y[k[q]];
        double w = fallback * fmax(smooth(edge / feather), 1e-4) / (sg * sg + 1e-6);
        if (c->texel_flags[near] & POOR_FLAGS)
                w *= 0.1;
        double phi = t->pose[2] + atan2(t->c2w[4], t->c2w[0]), cp = cos(phi), sp = sin(phi);
        a->w += w, a->h += w * h, a->s2 += w * w * sg * sg;
        a->n[0] += w * (cp * nx - sp * ny), a->n[1] += w * (sp * nx + cp * ny);
        for (int q = 0; q < 4; q++) {
                const struct imp_lafortune *L = &c->brdf[k[q]];
                double wb = w * b[q];
                for (int ch = 0; ch < 3; ch++)
                        a->rd[ch] += wb * L->rho_d[ch], a->rs[ch] += wb * L->rho_s[ch];
                a->lobe[0] += wb * L->cx, a->lobe[1] += wb * L->cy, a->lobe[2] += wb * L->cz, a->lobe[3] += wb * L->k;
        }
        if (w > a->wmax)
                a->wmax = w, a->flags_best = c->texel_flags[near], a->fit_flags_best = c->fit_flags[near];
        uint8_t m = c->mask[near] ? c->mask[near] : 1;
        a->mask = a->mask ? IMP_MIN(a->mask, m) : m;
}

static void finish(const struct acc *a, struct mosaic_out *o, size_t k) {
        if (!(a->w > 0))
                return;
        o->height[k] = (float) (a->h / a->w);
        o->nx_[k] = (float) (a->n[0] / a->w), o->ny_[k] = (float) (a->n[1] / a->w);
        o->sigma[k] = (float) (sqrt(a->s2) / a->w);
        o->mask[k] = a->mask;
        o->flags[k] = a->flags_best;
        o->fit_flags[k] = a->fit_flags_best;
        struct imp_lafortune *L = &o->brdf[k];
        for (int ch = 0; ch < 3; ch++)
                L->rho_d[ch] = (float) (a->rd[ch] / a->w), L->rho_s[ch] = (float) (a->rs[ch] / a->w);
        L->cx = (float) (a->lobe[0] / a->w), L->cy = (float) (a->lobe[1] / a->w), L->cz = (float) (a->lobe[2] / a->w);
        L->k = (float) (a->lobe[3] / a->w);
}

const char *imp_mosaic_uncovered_name(enum imp_mosaic_uncovered c) {
        static const char *const names[IMP_MOSAIC_UNCOVERED_N] = { "edge", "gap", "copy_edge", "hole" };
        return (unsigned) c < IMP_MOSAIC_UNCOVERED_N ? names[c] : "?";
}

/* Why painting (x, y) got no contribution (mosaic.h): whether a copy's grid holds it (within
 * half a texel, as nearest() reads) and how near that grid's edge; else how near the border. */
static enum imp_mosaic_uncovered uncovered_cause(const struct imp_painting *p, const unsigned *in, size_t n_in,
                                                 const struct mosaic_grid *g, double x, double y, double *ret_border) {
        bool in_grid = false, deep = false;
        for (size_t q = 0; q < n_in; q++) {
                const struct imp_mosaic_tile *t = &p->tiles[in[q]];
                double ij[2];
                if (!imp_mosaic_painting_to_tile(t, x, y, ij) ||
                    !(ij[0] > -0.5 && ij[1] > -0.5 && ij[0] < t->nx - 0.5 && ij[1] < t->ny - 0.5))
                        continue;
                in_grid = true;
                deep |= fmin(fmin(ij[0], t->nx - 1 - ij[0]), fmin(ij[1], t->ny - 1 - ij[1])) > 2;
        }
        *ret_border = fmin(fmin(x, g->extent_mm[0] - x), fmin(y, g->extent_mm[1] - y));
        if (in_grid)
                return deep ? IMP_MOSAIC_UNCOVERED_HOLE : IMP_MOSAIC_UNCOVERED_COPY_EDGE;
        return *ret_border <= g->edge_band_mm ? IMP_MOSAIC_UNCOVERED_EDGE : IMP_MOSAIC_UNCOVERED_GAP;
}

int mosaic_blend_tile(const struct imp_painting *p, const struct mosaic_cache *c, const unsigned *in, size_t n_in,
                      const struct mosaic_grid *g, int col, int row, struct mosaic_out *o) {
        int i0 = col * g->tile_px, j0 = row * g->tile_px;
        int r = mosaic_out_alloc(o, IMP_MIN(g->tile_px, g->nx - i0), IMP_MIN(g->tile_px, g->ny - j0));
        if (r < 0)
                return r;
        o->i0 = i0, o->j0 = j0;
        o->origin_mm[0] = i0 * g->pitch_mm, o->origin_mm[1] = j0 * g->pitch_mm;
        for (int j = 0; j < o->ny; j++)
                for (int i = 0; i < o->nx; i++) {
                        double x = (i0 + i) * g->pitch_mm, y = (j0 + j) * g->pitch_mm;
                        struct acc a = { 0 };
                        for (size_t q = 0; q < n_in; q++)
                                contribute(&p->tiles[in[q]], &c->copies[in[q]], x, y, g->feather_mm, &a);
                        finish(&a, o, (size_t) j * o->nx + i);
                        if (a.w > 0)
                                continue;
                        double border;
                        enum imp_mosaic_uncovered why = uncovered_cause(p, in, n_in, g, x, y, &border);
                        o->uncovered[why]++;
                        if (why == IMP_MOSAIC_UNCOVERED_EDGE)
                                o->edge_depth_mm = fmax(o->edge_depth_mm, border);
                }
        return 0;
}

static int write_maps(const struct mosaic_out *o, const char *dir, struct imp_error *err) {
        _cleanup_image_ struct imp_image *rd = NULL, *rs = NULL, *lo = NULL, *fl = NULL;
        int r;
        if ((r = imp_image_new(o->nx, o->ny, 3, IMP_PIX_F32, &rd)) < 0 || (r = imp_image_new(o->nx, o->ny, 3, IMP_PIX_F32, &rs)) < 0 ||
            (r = imp_image_new(o->nx, o->ny, 4, IMP_PIX_F32, &lo)) < 0 || (r = imp_image_new(o->nx, o->ny, 1, IMP_PIX_F32, &fl)) < 0)
                return imp_error_set(err, r, "out of memory");
        for (int j = 0; j < o->ny; j++)
                for (int i = 0; i < o->nx; i++) {
                        const struct imp_lafortune *L = &o->brdf[(size_t) j * o->nx + i];
                        float *d = imp_image_f32(rd, i, j), *s = imp_image_f32(rs, i, j), *l = imp_image_f32(lo, i, j);
                        for (int ch = 0; ch < 3; ch++)
                                d[ch] = L->rho_d[ch], s[ch] = L->rho_s[ch];
                        l[0] = L->cx, l[1] = L->cy, l[2] = L->cz, l[3] = L->k;
                        *imp_image_f32(fl, i, j) = o->fit_flags[(size_t) j * o->nx + i];
                }
        static const char *const rgb[] = { "R", "G", "B" }, *const lobe[] = { "cx", "cy", "cz", "k" },
                                 *const flags[] = { "flags" };
        char path[4200];
        const struct { const char *file; const struct imp_image *img; const char *const *names; } m[] = {
                { "rho_d.exr", rd, rgb }, { "rho_s.exr", rs, rgb }, { "lobe.exr", lo, lobe }, { "fit-flags.exr", fl, flags } };
        for (size_t q = 0; q < sizeof m / sizeof m[0]; q++) {
                snprintf(path, sizeof path, "%s/%s", dir, m[q].file);
                if ((r = imp_exr_write(path, m[q].img, m[q].names, true, err)) < 0)
                        return r;
        }
        return 0;
}

int mosaic_out_write(const struct mosaic_out *o, const struct mosaic_grid *g, const char *dir, struct imp_error *err) {
        struct imp_heightfield hf = { .nx = o->nx, .ny = o->ny, .pitch_mm = g->pitch_mm, .height_mm = o->height,
                                      .nx_ = o->nx_, .ny_ = o->ny_, .sigma_mm = o->sigma, .mask = o->mask,
                                      .texel_flags = o->flags };
        double T[16] = { 1, 0, 0, o->origin_mm[0], 0, 1, 0, o->origin_mm[1], 0, 0, 1, 0, 0, 0, 0, 1 };
        memcpy(hf.canvas_to_world, T, sizeof T);
        int r = imp_heightfield_write_exr(&hf, dir, err);
        if (r < 0 || (r = write_maps(o, dir, err)) < 0)
                return r;
        json_t *m = json_array();
        for (int i = 0; i < 16; i++)
                json_array_append_new(m, json_real(T[i]));
        _cleanup_json_ json_t *j = json_pack("{s:s,s:i,s:s,s:f,s:i,s:i,s:o,s:{s:s},s:{s:i,s:i}}", "format",
                                             "impasto-digital-copy", "version", 1, "units", "mm", "pitch_mm", g->pitch_mm,
                                             "nx", o->nx, "ny", o->ny, "canvas_to_world", m, "provenance", "software",
                                             "impasto mosaic", "mosaic_tile", "i0", o->i0, "j0", o->j0);
        if (!j)
                return imp_error_set(err, -ENOMEM, "out of memory");
        char path[4200];
        snprintf(path, sizeof path, "%s/copy.json", dir);
        return imp_json_save_atomic(path, j, err);
}
