/* Pass 2 and 3 of the mosaic on disk (mosaic-blend.h): relief boxes of every output tile with
 * the painting's global thresholds, and the multi-resolution pyramid. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "boxes.h"
#include "image.h"
#include "json-util.h"
#include "macro.h"
#include "mosaic-blend.h"

/* Reads FILE with channels NAMES into a w×h image of those channels in that order. */
static int read_channels(const char *file, const char *const *names, int n, struct imp_image **ret, struct imp_error *err) {
        char **have = NULL;
        _cleanup_image_ struct imp_image *img = NULL, *o = NULL;
        int r = imp_exr_read(file, &img, &have, err);
        if (r < 0)
                return r;
        int idx[8];
        for (int c = 0; c < n; c++)
                if ((idx[c] = imp_image_channel_index(have, names[c])) < 0) {
                        imp_strv_free(have);
                        return imp_error_set(err, -EBADMSG, "%s: channel \"%s\" missing", file, names[c]);
                }
        imp_strv_free(have);
        if ((r = imp_image_new(img->width, img->height, n, IMP_PIX_F32, &o)) < 0)
                return imp_error_set(err, r, "out of memory");
        for (int j = 0; j < img->height; j++)
                for (int i = 0; i < img->width; i++)
                        for (int c = 0; c < n; c++)
                                imp_image_f32(o, i, j)[c] = imp_image_f32(img, i, j)[idx[c]];
        *ret = TAKE_PTR(o);
        return 0;
}

/* Boxes of one output tile: cells of cell_px texels from the tile's corner. */
static int tile_boxes(const struct imp_image *hm, const struct mosaic_grid *g, double h_ref, double delta0, double H,
                      int cell_px, struct imp_boxes *b) {
        *b = (struct imp_boxes) { .cell_px = cell_px, .nx = hm->width, .ny = hm->height, .pitch_mm = g->pitch_mm,
                                  .h_ref_mm = h_ref, .H_mm = H, .delta0_mm = delta0 };
        b->cells_u = (hm->width + cell_px - 1) / cell_px, b->cells_v = (hm->height + cell_px - 1) / cell_px;
        b->boxes = calloc((size_t) b->cells_u * b->cells_v + 1, sizeof *b->boxes);
        if (!b->boxes)
                return -ENOMEM;
        for (int cv = 0; cv < b->cells_v; cv++)
                for (int cu = 0; cu < b->cells_u; cu++) {
                        struct imp_box x = { .cell_u = cu, .cell_v = cv, .u0 = cu * cell_px, .v0 = cv * cell_px,
                                             .hmax_mm = -INFINITY };
                        x.w = IMP_MIN(cell_px, hm->width - x.u0), x.h = IMP_MIN(cell_px, hm->height - x.v0);
                        for (int j = x.v0; j < x.v0 + x.h; j++)
                                for (int i = x.u0; i < x.u0 + x.w; i++) {
                                        const float *p = imp_image_f32(hm, i, j);
                                        if (!(p[1] >= 0.5f) || !(p[0] - h_ref > delta0))
                                                continue;
                                        x.n_significant++;
                                        if (p[0] > x.hmax_mm)
                                                x.hmax_mm = p[0], x.umax = i, x.vmax = j;
                                }
                        if (x.n_significant)
                                b->boxes[b->n_boxes++] = x, b->n_significant += x.n_significant;
                }
        return 0;
}

int mosaic_boxes_write(const struct mosaic_grid *g, const char *out, double h_ref, double delta0, double H, int cell_px,
                       size_t *ret_boxes, struct imp_error *err) {
        static const char *const HM[] = { "height", "mask" };
        *ret_boxes = 0;
        for (int row = 0; row < g->tiles_y; row++)
                for (int col = 0; col < g->tiles_x; col++) {
                        char path[4300];
                        snprintf(path, sizeof path, "%s/tiles/%03d-%03d/heightfield.exr", out, row, col);
                        _cleanup_image_ struct imp_image *hm = NULL;
                        int r = read_channels(path, HM, 2, &hm, err);
                        if (r < 0)
                                return r;
                        struct imp_boxes b;
                        if ((r = tile_boxes(hm, g, h_ref, delta0, H, cell_px, &b)) < 0)
                                return imp_error_set(err, r, "out of memory");
                        snprintf(path, sizeof path, "%s/tiles/%03d-%03d/boxes.json", out, row, col);
                        r = imp_boxes_save(&b, path, err);
                        *ret_boxes += b.n_boxes;
                        free(b.boxes);
                        if (r < 0)
                                return r;
                }
        return 0;
}

/* Level L tile (col, row) as height, R, G, B, coverage; *ret NULL outside the level's grid. */
static int read_level(const char *out, int L, int col, int row, int tiles_x, int tiles_y, struct imp_image **ret,
                      struct imp_error *err) {
        static const char *const HM[] = { "height", "mask" }, *const RGB[] = { "R", "G", "B" },
                                 *const ALL[] = { "height", "R", "G", "B", "coverage" };
        *ret = NULL;
        if (col >= tiles_x || row >= tiles_y)
                return 0;
        char path[4300];
        if (L > 0) {
                snprintf(path, sizeof path, "%s/pyramid/%d/%03d-%03d.exr", out, L, row, col);
                return read_channels(path, ALL, 5, ret, err);
        }
        _cleanup_image_ struct imp_image *hm = NULL, *rgb = NULL, *o = NULL;
        snprintf(path, sizeof path, "%s/tiles/%03d-%03d/heightfield.exr", out, row, col);
        int r = read_channels(path, HM, 2, &hm, err);
        snprintf(path, sizeof path, "%s/tiles/%03d-%03d/rho_d.exr", out, row, col);
        if (r < 0 || (r = read_channels(path, RGB, 3, &rgb, err)) < 0)
                return r;
        if ((r = imp_image_new(hm->width, hm->height, 5, IMP_PIX_F32, &o)) < 0)
                return imp_error_set(err, r, "out of memory");
        for (int j = 0; j < hm->height; j++)
                for (int i = 0; i < hm->width; i++) {
                        float *d = imp_image_f32(o, i, j), m = imp_image_f32(hm, i, j)[1] >= 0.5f;
                        d[0] = imp_image_f32(hm, i, j)[0];
                        memcpy(d + 1, imp_image_f32(rgb, i, j), 3 * sizeof *d);
                        d[4] = m;
                }
        *ret = TAKE_PTR(o);
        return 0;
}

/* One tile of level L from the 2×2 tiles of level L − 1 below it: each cell the coverage-
 * weighted mean of its four children (seed 003 §4.1: a cell is the union of four finer ones). */
static int level_tile(const char *out, int L, int col, int row, int nx, int ny, const int prev[2], int T,
                      struct imp_error *err) {
        _cleanup_image_ struct imp_image *c0 = NULL, *c1 = NULL, *c2 = NULL, *c3 = NULL, *o = NULL;
        struct imp_image **ch[4] = { &c0, &c1, &c2, &c3 };
        int r;
        for (int q = 0; q < 4; q++)
                if ((r = read_level(out, L - 1, 2 * col + (q & 1), 2 * row + (q >> 1), prev[0], prev[1], ch[q], err)) < 0)
                        return r;
        int w = IMP_MIN(T, nx - col * T), h = IMP_MIN(T, ny - row * T);
        if ((r = imp_image_new(w, h, 5, IMP_PIX_F32, &o)) < 0)
                return imp_error_set(err, r, "out of memory");
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double acc[5] = { 0 }, n = 0;
                        for (int s = 0; s < 4; s++) {
                                int ci = 2 * i + (s & 1), cj = 2 * j + (s >> 1);
                                const struct imp_image *c = *ch[(ci >= T) + 2 * (cj >= T)];
                                ci %= T, cj %= T;
                                if (!c || ci >= c->width || cj >= c->height)
                                        continue;
                                const float *v = imp_image_f32(c, ci, cj);
                                for (int k = 0; k < 4; k++)
                                        acc[k] += v[4] * v[k];
                                acc[4] += v[4], n++;
                        }
                        float *d = imp_image_f32(o, i, j);
                        for (int k = 0; k < 4; k++)
                                d[k] = acc[4] > 0 ? (float) (acc[k] / acc[4]) : 0;
                        d[4] = n > 0 ? (float) (acc[4] / n) : 0;
                }
        static const char *const ALL[] = { "height", "R", "G", "B", "coverage" };
        char path[4300];
        snprintf(path, sizeof path, "%s/pyramid/%d", out, L);
        if ((r = imp_mkdir_p(path, 0755)) < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", path, strerror(-r));
        snprintf(path, sizeof path, "%s/pyramid/%d/%03d-%03d.exr", out, L, row, col);
        return imp_exr_write(path, o, ALL, false, err);
}

int mosaic_pyramid_write(const struct mosaic_grid *g, const char *out, json_t **ret_levels, struct imp_error *err) {
        json_t *levels = json_array();
        int nx = g->nx, ny = g->ny, tiles[2] = { g->tiles_x, g->tiles_y }, L = 0;
        while (tiles[0] > 1 || tiles[1] > 1) {
                int prev[2] = { tiles[0], tiles[1] };
                nx = (nx + 1) / 2, ny = (ny + 1) / 2, L++;
                tiles[0] = (nx + g->tile_px - 1) / g->tile_px, tiles[1] = (ny + g->tile_px - 1) / g->tile_px;
                for (int row = 0; row < tiles[1]; row++)
                        for (int col = 0; col < tiles[0]; col++) {
                                int r = level_tile(out, L, col, row, nx, ny, prev, g->tile_px, err);
                                if (r < 0) {
                                        json_decref(levels);
                                        return r;
                                }
                        }
                json_array_append_new(levels, json_pack("{s:i,s:i,s:i,s:i,s:i,s:f}", "level", L, "nx", nx, "ny", ny,
                                                        "tiles_x", tiles[0], "tiles_y", tiles[1], "cell_mm",
                                                        g->pitch_mm * (1 << L)));
        }
        *ret_levels = levels;
        return L;
}
