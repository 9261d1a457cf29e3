/* Photometric normal refinement (photometric.h; method in docs/geometry.md). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "heightfield.h"
#include "photometric.h"
#include "macro.h"

#define DEG (M_PI / 180.0)
#define PN_SHADOW_FRAC  0.5           /* trimmed samples read below this × the fit */
#define PN_SHADOW_START 0.25          /* trimming: first solve without samples below this × median */
#define TILE 64

void imp_photometric_params_default(struct imp_photometric_params *ret) {
        *ret = (struct imp_photometric_params) {
                .min_samples = 6, .spec_cone_deg = 40, .min_cos = 0.05, .max_cond = 100,
                .min_albedo = 0.01, .max_dev_deg = 25, .passes = 5, .huber_delta = 1.345,
                .sigma_floor = 0.002, .tol_deg = 0.01, .geo_sigma_deg = 0, .lanczos = 3,
                .shadow_trim_sigma = 0, .filled_trim_sigma = 3, .filled_passes = 10, .filled_max_dev_deg = 60,
        };
}

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return x < y ? -1 : x > y;
}

/* Median of v[0..n) by insertion into a sorted copy (n ≤ IMP_BTF_MAX_SAMPLES). */
static double median_small(const double *v, int n, double *tmp) {
        if (n <= 0)
                return 0;
        memcpy(tmp, v, (size_t) n * sizeof *tmp);
        qsort(tmp, (size_t) n, sizeof *tmp, cmp_double);
        return n & 1 ? tmp[n / 2] : 0.5 * (tmp[n / 2 - 1] + tmp[n / 2]);
}

static void keep_geometric(struct imp_pn_texel *ret, uint16_t flags) {
        ret->n[0] = ret->n[1] = 0;
        ret->n[2] = 1;
        ret->flags |= flags;
}

int imp_photometric_texel(const struct imp_btf_sample *s, int n, const struct imp_photometric_params *p,
                          struct imp_pn_texel *ret) {
        *ret = (struct imp_pn_texel) { .n = { 0, 0, 1 }, .sigma_deg = 180 };
        if (n < 0 || n > IMP_BTF_MAX_SAMPLES)
                return -E2BIG;
        if (!p || p->min_samples < 3 || p->passes < 1 || !(p->max_cond > 1) || !(p->huber_delta > 0) ||
            !(p->sigma_floor > 0) || !(p->max_dev_deg > 0))
                return -EINVAL;
        double a[IMP_BTF_MAX_SAMPLES][3], y[IMP_BTF_MAX_SAMPLES], vv[IMP_BTF_MAX_SAMPLES][3];
        double w[IMP_BTF_MAX_SAMPLES], res[IMP_BTF_MAX_SAMPLES], tmp[IMP_BTF_MAX_SAMPLES];
        int m = 0;
        for (int i = 0; i < n; i++) {
                const struct imp_btf_sample *q = &s[i];
                double V = (q->value[0] + q->value[1] + q->value[2]) / 3.0;
                if (!(q->e_cos > 0) || !(q->l[2] > 0) || !isfinite(V) || !isfinite(q->l[0]) ||
                    !isfinite(q->l[1]) || !isfinite(q->v[0]) || !isfinite(q->v[1]) || !isfinite(q->v[2]))
                        continue;
                double E = q->e_cos / q->l[2];
                if (!isfinite(E) || !(E > 0))
                        continue;
                for (int k = 0; k < 3; k++) {
                        a[m][k] = q->l[k];
                        vv[m][k] = q->v[k];
                }
                y[m] = V / E;
                w[m] = 1;
                m++;
        }
        if (m < p->min_samples) {
                keep_geometric(ret, m == 0 ? IMP_PN_MASKED | IMP_PN_FEW_SAMPLES : IMP_PN_FEW_SAMPLES);
                ret->n_used = (uint16_t) m;
                return 0;
        }
        if (p->shadow_trim_sigma > 0) {
                /* Cast shadows expected: the first solve leaves out the samples darker than
                 * PN_SHADOW_START × the median, so that the shadows do not bias the fit the
                 * trimming starts from; they come back when the fit explains them. */
                double ymed = median_small(y, m, tmp);
                for (int i = 0; i < m; i++)
                        if (y[i] < PN_SHADOW_START * ymed)
                                w[i] = 0;
        }
        double nc[3] = { 0, 0, 1 }, g[3] = { 0, 0, 0 }, sigma = p->sigma_floor, cone = cos(p->spec_cone_deg * DEG);
        double cond = 1e12, Ainv[9] = {}, rms = 0;
        int used = 0;
        for (int pass = 0; pass < p->passes; pass++) {
                /* Which samples take part for the current normal: not near the mirror
                 * direction, not in attached shadow. */
                double A[9] = {}, b[3] = {}, sw = 0;
                used = 0;
                for (int i = 0; i < m; i++) {
                        double nv = nc[0] * vv[i][0] + nc[1] * vv[i][1] + nc[2] * vv[i][2];
                        double r[3], rl = 0, nl = 0;
                        for (int k = 0; k < 3; k++) {
                                r[k] = 2 * nv * nc[k] - vv[i][k];
                                rl += r[k] * a[i][k];
                                nl += nc[k] * a[i][k];
                        }
                        double wi = (rl > cone || nl < p->min_cos) ? 0.0 : w[i];
                        if (wi <= 0)
                                continue;
                        used++;
                        sw += wi;
                        for (int j = 0; j < 3; j++) {
                                b[j] += wi * a[i][j] * y[i];
                                for (int k = 0; k < 3; k++)
                                        A[3 * j + k] += wi * a[i][j] * a[i][k];
                        }
                }
                if (used < p->min_samples) {
                        keep_geometric(ret, IMP_PN_FEW_SAMPLES);
                        ret->n_used = (uint16_t) used;
                        return 0;
                }
                double lam[3], vec[9];
                imp_heightfield_eigen3(A, lam, vec);
                cond = lam[0] > 0 ? lam[2] / lam[0] : 1e12;
                if (!(cond <= p->max_cond)) {
                        ret->cond = (float) fmin(cond, 1e12);
                        ret->n_used = (uint16_t) used;
                        keep_geometric(ret, IMP_PN_ILL_COND);
                        return 0;
                }
                for (int j = 0; j < 9; j++)
                        Ainv[j] = 0;
                for (int e = 0; e < 3; e++)
                        for (int j = 0; j < 3; j++)
                                for (int k = 0; k < 3; k++)
                                        Ainv[3 * j + k] += vec[3 * e + j] * vec[3 * e + k] / lam[e];
                for (int j = 0; j < 3; j++)
                        g[j] = Ainv[3 * j] * b[0] + Ainv[3 * j + 1] * b[1] + Ainv[3 * j + 2] * b[2];
                double gl = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
                if (!(gl >= p->min_albedo) || !isfinite(gl)) {
                        ret->cond = (float) cond;
                        ret->n_used = (uint16_t) used;
                        keep_geometric(ret, IMP_PN_DARK);
                        return 0;
                }
                double nn[3] = { g[0] / gl, g[1] / gl, g[2] / gl };
                double moved = acos(fmin(1.0, fabs(nn[0] * nc[0] + nn[1] * nc[1] + nn[2] * nc[2]))) / DEG;
                /* Residuals over every sample (an excluded sample may come back), robust σ
                 * from the ones that took part, Huber weights for the next solve. */
                int k2 = 0;
                double ss = 0;
                for (int i = 0; i < m; i++) {
                        res[i] = y[i] - (g[0] * a[i][0] + g[1] * a[i][1] + g[2] * a[i][2]);
                        double nv = nn[0] * vv[i][0] + nn[1] * vv[i][1] + nn[2] * vv[i][2];
                        double rl = 0, nl = 0;
                        for (int k = 0; k < 3; k++) {
                                rl += (2 * nv * nn[k] - vv[i][k]) * a[i][k];
                                nl += nn[k] * a[i][k];
                        }
                        if (rl <= cone && nl >= p->min_cos) {
                                tmp[k2] = fabs(res[i]);
                                ss += w[i] * res[i] * res[i];
                                k2++;
                        }
                }
                double mad[IMP_BTF_MAX_SAMPLES];
                sigma = fmax(p->sigma_floor, 1.4826 * median_small(tmp, k2, mad));
                rms = sqrt(ss / fmax(sw, 1e-30));
                for (int k = 0; k < 3; k++)
                        nc[k] = nn[k];
                if (pass + 1 < p->passes) {
                        for (int i = 0; i < m; i++) {
                                double u = fabs(res[i]) / sigma;
                                w[i] = u <= p->huber_delta ? 1.0 : p->huber_delta / u;
                                /* cast shadow: far below the fit and under half of it */
                                if (p->shadow_trim_sigma > 0 && res[i] < -p->shadow_trim_sigma * sigma &&
                                    y[i] < PN_SHADOW_FRAC * (y[i] - res[i]))
                                        w[i] = 0;
                        }
                        if (pass > 0 && moved < p->tol_deg)
                                break;
                }
        }
        double gl = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
        double tr = Ainv[0] + Ainv[4] + Ainv[8], nAn = 0;
        for (int j = 0; j < 3; j++)
                for (int k = 0; k < 3; k++)
                        nAn += nc[j] * Ainv[3 * j + k] * nc[k];
        double var_t = fmax(0, tr - nAn);
        ret->albedo = (float) gl;
        ret->rms = (float) rms;
        ret->cond = (float) cond;
        ret->n_used = (uint16_t) used;
        ret->sigma_deg = (float) fmin(180.0, sigma * sqrt(var_t) / gl / DEG);
        ret->dev_deg = (float) (acos(fmax(-1.0, fmin(1.0, nc[2]))) / DEG);
        if (!(ret->dev_deg <= p->max_dev_deg)) {
                keep_geometric(ret, IMP_PN_DISAGREES);
                return 0;
        }
        for (int k = 0; k < 3; k++)
                ret->n[k] = (float) nc[k];
        return 0;
}

/* ---- re-sampling the frames with a Lanczos kernel ----------------------------------
 * The extractor reads each frame bilinearly at the texel's projection. Between pixels
 * that blends the shading of the neighbouring pixels' normals: on the demo's 0.2 mm
 * grooves (4 pixels per period) bilinear reading alone leaves 2.9° between the truth
 * normals at the pixels and at the texel, Lanczos-3 1.3° (docs/geometry.md). The
 * extractor keeps the geometry (directions, irradiance, shadow and visibility rays);
 * here each sample's value is read again with the Lanczos kernel. Samples come in light
 * order, so each is matched to its light by recomputing the local light direction. */

#define PN_MATCH_TOL 1e-4             /* |l − l_light| for a sample to be that light's */
#define PN_MAX_LANCZOS 4

struct resample {
        const struct imp_btf_heightfield *hf;
        const struct imp_btf_capture *cap;
        double R[9], t[3];            /* canvas → world */
        double (*light_c)[3];         /* light positions, canvas frame */
        double sat;                   /* saturation value (0: flags only) */
        int a;                        /* Lanczos order, 0 = off */
};

static double lanczos(double x, int a) {
        x = fabs(x);
        if (x < 1e-9)
                return 1;
        if (x >= a)
                return 0;
        return a * sin(M_PI * x) * sin(M_PI * x / a) / (M_PI * M_PI * x * x);
}

/* Lanczos value of frame f at px into ret[3]; false when the window leaves the frame or
 * holds a non-finite, saturated or invalid pixel (the caller keeps the bilinear value). */
static bool lanczos_sample(const struct resample *rs, int light, const double px[2], const double *wx,
                           const double *wy, float ret[3]) {
        const struct imp_image *f = rs->cap->frames[light];
        const struct imp_image *val = rs->cap->valid ? rs->cap->valid[light] : NULL;
        int a = rs->a, x0 = (int) floor(px[0]) - a + 1, y0 = (int) floor(px[1]) - a + 1;
        if (x0 < 0 || y0 < 0 || x0 + 2 * a > f->width || y0 + 2 * a > f->height)
                return false;
        double acc[3] = { 0, 0, 0 };
        for (int dy = 0; dy < 2 * a; dy++)
                for (int dx = 0; dx < 2 * a; dx++) {
                        const float *q = imp_image_f32(f, x0 + dx, y0 + dy);
                        if (val && *imp_image_u8(val, x0 + dx, y0 + dy))
                                return false;
                        for (int c = 0; c < 3; c++) {
                                double v = q[f->channels == 3 ? c : 0];
                                if (!isfinite(v) || (rs->sat > 0 && v >= rs->sat))
                                        return false;
                                acc[c] += wx[dx] * wy[dy] * v;
                        }
                }
        for (int c = 0; c < 3; c++)
                ret[c] = (float) acc[c];
        return true;
}

/* Re-reads the values of texel (u, v)'s n samples (light colour applied as the extractor
 * does). Returns how many were re-read. */
static int resample_texel(const struct resample *rs, int u, int v, struct imp_btf_sample *smp, int n) {
        const struct imp_btf_heightfield *hf = rs->hf;
        size_t idx = (size_t) v * hf->width + u;
        const float *nf = hf->normal + 3 * idx;
        double nl = sqrt(nf[0] * nf[0] + nf[1] * nf[1] + nf[2] * nf[2]);
        if (n <= 0 || !(nl > 0.5 && nl < 2.0) || rs->a <= 0)
                return 0;
        double nn[3] = { nf[0] / nl, nf[1] / nl, nf[2] / nl }, tb[3], bb[3];
        double P[3] = { u * hf->pitch_mm, v * hf->pitch_mm, hf->height_mm[idx] }, Pw[3], px[2];
        imp_local_frame(nn, tb, bb);
        for (int i = 0; i < 3; i++)
                Pw[i] = rs->R[3 * i] * P[0] + rs->R[3 * i + 1] * P[1] + rs->R[3 * i + 2] * P[2] + rs->t[i];
        if (!imp_pinhole_project(rs->cap->camera, Pw, px))
                return 0;
        double wx[2 * PN_MAX_LANCZOS], wy[2 * PN_MAX_LANCZOS], sx = 0, sy = 0;
        int x0 = (int) floor(px[0]) - rs->a + 1, y0 = (int) floor(px[1]) - rs->a + 1;
        for (int k = 0; k < 2 * rs->a; k++) {
                sx += wx[k] = lanczos(px[0] - (x0 + k), rs->a);
                sy += wy[k] = lanczos(px[1] - (y0 + k), rs->a);
        }
        for (int k = 0; k < 2 * rs->a; k++)
                wx[k] /= sx, wy[k] /= sy;
        int done = 0, j = 0;
        for (int s = 0; s < n && j < rs->cap->n_lights; s++) {
                for (; j < rs->cap->n_lights; j++) {
                        double wl[3], r = 0, lloc[3];
                        for (int i = 0; i < 3; i++) {
                                wl[i] = rs->light_c[j][i] - P[i];
                                r += wl[i] * wl[i];
                        }
                        r = sqrt(r);
                        for (int i = 0; i < 3; i++)
                                wl[i] /= r;
                        imp_to_local(tb, bb, nn, wl, lloc);
                        if (fabs(lloc[0] - smp[s].l[0]) + fabs(lloc[1] - smp[s].l[1]) +
                            fabs(lloc[2] - smp[s].l[2]) <= PN_MATCH_TOL)
                                break;
                }
                if (j == rs->cap->n_lights)
                        break;
                float val[3];
                if (lanczos_sample(rs, j, px, wx, wy, val)) {
                        const double *col = rs->cap->lights[j].colour;
                        bool white = col[0] == 0 && col[1] == 0 && col[2] == 0;
                        for (int c = 0; c < 3; c++)
                                smp[s].value[c] = white ? val[c] : col[c] > 0 ? (float) (val[c] / col[c]) : 0.0f;
                        done++;
                }
                j++;
        }
        return done;
}

/* Texel result (local frame of the geometric normal ng) → unit canvas normal in out;
 * out untouched when the texel kept the geometric normal. */
static void to_canvas(const float *ng, const struct imp_pn_texel *t, const struct imp_photometric_params *p,
                      float *out) {
        if (t->flags & IMP_PN_KEPT)
                return;
        double n0[3] = { ng[0], ng[1], ng[2] }, tt[3], bb[3], nn[3], len = 0;
        imp_local_frame(n0, tt, bb);
        double wp = 1, wg = 0;
        if (p->geo_sigma_deg > 0) {
                double sp2 = fmax(1e-6, (double) t->sigma_deg * t->sigma_deg);
                wp = 1 / sp2;
                wg = 1 / (p->geo_sigma_deg * p->geo_sigma_deg);
        }
        for (int c = 0; c < 3; c++) {
                nn[c] = wp * (t->n[0] * tt[c] + t->n[1] * bb[c] + t->n[2] * n0[c]) + wg * n0[c];
                len += nn[c] * nn[c];
        }
        len = sqrt(len);
        if (!(len > 0) || !isfinite(len))
                return;
        for (int c = 0; c < 3; c++)
                out[c] = (float) (nn[c] / len);
}

int imp_photometric_normals(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *sp, const struct imp_photometric_params *p,
                            float *ret_normal, float *ret_normal_bilinear, uint16_t *ret_flags,
                            struct imp_photometric_stats *ret_stats) {
        if (!hf || !cap || !sp || !p || !ret_normal || ret_normal == hf->normal || !hf->normal ||
            ret_normal_bilinear == hf->normal || ret_normal_bilinear == ret_normal ||
            hf->width <= 0 || hf->height <= 0)
                return -EINVAL;
        size_t nt = (size_t) hf->width * hf->height;
        _cleanup_btf_samples_ struct imp_btf_samples *smp = NULL;
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        int r = imp_btf_samples_new(TILE * TILE, cap->n_lights, &smp);
        if (r < 0)
                return r;
        r = imp_btf_hf_pyramid_new(hf, &py);
        if (r < 0)
                return r;
        _cleanup_free_ double *dev = malloc(nt * sizeof *dev), *sig = malloc(nt * sizeof *sig),
                              *rmsv = malloc(nt * sizeof *rmsv);
        if (!dev || !sig || !rmsv)
                return -ENOMEM;
        if (p->lanczos < 0 || p->lanczos > PN_MAX_LANCZOS)
                return -EINVAL;
        _cleanup_free_ double (*light_c)[3] = malloc((size_t) cap->n_lights * sizeof *light_c);
        if (!light_c)
                return -ENOMEM;
        /* Shadow-filled texels (mask value 2): cast-shadow trimming (photometric.h). */
        struct imp_photometric_params pf = *p;
        pf.shadow_trim_sigma = p->filled_trim_sigma;
        pf.passes = IMP_MAX(p->passes, p->filled_passes);
        pf.max_dev_deg = p->filled_max_dev_deg > 0 ? p->filled_max_dev_deg : p->max_dev_deg;
        struct resample rs = { .hf = hf, .cap = cap, .light_c = light_c, .sat = sp->saturation_value, .a = p->lanczos };
        for (int i = 0; i < 3; i++) {
                for (int k = 0; k < 3; k++)
                        rs.R[3 * i + k] = hf->canvas_to_world[4 * i + k];
                rs.t[i] = hf->canvas_to_world[4 * i + 3];
        }
        for (int j = 0; j < cap->n_lights; j++)   /* canvas = Rᵀ (world − t) */
                for (int i = 0; i < 3; i++) {
                        light_c[j][i] = 0;
                        for (int k = 0; k < 3; k++)
                                light_c[j][i] += rs.R[3 * k + i] * (cap->lights[j].pos_mm[k] - rs.t[k]);
                }
        memcpy(ret_normal, hf->normal, nt * 3 * sizeof *ret_normal);
        if (ret_normal_bilinear)
                memcpy(ret_normal_bilinear, hf->normal, nt * 3 * sizeof *ret_normal_bilinear);
        struct imp_photometric_stats st = { .n_texels = (long) nt };
        size_t n_ref = 0;
        double dev_sum = 0;
        for (int y0 = 0; y0 < hf->height; y0 += TILE)
                for (int x0 = 0; x0 < hf->width; x0 += TILE) {
                        int w = hf->width - x0 < TILE ? hf->width - x0 : TILE;
                        int h = hf->height - y0 < TILE ? hf->height - y0 : TILE;
                        r = imp_btf_samples_extract_pyramid(hf, cap, sp, py, x0, y0, w, h, smp);
                        if (r < 0)
                                return r;
                        long few = 0, ill = 0, dark = 0, dis = 0, msk = 0, res = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : few, ill, dark, dis, msk, res)
                        for (int k = 0; k < w * h; k++) {
                                size_t i = (size_t) (y0 + k / w) * hf->width + x0 + k % w;
                                struct imp_pn_texel t;
                                bool masked = (smp->flags[k] & (IMP_BTF_MASKED | IMP_BTF_HIDDEN)) ||
                                              (hf->mask && !hf->mask[i]);
                                if (masked) {
                                        t = (struct imp_pn_texel) { .n = { 0, 0, 1 }, .sigma_deg = 180,
                                                                    .flags = IMP_PN_MASKED };
                                } else {
                                        struct imp_btf_sample *ts = &smp->samples[(size_t) k * smp->max_per_texel];
                                        const struct imp_photometric_params *pt = hf->mask && hf->mask[i] == 2 ? &pf : p;
                                        if (ret_normal_bilinear) {
                                                struct imp_pn_texel tb;
                                                imp_photometric_texel(ts, smp->count[k], pt, &tb);
                                                to_canvas(&hf->normal[3 * i], &tb, pt, &ret_normal_bilinear[3 * i]);
                                        }
                                        res += resample_texel(&rs, x0 + k % w, y0 + k / w, ts, smp->count[k]);
                                        imp_photometric_texel(ts, smp->count[k], pt, &t);
                                }
                                if (ret_flags)
                                        ret_flags[i] = t.flags;
                                few += !!(t.flags & IMP_PN_FEW_SAMPLES) && !(t.flags & IMP_PN_MASKED);
                                ill += !!(t.flags & IMP_PN_ILL_COND);
                                dark += !!(t.flags & IMP_PN_DARK);
                                dis += !!(t.flags & IMP_PN_DISAGREES);
                                msk += !!(t.flags & IMP_PN_MASKED);
                                dev[i] = sig[i] = rmsv[i] = NAN;
                                if (t.flags & IMP_PN_KEPT)
                                        continue;
                                dev[i] = t.dev_deg;
                                sig[i] = t.sigma_deg;
                                rmsv[i] = t.rms;
                                to_canvas(&hf->normal[3 * i], &t, p, &ret_normal[3 * i]);
                        }
                        st.n_few += few;
                        st.n_ill += ill;
                        st.n_dark += dark;
                        st.n_disagree += dis;
                        st.n_masked += msk;
                        st.n_resampled += res;
                }
        /* Figures over the refined texels (compact the finite entries). */
        for (size_t i = 0; i < nt; i++)
                if (isfinite(dev[i])) {
                        dev_sum += dev[i];
                        dev[n_ref] = dev[i];
                        sig[n_ref] = sig[i];
                        rmsv[n_ref] = rmsv[i];
                        n_ref++;
                }
        st.n_refined = (long) n_ref;
        if (n_ref) {
                st.dev_deg_mean = dev_sum / n_ref;
                qsort(dev, n_ref, sizeof *dev, cmp_double);
                qsort(sig, n_ref, sizeof *sig, cmp_double);
                qsort(rmsv, n_ref, sizeof *rmsv, cmp_double);
                st.dev_deg_median = dev[n_ref / 2];
                st.sigma_deg_median = sig[n_ref / 2];
                st.rms_median = rmsv[n_ref / 2];
        }
        if (ret_stats)
                *ret_stats = st;
        return 0;
}
