/* Pairwise registration of overlapping tiles (mosaic.h): a coarse search over whole-texel
 * shifts, then robust Gauss-Newton on the residuals of the heights (and the normals when
 * asked: reg_channels) (Lucas-Kanade with Huber weights, sub-texel by bilinear interpolation) for the shift,
 * rotation and height offset of the second tile relative to the first, with its
 * information matrix (the nuisances, a height tilt and the normals' offsets, marginalised). The weights are Huber's
 * for the first iteration (convex), then Tukey's
 * biweight with c = 3.1·k (4.65 robust σ at k = 1.5), which gives a ghost or a defect in
 * the overlap no weight at all: Huber alone still lets 40 % of outliers pull the shift. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "macro.h"
#include "mosaic-internal.h"
#include "numerics.h"

#define NP 4                    /* a tile's pose correction: t_x, t_y, θ, dz (mosaic.h) */

void imp_mosaic_options_default(struct imp_mosaic_options *o) {
        *o = (struct imp_mosaic_options) {
                .search_sigma = 4, .sample_step = 2, .huber_k = 1.5, .min_overlap_mm = 1, .out_tile_px = 512,
                .cache_bytes = (size_t) 1 << 30, .box_cell_px = 20, .box_delta_frac = 0.3, .box_noise_k = 6,
                .box_ref_percentile = 5, .reg_channels = IMP_MOSAIC_REG_HEIGHT, .reg_smooth_px = 0.5,
        };
}

bool mosaic_height(const struct imp_mosaic_tile *t, const struct imp_copy *c, double x, double y, double *ret_h,
                   double ij[2]) {
        if (!imp_mosaic_painting_to_tile(t, x, y, ij))
                return false;
        if (!(ij[0] >= 0 && ij[1] >= 0 && ij[0] <= t->nx - 1 && ij[1] <= t->ny - 1))
                return false;
        int i = IMP_MIN((int) ij[0], t->nx - 2), j = IMP_MIN((int) ij[1], t->ny - 2);
        double fx = ij[0] - i, fy = ij[1] - j;
        size_t k = (size_t) j * t->nx + i;
        if (!c->mask[k] || !c->mask[k + 1] || !c->mask[k + t->nx] || !c->mask[k + t->nx + 1])
                return false;
        double h = (1 - fy) * ((1 - fx) * c->height[k] + fx * c->height[k + 1]) +
                   fy * ((1 - fx) * c->height[k + t->nx] + fx * c->height[k + t->nx + 1]);
        *ret_h = mosaic_painting_z(t, ij[0], ij[1], h);
        return true;
}

double mosaic_painting_z(const struct imp_mosaic_tile *t, double fi, double fj, double h) {
        const double *M = t->c2w;
        double u = fi * t->pitch_mm, v = fj * t->pitch_mm;
        return M[8] * u + M[9] * v + M[10] * h + M[11] + t->pose[3];
}

bool mosaic_height_box(const struct imp_mosaic_tile *t, const struct imp_copy *c, double x, double y, int r,
                       double *ret_h) {
        double s = 0, ij[2], h;
        for (int dj = -r; dj <= r; dj++)
                for (int di = -r; di <= r; di++) {
                        if (!mosaic_height(t, c, x + di * t->pitch_mm, y + dj * t->pitch_mm, &h, ij))
                                return false;
                        s += h;
                }
        *ret_h = s / ((2 * r + 1) * (2 * r + 1));
        return true;
}

bool mosaic_overlap(const struct imp_mosaic_tile *a, const struct imp_mosaic_tile *b, double m, double ret[4]) {
        ret[0] = fmax(a->bbox[0], b->bbox[0]) + m, ret[1] = fmax(a->bbox[1], b->bbox[1]) + m;
        ret[2] = fmin(a->bbox[2], b->bbox[2]) - m, ret[3] = fmin(a->bbox[3], b->bbox[3]) - m;
        return ret[2] > ret[0] && ret[3] > ret[1];
}

int mosaic_pairs(const struct imp_painting *p, double min_mm, unsigned (**ret)[2], size_t *ret_n) {
        size_t n = 0, cap = 16;
        unsigned (*v)[2] = malloc(cap * sizeof *v);
        if (!v)
                return -ENOMEM;
        for (unsigned a = 0; a < p->n_tiles; a++)
                for (unsigned b = a + 1; b < p->n_tiles; b++) {
                        double ov[4];
                        if (!mosaic_overlap(&p->tiles[a], &p->tiles[b], 0, ov) || ov[2] - ov[0] < min_mm ||
                            ov[3] - ov[1] < min_mm)
                                continue;
                        if (n == cap) {
                                void *nv = realloc(v, (cap *= 2) * sizeof *v);
                                if (!nv) {
                                        free(v);
                                        return -ENOMEM;
                                }
                                v = nv;
                        }
                        v[n][0] = a, v[n][1] = b, n++;
                }
        *ret = v, *ret_n = n;
        return 0;
}

/* The channels a pair is registered on: height (painting z) and the normal's x and y
 * (painting frame), each residual in units of its own robust σ. Heights alone are weak on a
 * rendered painting: a tile's height error (~10 µm, correlated over many texels) is larger
 * than what a shift of tens of µm changes in a relief sampled at 0.2 mm, while the
 * photometric normals (~2° noise) see the fine relief (painting-small: registration 38 →
 * 34 µm, the same scene without stage errors 22 → 18 µm; synthetic tiles 0.56 → 0.17 µm).
 * The albedo is left out: it pulled the shift on both (synthetic 0.17 → 6 µm; alone, 55 µm
 * on painting-small). The normals are left out by default: a rendered copy's photometric
 * normal map is smaller than its heights and the stage by ~2·10⁻⁴ (y) about the field
 * centre, which every pair then reads as its tiles standing too close (300 × 200 mm:
 * vertical pairs 7.4 µm short with them, 3.9 µm on heights alone; registration 16.8 →
 * 11.1 µm; docs/mosaic.md). */
enum { CH_H, CH_NX, CH_NY, NCH };

static bool channel_on(unsigned reg_channels, int ch) {
        return reg_channels & (ch == CH_H ? IMP_MOSAIC_REG_HEIGHT : IMP_MOSAIC_REG_NORMALS);
}
/* The unknowns of a pair: the pose difference, then nuisances: a tilt of the height residual
 * (x, y) and an offset of each normal channel (two tiles' copies stand on the canvas planes
 * their own data fit, a few µm apart over an overlap, which tilts their normals a little). */
enum { Q_TX = NP, Q_TY, Q_OFF };
#define NQ (Q_OFF + NCH - 1)

static bool channels(const struct imp_mosaic_tile *t, const struct imp_copy *c, double x, double y, double ret[NCH]) {
        double ij[2];
        if (!mosaic_height(t, c, x, y, &ret[CH_H], ij))
                return false;
        int i = IMP_MIN((int) ij[0], t->nx - 2), j = IMP_MIN((int) ij[1], t->ny - 2);
        double fx = ij[0] - i, fy = ij[1] - j, nx = 0, ny = 0;
        size_t k[4] = { (size_t) j * t->nx + i, (size_t) j * t->nx + i + 1, (size_t) (j + 1) * t->nx + i,
                        (size_t) (j + 1) * t->nx + i + 1 };
        double b[4] = { (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy };
        for (int q = 0; q < 4; q++)
                nx += b[q] * c->normal_x[k[q]], ny += b[q] * c->normal_y[k[q]];
        double phi = t->pose[2] + atan2(t->c2w[4], t->c2w[0]), cp = cos(phi), sp = sin(phi);
        ret[CH_NX] = cp * nx - sp * ny, ret[CH_NY] = sp * nx + cp * ny;
        return true;
}

/* Samples of a pair: painting points in the overlap and tile a's channels there; r and w
 * scratch (NCH per sample). */
struct samples {
        unsigned channels;            /* IMP_MOSAIC_REG_*: the channels that count */
        size_t n;
        double *x, *y, *fa, *r, *w;
};

static void samples_done(struct samples *s) {
        free(s->x), free(s->y), free(s->fa), free(s->r), free(s->w);
}

static int collect(const struct imp_mosaic_tile *ta, const struct imp_copy *ca, const double ov[4], double step,
                   struct samples *s) {
        size_t nx = (size_t) ((ov[2] - ov[0]) / step) + 1, ny = (size_t) ((ov[3] - ov[1]) / step) + 1;
        size_t cap = nx * ny;
        s->x = malloc(cap * sizeof(double)), s->y = malloc(cap * sizeof(double));
        s->fa = malloc(cap * NCH * sizeof(double)), s->r = malloc(cap * NCH * sizeof(double));
        s->w = malloc(cap * NCH * sizeof(double));
        if (!s->x || !s->y || !s->fa || !s->r || !s->w)
                return -ENOMEM;
        for (size_t j = 0; j < ny; j++)
                for (size_t i = 0; i < nx; i++) {
                        double x = ov[0] + i * step, y = ov[1] + j * step;
                        if (!channels(ta, ca, x, y, s->fa + NCH * s->n))
                                continue;
                        s->x[s->n] = x, s->y[s->n] = y, s->n++;
                }
        return 0;
}

/* Robust σ of v[0..n) (stride apart): 1.4826 · median |v − median|, scratch in tmp. */
static double robust_sigma(const double *v, size_t n, size_t stride, double *tmp, double *ret_median) {
        for (size_t i = 0; i < n; i++)
                tmp[i] = v[i * stride];
        qsort(tmp, n, sizeof *tmp, imp_cmp_double);
        double med = imp_median_sorted(tmp, n);
        for (size_t i = 0; i < n; i++)
                tmp[i] = fabs(v[i * stride] - med);
        qsort(tmp, n, sizeof *tmp, imp_cmp_double);
        if (ret_median)
                *ret_median = med;
        return 1.4826 * imp_median_sorted(tmp, n);
}

/* The point of b's current placement that b's corrected placement puts at (x, y). */
static void moved(const double q[NQ], const double c[2], double x, double y, double ret[2]) {
        double ex = x - c[0], ey = y - c[1];
        ret[0] = x - q[0] + q[2] * ey;
        ret[1] = y - q[1] - q[2] * ex;
}

/* Below these a channel's residual σ is noise of the float copy (height mm, normal). */
static const double ch_floor[NCH] = { 1e-5, 1e-4, 1e-4 };

/* Coarse search: the whole-texel shift (every `stride`-th sample) with the least product
 * over the channels of the median absolute residual about the median (least median of
 * squares, scale-free across channels: up to half the overlap may be a defect or a ghost
 * without pulling it). */
static void coarse(const struct imp_mosaic_tile *tb, const struct imp_copy *cb, const struct samples *s, double c[2],
                   int R, double q[NQ]) {
        double best = INFINITY;
        size_t stride = IMP_MAX(s->n / 4000, (size_t) 1), m = s->n / stride + 1;
        _cleanup_free_ double *r = malloc(m * NCH * sizeof *r), *tmp = malloc(m * sizeof *tmp);
        if (!r || !tmp)
                return;
        for (int sy = -R; sy <= R; sy++)
                for (int sx = -R; sx <= R; sx++) {
                        double t[NQ] = { sx * tb->pitch_mm, sy * tb->pitch_mm }, xy[2], f[NCH];
                        size_t n = 0, miss = 0;
                        for (size_t i = 0; i < s->n; i += stride) {
                                moved(t, c, s->x[i], s->y[i], xy);
                                if (!channels(tb, cb, xy[0], xy[1], f)) {
                                        miss++;
                                        continue;
                                }
                                for (int ch = 0; ch < NCH; ch++)
                                        r[n * NCH + ch] = f[ch] - s->fa[i * NCH + ch];
                                n++;
                        }
                        if (n < 20 || miss > n)
                                continue;
                        double cost = 0, med[NCH];
                        for (int ch = 0; ch < NCH; ch++)
                                if (channel_on(s->channels, ch))
                                        cost += log(fmax(robust_sigma(r + ch, n, NCH, tmp, &med[ch]), ch_floor[ch]));
                                else
                                        med[ch] = 0;
                        if (cost < best) {
                                best = cost, memcpy(q, t, sizeof t);
                                q[3] = -med[CH_H];
                                for (int ch = 1; ch < NCH; ch++)
                                        q[Q_OFF + ch - 1] = -med[ch];
                        }
                }
}

static double weight(double a, double k, bool redescend) {
        if (!redescend)
                return a <= k ? 1 : k / a;
        double c = 3.1 * k, u = a / c;
        return u < 1 ? (1 - u * u) * (1 - u * u) : 0;
}

/* Residual of channel ch at sample i from b's channels f there. */
static double resid(const struct samples *s, size_t i, int ch, const double f[NCH], const double q[NQ], const double c[2]) {
        double off = ch == CH_H ? q[3] + q[Q_TX] * (s->x[i] - c[0]) + q[Q_TY] * (s->y[i] - c[1]) : q[Q_OFF + ch - 1];
        return f[ch] + off - s->fa[i * NCH + ch];
}

/* Residuals at q (NAN where b has none) and, with JtJ/Jtr non-NULL, the robustly weighted
 * normal equations, each channel's residual in units of its robust σ scale[ch]. Returns the
 * number of samples. */
static size_t residuals(const struct imp_mosaic_tile *tb, const struct imp_copy *cb, struct samples *s, const double c[2],
                        const double q[NQ], const double scale[NCH], double k, bool redescend, double JtJ[NQ * NQ],
                        double Jtr[NQ], double *ret_inl) {
        size_t n = 0, inl = 0;
        double e = 0.5 * tb->pitch_mm;
        if (JtJ)
                memset(JtJ, 0, NQ * NQ * sizeof *JtJ), memset(Jtr, 0, NQ * sizeof *Jtr);
        for (size_t i = 0; i < s->n; i++) {
                double xy[2], f[NCH], fx0[NCH], fx1[NCH], fy0[NCH], fy1[NCH];
                moved(q, c, s->x[i], s->y[i], xy);
                for (int ch = 0; ch < NCH; ch++)
                        s->r[i * NCH + ch] = NAN;
                if (!channels(tb, cb, xy[0], xy[1], f))
                        continue;
                for (int ch = 0; ch < NCH; ch++)
                        s->r[i * NCH + ch] = resid(s, i, ch, f, q, c);
                n++;
                if (!JtJ)
                        continue;
                if (!channels(tb, cb, xy[0] - e, xy[1], fx0) || !channels(tb, cb, xy[0] + e, xy[1], fx1) ||
                    !channels(tb, cb, xy[0], xy[1] - e, fy0) || !channels(tb, cb, xy[0], xy[1] + e, fy1))
                        continue;
                double ex = s->x[i] - c[0], ey = s->y[i] - c[1];
                for (int ch = 0; ch < NCH; ch++) {
                        if (!channel_on(s->channels, ch))
                                continue;
                        double gx = (fx1[ch] - fx0[ch]) / (2 * e), gy = (fy1[ch] - fy0[ch]) / (2 * e);
                        double row[NQ] = { -gx, -gy, gx * ey - gy * ex };
                        if (ch == CH_H)
                                row[3] = 1, row[Q_TX] = ex, row[Q_TY] = ey;
                        else
                                row[Q_OFF + ch - 1] = 1;
                        double r = s->r[i * NCH + ch] / scale[ch], a = fabs(r), w = weight(a, k, redescend);
                        if (ch == CH_H)
                                inl += a <= k;
                        for (int p = 0; p < NQ; p++) {
                                double wr = w * row[p] / scale[ch];
                                Jtr[p] += wr * r;
                                for (int q2 = 0; q2 < NQ; q2++)
                                        JtJ[p * NQ + q2] += wr * row[q2] / scale[ch];
                        }
                }
        }
        if (ret_inl)
                *ret_inl = n ? (double) inl / n : 0;
        return n;
}

/* Each channel's robust σ of the finite residuals (floored), and the height's RMS. */
static void channel_sigma(struct samples *s, double scale[NCH], double *ret_rms) {
        _cleanup_free_ double *tmp = malloc((s->n + 1) * sizeof *tmp);
        for (int ch = 0; ch < NCH; ch++) {
                size_t n = 0;
                double ss = 0;
                for (size_t i = 0; i < s->n; i++)
                        if (isfinite(s->r[i * NCH + ch]))
                                s->w[n++] = s->r[i * NCH + ch], ss += s->r[i * NCH + ch] * s->r[i * NCH + ch];
                if (ch == CH_H)
                        *ret_rms = n ? sqrt(ss / n) : NAN;
                scale[ch] = n > 8 && tmp ? fmax(robust_sigma(s->w, n, 1, tmp, NULL), ch_floor[ch]) : 1;
        }
}

/* The pair's measurement and information: the pose part of the solution and the Schur
 * complement of the channel offsets (they are nuisances), scaled by the weighted residual
 * variance. */
static void measurement(const double q[NQ], const double JtJ[NQ * NQ], double s2, struct imp_mosaic_pair *pr) {
        enum { NO = NQ - NP };
        double C[NO * NO], info[NP * NP];
        for (int a = 0; a < NO; a++)
                for (int b = 0; b < NO; b++)
                        C[a * NO + b] = JtJ[(NP + a) * NQ + NP + b] + (a == b ? 1e-12 : 0);
        bool ok = imp_cholesky_factor(NO, C);
        for (int a = 0; a < NP; a++)
                for (int b = 0; b < NP; b++)
                        info[a * NP + b] = JtJ[a * NQ + b];
        for (int b = 0; ok && b < NP; b++) {
                double v[NO];
                for (int o = 0; o < NO; o++)
                        v[o] = JtJ[(NP + o) * NQ + b];
                imp_cholesky_solve(NO, C, v);
                for (int a = 0; a < NP; a++)
                        for (int o = 0; o < NO; o++)
                                info[a * NP + b] -= JtJ[a * NQ + NP + o] * v[o];
        }
        memcpy(pr->meas, q, NP * sizeof *q);
        for (int i = 0; i < NP * NP; i++)
                pr->info[i] = info[i] / s2;
        double L[NP * NP];
        memcpy(L, pr->info, sizeof L);
        if (imp_cholesky_factor(NP, L))
                for (int d = 0; d < 2; d++) {
                        double e[NP] = { 0 };
                        e[d] = 1;
                        imp_cholesky_solve(NP, L, e);
                        pr->sd_um[d] = 1e3 * sqrt(fmax(e[d], 0));
                }
}

/* Gauss-Newton from q; fills the pair's measurement and information. */
static int refine(const struct imp_mosaic_tile *tb, const struct imp_copy *cb, struct samples *s,
                  const struct imp_mosaic_options *o, double q[NQ], struct imp_mosaic_pair *pr) {
        double JtJ[NQ * NQ], Jtr[NQ], rms, scale[NCH];
        for (int it = 0; it < 30; it++) {
                residuals(tb, cb, s, pr->c_mm, q, scale, 1e300, false, NULL, NULL, NULL);
                channel_sigma(s, scale, &rms);
                if (it == 0)
                        pr->rms_before_um = 1e3 * rms;
                size_t n = residuals(tb, cb, s, pr->c_mm, q, scale, o->huber_k, it >= 1, JtJ, Jtr, &pr->inlier_frac);
                if (n < 50)
                        return snprintf(pr->why, sizeof pr->why, "%zu samples left in the overlap", n), -ENODATA;
                double L[NQ * NQ];
                memcpy(L, JtJ, sizeof L);
                for (int d = 0; d < NQ; d++)
                        L[d * (NQ + 1)] = L[d * (NQ + 1)] * (1 + 1e-9) + 1e-12;
                if (!imp_cholesky_factor(NQ, L))
                        return snprintf(pr->why, sizeof pr->why, "no texture to register on"), -ENODATA;
                imp_cholesky_solve(NQ, L, Jtr);
                for (int d = 0; d < NQ; d++)
                        q[d] -= Jtr[d];
                if (it >= 6 && hypot(Jtr[0], Jtr[1]) < 1e-6 && fabs(Jtr[2]) < 1e-8)
                        break;
        }
        size_t n = residuals(tb, cb, s, pr->c_mm, q, scale, o->huber_k, true, JtJ, Jtr, &pr->inlier_frac);
        double s2 = 0, sw = 0;
        for (size_t i = 0; i < s->n; i++)
                for (int ch = 0; ch < NCH; ch++)
                        if (channel_on(s->channels, ch) && isfinite(s->r[i * NCH + ch])) {
                                double a = fabs(s->r[i * NCH + ch]) / scale[ch], w = weight(a, o->huber_k, true);
                                s2 += w * a * a, sw += w;
                        }
        s2 /= fmax(sw - NQ, 1);
        channel_sigma(s, scale, &rms);
        pr->rms_after_um = 1e3 * rms;
        pr->n_samples = n;
        measurement(q, JtJ, s2, pr);
        pr->ok = true;
        return 0;
}

/* Search range: the relative pose's σ (two stage errors, each a shift and a rotation about
 * the tile's centre seen at the overlap) times search_sigma. */
static int search_px(const struct imp_painting *p, const struct imp_mosaic_tile *t, const struct imp_mosaic_options *o) {
        double arm = 0.5 * hypot(t->nx, t->ny) * t->pitch_mm, th = p->sigma_deg * M_PI / 180;
        double sd = sqrt(2 * p->sigma_mm * p->sigma_mm + 2 * th * th * arm * arm);
        return (int) ceil(o->search_sigma * sd / t->pitch_mm);
}

static int register_pair(struct imp_painting *p, const struct imp_mosaic_options *o, const struct imp_copy *ca,
                         const struct imp_copy *cb, struct imp_mosaic_pair *pr) {
        const struct imp_mosaic_tile *ta = &p->tiles[pr->a], *tb = &p->tiles[pr->b];
        int R = search_px(p, tb, o);
        double ov[4];
        if (!mosaic_overlap(ta, tb, (R + 2) * tb->pitch_mm, ov))
                return snprintf(pr->why, sizeof pr->why, "overlap narrower than the search range"), 0;
        pr->c_mm[0] = 0.5 * (ov[0] + ov[2]), pr->c_mm[1] = 0.5 * (ov[1] + ov[3]);
        struct samples s = { .channels = o->reg_channels ? o->reg_channels : IMP_MOSAIC_REG_HEIGHT };
        int r = collect(ta, ca, ov, o->sample_step * ta->pitch_mm, &s);
        if (r == 0 && s.n < 100)
                snprintf(pr->why, sizeof pr->why, "%zu samples on both masks", s.n);
        else if (r == 0) {
                double q[NQ] = { 0 };
                coarse(tb, cb, &s, pr->c_mm, R, q);
                if (refine(tb, cb, &s, o, q, pr) < 0)
                        pr->ok = false;
                else if (hypot(q[0], q[1]) > (R + 1) * tb->pitch_mm) {
                        /* beyond the search range: the Gauss-Newton wandered off (a corner overlap
                           with little relief, 0.7 mm on a simulated painting); a pair that far
                           off would drag the whole graph */
                        snprintf(pr->why, sizeof pr->why, "diverged: shift %.0f, %.0f µm beyond the search range (%.0f µm)",
                                 1e3 * q[0], 1e3 * q[1], 1e3 * (R + 1) * tb->pitch_mm);
                        pr->ok = false;
                }
        }
        samples_done(&s);
        return r;
}

/* What a pair is registered on (reg_smooth_px > 0): a copy's heights low-passed by a
 * Gaussian of σ = reg_smooth_px texels, normalised over the mask (each texel the weighted
 * mean of its measured neighbours), on the texels whose whole kernel is on the mask. It damps
 * the detail at the camera's pixel, whose heights depend on where the camera's rays landed in
 * each tile (the pixel phase, the obliquity at the field's edge), which every pair read as
 * the same few-µm shift: a scale the loops cannot see. σ = 0.5 (the default) on the rendered
 * 300 × 200 mm paintings: far corner / mean 2.11 → 1.24 and 2.28 → 1.55; σ ≥ 0.75 reads
 * the coarser relief's opposite bias, the tiles too far apart (σ 2: registration 9.6 →
 * 19.5 µm; docs/mosaic.md, "Registering on low-passed heights"). */
struct reg_view {
        float *height;
        uint8_t *mask;
};

static void reg_view_done(struct reg_view *v) {
        free(v->height), free(v->mask);
        *v = (struct reg_view) { 0 };
}

/* One pass of the separable kernel g[|d|], d = −R…R, along x or y: num and den in, their
 * blur out (outside the grid counts as 0). */
static void blur_pass(const float *num, const float *den, float *ret_num, float *ret_den, int nx, int ny,
                      bool along_x, const double *g, int R) {
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        double sn = 0, sd = 0;
                        for (int d = -R; d <= R; d++) {
                                int ii = along_x ? i + d : i, jj = along_x ? j : j + d;
                                if (ii < 0 || jj < 0 || ii >= nx || jj >= ny)
                                        continue;
                                size_t k = (size_t) jj * nx + ii;
                                sn += g[abs(d)] * num[k], sd += g[abs(d)] * den[k];
                        }
                        size_t k = (size_t) j * nx + i;
                        ret_num[k] = (float) sn, ret_den[k] = (float) sd;
                }
}

/* Texels whose whole (2R+1)² square, weighted by g, lies on `on` (a 0/1 map): ret[k] = 1. */
static void whole_kernel(const float *on, float *ret, float *t1, float *t2, int nx, int ny, const double *g, int R) {
        size_t n = (size_t) nx * ny;
        double full = 0;
        for (int d = -R; d <= R; d++)
                full += g[abs(d)];
        blur_pass(on, on, t1, t2, nx, ny, true, g, R);
        blur_pass(t1, t1, ret, t2, nx, ny, false, g, R);
        for (size_t k = 0; k < n; k++)
                ret[k] = on[k] > 0 && ret[k] >= full * full * (1 - 1e-5) ? 1 : 0;
}

static int reg_view_make(const struct imp_copy *c, const struct imp_mosaic_options *o, struct reg_view *v) {
        size_t n = (size_t) c->nx * c->ny;
        v->height = malloc(n * sizeof *v->height), v->mask = malloc(n);
        _cleanup_free_ float *num = malloc(n * sizeof *num), *den = malloc(n * sizeof *den), *tn = malloc(n * sizeof *tn),
                             *td = malloc(n * sizeof *td), *on = malloc(n * sizeof *on);
        if (!v->height || !v->mask || !num || !den || !tn || !td || !on)
                return reg_view_done(v), -ENOMEM;
        double s = o->reg_smooth_px, g[64];
        int R = IMP_MIN((int) ceil(3 * s), 63);
        for (int d = 0; d <= R; d++)
                g[d] = exp(-0.5 * d * d / (s * s));
        for (size_t k = 0; k < n; k++)
                on[k] = c->mask[k] ? 1 : 0, num[k] = c->mask[k] ? c->height[k] : 0;
        blur_pass(num, on, tn, td, c->nx, c->ny, true, g, R);
        blur_pass(tn, td, num, den, c->nx, c->ny, false, g, R);
        /* a texel whose kernel reaches off the mask would be a one-sided mean: a sloping
           relief's height moved inwards; left out */
        whole_kernel(on, td, tn, v->height, c->nx, c->ny, g, R);
        for (size_t k = 0; k < n; k++) {
                v->mask[k] = td[k] > 0 ? c->mask[k] : 0;
                v->height[k] = v->mask[k] ? num[k] / den[k] : c->height[k];
        }
        return 0;
}

static bool reg_view_wanted(const struct imp_mosaic_options *o) {
        return o->reg_smooth_px > 0;
}

/* c with the view's heights and mask (borrowed) when the options ask for a view. */
static struct imp_copy reg_copy(const struct imp_copy *c, const struct reg_view *v) {
        struct imp_copy r = *c;
        if (v->height)
                r.height = v->height, r.mask = v->mask;
        return r;
}

/* The overlapping pairs under the current poses and a cache stepping through them in order. */
static int pair_pass(struct imp_painting *p, const struct imp_mosaic_options *o, unsigned (**ret_pairs)[2], size_t *ret_n,
                     size_t **ret_off, struct mosaic_cache *c, struct imp_error *err) {
        imp_painting_update_bboxes(p);
        if (mosaic_pairs(p, o->min_overlap_mm, ret_pairs, ret_n) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        size_t *off = malloc((*ret_n + 1) * sizeof *off);
        if (!off)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t i = 0; i <= *ret_n; i++)
                off[i] = 2 * i;
        *ret_off = off;
        if (mosaic_cache_init(c, p, o->cache_bytes, off, &(*ret_pairs)[0][0], *ret_n) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return 0;
}

int imp_mosaic_register(struct imp_painting *p, const struct imp_mosaic_options *o, struct imp_mosaic_pair **ret,
                        size_t *ret_n, struct imp_error *err) {
        _cleanup_free_ unsigned (*pairs)[2] = NULL;
        _cleanup_free_ size_t *off = NULL;
        size_t n = 0;
        struct mosaic_cache c = { 0 };
        int r = pair_pass(p, o, &pairs, &n, &off, &c, err);
        _cleanup_free_ struct imp_mosaic_pair *pr = calloc(n ? n : 1, sizeof *pr);
        if (r < 0 || !pr) {
                mosaic_cache_done(&c);
                return r < 0 ? r : imp_error_set(err, -ENOMEM, "out of memory");
        }
        /* each tile's view, made at its first pair and dropped after its last */
        _cleanup_free_ struct reg_view *v = calloc(p->n_tiles ? p->n_tiles : 1, sizeof *v);
        _cleanup_free_ size_t *last = calloc(p->n_tiles ? p->n_tiles : 1, sizeof *last);
        if (!v || !last)
                r = imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t i = 0; i < n && r == 0; i++)
                last[pairs[i][0]] = last[pairs[i][1]] = i;
        for (size_t i = 0; i < n && r == 0; i++) {
                unsigned a = pr[i].a = pairs[i][0], b = pr[i].b = pairs[i][1];
                if ((r = mosaic_cache_step(&c, i, err)) < 0)
                        break;
                for (int e = 0; e < 2 && reg_view_wanted(o) && r == 0; e++) {
                        unsigned k = e ? b : a;
                        if (!v[k].height && reg_view_make(&c.copies[k], o, &v[k]) < 0)
                                r = imp_error_set(err, -ENOMEM, "out of memory");
                }
                struct imp_copy ca = reg_copy(&c.copies[a], &v[a]), cb = reg_copy(&c.copies[b], &v[b]);
                if (r == 0 && (r = register_pair(p, o, &ca, &cb, &pr[i])) < 0)
                        imp_error_set(err, r, "registering tiles %u and %u: %s", p->tiles[a].index, p->tiles[b].index,
                                      strerror(-r));
                for (int e = 0; e < 2; e++)
                        if (last[pairs[i][e]] == i)
                                reg_view_done(&v[pairs[i][e]]);
        }
        for (unsigned k = 0; v && k < p->n_tiles; k++)
                reg_view_done(&v[k]);
        mosaic_cache_done(&c);
        if (r < 0)
                return r;
        *ret = TAKE_PTR(pr), *ret_n = n;
        return 0;
}

int imp_mosaic_seam_step(struct imp_painting *p, const struct imp_mosaic_options *o, double *ret_rms_um,
                         size_t *ret_n, struct imp_error *err) {
        _cleanup_free_ unsigned (*pairs)[2] = NULL;
        _cleanup_free_ size_t *off = NULL;
        size_t n = 0, cnt = 0;
        struct mosaic_cache c = { 0 };
        int r = pair_pass(p, o, &pairs, &n, &off, &c, err);
        double ss = 0;
        for (size_t i = 0; i < n && r == 0; i++) {
                if ((r = mosaic_cache_step(&c, i, err)) < 0)
                        break;
                const struct imp_mosaic_tile *ta = &p->tiles[pairs[i][0]], *tb = &p->tiles[pairs[i][1]];
                double ov[4], step = 4 * ta->pitch_mm, ha, hb;
                if (!mosaic_overlap(ta, tb, 3 * ta->pitch_mm, ov))
                        continue;
                for (double y = ov[1]; y <= ov[3]; y += step)
                        for (double x = ov[0]; x <= ov[2]; x += step)
                                if (mosaic_height_box(ta, &c.copies[pairs[i][0]], x, y, 2, &ha) &&
                                    mosaic_height_box(tb, &c.copies[pairs[i][1]], x, y, 2, &hb))
                                        ss += (hb - ha) * (hb - ha), cnt++;
        }
        mosaic_cache_done(&c);
        if (r < 0)
                return r;
        *ret_rms_um = cnt ? 1e3 * sqrt(ss / cnt) : NAN;
        *ret_n = cnt;
        return 0;
}
