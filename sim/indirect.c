/* Interreflection through irradiance-vector grids (seed 002): a 2D grid over the canvas
 * and a 3D grid around the frame hold, per vertex, the indirect irradiance for the six
 * axis normals, path traced once per light on a decimated heightfield. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "indirect.h"
#include "lafortune.h"
#include "macro.h"

/* Test and diagnostic accessors (not in indirect.h: tests declare them themselves).
 * grid is 2 (canvas) or 3 (frame); a 2D vertex reports z = 0; ret_traced: computed by path
 * tracing (else filled from neighbours, or unused). */
int imp_indirect_grid_size(const struct imp_indirect *g, int grid, int ret_n[3]);
int imp_indirect_grid_vertex(const struct imp_indirect *g, int grid, int i, int j, int k,
                             double ret_pos_mm[3], float ret_vec[6][3], bool *ret_traced);

enum { DIR_PX, DIR_NX, DIR_PY, DIR_NY, DIR_PZ, DIR_NZ, N_DIRS };
#define VEC_FLOATS (N_DIRS * 3)          /* six RGB irradiances per vertex */

/* Vertex states: traced, filled from neighbours, or neither (never read by eval). */
enum { V_UNUSED, V_INVALID, V_TRACED, V_FILLED };

#define LIFT_PITCHES 0.25         /* 2D vertices sit this many traced pitches above the surface */
#define ORIGIN_EPS_PITCHES 0.02   /* ray origins leave the surface along n by this much */
#define MARCH_STEP_PITCHES 0.5    /* ray-march step, in traced pitches along x–y */
#define MARCH_MIN_DXY 0.05        /* caps the step of nearly vertical rays */
#define BISECT_ITERS 12           /* interval 2^-12 of a step: ~1e-4 pitch */
#define HF_BLOCK 8                /* cells per side of the max-height blocks rays skip over */
#define REFINE_PITCHES 2.0        /* a hit on the simplified surface is looked for on the full
                                     one within this many simplified pitches along x–y */
#define SNAP_TOL 1e-9             /* grid coordinates this close to an integer are exact */
#define LIGHT_REF_DIST_MM 1000.0  /* light intensity is the irradiance at this distance */

struct grid {
        int n[3];                 /* vertices along x, y, z (n[2] = 1 for the 2D grid) */
        double o[3], d[3];        /* first vertex and spacing, mm */
        float *vec;               /* n[0]·n[1]·n[2] × VEC_FLOATS */
        uint8_t *state;
};

struct imp_indirect {
        double canvas_min[2], canvas_max[2];
        struct grid g2;
        bool has_g3;
        struct grid g3;
};

/* A heightfield to trace: the surface itself (reference) or its decimation (grids). */
struct hfield {
        int nx, ny;
        double pitch, ox, oy;
        const float *h;
        double hmin, hmax;
        int bnx, bny;             /* HF_BLOCK × HF_BLOCK cell blocks ... */
        float *bmax;              /* ... and their maximum heights (owned; NULL: no skipping) */
};

struct light {
        double pos[3], axis[3], colour[3];
        double intensity, profile_exp;
};

struct tracer {
        const struct imp_sim_surface *surf;   /* albedo */
        const struct hfield *hf;              /* geometry rays see */
        const struct hfield *fine;            /* the full surface, for shading hits; or NULL */
        struct light light;
        int max_bounces;
};

/* ---- counter-based random numbers (splitmix64) ---- */

#define GOLDEN 0x9e3779b97f4a7c15ULL

static uint64_t mix64(uint64_t z) {
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
        return z ^ (z >> 31);
}

struct rng { uint64_t s; uint64_t draws; };

static double rng_uniform(struct rng *r) {
        r->s += GOLDEN;
        r->draws++;
        return (double) (mix64(r->s) >> 11) * 0x1.0p-53;   /* [0, 1) */
}

/* ---- heightfield geometry ---- */

static double hf_height(const struct hfield *f, double x, double y) {
        double fx = (x - f->ox) / f->pitch, fy = (y - f->oy) / f->pitch;
        fx = IMP_CLAMP(fx, 0.0, (double) (f->nx - 1));
        fy = IMP_CLAMP(fy, 0.0, (double) (f->ny - 1));
        int x0 = (int) fx, y0 = (int) fy;
        int x1 = x0 + 1 < f->nx ? x0 + 1 : x0, y1 = y0 + 1 < f->ny ? y0 + 1 : y0;
        double ax = fx - x0, ay = fy - y0;
        const float *h = f->h;
        double a = h[(size_t) y0 * f->nx + x0], b = h[(size_t) y0 * f->nx + x1];
        double c = h[(size_t) y1 * f->nx + x0], d = h[(size_t) y1 * f->nx + x1];
        return (a * (1 - ax) + b * ax) * (1 - ay) + (c * (1 - ax) + d * ax) * ay;
}

/* Unit normal by central differences over one pitch. */
static void hf_normal(const struct hfield *f, double x, double y, double ret[3]) {
        double p = f->pitch;
        double gx = (hf_height(f, x + p, y) - hf_height(f, x - p, y)) / (2 * p);
        double gy = (hf_height(f, x, y + p) - hf_height(f, x, y - p)) / (2 * p);
        double len = sqrt(gx * gx + gy * gy + 1);
        ret[0] = -gx / len;
        ret[1] = -gy / len;
        ret[2] = 1 / len;
}

static void hf_init(struct hfield *f, int nx, int ny, double pitch, double ox, double oy,
                    const float *h) {
        *f = (struct hfield) { .nx = nx, .ny = ny, .pitch = pitch, .ox = ox, .oy = oy, .h = h,
                               .hmin = INFINITY, .hmax = -INFINITY };
        for (size_t i = 0; i < (size_t) nx * ny; i++) {
                f->hmin = fmin(f->hmin, h[i]);
                f->hmax = fmax(f->hmax, h[i]);
        }
}

/* Block maxima over the samples a block's cells touch (its far edge included: bilinear
 * cells use both corners). Without them marching is slower, not different. */
static int hf_build_blocks(struct hfield *f) {
        f->bnx = (f->nx - 2) / HF_BLOCK + 1;
        f->bny = (f->ny - 2) / HF_BLOCK + 1;
        f->bmax = malloc((size_t) f->bnx * f->bny * sizeof(float));
        if (!f->bmax)
                return -ENOMEM;
        for (int bj = 0; bj < f->bny; bj++)
                for (int bi = 0; bi < f->bnx; bi++) {
                        float m = -INFINITY;
                        for (int j = bj * HF_BLOCK; j <= IMP_MIN((bj + 1) * HF_BLOCK, f->ny - 1); j++)
                                for (int i = bi * HF_BLOCK; i <= IMP_MIN((bi + 1) * HF_BLOCK, f->nx - 1); i++)
                                        m = fmaxf(m, f->h[(size_t) j * f->nx + i]);
                        f->bmax[(size_t) bj * f->bnx + bi] = m;
                }
        return 0;
}

static void hf_free_blocks(struct hfield *f) {
        free(f->bmax);
        f->bmax = NULL;
}

/* Parametric interval [t0, t1] of o + t·d inside [lo, hi] along one axis; false if empty. */
static bool clip_slab(double o, double d, double lo, double hi, double *t0, double *t1) {
        if (fabs(d) < 1e-300)
                return o >= lo && o <= hi;
        double a = (lo - o) / d, b = (hi - o) / d;
        if (a > b) { double t = a; a = b; b = t; }
        *t0 = fmax(*t0, a);
        *t1 = fmin(*t1, b);
        return *t0 <= *t1;
}

/* First crossing of the ray o + t·d (d unit) from above the heightfield to below it, for
 * t in (tmin, tmax]. The field ends at its sampled area: rays leaving it escape. A ray that
 * starts below the surface only counts a later entry from above. */
/* Where the ray at parameter t can jump to without meeting the surface: the end of the
 * current block's x–y box, or where it sinks to the block's maximum height; t itself when
 * the ray is not above that maximum. */
static double block_skip(const struct hfield *f, const double o[3], const double d[3], double t) {
        double x = o[0] + t * d[0], y = o[1] + t * d[1], z = o[2] + t * d[2];
        double bw = f->pitch * HF_BLOCK;
        int bi = IMP_CLAMP((int) floor((x - f->ox) / bw), 0, f->bnx - 1);
        int bj = IMP_CLAMP((int) floor((y - f->oy) / bw), 0, f->bny - 1);
        double top = f->bmax[(size_t) bj * f->bnx + bi];
        if (!(z > top))
                return t;
        double te = INFINITY;
        if (d[0] > 0) te = fmin(te, (f->ox + (bi + 1) * bw - o[0]) / d[0]);
        if (d[0] < 0) te = fmin(te, (f->ox + bi * bw - o[0]) / d[0]);
        if (d[1] > 0) te = fmin(te, (f->oy + (bj + 1) * bw - o[1]) / d[1]);
        if (d[1] < 0) te = fmin(te, (f->oy + bj * bw - o[1]) / d[1]);
        if (d[2] < 0) te = fmin(te, (top - o[2]) / d[2]);
        return fmax(te, t);
}

static double hf_gap(const struct hfield *f, const double o[3], const double d[3], double t) {
        return o[2] + t * d[2] - hf_height(f, o[0] + t * d[0], o[1] + t * d[1]);
}

/* First crossing of the ray o + t·d (d unit) from above the heightfield to below it, for
 * t in (tmin, tmax]: steps of half a pitch, skipping blocks the ray passes above, then
 * bisection. The field ends at its sampled area: rays leaving it escape. A ray that
 * starts below the surface only counts a later entry from above. */
static bool hf_march_range(const struct hfield *f, const double o[3], const double d[3],
                           double tmin, double tmax, double *ret_t) {
        double t0 = tmin, t1 = tmax;
        double x1 = f->ox + (f->nx - 1) * f->pitch, y1 = f->oy + (f->ny - 1) * f->pitch;
        if (!clip_slab(o[0], d[0], f->ox, x1, &t0, &t1) ||
            !clip_slab(o[1], d[1], f->oy, y1, &t0, &t1) ||
            !clip_slab(o[2], d[2], f->hmin - 1.0, f->hmax, &t0, &t1))
                return false;
        double dxy = hypot(d[0], d[1]);
        double dt = MARCH_STEP_PITCHES * f->pitch / fmax(dxy, MARCH_MIN_DXY);
        double nudge = 1e-6 * f->pitch;
        double tp = t0, gp = hf_gap(f, o, d, tp);
        while (tp < t1) {
                if (f->bmax) {
                        double ts = block_skip(f, o, d, tp);
                        if (ts > tp) {
                                tp = fmin(ts + nudge, t1);
                                gp = hf_gap(f, o, d, tp);
                                if (gp <= 0) {
                                        /* sank onto a block whose maximum is the surface
                                         * itself (a flat area): the crossing is here */
                                        *ret_t = tp;
                                        return true;
                                }
                                continue;
                        }
                }
                double t = fmin(tp + dt, t1);
                double g = hf_gap(f, o, d, t);
                if (gp > 0 && g <= 0) {
                        double a = tp, b = t;
                        for (int i = 0; i < BISECT_ITERS; i++) {
                                double m = 0.5 * (a + b);
                                if (hf_gap(f, o, d, m) > 0)
                                        a = m;
                                else
                                        b = m;
                        }
                        *ret_t = b;
                        return true;
                }
                tp = t;
                gp = g;
        }
        return false;
}

static bool hf_march(const struct hfield *f, const double o[3], const double d[3], double tmax,
                     double *ret_t) {
        return hf_march_range(f, o, d, 0, tmax, ret_t);
}

/* ---- light transport ---- */

static void light_init(struct light *l, const struct imp_rig_light *rl) {
        double a = sqrt(rl->axis[0] * rl->axis[0] + rl->axis[1] * rl->axis[1] +
                        rl->axis[2] * rl->axis[2]);
        for (int i = 0; i < 3; i++) {
                l->pos[i] = rl->pos_mm[i];
                l->axis[i] = a > 0 ? rl->axis[i] / a : 0;
                l->colour[i] = rl->colour[i];
        }
        l->intensity = rl->intensity;
        l->profile_exp = rl->profile_exp;
}

/* Direct irradiance (E·cosθ, shadowed) at surface point q with unit normal n, scalar:
 * multiply by the light's colour. */
static double direct_irradiance(const struct tracer *tr, const double q[3], const double n[3]) {
        const struct light *L = &tr->light;
        double l[3] = { L->pos[0] - q[0], L->pos[1] - q[1], L->pos[2] - q[2] };
        double dist = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
        if (!(dist > 1e-9))
                return 0;
        for (int i = 0; i < 3; i++) l[i] /= dist;
        double cos_r = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
        if (cos_r <= 0)
                return 0;
        double profile = 1;
        if (L->profile_exp > 0) {
                double c = -(L->axis[0] * l[0] + L->axis[1] * l[1] + L->axis[2] * l[2]);
                if (c <= 0)
                        return 0;
                profile = pow(c, L->profile_exp);
        }
        double eps = ORIGIN_EPS_PITCHES * tr->hf->pitch;
        double o[3] = { q[0] + eps * n[0], q[1] + eps * n[1], q[2] + eps * n[2] };
        double t;
        if (hf_march(tr->hf, o, l, dist, &t))
                return 0;
        double r = LIGHT_REF_DIST_MM / dist;
        return L->intensity * r * r * profile * cos_r;
}

static void surf_albedo(const struct imp_sim_surface *s, double x, double y, double ret[3]) {
        int i = (int) lround((x - s->origin_mm[0]) / s->pitch_mm);
        int j = (int) lround((y - s->origin_mm[1]) / s->pitch_mm);
        i = IMP_CLAMP(i, 0, s->nx - 1);
        j = IMP_CLAMP(j, 0, s->ny - 1);
        const float *a = s->albedo + ((size_t) j * s->nx + i) * 3;
        for (int c = 0; c < 3; c++) ret[c] = a[c];
}

/* Cosine-weighted direction about n; the first bounce of a path may be confined to one
 * stratum (cell sx, sy of an ns × ns grid over the unit square; ns = 1: the whole square). */
static void cosine_dir(const double n[3], struct rng *r, int ns, int sx, int sy, double ret[3]) {
        double t[3], b[3];
        imp_local_frame(n, t, b);
        double u1 = (sx + rng_uniform(r)) / ns, u2 = (sy + rng_uniform(r)) / ns;
        double rad = sqrt(u1), phi = 2 * M_PI * u2;
        double lx = rad * cos(phi), ly = rad * sin(phi), lz = sqrt(1 - u1);
        for (int i = 0; i < 3; i++) ret[i] = lx * t[i] + ly * b[i] + lz * n[i];
}

/* One path's estimate of the indirect irradiance at o for normal n. With cosine-weighted
 * directions the π of the estimator cancels the 1/π of each diffuse bounce, so each bounce
 * adds (product of albedos so far) × direct irradiance at the hit. */
static void trace_path(const struct tracer *tr, const double o[3], const double n[3],
                       struct rng *r, int ns, int sx, int sy, double acc[3]) {
        double T[3] = { 1, 1, 1 }, cur_o[3], cur_n[3];
        memcpy(cur_o, o, sizeof cur_o);
        memcpy(cur_n, n, sizeof cur_n);
        double eps = ORIGIN_EPS_PITCHES * tr->hf->pitch;
        for (int bounce = 0; bounce < tr->max_bounces; bounce++) {
                double d[3], t;
                if (bounce == 0)
                        cosine_dir(cur_n, r, ns, sx, sy, d);
                else
                        cosine_dir(cur_n, r, 1, 0, 0, d);
                double so[3] = { cur_o[0] + eps * cur_n[0], cur_o[1] + eps * cur_n[1],
                                 cur_o[2] + eps * cur_n[2] };
                if (!hf_march(tr->hf, so, d, INFINITY, &t))
                        return;
                const struct hfield *shade = tr->hf;
                if (tr->fine) {
                        /* seed 002 §3, appearance preserving: visibility on the simplified
                         * surface, shading (position, normal, albedo) on the detailed one */
                        double w = REFINE_PITCHES * tr->hf->pitch / fmax(hypot(d[0], d[1]), MARCH_MIN_DXY);
                        double tf;
                        if (hf_march_range(tr->fine, so, d, fmax(t - w, 0), t + w, &tf)) {
                                t = tf;
                                shade = tr->fine;
                        }
                }
                double q[3] = { so[0] + t * d[0], so[1] + t * d[1], so[2] + t * d[2] }, nq[3];
                double rho[3];
                hf_normal(shade, q[0], q[1], nq);
                surf_albedo(tr->surf, q[0], q[1], rho);
                for (int c = 0; c < 3; c++) T[c] *= rho[c];
                if (T[0] <= 0 && T[1] <= 0 && T[2] <= 0)
                        return;
                double e = direct_irradiance(tr, q, nq);
                for (int c = 0; c < 3; c++) acc[c] += T[c] * e * tr->light.colour[c];
                memcpy(cur_o, q, sizeof cur_o);
                memcpy(cur_n, nq, sizeof cur_n);
        }
}

/* Mean over `paths` paths; the first ns² paths stratify their first direction (jittered
 * strata over the cosine-weighted hemisphere), the rest are plain random. */
static void estimate(const struct tracer *tr, const double o[3], const double n[3], int paths,
                     uint64_t key, double ret[3], uint64_t *draws) {
        double acc[3] = { 0, 0, 0 };
        int ns = (int) sqrt((double) paths);
        for (int k = 0; k < paths; k++) {
                struct rng r = { .s = mix64(key + (uint64_t) k * GOLDEN) };
                if (k < ns * ns)
                        trace_path(tr, o, n, &r, ns, k % ns, k / ns, acc);
                else
                        trace_path(tr, o, n, &r, 1, 0, 0, acc);
                *draws += r.draws;
        }
        for (int c = 0; c < 3; c++) ret[c] = acc[c] / paths;
}

/* ---- grids ---- */

static size_t grid_count(const struct grid *g) {
        return (size_t) g->n[0] * g->n[1] * g->n[2];
}

static size_t grid_index(const struct grid *g, int i, int j, int k) {
        return ((size_t) k * g->n[1] + j) * g->n[0] + i;
}

static void grid_pos(const struct grid *g, size_t idx, int ret_ijk[3]) {
        ret_ijk[0] = idx % g->n[0];
        ret_ijk[1] = (idx / g->n[0]) % g->n[1];
        ret_ijk[2] = idx / ((size_t) g->n[0] * g->n[1]);
}

static int grid_alloc(struct grid *g) {
        size_t n = grid_count(g);
        g->vec = calloc(n * VEC_FLOATS, sizeof(float));
        g->state = calloc(n, 1);
        return g->vec && g->state ? 0 : -ENOMEM;
}

static void grid_free(struct grid *g) {
        free(g->vec);
        free(g->state);
}

static const double axis_normals[N_DIRS][3] = {
        { 1, 0, 0 }, { -1, 0, 0 }, { 0, 1, 0 }, { 0, -1, 0 }, { 0, 0, 1 }, { 0, 0, -1 },
};

/* Jacobi passes: every invalid vertex with valid neighbours (8 in 2D, 26 in 3D) takes their
 * average and becomes valid for the next pass; stops when a pass fills nothing. */
static int grid_fill(struct grid *g) {
        size_t n = grid_count(g);
        _cleanup_free_ uint8_t *next = malloc(n);
        if (!next)
                return -ENOMEM;
        for (bool changed = true; changed;) {
                changed = false;
                memcpy(next, g->state, n);
                for (size_t v = 0; v < n; v++) {
                        if (g->state[v] != V_INVALID)
                                continue;
                        int p[3], cnt = 0;
                        double sum[VEC_FLOATS] = { 0 };
                        grid_pos(g, v, p);
                        for (int dk = -1; dk <= 1; dk++)
                        for (int dj = -1; dj <= 1; dj++)
                        for (int di = -1; di <= 1; di++) {
                                int i = p[0] + di, j = p[1] + dj, k = p[2] + dk;
                                if (i < 0 || j < 0 || k < 0 || i >= g->n[0] || j >= g->n[1] ||
                                    k >= g->n[2])
                                        continue;
                                size_t u = grid_index(g, i, j, k);
                                if (g->state[u] != V_TRACED && g->state[u] != V_FILLED)
                                        continue;
                                for (int c = 0; c < VEC_FLOATS; c++)
                                        sum[c] += g->vec[u * VEC_FLOATS + c];
                                cnt++;
                        }
                        if (!cnt)
                                continue;
                        for (int c = 0; c < VEC_FLOATS; c++)
                                g->vec[v * VEC_FLOATS + c] = (float) (sum[c] / cnt);
                        next[v] = V_FILLED;
                        changed = true;
                }
                memcpy(g->state, next, n);
        }
        return 0;
}

static bool in_canvas(const struct imp_indirect *g, double x, double y) {
        return x >= g->canvas_min[0] && x <= g->canvas_max[0] &&
               y >= g->canvas_min[1] && y <= g->canvas_max[1];
}

/* 2D grid: vertices span the canvas extent exactly, at most pitch apart; each sits on the
 * traced surface lifted along z (seed 002 §2: a vertex on the surface sees only half the
 * directions). Vertices on frame samples are invalid and filled. */
static int setup_g2(struct imp_indirect *g, const struct imp_sim_surface *s, double pitch) {
        struct grid *g2 = &g->g2;
        for (int a = 0; a < 2; a++) {
                double ext = g->canvas_max[a] - g->canvas_min[a];
                int n = (int) ceil(ext / pitch - 1e-9) + 1;
                g2->n[a] = IMP_MAX(n, 2);
                g2->o[a] = g->canvas_min[a];
                g2->d[a] = ext / (g2->n[a] - 1);
        }
        g2->n[2] = 1;
        g2->d[2] = 1;
        int r = grid_alloc(g2);
        if (r < 0)
                return r;
        for (int j = 0; j < g2->n[1]; j++)
                for (int i = 0; i < g2->n[0]; i++) {
                        double x = g2->o[0] + i * g2->d[0], y = g2->o[1] + j * g2->d[1];
                        int si = (int) lround((x - s->origin_mm[0]) / s->pitch_mm);
                        int sj = (int) lround((y - s->origin_mm[1]) / s->pitch_mm);
                        si = IMP_CLAMP(si, 0, s->nx - 1);
                        sj = IMP_CLAMP(sj, 0, s->ny - 1);
                        bool frame = s->is_frame && s->is_frame[(size_t) sj * s->nx + si];
                        g2->state[grid_index(g2, i, j, 0)] = frame ? V_INVALID : V_TRACED;
                }
        return 0;
}

/* 3D grid: over the x–y box of every surface sample outside the canvas extent (the frame
 * and the step up to it), from the lowest surface height to one pitch above the frame.
 * Only vertex columns next to such samples are used; vertices below the traced surface are
 * invalid and filled. Returns 0 with has_g3 false when nothing lies outside the canvas. */
static int setup_g3(struct imp_indirect *g, const struct imp_sim_surface *s,
                    const struct hfield *hf, double pitch) {
        double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
        double ztop = -INFINITY;
        for (int j = 0; j < s->ny; j++)
                for (int i = 0; i < s->nx; i++) {
                        double x = s->origin_mm[0] + i * s->pitch_mm;
                        double y = s->origin_mm[1] + j * s->pitch_mm;
                        if (in_canvas(g, x, y))
                                continue;
                        lo[0] = fmin(lo[0], x); hi[0] = fmax(hi[0], x);
                        lo[1] = fmin(lo[1], y); hi[1] = fmax(hi[1], y);
                        ztop = fmax(ztop, s->height_mm[(size_t) j * s->nx + i]);
                }
        if (!isfinite(ztop))
                return 0;
        struct grid *g3 = &g->g3;
        double pad = s->pitch_mm;    /* covers points between samples on the step */
        for (int a = 0; a < 2; a++) {
                g3->o[a] = lo[a] - pad;
                g3->d[a] = pitch;
                g3->n[a] = (int) ceil((hi[a] - lo[a] + 2 * pad) / pitch - 1e-9) + 1;
        }
        g3->o[2] = hf->hmin;
        g3->d[2] = pitch;
        g3->n[2] = IMP_MAX((int) ceil((ztop - hf->hmin) / pitch - 1e-9) + 2, 2);
        int r = grid_alloc(g3);
        if (r < 0)
                return r;
        g->has_g3 = true;
        _cleanup_free_ uint8_t *col = calloc((size_t) g3->n[0] * g3->n[1], 1);
        if (!col)
                return -ENOMEM;
        for (int j = 0; j < s->ny; j++)
                for (int i = 0; i < s->nx; i++) {
                        double x = s->origin_mm[0] + i * s->pitch_mm;
                        double y = s->origin_mm[1] + j * s->pitch_mm;
                        if (in_canvas(g, x, y))
                                continue;
                        int ci0 = (int) floor((x - pad - g3->o[0]) / pitch);
                        int ci1 = (int) floor((x + pad - g3->o[0]) / pitch) + 1;
                        int cj0 = (int) floor((y - pad - g3->o[1]) / pitch);
                        int cj1 = (int) floor((y + pad - g3->o[1]) / pitch) + 1;
                        for (int cj = IMP_MAX(cj0, 0); cj <= IMP_MIN(cj1, g3->n[1] - 1); cj++)
                                for (int ci = IMP_MAX(ci0, 0); ci <= IMP_MIN(ci1, g3->n[0] - 1); ci++)
                                        col[(size_t) cj * g3->n[0] + ci] = 1;
                }
        for (int k = 0; k < g3->n[2]; k++)
                for (int j = 0; j < g3->n[1]; j++)
                        for (int i = 0; i < g3->n[0]; i++) {
                                if (!col[(size_t) j * g3->n[0] + i])
                                        continue;
                                double x = g3->o[0] + i * pitch, y = g3->o[1] + j * pitch;
                                double z = g3->o[2] + k * pitch;
                                bool inside = z <= hf_height(hf, x, y);
                                g3->state[grid_index(g3, i, j, k)] = inside ? V_INVALID : V_TRACED;
                        }
        return 0;
}

static void vertex_position(const struct grid *gr, const struct hfield *hf, bool is2d,
                            size_t idx, double ret[3]) {
        int p[3];
        grid_pos(gr, idx, p);
        ret[0] = gr->o[0] + p[0] * gr->d[0];
        ret[1] = gr->o[1] + p[1] * gr->d[1];
        ret[2] = is2d ? hf_height(hf, ret[0], ret[1]) + LIFT_PITCHES * hf->pitch
                      : gr->o[2] + p[2] * gr->d[2];
}

/* Traces every V_TRACED vertex of one grid. The random key depends only on the seed, the
 * grid, the vertex, the direction and the path, so the thread count does not matter. */
static void trace_grid(const struct tracer *tr, struct grid *gr, bool is2d, int paths,
                       uint64_t seed, struct imp_sim_counters *cnt) {
        uint64_t n_vert = 0, n_draws = 0;
        long n = (long) grid_count(gr);
        uint64_t grid_key = mix64(seed ^ (is2d ? 0x2d2d2d2dULL : 0x3d3d3d3dULL));
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : n_vert, n_draws)
        for (long v = 0; v < n; v++) {
                if (gr->state[v] != V_TRACED)
                        continue;
                double pos[3];
                vertex_position(gr, tr->hf, is2d, (size_t) v, pos);
                for (int dir = 0; dir < N_DIRS; dir++) {
                        uint64_t key = mix64(grid_key ^ mix64((uint64_t) v * N_DIRS + dir));
                        double e[3];
                        estimate(tr, pos, axis_normals[dir], paths, key, e, &n_draws);
                        for (int c = 0; c < 3; c++)
                                gr->vec[(size_t) v * VEC_FLOATS + dir * 3 + c] = (float) e[c];
                }
                n_vert++;
        }
        if (cnt) {
                cnt->grid_vertices += n_vert;
                cnt->indirect_paths += n_vert * N_DIRS * (uint64_t) paths;
                cnt->random_draws += n_draws;
        }
}

void imp_indirect_free(struct imp_indirect *g) {
        if (!g)
                return;
        grid_free(&g->g2);
        grid_free(&g->g3);
        free(g);
}
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_indirect *, imp_indirect_free);

static bool surface_ok(const struct imp_sim_surface *s) {
        return s && s->nx >= 2 && s->ny >= 2 && s->pitch_mm > 0 && isfinite(s->pitch_mm) &&
               s->height_mm && s->albedo && s->canvas_max_mm[0] > s->canvas_min_mm[0] &&
               s->canvas_max_mm[1] > s->canvas_min_mm[1];
}

/* Heights and albedos must be numbers: a NaN would spread through every path. */
static bool surface_finite(const struct imp_sim_surface *s) {
        for (size_t i = 0; i < (size_t) s->nx * s->ny; i++)
                if (!isfinite(s->height_mm[i]) || !isfinite(s->albedo[3 * i]) ||
                    !isfinite(s->albedo[3 * i + 1]) || !isfinite(s->albedo[3 * i + 2]))
                        return false;
        return true;
}

int imp_indirect_build(const struct imp_sim_surface *surf, const struct imp_rig_light *light,
                       const struct imp_indirect_params *p, struct imp_indirect **ret,
                       struct imp_sim_counters *cnt) {
        if (!surface_ok(surf) || !light || !p || !ret)
                return -EINVAL;
        if (!(p->canvas_pitch_mm > 0) || !(p->frame_pitch_mm > 0) || !isfinite(p->canvas_pitch_mm) ||
            !isfinite(p->frame_pitch_mm) || p->paths_per_vertex <= 0 || p->max_bounces <= 0)
                return -EINVAL;

        /* The traced geometry: every simplify-th sample (the paper's simplified mesh). */
        int s = IMP_MAX(p->simplify, 1);
        int cnx = (surf->nx - 1) / s + 1, cny = (surf->ny - 1) / s + 1;
        if (cnx < 2 || cny < 2)
                return -EINVAL;
        _cleanup_free_ float *coarse = malloc((size_t) cnx * cny * sizeof(float));
        if (!coarse)
                return -ENOMEM;
        for (int j = 0; j < cny; j++)
                for (int i = 0; i < cnx; i++)
                        coarse[(size_t) j * cnx + i] = surf->height_mm[(size_t) j * s * surf->nx + (size_t) i * s];
        _cleanup_(hf_free_blocks) struct hfield hf = { 0 }, fine = { 0 };
        hf_init(&hf, cnx, cny, surf->pitch_mm * s, surf->origin_mm[0], surf->origin_mm[1], coarse);
        hf_init(&fine, surf->nx, surf->ny, surf->pitch_mm, surf->origin_mm[0], surf->origin_mm[1],
                surf->height_mm);
        if (!surface_finite(surf))
                return -EINVAL;
        if (hf_build_blocks(&hf) < 0 || (s > 1 && hf_build_blocks(&fine) < 0))
                return -ENOMEM;

        _cleanup_(imp_indirect_freep) struct imp_indirect *g = calloc(1, sizeof *g);
        if (!g)
                return -ENOMEM;
        memcpy(g->canvas_min, surf->canvas_min_mm, sizeof g->canvas_min);
        memcpy(g->canvas_max, surf->canvas_max_mm, sizeof g->canvas_max);
        int r = setup_g2(g, surf, p->canvas_pitch_mm);
        if (r < 0)
                return r;
        r = setup_g3(g, surf, &hf, p->frame_pitch_mm);
        if (r < 0)
                return r;

        struct tracer tr = { .surf = surf, .hf = &hf, .fine = s > 1 ? &fine : NULL,
                             .max_bounces = p->max_bounces };
        light_init(&tr.light, light);
        trace_grid(&tr, &g->g2, true, p->paths_per_vertex, p->seed, cnt);
        if (g->has_g3)
                trace_grid(&tr, &g->g3, false, p->paths_per_vertex, p->seed, cnt);
        r = grid_fill(&g->g2);
        if (r >= 0 && g->has_g3)
                r = grid_fill(&g->g3);
        if (r < 0)
                return r;
        *ret = TAKE_PTR(g);
        return 0;
}

/* ---- evaluation ---- */

/* Cell index and fraction of coordinate x on an axis of n vertices; clamps to the grid and
 * snaps to a vertex when within rounding of it, so vertices reproduce exactly. */
static void axis_coord(double x, double o, double d, int n, int *ret_i, double *ret_f) {
        double f = (x - o) / d;
        double rf = nearbyint(f);
        if (fabs(f - rf) < SNAP_TOL)
                f = rf;
        f = IMP_CLAMP(f, 0.0, (double) (n - 1));
        int i = (int) f;
        if (i >= n - 1)
                i = IMP_MAX(n - 2, 0);
        *ret_i = i;
        *ret_f = n > 1 ? f - i : 0;
}

/* Interpolated six-vector at p (z ignored by the 2D grid), combined for normal n. The
 * bi/trilinear weight of a filled vertex is scaled by FILLED_WEIGHT (and of an unused one by
 * 0), then the weights renormalised: a point on the surface takes its light from the traced
 * vertices in the air around it, not from fill values that average across the surface (the
 * top of a frame next to a lit wall would glow). Still continuous: on a cell face only the
 * face's vertices weigh, and a filled vertex keeps a small weight so the sum never drops to
 * 0 while it is in use. Where every vertex is traced this is plain interpolation. */
#define FILLED_WEIGHT 1e-3
static void grid_eval(const struct grid *gr, const double p[3], const double n[3], double ret[3]) {
        int i[3];
        double f[3];
        int dims = gr->n[2] > 1 ? 3 : 2;
        for (int a = 0; a < 3; a++) {
                if (a < dims)
                        axis_coord(p[a], gr->o[a], gr->d[a], gr->n[a], &i[a], &f[a]);
                else
                        i[a] = 0, f[a] = 0;
        }
        int dsel[3] = { n[0] >= 0 ? DIR_PX : DIR_NX, n[1] >= 0 ? DIR_PY : DIR_NY,
                        n[2] >= 0 ? DIR_PZ : DIR_NZ };
        double w_axis[3] = { n[0] * n[0], n[1] * n[1], n[2] * n[2] };
        double v[3][3] = { { 0 } };      /* [axis][rgb] interpolated I_{±axis} */
        double wsum = 0;
        for (int c = 0; c < 8; c++) {
                int di = c & 1, dj = (c >> 1) & 1, dk = (c >> 2) & 1;
                if (dk && dims == 2)
                        continue;
                double w = (di ? f[0] : 1 - f[0]) * (dj ? f[1] : 1 - f[1]) *
                           (dims == 3 ? (dk ? f[2] : 1 - f[2]) : 1);
                if (w == 0)
                        continue;
                int ii = IMP_MIN(i[0] + di, gr->n[0] - 1), jj = IMP_MIN(i[1] + dj, gr->n[1] - 1);
                int kk = IMP_MIN(i[2] + dk, gr->n[2] - 1);
                size_t idx = grid_index(gr, ii, jj, kk);
                uint8_t st = gr->state[idx];
                w *= st == V_TRACED ? 1.0 : st == V_FILLED ? FILLED_WEIGHT : 0.0;
                if (w == 0)
                        continue;
                wsum += w;
                const float *vec = gr->vec + idx * VEC_FLOATS;
                for (int a = 0; a < 3; a++)
                        for (int ch = 0; ch < 3; ch++)
                                v[a][ch] += w * vec[dsel[a] * 3 + ch];
        }
        if (!(wsum > 0)) {
                ret[0] = ret[1] = ret[2] = 0;
                return;
        }
        for (int ch = 0; ch < 3; ch++)
                ret[ch] = (w_axis[0] * v[0][ch] + w_axis[1] * v[1][ch] + w_axis[2] * v[2][ch]) / wsum;
}

void imp_indirect_eval(const struct imp_indirect *g, const double p_mm[3], const double n[3],
                       float ret_rgb[3], struct imp_sim_counters *cnt) {
        ret_rgb[0] = ret_rgb[1] = ret_rgb[2] = 0;
        if (!g)
                return;
        if (cnt)
                __atomic_fetch_add(&cnt->indirect_lookups, 1, __ATOMIC_RELAXED);
        for (int a = 0; a < 3; a++)
                if (!isfinite(p_mm[a]) || !isfinite(n[a]))
                        return;    /* no light for a point that is not a point */
        const struct grid *gr = g->has_g3 && !in_canvas(g, p_mm[0], p_mm[1]) ? &g->g3 : &g->g2;
        double e[3];
        grid_eval(gr, p_mm, n, e);
        for (int c = 0; c < 3; c++)
                ret_rgb[c] = (float) fmax(e[c], 0.0);
}

/* Single bounce on the full-resolution surface, origin on the surface at p (not lifted). */
void imp_indirect_reference(const struct imp_sim_surface *surf, const struct imp_rig_light *light,
                            const double p_mm[3], const double n[3], int paths, uint64_t seed,
                            float ret_rgb[3]) {
        ret_rgb[0] = ret_rgb[1] = ret_rgb[2] = 0;
        if (!surface_ok(surf) || !light || paths <= 0)
                return;
        for (int a = 0; a < 3; a++)
                if (!isfinite(p_mm[a]) || !isfinite(n[a]))
                        return;
        _cleanup_(hf_free_blocks) struct hfield hf = { 0 };
        hf_init(&hf, surf->nx, surf->ny, surf->pitch_mm, surf->origin_mm[0], surf->origin_mm[1],
                surf->height_mm);
        (void) hf_build_blocks(&hf);      /* without blocks: slower, same answer */
        struct tracer tr = { .surf = surf, .hf = &hf, .max_bounces = 1 };
        light_init(&tr.light, light);
        double e[3];
        uint64_t draws = 0;
        estimate(&tr, p_mm, n, paths, mix64(seed ^ 0x7265665fULL), e, &draws);
        for (int c = 0; c < 3; c++)
                ret_rgb[c] = (float) e[c];
}

/* ---- accessors for tests and diagnostics ---- */

static const struct grid *pick_grid(const struct imp_indirect *g, int grid) {
        if (!g)
                return NULL;
        if (grid == 2)
                return &g->g2;
        if (grid == 3 && g->has_g3)
                return &g->g3;
        return NULL;
}

int imp_indirect_grid_size(const struct imp_indirect *g, int grid, int ret_n[3]) {
        const struct grid *gr = pick_grid(g, grid);
        if (!gr)
                return -ENOENT;
        memcpy(ret_n, gr->n, sizeof gr->n);
        return 0;
}

int imp_indirect_grid_vertex(const struct imp_indirect *g, int grid, int i, int j, int k,
                             double ret_pos_mm[3], float ret_vec[6][3], bool *ret_traced) {
        const struct grid *gr = pick_grid(g, grid);
        if (!gr)
                return -ENOENT;
        if (i < 0 || j < 0 || k < 0 || i >= gr->n[0] || j >= gr->n[1] || k >= gr->n[2])
                return -ERANGE;
        size_t v = grid_index(gr, i, j, k);
        if (ret_pos_mm) {
                ret_pos_mm[0] = gr->o[0] + i * gr->d[0];
                ret_pos_mm[1] = gr->o[1] + j * gr->d[1];
                ret_pos_mm[2] = gr->o[2] + k * gr->d[2];
        }
        if (ret_vec)
                memcpy(ret_vec, gr->vec + v * VEC_FLOATS, VEC_FLOATS * sizeof(float));
        if (ret_traced)
                *ret_traced = gr->state[v] == V_TRACED;
        return 0;
}
