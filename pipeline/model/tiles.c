/* Tile plans (tiles.h): even spacing with at least the asked overlap, serpentine order,
 * per-tile stage targets and height offsets. Pure arithmetic, no I/O but the conf group. */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "json-util.h"
#include "tiles.h"

struct imp_tile_plan {
        struct imp_tile_options opt;
        unsigned cols, rows;
        double step_mm[2];
        struct imp_tile *tiles;         /* scan order */
        double *correction_mm;          /* per grid cell, row-major */
};

void imp_tile_options_default(struct imp_tile_options *ret) {
        *ret = (struct imp_tile_options) { .overlap = IMP_TILES_DEFAULT_OVERLAP, .order = IMP_TILE_ORDER_ROWS };
}

static int check_options(const struct imp_tile_options *o, struct imp_error *err) {
        static const char axis[2] = { 'x', 'y' };
        for (int a = 0; a < 2; a++) {
                if (!(o->extent_mm[a] > 0 && o->extent_mm[a] <= IMP_PAINTING_MAX_MM))
                        return imp_error_set(err, -EINVAL, "tiles: extent_mm %c: expected a number in (0, %g] mm, got %g",
                                             axis[a], IMP_PAINTING_MAX_MM, o->extent_mm[a]);
                if (!(o->fov_mm[a] > 0 && o->fov_mm[a] <= IMP_PAINTING_MAX_MM))
                        return imp_error_set(err, -EINVAL, "tiles: fov_mm %c: expected a number in (0, %g] mm, got %g",
                                             axis[a], IMP_PAINTING_MAX_MM, o->fov_mm[a]);
                if (!(fabs(o->origin_mm[a]) <= 1e6))
                        return imp_error_set(err, -EINVAL, "tiles: origin_mm %c: expected a finite number within "
                                             "±1e6 mm, got %g", axis[a], o->origin_mm[a]);
        }
        if (!(o->edge_margin_mm >= 0 && o->edge_margin_mm <= IMP_PAINTING_MAX_MM))
                return imp_error_set(err, -EINVAL, "tiles: edge_margin_mm: expected a number in [0, %g] mm, got %g",
                                     IMP_PAINTING_MAX_MM, o->edge_margin_mm);
        if (!(o->overlap >= 0 && o->overlap <= IMP_TILES_MAX_OVERLAP))
                return imp_error_set(err, -EINVAL, "tiles: overlap: expected 0..%g (a fraction of the field), got %g",
                                     IMP_TILES_MAX_OVERLAP, o->overlap);
        if (o->order != IMP_TILE_ORDER_ROWS && o->order != IMP_TILE_ORDER_COLUMNS)
                return imp_error_set(err, -EINVAL, "tiles: order: expected rows or columns, got %d", (int) o->order);
        if (!isfinite(o->z_mm))
                return imp_error_set(err, -EINVAL, "tiles: z_mm: expected a finite number");
        for (int i = 0; i < 4; i++)
                if (!isfinite(o->corner_z_mm[i]))
                        return imp_error_set(err, -EINVAL, "tiles: corner_z_mm[%d]: expected a finite number", i);
        return 0;
}

/* Tiles along one axis and their spacing (0 for a single tile); extent includes both margins. */
static unsigned axis_count(double extent, double fov, double overlap, double *ret_step) {
        if (extent <= fov) {
                *ret_step = 0;
                return 1;
        }
        /* A hair of slack so that an exact fit (240 / 48) does not round up to one more tile. */
        double n = 1 + ceil((extent - fov) / (fov * (1 - overlap)) - 1e-9);
        *ret_step = (extent - fov) / (n - 1);
        return n > IMP_TILES_MAX ? IMP_TILES_MAX + 1 : (unsigned) n;
}

/* Centre of tile i along an axis of the painting frame: from the grown area's start −margin. */
static double axis_center(double extent, double margin, double fov, double step, unsigned i) {
        return step > 0 ? fov / 2 - margin + step * i : extent / 2;
}

/* The corners' bilinear surface at (x, y) of the painting frame. */
static double corner_surface(const struct imp_tile_options *o, double x, double y) {
        double u = IMP_CLAMP(x / o->extent_mm[0], 0.0, 1.0), v = IMP_CLAMP(y / o->extent_mm[1], 0.0, 1.0);
        const double *c = o->corner_z_mm;
        return (1 - u) * (1 - v) * c[0] + u * (1 - v) * c[1] + (1 - u) * v * c[2] + u * v * c[3];
}

/* Grid cell of scan position k: serpentine along the fast axis. */
static void scan_cell(const struct imp_tile_plan *p, unsigned k, unsigned *ret_col, unsigned *ret_row) {
        bool rows = p->opt.order == IMP_TILE_ORDER_ROWS;
        unsigned fast_n = rows ? p->cols : p->rows;
        unsigned slow = k / fast_n, fast = k % fast_n;
        if (slow % 2)
                fast = fast_n - 1 - fast;
        *ret_col = rows ? fast : slow;
        *ret_row = rows ? slow : fast;
}

static void fill_tile(struct imp_tile_plan *p, unsigned k) {
        const struct imp_tile_options *o = &p->opt;
        struct imp_tile *t = &p->tiles[k];
        unsigned col, row;
        scan_cell(p, k, &col, &row);
        double m = o->edge_margin_mm;
        double cx = axis_center(o->extent_mm[0], m, o->fov_mm[0], p->step_mm[0], col);
        double cy = axis_center(o->extent_mm[1], m, o->fov_mm[1], p->step_mm[1], row);
        double z_off = corner_surface(o, cx, cy) + p->correction_mm[(size_t) row * p->cols + col];
        *t = (struct imp_tile) {
                .index = k, .col = col, .row = row,
                .center_mm = { cx, cy },
                .rect_mm = { cx - o->fov_mm[0] / 2, cy - o->fov_mm[1] / 2, cx + o->fov_mm[0] / 2, cy + o->fov_mm[1] / 2 },
                .z_offset_mm = z_off,
                .stage_mm = { o->origin_mm[0] + cx, o->origin_mm[1] + cy, o->z_mm + z_off },
        };
}

int imp_tile_plan_new(const struct imp_tile_options *o, struct imp_tile_plan **ret, struct imp_error *err) {
        if (!o || !ret)
                return -EINVAL;
        int r = check_options(o, err);
        if (r < 0)
                return r;
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = calloc(1, sizeof *p);
        if (!p)
                return -ENOMEM;
        p->opt = *o;
        p->cols = axis_count(o->extent_mm[0] + 2 * o->edge_margin_mm, o->fov_mm[0], o->overlap, &p->step_mm[0]);
        p->rows = axis_count(o->extent_mm[1] + 2 * o->edge_margin_mm, o->fov_mm[1], o->overlap, &p->step_mm[1]);
        if ((uint64_t) p->cols * p->rows > IMP_TILES_MAX)
                return imp_error_set(err, -E2BIG, "tiles: %u × %u tiles for %g × %g mm at a %g × %g mm field: more than %d",
                                     p->cols, p->rows, o->extent_mm[0], o->extent_mm[1], o->fov_mm[0], o->fov_mm[1],
                                     IMP_TILES_MAX);
        size_t n = (size_t) p->cols * p->rows;
        p->tiles = calloc(n, sizeof *p->tiles);
        p->correction_mm = calloc(n, sizeof *p->correction_mm);
        if (!p->tiles || !p->correction_mm)
                return -ENOMEM;
        for (unsigned k = 0; k < n; k++)
                fill_tile(p, k);
        *ret = TAKE_PTR(p);
        return 0;
}

void imp_tile_plan_free(struct imp_tile_plan *p) {
        if (!p)
                return;
        free(p->tiles);
        free(p->correction_mm);
        free(p);
}

const struct imp_tile_options *imp_tile_plan_options(const struct imp_tile_plan *p) {
        return &p->opt;
}

size_t imp_tile_plan_count(const struct imp_tile_plan *p) {
        return p ? (size_t) p->cols * p->rows : 0;
}

const struct imp_tile *imp_tile_plan_tile(const struct imp_tile_plan *p, size_t i) {
        return p && i < imp_tile_plan_count(p) ? &p->tiles[i] : NULL;
}

/* Scan position of grid cell (col, row): scan_cell inverted. */
static size_t scan_index(const struct imp_tile_plan *p, unsigned col, unsigned row) {
        bool rows = p->opt.order == IMP_TILE_ORDER_ROWS;
        unsigned fast_n = rows ? p->cols : p->rows;
        unsigned slow = rows ? row : col, fast = rows ? col : row;
        if (slow % 2)
                fast = fast_n - 1 - fast;
        return (size_t) slow * fast_n + fast;
}

const struct imp_tile *imp_tile_plan_at(const struct imp_tile_plan *p, unsigned col, unsigned row) {
        if (!p || col >= p->cols || row >= p->rows)
                return NULL;
        return &p->tiles[scan_index(p, col, row)];
}

void imp_tile_plan_grid(const struct imp_tile_plan *p, unsigned *ret_cols, unsigned *ret_rows) {
        *ret_cols = p->cols;
        *ret_rows = p->rows;
}

void imp_tile_plan_spacing(const struct imp_tile_plan *p, double ret_step_mm[2], double ret_overlap[2]) {
        for (int a = 0; a < 2; a++) {
                ret_step_mm[a] = p->step_mm[a];
                ret_overlap[a] = p->step_mm[a] > 0 ? 1 - p->step_mm[a] / p->opt.fov_mm[a] : 0;
        }
}

int imp_tile_plan_set_z_correction(struct imp_tile_plan *p, unsigned col, unsigned row, double z_mm) {
        if (!p || col >= p->cols || row >= p->rows)
                return -ERANGE;
        if (!isfinite(z_mm))
                return -EINVAL;
        p->correction_mm[(size_t) row * p->cols + col] = z_mm;
        fill_tile(p, (unsigned) scan_index(p, col, row));
        return 0;
}

int imp_tile_plan_check_limits(const struct imp_tile_plan *p, const double min_mm[3], const double max_mm[3],
                               struct imp_error *err) {
        size_t n = imp_tile_plan_count(p);
        for (size_t i = 0; i < n; i++) {
                const struct imp_tile *t = &p->tiles[i];
                for (int a = 0; a < 3; a++)
                        if (!(t->stage_mm[a] >= min_mm[a] && t->stage_mm[a] <= max_mm[a]))
                                return imp_error_set(err, -ERANGE,
                                                     "tiles: tile %u (col %u, row %u): stage %c %.3f mm outside [%.3f, %.3f] mm",
                                                     t->index, t->col, t->row, "xyz"[a], t->stage_mm[a], min_mm[a],
                                                     max_mm[a]);
        }
        return 0;
}

static double move_len(const struct imp_tile *a, const struct imp_tile *b);

double imp_tile_plan_path_mm(const struct imp_tile_plan *p) {
        double len = 0;
        size_t n = imp_tile_plan_count(p);
        for (size_t i = 1; i < n; i++)
                len += move_len(&p->tiles[i - 1], &p->tiles[i]);
        return len;
}

double imp_tile_plan_move_s(const struct imp_tile_plan *p, double speed_mm_s, double settle_s) {
        size_t n = imp_tile_plan_count(p);
        if (n < 2 || !(speed_mm_s > 0))
                return 0;
        return imp_tile_plan_path_mm(p) / speed_mm_s + (double) (n - 1) * settle_s;
}

static double move_len(const struct imp_tile *a, const struct imp_tile *b) {
        const double *u = a->stage_mm, *v = b->stage_mm;
        return sqrt((v[0] - u[0]) * (v[0] - u[0]) + (v[1] - u[1]) * (v[1] - u[1]) + (v[2] - u[2]) * (v[2] - u[2]));
}

#define ESTIMATE_MAX_WORKERS 256

int imp_tile_plan_estimate(const struct imp_tile_plan *p, const struct imp_tile_cost *c, struct imp_tile_estimate *ret) {
        if (!p || !c || !ret)
                return -EINVAL;
        if (!(c->bytes >= 0 && isfinite(c->bytes) && c->capture_s >= 0 && isfinite(c->capture_s) &&
              c->process_s >= 0 && isfinite(c->process_s) && c->speed_mm_s > 0 && isfinite(c->speed_mm_s) &&
              c->settle_s >= 0 && isfinite(c->settle_s)) || c->workers < 1 || c->workers > ESTIMATE_MAX_WORKERS)
                return -EINVAL;
        size_t n = imp_tile_plan_count(p);
        double free_at[ESTIMATE_MAX_WORKERS] = { 0 };
        double captured = 0, end = 0;
        for (size_t i = 0; i < n; i++) {
                if (i > 0)
                        captured += move_len(&p->tiles[i - 1], &p->tiles[i]) / c->speed_mm_s + c->settle_s;
                captured += c->capture_s;
                unsigned w = 0;         /* the worker free first */
                for (unsigned k = 1; k < c->workers; k++)
                        if (free_at[k] < free_at[w])
                                w = k;
                free_at[w] = fmax(free_at[w], captured) + c->process_s;
                end = fmax(end, free_at[w]);
        }
        *ret = (struct imp_tile_estimate) {
                .tiles = n, .frames = n * c->frames, .bytes = (double) n * c->bytes,
                .move_s = imp_tile_plan_move_s(p, c->speed_mm_s, c->settle_s),
                .capture_s = captured, .process_s = (double) n * c->process_s, .wall_s = end,
        };
        return 0;
}

/* ---- the plan file's group ------------------------------------------------------------------ */

static int parse_options(const struct imp_conf *c, const config_setting_t *g, struct imp_tile_options *o,
                         struct imp_error *err) {
        static const char *const known[] = { "extent_mm", "fov_mm", "overlap", "edge_margin_mm", "order", "origin_mm",
                                             "z_mm", "corner_z_mm", "z_corrections", NULL };
        static const char *const orders[] = { "rows", "columns", NULL };
        int order = IMP_TILE_ORDER_ROWS, r;
        imp_tile_options_default(o);
        if ((r = imp_conf_check_known(c, g, known, err)) < 0 ||
            (r = imp_conf_get_doubles(c, g, "extent_mm", true, 2, o->extent_mm, 2, NULL, err)) < 0 ||
            (r = imp_conf_get_doubles(c, g, "fov_mm", true, 2, o->fov_mm, 2, NULL, err)) < 0 ||
            (r = imp_conf_get_double(c, g, "overlap", false, 0, IMP_TILES_MAX_OVERLAP, &o->overlap, err)) < 0 ||
            (r = imp_conf_get_double(c, g, "edge_margin_mm", false, 0, IMP_PAINTING_MAX_MM, &o->edge_margin_mm, err)) < 0 ||
            (r = imp_conf_get_enum(c, g, "order", false, orders, &order, err)) < 0 ||
            (r = imp_conf_get_doubles(c, g, "origin_mm", false, 2, o->origin_mm, 2, NULL, err)) < 0 ||
            (r = imp_conf_get_double(c, g, "z_mm", false, -1e6, 1e6, &o->z_mm, err)) < 0 ||
            (r = imp_conf_get_doubles(c, g, "corner_z_mm", false, 4, o->corner_z_mm, 4, NULL, err)) < 0)
                return r;
        o->order = (enum imp_tile_order) order;
        return 0;
}

static int parse_corrections(const struct imp_conf *c, const config_setting_t *g, struct imp_tile_plan *p,
                             struct imp_error *err) {
        static const char *const known[] = { "tile", "z_mm", NULL };
        config_setting_t *list = NULL;
        int r = imp_conf_get_list(c, g, "z_corrections", false, &list, err);
        if (r < 0 || !list)
                return r;
        for (int i = 0; i < config_setting_length(list); i++) {
                config_setting_t *e = config_setting_get_elem(list, (unsigned) i);
                double cell[2], z = 0;
                if ((r = imp_conf_check_known(c, e, known, err)) < 0 ||
                    (r = imp_conf_get_doubles(c, e, "tile", true, 2, cell, 2, NULL, err)) < 0 ||
                    (r = imp_conf_get_double(c, e, "z_mm", true, -1e3, 1e3, &z, err)) < 0)
                        return r;
                if (cell[0] != floor(cell[0]) || cell[1] != floor(cell[1]) || cell[0] < 0 || cell[1] < 0 ||
                    cell[0] >= p->cols || cell[1] >= p->rows)
                        return imp_error_set(err, -EINVAL, "%s:%d: %s.tile: expected [col, row] inside the %u × %u grid, got [%g, %g]",
                                             imp_conf_path(c), config_setting_source_line(e), imp_conf_setting_path(e),
                                             p->cols, p->rows, cell[0], cell[1]);
                (void) imp_tile_plan_set_z_correction(p, (unsigned) cell[0], (unsigned) cell[1], z);
        }
        return 0;
}

int imp_tile_plan_from_conf(const struct imp_conf *c, const config_setting_t *group, struct imp_tile_plan **ret,
                            struct imp_error *err) {
        if (!c || !group || !ret)
                return -EINVAL;
        struct imp_tile_options o;
        int r = parse_options(c, group, &o, err);
        if (r < 0)
                return r;
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = NULL;
        r = imp_tile_plan_new(&o, &p, err);
        if (r < 0)
                return imp_error_prefix(err, "%s:%d: %s: ", imp_conf_path(c), config_setting_source_line(group),
                                        imp_conf_setting_path(group));
        r = parse_corrections(c, group, p, err);
        if (r < 0)
                return r;
        *ret = TAKE_PTR(p);
        return 0;
}

/* ---- painting.json -------------------------------------------------------------------------- */

json_t *imp_tile_plan_painting_json(const struct imp_tile_plan *p, double stage_sigma_mm, double stage_sigma_deg) {
        const struct imp_tile_options *o = &p->opt;
        json_t *tiles = json_array();
        for (size_t k = 0; tiles && k < imp_tile_plan_count(p); k++) {
                const struct imp_tile *t = &p->tiles[k];
                char cap[32], copy[32];
                snprintf(cap, sizeof cap, "tiles/%04zu", k);
                snprintf(copy, sizeof copy, "copies/%04zu", k);
                json_t *e = json_pack("{s:I,s:I,s:I,s:[f,f],s:[f,f,f],s:[f,f,f],s:s,s:s}", "index", (json_int_t) k,
                                      "col", (json_int_t) t->col, "row", (json_int_t) t->row, "center_mm",
                                      t->center_mm[0], t->center_mm[1], "commanded_mm", t->stage_mm[0],
                                      t->stage_mm[1], t->stage_mm[2], "readback_mm", t->stage_mm[0], t->stage_mm[1],
                                      t->stage_mm[2], "capture", cap, "copy", copy);
                if (!e || json_array_append_new(tiles, e) < 0) {
                        json_decref(tiles);
                        return NULL;
                }
        }
        if (!tiles)
                return NULL;
        return json_pack("{s:s,s:i,s:[f,f],s:[f,f],s:f,s:f,s:[f,f],s:f,s:f,s:I,s:I,s:o}", "format", "impasto-painting",
                         "version", 1, "extent_mm", o->extent_mm[0], o->extent_mm[1], "fov_mm", o->fov_mm[0],
                         o->fov_mm[1], "overlap", o->overlap, "edge_margin_mm", o->edge_margin_mm, "origin_mm", o->origin_mm[0], o->origin_mm[1],
                         "stage_sigma_mm", stage_sigma_mm, "stage_sigma_deg", stage_sigma_deg, "cols",
                         (json_int_t) p->cols, "rows", (json_int_t) p->rows, "tiles", tiles);
}

int imp_painting_json_set_readback(json_t *painting, size_t k, const double readback_mm[3]) {
        json_t *t = json_array_get(json_object_get(painting, "tiles"), k);
        if (!t)
                return -ERANGE;
        json_t *a = json_pack("[f,f,f]", readback_mm[0], readback_mm[1], readback_mm[2]);
        return a && json_object_set_new(t, "readback_mm", a) == 0 ? 0 : -ENOMEM;
}

/* ---- painting.json read by others: bounded, checked -------------------------------------- */

/* A path of painting.json that must not leave the painting's directory: no ".." component. */
static int check_rel_path(const json_t *o, const char *key, const char *what, struct imp_error *err) {
        const char *v = NULL;
        int r = imp_json_get_string(o, key, false, &v, what, err);
        if (r < 0 || !v)
                return r < 0 ? -EBADMSG : 0;
        if (strlen(v) >= 4000)          /* "" is no path: a synthetic tile without a capture */
                return imp_error_set(err, -EBADMSG, "%s%s: expected a path of at most 3999 bytes, got %zu", what,
                                     key, strlen(v));
        for (const char *c = v; *c;) {
                size_t n = strcspn(c, "/");
                if (n == 2 && c[0] == '.' && c[1] == '.')
                        return imp_error_set(err, -EBADMSG, "%s%s: \"%s\" leaves the painting's directory "
                                             "(a \"..\" component): expected a path inside it", what, key, v);
                c += n;
                c += *c == '/';
        }
        return 0;
}

/* A finite array of n numbers (optional unless required). */
static int check_finite(const json_t *o, const char *key, bool required, int n, const char *what,
                        struct imp_error *err) {
        double v[3];
        if (imp_json_get_doubles(o, key, required, n, v, what, err) < 0)
                return -EBADMSG;
        if (!json_object_get(o, key))
                return 0;
        for (int i = 0; i < n; i++)
                if (!isfinite(v[i]) || fabs(v[i]) > 1e9)
                        return imp_error_set(err, -EBADMSG, "%s%s[%d]: expected a finite number of mm, got %g", what,
                                             key, i, v[i]);
        return 0;
}

/* An integer in [lo, hi] (optional: *ret unchanged when absent). */
static int check_int(const json_t *o, const char *key, long long lo, long long hi, long long *ret, const char *what,
                     struct imp_error *err) {
        long long v = *ret;
        if (imp_json_get_int(o, key, false, &v, what, err) < 0)
                return -EBADMSG;
        if (v < lo || v > hi)
                return imp_error_set(err, -EBADMSG, "%s%s: expected %lld..%lld, got %lld", what, key, lo, hi, v);
        *ret = v;
        return 0;
}

static int check_painting_tile(const json_t *t, size_t k, size_t n, long long cols, long long rows, uint8_t *seen,
                               const char *what, struct imp_error *err) {
        char w[4200];
        snprintf(w, sizeof w, "%.4000s: tiles[%zu].", what, k);
        if (!json_is_object(t))
                return imp_error_set(err, -EBADMSG, "%s: tiles[%zu]: expected an object, got %s", what, k,
                                     imp_json_type_name(t));
        long long idx = (long long) k, col = 0, row = 0;
        int r;
        if ((r = check_int(t, "index", 0, (long long) n - 1, &idx, w, err)) < 0 ||
            (r = check_int(t, "col", 0, cols - 1, &col, w, err)) < 0 ||
            (r = check_int(t, "row", 0, rows - 1, &row, w, err)) < 0 ||
            (r = check_finite(t, "center_mm", true, 2, w, err)) < 0 ||
            (r = check_finite(t, "readback_mm", true, 3, w, err)) < 0 ||
            (r = check_finite(t, "commanded_mm", false, 3, w, err)) < 0 ||
            (r = check_rel_path(t, "capture", w, err)) < 0 || (r = check_rel_path(t, "copy", w, err)) < 0)
                return r;
        if (seen[idx]++)
                return imp_error_set(err, -EBADMSG, "%sindex: %lld: another tile has it already", w, idx);
        json_t *done = json_object_get(t, "done");
        if (done && !json_is_boolean(done))
                return imp_error_set(err, -EBADMSG, "%sdone: expected a boolean, got %s", w, imp_json_type_name(done));
        return 0;
}

static int check_sizes(const json_t *j, const char *key, bool required, const char *what, struct imp_error *err) {
        double v[2];
        if (imp_json_get_doubles(j, key, required, 2, v, what, err) < 0)
                return -EBADMSG;
        for (int a = 0; a < 2 && json_object_get(j, key); a++)
                if (!(v[a] > 0 && v[a] <= IMP_PAINTING_MAX_MM))
                        return imp_error_set(err, -EBADMSG, "%s: %s[%d]: expected a size in (0, %g] mm, got %g", what,
                                             key, a, IMP_PAINTING_MAX_MM, v[a]);
        return 0;
}

/* One optional number in [lo, hi] (lo excluded when open_lo). */
static int check_number(const json_t *j, const char *key, double lo, bool open_lo, double hi, const char *what,
                        struct imp_error *err) {
        double v = lo;
        if (imp_json_get_double(j, key, false, &v, what, err) < 0)
                return -EBADMSG;
        if (json_object_get(j, key) && !(v >= lo && v <= hi && !(open_lo && v == lo)))
                return imp_error_set(err, -EBADMSG, "%s: %s: expected a number in %c%g, %g], got %g", what, key,
                                     open_lo ? '(' : '[', lo, hi, v);
        return 0;
}

static int check_painting_header(const json_t *j, const char *what, long long *cols, long long *rows,
                                 struct imp_error *err) {
        const char *fmt = NULL;
        long long version = 1;
        char w[4200];           /* "PATH: " for the helpers that put the key right after it */
        snprintf(w, sizeof w, "%.4000s: ", what);
        if (!json_is_object(j))
                return imp_error_set(err, -EBADMSG, "%s: expected an object, got %s", what, imp_json_type_name(j));
        if (imp_json_get_string(j, "format", true, &fmt, what, err) < 0)
                return -EBADMSG;
        if (strcmp(fmt, "impasto-painting"))
                return imp_error_set(err, -EBADMSG, "%s: format: expected \"impasto-painting\", got \"%.100s\"", what,
                                     fmt);
        int r;
        if ((r = check_int(j, "version", 1, 1, &version, w, err)) < 0 ||
            (r = check_sizes(j, "extent_mm", true, what, err)) < 0 || (r = check_sizes(j, "fov_mm", true, what, err)) < 0 ||
            (r = check_finite(j, "origin_mm", true, 2, w, err)) < 0 ||
            (r = check_number(j, "overlap", 0, false, 0.999, what, err)) < 0 ||
            (r = check_number(j, "edge_margin_mm", 0, false, IMP_PAINTING_MAX_MM, what, err)) < 0 ||
            (r = check_number(j, "stage_sigma_mm", 0, false, 1e3, what, err)) < 0 ||
            (r = check_number(j, "stage_sigma_deg", 0, false, 180, what, err)) < 0 ||
            (r = check_number(j, "stage_sigma_z_mm", 0, false, 1e3, what, err)) < 0 ||
            (r = check_number(j, "pitch_mm", 1e-3, false, 1000, what, err)) < 0 ||
            (r = check_int(j, "cols", 1, IMP_TILES_MAX, cols, w, err)) < 0 ||
            (r = check_int(j, "rows", 1, IMP_TILES_MAX, rows, w, err)) < 0)
                return r;
        return 0;
}

int imp_painting_json_check(const json_t *j, const char *what, struct imp_error *err) {
        long long cols = IMP_TILES_MAX, rows = IMP_TILES_MAX;
        int r = check_painting_header(j, what, &cols, &rows, err);
        if (r < 0)
                return r;
        const json_t *tiles = json_object_get(j, "tiles");
        size_t n = json_array_size(tiles);
        if (!json_is_array(tiles) || n == 0 || n > IMP_TILES_MAX)
                return imp_error_set(err, -EBADMSG, "%s: tiles: expected an array of 1..%d tiles, got %s%s%zu", what,
                                     IMP_TILES_MAX, tiles ? imp_json_type_name(tiles) : "nothing",
                                     json_is_array(tiles) ? " of " : "", json_is_array(tiles) ? n : 0);
        if ((json_object_get(j, "cols") || json_object_get(j, "rows")) && (unsigned long long) cols * rows < n)
                return imp_error_set(err, -EBADMSG, "%s: tiles: %zu tiles, more than cols × rows = %lld × %lld", what,
                                     n, cols, rows);
        uint8_t *seen = calloc(n, 1);
        if (!seen)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", what);
        for (size_t k = 0; k < n && r >= 0; k++)
                r = check_painting_tile(json_array_get(tiles, k), k, n, cols, rows, seen, what, err);
        free(seen);
        return r;
}

/* JSON values in text (the commas, colons and opening brackets outside strings, plus one):
 * what the parse will allocate, counted before it. */
static size_t count_values(const char *t, size_t n) {
        size_t v = 1;
        bool in_str = false;
        for (size_t i = 0; i < n; i++) {
                char c = t[i];
                if (in_str) {
                        if (c == '\\')
                                i++;
                        else if (c == '"')
                                in_str = false;
                } else if (c == '"')
                        in_str = true;
                else if (c == ',' || c == ':' || c == '[' || c == '{')
                        v++;
        }
        return v;
}

/* The whole regular file, at most IMP_PAINTING_JSON_MAX_BYTES; O_NONBLOCK: a FIFO put in its
 * place must not hang the reader. */
static int read_bounded(const char *path, char **ret, size_t *ret_size, struct imp_error *err) {
        int fd = open(path, O_RDONLY | O_CLOEXEC | O_NONBLOCK);
        if (fd < 0) {
                int r = -errno;
                return imp_error_set(err, r, "%s: %s", path, strerror(-r));
        }
        struct stat st = { 0 };
        if (fstat(fd, &st) < 0 || !S_ISREG(st.st_mode) || st.st_size > (off_t) IMP_PAINTING_JSON_MAX_BYTES) {
                bool reg = S_ISREG(st.st_mode);
                close(fd);
                return imp_error_set(err, -EBADMSG, "%s: expected a regular file of at most %u MiB (a painting of "
                                     "at most %d tiles), got %s%lld bytes", path, IMP_PAINTING_JSON_MAX_BYTES >> 20,
                                     IMP_TILES_MAX, reg ? "" : "a special file, ", reg ? (long long) st.st_size : 0LL);
        }
        char *buf = malloc((size_t) st.st_size + 1);
        size_t n = 0;
        ssize_t k = 1;
        while (buf && n < (size_t) st.st_size && (k = read(fd, buf + n, (size_t) st.st_size - n)) > 0)
                n += (size_t) k;
        int r = !buf ? -ENOMEM : k < 0 ? -errno : 0;
        close(fd);
        if (r < 0) {
                free(buf);
                return imp_error_set(err, r, "%s: %s", path, strerror(-r));
        }
        *ret = buf;
        *ret_size = n;  /* a file that shrank meanwhile: what was there */
        return 0;
}

int imp_painting_json_read(const char *path, json_t **ret, struct imp_error *err) {
        *ret = NULL;
        char *text = NULL;
        size_t n = 0;
        int r = read_bounded(path, &text, &n, err);
        if (r < 0)
                return r;
        size_t values = count_values(text, n);
        if (values > IMP_PAINTING_JSON_MAX_VALUES) {
                free(text);
                return imp_error_set(err, -EBADMSG, "%s: %zu JSON values, expected at most %u (a painting of at most "
                                     "%d tiles has ~32 a tile): not parsed", path, values, IMP_PAINTING_JSON_MAX_VALUES,
                                     IMP_TILES_MAX);
        }
        json_error_t je;
        json_t *j = json_loadb(text, n, JSON_REJECT_DUPLICATES, &je);
        free(text);
        if (!j)
                return imp_error_set(err, -EBADMSG, "%s:%d:%d: %s", path, je.line, je.column, je.text);
        *ret = j;
        return 0;
}

int imp_painting_json_load(const char *path, json_t **ret, struct imp_error *err) {
        json_t *j = NULL;
        int r = imp_painting_json_read(path, &j, err);
        if (r >= 0 && (r = imp_painting_json_check(j, path, err)) < 0)
                json_decref(j);
        else if (r >= 0)
                *ret = j;
        return r;
}
