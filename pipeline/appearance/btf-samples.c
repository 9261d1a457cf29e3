/* Radiance samples per heightfield texel (seed 000 §4.4): back-project each texel into
 * every frame, express view and light directions in the texel's local frame, and reject
 * what is not direct illumination — self-shadowed lights and hidden texels found by ray
 * casting on the heightfield (linear search then bisection, seed §5.2), saturated and
 * invalid pixels. Works on one tile of texels at a time. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "btf.h"
#include "hdr.h"

void imp_btf_sample_params_default(struct imp_btf_sample_params *ret) {
        *ret = (struct imp_btf_sample_params) {
                .min_cos_l = 0.02,
                .min_e_cos = 1e-6,
                .saturation_value = 0.0,
                .dark_value = -HUGE_VAL,
                .march_step_texels = 0.5,
                .march_refine = 8,
                .shadow_bias_texels = 0.05,
        };
}

int imp_btf_samples_new(int capacity_texels, int max_per_texel, struct imp_btf_samples **ret) {
        if (capacity_texels <= 0 || max_per_texel <= 0 || max_per_texel > IMP_BTF_MAX_SAMPLES)
                return -EINVAL;
        struct imp_btf_samples *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        s->capacity_texels = capacity_texels;
        s->max_per_texel = max_per_texel;
        s->count = calloc(capacity_texels, sizeof *s->count);
        s->flags = calloc(capacity_texels, sizeof *s->flags);
        s->n_shadowed = calloc(capacity_texels, sizeof *s->n_shadowed);
        s->samples = malloc((size_t) capacity_texels * max_per_texel * sizeof *s->samples);
        if (!s->count || !s->flags || !s->n_shadowed || !s->samples) {
                imp_btf_samples_free(s);
                return -ENOMEM;
        }
        *ret = s;
        return 0;
}

void imp_btf_samples_free(struct imp_btf_samples *s) {
        if (!s)
                return;
        free(s->count);
        free(s->flags);
        free(s->n_shadowed);
        free(s->samples);
        free(s);
}

int imp_btf_rays_new(int width, int height, int n_lights, struct imp_btf_rays **ret) {
        if (width <= 0 || height <= 0 || n_lights <= 0 || n_lights > IMP_BTF_MAX_SAMPLES || !ret)
                return -EINVAL;
        struct imp_btf_rays *r = calloc(1, sizeof *r);
        if (!r)
                return -ENOMEM;
        size_t nt = (size_t) width * height;
        *r = (struct imp_btf_rays) { .width = width, .height = height, .n_lights = n_lights,
                                     .words = (n_lights + 63) / 64 };
        r->known = calloc(nt * r->words, sizeof *r->known);
        r->blocked = calloc(nt * r->words, sizeof *r->blocked);
        r->camera = calloc(nt, sizeof *r->camera);
        if (!r->known || !r->blocked || !r->camera) {
                imp_btf_rays_free(r);
                return -ENOMEM;
        }
        *ret = r;
        return 0;
}

void imp_btf_rays_free(struct imp_btf_rays *r) {
        if (!r)
                return;
        free(r->known);
        free(r->blocked);
        free(r->camera);
        free(r);
}

double imp_btf_light_irradiance(const struct imp_rig_light *light, const double X[3]) {
        double d[3] = { X[0] - light->pos_mm[0], X[1] - light->pos_mm[1], X[2] - light->pos_mm[2] };
        double r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if (!(r2 > 0.0))
                return 0.0;
        double e = light->intensity * 1e6 / r2;
        if (light->profile_exp != 0.0) {
                double c = (d[0] * light->axis[0] + d[1] * light->axis[1] + d[2] * light->axis[2]) / sqrt(r2);
                double pe = light->profile_exp;
                e *= !(c > 0.0) ? 0.0 : pe == 1.0 ? c : pe == 2.0 ? c * c : pow(c, pe);
        }
        return e;
}

/* ---- geometry helpers ---------------------------------------------------------- */

/* Rigid 4×4 (row-major) → rotation R, translation t; false when not rigid. */
static bool rigid_parts(const double M[16], double R[9], double t[3]) {
        for (int i = 0; i < 3; i++) {
                for (int j = 0; j < 3; j++)
                        R[3 * i + j] = M[4 * i + j];
                t[i] = M[4 * i + 3];
        }
        if (fabs(M[12]) + fabs(M[13]) + fabs(M[14]) + fabs(M[15] - 1.0) > 1e-12)
                return false;
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        double dot = R[i] * R[j] + R[3 + i] * R[3 + j] + R[6 + i] * R[6 + j];
                        if (!(fabs(dot - (i == j)) < 1e-6))
                                return false;
                }
        return true;
}

static void mat_apply(const double R[9], const double t[3], const double x[3], double ret[3]) {
        for (int i = 0; i < 3; i++)
                ret[i] = R[3 * i] * x[0] + R[3 * i + 1] * x[1] + R[3 * i + 2] * x[2] + t[i];
}

/* World → canvas: Rᵀ (x − t). */
static void mat_apply_inv(const double R[9], const double t[3], const double x[3], double ret[3]) {
        double y[3] = { x[0] - t[0], x[1] - t[1], x[2] - t[2] };
        for (int i = 0; i < 3; i++)
                ret[i] = R[i] * y[0] + R[3 + i] * y[1] + R[6 + i] * y[2];
}

/* ---- ray casting on the heightfield (canvas frame) ------------------------------- */

double imp_btf_heightfield_hmax(const struct imp_btf_heightfield *hf) {
        double hmax = -HUGE_VAL;
        size_t n = (size_t) hf->width * hf->height;
        for (size_t i = 0; i < n; i++)
                if (isfinite(hf->height_mm[i]) && hf->height_mm[i] > hmax)
                        hmax = hf->height_mm[i];
        return hmax;
}

/* Bilinear height at texel coordinates (fu, fv); false outside the grid. Non-finite →
 * -HUGE_VAL. */
static bool height_at_texel(const struct imp_btf_heightfield *hf, double fu, double fv, double *ret) {
        if (!(fu >= 0.0 && fv >= 0.0 && fu <= hf->width - 1 && fv <= hf->height - 1))
                return false;
        int u = IMP_MIN((int) fu, hf->width - 2), v = IMP_MIN((int) fv, hf->height - 2);
        u = IMP_MAX(u, 0);
        v = IMP_MAX(v, 0);
        double a = fu - u, b = fv - v;
        const float *h0 = hf->height_mm + (size_t) v * hf->width + u;
        const float *h1 = hf->width > 1 ? h0 + 1 : h0;
        const float *h2 = hf->height > 1 ? h0 + hf->width : h0;
        const float *h3 = hf->height > 1 ? h1 + hf->width : h1;
        double h = (1 - b) * ((1 - a) * *h0 + a * *h1) + b * ((1 - a) * *h2 + a * *h3);
        *ret = isfinite(h) ? h : -HUGE_VAL;
        return true;
}

/* A max pyramid over the cells of the heightfield: cell (u, v) spans texels u..u+1 ×
 * v..v+1 and holds the largest finite corner height (the bilinear surface over the cell
 * never exceeds it; -inf when no corner is finite: non-finite heights never occlude);
 * level L holds the maxima of 2^L × 2^L cells. It lets the ray march skip, exactly, the
 * sample points that lie above every height of the block they cross. */
#define PYR_LEVELS_MAX 16
struct imp_btf_hf_pyramid {
        const float *height_mm;       /* the heightfield it was built from (identity check) */
        int width, height;
        int levels;                   /* 0: no pyramid (grid narrower than 2 texels) */
        int lw[PYR_LEVELS_MAX], lh[PYR_LEVELS_MAX];
        float *lvl[PYR_LEVELS_MAX];   /* one allocation, lvl[0] owns it */
        double hmax;                  /* highest finite height (-HUGE_VAL: none) */
        struct imp_btf_horizon *hz;   /* conservative horizon for bias 0 (btf-horizon.c) */
};

void imp_btf_hf_pyramid_free(struct imp_btf_hf_pyramid *py) {
        if (!py)
                return;
        imp_btf_horizon_free(py->hz);
        free(py->lvl[0]);
        free(py);
}

static float max4(float a, float b, float c, float d) {
        float m = a > b ? a : b, n = c > d ? c : d;
        return m > n ? m : n;
}

int imp_btf_hf_pyramid_new(const struct imp_btf_heightfield *hf, struct imp_btf_hf_pyramid **ret) {
        return imp_btf_hf_pyramid_new_horizon(hf, true, ret);
}

int imp_btf_hf_pyramid_new_horizon(const struct imp_btf_heightfield *hf, bool horizon,
                                   struct imp_btf_hf_pyramid **ret) {
        if (!hf || !ret || hf->width <= 0 || hf->height <= 0 || !hf->height_mm)
                return -EINVAL;
        struct imp_btf_hf_pyramid *py = calloc(1, sizeof *py);
        if (!py)
                return -ENOMEM;
        py->height_mm = hf->height_mm;
        py->width = hf->width;
        py->height = hf->height;
        int r = horizon ? imp_btf_horizon_new(hf, 0.0, &py->hz) : 0;
        if (r < 0) {
                free(py);
                return r;
        }
        if (hf->width < 2 || hf->height < 2) {
                py->hmax = imp_btf_heightfield_hmax(hf);
                *ret = py;
                return 0;
        }
        size_t total = 0;
        int w = hf->width - 1, h = hf->height - 1, n = 0;
        for (;;) {
                py->lw[n] = w;
                py->lh[n] = h;
                total += (size_t) w * h;
                n++;
                if ((w == 1 && h == 1) || n == PYR_LEVELS_MAX)
                        break;
                w = (w + 1) / 2;
                h = (h + 1) / 2;
        }
        float *buf = malloc(total * sizeof *buf);
        if (!buf) {
                imp_btf_hf_pyramid_free(py);
                return -ENOMEM;
        }
        py->levels = n;
        size_t off = 0;
        for (int L = 0; L < n; off += (size_t) py->lw[L] * py->lh[L], L++)
                py->lvl[L] = buf + off;
        const int W = hf->width, cw = py->lw[0];
#pragma omp parallel for schedule(static)
        for (int v = 0; v < py->lh[0]; v++)
                for (int u = 0; u < cw; u++) {
                        const float *q = hf->height_mm + (size_t) v * W + u;
                        float c[4] = { q[0], q[1], q[W], q[W + 1] }, m = -HUGE_VALF;
                        for (int i = 0; i < 4; i++)
                                if (isfinite(c[i]) && c[i] > m)
                                        m = c[i];
                        py->lvl[0][(size_t) v * cw + u] = m;
                }
        for (int L = 1; L < n; L++) {
                const float *src = py->lvl[L - 1];
                int sw = py->lw[L - 1], sh = py->lh[L - 1];
                for (int v = 0; v < py->lh[L]; v++)
                        for (int u = 0; u < py->lw[L]; u++) {
                                int u0 = 2 * u, v0 = 2 * v, u1 = IMP_MIN(u0 + 1, sw - 1), v1 = IMP_MIN(v0 + 1, sh - 1);
                                py->lvl[L][(size_t) v * py->lw[L] + u] =
                                        max4(src[(size_t) v0 * sw + u0], src[(size_t) v0 * sw + u1],
                                             src[(size_t) v1 * sw + u0], src[(size_t) v1 * sw + u1]);
                        }
        }
        /* The top cell covers the grid: the highest finite height (-inf: none). */
        py->hmax = py->lvl[n - 1][0];
        *ret = py;
        return 0;
}

/* floor(te / step) + 1 for te > 0, the quotient rounded as the division rounds it: from
 * te · istep (istep = 1 / step, a multiplication instead of the division in the march's
 * dependent chain) when that lies well clear of an integer — its error, a few ulp, is then
 * below the distance and the floor is the same — else from the division. */
static inline long next_point(double te, double step, double istep) {
        double q = te * istep;
        long k = (long) q;
        double f = q - (double) k;
        if (q < 1e6 && f > 1e-6 && f < 1.0 - 1e-6)
                return k + 1;
        return (long) (te / step) + 1;
}

/* The ray march of imp_btf_heightfield_ray(); py may be NULL (plain march). Sample point
 * k sits at t = k·step. With a pyramid, a block of cells is skipped when the lowest point
 * of the ray inside it is no lower than the block's maximum minus the bias: no sample
 * point there can be blocked, and leaving the grid or rising above hmax_mm cannot be
 * undone further along (the grid is convex; z rises monotonically when d[2] ≥ 0, and
 * with d[2] < 0 the first point already decides it). Hits are thus those of the plain
 * march. The level walk goes up after a skip and down after a miss. The march starts at
 * sample point k0 ≥ 1: a caller passes k0 > 1 only when no point before it can be a hit
 * (the same monotonicity makes the result the plain march's). */
static bool march(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *p,
                  const struct imp_btf_hf_pyramid *py, double hmax_mm, const double o[3], const double d[3],
                  double max_t_mm, long k0, double *ret_t_mm) {
        double step = p->march_step_texels * hf->pitch_mm;
        double bias = p->shadow_bias_texels * hf->pitch_mm;
        double ip = 1.0 / hf->pitch_mm;
        if (!(step > 0.0))
                return false;
        const double istep = 1.0 / step;
        int levels = py ? py->levels : 0, L = levels > 0 ? IMP_MIN(levels - 1, 2) : -1;
        /* Texel-space ray: fu = ou + t·du. */
        double ou = o[0] * ip, ov = o[1] * ip, du = d[0] * ip, dv = d[1] * ip;
        double iu = du != 0.0 ? 1.0 / du : HUGE_VAL, iv = dv != 0.0 ? 1.0 / dv : HUGE_VAL;
        for (long k = k0;; ) {
                double t = k * step;
                if (!(t <= max_t_mm))
                        return false;
                double fu = ou + t * du, fv = ov + t * dv, z = o[2] + t * d[2];
                if (z > hmax_mm)
                        return false;
                if (!(fu >= 0.0 && fv >= 0.0 && fu <= hf->width - 1 && fv <= hf->height - 1))
                        return false;
                if (L >= 0) {
                        int cu = IMP_MIN((int) fu, py->lw[0] - 1), cv = IMP_MIN((int) fv, py->lh[0] - 1);
                        bool skipped = false;
                        while (L >= 0) {
                                int bu = cu >> L, bv = cv >> L;
                                /* The block's extent in texel coordinates, clipped to the grid. */
                                int uhi = IMP_MIN((bu + 1) << L, hf->width - 1), vhi = IMP_MIN((bv + 1) << L, hf->height - 1);
                                double te = max_t_mm, tu = HUGE_VAL, tv = HUGE_VAL;
                                if (du != 0.0)
                                        tu = ((du > 0.0 ? uhi : bu << L) - ou) * iu;
                                if (dv != 0.0)
                                        tv = ((dv > 0.0 ? vhi : bv << L) - ov) * iv;
                                te = tu < te ? tu : te;
                                te = tv < te ? tv : te;
                                double zmin = d[2] >= 0.0 ? z : o[2] + te * d[2];
                                if (te >= t && zmin >= (double) py->lvl[L][(size_t) bv * py->lw[L] + bu] - bias) {
                                        long kn = next_point(te, step, istep);
                                        k = kn > k ? kn : k + 1;
                                        L = IMP_MIN(L + 1, levels - 1);
                                        skipped = true;
                                        break;
                                }
                                L--;
                        }
                        if (skipped)
                                continue;
                        L = 0;
                }
                double h;
                (void) height_at_texel(hf, fu, fv, &h);
                if (z < h - bias) {
                        if (!ret_t_mm)   /* no hit point asked (the extractor's tests): no bisection */
                                return true;
                        /* Bisection between the last point above and the first below. */
                        double lo = (k - 1) * step, hi = t;
                        for (int i = 0; i < p->march_refine; i++) {
                                double m = 0.5 * (lo + hi), hm;
                                if (height_at_texel(hf, ou + m * du, ov + m * dv, &hm) && o[2] + m * d[2] < hm - bias)
                                        hi = m;
                                else
                                        lo = m;
                        }
                        *ret_t_mm = hi;
                        return true;
                }
                k++;
        }
}

bool imp_btf_heightfield_ray(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *p,
                             double hmax_mm, const double o[3], const double d[3], double max_t_mm,
                             double *ret_t_mm) {
        return march(hf, p, NULL, hmax_mm, o, d, max_t_mm, 1, ret_t_mm);
}

/* ---- frames ------------------------------------------------------------------ */

int imp_btf_valid_from_hdr(const struct imp_image *hdr_flags, struct imp_image **ret) {
        if (!hdr_flags || hdr_flags->type != IMP_PIX_U8 || !ret)
                return -EINVAL;
        struct imp_image *v;
        int r = imp_image_new(hdr_flags->width, hdr_flags->height, 1, IMP_PIX_U8, &v);
        if (r < 0)
                return r;
        for (int y = 0; y < hdr_flags->height; y++)
                for (int x = 0; x < hdr_flags->width; x++) {
                        const uint8_t *f = imp_image_u8(hdr_flags, x, y);
                        uint8_t o = 0;
                        for (int c = 0; c < hdr_flags->channels; c++) {
                                if (f[c] & IMP_HDR_SATURATED)
                                        o |= IMP_BTF_PIX_SATURATED;
                                if (f[c] & IMP_HDR_DARK)
                                        o |= IMP_BTF_PIX_INVALID;
                        }
                        *imp_image_u8(v, x, y) = o;
                }
        *ret = v;
        return 0;
}

enum { PIX_OK, PIX_SATURATED, PIX_INVALID };

/* The bilinear taps of pixel position px (pixel centres at integers): the same for every
 * light of a texel, so formed once per texel. */
struct taps {
        int xs[2], ys[2];
        double w[4];
};

static void bilinear_taps(int width, int height, const double px[2], struct taps *t) {
        int x0 = (int) floor(px[0]), y0 = (int) floor(px[1]);
        double a = px[0] - x0, b = px[1] - y0;
        t->xs[0] = x0;
        t->xs[1] = IMP_MIN(x0 + 1, width - 1);
        t->ys[0] = y0;
        t->ys[1] = IMP_MIN(y0 + 1, height - 1);
        t->w[0] = (1 - a) * (1 - b);
        t->w[1] = a * (1 - b);
        t->w[2] = (1 - a) * b;
        t->w[3] = a * b;
}

/* Bilinear value of frame f at the taps t. */
static int frame_sample(const struct imp_image *f, const struct imp_image *valid, double sat,
                        const struct taps *t, float ret[3]) {
        double acc[3] = { 0, 0, 0 };
        int state = PIX_OK;
        for (int k = 0; k < 4; k++) {
                int x = t->xs[k & 1], y = t->ys[k >> 1];
                const float *q = imp_image_f32(f, x, y);
                for (int c = 0; c < 3; c++) {
                        double val = q[f->channels == 3 ? c : 0];
                        if (!isfinite(val))
                                return PIX_INVALID;
                        if (sat > 0.0 && val >= sat)
                                state = PIX_SATURATED;
                        acc[c] += t->w[k] * val;
                }
                if (valid) {
                        uint8_t fl = *imp_image_u8(valid, x, y);
                        if (fl & IMP_BTF_PIX_SATURATED)
                                state = PIX_SATURATED;
                        else if (fl && state == PIX_OK)
                                state = PIX_INVALID;
                }
        }
        for (int c = 0; c < 3; c++)
                ret[c] = (float) acc[c];
        return state;
}

/* A pixel's tap state in the band (one light): frame_sample()'s decisions on that tap. */
enum {
        TAP_NONFINITE = 1 << 0,       /* the value is not finite */
        TAP_SATURATED = 1 << 1,       /* value ≥ saturation_value, or masked saturated */
        TAP_MASKED    = 1 << 2,       /* any validity bit */
};

/* frame_sample() of light j from the band (t inside its box): the OR of the four taps'
 * states gives its decision (a non-finite tap returns at once there, whatever the other
 * taps; else a saturated one wins over a masked one), and the value is summed in its order
 * from the same floats (the band holds the frame's value wherever no bit is set). ret
 * NULL: the decision alone, no value read. */
static int band_sample(const struct imp_btf_band *b, const struct taps *t, int j, float ret[3]) {
        const size_t L = b->L;
        size_t o[4];
        for (int k = 0; k < 4; k++)
                o[k] = ((size_t) (t->ys[k >> 1] - b->y0) * b->cols + (t->xs[k & 1] - b->x0)) * L + j;
        unsigned s = b->st[o[0]] | b->st[o[1]] | b->st[o[2]] | b->st[o[3]];
        if (s & TAP_NONFINITE)
                return PIX_INVALID;
        if (s & TAP_SATURATED)
                return PIX_SATURATED;
        if (s)
                return PIX_INVALID;
        if (!ret)   /* the decision only: the caller has the value */
                return PIX_OK;
        double acc = 0;
        for (int k = 0; k < 4; k++)
                acc += t->w[k] * (double) b->v[o[k]];
        ret[0] = ret[1] = ret[2] = (float) acc;
        return PIX_OK;
}

static int check_capture(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap) {
        if (!hf || !cap || !cap->camera || !cap->lights || !cap->frames || hf->width <= 0 ||
            hf->height <= 0 || !(hf->pitch_mm > 0.0) || !hf->height_mm || !hf->normal)
                return -EINVAL;
        if (cap->n_lights <= 0 || cap->n_lights > IMP_BTF_MAX_SAMPLES)
                return -E2BIG;
        const struct imp_pinhole *m = cap->camera;
        for (int i = 0; i < cap->n_lights; i++) {
                const struct imp_image *f = cap->frames[i];
                if (!f || f->type != IMP_PIX_F32 || (f->channels != 1 && f->channels != 3) ||
                    f->width != m->width || f->height != m->height)
                        return -EINVAL;
                const struct imp_image *v = cap->valid ? cap->valid[i] : NULL;
                if (v && (v->type != IMP_PIX_U8 || v->width != f->width || v->height != f->height))
                        return -EINVAL;
        }
        return 0;
}

/* Everything per light and per capture that does not depend on the texel. */
struct scene {
        double R[9], t[3];            /* canvas → world */
        double cam_c[3];              /* camera centre, canvas frame */
        double hmax;
        const struct imp_btf_hf_pyramid *py;  /* levels = 0: plain march */
        const struct imp_btf_horizon *hz;     /* rays it clears are not marched */
        double (*light_c)[3];         /* light positions, canvas frame */
        double colour_inv[IMP_BTF_MAX_SAMPLES][3];
        const double *lt;             /* the lights' LT_* rows of n_lights each (light_table()) */
        bool any_pow;                 /* a light's profile exponent needs pow() */
};

/* The lights by field, a row of n_lights doubles each, for light_geometry()'s lanes. */
enum { LT_CX, LT_CY, LT_CZ, LT_WX, LT_WY, LT_WZ, LT_I6, LT_AX, LT_AY, LT_AZ, LT_PE, LT_ROWS };

/* The lights' geometry at one texel, LIGHT_CHUNK lights at a time: the direction wl
 * (canvas frame, unit), distance r, local direction lloc, irradiance e (at normal
 * incidence) and horizontal run of each, as the loop of extract_texel(),
 * imp_btf_light_irradiance() and imp_btf_horizon_clear() compute them one light at a time
 * (the same operations in the same order, so the same values), in vector lanes: one
 * light's square roots and divisions are a dependent chain, LIGHT_CHUNK lights' are not. */
#define LIGHT_CHUNK 64
struct light_geo {
        double wl[3][LIGHT_CHUNK], r[LIGHT_CHUNK], lloc[3][LIGHT_CHUNK], e[LIGHT_CHUNK];
        double run[LIGHT_CHUNK];      /* √(wl₀² + wl₁²), imp_btf_horizon_clear()'s */
        double rr[LIGHT_CHUNK], r2[LIGHT_CHUNK], s2[LIGHT_CHUNK], dot[LIGHT_CHUNK];   /* scratch */
};

/* x[k] = sqrt(src[k]), k < n, in the lanes of the caller's target (its no-math-errno lets
 * gcc vectorise sqrt(); the instruction rounds as sqrt() does). */
#define SQRT_LANES(src, x, n)                                   \
        _Pragma("omp simd")                                     \
        for (int k_ = 0; k_ < (n); k_++)                        \
                (x)[k_] = sqrt((src)[k_])

/* Built for AVX-512, AVX2 and the baseline, the CPU picks at load time; no FMA contraction
 * (the same operations, rounded the same, on every machine). gcc 12 if-converts the
 * selects only with no-trapping-math. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define LG_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define LG_CLONES
#endif
LG_CLONES __attribute__((optimize("no-trapping-math", "no-math-errno", "fp-contract=off")))
static void light_geometry(const struct scene *sc, int n_lights, int j0, int nj, const double P[3],
                           const double Pw[3], const double tb[3], const double bb[3], const double n[3],
                           struct light_geo *g) {
        const double *lt = sc->lt + j0;
        const size_t L = (size_t) n_lights;
#pragma omp simd
        for (int k = 0; k < nj; k++) {
                double w0 = lt[LT_CX * L + k] - P[0], w1 = lt[LT_CY * L + k] - P[1], w2 = lt[LT_CZ * L + k] - P[2];
                g->wl[0][k] = w0, g->wl[1][k] = w1, g->wl[2][k] = w2;
                g->rr[k] = w0 * w0 + w1 * w1 + w2 * w2;
                /* imp_btf_light_irradiance()'s d = X − pos */
                double d0 = Pw[0] - lt[LT_WX * L + k], d1 = Pw[1] - lt[LT_WY * L + k], d2 = Pw[2] - lt[LT_WZ * L + k];
                g->r2[k] = d0 * d0 + d1 * d1 + d2 * d2;
                g->dot[k] = d0 * lt[LT_AX * L + k] + d1 * lt[LT_AY * L + k] + d2 * lt[LT_AZ * L + k];
        }
        SQRT_LANES(g->rr, g->r, nj);
        SQRT_LANES(g->r2, g->s2, nj);   /* r2: the irradiance's squared distance, s2: its root */
#pragma omp simd
        for (int k = 0; k < nj; k++) {
                double r = g->r[k], w0 = g->wl[0][k] / r, w1 = g->wl[1][k] / r, w2 = g->wl[2][k] / r;
                g->wl[0][k] = w0, g->wl[1][k] = w1, g->wl[2][k] = w2;
                g->lloc[0][k] = tb[0] * w0 + tb[1] * w1 + tb[2] * w2;
                g->lloc[1][k] = bb[0] * w0 + bb[1] * w1 + bb[2] * w2;
                g->lloc[2][k] = n[0] * w0 + n[1] * w1 + n[2] * w2;
                double r2 = g->r2[k], pe = lt[LT_PE * L + k];
                double e = lt[LT_I6 * L + k] / r2, c = g->dot[k] / g->s2[k];
                double f = !(c > 0.0) ? 0.0 : pe == 1.0 ? c : c * c;   /* pe 2 (others: any_pow) */
                e = pe != 0.0 ? e * f : e;
                g->e[k] = r2 > 0.0 ? e : 0.0;
                g->rr[k] = w0 * w0 + w1 * w1;
        }
        SQRT_LANES(g->rr, g->run, nj);
}

/* Texel idx's record in p->rays (struct imp_btf_rays): mode OFF when there is none; a
 * recording starts the texel undecided. */
struct ray_rec {
        int mode;
        uint64_t *known, *blocked;
        uint8_t *cam;
};

static void ray_rec_of(const struct imp_btf_sample_params *p, size_t idx, struct ray_rec *rr) {
        struct imp_btf_rays *r = p->rays;
        *rr = (struct ray_rec) { .mode = r ? p->rays_mode : IMP_BTF_RAYS_OFF };
        if (rr->mode == IMP_BTF_RAYS_OFF)
                return;
        rr->known = r->known + idx * r->words;
        rr->blocked = r->blocked + idx * r->words;
        rr->cam = r->camera + idx;
        if (rr->mode == IMP_BTF_RAYS_RECORD) {
                memset(rr->known, 0, r->words * sizeof *rr->known);
                memset(rr->blocked, 0, r->words * sizeof *rr->blocked);
                *rr->cam = IMP_BTF_CAM_UNKNOWN;
        }
}

/* A texel's horizon (imp_btf_horizon_split()): have false when the scene has none. */
struct texel_hz {
        bool have;
        float near[4], far[4];
};

/* The shadow or visibility ray from P along unit d (horizontal length run =
 * √(d₀² + d₁²), as imp_btf_horizon_clear() computes it) to distance max_t: blocked? The
 * horizon's two parts decide it without a march when the ray is at least as steep as both;
 * as steep as the near part only, the march starts at the last sample point 2 steps short
 * of IMP_BTF_HORIZON_SPLIT texels of run (no point before can be blocked); as steep as the
 * far part only, it stops one texel of run beyond them (no point after can be). Either way
 * the decision is the plain march's. */
static bool ray_blocked(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *p,
                        const struct scene *sc, const struct texel_hz *th, const double P[3], const double d[3],
                        double run, double max_t) {
        long k0 = 1;
        if (th->have && d[2] > 0.0) {
                int q = (d[0] < 0.0) | (d[1] < 0.0) << 1;
                bool near = d[2] >= (double) th->near[q] * run, far = d[2] >= (double) th->far[q] * run;
                if (near && far)
                        return false;
                /* run > 0 here: with run 0 both hold. */
                double split_mm = IMP_BTF_HORIZON_SPLIT * hf->pitch_mm;
                if (near) {
                        double x = fmin(split_mm / (p->march_step_texels * hf->pitch_mm * run), 1e15);
                        k0 = IMP_MAX((long) x, 1L);
                } else if (far)
                        max_t = fmin(max_t, split_mm / run * (1.0 + 1e-9));
        }
        return march(hf, p, sc->py, sc->hmax, P, d, max_t, k0, NULL);
}

/* The camera ray of texel (u, v) from P (direction wv, distance dist_c): blocked? From the
 * record when it has the decision, else marched (and recorded when recording). */
static bool camera_blocked(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *p,
                           const struct scene *sc, const struct ray_rec *rr, const struct texel_hz *th,
                           const double P[3], const double wv[3], double dist_c) {
        if (rr->mode == IMP_BTF_RAYS_REUSE && *rr->cam != IMP_BTF_CAM_UNKNOWN)
                return *rr->cam == IMP_BTF_CAM_BLOCKED;
        bool blocked = ray_blocked(hf, p, sc, th, P, wv, sqrt(wv[0] * wv[0] + wv[1] * wv[1]), dist_c);
        if (rr->mode == IMP_BTF_RAYS_RECORD)
                *rr->cam = blocked ? IMP_BTF_CAM_BLOCKED : IMP_BTF_CAM_CLEAR;
        return blocked;
}

/* Values given by the caller (imp_btf_extract_texel_given()): value[j] for light j when
 * ok[j]. */
struct given {
        const float (*value)[3];
        const uint8_t *ok;
};

/* The pixel reading of light j at the taps into val (its value when g gives none): the
 * decision PIX_*. With a value given, from the band, and no dark test to feed, only the
 * taps' states are read. */
static int read_light(const struct imp_btf_capture *cap, const struct imp_btf_sample_params *p,
                      const struct imp_btf_band *b, bool in_band, const struct given *g, const struct taps *tp,
                      int j, const struct scene *sc, float val[3]) {
        bool have = g && g->ok[j], skip = have && in_band && !(p->dark_value > -HUGE_VAL);
        int st = in_band ? band_sample(b, tp, j, skip ? NULL : val)
                         : frame_sample(cap->frames[j], cap->valid ? cap->valid[j] : NULL, p->saturation_value, tp,
                                        val);
        if (st != PIX_OK || (!skip && val[0] < p->dark_value && val[1] < p->dark_value && val[2] < p->dark_value))
                return st == PIX_OK ? PIX_INVALID : st;
        for (int c = 0; c < 3; c++)
                val[c] = have ? g->value[j][c] : (float) (val[c] * sc->colour_inv[j][c]);
        return PIX_OK;
}

static void extract_texel(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                          const struct imp_btf_sample_params *p, const struct scene *sc,
                          const struct imp_btf_band *b, const struct given *g, int u, int v,
                          struct imp_btf_sample *out, uint16_t *ret_light, uint16_t *ret_count, uint16_t *ret_flags,
                          uint16_t *ret_shadowed) {
        size_t idx = (size_t) v * hf->width + u;
        const float *nf = hf->normal + 3 * idx;
        double n[3] = { nf[0], nf[1], nf[2] };
        double nl = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        int count = 0, shadowed = 0;
        uint16_t flags = 0;

        *ret_count = 0;
        *ret_shadowed = 0;
        struct ray_rec rr;
        ray_rec_of(p, idx, &rr);
        if ((hf->mask && !hf->mask[idx]) || !isfinite(hf->height_mm[idx]) || !(nl > 0.5 && nl < 2.0)) {
                *ret_flags = IMP_BTF_MASKED;
                return;
        }
        for (int i = 0; i < 3; i++)
                n[i] /= nl;
        double P[3] = { u * hf->pitch_mm, v * hf->pitch_mm, hf->height_mm[idx] }, Pw[3], px[2];
        double tb[3], bb[3], wv[3], vloc[3];
        imp_local_frame(n, tb, bb);
        struct texel_hz th;
        th.have = imp_btf_horizon_split(sc->hz, u, v, th.near, th.far);

        double dist_c = 0.0;
        for (int i = 0; i < 3; i++) {
                wv[i] = sc->cam_c[i] - P[i];
                dist_c += wv[i] * wv[i];
        }
        dist_c = sqrt(dist_c);
        for (int i = 0; i < 3; i++)
                wv[i] /= dist_c;
        imp_to_local(tb, bb, n, wv, vloc);
        mat_apply(sc->R, sc->t, P, Pw);
        if (!(vloc[2] > 0.0) || !imp_pinhole_project(cap->camera, Pw, px) || !(px[0] >= 0.0 && px[1] >= 0.0 &&
            px[0] <= cap->camera->width - 1 && px[1] <= cap->camera->height - 1) ||
            camera_blocked(hf, p, sc, &rr, &th, P, wv, dist_c)) {
                *ret_flags = IMP_BTF_HIDDEN;
                return;
        }
        struct taps tp;
        bilinear_taps(cap->camera->width, cap->camera->height, px, &tp);
        bool in_band = b && tp.xs[0] >= b->x0 && tp.ys[0] >= b->y0 && tp.xs[1] < b->x0 + b->cols &&
                       tp.ys[1] < b->y0 + b->rows;

        struct light_geo lg;
        for (int j = 0; j < cap->n_lights; j++) {
                int k = j % LIGHT_CHUNK;
                if (k == 0)
                        light_geometry(sc, cap->n_lights, j, IMP_MIN(LIGHT_CHUNK, cap->n_lights - j), P, Pw, tb, bb,
                                       n, &lg);
                double wl[3] = { lg.wl[0][k], lg.wl[1][k], lg.wl[2][k] };
                double lloc[3] = { lg.lloc[0][k], lg.lloc[1][k], lg.lloc[2][k] };
                if (!(lloc[2] >= p->min_cos_l))
                        continue;
                double irr = sc->any_pow ? imp_btf_light_irradiance(&cap->lights[j], Pw) : lg.e[k];
                double e_cos = irr * lloc[2];
                if (!(e_cos >= p->min_e_cos))
                        continue;
                uint64_t bit = (uint64_t) 1 << (j & 63);
                bool blocked;
                if (rr.mode == IMP_BTF_RAYS_REUSE && (rr.known[j >> 6] & bit))
                        blocked = rr.blocked[j >> 6] & bit;
                else {
                        blocked = ray_blocked(hf, p, sc, &th, P, wl, lg.run[k], lg.r[k]);
                        if (rr.mode == IMP_BTF_RAYS_RECORD) {
                                rr.known[j >> 6] |= bit;
                                rr.blocked[j >> 6] |= blocked ? bit : 0;
                        }
                }
                if (blocked) {
                        shadowed++;
                        continue;
                }
                float val[3];
                int st = read_light(cap, p, b, in_band, g, &tp, j, sc, val);
                if (st == PIX_SATURATED)
                        flags |= IMP_BTF_SATURATED;
                if (st != PIX_OK)
                        continue;
                if (ret_light)
                        ret_light[count] = (uint16_t) j;
                struct imp_btf_sample *s = &out[count++];
                for (int i = 0; i < 3; i++) {
                        s->v[i] = (float) vloc[i];
                        s->l[i] = (float) lloc[i];
                        s->value[i] = val[i];
                }
                s->e_cos = (float) e_cos;
        }
        *ret_count = (uint16_t) count;
        *ret_flags = flags;
        *ret_shadowed = (uint16_t) shadowed;
}

int imp_btf_samples_extract(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *p, int x0, int y0, int w, int h,
                            struct imp_btf_samples *out) {
        if (!hf)
                return -EINVAL;
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        int r = imp_btf_hf_pyramid_new(hf, &py);
        if (r < 0)
                return r;
        return imp_btf_samples_extract_pyramid(hf, cap, p, py, x0, y0, w, h, out);
}

struct imp_btf_extractor {
        const struct imp_btf_heightfield *hf;
        const struct imp_btf_capture *cap;
        struct imp_btf_sample_params p;
        struct scene sc;
        double (*light_c)[3];
        double *lt;
};

void imp_btf_extractor_free(struct imp_btf_extractor *x) {
        if (!x)
                return;
        free(x->light_c);
        free(x->lt);
        free(x);
}

/* sc's light table (its light_c set): the rows of enum LT_*. */
static void light_table(const struct imp_btf_capture *cap, struct scene *sc, double *lt) {
        const size_t L = (size_t) cap->n_lights;
        sc->any_pow = false;
        for (size_t j = 0; j < L; j++) {
                const struct imp_rig_light *l = &cap->lights[j];
                const double row[LT_ROWS] = { sc->light_c[j][0], sc->light_c[j][1], sc->light_c[j][2], l->pos_mm[0],
                                              l->pos_mm[1], l->pos_mm[2], l->intensity * 1e6, l->axis[0], l->axis[1],
                                              l->axis[2], l->profile_exp };
                for (int f = 0; f < LT_ROWS; f++)
                        lt[f * L + j] = row[f];
                sc->any_pow |= l->profile_exp != 0.0 && l->profile_exp != 1.0 && l->profile_exp != 2.0;
        }
        sc->lt = lt;
}

int imp_btf_extractor_new(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                          const struct imp_btf_sample_params *p, const struct imp_btf_hf_pyramid *py,
                          struct imp_btf_extractor **ret) {
        int r = check_capture(hf, cap);
        if (r < 0)
                return r;
        if (!p || !py || !ret || py->height_mm != hf->height_mm || py->width != hf->width || py->height != hf->height)
                return -EINVAL;
        if (p->rays && p->rays_mode != IMP_BTF_RAYS_OFF &&
            ((p->rays_mode != IMP_BTF_RAYS_RECORD && p->rays_mode != IMP_BTF_RAYS_REUSE) ||
             p->rays->width != hf->width || p->rays->height != hf->height || p->rays->n_lights != cap->n_lights))
                return -EINVAL;
        struct imp_btf_extractor *x = calloc(1, sizeof *x);
        if (!x)
                return -ENOMEM;
        x->light_c = malloc(cap->n_lights * sizeof *x->light_c);
        x->lt = malloc((size_t) LT_ROWS * cap->n_lights * sizeof *x->lt);
        if (!x->light_c || !x->lt) {
                imp_btf_extractor_free(x);
                return -ENOMEM;
        }
        struct scene *sc = &x->sc;
        if (!rigid_parts(hf->canvas_to_world, sc->R, sc->t)) {
                imp_btf_extractor_free(x);
                return -EINVAL;
        }
        x->hf = hf;
        x->cap = cap;
        x->p = *p;
        /* The pyramid's horizon is built for bias 0: conservative for any bias ≥ 0. */
        sc->hz = p->shadow_bias_texels >= 0.0 ? py->hz : NULL;
        double cw[3];
        imp_pinhole_centre(cap->camera, cw);
        mat_apply_inv(sc->R, sc->t, cw, sc->cam_c);
        sc->hmax = py->hmax;
        sc->py = py->levels > 0 ? py : NULL;
        sc->light_c = x->light_c;
        for (int j = 0; j < cap->n_lights; j++) {
                const struct imp_rig_light *L = &cap->lights[j];
                bool unset = L->colour[0] == 0.0 && L->colour[1] == 0.0 && L->colour[2] == 0.0;
                mat_apply_inv(sc->R, sc->t, L->pos_mm, x->light_c[j]);
                for (int c = 0; c < 3; c++)
                        sc->colour_inv[j][c] = unset ? 1.0 : L->colour[c] > 0.0 ? 1.0 / L->colour[c] : 0.0;
        }
        light_table(cap, sc, x->lt);
        *ret = x;
        return 0;
}

int imp_btf_extract_texel(const struct imp_btf_extractor *x, int u, int v, struct imp_btf_sample *out,
                          uint16_t *ret_flags, uint16_t *ret_shadowed) {
        return imp_btf_extract_texel_band(x, NULL, u, v, out, NULL, ret_flags, ret_shadowed);
}

int imp_btf_extract_texel_band(const struct imp_btf_extractor *x, const struct imp_btf_band *b, int u, int v,
                               struct imp_btf_sample *out, uint16_t *ret_light, uint16_t *ret_flags,
                               uint16_t *ret_shadowed) {
        uint16_t count;
        extract_texel(x->hf, x->cap, &x->p, &x->sc, b, NULL, u, v, out, ret_light, &count, ret_flags, ret_shadowed);
        return count;
}

int imp_btf_extract_texel_given(const struct imp_btf_extractor *x, const struct imp_btf_band *b, int u, int v,
                                const float (*given)[3], const uint8_t *given_ok, struct imp_btf_sample *out,
                                uint16_t *ret_light, uint16_t *ret_flags, uint16_t *ret_shadowed) {
        uint16_t count;
        struct given g = { .value = given, .ok = given_ok };
        extract_texel(x->hf, x->cap, &x->p, &x->sc, b, given && given_ok ? &g : NULL, u, v, out, ret_light, &count,
                      ret_flags, ret_shadowed);
        return count;
}

/* ---- the frames interleaved by light, one band of texel rows at a time ------------ */

static bool band_usable(const struct imp_btf_capture *cap) {
        const struct imp_image *f0 = cap->frames[0];
        for (int j = 0; j < cap->n_lights; j++) {
                const struct imp_image *f = cap->frames[j], *m = cap->valid ? cap->valid[j] : NULL;
                if (f->type != IMP_PIX_F32 || f->channels != 1 || f->width != f0->width || f->height != f0->height)
                        return false;
                if (m && (m->type != IMP_PIX_U8 || m->width != f0->width || m->height != f0->height))
                        return false;
        }
        return true;
}

/* The pixel box (clamped to the frames) of the projections of texel rows [v0, v0 + rows)
 * ± margin: [floor(p) − margin + 1, floor(p) + margin + 1) on each axis; false when no
 * texel of them projects. */
static bool band_box(const struct imp_btf_extractor *x, int v0, int rows, int margin, struct imp_btf_band *b) {
        const struct imp_btf_heightfield *hf = x->hf;
        const struct imp_pinhole *cam = x->cap->camera;
        double xlo = INFINITY, ylo = INFINITY, xhi = -INFINITY, yhi = -INFINITY;
#pragma omp parallel for schedule(static) reduction(min : xlo, ylo) reduction(max : xhi, yhi)
        for (int k = 0; k < rows * hf->width; k++) {
                int u = k % hf->width, v = v0 + k / hf->width;
                double P[3] = { u * hf->pitch_mm, v * hf->pitch_mm, hf->height_mm[(size_t) v * hf->width + u] }, Pw[3], px[2];
                mat_apply(x->sc.R, x->sc.t, P, Pw);
                if (!imp_pinhole_project(cam, Pw, px) || !isfinite(px[0]) || !isfinite(px[1]))
                        continue;
                xlo = fmin(xlo, px[0]), xhi = fmax(xhi, px[0]);
                ylo = fmin(ylo, px[1]), yhi = fmax(yhi, px[1]);
        }
        if (!(xlo <= xhi && ylo <= yhi))
                return false;
        double x0 = fmax(0, floor(xlo) - margin + 1), x1 = fmin(cam->width, floor(xhi) + margin + 1);
        double y0 = fmax(0, floor(ylo) - margin + 1), y1 = fmin(cam->height, floor(yhi) + margin + 1);
        if (!(x0 < x1 && y0 < y1))
                return false;
        b->x0 = (int) x0, b->y0 = (int) y0, b->cols = (int) (x1 - x0), b->rows = (int) (y1 - y0);
        b->L = x->cap->n_lights;
        return true;
}

/* Fills b's values and states from the frames, row by row in blocks of BAND_FILL_COLS
 * pixels: a block's L lights (BAND_FILL_COLS · L · 5 bytes) stay in L1 while every light's
 * row is copied into them. */
#define BAND_FILL_COLS 64
static void band_fill(const struct imp_btf_capture *cap, double sat, struct imp_btf_band *b) {
        const size_t L = b->L;
#pragma omp parallel for schedule(static) collapse(2)
        for (int y = 0; y < b->rows; y++)
                for (int c0 = 0; c0 < b->cols; c0 += BAND_FILL_COLS) {
                        int nc = IMP_MIN(BAND_FILL_COLS, b->cols - c0);
                        float *dst = b->v + ((size_t) y * b->cols + c0) * L;
                        uint8_t *sdst = b->st + ((size_t) y * b->cols + c0) * L;
                        for (size_t l = 0; l < L; l++) {
                                const float *src = imp_image_f32(cap->frames[l], b->x0 + c0, b->y0 + y);
                                const struct imp_image *m = cap->valid ? cap->valid[l] : NULL;
                                const uint8_t *bad = m ? imp_image_u8(m, b->x0 + c0, b->y0 + y) : NULL;
                                for (int x = 0; x < nc; x++) {
                                        double val = src[x];
                                        uint8_t fl = bad ? bad[x] : 0, s = 0;
                                        s |= isfinite(val) ? 0 : TAP_NONFINITE;
                                        s |= (sat > 0.0 && val >= sat) || (fl & IMP_BTF_PIX_SATURATED) ? TAP_SATURATED : 0;
                                        s |= fl ? TAP_MASKED : 0;
                                        dst[(size_t) x * L + l] = fl ? NAN : src[x];
                                        sdst[(size_t) x * L + l] = s;
                                }
                        }
                }
}

bool imp_btf_band_load(const struct imp_btf_extractor *x, int v0, int rows, int margin, struct imp_btf_band *b) {
        if (!x || !b || v0 < 0 || rows <= 0 || v0 + rows > x->hf->height || !band_usable(x->cap))
                return false;
        struct imp_btf_band nb = *b;
        if (!band_box(x, v0, rows, IMP_MAX(margin, 1), &nb))
                return false;
        size_t cells = (size_t) nb.cols * nb.rows * nb.L, need = cells * (sizeof *nb.v + sizeof *nb.st);
        if (need > IMP_BTF_BAND_BYTES)
                return false;
        if (need > b->have) {
                imp_btf_band_done(b);
                float *buf = malloc(need);
                if (!buf)
                        return false;
                b->v = buf;
                b->have = need;
        }
        nb.v = b->v;
        nb.st = (uint8_t *) (b->v + cells);
        nb.have = b->have;
        band_fill(x->cap, x->p.saturation_value, &nb);
        *b = nb;
        return true;
}

void imp_btf_band_done(struct imp_btf_band *b) {
        if (!b)
                return;
        free(b->v);
        *b = (struct imp_btf_band) {};
}

int imp_btf_samples_extract_pyramid(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                                    const struct imp_btf_sample_params *p, const struct imp_btf_hf_pyramid *py,
                                    int x0, int y0, int w, int h, struct imp_btf_samples *out) {
        int r = check_capture(hf, cap);
        if (r < 0)
                return r;
        if (!p || !out || !py || w <= 0 || h <= 0 || x0 < 0 || y0 < 0 || x0 + w > hf->width ||
            y0 + h > hf->height)
                return -EINVAL;
        if ((long) w * h > out->capacity_texels || cap->n_lights > out->max_per_texel)
                return -E2BIG;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
        r = imp_btf_extractor_new(hf, cap, p, py, &x);
        if (r < 0)
                return r;
        out->x0 = x0;
        out->y0 = y0;
        out->w = w;
        out->h = h;
#pragma omp parallel for schedule(dynamic, 16)
        for (int i = 0; i < w * h; i++)
                out->count[i] = (uint16_t) imp_btf_extract_texel(x, x0 + i % w, y0 + i / w,
                                                                 out->samples + (size_t) i * out->max_per_texel,
                                                                 &out->flags[i], &out->n_shadowed[i]);
        return 0;
}
