/* Scores against truth (mosaic.h): the in-plane registration error against the truth poses,
 * the truth heights, and the seam step the output mosaic shows (mosaic-internal.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "image.h"
#include "json-util.h"
#include "macro.h"
#include "mosaic-internal.h"

/* The 4 corners and the centre of tile t: estimated and true painting positions. */
static void tile_points(const struct imp_mosaic_tile *t, double est[5][2], double tru[5][2]) {
        const double *M = t->c2w;
        for (int q = 0; q < 5; q++) {
                double fi = q == 4 ? 0.5 * (t->nx - 1) : (q & 1) ? t->nx - 1 : 0;
                double fj = q == 4 ? 0.5 * (t->ny - 1) : (q & 2) ? t->ny - 1 : 0;
                imp_mosaic_tile_to_painting(t, fi, fj, est[q]);
                double u = fi * t->pitch_mm, v = fj * t->pitch_mm;
                double wx = M[0] * u + M[1] * v + M[3], wy = M[4] * u + M[5] * v + M[7];
                double c = cos(t->truth[2]), s = sin(t->truth[2]);
                tru[q][0] = t->truth[0] + c * wx - s * wy, tru[q][1] = t->truth[1] + s * wx + c * wy;
        }
}

int imp_mosaic_registration_error(const struct imp_painting *p, struct imp_mosaic_reg_error *ret) {
        if (!p->has_truth)
                return -ENODATA;
        size_t n = 5 * p->n_tiles;
        double (*e)[2] = malloc(n * sizeof *e), (*X)[2] = malloc(n * sizeof *X);
        if (!e || !X)
                return free(e), free(X), -ENOMEM;
        double m[2] = { 0 }, xm[2] = { 0 }, ss = 0;
        for (size_t k = 0; k < p->n_tiles; k++) {
                double est[5][2], tru[5][2];
                tile_points(&p->tiles[k], est, tru);
                for (int q = 0; q < 5; q++) {
                        size_t i = 5 * k + q;
                        e[i][0] = est[q][0] - tru[q][0], e[i][1] = est[q][1] - tru[q][1];
                        X[i][0] = tru[q][0], X[i][1] = tru[q][1];
                        m[0] += e[i][0] / n, m[1] += e[i][1] / n, xm[0] += X[i][0] / n, xm[1] += X[i][1] / n;
                        ss += e[i][0] * e[i][0] + e[i][1] * e[i][1];
                }
        }
        /* The common rigid motion: translation m and rotation φ about the centroid. */
        double num = 0, den = 0;
        for (size_t i = 0; i < n; i++) {
                double jx = -(X[i][1] - xm[1]), jy = X[i][0] - xm[0];
                num += jx * (e[i][0] - m[0]) + jy * (e[i][1] - m[1]), den += jx * jx + jy * jy;
        }
        double phi = den > 0 ? num / den : 0, rs = 0, sum = 0, far = -1, far_d = -1, mx = 0;
        for (size_t i = 0; i < n; i++) {
                double rx = e[i][0] - m[0] + phi * (X[i][1] - xm[1]), ry = e[i][1] - m[1] - phi * (X[i][0] - xm[0]);
                double a = hypot(rx, ry);
                rs += a * a, sum += a, mx = fmax(mx, a);
                double d = hypot(X[i][0] - X[0][0], X[i][1] - X[0][1]);
                if (d > far_d)
                        far_d = d, far = a;
        }
        *ret = (struct imp_mosaic_reg_error) { .abs_rms_um = 1e3 * sqrt(ss / n), .rms_um = 1e3 * sqrt(rs / n),
                                               .mean_um = 1e3 * sum / n, .far_corner_um = 1e3 * far, .max_um = 1e3 * mx };
        free(e), free(X);
        return 0;
}

static double truth_exr_height(void *ctx, double x, double y) {
        const struct imp_mosaic_truth_exr *t = ctx;
        double fi = (x - t->origin_mm[0]) / t->pitch_mm[0], fj = (y - t->origin_mm[1]) / t->pitch_mm[1];
        if (!(fi >= 0 && fj >= 0 && fi <= t->img->width - 1 && fj <= t->img->height - 1))
                return NAN;
        int i = (int) fi, j = (int) fj;
        i = i > t->img->width - 2 ? t->img->width - 2 : i, j = j > t->img->height - 2 ? t->img->height - 2 : j;
        double fx = fi - i, fy = fj - j;
        double h00 = imp_image_f32(t->img, i, j)[t->channel], h10 = imp_image_f32(t->img, i + 1, j)[t->channel];
        double h01 = imp_image_f32(t->img, i, j + 1)[t->channel], h11 = imp_image_f32(t->img, i + 1, j + 1)[t->channel];
        return (1 - fy) * ((1 - fx) * h00 + fx * h10) + fy * ((1 - fx) * h01 + fx * h11);
}

/* The truth's sample grid: the simulator's truth/truth.json gives it (sample (I, J) at
 * origin + (I, J)·pitch: point samples from the canvas corner to its far corner, so W =
 * extent/pitch + 1); without it, the synthetic convention (I·extent_x/W, J·extent_y/H). */
static int truth_grid(const struct imp_painting *p, struct imp_mosaic_truth_exr *t, struct imp_error *err) {
        char path[4300];
        t->pitch_mm[0] = p->extent_mm[0] / t->img->width, t->pitch_mm[1] = p->extent_mm[1] / t->img->height;
        t->origin_mm[0] = t->origin_mm[1] = 0;
        snprintf(path, sizeof path, "%s/truth/truth.json", p->dir);
        if (access(path, F_OK) < 0)
                return 0;
        _cleanup_json_ json_t *j = NULL;
        double pitch;
        long long nx, ny;
        int r = imp_json_load(path, &j, err);
        if (r < 0 || (r = imp_json_get_double(j, "pitch_mm", true, &pitch, path, err)) < 0 ||
            (r = imp_json_get_doubles(j, "origin_mm", true, 2, t->origin_mm, path, err)) < 0 ||
            (r = imp_json_get_int(j, "nx", true, &nx, path, err)) < 0 || (r = imp_json_get_int(j, "ny", true, &ny, path, err)) < 0)
                return r;
        if (!(pitch > 0) || !isfinite(t->origin_mm[0]) || !isfinite(t->origin_mm[1]) || nx != t->img->width ||
            ny != t->img->height)
                return imp_error_set(err, -EBADMSG, "%s: expected pitch_mm > 0, a finite origin_mm and nx, ny of the "
                                     "heightfield (%d × %d), got %g, %lld × %lld", path, t->img->width, t->img->height,
                                     pitch, nx, ny);
        t->pitch_mm[0] = t->pitch_mm[1] = pitch;
        return 0;
}

int imp_mosaic_truth_load(const struct imp_painting *p, struct imp_mosaic_truth_exr *t, struct imp_mosaic_truth *ret,
                          struct imp_error *err) {
        char path[4300];
        memset(t, 0, sizeof *t);
        snprintf(path, sizeof path, "%s/truth/height.exr", p->dir);
        if (access(path, F_OK) < 0)     /* the simulator's name for the same channel */
                snprintf(path, sizeof path, "%s/truth/heightfield.exr", p->dir);
        if (access(path, F_OK) < 0)
                return -ENOENT;
        char **names = NULL;
        int r = imp_exr_read(path, &t->img, &names, err);
        if (r < 0)
                return r;
        t->channel = imp_image_channel_index(names, "height");
        imp_strv_free(names);
        if (t->channel < 0 || t->img->width < 2 || t->img->height < 2) {
                imp_mosaic_truth_done(t);
                return imp_error_set(err, -EBADMSG, "%s: expected a channel \"height\" over at least 2×2 texels", path);
        }
        if ((r = truth_grid(p, t, err)) < 0) {
                imp_mosaic_truth_done(t);
                return r;
        }
        *ret = (struct imp_mosaic_truth) { truth_exr_height, t };
        return 0;
}

void imp_mosaic_truth_done(struct imp_mosaic_truth_exr *t) {
        imp_image_free(t->img);
        t->img = NULL;
}

/* The seam step the output shows (mosaic-internal.h). Each seam between two neighbouring
 * tiles (same row, next column: the jump is along x; same column, next row: along y) gets
 * two bands of SEAM_BAND_MM just outside the overlap, one on each side (where only one of
 * the two tiles contributes), cut along the seam into segments of SEAM_SEG_MM; the jump of a
 * segment is the mosaic's mean height error over its band on the second tile's side minus
 * that on the first's. Away from the other axis's overlaps (corners: four tiles) by the
 * overlap + a band. The same two bands, as far apart, placed about the first tile's centre
 * (one tile only, no seam) give the jump the copies' own error shows over that distance:
 * the reference. A segment counts when both its bands are at least half covered. */
#define SEAM_BAND_MM 1.0
#define SEAM_SEG_MM 2.0
#define SEAM_SEGS_MAX 4096

struct seam_probe {
        int axis;                     /* 0: the jump is along x (bands are columns), 1: along y */
        bool ref;                     /* about a tile's centre (no seam) */
        double lo[2], hi[2];          /* the two bands across the seam: [lo, lo + band) ... */
        double s0;                    /* along the seam: segments of SEAM_SEG_MM from s0 */
        int n_seg;
        double *sum;                  /* 2 per segment: the band before, the band after */
        size_t *cnt;
};

struct mosaic_seam_score {
        struct seam_probe *pr;
        size_t n, cap;
        double pitch_mm;
};

static int seam_probe_add(struct mosaic_seam_score *s, int axis, bool ref, double a0, double b0, double s0, double s1) {
        int n_seg = (int) floor((s1 - s0) / SEAM_SEG_MM);
        if (n_seg < 1)
                return 0;
        n_seg = IMP_MIN(n_seg, SEAM_SEGS_MAX);
        if (s->n == s->cap) {
                size_t cap = s->cap ? 2 * s->cap : 64;
                struct seam_probe *np = realloc(s->pr, cap * sizeof *np);
                if (!np)
                        return -ENOMEM;
                s->pr = np, s->cap = cap;
        }
        struct seam_probe *q = &s->pr[s->n];
        *q = (struct seam_probe) { .axis = axis, .ref = ref, .lo = { a0, b0 }, .hi = { a0 + SEAM_BAND_MM, b0 + SEAM_BAND_MM },
                                   .s0 = s0, .n_seg = n_seg, .sum = calloc(2 * (size_t) n_seg, sizeof(double)),
                                   .cnt = calloc(2 * (size_t) n_seg, sizeof(size_t)) };
        if (!q->sum || !q->cnt)
                return free(q->sum), free(q->cnt), -ENOMEM;
        s->n++;
        return 0;
}

/* The seam of neighbours a (before) and b (after) along axis, and its reference in a. */
static int seam_probes_pair(struct mosaic_seam_score *s, const struct imp_painting *p, const struct imp_mosaic_tile *a,
                            const struct imp_mosaic_tile *b, int axis) {
        int o = 1 - axis;
        double gap0 = b->bbox[axis], gap1 = a->bbox[axis + 2];      /* the overlap across the seam */
        if (!(gap1 > gap0))
                return 0;
        double margin = p->overlap * p->fov_mm[o] + SEAM_BAND_MM;
        double s0 = fmax(a->bbox[o], b->bbox[o]) + margin, s1 = fmin(a->bbox[o + 2], b->bbox[o + 2]) - margin;
        int r = seam_probe_add(s, axis, false, gap0 - SEAM_BAND_MM, gap1, s0, s1);
        double c = 0.5 * (a->bbox[axis] + a->bbox[axis + 2]), half = 0.5 * (gap1 - gap0);
        return r < 0 ? r : seam_probe_add(s, axis, true, c - half - SEAM_BAND_MM, c + half, s0, s1);
}

void mosaic_seam_score_free(struct mosaic_seam_score *s) {
        if (!s)
                return;
        for (size_t k = 0; k < s->n; k++)
                free(s->pr[k].sum), free(s->pr[k].cnt);
        free(s->pr), free(s);
}

int mosaic_seam_score_new(const struct imp_painting *p, double pitch_mm, struct mosaic_seam_score **ret) {
        struct mosaic_seam_score *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        s->pitch_mm = pitch_mm;
        int r = 0;
        for (size_t i = 0; i < p->n_tiles && r == 0; i++)
                for (size_t k = 0; k < p->n_tiles && r == 0; k++) {
                        const struct imp_mosaic_tile *a = &p->tiles[i], *b = &p->tiles[k];
                        int axis = a->row == b->row && b->col == a->col + 1 ? 0
                                   : a->col == b->col && b->row == a->row + 1 ? 1 : -1;
                        if (axis < 0)
                                continue;
                        /* before / after by position (a grid may number its columns either way) */
                        bool swap = b->bbox[axis] + b->bbox[axis + 2] < a->bbox[axis] + a->bbox[axis + 2];
                        r = seam_probes_pair(s, p, swap ? b : a, swap ? a : b, axis);
                }
        if (r < 0) {
                mosaic_seam_score_free(s);
                return r;
        }
        *ret = s;
        return 0;
}

void mosaic_seam_score_add(struct mosaic_seam_score *s, double x, double y, double err_mm) {
        const double xy[2] = { x, y };
        for (size_t k = 0; k < s->n; k++) {
                struct seam_probe *q = &s->pr[k];
                double u = xy[q->axis], v = xy[1 - q->axis];
                int side = u >= q->lo[0] && u < q->hi[0] ? 0 : u >= q->lo[1] && u < q->hi[1] ? 1 : -1;
                if (side < 0 || v < q->s0)
                        continue;
                long seg = (long) ((v - q->s0) / SEAM_SEG_MM);
                if (seg >= q->n_seg)
                        continue;
                q->sum[2 * seg + side] += err_mm, q->cnt[2 * seg + side]++;
        }
}

void mosaic_seam_score_finish(const struct mosaic_seam_score *s, struct imp_mosaic_figures *f) {
        double ss[2] = { 0 };
        size_t n[2] = { 0 };
        /* a band of a segment holds about band × segment / pitch² texels */
        double full = SEAM_BAND_MM * SEAM_SEG_MM / (s->pitch_mm * s->pitch_mm);
        for (size_t k = 0; k < s->n; k++) {
                const struct seam_probe *q = &s->pr[k];
                for (int g = 0; g < q->n_seg; g++) {
                        const size_t *c = &q->cnt[2 * g];
                        if (c[0] < 0.5 * full || c[1] < 0.5 * full)
                                continue;
                        double jump = q->sum[2 * g + 1] / c[1] - q->sum[2 * g] / c[0];
                        ss[q->ref] += jump * jump, n[q->ref]++;
                }
        }
        f->seam_out_jump_um = n[0] ? 1e3 * sqrt(ss[0] / n[0]) : NAN;
        f->seam_out_ref_um = n[1] ? 1e3 * sqrt(ss[1] / n[1]) : NAN;
        f->seam_out_n = n[0];
        double d = f->seam_out_jump_um * f->seam_out_jump_um - f->seam_out_ref_um * f->seam_out_ref_um;
        f->seam_out_step_um = isfinite(d) ? sqrt(fmax(d, 0)) : NAN;
}
