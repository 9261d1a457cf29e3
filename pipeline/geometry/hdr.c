/* HDR merge (see hdr.h): per pixel, two passes over the exposure stack. Pass 1 excludes
 * samples by their measured DN and weights by the measured signal; pass 2 re-selects and
 * re-weights with the noise predicted from the pass-1 estimate, because weights computed
 * from the noisy sample itself favour low draws and bias the mean downwards.
 * Two implementations of the same estimator: without a per-pixel dark frame everything
 * pass 1 needs is a function of the DN alone, so it comes from one table per exposure
 * (float, vectorised, see merge_span); with a dark frame, the scalar double merge_one. */
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "hdr.h"

#define HDR_DEFAULT_DARK_K            3.0
#define HDR_DEFAULT_SAT_MARGIN_FRAC   0.02   /* of the clip level above the offset */
#define HDR_MAX_STACK                 64

struct hdr_exp {
        const struct imp_image *frame;
        double g;                /* electrons per DN */
        double t_s;              /* exposure, s */
        double dark_e;           /* dark-current electrons expected */
        double fw_dn;            /* full well expressed in DN above the offset */
        double k;                /* frames averaged (>= 1): noise variance / k */
};

struct hdr_ctx {
        struct hdr_exp e[HDR_MAX_STACK];
        size_t n;
        const struct imp_sensor *s;
        const struct imp_hdr_options *o;
        double max_dn, k_read_e, margin_frac, margin_dn;
};

void imp_hdr_options_default(struct imp_hdr_options *opt) {
        *opt = (struct imp_hdr_options) {
                .dark_k = HDR_DEFAULT_DARK_K,
                .saturation_margin_dn = -1,
                .demosaic = true,
        };
}

double imp_hdr_e_per_dn(const struct imp_sensor *sensor, double gain_db) {
        return sensor->gain_e_per_dn * pow(10.0, -gain_db / 20.0);
}

void imp_hdr_result_done(struct imp_hdr_result *r) {
        if (!r)
                return;
        imp_image_free(r->value);
        imp_image_free(r->variance);
        imp_image_free(r->flags);
        *r = (struct imp_hdr_result) {};
}

static inline double sample_any(const struct imp_image *img, int x, int y, int c) {
        const uint8_t *row = imp_image_row(img, y);
        size_t i = (size_t) x * img->channels + c;
        switch (img->type) {
        case IMP_PIX_U16: return ((const uint16_t *) row)[i];
        case IMP_PIX_F32: return ((const float *) row)[i];
        default:          return row[i];
        }
}

/* Merge one pixel/channel. Writes value, variance, flags. */
static void merge_one(const struct hdr_ctx *cx, int x, int y, int c, float *ret_v, float *ret_var,
                      uint8_t *ret_flag) {
        const struct imp_sensor *s = cx->s;
        double off = cx->o->dark ? sample_any(cx->o->dark, x, y, c) : s->black_level_dn;
        double flat = cx->o->flat ? sample_any(cx->o->flat, x, y, c) : 1.0;
        if (!(flat > 0) || !isfinite(flat))
                flat = 1.0;
        double read2 = s->read_noise_e * s->read_noise_e;
        double raw[HDR_MAX_STACK], e_meas[HDR_MAX_STACK], sat_dn[HDR_MAX_STACK], clip_dn[HDR_MAX_STACK];

        double sw = 0, swv = 0, sat_lb = 0, dark_lim = INFINITY;
        bool any_sat = false;
        for (size_t i = 0; i < cx->n; i++) {
                const struct hdr_exp *e = &cx->e[i];
                raw[i] = ((const uint16_t *) imp_image_row(e->frame, y))[(size_t) x * e->frame->channels + c];
                clip_dn[i] = fmin(cx->max_dn, off + e->fw_dn);
                double margin = cx->margin_dn >= 0 ? cx->margin_dn : cx->margin_frac * (clip_dn[i] - off);
                sat_dn[i] = clip_dn[i] - margin;
                double lin = cx->o->response ? cx->o->response[(int) fmin(raw[i], cx->max_dn)] : raw[i];
                e_meas[i] = (lin - off) * e->g - e->dark_e;
                double to_v = 1.0 / (s->quantum_scale * e->t_s * flat);
                if (raw[i] >= sat_dn[i]) {
                        any_sat = true;
                        sat_lb = fmax(sat_lb, ((sat_dn[i] - off) * e->g - e->dark_e) * to_v);
                        continue;
                }
                dark_lim = fmin(dark_lim, cx->k_read_e * to_v);
                if (e_meas[i] < cx->k_read_e)
                        continue;
                double var_e = (e_meas[i] + e->dark_e + read2) / e->k + e->g * e->g / 12.0;
                double w = 1.0 / (var_e * to_v * to_v);
                sw += w;
                swv += w * e_meas[i] * to_v;
        }
        if (sw <= 0) {
                if (any_sat) {
                        *ret_v = (float) fmax(sat_lb, 0.0);
                        *ret_var = (float) (sat_lb * sat_lb);
                        *ret_flag = IMP_HDR_SATURATED;
                } else {
                        *ret_v = 0;
                        *ret_var = isfinite(dark_lim) ? (float) (dark_lim * dark_lim) : 0.0f;
                        *ret_flag = IMP_HDR_DARK;
                }
                return;
        }
        double v0 = swv / sw, var0 = 1.0 / sw;

        /* Pass 2: selection and weights from the prediction at v0. */
        double sw2 = 0, swv2 = 0;
        for (size_t i = 0; i < cx->n; i++) {
                const struct hdr_exp *e = &cx->e[i];
                double to_v = 1.0 / (s->quantum_scale * e->t_s * flat);
                double e_pred = v0 / to_v;
                double dn_pred = off + (e_pred + e->dark_e) / e->g;
                if (dn_pred >= sat_dn[i] || raw[i] >= clip_dn[i] - 0.5 || e_pred < cx->k_read_e)
                        continue;
                double var_e = (fmax(e_pred, 0.0) + e->dark_e + read2) / e->k + e->g * e->g / 12.0;
                double w = 1.0 / (var_e * to_v * to_v);
                sw2 += w;
                swv2 += w * e_meas[i] * to_v;
        }
        if (sw2 > 0) {
                v0 = swv2 / sw2;
                var0 = 1.0 / sw2;
        }
        *ret_v = (float) v0;
        *ret_var = (float) var0;
        *ret_flag = 0;
}

/* Bilinear RGGB demosaic of a merged 1-channel mosaic into 3 channels. */
static void demosaic(const struct imp_image *v1, const struct imp_image *var1, const struct imp_image *f1,
                     struct imp_image *v3, struct imp_image *var3, struct imp_image *f3) {
        int w = v1->width, h = v1->height;
        #pragma omp parallel for schedule(static)
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        int own = (y & 1) == 0 ? ((x & 1) == 0 ? 0 : 1) : ((x & 1) == 0 ? 1 : 2);
                        for (int c = 0; c < 3; c++) {
                                float *ov = imp_image_f32(v3, x, y) + c, *ovar = imp_image_f32(var3, x, y) + c;
                                uint8_t *of = imp_image_u8(f3, x, y) + c;
                                if (c == own) {
                                        *ov = *imp_image_f32(v1, x, y);
                                        *ovar = *imp_image_f32(var1, x, y);
                                        *of = *imp_image_u8(f1, x, y);
                                        continue;
                                }
                                double sv = 0, svar = 0;
                                int m = 0;
                                uint8_t fl = 0;
                                for (int dy = -1; dy <= 1; dy++)
                                        for (int dx = -1; dx <= 1; dx++) {
                                                int xx = x + dx, yy = y + dy;
                                                if ((dx | dy) == 0 || xx < 0 || yy < 0 || xx >= w || yy >= h)
                                                        continue;
                                                int cc = (yy & 1) == 0 ? ((xx & 1) == 0 ? 0 : 1) : ((xx & 1) == 0 ? 1 : 2);
                                                if (cc != c)
                                                        continue;
                                                sv += *imp_image_f32(v1, xx, yy);
                                                svar += *imp_image_f32(var1, xx, yy);
                                                fl |= *imp_image_u8(f1, xx, yy);
                                                m++;
                                        }
                                /* m >= 1 whenever the image is at least 2×2 (checked). */
                                *ov = (float) (sv / m);
                                *ovar = (float) (svar / ((double) m * m));
                                *of = fl ? IMP_HDR_INTERPOLATED_FLAGGED : 0;
                        }
                }
}

/* Table-driven path (no dark frame: the offset is black_level_dn everywhere).
 * Units: x = electrons the shortest exposure would collect at flat 1, x = V·f / a_ref, with
 * a_i = 1/(quantum_scale · t_i), a_ref the largest a_i and r_i = a_i / a_ref <= 1. Sample i
 * estimates x by e_meas·r_i with inverse variance 1/(var_e·r_i²). The flat factor f scales
 * every weight by f² and every estimate by 1/f, so it cancels out of the weighted mean and
 * is applied once per pixel: V = x·a_ref/f, var(V) = a_ref²/(f²·Σw). Pass 2's prediction
 * e_pred = x0/r_i does not depend on f either: its exclusions are thresholds on x0 and its
 * weight is 1/(x0·r_i + c_i·r_i²), c_i the signal-independent variance. Float sums of at
 * most HDR_MAX_STACK positive terms: relative error ~1e-6, far inside the estimator's
 * noise. */
#define HDR_SPAN 256    /* samples merged together: their sums (9 KiB) stay in L1 */
#define HDR_KEEP_X 4    /* exposures whose pass-1 table reading pass 2 reuses (4 KiB) */

struct hdr_fast_exp {
        const float *w1;           /* [2^bits] pass-1 weight, 0 when excluded */
        const float *x;            /* [2^bits] estimate e_meas·r (0 if non-finite) */
        float r, b;                /* pass-2 weight 1/(x0·r + b) (r divided by the frames averaged) */
        float x_sat, x_lo;         /* pass 2 keeps x_lo <= x0 < x_sat */
        float sat_lb;              /* V·f lower bound from a saturated sample (>= 0) */
        uint32_t sat_dn, clip_dn;  /* raw >= sat_dn: saturated; raw >= clip_dn: clipped */
};

struct hdr_fast {
        struct hdr_fast_exp e[HDR_MAX_STACK];
        size_t n;
        uint32_t max_dn;
        float a_ref, a_ref2;
        float dark_lim;            /* detection limit of the longest exposure, V·f */
};

static uint32_t dn_threshold(double dn) {   /* smallest integer DN >= dn */
        return (uint32_t) fmin(fmax(ceil(dn), 0.0), 65536.0);
}

/* Fills fx and its tables (2 · n · 2^bits floats, caller-allocated). */
static void fast_build(const struct hdr_ctx *cx, float *tab, struct hdr_fast *fx) {
        const struct imp_sensor *s = cx->s;
        size_t n_dn = (size_t) cx->max_dn + 1;
        double off = s->black_level_dn, read2 = s->read_noise_e * s->read_noise_e;
        double a_ref = 0, a_min = INFINITY;
        for (size_t i = 0; i < cx->n; i++) {
                double a = 1.0 / (s->quantum_scale * cx->e[i].t_s);
                a_ref = fmax(a_ref, a);
                a_min = fmin(a_min, a);
        }
        *fx = (struct hdr_fast) {
                .n = cx->n, .max_dn = (uint32_t) cx->max_dn,
                .a_ref = (float) a_ref, .a_ref2 = (float) (a_ref * a_ref),
                .dark_lim = (float) (cx->k_read_e * a_min),
        };
        for (size_t i = 0; i < cx->n; i++) {
                const struct hdr_exp *e = &cx->e[i];
                double a = 1.0 / (s->quantum_scale * e->t_s), r = a / a_ref;
                double clip = fmin(cx->max_dn, off + e->fw_dn);
                double sat = clip - (cx->margin_dn >= 0 ? cx->margin_dn : cx->margin_frac * (clip - off));
                double c = (e->dark_e + read2) / e->k + e->g * e->g / 12.0;
                double e_sat = (sat - off) * e->g - e->dark_e;
                float *w1 = tab + 2 * i * n_dn, *x = w1 + n_dn;
                for (size_t d = 0; d < n_dn; d++) {
                        double lin = cx->o->response ? cx->o->response[d] : (double) d;
                        double em = (lin - off) * e->g - e->dark_e;
                        bool finite = isfinite(em);
                        w1[d] = finite && d < sat && em >= cx->k_read_e ? (float) (1.0 / ((em / e->k + c) * r * r)) : 0.0f;
                        x[d] = finite ? (float) (em * r) : 0.0f;
                }
                fx->e[i] = (struct hdr_fast_exp) {
                        .w1 = w1, .x = x, .r = (float) (r / e->k), .b = (float) (c * r * r),
                        .x_sat = (float) (e_sat * r), .x_lo = (float) (cx->k_read_e * r),
                        .sat_lb = (float) fmax(e_sat * a, 0.0),
                        .sat_dn = dn_threshold(sat), .clip_dn = dn_threshold(clip - 0.5),
                };
        }
}

/* Merges m <= HDR_SPAN samples; raw[i] points at exposure i's first sample, flat (NULL:
 * 1) at the flat field's. Branch-free so that it vectorises (float compares need
 * no-trapping-math with gcc 12; the table reads become gathers with AVX2). */
__attribute__((target_clones("avx2", "default"),
               optimize("tree-vectorize", "vect-cost-model=dynamic", "no-trapping-math")))
static void merge_span(const struct hdr_fast *fx, const uint16_t *const *raw, const float *flat, size_t m,
                       float *ret_v, float *ret_var, uint8_t *ret_flag) {
        float sw[HDR_SPAN], sx[HDR_SPAN], lb[HDR_SPAN], x0[HDR_SPAN], sw2[HDR_SPAN], sx2[HDR_SPAN], fl[HDR_SPAN];
        float xk[HDR_KEEP_X + 1][HDR_SPAN];   /* x[d] of the first exposures (the last row: discarded) */
        int32_t sat[HDR_SPAN];
        uint32_t max_dn = fx->max_dn;

        for (size_t j = 0; j < m; j++) {
                sw[j] = sx[j] = lb[j] = sw2[j] = sx2[j] = 0;
                sat[j] = 0;
        }
        for (size_t i = 0; i < fx->n; i++) {
                const struct hdr_fast_exp *e = &fx->e[i];
                const uint16_t *p = raw[i];
                const float *w1 = e->w1, *xt = e->x;
                uint32_t sat_dn = e->sat_dn;
                float sat_lb = e->sat_lb;
                float *keep = xk[i < HDR_KEEP_X ? i : HDR_KEEP_X];
                for (size_t j = 0; j < m; j++) {
                        uint32_t d = p[j] < max_dn ? p[j] : max_dn;
                        float w = w1[d], xd = xt[d];
                        keep[j] = xd;
                        sw[j] += w;
                        sx[j] += w * xd;
                        int32_t s = p[j] >= sat_dn;
                        float l = s ? sat_lb : 0.0f;
                        sat[j] |= s;
                        lb[j] = l > lb[j] ? l : lb[j];
                }
        }
        for (size_t j = 0; j < m; j++)
                x0[j] = sw[j] > 0 ? sx[j] / sw[j] : 0.0f;
        /* Pass 2. x0 = 0 (nothing usable) is below every x_lo, so such pixels stay out. */
        for (size_t i = 0; i < fx->n; i++) {
                const struct hdr_fast_exp *e = &fx->e[i];
                const uint16_t *p = raw[i];
                const float *xt = e->x;
                uint32_t clip_dn = e->clip_dn;
                float r = e->r, b = e->b, x_sat = e->x_sat, x_lo = e->x_lo;
                const float *kept = xk[i < HDR_KEEP_X ? i : 0];
                if (i < HDR_KEEP_X)   /* the same x[d] values, read back instead of gathered */
                        for (size_t j = 0; j < m; j++) {
                                float xx = x0[j];
                                float q = 1.0f / (xx * r + b);     /* > 0: x0 >= 0, b > 0 */
                                bool ok = p[j] < clip_dn && xx < x_sat && xx >= x_lo;
                                q = ok ? q : 0.0f;
                                sw2[j] += q;
                                sx2[j] += q * kept[j];
                        }
                else
                        for (size_t j = 0; j < m; j++) {
                                uint32_t d = p[j] < max_dn ? p[j] : max_dn;
                                float xx = x0[j];
                                float q = 1.0f / (xx * r + b);
                                bool ok = p[j] < clip_dn && xx < x_sat && xx >= x_lo;
                                q = ok ? q : 0.0f;
                                sw2[j] += q;
                                sx2[j] += q * xt[d];
                        }
        }
        if (flat)
                for (size_t j = 0; j < m; j++)
                        fl[j] = flat[j] > 0 && flat[j] <= FLT_MAX ? 1.0f / flat[j] : 1.0f;
        else
                for (size_t j = 0; j < m; j++)
                        fl[j] = 1.0f;
        float a_ref = fx->a_ref, a_ref2 = fx->a_ref2, dark_lim = fx->dark_lim;
        for (size_t j = 0; j < m; j++) {
                float inv_f = fl[j];
                bool ok1 = sw[j] > 0, ok2 = sw2[j] > 0;
                float x = ok2 ? sx2[j] / sw2[j] : x0[j];
                float s = ok2 ? sw2[j] : ok1 ? sw[j] : 1.0f;
                float v = x * a_ref * inv_f, var = a_ref2 * inv_f * inv_f / s;
                float v_sat = lb[j] * inv_f, v_dark = dark_lim * inv_f;
                ret_v[j] = ok1 ? v : sat[j] ? v_sat : 0.0f;
                ret_var[j] = ok1 ? var : sat[j] ? v_sat * v_sat : v_dark * v_dark;
                ret_flag[j] = ok1 ? 0 : sat[j] ? IMP_HDR_SATURATED : IMP_HDR_DARK;
        }
}

static int merge_fast(const struct hdr_ctx *cx, struct imp_image *v, struct imp_image *var, struct imp_image *fl,
                      size_t *ret_sat, size_t *ret_dark) {
        size_t n_dn = (size_t) cx->max_dn + 1;
        _cleanup_free_ float *tab = malloc(2 * cx->n * n_dn * sizeof(float));
        if (!tab)
                return -ENOMEM;
        struct hdr_fast fx;
        fast_build(cx, tab, &fx);
        const struct imp_image *flat = cx->o->flat;
        int h = v->height;
        size_t ns = (size_t) v->width * v->channels, n_sat = 0, n_dark = 0;
        #pragma omp parallel for schedule(static) reduction(+:n_sat,n_dark)
        for (int y = 0; y < h; y++) {
                const uint16_t *raw[HDR_MAX_STACK];
                const float *flat_row = flat ? imp_image_row(flat, y) : NULL;
                float *pv = imp_image_row(v, y), *pvar = imp_image_row(var, y);
                uint8_t *pf = imp_image_row(fl, y);
                for (size_t j0 = 0; j0 < ns; j0 += HDR_SPAN) {
                        size_t m = ns - j0 < HDR_SPAN ? ns - j0 : HDR_SPAN;
                        for (size_t i = 0; i < cx->n; i++)
                                raw[i] = (const uint16_t *) imp_image_row(cx->e[i].frame, y) + j0;
                        merge_span(&fx, raw, flat_row ? flat_row + j0 : NULL, m, pv + j0, pvar + j0, pf + j0);
                        for (size_t j = j0; j < j0 + m; j++) {
                                n_sat += pf[j] == IMP_HDR_SATURATED;
                                n_dark += pf[j] == IMP_HDR_DARK;
                        }
                }
        }
        *ret_sat = n_sat;
        *ret_dark = n_dark;
        return 0;
}

static bool same_layout(const struct imp_image *a, const struct imp_image *b) {
        return a->width == b->width && a->height == b->height && a->channels == b->channels;
}

/* *img taken when it has this layout (its samples are all overwritten by the merge). */
static struct imp_image *recycled(struct imp_image **img, int w, int h, int C, enum imp_pixel_type type) {
        struct imp_image *m = *img;
        if (!m || m->width != w || m->height != h || m->channels != C || m->type != type)
                return NULL;
        return TAKE_PTR(*img);
}

int imp_hdr_merge(const struct imp_hdr_exposure *stack, size_t n, const struct imp_sensor *sensor,
                  const struct imp_hdr_options *opt, struct imp_hdr_result *ret) {
        struct imp_hdr_options defaults;
        if (!stack || n == 0 || n > HDR_MAX_STACK || !sensor || !ret)
                return -EINVAL;
        if (!opt) {
                imp_hdr_options_default(&defaults);
                opt = &defaults;
        }
        if (sensor->bits < 1 || sensor->bits > 16 || !(sensor->gain_e_per_dn > 0) ||
            !(sensor->quantum_scale > 0) || !(sensor->full_well_e > 0) || !(sensor->read_noise_e >= 0))
                return -EINVAL;
        const struct imp_image *f0 = stack[0].frame;
        if (!f0 || f0->type != IMP_PIX_U16 || (f0->channels != 1 && f0->channels != 3))
                return -EINVAL;
        for (size_t i = 0; i < n; i++) {
                const struct imp_image *f = stack[i].frame;
                if (!f || f->type != IMP_PIX_U16 || !same_layout(f, f0) ||
                    !(stack[i].exposure_us > 0) || !isfinite(stack[i].gain_db))
                        return -EINVAL;
        }
        if (opt->dark && (!same_layout(opt->dark, f0) || opt->dark->type == IMP_PIX_U8))
                return -EINVAL;
        if (opt->flat && (!same_layout(opt->flat, f0) || opt->flat->type != IMP_PIX_F32))
                return -EINVAL;
        bool bayer = sensor->bayer && f0->channels == 1 && opt->demosaic;
        if (bayer && (f0->width < 2 || f0->height < 2))
                return -EINVAL;

        struct hdr_ctx cx = {
                .n = n, .s = sensor, .o = opt,
                .max_dn = (double) ((1u << sensor->bits) - 1),
                .k_read_e = (opt->dark_k > 0 ? opt->dark_k : HDR_DEFAULT_DARK_K) *
                            fmax(sensor->read_noise_e, 0.5),
                .margin_frac = HDR_DEFAULT_SAT_MARGIN_FRAC,
                .margin_dn = opt->saturation_margin_dn,
        };
        for (size_t i = 0; i < n; i++) {
                double g = imp_hdr_e_per_dn(sensor, stack[i].gain_db);
                cx.e[i] = (struct hdr_exp) {
                        .frame = stack[i].frame, .g = g, .t_s = stack[i].exposure_us * 1e-6,
                        .dark_e = fmax(sensor->dark_current_e_per_s, 0.0) * stack[i].exposure_us * 1e-6,
                        .fw_dn = sensor->full_well_e / g,
                        .k = stack[i].n_frames > 1 ? (double) stack[i].n_frames : 1.0,
                };
        }

        int w = f0->width, h = f0->height, C = f0->channels, r;
        _cleanup_image_ struct imp_image *v = NULL, *var = NULL, *fl = NULL;
        if (opt->recycle && !bayer) {
                var = recycled(&opt->recycle->variance, w, h, C, IMP_PIX_F32);
                fl = recycled(&opt->recycle->flags, w, h, C, IMP_PIX_U8);
        }
        if ((r = imp_image_new_in(bayer ? NULL : opt->arena, w, h, C, IMP_PIX_F32, &v)) < 0 ||
            (!var && (r = imp_image_new(w, h, C, IMP_PIX_F32, &var)) < 0) ||
            (!fl && (r = imp_image_new(w, h, C, IMP_PIX_U8, &fl)) < 0))
                return r;
        size_t n_sat = 0, n_dark = 0;
        if (!opt->dark) {
                if ((r = merge_fast(&cx, v, var, fl, &n_sat, &n_dark)) < 0)
                        return r;
        } else {
                #pragma omp parallel for schedule(static) reduction(+:n_sat,n_dark)
                for (int y = 0; y < h; y++)
                        for (int x = 0; x < w; x++)
                                for (int c = 0; c < C; c++) {
                                        uint8_t *pf = imp_image_u8(fl, x, y) + c;
                                        merge_one(&cx, x, y, c, imp_image_f32(v, x, y) + c,
                                                  imp_image_f32(var, x, y) + c, pf);
                                        n_sat += (*pf & IMP_HDR_SATURATED) != 0;
                                        n_dark += (*pf & IMP_HDR_DARK) != 0;
                                }
        }

        if (bayer) {
                _cleanup_image_ struct imp_image *v3 = NULL, *var3 = NULL, *fl3 = NULL;
                if ((r = imp_image_new_in(opt->arena, w, h, 3, IMP_PIX_F32, &v3)) < 0 ||
                    (r = imp_image_new(w, h, 3, IMP_PIX_F32, &var3)) < 0 ||
                    (r = imp_image_new(w, h, 3, IMP_PIX_U8, &fl3)) < 0)
                        return r;
                demosaic(v, var, fl, v3, var3, fl3);
                imp_image_free(v);
                imp_image_free(var);
                imp_image_free(fl);
                v = TAKE_PTR(v3);
                var = TAKE_PTR(var3);
                fl = TAKE_PTR(fl3);
        }
        *ret = (struct imp_hdr_result) {
                .value = TAKE_PTR(v), .variance = TAKE_PTR(var), .flags = TAKE_PTR(fl),
                .n_saturated = n_sat, .n_dark = n_dark,
        };
        return 0;
}

int imp_hdr_saturated_mask(const struct imp_image *flags, struct imp_image **ret) {
        if (!flags || flags->type != IMP_PIX_U8 || flags->channels < 1 || !ret)
                return -EINVAL;
        struct imp_image *m;
        int r = imp_image_new(flags->width, flags->height, 1, IMP_PIX_U8, &m);
        if (r < 0)
                return r;
        for (int y = 0; y < flags->height; y++)
                for (int x = 0; x < flags->width; x++) {
                        const uint8_t *f = imp_image_u8(flags, x, y);
                        uint8_t o = 0;
                        for (int c = 0; c < flags->channels; c++)
                                o |= (f[c] & IMP_HDR_SATURATED) != 0;
                        *imp_image_u8(m, x, y) = o;
                }
        *ret = m;
        return 0;
}
