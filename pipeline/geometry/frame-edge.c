/* Flush-frame bands found by the albedo step at a straight canvas edge (frame-edge.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "frame-edge.h"
#include "macro.h"
#include "numerics.h"

#define HF_EDGE_SEGMENTS    4         /* segments along a side */
#define HF_EDGE_MIN_AGREE   3         /* segments that must find the same boundary */
#define HF_EDGE_AGREE_BINS  3         /* their boundaries within this many bins */
#define HF_EDGE_DEPTH_FRAC  0.4       /* bins reach this fraction of the fill's extent inward */
#define HF_EDGE_STEP_REL    0.08      /* albedo step, relative to the outer level */
#define HF_EDGE_STEP_SIGMA  4.0       /* ... and in units of the outer band's pixel spread */
#define HF_EDGE_MIN_PTS     5         /* pixels for a bin's median */
#define HF_EDGE_CONFIRM     4         /* bins past the boundary whose mean must differ too */

/* Per side: pixel values grouped by (segment, bin) with counting sort. */
struct side_bins {
        int nb;                       /* bins per segment */
        size_t *off;                  /* (SEG·nb + 1) offsets into val */
        float *val;
};

static void side_bins_done(struct side_bins *b) {
        free(b->off);
        free(b->val);
}

/* Inward distance t from side k's edge and position a along it, for pixel i. */
static void side_coords(int k, double u, double v, const double box[4], double *ret_t, double *ret_a) {
        switch (k) {
        case 0: *ret_t = u - box[0], *ret_a = v; break;
        case 1: *ret_t = box[1] - u, *ret_a = v; break;
        case 2: *ret_t = v - box[2], *ret_a = u; break;
        default: *ret_t = box[3] - v, *ret_a = u; break;
        }
}

/* Segment and bin of a pixel on side k, or false when outside the central half of the
 * side or deeper than the bins reach. */
static bool side_slot(int k, const double *uv, const double box[4], double bin, int nb, size_t *ret) {
        double t, a;
        side_coords(k, uv[0], uv[1], box, &t, &a);
        double a0 = k < 2 ? box[2] : box[0], a1 = k < 2 ? box[3] : box[1], len = a1 - a0;
        double c0 = a0 + 0.25 * len, c1 = a1 - 0.25 * len;
        if (!(a >= c0 && a < c1 && t >= 0))
                return false;
        int b = (int) (t / bin);
        if (b >= nb)
                return false;
        int s = IMP_MIN((int) ((a - c0) / (c1 - c0) * HF_EDGE_SEGMENTS), HF_EDGE_SEGMENTS - 1);
        *ret = (size_t) s * nb + b;
        return true;
}

static int side_fill(int k, const double *uv, const float *val, size_t n, const double box[4], double bin,
                     struct side_bins *b) {
        size_t ns = (size_t) HF_EDGE_SEGMENTS * b->nb;
        b->off = calloc(ns + 1, sizeof(size_t));
        b->val = malloc((n ? n : 1) * sizeof(float));
        _cleanup_free_ size_t *fillp = malloc((ns + 1) * sizeof(size_t));
        if (!b->off || !b->val || !fillp)
                return -ENOMEM;
        size_t slot;
        for (size_t i = 0; i < n; i++)
                if (side_slot(k, uv + 2 * i, box, bin, b->nb, &slot))
                        b->off[slot + 1]++;
        for (size_t s = 0; s < ns; s++)
                b->off[s + 1] += b->off[s];
        memcpy(fillp, b->off, (ns + 1) * sizeof(size_t));
        for (size_t i = 0; i < n; i++)
                if (side_slot(k, uv + 2 * i, box, bin, b->nb, &slot))
                        b->val[fillp[slot]++] = val[i];
        return 0;
}

/* Median of a slot (NAN with too few pixels); the values are reordered. */
static double slot_median(struct side_bins *b, size_t s) {
        size_t cnt = b->off[s + 1] - b->off[s];
        if (cnt < HF_EDGE_MIN_PTS)
                return NAN;
        return imp_select_kth_float(b->val + b->off[s], cnt, cnt / 2);
}

/* Outer level A and pixel spread σ (1.4826·MAD) of the first two populated bins of
 * segment s. False when they hold too few pixels. */
static bool outer_level(struct side_bins *b, int s, double *ret_a, double *ret_sigma) {
        size_t s0 = (size_t) s * b->nb, cnt = 0;
        int used = 0;
        for (int k = 0; k < b->nb && used < 2; k++)
                if (b->off[s0 + k + 1] - b->off[s0 + k] >= HF_EDGE_MIN_PTS) {
                        cnt += b->off[s0 + k + 1] - b->off[s0 + k];
                        used++;
                }
        if (used < 2)
                return false;
        _cleanup_free_ float *tmp = malloc(cnt * sizeof(float));
        if (!tmp)
                return false;
        size_t q = 0;
        used = 0;
        for (int k = 0; k < b->nb && used < 2; k++) {
                size_t c = b->off[s0 + k + 1] - b->off[s0 + k];
                if (c >= HF_EDGE_MIN_PTS) {
                        memcpy(tmp + q, b->val + b->off[s0 + k], c * sizeof(float));
                        q += c;
                        used++;
                }
        }
        double a = imp_select_kth_float(tmp, cnt, cnt / 2);
        for (size_t i = 0; i < cnt; i++)
                tmp[i] = fabsf(tmp[i] - (float) a);
        *ret_a = a;
        *ret_sigma = 1.4826 * imp_select_kth_float(tmp, cnt, cnt / 2);
        return true;
}

/* Boundary bin of segment s (-1: none). */
static int segment_boundary(struct side_bins *b, int s) {
        double A, sigma;
        if (!outer_level(b, s, &A, &sigma))
                return -1;
        double tau = fmax(HF_EDGE_STEP_REL * fabs(A), HF_EDGE_STEP_SIGMA * sigma);
        int nb = b->nb;
        _cleanup_free_ double *p = malloc(nb * sizeof(double));
        _cleanup_free_ int *idx = malloc(nb * sizeof(int));
        if (!p || !idx)
                return -1;
        for (int k = 0; k < nb; k++)
                p[k] = slot_median(b, (size_t) s * nb + k);
        /* Over the populated bins (a bin emptied by the shadow of a small step is
         * skipped): the first off the outer level by τ/2 (the band drifts no farther
         * before it: shading towards a deep frame's wall is no frame); it or, when it is
         * the mixed bin across the edge, the next must start a step of τ that lasts. */
        int nf = 0;
        for (int k = 0; k < nb; k++)
                if (isfinite(p[k]))
                        idx[nf++] = k;
        int k0 = 1;
        while (k0 < nf && !(fabs(p[idx[k0]] - A) > 0.5 * tau))
                k0++;
        for (int k = k0; k <= k0 + 1 && k + HF_EDGE_CONFIRM <= nf; k++) {
                if (!(fabs(p[idx[k]] - A) > tau && fabs(p[idx[k + 1]] - A) > tau))
                        continue;
                double sum = 0;
                for (int q = k; q < k + HF_EDGE_CONFIRM; q++)
                        sum += p[idx[q]];
                return fabs(sum / HF_EDGE_CONFIRM - A) > tau ? idx[k] : -1;
        }
        return -1;
}

/* Boundary of a side in bins (-1: none), from its segments. */
static int side_boundary(struct side_bins *b) {
        int nf = 0, lo = INT32_MAX, hi = -1;
        for (int s = 0; s < HF_EDGE_SEGMENTS; s++) {
                int k = segment_boundary(b, s);
                if (k >= 0) {
                        nf++;
                        lo = IMP_MIN(lo, k), hi = IMP_MAX(hi, k);
                }
        }
        return nf >= HF_EDGE_MIN_AGREE && hi - lo <= HF_EDGE_AGREE_BINS ? hi : -1;
}

/* The canvas pixels' plane coordinates (u, v), albedo, and bounding box. */
static size_t collect(const struct imp_range_image *r, const float *albedo, const double m[3], const double ex[3],
                      const double ey[3], const uint8_t *canvas, double *uv, float *val, double box[4]) {
        size_t N = (size_t) r->width * r->height, n = 0;
        box[0] = box[2] = INFINITY, box[1] = box[3] = -INFINITY;
        for (size_t i = 0; i < N; i++) {
                if (!canvas[i] || !isfinite(albedo[i]))
                        continue;
                const float *X = r->xyz + 3 * i;
                double d[3] = { X[0] - m[0], X[1] - m[1], X[2] - m[2] };
                double u = imp_dot3(d, ex), v = imp_dot3(d, ey);
                uv[2 * n] = u, uv[2 * n + 1] = v, val[n++] = albedo[i];
                box[0] = fmin(box[0], u), box[1] = fmax(box[1], u);
                box[2] = fmin(box[2], v), box[3] = fmax(box[3], v);
        }
        return n;
}

void imp_canvas_axes(const double n[3], double ret_ex[3], double ret_ey[3]) {
        double ex[3] = { 1, 0, 0 };
        if (fabs(n[0]) > 0.9)
                ex[0] = 0, ex[1] = 1;
        double pr = imp_dot3(ex, n);
        for (int q = 0; q < 3; q++)
                ex[q] -= pr * n[q];
        imp_normalize3(ex);
        memcpy(ret_ex, ex, sizeof ex);
        imp_cross3(n, ex, ret_ey);
}

int imp_frame_edge_trim(const struct imp_range_image *r, const float *albedo, const double m[3], const double n[3],
                        double bin_mm, uint8_t *canvas, struct imp_frame_edge *ret) {
        if (!r || !albedo || !m || !n || !canvas || !ret || !(bin_mm > 0))
                return -EINVAL;
        *ret = (struct imp_frame_edge) {};
        size_t N = (size_t) r->width * r->height;
        double ex[3], ey[3];
        imp_canvas_axes(n, ex, ey);
        _cleanup_free_ double *uv = malloc((N ? N : 1) * 2 * sizeof(double));
        _cleanup_free_ float *val = malloc((N ? N : 1) * sizeof(float));
        if (!uv || !val)
                return -ENOMEM;
        double box[4];
        size_t cnt = collect(r, albedo, m, ex, ey, canvas, uv, val, box);
        if (cnt < 3)
                return 0;
        double cut[4];
        for (int k = 0; k < 4; k++) {
                double extent = k < 2 ? box[1] - box[0] : box[3] - box[2];
                struct side_bins b = { .nb = (int) fmin(HF_EDGE_DEPTH_FRAC * extent / bin_mm, 4096) };
                cut[k] = -INFINITY;
                if (b.nb < HF_EDGE_CONFIRM + 2)
                        continue;
                int rr = side_fill(k, uv, val, cnt, box, bin_mm, &b);
                int kb = rr < 0 ? -1 : side_boundary(&b);
                side_bins_done(&b);
                if (rr < 0)
                        return rr;
                if (kb >= 0) {
                        ret->trim_mm[k] = (kb + 0.5) * bin_mm;
                        ret->sides_trimmed |= 1u << k;
                        cut[k] = ret->trim_mm[k];
                }
        }
        if (!ret->sides_trimmed)
                return 0;
        for (size_t i = 0; i < N; i++) {
                if (!canvas[i])
                        continue;
                const float *X = r->xyz + 3 * i;
                double d[3] = { X[0] - m[0], X[1] - m[1], X[2] - m[2] };
                double u = imp_dot3(d, ex), v = imp_dot3(d, ey);
                bool out = false;
                for (int k = 0; k < 4 && !out; k++) {
                        double t, a;
                        side_coords(k, u, v, box, &t, &a);
                        out = t < cut[k];
                }
                if (out) {
                        canvas[i] = 0;
                        ret->n_trimmed++;
                }
        }
        return 0;
}
