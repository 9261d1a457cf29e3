/* The projector's gamma and black level from a set of phase-shift frames of a flat white
 * target (calib-projector-gamma.h). The gamma itself: imp_radiometric_projector_gamma();
 * here: choosing the frames, binning, the contrast threshold, the black level and the
 * block spread. docs/calibration-lights.md explains and measures the choices. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib-projector-gamma.h"
#include "calib-radiometric.h"
#include "macro.h"
#include "numerics.h"

#define GAMMA_BIN_PHASE_RAD 0.07      /* a pixel bin spans at most this much pattern phase … */
#define GAMMA_BIN_MAX 8               /* … and at most this many pixels a side */
#define GAMMA_CONTRAST_FRAC 0.25      /* pixels kept: white − black above this × … */
#define GAMMA_CONTRAST_QUANTILE 0.99  /* … this quantile of white − black over the frame */
#define GAMMA_CONTRAST_MIN_SNR 5.0    /* … which must exceed the noise of white − black this many times
                                         (pure noise: ¼ of its 99th percentile is 0.8 σ) */
#define GAMMA_CLIP_FRAC_MAX 0.001     /* an exposure whose white frame clips more is passed over */
#define GAMMA_BLOCKS 8                /* gamma_sigma: the spread of GAMMA_BLOCKS² block estimates */
#define GAMMA_BLOCK_MIN_PX 16         /* a block needs this many kept bins */
#define GAMMA_MAX_STEPS 64            /* the plan's limit on phase steps */
#define GAMMA_MAX_EXPOSURES 64        /* distinct exposures of one phase set considered */

/* The set's frames of one gamma measurement, as record indices (-1: missing). */
struct gamma_frames {
        long white, black, step[GAMMA_MAX_STEPS];
};

static bool same_exposure(double a, double b) {
        return fabs(a - b) <= 1e-9 * fmax(a, b);
}

static void free_frames(struct imp_image **v, int n) {
        for (int i = 0; i < n; i++)
                imp_image_free(v[i]);
}

/* The phase set to use: the longest period (the least blurred by the projector's and
 * camera's optics), then the most steps, then axis x before y. False when there is none. */
static bool pick_phase(const struct imp_captureset *cs, const char *cam, struct imp_projector_gamma *g) {
        bool found = false;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                const struct imp_pattern *p = &rec->pattern;
                if (strcmp(rec->camera, cam) || p->kind != IMP_PAT_PHASE || p->steps > GAMMA_MAX_STEPS)
                        continue;
                if (!found || p->period_px > g->period_px ||
                    (p->period_px == g->period_px && (p->steps > g->steps || (p->steps == g->steps && p->axis < g->axis)))) {
                        g->period_px = p->period_px;
                        g->steps = p->steps;
                        g->axis = p->axis;
                        g->tile = rec->tile;
                        found = true;
                }
        }
        return found;
}

static bool is_chosen_phase(const struct imp_frame_record *rec, const char *cam, const struct imp_projector_gamma *g) {
        const struct imp_pattern *p = &rec->pattern;
        return !strcmp(rec->camera, cam) && rec->tile == g->tile && p->kind == IMP_PAT_PHASE &&
               p->period_px == g->period_px && p->steps == g->steps && p->axis == g->axis;
}

/* White, black and every step of the chosen phase set at `exposure_us` (the first of
 * duplicates). Returns the number of frames missing, named in `what`. */
static int find_frames(const struct imp_captureset *cs, const char *cam, const struct imp_projector_gamma *g, double exposure_us,
                       struct gamma_frames *f, char *what, size_t len) {
        f->white = f->black = -1;
        for (int k = 0; k < g->steps; k++)
                f->step[k] = -1;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (strcmp(rec->camera, cam) || rec->tile != g->tile || !same_exposure(rec->exposure_us, exposure_us))
                        continue;
                if (rec->pattern.kind == IMP_PAT_WHITE && f->white < 0)
                        f->white = (long) i;
                else if (rec->pattern.kind == IMP_PAT_BLACK && f->black < 0)
                        f->black = (long) i;
                else if (is_chosen_phase(rec, cam, g) && rec->pattern.step >= 0 && rec->pattern.step < g->steps &&
                         f->step[rec->pattern.step] < 0)
                        f->step[rec->pattern.step] = (long) i;
        }
        int missing = 0, steps_missing = 0;
        size_t o = 0;
        what[0] = 0;
        if (f->white < 0)
                missing++, o += (size_t) snprintf(what + o, len - IMP_MIN(o, len), "the white frame, ");
        if (f->black < 0)
                missing++, o += (size_t) snprintf(what + o, len - IMP_MIN(o, len), "the black frame, ");
        for (int k = 0; k < g->steps; k++)
                steps_missing += f->step[k] < 0;
        if (steps_missing)
                o += (size_t) snprintf(what + o, len - IMP_MIN(o, len), "%d of the %d phase steps, ", steps_missing, g->steps);
        if (o >= 2 && o < len)
                what[o - 2] = 0;
        return missing + steps_missing;
}

static double clip_fraction(const struct imp_image *img, double clip_dn) {
        size_t n = 0;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        n += imp_image_get(img, x, y, 0) >= clip_dn;
        return (double) n / ((double) img->width * img->height);
}

/* F32 means of white, black and the steps over bin × bin pixel bins (the last partial row
 * and column dropped). Where any frame reaches the ADC clip code in a bin, its
 * white is set to its black: the bin has no contrast and is left out (a clipped white would
 * misplace every n_k there). Returns the number of such bins, or < 0. */
static int gamma_images(struct imp_image *const *raw, int n, int bin, double clip_dn, struct imp_image **f32) {
        const int w = raw[0]->width / bin, h = raw[0]->height / bin;
        for (int k = 0; k < n; k++)
                if (imp_image_new(w, h, 1, IMP_PIX_F32, &f32[k]) < 0) {
                        free_frames(f32, k);
                        memset(f32, 0, (size_t) k * sizeof *f32);
                        return -ENOMEM;
                }
        int clipped = 0;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        bool clip = false;
                        for (int k = 0; k < n; k++) {
                                double sum = 0;
                                for (int v = 0; v < bin; v++)
                                        for (int u = 0; u < bin; u++) {
                                                double dn = imp_image_get(raw[k], x * bin + u, y * bin + v, 0);
                                                sum += dn;
                                                clip |= dn >= clip_dn;
                                        }
                                *imp_image_f32(f32[k], x, y) = (float) (sum / (bin * bin));
                        }
                        if (clip) {
                                *imp_image_f32(f32[0], x, y) = *imp_image_f32(f32[1], x, y);
                                clipped++;
                        }
                }
        return clipped;
}

/* The bin size for the estimate. Averaging bin × bin pixels before normalising divides the
 * estimator's work by bin² and its one noise bias, through the division by white − black
 * (~σ²/contrast², −0.045 % on the demo target unbinned, −0.009 % in 3 × 3 bins), by about
 * as much. The mean over a bin stands for the pattern at its centre only while the phase varies little
 * across it (a profile averaged over Δφ changes by ~Δφ²/24): the bin is the most pixels
 * spanning GAMMA_BIN_PHASE_RAD at the median phase gradient of the kept pixels, with the
 * phase per pixel from the steps' first Fourier coefficient (N-step phase shifting). */
static int gamma_bin(struct imp_image *const *img, int n, double min_contrast, int *ret_bin) {
        const int w = img[0]->width, h = img[0]->height, steps = n - 2;
        _cleanup_free_ float *phase = malloc((size_t) w * h * sizeof *phase);
        _cleanup_free_ float *grad = malloc((size_t) w * h * sizeof *grad);
        if (!phase || !grad)
                return -ENOMEM;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        double v[GAMMA_MAX_STEPS];
                        for (int k = 0; k < steps; k++)
                                v[k] = *imp_image_f32(img[2 + k], x, y);
                        bool kept = *imp_image_f32(img[0], x, y) - *imp_image_f32(img[1], x, y) > min_contrast;
                        phase[(size_t) y * w + x] = kept ? (float) imp_phase_nstep(v, steps) : NAN;
                }
        size_t ng = 0;
        for (int y = 0; y + 1 < h; y++)
                for (int x = 0; x + 1 < w; x++) {
                        float p = phase[(size_t) y * w + x], px = phase[(size_t) y * w + x + 1],
                              py = phase[(size_t) (y + 1) * w + x];
                        if (isnan(p) || isnan(px) || isnan(py))
                                continue;
                        double dx = remainder(px - p, 2 * M_PI), dy = remainder(py - p, 2 * M_PI);
                        grad[ng++] = (float) hypot(dx, dy);
                }
        if (ng == 0) {
                *ret_bin = 1;
                return 0;
        }
        qsort(grad, ng, sizeof *grad, imp_cmp_float);
        double g = grad[ng / 2];
        int bin = g > 0 ? (int) IMP_CLAMP(floor(GAMMA_BIN_PHASE_RAD / g), 1.0, (double) GAMMA_BIN_MAX) : GAMMA_BIN_MAX;
        *ret_bin = IMP_MAX(IMP_MIN(bin, IMP_MIN(w, h)), 1);
        return 0;
}

/* The contrast threshold: GAMMA_CONTRAST_FRAC of the GAMMA_CONTRAST_QUANTILE of white −
 * black over the frame (robust to a few hot pixels). -ENOENT (*ret and *ret_noise set) when
 * that threshold is within GAMMA_CONTRAST_MIN_SNR of the noise of white − black, estimated
 * as 1.4826·MAD of horizontal neighbours' differences / √2 (which a smooth signal leaves
 * alone): the projector does not light the target (a relative threshold alone would keep
 * the brightest noise). */
static int contrast_threshold(const struct imp_image *white, const struct imp_image *black, double *ret,
                              double *ret_noise) {
        const int w = white->width, h = white->height;
        size_t n = (size_t) w * h, m = 0;
        _cleanup_free_ float *c = malloc(n * sizeof *c), *dd = malloc(n * sizeof *dd);
        if (!c || !dd)
                return -ENOMEM;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        float d = *imp_image_f32(white, x, y) - *imp_image_f32(black, x, y);
                        c[(size_t) y * w + x] = d;
                        if (x > 0)
                                dd[m++] = fabsf(d - c[(size_t) y * w + x - 1]);
                }
        qsort(c, n, sizeof *c, imp_cmp_float);
        *ret = GAMMA_CONTRAST_FRAC * c[(size_t) (GAMMA_CONTRAST_QUANTILE * (double) (n - 1))];
        *ret_noise = 0;
        if (m > 0) {
                qsort(dd, m, sizeof *dd, imp_cmp_float);
                *ret_noise = 1.4826 * dd[m / 2] / M_SQRT2;
        }
        return *ret > GAMMA_CONTRAST_MIN_SNR * *ret_noise ? 0 : -ENOENT;
}

/* The spread of per-block estimates: the frame cut into GAMMA_BLOCKS × GAMMA_BLOCKS blocks,
 * gamma estimated in each with GAMMA_BLOCK_MIN_PX kept bins or more (and its root inside
 * the bounds); σ = sd(blocks) / √blocks. It holds the pixel noise and whatever varies
 * across the frame; a bias common to every pixel does not show in it. */
static int gamma_blocks(struct imp_image *const *img, int n, double min_contrast, double *ret_sigma, int *ret_blocks) {
        double est[GAMMA_BLOCKS * GAMMA_BLOCKS];
        int nb = 0, w = img[0]->width, h = img[0]->height, r = 0;
        struct imp_image *sub[2 + GAMMA_MAX_STEPS] = {};
        for (int by = 0; by < GAMMA_BLOCKS; by++)
                for (int bx = 0; bx < GAMMA_BLOCKS; bx++) {
                        int x0 = bx * w / GAMMA_BLOCKS, x1 = (bx + 1) * w / GAMMA_BLOCKS;
                        int y0 = by * h / GAMMA_BLOCKS, y1 = (by + 1) * h / GAMMA_BLOCKS;
                        if (x1 <= x0 || y1 <= y0)
                                continue;
                        for (int k = 0; k < n; k++) {
                                if ((r = imp_image_new(x1 - x0, y1 - y0, 1, IMP_PIX_F32, &sub[k])) < 0)
                                        goto out;
                                for (int y = y0; y < y1; y++)
                                        memcpy(imp_image_f32(sub[k], 0, y - y0), imp_image_f32(img[k], x0, y),
                                               (size_t) (x1 - x0) * sizeof(float));
                        }
                        double g;
                        int px = 0;
                        if (imp_radiometric_projector_gamma(sub[0], sub[1], (const struct imp_image *const *) &sub[2],
                                                            n - 2, min_contrast, &g, &px) == 0 &&
                            px >= GAMMA_BLOCK_MIN_PX)
                                est[nb++] = g;
                        free_frames(sub, n);
                        memset(sub, 0, sizeof sub);
                }
        double mean = 0, ss = 0;
        for (int i = 0; i < nb; i++)
                mean += est[i] / nb;
        for (int i = 0; i < nb; i++)
                ss += (est[i] - mean) * (est[i] - mean);
        *ret_sigma = nb >= IMP_GAMMA_MIN_BLOCKS ? sqrt(ss / (nb - 1) / nb) : IMP_GAMMA_SIGMA_NONE;
        *ret_blocks = nb;
out:
        free_frames(sub, n);
        return r;
}

/* The projector's black level b (struct imp_projector_gamma) from the kept bins of white and black. */
static int projector_black(const struct imp_image *white, const struct imp_image *black, double min_contrast,
                           double sensor_black_dn, double *ret) {
        size_t n = (size_t) white->width * white->height, m = 0;
        _cleanup_free_ float *r = malloc(n * sizeof *r);
        if (!r)
                return -ENOMEM;
        for (int y = 0; y < white->height; y++)
                for (int x = 0; x < white->width; x++) {
                        double w = *imp_image_f32(white, x, y), b = *imp_image_f32(black, x, y);
                        if (w - b > min_contrast && w - sensor_black_dn > 0)
                                r[m++] = (float) ((b - sensor_black_dn) / (w - sensor_black_dn));
                }
        if (m == 0)
                return -ENOENT;
        qsort(r, m, sizeof *r, imp_cmp_float);
        *ret = IMP_CLAMP((double) r[m / 2], 0.0, 0.999);
        return 0;
}

/* The exposures holding the chosen phase set, longest first; their number. */
static int phase_exposures(const struct imp_captureset *cs, const char *cam, const struct imp_projector_gamma *g,
                           double exps[GAMMA_MAX_EXPOSURES]) {
        int ne = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (!is_chosen_phase(rec, cam, g))
                        continue;
                bool seen = false;
                for (int e = 0; e < ne && !seen; e++)
                        seen = same_exposure(exps[e], rec->exposure_us);
                if (!seen && ne < GAMMA_MAX_EXPOSURES)
                        exps[ne++] = rec->exposure_us;
        }
        qsort(exps, (size_t) ne, sizeof *exps, imp_cmp_double_desc);
        return ne;
}

/* The phase set and its exposure: the longest exposure with every frame whose white clips
 * at most GAMMA_CLIP_FRAC_MAX of the pixels (the most signal); else the shortest complete
 * one. Fills g's pattern fields and exposure_us. */
static int choose_frames(const struct imp_captureset *cs, const char *cam, double clip_dn, struct imp_projector_gamma *g,
                         struct gamma_frames *ret, struct imp_error *err) {
        const char *set = imp_captureset_dir(cs);
        if (!pick_phase(cs, cam, g))
                return imp_error_set(err, -ENOENT, "%s: no phase-shift frames of camera %s (the projector's gamma needs "
                                     "white, black and N >= 3 phase steps of one period: the plan's "
                                     "structured_light.phase, e.g. config/plans/projector-gamma.cfg)", set, cam);
        if (g->steps < 3)
                return imp_error_set(err, -EINVAL, "%s: %d phase steps of period %g px; the gamma needs 3 or more", set,
                                     g->steps, g->period_px);
        double exps[GAMMA_MAX_EXPOSURES];
        int ne = phase_exposures(cs, cam, g, exps);
        struct gamma_frames f;
        char what[160], first_what[200] = "";
        bool have = false;
        for (int e = 0; e < ne; e++) {
                if (find_frames(cs, cam, g, exps[e], &f, what, sizeof what) > 0) {
                        if (!first_what[0])
                                snprintf(first_what, sizeof first_what, "%s at %g us", what, exps[e]);
                        continue;
                }
                *ret = f;
                g->exposure_us = exps[e];
                have = true;
                _cleanup_image_ struct imp_image *wh = NULL;
                int r = imp_captureset_load_frame(cs, (size_t) f.white, &wh, err);
                if (r < 0)
                        return r;
                if (clip_fraction(wh, clip_dn) <= GAMMA_CLIP_FRAC_MAX)
                        break;
        }
        if (!have)
                return imp_error_set(err, -ENOENT, "%s: camera %s: no complete phase set for the projector's gamma "
                                     "(period %g px along %s, %d steps): missing %s", set, cam, g->period_px,
                                     g->axis ? "y" : "x", g->steps, first_what);
        return 0;
}

/* Loads white, black and the steps into raw[0 .. 2 + steps): one size, one gain, mono. */
static int load_frames(const struct imp_captureset *cs, const struct gamma_frames *chosen,
                       struct imp_projector_gamma *g, struct imp_image **raw, struct imp_error *err) {
        const char *set = imp_captureset_dir(cs);
        const int n = 2 + g->steps;
        long idx[2 + GAMMA_MAX_STEPS] = { chosen->white, chosen->black };
        memcpy(&idx[2], chosen->step, (size_t) g->steps * sizeof *idx);
        for (int k = 0; k < n; k++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, (size_t) idx[k]);
                int r = imp_captureset_load_frame(cs, (size_t) idx[k], &raw[k], err);
                if (r < 0)
                        return r;
                if (raw[k]->width != raw[0]->width || raw[k]->height != raw[0]->height ||
                    raw[k]->channels != raw[0]->channels)
                        return imp_error_set(err, -EINVAL, "%s: %s is %d x %d x %d, the white frame %d x %d x %d", set,
                                             rec->file, raw[k]->width, raw[k]->height, raw[k]->channels,
                                             raw[0]->width, raw[0]->height, raw[0]->channels);
                if (k == 0)
                        g->gain_db = rec->gain_db;
                else if (rec->gain_db != g->gain_db)
                        return imp_error_set(err, -EINVAL, "%s: %s at gain %g dB, the white frame at %g dB", set,
                                             rec->file, rec->gain_db, g->gain_db);
        }
        if (raw[0]->channels != 1)
                return imp_error_set(err, -EINVAL, "%s: colour frames (%d channels): the gamma is measured on mono "
                                     "frames", set, raw[0]->channels);
        return 0;
}

/* The binned images and the contrast threshold: unbinned first, for the phase gradient
 * that sets the bin; then binned (docs/calibration-lights.md). */
static int binned_images(const char *set, struct imp_image *const *raw, int n, double clip_dn,
                         struct imp_projector_gamma *g, struct imp_image **img, struct imp_error *err) {
        double noise_dn;
        int r;
        if ((g->clipped_px = gamma_images(raw, n, 1, clip_dn, img)) < 0)
                return g->clipped_px;
        if ((r = contrast_threshold(img[0], img[1], &g->min_contrast_dn, &noise_dn)) == -ENOENT)
                return imp_error_set(err, -ENOENT, "%s: white - black reaches %.1f DN (its 99th percentile) against "
                                     "a noise of %.1f DN: the projector does not light the target (or the scene "
                                     "renders no projector light)", set, g->min_contrast_dn / GAMMA_CONTRAST_FRAC,
                                     noise_dn);
        if (r < 0 || (r = gamma_bin(img, n, g->min_contrast_dn, &g->bin)) < 0)
                return r;
        if (g->bin > 1) {
                free_frames(img, n);
                memset(img, 0, (size_t) n * sizeof *img);
                if ((r = gamma_images(raw, n, g->bin, clip_dn, img)) < 0 ||
                    (r = contrast_threshold(img[0], img[1], &g->min_contrast_dn, &noise_dn)) < 0)
                        return r == -ENOENT ? -EDOM : r;
        }
        return 0;
}

/* The gamma, the black level and the block spread from the binned images. */
static int estimate(const char *set, struct imp_image *const *img, int n, struct imp_projector_gamma *g,
                    struct imp_error *err) {
        int r = imp_radiometric_projector_gamma(img[0], img[1], (const struct imp_image *const *) &img[2], g->steps,
                                                g->min_contrast_dn, &g->gamma, &g->pixels);
        if (r == -ENOENT)
                return imp_error_set(err, -ENOENT, "%s: no pixel with white - black above %.1f DN: the projector "
                                     "does not light the target", set, g->min_contrast_dn);
        if (r < 0)
                return imp_error_set(err, -EDOM, "%s: projector gamma: %s", set, strerror(-r));
        g->status = r;
        g->pixels *= g->bin * g->bin;
        if (projector_black(img[0], img[1], g->min_contrast_dn, g->sensor_black_dn, &g->black_level) < 0)
                return imp_error_set(err, -EDOM, "%s: the projector's black level: no pixel above the sensor's", set);
        return gamma_blocks(img, n, g->min_contrast_dn, &g->gamma_sigma, &g->blocks);
}

int imp_projector_gamma_measure(const struct imp_captureset *cs, const char *cam, double sensor_black_dn,
                                struct imp_projector_gamma *ret, struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        const char *set = imp_captureset_dir(cs);
        const struct imp_rig_camera *camera = NULL;
        for (int i = 0; i < rig->n_cameras && !camera; i++)
                if (!strcmp(rig->cameras[i].name, cam))
                        camera = &rig->cameras[i];
        if (!camera)
                return imp_error_set(err, -ENOENT, "no camera '%s' in %s/rig.json", cam, set);
        if (!rig->has_projector)
                return imp_error_set(err, -EINVAL, "%s: the rig has no projector", set);
        struct imp_projector_gamma g = { .status = 0 };
        struct gamma_frames chosen;
        const double clip_dn = (1 << camera->sensor.bits) - 1;
        int r = choose_frames(cs, cam, clip_dn, &g, &chosen, err);
        if (r < 0)
                return r;
        const int n = 2 + g.steps;
        struct imp_image *raw[2 + GAMMA_MAX_STEPS] = {}, *img[2 + GAMMA_MAX_STEPS] = {};
        g.sensor_black_dn = isnan(sensor_black_dn) ? camera->sensor.black_level_dn : sensor_black_dn;
        if ((r = load_frames(cs, &chosen, &g, raw, err)) >= 0 && (r = binned_images(set, raw, n, clip_dn, &g, img, err)) >= 0 &&
            (r = estimate(set, img, n, &g, err)) >= 0)
                *ret = g;
        free_frames(raw, n);
        free_frames(img, n);
        return r < 0 ? r : 0;
}
