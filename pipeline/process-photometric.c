/* Photometric-only processing (process-photometric.h): per camera pixel, the dome sweep's
 * samples on the surface plane z = 0 (near-field light direction and irradiance from the
 * rig, as the dome's own processing uses them: btf.h imp_btf_light_irradiance), the
 * robust Lambertian solve of photometric.h (Woodham 1980's least squares with attached
 * shadows, the specular cone and cast shadows left out and Huber reweighting), the
 * Lafortune fit of btf.h in the normal's local frame, and heights by least-squares
 * integration of the normals (fuse.h with no position term). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "btf.h"
#include "captureset.h"
#include "fuse.h"
#include "hdr.h"
#include "json-util.h"
#include "photometric.h"
#include "process-photometric.h"
#include "quality.h"
#include "version.h"

#define PO_MAX_EXPOSURES 8            /* distinct exposures merged per light */
#define PO_SHADOW_TRIM_SIGMA 3.0      /* darker than the fit by this many robust σ: cast shadow */
#define PO_PASSES 10                  /* solves: least squares + reweightings */
#define PO_SPEC_CONE_DEG 20.0         /* samples this close to the mirror direction left out:
                                         the highlight of a varnish (k ≈ 80) without losing a
                                         dome ring at 55° (40° would, for a level surface) */
#define PO_MIN_SAMPLES 5              /* 3 unknowns, 2 to spare for the residual σ */
#define PO_MAX_DEV_DEG 85.0           /* a normal may tilt this far from the camera axis */
#define PO_SHADOWED_FRAC 0.5          /* fewer than this fraction of lit samples used → SHADOWED */
#define PO_DARK_FRAC 0.5              /* more than this fraction of samples dark → DARK */
#define PO_FAR_MM 1e5               /* lights farther than this are distant in copy.json */

void imp_po_options_default(struct imp_po_options *ret) {
        *ret = (struct imp_po_options) { .method = IMP_PO_ROBUST, .btf = true, .heights = true,
                                         .integrate_iterations = 4000 };
}

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

void imp_po_dome_done(struct imp_po_dome *in) {
        if (!in)
                return;
        for (int i = 0; i < in->n; i++) {
                imp_image_free(in->value[i]);
                imp_image_free(in->flags[i]);
        }
        free(in->value);
        free(in->flags);
        free(in->lights);
        free(in->mask);
        *in = (struct imp_po_dome) {};
}

/* One light's distinct exposures (the first frame of each; repeats are not averaged). */
struct light_stack {
        int light;
        size_t idx[PO_MAX_EXPOSURES];
        int n;
};

static int group_by_light(const struct imp_captureset *cs, const char *camera, struct light_stack **ret, int *ret_n) {
        size_t count = imp_captureset_count(cs);
        struct light_stack *v = calloc(count ? count : 1, sizeof *v);
        int n = 0;
        if (!v)
                return -ENOMEM;
        for (size_t i = 0; i < count; i++) {
                const struct imp_frame_record *r = imp_captureset_record(cs, i);
                if (strcmp(r->step, "dome") || strcmp(r->camera, camera) || r->tile != 0 || r->light < 0)
                        continue;
                int k = n - 1;
                while (k >= 0 && v[k].light != r->light)
                        k--;
                if (k < 0) {
                        k = n++;
                        v[k].light = r->light;
                }
                bool have = false;
                for (int e = 0; e < v[k].n && !have; e++) {
                        const struct imp_frame_record *q = imp_captureset_record(cs, v[k].idx[e]);
                        have = q->exposure_us == r->exposure_us && q->gain_db == r->gain_db;
                }
                if (!have && v[k].n < PO_MAX_EXPOSURES)
                        v[k].idx[v[k].n++] = i;
        }
        *ret = v;
        *ret_n = n;
        return 0;
}

static int merge_light(const struct imp_captureset *cs, const struct light_stack *s, const struct imp_sensor *sensor,
                       struct imp_hdr_result *ret, struct imp_error *err) {
        struct imp_image *frames[PO_MAX_EXPOSURES] = {};
        struct imp_hdr_exposure ex[PO_MAX_EXPOSURES];
        int r = 0;
        for (int e = 0; e < s->n && r >= 0; e++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, s->idx[e]);
                r = imp_captureset_load_frame(cs, s->idx[e], &frames[e], err);
                ex[e] = (struct imp_hdr_exposure) { frames[e], rec->exposure_us, rec->gain_db, 1 };
        }
        if (r >= 0) {
                struct imp_hdr_options opt;
                imp_hdr_options_default(&opt);
                opt.demosaic = true;
                r = imp_hdr_merge(ex, (size_t) s->n, sensor, &opt, ret);
                if (r < 0)
                        imp_error_set(err, r, "%s: light %d: HDR merge failed: %s", imp_captureset_dir(cs), s->light,
                                      strerror(-r));
        }
        for (int e = 0; e < s->n; e++)
                imp_image_free(frames[e]);
        return r;
}

/* Surface point of pixel (x, y): the camera ray on the world plane z = 0. */
bool imp_po_pixel_point(const struct imp_pinhole *m, double x, double y, double ret_X[3]) {
        double o[3], d[3], px[2] = { x, y };
        imp_pinhole_ray_world(m, px, o, d);
        if (!(fabs(d[2]) > 1e-12))
                return false;
        double t = -o[2] / d[2];
        if (!(t > 0))
                return false;
        for (int k = 0; k < 3; k++)
                ret_X[k] = o[k] + t * d[k];
        return true;
}

static int load_dome(const struct imp_captureset *cs, struct imp_po_dome *in, struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        if (rig->n_cameras < 1)
                return imp_error_set(err, -EINVAL, "%s/rig.json: no camera", in->dir);
        in->camera = rig->cameras[0];
        _cleanup_free_ struct light_stack *st = NULL;
        int n = 0, r = group_by_light(cs, in->camera.name, &st, &n);
        if (r < 0)
                return imp_error_set(err, r, "out of memory");
        if (n < 3)
                return imp_error_set(err, -EINVAL, "%s/manifest.jsonl: %d dome lights for camera %s: photometric "
                                     "processing needs at least 3", in->dir, n, in->camera.name);
        if (n > IMP_BTF_MAX_SAMPLES)
                return imp_error_set(err, -EINVAL, "%s: %d dome lights, at most %d", in->dir, n, IMP_BTF_MAX_SAMPLES);
        in->value = calloc((size_t) n, sizeof *in->value);
        in->flags = calloc((size_t) n, sizeof *in->flags);
        in->lights = calloc((size_t) n, sizeof *in->lights);
        if (!in->value || !in->flags || !in->lights)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (int i = 0; i < n; i++) {
                const struct imp_rig_light *L = NULL;
                for (int k = 0; k < rig->n_lights && !L; k++)
                        if (rig->lights[k].id == st[i].light)
                                L = &rig->lights[k];
                if (!L)
                        return imp_error_set(err, -EINVAL, "%s/manifest.jsonl: frame %zu: light %d is not in rig.json",
                                             in->dir, st[i].idx[0], st[i].light);
                struct imp_hdr_result hr = {};
                if ((r = merge_light(cs, &st[i], &in->camera.sensor, &hr, err)) < 0)
                        return r;
                in->lights[i] = *L;
                in->value[i] = TAKE_PTR(hr.value);
                in->flags[i] = TAKE_PTR(hr.flags);
                in->n = i + 1;
                imp_hdr_result_done(&hr);
                if (in->value[i]->width != in->value[0]->width || in->value[i]->height != in->value[0]->height ||
                    in->value[i]->channels != in->value[0]->channels)
                        return imp_error_set(err, -EINVAL, "%s: light %d: frame size differs from light %d's",
                                             in->dir, st[i].light, st[0].light);
        }
        in->width = in->value[0]->width;
        in->height = in->value[0]->height;
        in->channels = in->value[0]->channels;
        return 0;
}

/* The optional mask.png of the set, and the pixel footprint (import.json, else the camera's
 * at the image centre on z = 0). */
static int load_mask_and_pitch(struct imp_po_dome *in, struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%s/mask.png", in->dir);
        _cleanup_image_ struct imp_image *m = NULL;
        if (access(path, F_OK) == 0) {
                int r = imp_png_read(path, &m, err);
                if (r < 0)
                        return r;
                if (m->width != in->width || m->height != in->height)
                        return imp_error_set(err, -EINVAL, "%s: %dx%d, the frames are %dx%d", path, m->width,
                                             m->height, in->width, in->height);
                if (!(in->mask = malloc((size_t) in->width * in->height)))
                        return imp_error_set(err, -ENOMEM, "out of memory");
                for (int y = 0; y < in->height; y++)
                        for (int x = 0; x < in->width; x++)
                                in->mask[(size_t) y * in->width + x] = imp_image_get(m, x, y, 0) > 0;
        }
        double a[3], b[3], cx = in->camera.model.cx, cy = in->camera.model.cy;
        if (!imp_po_pixel_point(&in->camera.model, cx, cy, a) || !imp_po_pixel_point(&in->camera.model, cx + 1, cy, b))
                return imp_error_set(err, -EINVAL, "%s/rig.json: camera %s does not see the plane z = 0", in->dir,
                                     in->camera.name);
        in->pixel_mm = sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
        snprintf(path, sizeof path, "%s/import.json", in->dir);
        if (access(path, F_OK) == 0) {
                _cleanup_json_ json_t *j = NULL;
                int r = imp_json_load(path, &j, err);
                if (r < 0)
                        return r;
                double p = 0;
                if (imp_json_get_double(j, "pixel_mm", false, &p, path, err) == 0 && p > 0)
                        in->pixel_mm = p;
        }
        return 0;
}

int imp_po_dome_load(const char *capture_dir, struct imp_po_dome *ret, struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        struct imp_po_dome d = { .dir = capture_dir };
        int r = imp_captureset_open(capture_dir, &cs, err);
        if (r >= 0 && (r = load_dome(cs, &d, err)) >= 0)
                r = load_mask_and_pitch(&d, err);
        if (r < 0) {
                imp_po_dome_done(&d);
                return r;
        }
        *ret = d;
        return 0;
}

/* ---- per pixel ------------------------------------------------------------------------ */

struct po_counts {
        int lit, saturated, dark;
};

/* The samples of pixel (x, y) in the world frame (z = the plane's normal), per-channel
 * values divided by the light's colour. Robust: saturated and dark samples left out. */
static int pixel_samples(const struct imp_po_dome *in, enum imp_po_method method, int x, int y, struct imp_btf_sample *out,
                         struct po_counts *cnt) {
        double X[3], C[3], v[3];
        *cnt = (struct po_counts) {};
        if (!imp_po_pixel_point(&in->camera.model, x, y, X))
                return 0;
        imp_pinhole_centre(&in->camera.model, C);
        double vl = sqrt((C[0] - X[0]) * (C[0] - X[0]) + (C[1] - X[1]) * (C[1] - X[1]) + (C[2] - X[2]) * (C[2] - X[2]));
        for (int k = 0; k < 3; k++)
                v[k] = (C[k] - X[k]) / vl;
        int m = 0;
        for (int i = 0; i < in->n; i++) {
                const struct imp_rig_light *L = &in->lights[i];
                double d[3], dl = 0;
                for (int k = 0; k < 3; k++) {
                        d[k] = L->pos_mm[k] - X[k];
                        dl += d[k] * d[k];
                }
                dl = sqrt(dl);
                if (!(d[2] > 0))
                        continue;
                cnt->lit++;
                const float *val = imp_image_f32(in->value[i], x, y);
                const uint8_t *fl = imp_image_u8(in->flags[i], x, y);
                bool sat = false, dark = false;
                for (int c = 0; c < in->channels; c++) {
                        sat |= fl[c] & IMP_HDR_SATURATED;
                        dark |= fl[c] & IMP_HDR_DARK;
                }
                cnt->saturated += sat;
                cnt->dark += dark;
                if (method == IMP_PO_ROBUST && (sat || dark))
                        continue;
                struct imp_btf_sample *s = &out[m++];
                double E = imp_btf_light_irradiance(L, X);
                for (int k = 0; k < 3; k++) {
                        s->l[k] = (float) (d[k] / dl);
                        s->v[k] = (float) v[k];
                        int c = in->channels == 3 ? k : 0;
                        s->value[k] = (float) (val[c] / (L->colour[k] > 0 ? L->colour[k] : 1.0));
                }
                s->e_cos = (float) (E * d[2] / dl);
        }
        return m;
}

static void photometric_params(enum imp_po_method method, struct imp_photometric_params *p) {
        imp_photometric_params_default(p);
        p->max_dev_deg = PO_MAX_DEV_DEG;
        if (method == IMP_PO_WOODHAM) {
                p->min_samples = 3;
                p->passes = 1;
                p->spec_cone_deg = 0;    /* cos 0 = 1: no sample is in the cone */
                p->min_cos = -2;         /* no attached-shadow test */
                p->max_cond = 1e12;
                /* the plain baseline: none of the model checks that back a texel off */
                p->max_ambient_rel = INFINITY;
                p->max_rms_ratio = INFINITY;
                p->max_rel_rms = INFINITY;
                p->max_sigma_deg = INFINITY;
        } else {
                p->passes = PO_PASSES;
                p->spec_cone_deg = PO_SPEC_CONE_DEG;
                p->min_samples = PO_MIN_SAMPLES;
                p->shadow_trim_sigma = PO_SHADOW_TRIM_SIGMA;
        }
}

/* Output planes, one value (or 3) per pixel. */
struct po_out {
        float *normal;                 /* 3, image frame: x right, y up, z towards the camera */
        float *albedo;                 /* 3 */
        float *sigma_deg;
        uint16_t *flags;               /* IMP_TEXEL_* */
        struct imp_btf_texel *tex;     /* NULL without btf */
};

/* World-frame vector → image frame (x right, y up, z towards the camera). */
static void to_image(const struct imp_pinhole *m, const double w[3], float ret[3]) {
        double c[3];
        for (int j = 0; j < 3; j++)
                c[j] = m->R[3 * j] * w[0] + m->R[3 * j + 1] * w[1] + m->R[3 * j + 2] * w[2];
        ret[0] = (float) c[0];
        ret[1] = (float) -c[1];
        ret[2] = (float) -c[2];
}

static uint16_t texel_flags(const struct imp_pn_texel *t, const struct po_counts *c, int m) {
        uint16_t f = 0;
        if (c->saturated)
                f |= IMP_TEXEL_SATURATED;
        if ((t->flags & IMP_PN_DARK) || c->dark > PO_DARK_FRAC * c->lit)
                f |= IMP_TEXEL_DARK;
        if (t->flags & IMP_PN_FEW_SAMPLES)
                f |= IMP_TEXEL_FEW_SAMPLES;
        if (t->flags & IMP_PN_KEPT)
                f |= IMP_TEXEL_PHOTOMETRIC_REJECTED;
        if (m > 0 && t->n_used < PO_SHADOWED_FRAC * m)
                f |= IMP_TEXEL_SHADOWED;
        return f;
}

/* The Lafortune fit of the pixel's samples in the local frame of its normal n (world). */
static void fit_pixel(struct imp_btf_sample *s, int m, const double n[3], const struct imp_btf_fit_params *fp,
                      struct imp_btf_texel *ret) {
        double t[3], b[3];
        imp_local_frame(n, t, b);
        for (int i = 0; i < m; i++) {
                double l[3] = { s[i].l[0], s[i].l[1], s[i].l[2] }, v[3] = { s[i].v[0], s[i].v[1], s[i].v[2] };
                double E = s[i].e_cos / s[i].l[2];
                s[i].l[0] = (float) (l[0] * t[0] + l[1] * t[1] + l[2] * t[2]);
                s[i].l[1] = (float) (l[0] * b[0] + l[1] * b[1] + l[2] * b[2]);
                s[i].l[2] = (float) (l[0] * n[0] + l[1] * n[1] + l[2] * n[2]);
                s[i].v[0] = (float) (v[0] * t[0] + v[1] * t[1] + v[2] * t[2]);
                s[i].v[1] = (float) (v[0] * b[0] + v[1] * b[1] + v[2] * b[2]);
                s[i].v[2] = (float) (v[0] * n[0] + v[1] * n[1] + v[2] * n[2]);
                s[i].e_cos = (float) (E * s[i].l[2]);
        }
        imp_btf_fit_texel(s, m, fp, ret);
}

/* Per-channel albedo: the mean albedo split in the ratio of the channels' shading. */
static void channel_albedo(const struct imp_btf_sample *s, int m, float albedo, float ret[3]) {
        double sum[3] = { 0, 0, 0 };
        for (int i = 0; i < m; i++)
                for (int c = 0; c < 3; c++)
                        sum[c] += s[i].value[c] / (s[i].e_cos / s[i].l[2]);
        double mean = (sum[0] + sum[1] + sum[2]) / 3;
        for (int c = 0; c < 3; c++)
                ret[c] = mean > 0 ? (float) (albedo * sum[c] / mean) : albedo;
}

static void solve_pixel(const struct imp_po_dome *in, const struct imp_po_options *o,
                        const struct imp_photometric_params *pp, const struct imp_btf_fit_params *fp, int x, int y,
                        struct imp_btf_sample *s, struct po_out *out) {
        size_t t = (size_t) y * in->width + x;
        struct po_counts cnt;
        struct imp_pn_texel pn;
        int m = in->mask && !in->mask[t] ? 0 : pixel_samples(in, o->method, x, y, s, &cnt);
        if (m == 0)
                cnt = (struct po_counts) {};
        imp_photometric_texel(s, m, pp, &pn);
        out->flags[t] = texel_flags(&pn, &cnt, m);
        double n[3] = { pn.n[0], pn.n[1], pn.n[2] };
        to_image(&in->camera.model, n, &out->normal[3 * t]);
        out->sigma_deg[t] = (pn.flags & IMP_PN_KEPT) ? 180.f : pn.sigma_deg;
        channel_albedo(s, m, pn.albedo, &out->albedo[3 * t]);
        if (out->tex) {
                if (pn.flags & IMP_PN_KEPT)
                        out->tex[t] = (struct imp_btf_texel) { .cz = 1, .k = (float) fp->k_default,
                                                               .flags = IMP_BTF_MASKED };
                else
                        fit_pixel(s, m, n, fp, &out->tex[t]);
        }
}

struct po_stats {
        long pixels, refined, flag_count[IMP_TEXEL_FLAG_COUNT];
        double sigma_deg_median;
};

static void solve_all(const struct imp_po_dome *in, const struct imp_po_options *o, struct po_out *out) {
        struct imp_photometric_params pp;
        struct imp_btf_fit_params fp;
        photometric_params(o->method, &pp);
        imp_btf_fit_params_default(&fp);
        #pragma omp parallel for schedule(dynamic, 4)
        for (int y = 0; y < in->height; y++) {
                struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];   /* 20 KiB per thread */
                for (int x = 0; x < in->width; x++)
                        solve_pixel(in, o, &pp, &fp, x, y, s, out);
        }
}

/* ---- heights, files ------------------------------------------------------------------- */

/* Least-squares integration of the normals (fuse.h with every pixel an unknown without a
 * position: mask value 2), from z = 0, on the pixel grid (rows go down, so the grid's y
 * slope is −(−ny)/nz). Pixels whose normal was rejected are left out (height 0, mask 0). */
static int integrate(const struct imp_po_dome *in, const struct imp_po_options *o, const struct po_out *out,
                     float *height, uint8_t *mask, json_t **ret) {
        size_t nt = (size_t) in->width * in->height;
        _cleanup_free_ float *ng = malloc(nt * 3 * sizeof *ng);
        if (!ng)
                return -ENOMEM;
        for (size_t t = 0; t < nt; t++) {
                bool ok = !(out->flags[t] & IMP_TEXEL_PHOTOMETRIC_REJECTED) && (!in->mask || in->mask[t]);
                mask[t] = ok ? 2 : 0;
                height[t] = 0;
                ng[3 * t] = out->normal[3 * t];
                ng[3 * t + 1] = -out->normal[3 * t + 1];
                ng[3 * t + 2] = out->normal[3 * t + 2];
        }
        struct imp_fuse_params fp;
        struct imp_fuse_stats fs = {};
        imp_fuse_params_default(&fp);
        fp.max_iter = o->integrate_iterations;
        double t0 = now_s();
        int r = imp_fuse_heights(in->width, in->height, in->pixel_mm, height, ng, NULL, mask, &fp, NULL, &fs);
        if (r < 0)
                return r;
        /* the integration fixes the heights up to one constant per region: mean 0 */
        double sum = 0;
        long cnt = 0;
        for (size_t t = 0; t < nt; t++)
                if (mask[t]) {
                        sum += height[t];
                        cnt++;
                }
        for (size_t t = 0; t < nt; t++)
                height[t] = mask[t] ? (float) (height[t] - sum / (cnt ? cnt : 1)) : 0.f;
        *ret = json_pack("{s:s,s:I,s:I,s:i,s:f,s:f,s:f}",
                         "method", "least-squares integration of central-difference slopes (Poisson), conjugate gradients from 0",
                         "pixels", (json_int_t) fs.n_texels, "gradient_rows", (json_int_t) fs.n_rows,
                         "iterations", fs.iterations, "residual_rel", fs.residual_rel,
                         "normal_agreement_deg", fs.agree_deg_after, "seconds", now_s() - t0);
        return *ret ? 0 : -ENOMEM;
}

static int write_exr_planes(const char *dir, const char *name, int w, int h, int nch, const float *const *planes,
                            const int *stride, const char *const *names, bool half, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_new(w, h, nch, IMP_PIX_F32, &img);
        if (r < 0)
                return imp_error_set(err, r, "%s/%s: cannot allocate", dir, name);
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t t = (size_t) y * w + x;
                        float *p = imp_image_f32(img, x, y);
                        for (int c = 0; c < nch; c++)
                                p[c] = planes[c][t * (size_t) stride[c]];
                }
        char path[4200];
        snprintf(path, sizeof path, "%s/%s", dir, name);
        return imp_exr_write(path, img, names, half, err);
}

/* heightfield.exr and albedo.exr. */
static int write_geometry(const char *dir, const struct imp_po_dome *in, const struct po_out *out, const float *height,
                          const uint8_t *mask, struct imp_error *err) {
        size_t nt = (size_t) in->width * in->height;
        _cleanup_free_ float *fl = malloc(nt * 2 * sizeof *fl);
        if (!fl)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t t = 0; t < nt; t++) {
                fl[t] = out->flags[t];
                fl[nt + t] = mask[t] ? 1.f : 0.f;
        }
        const float *hp[] = { height, out->normal, out->normal + 1, out->normal + 2, out->sigma_deg, fl, fl + nt };
        static const int hs[] = { 1, 3, 3, 3, 1, 1, 1 };
        static const char *const hn[] = { "height", "nx", "ny", "nz", "sigma_deg", "flags", "mask" };
        int r = write_exr_planes(dir, "heightfield.exr", in->width, in->height, 7, hp, hs, hn, false, err);
        if (r < 0)
                return r;
        const float *ap[] = { out->albedo, out->albedo + 1, out->albedo + 2 };
        static const int as[] = { 3, 3, 3 };
        static const char *const rgb[] = { "R", "G", "B" };
        return write_exr_planes(dir, "albedo.exr", in->width, in->height, 3, ap, as, rgb, true, err);
}

/* rho_d.exr, rho_s.exr, lobe.exr, fit-flags.exr as process.c writes them. */
static int write_btf(const char *dir, const struct imp_po_dome *in, const struct imp_btf_texel *tex, struct imp_error *err) {
        size_t nt = (size_t) in->width * in->height;
        _cleanup_free_ float *f = malloc(nt * 11 * sizeof *f);
        if (!f)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t t = 0; t < nt; t++) {
                const struct imp_btf_texel *x = &tex[t];
                float v[11] = { x->rho_d[0], x->rho_d[1], x->rho_d[2], x->rho_s[0], x->rho_s[1], x->rho_s[2],
                                x->cx, x->cy, x->cz, x->k, x->flags };
                for (int c = 0; c < 11; c++)
                        f[c * nt + t] = v[c];
        }
        static const int one[] = { 1, 1, 1, 1 };
        static const char *const rgb[] = { "R", "G", "B" }, *const lobe[] = { "cx", "cy", "cz", "k" };
        static const char *const flags[] = { "flags" };
        const float *d[] = { f, f + nt, f + 2 * nt }, *s[] = { f + 3 * nt, f + 4 * nt, f + 5 * nt };
        const float *l[] = { f + 6 * nt, f + 7 * nt, f + 8 * nt, f + 9 * nt }, *fl[] = { f + 10 * nt };
        int r;
        if ((r = write_exr_planes(dir, "rho_d.exr", in->width, in->height, 3, d, one, rgb, true, err)) < 0 ||
            (r = write_exr_planes(dir, "rho_s.exr", in->width, in->height, 3, s, one, rgb, true, err)) < 0 ||
            (r = write_exr_planes(dir, "lobe.exr", in->width, in->height, 4, l, one, lobe, true, err)) < 0)
                return r;
        return write_exr_planes(dir, "fit-flags.exr", in->width, in->height, 1, fl, one, flags, true, err);
}

static int cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return (x > y) - (x < y);
}

/* True when some light is close enough for its direction to vary over the image. */
static bool near_field(const struct imp_po_dome *in) {
        for (int i = 0; i < in->n; i++) {
                const double *p = in->lights[i].pos_mm;
                if (sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]) < PO_FAR_MM)
                        return true;
        }
        return false;
}

static json_t *stage_json(const struct imp_po_dome *in, const struct imp_po_options *o, const struct po_out *out) {
        size_t nt = (size_t) in->width * in->height, refined = 0, counted = 0;
        long fc[IMP_TEXEL_FLAG_COUNT] = {};
        _cleanup_free_ float *sig = malloc(nt * sizeof *sig);
        for (size_t t = 0; t < nt; t++) {
                if (in->mask && !in->mask[t])
                        continue;
                counted++;
                for (unsigned b = 0; b < IMP_TEXEL_FLAG_COUNT; b++)
                        fc[b] += (out->flags[t] >> b) & 1;
                if (!(out->flags[t] & IMP_TEXEL_PHOTOMETRIC_REJECTED) && sig)
                        sig[refined++] = out->sigma_deg[t];
        }
        if (sig && refined)
                qsort(sig, refined, sizeof *sig, cmp_float);
        json_t *flags = json_object();
        for (unsigned b = 0; b < IMP_TEXEL_FLAG_COUNT; b++)
                if (fc[b])
                        json_object_set_new(flags, imp_texel_flag_name(b), json_integer(fc[b]));
        return json_pack("{s:s,s:i,s:b,s:f,s:I,s:I,s:f,s:o}",
                         "method", o->method == IMP_PO_WOODHAM ? "woodham" : "robust",
                         "lights", in->n, "near_field", near_field(in),
                         "pixel_mm", in->pixel_mm, "pixels", (json_int_t) counted, "refined", (json_int_t) refined,
                         "sigma_deg_median", refined && sig ? sig[refined / 2] : 180.0, "flags", flags);
}

static int write_copy_json(const char *capture_dir, const char *copy_dir, const struct imp_po_dome *in, json_t *stage,
                           double seconds, struct imp_error *err) {
        _cleanup_json_ json_t *j = json_pack("{s:s,s:i,s:s,s:s,s:f,s:i,s:i,s:s,s:{s:s,s:s,s:f},s:{s:o}}",
                "format", "impasto-digital-copy", "version", 1, "units", "mm", "grid", "image",
                "pitch_mm", in->pixel_mm, "nx", in->width, "ny", in->height,
                "normal_frame", "image: x right, y up, z towards the camera",
                "provenance", "software", "impasto " IMPASTO_VERSION_STRING, "capture", capture_dir,
                              "seconds", seconds,
                "stages", "photometric_only", stage);
        if (!j)
                return imp_error_set(err, -ENOMEM, "out of memory");
        char path[4200];
        snprintf(path, sizeof path, "%s/copy.json", copy_dir);
        return imp_json_save_atomic(path, j, err);
}

static int run(const char *capture_dir, const char *copy_dir, const struct imp_po_options *o, struct imp_po_dome *in,
               struct imp_error *err) {
        double t0 = now_s();
        int r = imp_po_dome_load(capture_dir, in, err);
        if (r < 0)
                return r;
        if ((r = imp_mkdir_p(copy_dir, 0755)) < 0)
                return imp_error_set(err, r, "%s: cannot create the copy directory: %s", copy_dir, strerror(-r));
        size_t nt = (size_t) in->width * in->height;
        _cleanup_free_ float *planes = malloc(nt * 9 * sizeof *planes);
        _cleanup_free_ uint16_t *flags = malloc(nt * sizeof *flags);
        _cleanup_free_ uint8_t *mask = malloc(nt);
        _cleanup_free_ struct imp_btf_texel *tex = o->btf ? calloc(nt, sizeof *tex) : NULL;
        if (!planes || !flags || !mask || (o->btf && !tex))
                return imp_error_set(err, -ENOMEM, "out of memory");
        struct po_out out = { planes, planes + 3 * nt, planes + 6 * nt, flags, tex };
        float *height = planes + 7 * nt;
        double t_load = now_s();
        solve_all(in, o, &out);
        double t_solve = now_s();
        json_t *stage = stage_json(in, o, &out), *integ = NULL;
        if (!stage)
                return imp_error_set(err, -ENOMEM, "out of memory");
        json_object_set_new(stage, "seconds_load", json_real(t_load - t0));
        json_object_set_new(stage, "seconds_solve", json_real(t_solve - t_load));
        if (o->heights && (r = integrate(in, o, &out, height, mask, &integ)) < 0) {
                json_decref(stage);
                return imp_error_set(err, r, "%s: height integration failed: %s", capture_dir, strerror(-r));
        }
        if (!o->heights)
                for (size_t t = 0; t < nt; t++) {
                        height[t] = 0;
                        mask[t] = !(out.flags[t] & IMP_TEXEL_PHOTOMETRIC_REJECTED) && (!in->mask || in->mask[t]);
                }
        json_object_set_new(stage, "integration", integ ? integ : json_null());
        if ((r = write_geometry(copy_dir, in, &out, height, mask, err)) < 0 ||
            (tex && (r = write_btf(copy_dir, in, tex, err)) < 0)) {
                json_decref(stage);
                return r;
        }
        return write_copy_json(capture_dir, copy_dir, in, stage, now_s() - t0, err);
}

int imp_process_photometric(const char *capture_dir, const char *copy_dir, const struct imp_po_options *o,
                            struct imp_error *err) {
        if (!capture_dir || !copy_dir || !o || o->integrate_iterations < 0)
                return imp_error_set(err, -EINVAL, "photometric-only processing: bad arguments");
#ifdef _OPENMP
        int threads_before = omp_get_max_threads();
        if (o->threads > 0)
                omp_set_num_threads(o->threads);
#endif
        struct imp_po_dome in = {};
        int r = run(capture_dir, copy_dir, o, &in, err);
        imp_po_dome_done(&in);
#ifdef _OPENMP
        omp_set_num_threads(threads_before);
#endif
        return r;
}
