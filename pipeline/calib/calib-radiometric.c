/* Radiometric calibration: photon transfer (mean–variance) for the camera, phase-shift
 * gamma for the projector. docs/calibration-lights.md explains the choices. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "calib-radiometric.h"
#include "captureset.h"
#include "macro.h"
#include "numerics.h"

#define QUANTISATION_VAR_DN2 (1.0 / 12.0)   /* rounding to integer DN */
#define SAT_VAR_DROP 0.5                    /* variance below this × max so far: saturated */
#define SAT_CLIP_FRACTION 0.001
#define SAT_MARGIN_SIGMA 4.0
#define NONLINEAR_PCT 1.0
#define UNDETERMINED_SIGMA 1e30
#define GAMMA_LO 0.3
#define GAMMA_HI 5.0
#define GAMMA_ITERS 60

static bool same_shape(const struct imp_image *a, const struct imp_image *b) {
        return a && b && a->width == b->width && a->height == b->height;
}

/* Mean of (a + b)/2, variance of (a − b)/2·… over the ROI: ret[0] mean, ret[1] var(a−b)/2,
 * ret[2] spatial variance of a, ret[3] fraction at the clip code (either frame). */
static void pair_stats(const struct imp_image *a, const struct imp_image *b, const int roi[4], double clip,
                       double ret[4]) {
        double s = 0, sd = 0, sdd = 0, sa = 0, saa = 0;
        long n = 0, nc = 0;
        for (int y = roi[1]; y < roi[1] + roi[3]; y++)
                for (int x = roi[0]; x < roi[0] + roi[2]; x++) {
                        double va = imp_image_get(a, x, y, 0), vb = b ? imp_image_get(b, x, y, 0) : va;
                        double d = va - vb;
                        s += 0.5 * (va + vb);
                        sd += d;
                        sdd += d * d;
                        sa += va;
                        saa += va * va;
                        nc += va >= clip || vb >= clip;
                        n++;
                }
        double md = sd / n, ma = sa / n;
        ret[0] = s / n;
        ret[1] = n > 1 ? (sdd - n * md * md) / (n - 1) / 2 : 0;
        ret[2] = n > 1 ? (saa - n * ma * ma) / (n - 1) : 0;
        ret[3] = (double) nc / n;
}

/* Checks the input and sets the ROI (x, y, w, h): 0 or -EINVAL (err says why). */
static int check_input(const struct imp_ptc_input *in, int roi[4], struct imp_error *err) {
        if (in->n_levels < 1 || in->n_levels > IMP_PTC_MAX_LEVELS || !in->levels ||
            in->n_darks < 1 || !in->darks || in->bits < 1 || in->bits > 16)
                return imp_error_set(err, -EINVAL, "photon transfer: bad arguments (levels 1..%d, ≥ 1 dark, bits 1..16)",
                                     IMP_PTC_MAX_LEVELS);
        const struct imp_image *ref = in->darks[0];
        for (int i = 0; i < in->n_darks; i++)
                if (!same_shape(ref, in->darks[i]))
                        return imp_error_set(err, -EINVAL, "photon transfer: dark frame %d differs in size", i);
        for (int i = 0; i < in->n_levels; i++)
                if (!same_shape(ref, in->levels[i].a) || !same_shape(ref, in->levels[i].b) ||
                    !(in->levels[i].exposure_us > 0))
                        return imp_error_set(err, -EINVAL, "photon transfer: level %d: missing frame, size differs "
                                             "from the darks, or exposure ≤ 0", i);
        roi[0] = roi[1] = 0, roi[2] = ref->width, roi[3] = ref->height;
        if (in->roi[2] > 0) {
                memcpy(roi, in->roi, 4 * sizeof *roi);
                if (roi[0] < 0 || roi[1] < 0 || roi[3] < 1 || roi[0] + roi[2] > ref->width || roi[1] + roi[3] > ref->height)
                        return imp_error_set(err, -EINVAL, "photon transfer: ROI outside the %dx%d frame", ref->width,
                                             ref->height);
        }
        return 0;
}

/* The points of every level, in exposure order, into out->points; sp_sd[k] the spatial σ
 * of point k; saturation (the first level whose variance drops below SAT_VAR_DROP × the
 * largest so far, or that clips) and every later level flagged saturated; *ret_sat_mean
 * the largest mean among them (∞ when none). */
static void level_points(const struct imp_ptc_input *in, const int roi[4], double clip, double black,
                         struct imp_ptc_result *out, double *sp_sd, double *ret_sat_mean) {
        double st[4];
        int order[IMP_PTC_MAX_LEVELS];
        for (int i = 0; i < in->n_levels; i++)
                order[i] = i;
        for (int i = 1; i < in->n_levels; i++)
                for (int j = i; j > 0 && in->levels[order[j]].exposure_us < in->levels[order[j - 1]].exposure_us; j--) {
                        int t = order[j]; order[j] = order[j - 1]; order[j - 1] = t;
                }
        double vmax = 0, sat_mean = INFINITY, sat_exp = INFINITY;
        for (int k = 0; k < in->n_levels; k++) {
                const struct imp_ptc_level *L = &in->levels[order[k]];
                struct imp_ptc_point *p = &out->points[k];
                pair_stats(L->a, L->b, roi, clip, st);
                *p = (struct imp_ptc_point) { .exposure_us = L->exposure_us, .mean_dn = st[0] - black,
                                              .var_dn2 = st[1], .clip_fraction = st[3] };
                sp_sd[k] = sqrt(IMP_MAX(st[2], 0.0));
                if (!isfinite(sat_exp) && (st[1] < SAT_VAR_DROP * vmax || st[3] > SAT_CLIP_FRACTION)) {
                        sat_mean = p->mean_dn;
                        sat_exp = L->exposure_us;
                        out->flags |= IMP_PTC_SATURATION_FOUND;
                }
                if (!isfinite(sat_exp))
                        vmax = IMP_MAX(vmax, st[1]);
        }
        /* the saturation mean: the largest mean among saturated levels (clip plateau) */
        for (int k = 0; k < in->n_levels; k++)
                if (out->points[k].exposure_us >= sat_exp) {
                        out->points[k].saturated = true;
                        sat_mean = IMP_MAX(sat_mean, out->points[k].mean_dn);
                }
        *ret_sat_mean = sat_mean;
}

int imp_radiometric_ptc(const struct imp_ptc_input *in, struct imp_ptc_result *ret, struct imp_error *err) {
        if (!in || !ret)
                return imp_error_set(err, -EINVAL, "photon transfer: bad arguments");
        int roi[4], rc = check_input(in, roi, err);
        if (rc < 0)
                return rc;
        double clip = (double) ((1u << in->bits) - 1), st[4];
        struct imp_ptc_result out = { .sensor.bits = in->bits, .n_points = in->n_levels };

        /* black level and read noise from the darks */
        double black = 0;
        for (int i = 0; i < in->n_darks; i++) {
                pair_stats(in->darks[i], NULL, roi, clip, st);
                black += st[0] / in->n_darks;
        }
        double var_dark = -1;
        if (in->n_darks >= 2) {
                pair_stats(in->darks[0], in->darks[1], roi, clip, st);
                var_dark = st[1];
        }
        out.sensor.black_level_dn = black;

        /* per level, in exposure order */
        double sp_sd[IMP_PTC_MAX_LEVELS], sat_mean;
        level_points(in, roi, clip, black, &out, sp_sd, &sat_mean);

        /* weighted fit var = q + s·mean, and the linear response mean = a + b·t */
        double W = 0, Wx = 0, Wy = 0, Wxx = 0, Wxy = 0, T = 0, Tx = 0, Ty = 0, Txx = 0, Txy = 0;
        int nu = 0;
        for (int k = 0; k < in->n_levels; k++) {
                struct imp_ptc_point *p = &out.points[k];
                if (p->saturated || p->mean_dn + SAT_MARGIN_SIGMA * sp_sd[k] >= sat_mean || !(p->var_dn2 > 0))
                        continue;
                p->used = true;
                nu++;
                double w = 1 / (p->var_dn2 * p->var_dn2), x = p->mean_dn, y = p->var_dn2, t = p->exposure_us;
                W += w; Wx += w * x; Wy += w * y; Wxx += w * x * x; Wxy += w * x * y;
                T += 1; Tx += t; Ty += x; Txx += t * t; Txy += t * x;
        }
        double det = W * Wxx - Wx * Wx, slope = det > 0 ? (W * Wxy - Wx * Wy) / det : 0;
        double icpt = det > 0 ? (Wy - slope * Wx) / W : 0;
        double gscale = pow(10.0, in->gain_db / 20.0);   /* e/DN at gain_db = g₀ · 10^(−gain_db/20) */
        if (nu < 3 || !(slope > 0)) {
                out.flags |= IMP_PTC_FEW_LEVELS;
                out.sensor.gain_e_per_dn = 1;
                out.gain_sigma_e_per_dn = UNDETERMINED_SIGMA;
        } else {
                double g = 1 / slope;
                /* residual-scaled slope variance: Var(s) = χ²/(n−2) · W/det */
                double chi2 = 0;
                for (int k = 0; k < in->n_levels; k++)
                        if (out.points[k].used) {
                                double r = out.points[k].var_dn2 - icpt - slope * out.points[k].mean_dn;
                                chi2 += r * r / (out.points[k].var_dn2 * out.points[k].var_dn2);
                        }
                double vs = (nu > 2 ? chi2 / (nu - 2) : 1) * W / det;
                out.sensor.gain_e_per_dn = g * gscale;
                out.gain_sigma_e_per_dn = g * g * sqrt(vs) * gscale;
        }
        double g_eff = out.sensor.gain_e_per_dn / gscale;
        out.read_noise_fit_e = icpt > QUANTISATION_VAR_DN2 ? g_eff * sqrt(icpt - QUANTISATION_VAR_DN2) : 0;
        if (var_dark >= 0) {
                out.read_noise_dark_e = g_eff * sqrt(IMP_MAX(var_dark - QUANTISATION_VAR_DN2, 0.0));
                out.sensor.read_noise_e = out.read_noise_dark_e;
        } else {
                out.flags |= IMP_PTC_READ_FROM_INTERCEPT;
                out.sensor.read_noise_e = out.read_noise_fit_e;
        }
        double tdet = T * Txx - Tx * Tx;
        if (nu >= 2 && tdet > 0) {
                out.response_dn_per_us = (T * Txy - Tx * Ty) / tdet;
                out.response_offset_dn = (Ty - out.response_dn_per_us * Tx) / T;
                double worst = 0, top = 0;
                for (int k = 0; k < in->n_levels; k++)
                        if (out.points[k].used) {
                                const struct imp_ptc_point *p = &out.points[k];
                                worst = IMP_MAX(worst, fabs(p->mean_dn - out.response_offset_dn -
                                                            out.response_dn_per_us * p->exposure_us));
                                top = IMP_MAX(top, p->mean_dn);
                        }
                out.max_nonlinearity_pct = top > 0 ? 100 * worst / top : 0;
                if (out.max_nonlinearity_pct > NONLINEAR_PCT)
                        out.flags |= IMP_PTC_NONLINEAR;
        }
        if (isfinite(sat_mean)) {
                out.saturation_dn = sat_mean;
                out.sensor.full_well_e = sat_mean * g_eff;
        }
        *ret = out;
        return 0;
}

#define PTC_MAX_DARKS 64

static bool same_light(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return !strcmp(a->camera, b->camera) && a->light == b->light && fabs(a->exposure_us - b->exposure_us) <= 1e-9 * a->exposure_us &&
               a->gain_db == b->gain_db && !memcmp(&a->pattern, &b->pattern, sizeof a->pattern) && !strcmp(a->step, b->step);
}

static int cmp_level(const void *x, const void *y) {
        const struct imp_ptc_level *a = x, *b = y;
        return (a->exposure_us > b->exposure_us) - (a->exposure_us < b->exposure_us);
}

/* The frames of one photon-transfer measurement: loaded flat pairs and darks. */
struct ptc_frames {
        struct imp_image **frames;    /* 2 × levels, then the darks */
        struct imp_ptc_level *levels;
        int nf, nl, nd;
        double gain_db;
};

static void ptc_frames_free(struct ptc_frames *f) {
        for (int i = 0; i < f->nf; i++)
                imp_image_free(f->frames[i]);
        free(f->frames);
        free(f->levels);
}

/* Flat pairs: each frame with the next unused one taken in the same light. */
static int load_pairs(const struct imp_captureset *cs, const char *cam, struct ptc_frames *f, struct imp_error *err) {
        size_t n = imp_captureset_count(cs);
        _cleanup_free_ bool *used = calloc(n + 1, sizeof *used);
        if (!used)
                return -ENOMEM;
        for (size_t i = 0; i < n && f->nl < IMP_PTC_MAX_LEVELS; i++) {
                const struct imp_frame_record *a = imp_captureset_record(cs, i);
                if (used[i] || strcmp(a->camera, cam) || !strcmp(a->step, "dark"))
                        continue;
                for (size_t k = i + 1; k < n; k++) {
                        const struct imp_frame_record *b = imp_captureset_record(cs, k);
                        if (used[k] || !same_light(a, b))
                                continue;
                        if (!isnan(f->gain_db) && a->gain_db != f->gain_db)
                                return imp_error_set(err, -EINVAL, "%s: frames at gains %g and %g dB",
                                                     imp_captureset_dir(cs), f->gain_db, a->gain_db);
                        f->gain_db = a->gain_db;
                        used[i] = used[k] = true;
                        int r = imp_captureset_load_frame(cs, i, &f->frames[f->nf], err);
                        if (r < 0)
                                return r;
                        f->nf++;
                        if ((r = imp_captureset_load_frame(cs, k, &f->frames[f->nf], err)) < 0)
                                return r;
                        f->nf++;
                        f->levels[f->nl++] = (struct imp_ptc_level) { a->exposure_us, f->frames[f->nf - 2],
                                                                      f->frames[f->nf - 1] };
                        break;
                }
        }
        return 0;
}

/* The darks of the shortest dark exposure. */
static int load_darks(const struct imp_captureset *cs, const char *cam, struct ptc_frames *f, struct imp_error *err) {
        size_t n = imp_captureset_count(cs);
        double dark_exp = INFINITY;
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (!strcmp(rec->step, "dark") && !strcmp(rec->camera, cam))
                        dark_exp = IMP_MIN(dark_exp, rec->exposure_us);
        }
        for (size_t i = 0; i < n && f->nd < PTC_MAX_DARKS; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (strcmp(rec->step, "dark") || strcmp(rec->camera, cam) || rec->exposure_us != dark_exp)
                        continue;
                int r = imp_captureset_load_frame(cs, i, &f->frames[f->nf], err);
                if (r < 0)
                        return r;
                f->nf++, f->nd++;
        }
        return 0;
}

int imp_radiometric_ptc_measure(const struct imp_captureset *cs, const char *cam, const int roi[4],
                                struct imp_ptc_result *ret, int *ret_levels, int *ret_darks, struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        const struct imp_rig_camera *camera = NULL;
        for (int i = 0; i < rig->n_cameras && !camera; i++)
                if (!strcmp(rig->cameras[i].name, cam))
                        camera = &rig->cameras[i];
        if (!camera)
                return imp_error_set(err, -ENOENT, "no camera '%s' in %s/rig.json", cam, imp_captureset_dir(cs));
        struct ptc_frames f = { .frames = calloc(2 * IMP_PTC_MAX_LEVELS + PTC_MAX_DARKS, sizeof *f.frames),
                                .levels = calloc(IMP_PTC_MAX_LEVELS, sizeof *f.levels), .gain_db = NAN };
        int r = f.frames && f.levels ? 0 : -ENOMEM;
        if (r == 0 && (r = load_pairs(cs, cam, &f, err)) == 0)
                r = load_darks(cs, cam, &f, err);
        int first_dark = f.nf - f.nd;
        if (r == 0 && (f.nl == 0 || f.nd == 0))
                r = imp_error_set(err, -ENODATA, "%s: need pairs of equal flat frames and dark frames (found %d pairs, "
                                  "%d darks of %s)", imp_captureset_dir(cs), f.nl, f.nd, cam);
        if (r == 0) {
                qsort(f.levels, (size_t) f.nl, sizeof *f.levels, cmp_level);
                struct imp_ptc_input in = { .bits = camera->sensor.bits, .gain_db = f.gain_db, .n_levels = f.nl,
                                            .levels = f.levels, .n_darks = f.nd,
                                            .darks = (const struct imp_image *const *) &f.frames[first_dark],
                                            .roi = { roi[0], roi[1], roi[2], roi[3] } };
                r = imp_radiometric_ptc(&in, ret, err);
        }
        if (r == 0 && ret_levels)
                *ret_levels = f.nl;
        if (r == 0 && ret_darks)
                *ret_darks = f.nd;
        ptc_frames_free(&f);
        return r;
}

double imp_radiometric_dn_to_value(const struct imp_sensor *s, double exposure_us, double gain_db, double dn) {
        double e_per_dn = s->gain_e_per_dn * pow(10.0, -gain_db / 20.0);
        double denom = s->quantum_scale * exposure_us * 1e-6;
        return denom > 0 ? (dn - s->black_level_dn) * e_per_dn / denom : 0;
}

/* Σ c^γ over all samples, from ln c (−∞ where c = 0). Decreasing in γ. */
static double gamma_model(const double *ln_c, size_t count, double gamma) {
        double s = 0;
        for (size_t i = 0; i < count; i++)
                s += exp(gamma * ln_c[i]);
        return s;
}

int imp_radiometric_projector_gamma(const struct imp_image *white, const struct imp_image *black,
                                    const struct imp_image *const *steps, int n_steps, double min_contrast,
                                    double *ret_gamma, int *ret_pixels) {
        if (!same_shape(white, black) || !steps || n_steps < 3 || !ret_gamma)
                return -EINVAL;
        for (int k = 0; k < n_steps; k++)
                if (!same_shape(white, steps[k]))
                        return -EINVAL;
        size_t cap = (size_t) white->width * white->height * n_steps, cnt = 0;
        _cleanup_free_ double *ln_c = malloc(cap * sizeof *ln_c);
        _cleanup_free_ double *n = malloc((size_t) n_steps * sizeof *n);
        if (!ln_c || !n)
                return -ENOMEM;
        double data = 0;   /* Σ n_k */
        int npx = 0;
        for (int y = 0; y < white->height; y++)
                for (int x = 0; x < white->width; x++) {
                        double w = imp_image_get(white, x, y, 0), b = imp_image_get(black, x, y, 0);
                        if (!(w - b > min_contrast))
                                continue;
                        /* the phase from the first Fourier coefficient of the n_k (N-step phase
                         * shifting): c^γ is even about the crest, so its fundamental keeps
                         * the pattern's phase for any γ (up to the aliased harmonics N ± 1) */
                        for (int k = 0; k < n_steps; k++) {
                                n[k] = (imp_image_get(steps[k], x, y, 0) - b) / (w - b);
                                data += n[k];
                        }
                        double theta = imp_phase_nstep(n, n_steps);
                        for (int k = 0; k < n_steps; k++) {
                                double ck = 0.5 + 0.5 * cos(theta + 2 * M_PI * k / n_steps);
                                ln_c[cnt++] = ck > 0 ? log(ck) : -INFINITY;
                        }
                        npx++;
                }
        if (npx == 0)
                return -ENOENT;
        double lo = GAMMA_LO, hi = GAMMA_HI;
        int r = 0;
        double g;
        if (!(gamma_model(ln_c, cnt, lo) > data)) {
                g = lo;
                r = 1;
        } else if (!(gamma_model(ln_c, cnt, hi) < data)) {
                g = hi;
                r = 1;
        } else {
                for (int it = 0; it < GAMMA_ITERS; it++) {
                        double mid = 0.5 * (lo + hi);
                        if (gamma_model(ln_c, cnt, mid) > data)
                                lo = mid;
                        else
                                hi = mid;
                }
                g = 0.5 * (lo + hi);
        }
        *ret_gamma = g;
        if (ret_pixels)
                *ret_pixels = npx;
        return r;
}

json_t *imp_radiometric_ptc_to_json(const struct imp_ptc_result *r) {
        json_t *pts = json_array(), *flags = json_array();
        for (int k = 0; k < r->n_points; k++) {
                const struct imp_ptc_point *p = &r->points[k];
                json_array_append_new(pts, json_pack("{s:f, s:f, s:f, s:f, s:b, s:b}", "exposure_us", p->exposure_us,
                                                     "mean_dn", p->mean_dn, "var_dn2", p->var_dn2, "clip_fraction",
                                                     p->clip_fraction, "used", p->used, "saturated", p->saturated));
        }
        static const char *const names[] = { "saturation_found", "few_levels", "read_from_intercept", "nonlinear" };
        for (unsigned i = 0; i < ARRAY_SIZE(names); i++)
                if (r->flags & (1u << i))
                        json_array_append_new(flags, json_string(names[i]));
        const struct imp_sensor *s = &r->sensor;
        return json_pack("{s:{s:i, s:f, s:f, s:f, s:f}, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:o, s:o}",
                         "sensor", "bits", s->bits, "black_level_dn", s->black_level_dn, "gain_e_per_dn",
                         s->gain_e_per_dn, "read_noise_e", s->read_noise_e, "full_well_e", s->full_well_e,
                         "gain_sigma_e_per_dn", r->gain_sigma_e_per_dn, "read_noise_dark_e", r->read_noise_dark_e,
                         "read_noise_fit_e", r->read_noise_fit_e, "response_dn_per_us", r->response_dn_per_us,
                         "response_offset_dn", r->response_offset_dn, "max_nonlinearity_pct",
                         r->max_nonlinearity_pct, "saturation_dn", r->saturation_dn, "flags", flags, "points", pts);
}
