/* Structured-light decoder on synthetic frames with known truth: a smooth projector→camera
 * warp, projector gamma 2.2 and black level 0.05, Gaussian defocus σ = 1 camera pixel
 * (0.5 projector pixel: the warp maps about 2 camera pixels to a projector pixel),
 * pixelated projector, textured albedo, a global-light offset that varies across the
 * image (up to more than the direct light), additive Gaussian noise, and a patch the
 * projector hardly reaches. Tolerances are stated next to each check. */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include "structured-light.h"
#include "test.h"

#define PW 128          /* projector */
#define PH 96
#define CW 224          /* camera */
#define CH 168
#define GAMMA 2.2
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
        r = decode(&all, &p);
        if (r) {
                check_phase(r, "gray + phase 4×16", 0.05, 95.0);
                imp_sl_result_free(r);
        }

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

        test_errors(&all);
        set_free(&all);
        return TEST_DONE();
}
