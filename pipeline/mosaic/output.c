/* The mosaic on disk (mosaic.h): output tiles in order, then the relief boxes with global
 * thresholds, then the pyramid, then the index. */
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
#include "numerics.h"

/* Input tiles overlapping each output tile (CSR), output tiles row-major. */
static int schedule(const struct imp_painting *p, const struct mosaic_grid *g, size_t **ret_off, unsigned **ret_tiles) {
        size_t n_out = (size_t) g->tiles_x * g->tiles_y, cap = n_out * 4 + 16, n = 0;
        size_t *off = malloc((n_out + 1) * sizeof *off);
        unsigned *tl = malloc(cap * sizeof *tl);
        if (!off || !tl)
                return free(off), free(tl), -ENOMEM;
        for (size_t s = 0; s < n_out; s++) {
                int col = (int) (s % g->tiles_x), row = (int) (s / g->tiles_x);
                double x0 = (col * g->tile_px - 1) * g->pitch_mm, y0 = (row * g->tile_px - 1) * g->pitch_mm;
                double x1 = ((col + 1) * g->tile_px) * g->pitch_mm, y1 = ((row + 1) * g->tile_px) * g->pitch_mm;
                off[s] = n;
                for (unsigned k = 0; k < p->n_tiles; k++) {
                        const double *b = p->tiles[k].bbox;
                        if (b[2] < x0 || b[0] > x1 || b[3] < y0 || b[1] > y1)
                                continue;
                        if (n == cap) {
                                unsigned *nt = realloc(tl, (cap *= 2) * sizeof *tl);
                                if (!nt)
                                        return free(off), free(tl), -ENOMEM;
                                tl = nt;
                        }
                        tl[n++] = k;
                }
        }
        off[n_out] = n;
        *ret_off = off, *ret_tiles = tl;
        return 0;
}

/* Every 4th texel's height and σ (each axis) for the global box thresholds. */
struct sample_set {
        double *h, *s;
        size_t n, ns, cap;
        double hmax;
};

static int keep_samples(struct sample_set *ss, const struct mosaic_out *o) {
        for (int j = 0; j < o->ny; j++)
                for (int i = 0; i < o->nx; i++) {
                        size_t k = (size_t) j * o->nx + i;
                        if (!o->mask[k])
                                continue;
                        ss->hmax = fmax(ss->hmax, o->height[k]);
                        if (((o->i0 + i) & 3) || ((o->j0 + j) & 3))
                                continue;
                        if (ss->n == ss->cap) {
                                ss->cap = ss->cap ? 2 * ss->cap : 4096;
                                double *nh = realloc(ss->h, ss->cap * sizeof *nh);
                                if (!nh)
                                        return -ENOMEM;
                                ss->h = nh;
                                double *ns = realloc(ss->s, ss->cap * sizeof *ns);
                                if (!ns)
                                        return -ENOMEM;
                                ss->s = ns;
                        }
                        ss->h[ss->n++] = o->height[k];
                        if (o->mask[k] == 1)
                                ss->s[ss->ns++] = o->sigma[k];
                }
        return 0;
}

static void tile_dir(char *buf, size_t n, const char *out, int col, int row) {
        snprintf(buf, n, "%s/tiles/%03d-%03d", out, row, col);
}

static void score_truth(const struct mosaic_out *o, const struct mosaic_grid *g, const struct imp_mosaic_truth *truth,
                        struct mosaic_seam_score *seams, double *ss, size_t *cnt) {
        if (!truth)
                return;
        for (int j = 0; j < o->ny; j++)
                for (int i = 0; i < o->nx; i++) {
                        size_t k = (size_t) j * o->nx + i;
                        if (!o->mask[k])
                                continue;
                        double x = (o->i0 + i) * g->pitch_mm, y = (o->j0 + j) * g->pitch_mm;
                        double t = truth->height(truth->ctx, x, y);
                        if (!isfinite(t))
                                continue;
                        *ss += (o->height[k] - t) * (o->height[k] - t), ++*cnt;
                        mosaic_seam_score_add(seams, x, y, o->height[k] - t);
                }
}

/* Pass 1: blends and writes every output tile. */
static int blend_pass(struct imp_painting *p, const struct imp_mosaic_options *o, const struct mosaic_grid *g,
                      const char *out, const struct imp_mosaic_truth *truth, struct sample_set *ss,
                      struct imp_mosaic_figures *f, struct imp_error *err) {
        _cleanup_free_ size_t *off = NULL;
        _cleanup_free_ unsigned *tl = NULL;
        if (schedule(p, g, &off, &tl) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        size_t n_out = (size_t) g->tiles_x * g->tiles_y;
        struct mosaic_cache c;
        if (mosaic_cache_init(&c, p, o->cache_bytes, off, tl, n_out) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        double tss = 0;
        struct mosaic_seam_score *seams = NULL;
        int r = truth ? mosaic_seam_score_new(p, g->pitch_mm, &seams) : 0;
        if (r < 0)
                imp_error_set(err, r, "out of memory");
        for (size_t s = 0; s < n_out && r == 0; s++) {
                int col = (int) (s % g->tiles_x), row = (int) (s / g->tiles_x);
                struct mosaic_out t = { 0 };
                char dir[4300];
                tile_dir(dir, sizeof dir, out, col, row);
                if ((r = mosaic_cache_step(&c, s, err)) < 0)
                        break;
                if ((r = mosaic_blend_tile(p, &c, tl + off[s], off[s + 1] - off[s], g, col, row, &t)) < 0)
                        imp_error_set(err, r, "out of memory");
                else if ((r = mosaic_out_write(&t, g, dir, err)) == 0 && (r = keep_samples(ss, &t)) < 0)
                        imp_error_set(err, r, "out of memory");
                if (r == 0) {
                        f->texels_written += (size_t) t.nx * t.ny;
                        for (size_t k = 0; k < (size_t) t.nx * t.ny; k++)
                                f->texels_covered += t.mask[k] != 0;
                        for (int q = 0; q < IMP_MOSAIC_UNCOVERED_N; q++)
                                f->uncovered[q] += t.uncovered[q];
                        f->edge_depth_mm = fmax(f->edge_depth_mm, t.edge_depth_mm);
                        score_truth(&t, g, truth, seams, &tss, &f->height_n);
                }
                mosaic_out_done(&t);
        }
        f->input_loads = c.loads, f->max_resident = c.max_resident;
        mosaic_cache_done(&c);
        f->height_rmse_um = f->height_n ? 1e3 * sqrt(tss / f->height_n) : NAN;
        f->seam_out_step_um = f->seam_out_jump_um = f->seam_out_ref_um = NAN;
        if (seams)
                mosaic_seam_score_finish(seams, f);
        mosaic_seam_score_free(seams);
        return r;
}

static int box_thresholds(struct sample_set *ss, const struct imp_mosaic_options *o, struct imp_mosaic_figures *f) {
        if (ss->n == 0)
                return -ENODATA;
        double sig = 0;
        int r = imp_quantile(ss->h, ss->n, o->box_ref_percentile / 100, &f->h_ref_mm);
        if (r < 0)
                return r;
        if (ss->ns)
                imp_quantile(ss->s, ss->ns, 0.5, &sig);
        f->H_mm = ss->hmax - f->h_ref_mm;
        f->delta0_mm = fmax(o->box_delta_frac * f->H_mm, o->box_noise_k * sig);
        return 0;
}

static json_t *index_json(const struct imp_painting *p, const struct mosaic_grid *g, const struct imp_mosaic_figures *f,
                          const struct imp_mosaic_options *o, json_t *levels) {
        json_t *tiles = json_array(), *inputs = json_array();
        for (int row = 0; row < g->tiles_y; row++)
                for (int col = 0; col < g->tiles_x; col++) {
                        char dir[64];
                        snprintf(dir, sizeof dir, "tiles/%03d-%03d", row, col);
                        json_array_append_new(tiles, json_pack("{s:s,s:i,s:i,s:i,s:i,s:i,s:i}", "dir", dir, "col", col,
                                "row", row, "i0", col * g->tile_px, "j0", row * g->tile_px,
                                "nx", IMP_MIN(g->tile_px, g->nx - col * g->tile_px),
                                "ny", IMP_MIN(g->tile_px, g->ny - row * g->tile_px)));
                }
        for (size_t k = 0; k < p->n_tiles; k++) {
                const struct imp_mosaic_tile *t = &p->tiles[k];
                json_array_append_new(inputs, json_pack("{s:i,s:s,s:[f,f],s:f,s:f}", "index", t->index, "copy", t->copy,
                        "shift_mm", t->pose[0], t->pose[1], "theta_deg", t->pose[2] * 180 / M_PI, "dz_mm", t->pose[3]));
        }
        return json_pack("{s:s,s:i,s:s,s:f,s:i,s:i,s:[f,f],s:i,s:i,s:i,s:o,s:{s:f,s:f,s:f,s:i,s:I},s:o,s:o,s:b}",
                         "format", "impasto-mosaic", "version", 1, "units", "mm", "pitch_mm", g->pitch_mm, "nx", g->nx,
                         "ny", g->ny, "extent_mm", p->extent_mm[0], p->extent_mm[1], "tile_px", g->tile_px,
                         "tiles_x", g->tiles_x, "tiles_y", g->tiles_y, "tiles", tiles, "boxes", "h_ref", f->h_ref_mm,
                         "delta0", f->delta0_mm, "H", f->H_mm, "cell_px", o->box_cell_px, "n_boxes",
                         (json_int_t) f->n_boxes, "pyramid", levels, "input_tiles", inputs, "prior_only", o->prior_only);
}

static json_t *number_or_null(double v) {
        return isfinite(v) ? json_real(v) : json_null();
}

/* The figures against truth (docs/mosaic.md): the height RMSE and the output's seam step. */
static json_t *truth_json(const struct imp_mosaic_figures *f) {
        return json_pack("{s:o,s:I,s:o,s:o,s:o,s:I}", "height_rmse_um", number_or_null(f->height_rmse_um),
                         "height_texels", (json_int_t) f->height_n, "seam_step_output_um",
                         number_or_null(f->seam_out_step_um), "seam_jump_output_um", number_or_null(f->seam_out_jump_um),
                         "seam_jump_reference_um", number_or_null(f->seam_out_ref_um), "seam_segments",
                         (json_int_t) f->seam_out_n);
}

/* The extent's coverage (docs/mosaic.md, "Coverage"): texels, covered, and the others by
 * cause; the output tiles' masks say which ones. */
static json_t *coverage_json(const struct imp_mosaic_figures *f) {
        json_t *why = json_object();
        for (int q = 0; why && q < IMP_MOSAIC_UNCOVERED_N; q++)
                json_object_set_new(why, imp_mosaic_uncovered_name(q), json_integer((json_int_t) f->uncovered[q]));
        return json_pack("{s:I,s:I,s:o,s:f,s:f}", "texels", (json_int_t) (f->out_nx * f->out_ny), "covered",
                         (json_int_t) f->texels_covered, "uncovered", why, "edge_band_mm", f->edge_band_mm,
                         "edge_depth_mm", f->edge_depth_mm);
}

static int make_grid(const struct imp_painting *p, const struct imp_mosaic_options *o, struct mosaic_grid *g,
                     struct imp_error *err) {
        double pitch = p->tiles[0].pitch_mm;
        for (size_t k = 1; k < p->n_tiles; k++)
                if (fabs(p->tiles[k].pitch_mm - pitch) > 1e-6 * pitch)
                        return imp_error_set(err, -EMEDIUMTYPE, "%s: pitch_mm %g differs from the first tile's %g (one pitch "
                                             "per painting)", p->tiles[k].copy, p->tiles[k].pitch_mm, pitch);
        if (o->out_tile_px < 16 || o->out_tile_px > 8192)
                return imp_error_set(err, -EINVAL, "mosaic: out_tile_px: expected 16..8192, got %d", o->out_tile_px);
        *g = (struct mosaic_grid) { .pitch_mm = pitch, .tile_px = o->out_tile_px };
        g->nx = (int) ceil(p->extent_mm[0] / pitch - 1e-6), g->ny = (int) ceil(p->extent_mm[1] / pitch - 1e-6);
        g->tiles_x = (g->nx + g->tile_px - 1) / g->tile_px, g->tiles_y = (g->ny + g->tile_px - 1) / g->tile_px;
        g->feather_mm = o->feather_mm > 0 ? o->feather_mm
                                          : fmax(0.5 * p->overlap * fmin(p->fov_mm[0], p->fov_mm[1]), 2 * pitch);
        g->extent_mm[0] = p->extent_mm[0], g->extent_mm[1] = p->extent_mm[1];
        /* an uncovered texel beyond every copy this near the border is the outer tiles' shortfall
           (a gap between two copies lies an overlap's half or more inside) */
        g->edge_band_mm = fmax(0.5 * p->overlap * fmin(p->fov_mm[0], p->fov_mm[1]), 2 * pitch);
        return 0;
}

int imp_mosaic_write(struct imp_painting *p, const struct imp_mosaic_options *o, const char *out,
                     const struct imp_mosaic_truth *truth, struct imp_mosaic_figures *f, struct imp_error *err) {
        memset(f, 0, sizeof *f);
        struct mosaic_grid g;
        int r = make_grid(p, o, &g, err);
        if (r < 0)
                return r;
        imp_painting_update_bboxes(p);
        char path[4300];
        snprintf(path, sizeof path, "%s/tiles", out);
        if ((r = imp_mkdir_p(path, 0755)) < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", path, strerror(-r));
        f->out_nx = g.nx, f->out_ny = g.ny, f->out_tiles_x = g.tiles_x, f->out_tiles_y = g.tiles_y;
        f->edge_band_mm = g.edge_band_mm;
        struct sample_set ss = { .hmax = -INFINITY };
        r = blend_pass(p, o, &g, out, truth, &ss, f, err);
        if (r == 0 && (r = box_thresholds(&ss, o, f)) < 0)
                imp_error_set(err, r, "mosaic: no texel of the painting is covered by a tile");
        free(ss.h), free(ss.s);
        if (r < 0)
                return r;
        f->texels_doubled = f->texels_written - (size_t) g.nx * g.ny;   /* the tiles partition the grid */
        if ((r = mosaic_boxes_write(&g, out, f->h_ref_mm, f->delta0_mm, f->H_mm, o->box_cell_px, &f->n_boxes, err)) < 0)
                return r;
        json_t *levels = NULL;
        if ((r = mosaic_pyramid_write(&g, out, &levels, err)) < 0)
                return r;
        f->pyramid_levels = r;
        _cleanup_json_ json_t *j = index_json(p, &g, f, o, levels);
        if (!j || json_object_set_new(j, "coverage", coverage_json(f)) < 0 ||
            (truth && json_object_set_new(j, "truth", truth_json(f)) < 0))
                return imp_error_set(err, -ENOMEM, "out of memory");
        snprintf(path, sizeof path, "%s/mosaic.json", out);
        return imp_json_save_atomic(path, j, err);
}
