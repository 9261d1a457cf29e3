/* Structured-light decoder on synthetic frames with known truth: a smooth projector→camera
 * warp, projector gamma 2.2 and black level 0.05, Gaussian defocus σ = 1 camera pixel
 * (0.5 projector pixel: the warp maps about 2 camera pixels to a projector pixel),
 * pixelated projector, textured albedo, a global-light offset that varies across the
 * image (up to more than the direct light), additive Gaussian noise, and a patch the
 * projector hardly reaches. Tolerances are stated next to each check. */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "structured-light.h"
#include "test.h"

#define PW 128          /* projector */
#define PH 96
#define CW 224          /* camera */
#define CH 168
#ifndef GAMMA           /* -DGAMMA=1.0: the conventions alone (3 steps: 0.008 px RMS) */
#define GAMMA 2.2
#endif
#define BLACK 0.05
#define SIGMA_P 0.5     /* defocus in projector pixels (= 1 camera pixel) */
#define NOISE 0.001     /* additive, white = 1 */
#define TAB 64          /* irradiance table samples per projector pixel */

/* Low-modulation patch: the projector hardly reaches it. */
static bool in_dark_patch(int x, int y) { return x >= 20 && x < 50 && y >= 20 && y < 40; }

static void warp(int x, int y, double *u, double *v) {
        double cx = x + 0.5, cy = y + 0.5;
        *u = 6.0 + 0.5 * cx + 2.0 * sin(2 * M_PI * cy / CH) + 0.0004 * (cx - 112) * (cx - 112);
        *v = 5.0 + 0.5 * cy + 1.5 * sin(2 * M_PI * cx / CW) + 0.0002 * (cx - 112) * (cy - 84);
}

static double albedo(int x, int y) {
        if (in_dark_patch(x, y))
                return 0.004;
        return 0.6 + 0.2 * sin(x / 7.0) * cos(y / 5.0);
}

static double global_light(int x, int y) {
        return 0.05 + 0.75 * ((double) x / CW) * ((double) y / CH);   /* up to 0.8 > L_d */
}

static uint64_t rng_state = 0x9E3779B97F4A7C15ull;
static double gauss(void) {
        double s[2];
        for (int i = 0; i < 2; i++) {
                rng_state ^= rng_state << 13;
                rng_state ^= rng_state >> 7;
                rng_state ^= rng_state << 17;
                s[i] = ((rng_state >> 11) + 0.5) / 9007199254740992.0;
        }
        return sqrt(-2 * log(s[0])) * cos(2 * M_PI * s[1]);
}

static double emission(const struct imp_pattern *pat, int c) {
        struct imp_pattern q = *pat;
        double val = imp_sl_pattern_value(&q, q.axis == 0 ? c : 0, q.axis == 1 ? c : 0);
        return BLACK + (1 - BLACK) * pow(val, GAMMA);
}

/* Camera image of one pattern (f32, white ≈ albedo). The pattern varies along one axis
 * only, so the defocused irradiance is a 1-D sum of erf-weighted pixel emissions,
 * tabulated at 1/TAB px and interpolated. */
static struct imp_image *render(const struct imp_pattern *pat) {
        int ext = pat->axis == 1 && pat->kind != IMP_PAT_WHITE && pat->kind != IMP_PAT_BLACK ? PH : PW;
        int n = ext * TAB + 1;
        double *tab = malloc(n * sizeof *tab), mean = 0;
        for (int c = 0; c < ext; c++)
                mean += emission(pat, c) / ext;
        for (int i = 0; i < n; i++) {
                double u = (double) i / TAB, s = 0;
                for (int c = (int) u - 5; c <= (int) u + 5; c++) {
                        if (c < 0 || c >= ext)
                                continue;
                        double w = 0.5 * (erf((c + 1 - u) / (SIGMA_P * M_SQRT2)) -
                                          erf((c - u) / (SIGMA_P * M_SQRT2)));
                        s += w * emission(pat, c);
                }
                tab[i] = s;
        }
        struct imp_image *im = NULL;
        if (imp_image_new(CW, CH, 1, IMP_PIX_F32, &im) < 0)
                abort();
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        double u, v;
                        warp(x, y, &u, &v);
                        double t = (pat->axis == 1 ? v : u) * TAB;
                        int i = (int) t;
                        if (i < 0 || i >= n - 1)
                                abort();       /* the warp stays inside the projector */
                        double irr = tab[i] + (t - i) * (tab[i + 1] - tab[i]);
                        *imp_image_f32(im, x, y) = (float) (albedo(x, y) * irr +
                                                            global_light(x, y) * mean + NOISE * gauss());
                }
        free(tab);
        return im;
}

struct set {
        struct imp_pattern *pat;
        struct imp_image **img;
        int n;
};

static void set_render(struct set *s, struct imp_pattern *pat, int n) {
        s->pat = pat;
        s->n = n;
        s->img = calloc(n, sizeof *s->img);
        for (int i = 0; i < n; i++)
                s->img[i] = render(&pat[i]);
}

static void set_free(struct set *s) {
        for (int i = 0; i < s->n; i++)
                imp_image_free(s->img[i]);
        free(s->img);
        free(s->pat);
}

static struct imp_sl_params params(void) {
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_F32);
        p.proj_width = PW;
        p.proj_height = PH;
        p.black_level = BLACK;
        return p;
}

static struct imp_sl_result *decode(const struct set *s, const struct imp_sl_params *p) {
        struct imp_sl_frames fr = { s->pat, (const struct imp_image *const *) s->img, s->n };
        struct imp_error err = { 0 };
        struct imp_sl_result *r = NULL;
        int rc = imp_sl_decode(&fr, p, &r, &err);
        CHECK_MSG(rc == 0, "decode: %d %s", rc, err.msg);
        return r;
}

/* Gray-only: the decoded code must be floor(true position) on valid pixels. A pixel whose
 * true position lies within UNDECIDABLE_PX of a code boundary cannot be decided by any
 * decoder at this noise level (the p − p̄ difference there is below the noise), so the
 * exact figure is stated both over all valid pixels and over the decidable ones. Every
 * error must be ±1 code and lie within NEAR_PX of a boundary: besides noise, the y planes
 * of a 96-row projector light unequal fractions of it in pattern and inverse, so the
 * global light (∝ lit fraction here, up to 0.8) shifts their crossings by up to ≈ 0.2 px. */
#define UNDECIDABLE_PX 0.005
#define NEAR_PX 0.25
static void check_gray(const struct imp_sl_result *r, const char *what, double min_exact,
                       double min_exact_all, double min_valid) {
        long valid = 0, exact = 0, lit = 0, dark_valid = 0, dark_unflagged = 0;
        long dec = 0, dec_exact = 0, big = 0, unflagged = 0, far = 0;
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        size_t o = (size_t) y * CW + x;
                        int f = r->flags[o];
                        bool ok = (f & IMP_SL_VALID_X) && (f & IMP_SL_VALID_Y);
                        if (in_dark_patch(x, y)) {
                                dark_valid += (f & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) != 0;
                                dark_unflagged += !(f & (IMP_SL_SHADOW | IMP_SL_LOW_MODULATION));
                                continue;
                        }
                        lit++;
                        if (!ok)
                                continue;
                        double u, v;
                        warp(x, y, &u, &v);
                        double ex = r->proj_x[o] - (floor(u) + 0.5), ey = r->proj_y[o] - (floor(v) + 0.5);
                        bool hit = ex == 0 && ey == 0;
                        double du = u - floor(u), dv = v - floor(v);
                        bool decidable = fmin(du, 1 - du) > UNDECIDABLE_PX && fmin(dv, 1 - dv) > UNDECIDABLE_PX;
                        valid++;
                        exact += hit;
                        dec += decidable;
                        dec_exact += decidable && hit;
                        big += fabs(ex) > 1 || fabs(ey) > 1;
                        unflagged += !hit && !(f & IMP_SL_WEAK_BIT);
                        far += !hit && !(fmin(du, 1 - du) <= NEAR_PX || fmin(dv, 1 - dv) <= NEAR_PX);
                }
        double pe = 100.0 * exact / (valid ? valid : 1), pv = 100.0 * valid / lit;
        double pd = 100.0 * dec_exact / (dec ? dec : 1);
        fprintf(stderr, "%s: valid %.2f%% of lit pixels; exact %.3f%% of valid, %.3f%% of the "
                "decidable ones (%ld within %.3f px of a boundary); errors > 1 code: %ld, without "
                "WEAK_BIT: %ld, farther than %.2f px from a boundary: %ld\n", what, pv, pe, pd,
                valid - dec, UNDECIDABLE_PX, big, unflagged, NEAR_PX, far);
        CHECK_GE(pd, min_exact);
        CHECK_GE(pe, min_exact_all);
        CHECK_GE(pv, min_valid);
        CHECK_INT_EQ(big, 0);
        CHECK_INT_EQ(far, 0);
        CHECK_INT_EQ(dark_valid, 0);
        CHECK_INT_EQ(dark_unflagged, 0);
}

/* Sub-pixel: RMS of (decoded − true) over pixels refined by phase. */
static void check_phase(const struct imp_sl_result *r, const char *what, double max_rms,
                        double min_cover) {
        double se[2] = { 0, 0 }, maxe[2] = { 0, 0 };
        long n[2] = { 0, 0 }, lit = 0;
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        if (in_dark_patch(x, y))
                                continue;
                        lit++;
                        size_t o = (size_t) y * CW + x;
                        double t[2];
                        warp(x, y, &t[0], &t[1]);
                        for (int a = 0; a < 2; a++) {
                                int need = a == 0 ? IMP_SL_VALID_X | IMP_SL_SUBPIXEL_X
                                                  : IMP_SL_VALID_Y | IMP_SL_SUBPIXEL_Y;
                                if ((r->flags[o] & need) != need)
                                        continue;
                                double e = (a == 0 ? r->proj_x[o] : r->proj_y[o]) - t[a];
                                se[a] += e * e;
                                maxe[a] = fmax(maxe[a], fabs(e));
                                n[a]++;
                        }
                }
        for (int a = 0; a < 2; a++) {
                double rms = sqrt(se[a] / (n[a] ? n[a] : 1)), cover = 100.0 * n[a] / lit;
                fprintf(stderr, "%s: axis %c: sub-pixel on %.2f%% of lit pixels, RMS %.4f px, "
                        "max %.4f px\n", what, "xy"[a], cover, rms, maxe[a]);
                CHECK_LE(rms, max_rms);
                CHECK_GE(cover, min_cover);
        }
}

/* Position error RMS (projector px, both axes pooled) over the pixels valid on both axes
 * outside the dark patch, whatever refined them; *ret_n their count, *ret_sub those with a
 * sub-pixel flag on both axes. */
static double rms_valid(const struct imp_sl_result *r, long *ret_n, long *ret_sub) {
        double se = 0;
        long n = 0, sub = 0;
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        size_t o = (size_t) y * CW + x;
                        int f = r->flags[o];
                        if (in_dark_patch(x, y) || (f & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) !=
                                                           (IMP_SL_VALID_X | IMP_SL_VALID_Y))
                                continue;
                        double u, v;
                        warp(x, y, &u, &v);
                        se += (r->proj_x[o] - u) * (r->proj_x[o] - u) + (r->proj_y[o] - v) * (r->proj_y[o] - v);
                        n++;
                        sub += (f & (IMP_SL_SUBPIXEL_X | IMP_SL_SUBPIXEL_Y)) == (IMP_SL_SUBPIXEL_X | IMP_SL_SUBPIXEL_Y);
                }
        *ret_n = n;
        *ret_sub = sub;
        return sqrt(se / (2.0 * (n ? n : 1)));
}

/* 3-step phase at 16 px under the projector's gamma 2.2 (accuracy study, issue #4: "p3"
 * came out worse than Gray code alone). With 3 steps the 2nd harmonic that gamma puts into
 * the sinusoid aliases onto the fundamental: a phase error of amplitude a₂/a₁ ≈ 0.28 rad
 * (0.7 px at 16 px, ≈ 0.5 px RMS), more than the ±½-px quantisation of the Gray centre
 * (0.29 px RMS). The decoder must never return worse than the Gray code: with the gamma
 * known it inverts the phase response; without it, it measures the phase's disagreement
 * with the Gray code and falls back to the Gray centre (IMP_SL_PHASE_REJECTED). */
static void test_three_step(int ngray) {
        double periods[] = { 16 };
        struct imp_pattern *seq = NULL;
        int nseq = 0;
        CHECK_OK(imp_sl_sequence(PW, PH, 3, periods, 1, &seq, &nseq));
        struct set s3;
        set_render(&s3, seq, nseq);
        struct set gray = { .pat = s3.pat, .img = s3.img, .n = ngray };  /* the same Gray frames */
        struct imp_sl_params p = params();
        long n, sub, n_gray;
        struct imp_sl_result *r = decode(&gray, &p);
        double rms_gray = r ? rms_valid(r, &n_gray, &sub) : 1e9;
        fprintf(stderr, "3-step: gray only: RMS %.4f px on %ld pixels\n", rms_gray, n_gray);
        imp_sl_result_free(r);

        /* The phase as it comes, gamma unknown (the old behaviour): worse than Gray. */
        p.keep_phase = true;
        r = decode(&s3, &p);
        double rms_raw = r ? rms_valid(r, &n, &sub) : 1e9;
        fprintf(stderr, "3-step: phase kept, gamma unknown: RMS %.4f px (%.2f× gray) on %ld pixels, "
                "estimated from the Gray code %.4f / %.4f px\n", rms_raw, rms_raw / rms_gray, sub,
                r ? r->phase_err_px[0] : -1, r ? r->phase_err_px[1] : -1);
        CHECK_GE(rms_raw, 1.3 * rms_gray);             /* the harm the guard below prevents */
        /* The estimate √(mean (u − centre)² − 1/12) recovers the true error within 15 %. */
        CHECK(r && fabs(r->phase_err_px[0] - rms_raw) < 0.15 * rms_raw);
        CHECK(r && fabs(r->phase_err_px[1] - rms_raw) < 0.15 * rms_raw);
        imp_sl_result_free(r);

        /* Default: the decoder sees the phase is worse than its Gray code and falls back. */
        p.keep_phase = false;
        r = decode(&s3, &p);
        double rms_guard = r ? rms_valid(r, &n, &sub) : 1e9;
        long flagged = 0;
        for (size_t i = 0; r && i < (size_t) CW * CH; i++)
                flagged += (r->flags[i] & (IMP_SL_VALID_X | IMP_SL_PHASE_REJECTED)) ==
                           (IMP_SL_VALID_X | IMP_SL_PHASE_REJECTED);
        fprintf(stderr, "3-step: gamma unknown, guarded: RMS %.4f px on %ld pixels, %ld flagged "
                "PHASE_REJECTED\n", rms_guard, n, flagged);
        CHECK(r && r->phase_rejected[0] && r->phase_rejected[1]);
        CHECK_LE(rms_guard, rms_gray);
        CHECK_INT_EQ(n, n_gray);
        CHECK_INT_EQ(sub, 0);
        CHECK_INT_EQ(flagged, r ? (long) r->n_valid_x : -1);
        imp_sl_result_free(r);

        /* Gamma known (radiometric calibration): the response is inverted. With the blur
         * known too the residual is noise and the erf-pixel approximation; without it the
         * modelled 2nd harmonic is 6 % too strong (σ = 0.5 px attenuates it so). */
        p.projector_gamma = GAMMA;
        r = decode(&s3, &p);
        double rms_g = r ? rms_valid(r, &n, &sub) : 1e9;
        fprintf(stderr, "3-step: gamma %.1f known, blur unknown: RMS %.4f px (%.3f× gray), %ld "
                "sub-pixel\n", GAMMA, rms_g, rms_g / rms_gray, sub);
        CHECK_LE(rms_g, 0.1);
        CHECK(r && !r->phase_rejected[0] && !r->phase_rejected[1]);
        imp_sl_result_free(r);
        p.projector_defocus_px = SIGMA_P;
        r = decode(&s3, &p);
        double rms_gd = r ? rms_valid(r, &n, &sub) : 1e9;
        fprintf(stderr, "3-step: gamma %.1f and blur %.1f px known: RMS %.4f px (%.3f× gray), "
                "estimated %.4f px\n", GAMMA, SIGMA_P, rms_gd, rms_gd / rms_gray, r ? r->phase_err_px[0] : -1);
        CHECK_LE(rms_gd, 0.03);
        CHECK_INT_EQ(sub, n);
        imp_sl_result_free(r);
        set_free(&s3);
}

static void test_helpers(void) {
        CHECK_INT_EQ(imp_sl_gray_bits(1024), 10);
        CHECK_INT_EQ(imp_sl_gray_bits(768), 10);
        CHECK_INT_EQ(imp_sl_gray_bits(1), 0);
        CHECK_INT_EQ(imp_sl_gray_bits(3), 2);
        struct imp_pattern g = { .kind = IMP_PAT_GRAY, .axis = 0, .bit = 0, .nbits = 10 };
        CHECK(imp_sl_pattern_value(&g, 511, 0) == 0.0 && imp_sl_pattern_value(&g, 512, 0) == 1.0);
        g.inverse = true;
        CHECK(imp_sl_pattern_value(&g, 511, 0) == 1.0);
        struct imp_pattern ph = { .kind = IMP_PAT_PHASE, .axis = 1, .period_px = 16, .step = 0, .steps = 4 };
        /* Row 3 has centre 3.5: ½ + ½ cos(2π·3.5/16 + 2π·1/4) with step 1. */
        ph.step = 1;
        CHECK_NEAR(imp_sl_pattern_value(&ph, 0, 3), 0.5 + 0.5 * cos(2 * M_PI * 3.5 / 16 + M_PI / 2), 1e-12);
}

/* Gray code without its finest planes: the code then gives the phase's period (a stripe
 * of 2^k px) and the phase the rest. Dropping 2 or 3 planes (stripes of 4 or 8 px, at
 * most half the 16-px period) must decode as well as the full code; 4 planes (16-px
 * stripes) or no phase frames are refused. */
static void test_fewer_bits(const struct set *all, double rms_full) {
        struct imp_sl_params p = params();
        for (int drop = 2; drop <= 4; drop++) {
                struct imp_pattern pat[128];
                const struct imp_image *img[128];
                int n = 0, nphase = 0;
                for (int i = 0; i < all->n && n < 128; i++) {
                        const struct imp_pattern *q = &all->pat[i];
                        if (q->kind == IMP_PAT_GRAY && q->bit >= q->nbits - drop)
                                continue;
                        nphase += q->kind == IMP_PAT_PHASE;
                        pat[n] = *q;
                        img[n++] = all->img[i];
                }
                struct imp_sl_frames fr = { pat, img, n };
                struct imp_error err = { 0 };
                struct imp_sl_result *r = NULL;
                int rc = imp_sl_decode(&fr, &p, &r, &err);
                if (drop == 4) {
                        CHECK_ERR(rc, -EINVAL);
                        CHECK_STR_CONTAINS(err.msg, "phase period");
                        continue;
                }
                CHECK_OK(rc);
                if (!r)
                        continue;
                long nv, sub;
                double rms = rms_valid(r, &nv, &sub);
                fprintf(stderr, "gray without its %d finest planes + phase 4×16: RMS %.4f px (full code "
                        "%.4f), %ld valid, %ld sub-pixel, %zu disagree\n", drop, rms, rms_full, nv, sub,
                        r->n_disagree);
                CHECK_LE(rms, rms_full * 1.05);
                CHECK_GE(sub, nv * 99 / 100);
                CHECK(!r->phase_rejected[0] && !r->phase_rejected[1]);
                imp_sl_result_free(r);
                /* Without the phase frames the shortened code is refused. */
                fr.n = n - nphase;
                CHECK_ERR(imp_sl_decode(&fr, &p, &r, &err), -EINVAL);
                CHECK_STR_CONTAINS(err.msg, "missing");
        }
}

static void test_errors(struct set *s) {
        struct imp_sl_params p = params();
        struct imp_error err = { 0 };
        struct imp_sl_result *sentinel = (struct imp_sl_result *) &err, *r = sentinel;
        /* A missing plane: drop frame 3 (axis x, bit 1, inverse). */
        struct imp_pattern pat[64];
        const struct imp_image *img[64];
        int n = 0;
        for (int i = 0; i < s->n && n < 64; i++)
                if (i != 3) {
                        pat[n] = s->pat[i];
                        img[n++] = s->img[i];
                }
        struct imp_sl_frames fr = { pat, img, n };
        CHECK_ERR(imp_sl_decode(&fr, &p, &r, &err), -EINVAL);
        CHECK(r == sentinel);
        CHECK_STR_CONTAINS(err.msg, "inverses");
        /* A duplicate plane. */
        pat[3] = pat[2];
        CHECK_ERR(imp_sl_decode(&fr, &p, &r, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "same Gray plane");
        /* Too few phase steps. */
        struct imp_pattern ph[2] = { { .kind = IMP_PAT_PHASE, .period_px = 16, .step = 0, .steps = 2 },
                                     { .kind = IMP_PAT_PHASE, .period_px = 16, .step = 1, .steps = 2 } };
        struct imp_sl_frames fp = { ph, img, 2 };
        CHECK_ERR(imp_sl_decode(&fp, &p, &r, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "steps");
        /* Mismatched sizes. */
        struct imp_image *small = NULL;
        CHECK_OK(imp_image_new(CW / 2, CH, 1, IMP_PIX_F32, &small));
        for (int i = 0; i < s->n; i++)
                img[i] = s->img[i];
        img[5] = small;
        struct imp_sl_frames fm = { s->pat, img, s->n };
        CHECK_ERR(imp_sl_decode(&fm, &p, &r, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "frame 5");
        imp_image_free(small);
        /* Bad parameters. */
        struct imp_sl_frames fg = { s->pat, (const struct imp_image *const *) s->img, s->n };
        p.black_level = 1.0;
        CHECK_ERR(imp_sl_decode(&fg, &p, &r, &err), -EINVAL);
        CHECK(r == sentinel);
}

/* The maps every result has (coordinates, confidence, σ, flags) and the counts, equal. */
static bool same_coords(const struct imp_sl_result *ro, const struct imp_sl_result *rf) {
        size_t np = (size_t) rf->width * rf->height;
        return ro->width == rf->width && ro->height == rf->height &&
                    !memcmp(ro->proj_x, rf->proj_x, np * sizeof(float)) &&
                    !memcmp(ro->proj_y, rf->proj_y, np * sizeof(float)) &&
                    !memcmp(ro->confidence, rf->confidence, np * sizeof *rf->confidence) &&
                    !memcmp(ro->sigma_px, rf->sigma_px, np * sizeof *rf->sigma_px) &&
                    !memcmp(ro->flags, rf->flags, np * sizeof(uint16_t)) &&
                    ro->n_valid_x == rf->n_valid_x && ro->n_valid_y == rf->n_valid_y &&
                    ro->n_valid_xy == rf->n_valid_xy && ro->n_shadow == rf->n_shadow &&
                    ro->n_saturated == rf->n_saturated && ro->n_weak == rf->n_weak &&
                    ro->n_disagree == rf->n_disagree &&
                    !memcmp(ro->phase_err_px, rf->phase_err_px, sizeof ro->phase_err_px);
}

/* direct_only: direct as the full decode's, no global or modulation map, every other map
 * and count the same; imp_sl_decode_reuse turns a full result into a direct_only one. */
static void check_direct_only(const struct imp_sl_frames *fr, const struct imp_sl_params *p,
                              const struct imp_sl_result *rf, const char *what) {
        struct imp_sl_params pd = *p;
        pd.direct_only = true;
        struct imp_sl_result *rd = NULL, *rr = NULL;
        struct imp_error err = {};
        size_t np = (size_t) rf->width * rf->height;
        CHECK_OK(imp_sl_decode(fr, &pd, &rd, &err));
        CHECK_OK(imp_sl_decode(fr, p, &rr, &err));
        if (!rd || !rr)
                return;
        CHECK_MSG(rd->direct && !rd->global && !rd->modulation && !memcmp(rd->direct, rf->direct, np * sizeof(float)),
                  "%s: direct_only keeps direct (the full decode's) alone", what);
        CHECK_MSG(same_coords(rd, rf), "%s: direct_only maps and counts = the full decode's", what);
        CHECK_OK(imp_sl_decode_reuse(fr, &pd, &rr, &err));
        CHECK_MSG(rr->direct && !rr->global && !memcmp(rr->direct, rf->direct, np * sizeof(float)) &&
                  same_coords(rr, rf), "%s: full result reused for direct_only", what);
        imp_sl_result_free(rd);
        imp_sl_result_free(rr);
}

/* coords_only: no direct, global or modulation map, and every other map and count as the
 * full decode's; imp_sl_decode_reuse turns a full result into a coords_only one and back.
 * direct_only too (check_direct_only). */
static void check_coords_only(const struct imp_sl_frames *fr, const struct imp_sl_params *p,
                              const char *what) {
        struct imp_sl_params pc = *p;
        pc.coords_only = true;
        struct imp_sl_result *rf = NULL, *ro = NULL, *rr = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_sl_decode(fr, p, &rf, &err));
        CHECK_OK(imp_sl_decode(fr, &pc, &ro, &err));
        CHECK_OK(imp_sl_decode(fr, p, &rr, &err));
        if (!rf || !ro || !rr)
                return;
        size_t np = (size_t) rf->width * rf->height;
        CHECK_MSG(ro->proj_x && !ro->direct && !ro->global && !ro->modulation,
                  "%s: coords_only has no direct/global/modulation maps", what);
        CHECK_MSG(same_coords(ro, rf), "%s: coords_only maps and counts = the full decode's", what);
        check_direct_only(fr, p, rf, what);
        /* the full result reused for coords_only, then for the full decode again */
        CHECK_OK(imp_sl_decode_reuse(fr, &pc, &rr, &err));
        CHECK_MSG(!rr->direct && !memcmp(rr->proj_x, rf->proj_x, np * sizeof(float)),
                  "%s: full result reused for coords_only", what);
        CHECK_OK(imp_sl_decode_reuse(fr, p, &rr, &err));
        CHECK_MSG(rr->direct && !memcmp(rr->direct, rf->direct, np * sizeof(float)) &&
                  !memcmp(rr->global, rf->global, np * sizeof(float)) &&
                  !memcmp(rr->modulation, rf->modulation, np * sizeof(float)),
                  "%s: coords_only result reused for the full decode", what);
        imp_sl_result_free(rf);
        imp_sl_result_free(ro);
        imp_sl_result_free(rr);
}

/* The integer paths (u8 frames: byte lanes with inverses, 16-bit lanes without) against
 * the float path on the same integer samples: every map byte for byte. Frames scaled so
 * that the brightest pixels clip at 255 (saturation and hi rules), with and without
 * inverses, robust and sign-only, and thresholds that are not integers. cw: the frames'
 * width, their first cw columns (not a multiple of 8: the vector loops' tails). */
static void test_u8_equals_float(const struct set *g, int cw) {
        int n = g->n;
        struct imp_image **u8 = calloc(n, sizeof *u8), **f32 = calloc(n, sizeof *f32);
        for (int i = 0; i < n; i++) {
                CHECK_OK(imp_image_new(cw, CH, 1, IMP_PIX_U8, &u8[i]));
                CHECK_OK(imp_image_new(cw, CH, 1, IMP_PIX_F32, &f32[i]));
                for (int y = 0; y < CH; y++)
                        for (int x = 0; x < cw; x++) {
                                double v = rint(300.0 * *imp_image_f32(g->img[i], x, y));
                                v = v < 0 ? 0 : v > 255 ? 255 : v;
                                *imp_image_u8(u8[i], x, y) = (uint8_t) v;
                                *imp_image_f32(f32[i], x, y) = (float) v;
                        }
        }
        struct imp_pattern pat[64];
        const struct imp_image *iu[64], *iff[64];
        for (int inv = 1; inv >= 0; inv--) {
                int m = 0;
                for (int i = 0; i < n; i++)
                        if (inv || !(g->pat[i].kind == IMP_PAT_GRAY && g->pat[i].inverse)) {
                                pat[m] = g->pat[i];
                                iu[m] = u8[i];
                                iff[m++] = f32[i];
                        }
                for (int robust = 0; robust < 2; robust++) {
                        struct imp_sl_params p;
                        imp_sl_params_default(&p, IMP_PIX_U8);
                        p.proj_width = PW;
                        p.proj_height = PH;
                        p.black_level = BLACK;
                        p.min_bit_contrast = 4.5;
                        p.saturation = 255;      /* the float path has no level of its own */
                        p.robust = robust;
                        struct imp_sl_frames fu = { pat, iu, m }, ff = { pat, iff, m };
                        struct imp_sl_result *ru = NULL, *rf = NULL;
                        struct imp_error err = {};
                        CHECK_OK(imp_sl_decode(&fu, &p, &ru, &err));
                        CHECK_OK(imp_sl_decode(&ff, &p, &rf, &err));
                        if (!ru || !rf)
                                continue;
                        size_t np = (size_t) cw * CH;
                        bool same = !memcmp(ru->proj_x, rf->proj_x, np * sizeof(float)) &&
                                    !memcmp(ru->proj_y, rf->proj_y, np * sizeof(float)) &&
                                    !memcmp(ru->confidence, rf->confidence, np * sizeof *rf->confidence) &&
                                    !memcmp(ru->direct, rf->direct, np * sizeof(float)) &&
                                    !memcmp(ru->global, rf->global, np * sizeof(float)) &&
                                    !memcmp(ru->sigma_px, rf->sigma_px, np * sizeof *rf->sigma_px) &&
                                    !memcmp(ru->flags, rf->flags, np * sizeof(uint16_t)) &&
                                    ru->n_valid_xy == rf->n_valid_xy && ru->n_weak == rf->n_weak &&
                                    ru->n_saturated == rf->n_saturated;
                        size_t nsat = 0, nweak = 0, nvx = 0, nvy = 0, nxy = 0, nsh = 0;
                        for (size_t i = 0; i < np; i++) {
                                nsat += !!(ru->flags[i] & IMP_SL_SATURATED);
                                nweak += !!(ru->flags[i] & IMP_SL_WEAK_BIT);
                                nvx += !!(ru->flags[i] & IMP_SL_VALID_X);
                                nvy += !!(ru->flags[i] & IMP_SL_VALID_Y);
                                nxy += (ru->flags[i] & IMP_SL_VALID_X) && (ru->flags[i] & IMP_SL_VALID_Y);
                                nsh += !!(ru->flags[i] & IMP_SL_SHADOW);
                        }
                        /* the counts are the flags' (nothing counted past a row's end) */
                        CHECK_MSG(ru->n_valid_x == nvx && ru->n_valid_y == nvy && ru->n_valid_xy == nxy &&
                                  ru->n_shadow == nsh && ru->n_saturated == nsat && ru->n_weak == nweak,
                                  "width %d: counts = flags (valid %zu vs %zu)", cw, ru->n_valid_xy, nxy);
                        CHECK_MSG(same, "u8 path = float path (width %d, inverses %d, robust %d): "
                                  "valid %zu vs %zu", cw, inv, robust, ru->n_valid_xy, rf->n_valid_xy);
                        check_coords_only(&fu, &p, inv ? "u8 with inverses" : "u8 without inverses");
                        CHECK(nsat > 0 && nweak > 0);    /* the clipped and weak rules ran */
                        imp_sl_result_free(ru);
                        imp_sl_result_free(rf);
                }
        }
        for (int i = 0; i < n; i++) {
                imp_image_free(u8[i]);
                imp_image_free(f32[i]);
        }
        free(u8);
        free(f32);
}

/* Rows y0..y0+h of the frames g tiled TX × TY times (u8: scaled as test_u8_equals_float). */
#define TX 4
#define TY 4
static struct imp_image *tiled(const struct imp_image *src, bool u8, int y0, int h) {
        struct imp_image *im = NULL;
        CHECK_OK(imp_image_new(TX * CW, h, 1, u8 ? IMP_PIX_U8 : IMP_PIX_F32, &im));
        for (int y = 0; im && y < h; y++)
                for (int x = 0; x < TX * CW; x++) {
                        float v = *imp_image_f32(src, x % CW, (y0 + y) % CH);
                        if (u8)
                                *imp_image_u8(im, x, y) = (uint8_t) fmin(fmax(rint(300.0 * v), 0), 255);
                        else
                                *imp_image_f32(im, x, y) = v;
                }
        return im;
}

/* A result larger than STREAM_MIN_BYTES (16 MiB: 896 × 672 × 30 B) is built in scratch rows
 * and streamed to the maps: its rows equal those of a decode of a 40-row band of the same
 * frames (0.9 MiB, written in place), at the top and at the bottom, every map byte for
 * byte, on the byte-lane path (u8) and the float path. */
static void test_streamed(const struct set *g) {
        enum { BH = 40, TH = TY * CH };
        const int tw = TX * CW, y0s[2] = { 0, TH - BH };
        for (int u8 = 1; u8 >= 0; u8--) {
                struct imp_image *big[64] = {}, *band[64] = {};
                struct imp_sl_params p = params();
                if (u8) {
                        imp_sl_params_default(&p, IMP_PIX_U8);
                        p.proj_width = PW, p.proj_height = PH, p.black_level = BLACK;
                }
                for (int i = 0; i < g->n; i++)
                        big[i] = tiled(g->img[i], u8, 0, TH);
                struct imp_sl_frames fb = { g->pat, (const struct imp_image *const *) big, g->n };
                struct imp_sl_result *rb = NULL, *rs = NULL;
                struct imp_error err = {};
                CHECK_OK(imp_sl_decode(&fb, &p, &rb, &err));
                CHECK((size_t) tw * TH * 30 >= 16u << 20);
                for (int k = 0; k < 2 && rb; k++) {
                        for (int i = 0; i < g->n; i++) {
                                imp_image_free(band[i]);
                                band[i] = tiled(g->img[i], u8, y0s[k], BH);
                        }
                        struct imp_sl_frames fs = { g->pat, (const struct imp_image *const *) band, g->n };
                        CHECK_OK(imp_sl_decode_reuse(&fs, &p, &rs, &err));
                        if (!rs)
                                break;
                        size_t o = (size_t) y0s[k] * tw, nb = (size_t) BH * tw, fb4 = nb * sizeof(float);
                        bool same = !memcmp(rb->proj_x + o, rs->proj_x, fb4) && !memcmp(rb->proj_y + o, rs->proj_y, fb4) &&
                                    !memcmp(rb->confidence + o, rs->confidence, nb * sizeof *rs->confidence) &&
                                    !memcmp(rb->sigma_px + o, rs->sigma_px, nb * sizeof *rs->sigma_px) &&
                                    !memcmp(rb->direct + o, rs->direct, fb4) && !memcmp(rb->global + o, rs->global, fb4) &&
                                    !memcmp(rb->modulation + o, rs->modulation, fb4) &&
                                    !memcmp(rb->flags + o, rs->flags, nb * sizeof(uint16_t));
                        CHECK_MSG(same, "streamed result (%s) rows %d–%d = the band's decode", u8 ? "u8" : "f32",
                                  y0s[k], y0s[k] + BH);
                        CHECK_INT_GE(rs->n_valid_xy, nb / 4);   /* the band decodes: not all invalid */
                }
                imp_sl_result_free(rb);
                imp_sl_result_free(rs);
                for (int i = 0; i < g->n; i++) {
                        imp_image_free(big[i]);
                        imp_image_free(band[i]);
                }
        }
}

int main(void) {
        test_helpers();

        /* Gray code (with inverses), white, black, and 4-step phase at 16 px on both axes. */
        double periods[] = { 16 };
        struct imp_pattern *seq = NULL;
        int nseq = 0;
        CHECK_OK(imp_sl_sequence(PW, PH, 4, periods, 1, &seq, &nseq));
        int ngray = 2 * (imp_sl_gray_bits(PW) + imp_sl_gray_bits(PH)) + 2;
        struct set all;
        set_render(&all, seq, nseq);

        struct set gray = { .pat = all.pat, .img = all.img, .n = ngray };
        struct imp_sl_params p = params();
        struct imp_sl_result *r = decode(&gray, &p);
        if (r) {
                /* ≥ 99.5 % exact (brief); ≥ 95 % of lit pixels decoded. */
                check_gray(r, "gray, robust", 99.5, 99.0, 95.0);
                CHECK(r->n_valid_xy > 0 && r->n_shadow >= 600);
                imp_sl_result_free(r);
        }
        p.robust = false;
        r = decode(&gray, &p);
        if (r) {
                check_gray(r, "gray, sign only", 99.5, 99.0, 95.0);
                imp_sl_result_free(r);
        }
        p.robust = true;
        test_u8_equals_float(&gray, CW);
        test_u8_equals_float(&gray, CW - 3);
        test_streamed(&gray);

        /* Without inverses: p̄ = white + black − p. */
        struct imp_pattern pat_ni[64];
        const struct imp_image *img_ni[64];
        int nni = 0;
        for (int i = 0; i < ngray; i++)
                if (!(all.pat[i].kind == IMP_PAT_GRAY && all.pat[i].inverse)) {
                        pat_ni[nni] = all.pat[i];
                        img_ni[nni++] = all.img[i];
                }
        struct imp_sl_frames fni = { pat_ni, img_ni, nni };
        struct imp_error err = { 0 };
        r = NULL;
        CHECK_OK(imp_sl_decode(&fni, &p, &r, &err));
        if (r) {
                check_gray(r, "gray without inverses", 99.5, 99.0, 95.0);
                imp_sl_result_free(r);
        }

        /* Gray + 4-step phase, period 16 px: RMS ≤ 0.05 projector px (brief). The gamma of
         * 2.2 leaves a 3rd harmonic that 4 steps alias onto the fundamental: predicted
         * ≈ 0.017 px RMS; noise adds ≈ 0.003 px. */
        test_u8_equals_float(&all, CW - 3);     /* the byte lanes' rows for the phase path */
        struct imp_sl_frames fall = { all.pat, (const struct imp_image *const *) all.img, all.n };
        check_coords_only(&fall, &p, "gray + phase, f32");
        r = decode(&all, &p);
        if (r) {
                check_phase(r, "gray + phase 4×16", 0.05, 95.0);
                long nv, sub;
                test_fewer_bits(&all, rms_valid(r, &nv, &sub));
                imp_sl_result_free(r);
        }
        /* The same with the projector's gamma and blur known: the 3rd harmonic is undone,
         * noise (≈ 0.003 px) and the erf-pixel approximation remain. */
        p.projector_gamma = GAMMA;
        p.projector_defocus_px = SIGMA_P;
        r = decode(&all, &p);
        if (r) {
                check_phase(r, "gray + phase 4×16, gamma known", 0.008, 95.0);
                imp_sl_result_free(r);
        }
        p.projector_gamma = p.projector_defocus_px = 0;

        /* Phase only, two periods per axis and no Gray code: the coarse period is the
         * projector extent (128 for x, 96 for y), so that every step lights the same
         * fraction of the projector and the global light stays the same across steps
         * (a 128-px period over 96 rows biases the coarse phase where global light is
         * strong, and the decoder then flags IMP_SL_DISAGREE). */
        const double per[2][2] = { { PW, 16 }, { PH, 16 } };
        int nph = 2 + 2 * 2 * 4;
        struct imp_pattern *pat2 = calloc(nph, sizeof *pat2);
        pat2[0] = (struct imp_pattern) { .kind = IMP_PAT_WHITE };
        pat2[1] = (struct imp_pattern) { .kind = IMP_PAT_BLACK };
        for (int a = 0, k = 2; a < 2; a++)
                for (int j = 0; j < 2; j++)
                        for (int st = 0; st < 4; st++)
                                pat2[k++] = (struct imp_pattern) { .kind = IMP_PAT_PHASE, .axis = a,
                                        .period_px = per[a][j], .step = st, .steps = 4 };
        struct set ph;
        set_render(&ph, pat2, nph);
        r = decode(&ph, &p);
        if (r) {
                check_phase(r, "phase only 4×{extent,16}", 0.05, 95.0);
                imp_sl_result_free(r);
        }
        set_free(&ph);

        test_three_step(ngray);
        test_errors(&all);
        set_free(&all);
        return TEST_DONE();
}
