/* HDR merge (see hdr.h): per pixel, two passes over the exposure stack. Pass 1 excludes
 * samples by their measured DN and weights by the measured signal; pass 2 re-selects and
 * re-weights with the noise predicted from the pass-1 estimate, because weights computed
 * from the noisy sample itself favour low draws and bias the mean downwards. */
#include <math.h>
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
                double var_e = e_meas[i] + e->dark_e + read2 + e->g * e->g / 12.0;
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
                double var_e = fmax(e_pred, 0.0) + e->dark_e + read2 + e->g * e->g / 12.0;
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

static bool same_layout(const struct imp_image *a, const struct imp_image *b) {
        return a->width == b->width && a->height == b->height && a->channels == b->channels;
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
                };
        }

        int w = f0->width, h = f0->height, C = f0->channels, r;
        _cleanup_image_ struct imp_image *v = NULL, *var = NULL, *fl = NULL;
        if ((r = imp_image_new(w, h, C, IMP_PIX_F32, &v)) < 0 ||
            (r = imp_image_new(w, h, C, IMP_PIX_F32, &var)) < 0 ||
            (r = imp_image_new(w, h, C, IMP_PIX_U8, &fl)) < 0)
                return r;
        size_t n_sat = 0, n_dark = 0;
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

        if (bayer) {
                _cleanup_image_ struct imp_image *v3 = NULL, *var3 = NULL, *fl3 = NULL;
                if ((r = imp_image_new(w, h, 3, IMP_PIX_F32, &v3)) < 0 ||
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
