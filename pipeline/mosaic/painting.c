/* painting.json, the tiles' copy.json and the truth poses; placement of a tile in the
 * painting frame (mosaic.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "json-util.h"
#include "macro.h"
#include "mosaic.h"
#include "tiles.h"

void imp_painting_done(struct imp_painting *p) {
        if (!p)
                return;
        free(p->tiles);
        memset(p, 0, sizeof *p);
}

void imp_mosaic_tile_to_painting(const struct imp_mosaic_tile *t, double fi, double fj, double ret[2]) {
        const double *M = t->c2w;
        double u = fi * t->pitch_mm, v = fj * t->pitch_mm;
        double wx = M[0] * u + M[1] * v + M[3], wy = M[4] * u + M[5] * v + M[7];
        double c = cos(t->pose[2]), s = sin(t->pose[2]);
        ret[0] = t->nominal_mm[0] + t->pose[0] + c * wx - s * wy;
        ret[1] = t->nominal_mm[1] + t->pose[1] + s * wx + c * wy;
}

bool imp_mosaic_painting_to_tile(const struct imp_mosaic_tile *t, double x, double y, double ret[2]) {
        const double *M = t->c2w;
        double c = cos(t->pose[2]), s = sin(t->pose[2]);
        double dx = x - t->nominal_mm[0] - t->pose[0], dy = y - t->nominal_mm[1] - t->pose[1];
        double wx = c * dx + s * dy - M[3], wy = -s * dx + c * dy - M[7];
        double det = M[0] * M[5] - M[1] * M[4];
        if (!(fabs(det) > 1e-12))
                return false;
        double u = (M[5] * wx - M[1] * wy) / det, v = (-M[4] * wx + M[0] * wy) / det;
        ret[0] = u / t->pitch_mm, ret[1] = v / t->pitch_mm;
        return true;
}

void imp_painting_update_bboxes(struct imp_painting *p) {
        for (size_t k = 0; k < p->n_tiles; k++) {
                struct imp_mosaic_tile *t = &p->tiles[k];
                double b[4] = { INFINITY, INFINITY, -INFINITY, -INFINITY };
                for (int c = 0; c < 4; c++) {
                        double xy[2];
                        imp_mosaic_tile_to_painting(t, (c & 1) ? t->nx - 1 : 0, (c & 2) ? t->ny - 1 : 0, xy);
                        b[0] = fmin(b[0], xy[0]), b[1] = fmin(b[1], xy[1]);
                        b[2] = fmax(b[2], xy[0]), b[3] = fmax(b[3], xy[1]);
                }
                memcpy(t->bbox, b, sizeof b);
        }
}

/* The tile's copy.json: grid and canvas_to_world. */
static int load_tile_copy(struct imp_mosaic_tile *t, struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%s/copy.json", t->copy);
        _cleanup_json_ json_t *j = NULL;
        int r = imp_json_load(path, &j, err);
        if (r < 0)
                return r;
        long long nx, ny;
        if ((r = imp_json_get_int(j, "nx", true, &nx, path, err)) < 0 ||
            (r = imp_json_get_int(j, "ny", true, &ny, path, err)) < 0 ||
            (r = imp_json_get_double(j, "pitch_mm", true, &t->pitch_mm, path, err)) < 0 ||
            (r = imp_json_get_doubles(j, "canvas_to_world", true, 16, t->c2w, path, err)) < 0)
                return r;
        if (nx < 2 || ny < 2 || nx > 65536 || ny > 65536 || !(t->pitch_mm > 0) || !isfinite(t->pitch_mm))
                return imp_error_set(err, -EBADMSG, "%s: expected nx, ny in 2..65536 and pitch_mm > 0, got %lldx%lld at %g",
                                     path, nx, ny, t->pitch_mm);
        t->nx = (int) nx, t->ny = (int) ny;
        for (int i = 0; i < 16; i++)
                if (!isfinite(t->c2w[i]))
                        return imp_error_set(err, -EBADMSG, "%s: canvas_to_world: expected finite numbers", path);
        if (!(fabs(t->c2w[0] * t->c2w[5] - t->c2w[1] * t->c2w[4]) > 0.5))
                return imp_error_set(err, -EBADMSG, "%s: canvas_to_world: the canvas is not within 60° of the "
                                     "painting plane (expected the copy of a tile seen from above)", path);
        return 0;
}

static int load_tile(struct imp_painting *p, const json_t *o, size_t k, const char *path, struct imp_error *err) {
        char what[4400];
        snprintf(what, sizeof what, "%s: tiles[%zu].", path, k);
        struct imp_mosaic_tile *t = &p->tiles[k];
        long long idx = (long long) k, col = 0, row = 0;
        const char *copy = NULL;
        double rb[3] = { 0 }, ctr[2];
        int r;
        if ((r = imp_json_get_int(o, "index", false, &idx, what, err)) < 0 ||
            (r = imp_json_get_int(o, "col", false, &col, what, err)) < 0 ||
            (r = imp_json_get_int(o, "row", false, &row, what, err)) < 0 ||
            (r = imp_json_get_doubles(o, "center_mm", true, 2, ctr, what, err)) < 0 ||
            (r = imp_json_get_doubles(o, "readback_mm", true, 3, rb, what, err)) < 0)
                return r;
        if ((r = imp_json_get_string(o, "copy", false, &copy, what, err)) < 0)
                return r;
        if (!copy)
                return imp_error_set(err, -ENODATA, "%scopy: missing (the tile is not processed yet)", what);
        if (idx < 0 || col < 0 || row < 0 || !isfinite(rb[0]) || !isfinite(rb[1]))
                return imp_error_set(err, -EBADMSG, "%sexpected index, col, row ≥ 0 and a finite readback_mm", what);
        t->index = (unsigned) idx, t->col = (unsigned) col, t->row = (unsigned) row;
        int len = copy[0] == '/' ? snprintf(t->copy, sizeof t->copy, "%s", copy)
                                 : snprintf(t->copy, sizeof t->copy, "%s/%s", p->dir, copy);
        if (len < 0 || (size_t) len >= sizeof t->copy)
                return imp_error_set(err, -ENAMETOOLONG, "%scopy: path too long", what);
        t->nominal_mm[0] = rb[0] - p->origin_mm[0];
        t->nominal_mm[1] = rb[1] - p->origin_mm[1];
        t->prior_sd[0] = t->prior_sd[1] = p->sigma_mm;
        t->prior_sd[2] = p->sigma_deg * M_PI / 180;
        t->prior_sd[3] = p->sigma_z_mm;
        return load_tile_copy(t, err);
}

/* truth/tile-poses.json: { "tiles": [ { "index", "x_mm", "y_mm" (or "offset_mm": [x, y]), "theta_deg" } ] }. */
static int load_truth(struct imp_painting *p, struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%s/truth/tile-poses.json", p->dir);
        if (access(path, F_OK) < 0)
                return 0;
        _cleanup_json_ json_t *j = NULL;
        int r = imp_json_load(path, &j, err);
        if (r < 0)
                return r;
        json_t *arr = json_object_get(j, "tiles");
        if (!json_is_array(arr))
                return imp_error_set(err, -EBADMSG, "%s: tiles: expected an array", path);
        for (size_t i = 0; i < json_array_size(arr); i++) {
                char what[4400];
                snprintf(what, sizeof what, "%s: tiles[%zu].", path, i);
                long long idx;
                double x, y, th;
                json_t *o = json_array_get(arr, i);
                /* the simulator writes "offset_mm": [x, y] (painting_xy = R(θ)·world_xy + offset,
                 * world origin at the field centre: the same point as x_mm, y_mm) */
                json_t *off = json_object_get(o, "offset_mm");
                bool has_off = json_is_array(off) && json_array_size(off) == 2 &&
                               json_is_number(json_array_get(off, 0)) && json_is_number(json_array_get(off, 1));
                if (has_off)
                        x = json_number_value(json_array_get(off, 0)), y = json_number_value(json_array_get(off, 1));
                if ((r = imp_json_get_int(o, "index", true, &idx, what, err)) < 0 ||
                    (!has_off && (r = imp_json_get_double(o, "x_mm", true, &x, what, err)) < 0) ||
                    (!has_off && (r = imp_json_get_double(o, "y_mm", true, &y, what, err)) < 0) ||
                    (r = imp_json_get_double(o, "theta_deg", true, &th, what, err)) < 0)
                        return r;
                for (size_t k = 0; k < p->n_tiles; k++)
                        if (p->tiles[k].index == idx) {
                                p->tiles[k].has_truth = true;
                                p->tiles[k].truth[0] = x, p->tiles[k].truth[1] = y;
                                p->tiles[k].truth[2] = th * M_PI / 180;
                        }
        }
        p->has_truth = true;
        for (size_t k = 0; k < p->n_tiles; k++)
                p->has_truth &= p->tiles[k].has_truth;
        return 0;
}

static int load_header(struct imp_painting *p, const json_t *j, const char *path, struct imp_error *err) {
        const char *fmt = NULL;
        int r = imp_json_get_string(j, "format", true, &fmt, path, err);
        if (r < 0)
                return r;
        if (strcmp(fmt, "impasto-painting") != 0)
                return imp_error_set(err, -EBADMSG, "%s: format: expected \"impasto-painting\", got \"%s\"", path, fmt);
        p->overlap = 0.2, p->sigma_mm = 0.05, p->sigma_deg = 0.05, p->sigma_z_mm = NAN;
        if ((r = imp_json_get_doubles(j, "extent_mm", true, 2, p->extent_mm, path, err)) < 0 ||
            (r = imp_json_get_doubles(j, "fov_mm", true, 2, p->fov_mm, path, err)) < 0 ||
            (r = imp_json_get_doubles(j, "origin_mm", true, 2, p->origin_mm, path, err)) < 0 ||
            (r = imp_json_get_double(j, "overlap", false, &p->overlap, path, err)) < 0 ||
            (r = imp_json_get_double(j, "stage_sigma_mm", false, &p->sigma_mm, path, err)) < 0 ||
            (r = imp_json_get_double(j, "stage_sigma_deg", false, &p->sigma_deg, path, err)) < 0 ||
            (r = imp_json_get_double(j, "stage_sigma_z_mm", false, &p->sigma_z_mm, path, err)) < 0)
                return r;
        if (isnan(p->sigma_z_mm))
                p->sigma_z_mm = p->sigma_mm;
        if (!(p->extent_mm[0] > 0 && p->extent_mm[1] > 0 && p->fov_mm[0] > 0 && p->fov_mm[1] > 0))
                return imp_error_set(err, -EBADMSG, "%s: extent_mm, fov_mm: expected positive sizes", path);
        if (!(p->sigma_mm > 0 && p->sigma_deg > 0 && p->sigma_z_mm > 0))
                return imp_error_set(err, -EBADMSG, "%s: stage_sigma_mm, stage_sigma_deg: expected > 0 (a prior "
                                     "of σ 0 would forbid any registration)", path);
        return 0;
}

int imp_painting_load(const char *dir, struct imp_painting *p, struct imp_error *err) {
        memset(p, 0, sizeof *p);
        snprintf(p->dir, sizeof p->dir, "%s", dir);
        char path[4200];
        snprintf(path, sizeof path, "%s/painting.json", dir);
        _cleanup_json_ json_t *j = NULL;
        int r = imp_painting_json_read(path, &j, err);     /* bounded; every field checked: tiles.h */
        if (r < 0 || (r = load_header(p, j, path, err)) < 0 || (r = imp_painting_json_check(j, path, err)) < 0)
                return r;
        json_t *arr = json_object_get(j, "tiles");
        if (!json_is_array(arr) || json_array_size(arr) == 0)
                return imp_error_set(err, -EBADMSG, "%s: tiles: expected a non-empty array", path);
        p->n_tiles = json_array_size(arr);
        if (!(p->tiles = calloc(p->n_tiles, sizeof *p->tiles)))
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t k = 0; k < p->n_tiles; k++)
                if ((r = load_tile(p, json_array_get(arr, k), k, path, err)) < 0)
                        return r;
        imp_painting_update_bboxes(p);
        return load_truth(p, err);
}
