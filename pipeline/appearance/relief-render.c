/* Hybrid bump / relief-mapping renderer of a digital copy (seed §5), on the CPU: one ray
 * per pixel in the canvas frame; boxes found by a 2D DDA over a cell grid; relief mapping
 * inside a box by a linear then a binary search; per-box α blending (eq. 2). */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "macro.h"
#include "relief-render.h"

#define RIGID_TOL 1e-6
#define DZ_MIN 1e-9                   /* |ray z| below this: parallel to the plane, a miss */
#define LINEAR_STEPS_MAX 4096
#define SHADOW_STEPS_MAX 8192
#define BOX_PER_CELL 4                /* non-overlapping boxes no thinner than a cell */
#define RECENT 8                      /* boxes remembered as tested along one ray */

struct imp_relief_scene {
        struct imp_relief_copy c;     /* borrowed arrays */
        double R[9], t[3];            /* canvas → world rotation, translation */
        float *box_top;               /* per box, mm */
        double top_mm;                /* highest box top (≥ δ0) */
        uint8_t *in_box;              /* nx·ny, 1 = texel inside a box */
        int g, cells_u, cells_v;      /* cell side in texels, cell grid */
        int32_t (*cells)[BOX_PER_CELL];     /* box ids, -1 = none */
};

void imp_relief_options_default(struct imp_relief_options *opt) {
        *opt = (struct imp_relief_options) {
                .mode = IMP_RELIEF_ADAPTIVE,
                .K = 0, .eps_min = 0.5, .eps_max = 2.0,
                .shadows = false,
                .linear_step_texels = 1.0,
                .binary_steps = 8,
        };
}

void imp_relief_scene_free(struct imp_relief_scene *s) {
        if (!s)
                return;
        free(s->box_top);
        free(s->in_box);
        free(s->cells);
        free(s);
}

static bool finite_nonneg(float x) { return isfinite(x) && x >= 0; }

static bool brdf_ok(const struct imp_lafortune *b) {
        for (int c = 0; c < 3; c++)
                if (!finite_nonneg(b->rho_d[c]) || !finite_nonneg(b->rho_s[c]))
                        return false;
        return isfinite(b->cx) && isfinite(b->cy) && isfinite(b->cz) && finite_nonneg(b->k);
}

static int check_copy(const struct imp_relief_copy *c) {
        if (c->nx < 1 || c->ny < 1 || c->nx > (1 << 20) || c->ny > (1 << 20) ||
            !(c->pitch_mm > 0) || !isfinite(c->pitch_mm) || !isfinite(c->delta0_mm) ||
            !c->height_mm || !c->normal_x || !c->normal_y || !c->brdf ||
            (c->n_boxes > 0 && !c->boxes))
                return -EINVAL;
        const double *M = c->canvas_to_world;
        for (int i = 0; i < 16; i++)
                if (!isfinite(M[i]))
                        return -EINVAL;
        if (M[12] != 0 || M[13] != 0 || M[14] != 0 || M[15] != 1)
                return -EINVAL;
        for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++) {
                        double d = M[a] * M[b] + M[4 + a] * M[4 + b] + M[8 + a] * M[8 + b];
                        if (fabs(d - (a == b)) > RIGID_TOL)
                                return -EINVAL;
                }
        size_t n = (size_t) c->nx * c->ny;
        for (size_t k = 0; k < n; k++)
                if (!isfinite(c->height_mm[k]) || !isfinite(c->normal_x[k]) ||
                    !isfinite(c->normal_y[k]) || !brdf_ok(&c->brdf[k]))
                        return -EINVAL;
        for (size_t b = 0; b < c->n_boxes; b++) {
                const struct imp_relief_box *x = &c->boxes[b];
                if (x->w < 1 || x->h < 1 || x->u0 < 0 || x->v0 < 0 || x->u0 > c->nx - x->w ||
                    x->v0 > c->ny - x->h || !isfinite(x->hmax_mm) || x->umax < 0 ||
                    x->umax >= c->nx || x->vmax < 0 || x->vmax >= c->ny)
                        return -EINVAL;
        }
        return 0;
}

/* Box tops, the in-box texel map (rejecting overlaps) and the cell grid. */
static int build_boxes(struct imp_relief_scene *s) {
        const struct imp_relief_copy *c = &s->c;
        s->top_mm = c->delta0_mm;
        s->in_box = calloc((size_t) c->nx * c->ny, 1);
        s->box_top = malloc(sizeof *s->box_top * (c->n_boxes ? c->n_boxes : 1));
        if (!s->in_box || !s->box_top)
                return -ENOMEM;
        int g = INT32_MAX;
        for (size_t b = 0; b < c->n_boxes; b++) {
                const struct imp_relief_box *x = &c->boxes[b];
                float top = IMP_MAX(x->hmax_mm, (float) c->delta0_mm);
                for (int j = x->v0; j < x->v0 + x->h; j++)
                        for (int i = x->u0; i < x->u0 + x->w; i++) {
                                size_t k = (size_t) j * c->nx + i;
                                if (s->in_box[k])
                                        return -EINVAL;
                                s->in_box[k] = 1;
                                top = IMP_MAX(top, c->height_mm[k]);
                        }
                s->box_top[b] = top;
                s->top_mm = IMP_MAX(s->top_mm, (double) top);
                g = IMP_MIN(g, IMP_MIN(x->w, x->h));
        }
        if (c->n_boxes == 0)
                g = IMP_MAX(c->nx, c->ny);
        s->g = g;
        s->cells_u = (c->nx + g - 1) / g;
        s->cells_v = (c->ny + g - 1) / g;
        s->cells = malloc(sizeof *s->cells * (size_t) s->cells_u * s->cells_v);
        if (!s->cells)
                return -ENOMEM;
        memset(s->cells, 0xff, sizeof *s->cells * (size_t) s->cells_u * s->cells_v);
        for (size_t b = 0; b < c->n_boxes; b++) {
                const struct imp_relief_box *x = &c->boxes[b];
                for (int cv = x->v0 / g; cv <= (x->v0 + x->h - 1) / g; cv++)
                        for (int cu = x->u0 / g; cu <= (x->u0 + x->w - 1) / g; cu++) {
                                int32_t *cell = s->cells[(size_t) cv * s->cells_u + cu];
                                int k = 0;
                                while (k < BOX_PER_CELL && cell[k] >= 0)
                                        k++;
                                if (k == BOX_PER_CELL)  /* impossible without overlap */
                                        return -EINVAL;
                                cell[k] = (int32_t) b;
                        }
        }
        return 0;
}

int imp_relief_scene_new(const struct imp_relief_copy *copy, struct imp_relief_scene **ret) {
        if (!copy || !ret)
                return -EINVAL;
        int r = check_copy(copy);
        if (r < 0)
                return r;
        struct imp_relief_scene *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        s->c = *copy;
        const double *M = copy->canvas_to_world;
        for (int a = 0; a < 3; a++) {
                for (int b = 0; b < 3; b++)
                        s->R[3 * a + b] = M[4 * a + b];
                s->t[a] = M[4 * a + 3];
        }
        r = build_boxes(s);
        if (r < 0) {
                imp_relief_scene_free(s);
                return r;
        }
        *ret = s;
        return 0;
}

/* ---- per-frame context ---- */

struct ctx {
        const struct imp_relief_scene *s;
        const struct imp_relief_options *opt;
        int channels;
        double C[3];                  /* camera centre, canvas frame */
        double A[9];                  /* camera device dir → canvas dir */
        bool distorted;
        const struct imp_pinhole *view;
        double Lp[3], La[3];          /* light position and axis, canvas frame */
        double Li[3];                 /* intensity · colour per channel */
        double Lexp;
        const float *alpha;           /* per box */
};

/* world → canvas: c = Rᵀ (w − t) (points) or Rᵀ w (directions). */
static void to_canvas_dir(const struct imp_relief_scene *s, const double w[3], double r[3]) {
        for (int i = 0; i < 3; i++)
                r[i] = s->R[i] * w[0] + s->R[3 + i] * w[1] + s->R[6 + i] * w[2];
}
static void to_canvas_pt(const struct imp_relief_scene *s, const double w[3], double r[3]) {
        double d[3] = { w[0] - s->t[0], w[1] - s->t[1], w[2] - s->t[2] };
        to_canvas_dir(s, d, r);
}

static int nearest(double x, double pitch, int n) {
        double f = floor(x / pitch + 0.5);
        if (!(f >= 0))
                return 0;
        if (f > n - 1)
                return n - 1;
        return (int) f;
}

/* Effective height inside box b: bilinear over the box's texels, never below δ0. */
static double box_height(const struct imp_relief_scene *s, const struct imp_relief_box *b,
                         double x, double y) {
        const struct imp_relief_copy *c = &s->c;
        double fx = x / c->pitch_mm, fy = y / c->pitch_mm;
        double i0f = floor(fx), j0f = floor(fy);
        double a = fx - i0f, bb = fy - j0f;
        int i0 = IMP_CLAMP((int) i0f, b->u0, b->u0 + b->w - 1);
        int i1 = IMP_CLAMP((int) i0f + 1, b->u0, b->u0 + b->w - 1);
        int j0 = IMP_CLAMP((int) j0f, b->v0, b->v0 + b->h - 1);
        int j1 = IMP_CLAMP((int) j0f + 1, b->v0, b->v0 + b->h - 1);
        const float *H = c->height_mm;
        double h = (1 - bb) * ((1 - a) * H[(size_t) j0 * c->nx + i0] + a * H[(size_t) j0 * c->nx + i1]) +
                   bb * ((1 - a) * H[(size_t) j1 * c->nx + i0] + a * H[(size_t) j1 * c->nx + i1]);
        return IMP_MAX(h, c->delta0_mm);
}

/* Height of the hybrid surface for shadow rays: relief inside boxes, the plane elsewhere. */
static double surface_height(const struct imp_relief_scene *s, double x, double y) {
        const struct imp_relief_copy *c = &s->c;
        int i = nearest(x, c->pitch_mm, c->nx), j = nearest(y, c->pitch_mm, c->ny);
        size_t k = (size_t) j * c->nx + i;
        if (!s->in_box[k])
                return c->delta0_mm;
        return IMP_MAX((double) c->height_mm[k], c->delta0_mm);
}

/* True when the segment from P towards the light passes below the hybrid surface. Starts
 * one step away from P so that the surface P lies on does not shadow itself. */
static bool in_shadow(const struct ctx *x, const double P[3], const double l[3]) {
        const struct imp_relief_scene *s = x->s;
        const struct imp_relief_copy *c = &s->c;
        if (s->c.n_boxes == 0 || l[2] <= 0 || P[2] >= s->top_mm)
                return false;
        double lxy = hypot(l[0], l[1]);
        double dt = lxy > 1e-12 ? c->pitch_mm / lxy : 1e30;
        double dist = sqrt((x->Lp[0] - P[0]) * (x->Lp[0] - P[0]) + (x->Lp[1] - P[1]) * (x->Lp[1] - P[1]) +
                           (x->Lp[2] - P[2]) * (x->Lp[2] - P[2]));
        double xmin = -0.5 * c->pitch_mm, xmax = (c->nx - 0.5) * c->pitch_mm;
        double ymin = -0.5 * c->pitch_mm, ymax = (c->ny - 0.5) * c->pitch_mm;
        for (int k = 1; k < SHADOW_STEPS_MAX; k++) {
                double t = k * dt;
                if (t >= dist)
                        return false;
                double q[3] = { P[0] + t * l[0], P[1] + t * l[1], P[2] + t * l[2] };
                if (q[2] >= s->top_mm || q[0] < xmin || q[0] >= xmax || q[1] < ymin || q[1] >= ymax)
                        return false;
                if (q[2] < surface_height(s, q[0], q[1]))
                        return true;
        }
        return false;
}

/* V = E · cos θl · f(v, l) at canvas point P with texel (i, j)'s normal and BRDF. */
static void shade(const struct ctx *x, const double P[3], int i, int j, bool shadow_ok,
                  double ret[3]) {
        const struct imp_relief_copy *c = &x->s->c;
        size_t k = (size_t) j * c->nx + i;
        ret[0] = ret[1] = ret[2] = 0;
        double n[3] = { c->normal_x[k], c->normal_y[k], 0 };
        double q = n[0] * n[0] + n[1] * n[1];
        if (q > 1) {
                double sc = 1 / sqrt(q);
                n[0] *= sc, n[1] *= sc;
        } else
                n[2] = sqrt(1 - q);
        double l[3], v[3];
        double dl = 0, dv = 0;
        for (int a = 0; a < 3; a++) {
                l[a] = x->Lp[a] - P[a];
                v[a] = x->C[a] - P[a];
                dl += l[a] * l[a];
                dv += v[a] * v[a];
        }
        if (!(dl > 1e-18) || !(dv > 1e-18))
                return;
        double il = 1 / sqrt(dl), iv = 1 / sqrt(dv);
        for (int a = 0; a < 3; a++)
                l[a] *= il, v[a] *= iv;
        double cos_l = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
        if (cos_l <= 0)
                return;
        /* Near-field point light: E = intensity · (1000 / d)² · max(0, cos to axis)^p. */
        double cax = -(x->La[0] * l[0] + x->La[1] * l[1] + x->La[2] * l[2]);
        double prof = x->Lexp > 0 ? (cax > 0 ? pow(cax, x->Lexp) : 0) : 1;
        double E = 1e6 / dl * prof;
        if (E <= 0)
                return;
        if (shadow_ok && x->opt->shadows && in_shadow(x, P, l))
                return;
        double t[3], b[3], vl[3], ll[3];
        imp_local_frame(n, t, b);
        imp_to_local(t, b, n, v, vl);
        imp_to_local(t, b, n, l, ll);
        for (int ch = 0; ch < x->channels; ch++)
                ret[ch] = x->Li[ch] * E * cos_l * imp_lafortune_eval(&c->brdf[k], ch, vl, ll);
}

/* Ray / axis-aligned box slab test; false when the ray misses. */
static bool slab(const double o[3], const double d[3], const double lo[3], const double hi[3],
                 double *ret_t0, double *ret_t1) {
        double t0 = -INFINITY, t1 = INFINITY;
        for (int a = 0; a < 3; a++) {
                if (fabs(d[a]) < 1e-300) {
                        if (o[a] < lo[a] || o[a] > hi[a])
                                return false;
                        continue;
                }
                double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
                if (ta > tb) {
                        double tmp = ta;
                        ta = tb, tb = tmp;
                }
                t0 = IMP_MAX(t0, ta);
                t1 = IMP_MIN(t1, tb);
        }
        *ret_t0 = t0;
        *ret_t1 = t1;
        return t0 <= t1;
}

static void box_bounds(const struct imp_relief_scene *s, size_t b, double lo[3], double hi[3]) {
        const struct imp_relief_box *x = &s->c.boxes[b];
        double p = s->c.pitch_mm;
        lo[0] = (x->u0 - 0.5) * p, hi[0] = (x->u0 + x->w - 0.5) * p;
        lo[1] = (x->v0 - 0.5) * p, hi[1] = (x->v0 + x->h - 0.5) * p;
        lo[2] = s->c.delta0_mm, hi[2] = s->box_top[b];
}

/* §5.2: linear search from the entry E (tE) to the exit S (tS), then binary refinement.
 * Returns true with the hit parameter when the ray meets the relief inside the box. */
static bool relief_search(const struct ctx *x, size_t bi, const double o[3], const double d[3],
                          double tE, double tS, double *ret_t) {
        const struct imp_relief_scene *s = x->s;
        const struct imp_relief_box *b = &s->c.boxes[bi];
        double len_xy = hypot(d[0], d[1]) * (tS - tE);
        double step = x->opt->linear_step_texels * s->c.pitch_mm;
        int n = (int) IMP_MIN(ceil(len_xy / step), (double) LINEAR_STEPS_MAX);
        n = IMP_MAX(n, 2);
        double dt = (tS - tE) / n, prev = tE;
        for (int k = 0; k <= n; k++) {
                double t = k == n ? tS : tE + k * dt;
                double z = o[2] + t * d[2];
                if (z <= box_height(s, b, o[0] + t * d[0], o[1] + t * d[1])) {
                        if (k == 0) {           /* entered through a wall below the surface */
                                *ret_t = tE;
                                return true;
                        }
                        double lo = prev, hi = t;
                        for (int it = 0; it < x->opt->binary_steps; it++) {
                                double m = 0.5 * (lo + hi);
                                if (o[2] + m * d[2] <= box_height(s, b, o[0] + m * d[0], o[1] + m * d[1]))
                                        hi = m;
                                else
                                        lo = m;
                        }
                        *ret_t = hi;     /* on or below the surface */
                        return true;
                }
                prev = t;
        }
        return false;
}

/* Walks the cell grid along the ray's footprint in the slab [δ0, top] and relief-maps the
 * drawn boxes in the order the ray enters them; the first hit wins (boxes do not overlap,
 * so their ray intervals are disjoint). */
static bool trace_boxes(const struct ctx *x, const double o[3], const double d[3],
                        double *ret_t, size_t *ret_box) {
        const struct imp_relief_scene *s = x->s;
        const struct imp_relief_copy *c = &s->c;
        double p = c->pitch_mm;
        double lo[3] = { -0.5 * p, -0.5 * p, c->delta0_mm };
        double hi[3] = { (c->nx - 0.5) * p, (c->ny - 0.5) * p, s->top_mm };
        double t0, t1;
        if (!slab(o, d, lo, hi, &t0, &t1))
                return false;
        t0 = IMP_MAX(t0, 0.0);
        if (t0 > t1)
                return false;
        /* Cell coordinates: s(t) = ((x/p) + ½) / g. */
        double gp = p * s->g;
        double sx = (o[0] + t0 * d[0]) / gp + 0.5 / s->g, sy = (o[1] + t0 * d[1]) / gp + 0.5 / s->g;
        int cu = IMP_CLAMP((int) floor(sx), 0, s->cells_u - 1), cv = IMP_CLAMP((int) floor(sy), 0, s->cells_v - 1);
        int su = d[0] > 0 ? 1 : -1, sv = d[1] > 0 ? 1 : -1;
        double dsx = d[0] / gp, dsy = d[1] / gp;
        double tdx = fabs(dsx) > 1e-300 ? 1 / fabs(dsx) : INFINITY;
        double tdy = fabs(dsy) > 1e-300 ? 1 / fabs(dsy) : INFINITY;
        double tmx = fabs(dsx) > 1e-300 ? t0 + ((su > 0 ? cu + 1 : cu) - sx) / dsx : INFINITY;
        double tmy = fabs(dsy) > 1e-300 ? t0 + ((sv > 0 ? cv + 1 : cv) - sy) / dsy : INFINITY;
        int32_t recent[RECENT];
        int n_recent = 0;
        for (int guard = 0; guard < s->cells_u + s->cells_v + 2; guard++) {
                const int32_t *cell = s->cells[(size_t) cv * s->cells_u + cu];
                double cand_t0[BOX_PER_CELL], cand_t1[BOX_PER_CELL];
                int32_t cand[BOX_PER_CELL];
                int nc = 0;
                for (int k = 0; k < BOX_PER_CELL && cell[k] >= 0; k++) {
                        int32_t b = cell[k];
                        bool seen = false;
                        for (int r = 0; r < IMP_MIN(n_recent, RECENT); r++)
                                seen |= recent[r] == b;
                        if (seen)
                                continue;
                        recent[n_recent++ % RECENT] = b;
                        if (!(x->alpha[b] > 0))
                                continue;
                        double blo[3], bhi[3], e, f;
                        box_bounds(s, (size_t) b, blo, bhi);
                        if (!slab(o, d, blo, bhi, &e, &f) || f < 0)
                                continue;
                        e = IMP_MAX(e, 0.0);
                        int m = nc++;         /* insertion by entry parameter */
                        while (m > 0 && cand_t0[m - 1] > e) {
                                cand_t0[m] = cand_t0[m - 1], cand_t1[m] = cand_t1[m - 1], cand[m] = cand[m - 1];
                                m--;
                        }
                        cand_t0[m] = e, cand_t1[m] = f, cand[m] = b;
                }
                for (int k = 0; k < nc; k++)
                        if (relief_search(x, (size_t) cand[k], o, d, cand_t0[k], cand_t1[k], ret_t)) {
                                *ret_box = (size_t) cand[k];
                                return true;
                        }
                double tnext = IMP_MIN(tmx, tmy);
                if (tnext > t1)
                        break;
                if (tmx < tmy) {
                        cu += su;
                        tmx += tdx;
                } else {
                        cv += sv;
                        tmy += tdy;
                }
                if (cu < 0 || cu >= s->cells_u || cv < 0 || cv >= s->cells_v)
                        break;
        }
        return false;
}

/* One pixel: bump result on the plane z = δ0 (§5.1), relief result over the boxes (§5.2),
 * blended with the hit box's α (§5.3). */
static bool render_pixel(const struct ctx *x, const double o[3], const double d[3],
                         double ret_v[3], float *ret_alpha, bool *ret_relief) {
        const struct imp_relief_scene *s = x->s;
        const struct imp_relief_copy *c = &s->c;
        double p = c->pitch_mm;
        ret_v[0] = ret_v[1] = ret_v[2] = 0;
        *ret_alpha = 0;
        *ret_relief = false;
        if (!(d[2] < -DZ_MIN))
                return false;
        bool hit = false;
        double bump[3] = { 0, 0, 0 };
        double tb = (c->delta0_mm - o[2]) / d[2];
        double xb = o[0] + tb * d[0], yb = o[1] + tb * d[1];
        if (xb >= -0.5 * p && xb < (c->nx - 0.5) * p && yb >= -0.5 * p && yb < (c->ny - 0.5) * p) {
                int i = nearest(xb, p, c->nx), j = nearest(yb, p, c->ny);
                /* §5.4: light and view directions from the real surface position. */
                double P[3] = { xb, yb, c->height_mm[(size_t) j * c->nx + i] };
                shade(x, P, i, j, false, bump);
                if (x->opt->shadows) {
                        double Q[3] = { xb, yb, c->delta0_mm }, l[3], dl = 0;
                        for (int a = 0; a < 3; a++)
                                l[a] = x->Lp[a] - Q[a], dl += l[a] * l[a];
                        dl = sqrt(dl);
                        for (int a = 0; a < 3; a++)
                                l[a] /= dl > 0 ? dl : 1;
                        if (dl > 0 && in_shadow(x, Q, l))
                                bump[0] = bump[1] = bump[2] = 0;
                }
                hit = true;
        }
        memcpy(ret_v, bump, sizeof bump);
        if (x->opt->mode == IMP_RELIEF_BUMP_ONLY || c->n_boxes == 0)
                return hit;
        double th;
        size_t bi;
        if (!trace_boxes(x, o, d, &th, &bi))
                return hit;
        double P[3] = { o[0] + th * d[0], o[1] + th * d[1], o[2] + th * d[2] };
        int i = nearest(P[0], p, c->nx), j = nearest(P[1], p, c->ny);
        double rel[3];
        shade(x, P, i, j, true, rel);
        double a = x->alpha[bi];
        for (int ch = 0; ch < 3; ch++)
                ret_v[ch] = a * rel[ch] + (1 - a) * bump[ch];
        *ret_alpha = (float) a;
        *ret_relief = true;
        return true;
}

static int check_options(const struct imp_relief_options *o) {
        if (!o || (o->mode != IMP_RELIEF_BUMP_ONLY && o->mode != IMP_RELIEF_RELIEF_ALL &&
                   o->mode != IMP_RELIEF_ADAPTIVE))
                return -EINVAL;
        if (!isfinite(o->K) || !isfinite(o->eps_min) || !isfinite(o->eps_max) ||
            o->eps_max < o->eps_min || !(o->linear_step_texels >= 0.05 && o->linear_step_texels <= 16) ||
            o->binary_steps < 0 || o->binary_steps > 30)
                return -EINVAL;
        return 0;
}

static bool view_ok(const struct imp_pinhole *v) {
        if (!v || v->width < 1 || v->height < 1 || !(v->fx > 0) || !(v->fy > 0) || !isfinite(v->fx) ||
            !isfinite(v->fy) || !isfinite(v->cx) || !isfinite(v->cy))
                return false;
        for (int i = 0; i < 9; i++)
                if (!isfinite(v->R[i]))
                        return false;
        return isfinite(v->t[0]) && isfinite(v->t[1]) && isfinite(v->t[2]) && isfinite(v->k1) &&
               isfinite(v->k2) && isfinite(v->k3) && isfinite(v->p1) && isfinite(v->p2);
}

int imp_relief_box_alpha(const struct imp_relief_scene *s, const struct imp_pinhole *view,
                         const struct imp_relief_options *opt, float *ret_alpha) {
        if (!s || !view_ok(view) || check_options(opt) < 0 || (s->c.n_boxes && !ret_alpha))
                return -EINVAL;
        const struct imp_relief_copy *c = &s->c;
        double Cw[3], C[3];
        imp_pinhole_centre(view, Cw);
        to_canvas_pt(s, Cw, C);
        bool below = !(C[2] > c->delta0_mm);
        double K = opt->K > 0 ? opt->K : view->fx;
        for (size_t b = 0; b < c->n_boxes; b++) {
                float a;
                if (below)
                        a = 0;
                else if (opt->mode == IMP_RELIEF_BUMP_ONLY)
                        a = 0;
                else if (opt->mode == IMP_RELIEF_RELIEF_ALL)
                        a = 1;
                else {
                        const struct imp_relief_box *x = &c->boxes[b];
                        double I[3] = { x->umax * c->pitch_mm, x->vmax * c->pitch_mm, x->hmax_mm };
                        double v[3] = { I[0] - C[0], I[1] - C[1], I[2] - C[2] };
                        double CI = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                        double above = IMP_MAX(I[2] - c->delta0_mm, 0.0);
                        double cos_t = CI > 0 ? -v[2] / CI : 0;
                        if (above == 0)
                                a = 0;   /* no relief above the plane: nothing to correct */
                        else if (!(cos_t > 1e-12) || !(CI > 0))
                                a = 1;   /* I seen parallel to the plane (or from I itself) */
                        else {
                                double kr = K * (above / cos_t) / CI;   /* K · |IB| / |CI| */
                                if (kr < opt->eps_min)
                                        a = 0;
                                else if (kr > opt->eps_max)
                                        a = 1;
                                else
                                        a = (float) ((kr - opt->eps_min) / (opt->eps_max - opt->eps_min));
                                if (!isfinite(a))
                                        a = 1;
                        }
                }
                ret_alpha[b] = a;
        }
        return below ? IMP_RELIEF_CAMERA_BELOW : 0;
}

static bool image_ok(const struct imp_image *img, const struct imp_pinhole *v, int ch_min, int ch_max) {
        return img && img->type == IMP_PIX_F32 && img->width == v->width && img->height == v->height &&
               img->channels >= ch_min && img->channels <= ch_max && img->data;
}

static void zero_image(struct imp_image *img) {
        for (int y = 0; y < img->height; y++)
                memset(imp_image_row(img, y), 0, (size_t) img->width * img->channels * sizeof(float));
}

int imp_relief_render(const struct imp_relief_scene *s, const struct imp_pinhole *view,
                      const struct imp_rig_light *light, const struct imp_relief_options *opt,
                      struct imp_image *out, struct imp_image *ret_alpha,
                      struct imp_relief_stats *ret_stats) {
        if (!s || !view_ok(view) || !light || check_options(opt) < 0 || !image_ok(out, view, 1, 3) ||
            out->channels == 2 || (ret_alpha && !image_ok(ret_alpha, view, 1, 1)))
                return -EINVAL;
        for (int a = 0; a < 3; a++)
                if (!isfinite(light->pos_mm[a]) || !isfinite(light->axis[a]) || !isfinite(light->colour[a]))
                        return -EINVAL;
        if (!isfinite(light->intensity) || !isfinite(light->profile_exp) || light->profile_exp < 0)
                return -EINVAL;

        struct imp_relief_stats st = { 0 };
        float *alpha = malloc(sizeof *alpha * (s->c.n_boxes ? s->c.n_boxes : 1));
        if (!alpha)
                return -ENOMEM;
        int fl = imp_relief_box_alpha(s, view, opt, alpha);
        if (fl < 0) {
                free(alpha);
                return fl;
        }
        st.flags = (unsigned) fl;
        for (size_t b = 0; b < s->c.n_boxes; b++) {
                st.n_boxes_drawn += alpha[b] > 0;
                st.n_boxes_blended += alpha[b] > 0 && alpha[b] < 1;
        }
        if (st.flags & IMP_RELIEF_CAMERA_BELOW) {
                zero_image(out);
                if (ret_alpha)
                        zero_image(ret_alpha);
                free(alpha);
                if (ret_stats)
                        *ret_stats = st;
                return 0;
        }

        struct ctx x = { .s = s, .opt = opt, .channels = out->channels, .view = view, .alpha = alpha };
        double Cw[3], Lc[3];
        imp_pinhole_centre(view, Cw);
        to_canvas_pt(s, Cw, x.C);
        to_canvas_pt(s, light->pos_mm, x.Lp);
        to_canvas_dir(s, light->axis, Lc);
        double la = sqrt(Lc[0] * Lc[0] + Lc[1] * Lc[1] + Lc[2] * Lc[2]);
        for (int a = 0; a < 3; a++) {
                x.La[a] = la > 0 ? Lc[a] / la : 0;
                x.Li[a] = light->intensity * light->colour[a];
        }
        x.Lexp = light->profile_exp;
        x.distorted = view->k1 != 0 || view->k2 != 0 || view->k3 != 0 || view->p1 != 0 || view->p2 != 0;
        /* device dir → world: Rcamᵀ d; world → canvas: Rᵀ w. */
        for (int r = 0; r < 3; r++)
                for (int k = 0; k < 3; k++) {
                        double sum = 0;
                        for (int m = 0; m < 3; m++)
                                sum += s->R[3 * m + r] * view->R[3 * k + m];
                        x.A[3 * r + k] = sum;
                }

        size_t n_relief = 0, n_hit = 0;
#ifdef _OPENMP
#pragma omp parallel for schedule(dynamic, 4) reduction(+ : n_relief, n_hit)
#endif
        for (int py = 0; py < view->height; py++) {
                for (int px = 0; px < view->width; px++) {
                        double dev[3];
                        if (x.distorted) {
                                double pp[2] = { px, py };
                                imp_pinhole_ray_device(view, pp, dev);
                        } else {
                                dev[0] = (px - view->cx) / view->fx;
                                dev[1] = (py - view->cy) / view->fy;
                                dev[2] = 1;
                        }
                        double d[3];
                        for (int r = 0; r < 3; r++)
                                d[r] = x.A[3 * r] * dev[0] + x.A[3 * r + 1] * dev[1] + x.A[3 * r + 2] * dev[2];
                        double dn = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                        for (int r = 0; r < 3; r++)
                                d[r] /= dn;
                        double v[3];
                        float a;
                        bool rel;
                        bool hit = render_pixel(&x, x.C, d, v, &a, &rel);
                        n_hit += hit;
                        n_relief += rel;
                        float *o = imp_image_f32(out, px, py);
                        for (int ch = 0; ch < out->channels; ch++)
                                o[ch] = isfinite(v[ch]) ? (float) v[ch] : 0.0f;
                        if (ret_alpha)
                                *imp_image_f32(ret_alpha, px, py) = a;
                }
        }
        st.n_pixels_relief = n_relief;
        st.n_pixels_hit = n_hit;
        free(alpha);
        if (ret_stats)
                *ret_stats = st;
        return 0;
}
