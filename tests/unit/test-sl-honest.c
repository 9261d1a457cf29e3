/* The structured-light decoder's σ and flags on pixels where its model breaks: f32 frames
 * (as after an HDR merge) in which one band of pixels sees a phase that contradicts its
 * Gray code by 1.5 px (a phase the decoder cannot trust) and another band is clipped in the
 * phase frames (the merge's saturation masks say so). Asserted: every output finite; the
 * contradicting pixels carry IMP_SL_PHASE_REJECTED and the clipped ones IMP_SL_SATURATED;
 * the pixels without those flags are within 3σ (σ = the larger of the decoder's sigma_px
 * and imp_triangulate's default 0.1 px / confidence) in at least 99 %; the flagged ones too.
 * Each guard is also switched off once (phase_margin_px = ∞ with keep_phase; no saturation
 * masks) to show that the same figures then fail: the assertions test the checks, not the
 * data. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include "structured-light.h"
#include "test.h"

#define PW 128
#define PH 64
#define CW 160
#define CH 80
#define PERIOD 16.0
#define SCALE 0.7            /* projector px per camera px */
#define BAD_PHASE_PX 1.5     /* band A: the phase frames see u + this */
#define CLIP 0.3             /* band B: phase frames clipped here (white ≈ 0.85) */
#define NOISE 0.002
#define SIGMA_TRI_PX 0.1     /* imp_triangulate_options_default().sigma_proj_px */

static bool band_a(int x) { return x >= 40 && x < 60; }
static bool band_b(int x) { return x >= 90 && x < 110; }
static double true_u(int x) { return SCALE * (x + 0.5) + 3.1; }
static double true_v(int y) { return SCALE * (y + 0.5) + 2.3; }

static double pattern(const struct imp_pattern *pat, double u, double v) {
        if (pat->kind == IMP_PAT_PHASE) {
                double c = pat->axis == 0 ? u : v;
                return 0.5 + 0.5 * cos(2 * M_PI * c / pat->period_px + 2 * M_PI * pat->step / pat->steps);
        }
        return imp_sl_pattern_value(pat, (int) floor(u), (int) floor(v));
}

struct scene {
        struct imp_pattern *seq;
        int n;
        struct imp_image **img, **sat;
};

static void render(struct scene *s) {
        double periods[] = { PERIOD };
        CHECK_OK(imp_sl_sequence(PW, PH, 4, periods, 1, &s->seq, &s->n));
        s->img = calloc(s->n, sizeof *s->img);
        s->sat = calloc(s->n, sizeof *s->sat);
        uint64_t rng = 7;
        for (int i = 0; i < s->n; i++) {
                const struct imp_pattern *pat = &s->seq[i];
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, &s->img[i]));
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_U8, &s->sat[i]));
                for (int y = 0; y < CH; y++)
                        for (int x = 0; x < CW; x++) {
                                double u = true_u(x), v = true_v(y);
                                if (band_a(x) && pat->kind == IMP_PAT_PHASE)
                                        u += BAD_PHASE_PX, v += BAD_PHASE_PX;
                                double val = 0.05 + 0.8 * pattern(pat, u, v) + NOISE * test_nrand(&rng);
                                bool clip = band_b(x) && pat->kind == IMP_PAT_PHASE && val > CLIP;
                                *imp_image_f32(s->img[i], x, y) = (float) (clip ? CLIP : val);
                                *imp_image_u8(s->sat[i], x, y) = clip;
                        }
        }
}

struct figures {
        long valid, unflagged, beyond_unflagged, flagged, beyond_flagged;
        long a_pix, a_flagged, b_pix, b_flagged, nonfinite;
        double b_err_max, sigma_med_unflagged;
};

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

static struct figures decode(const struct scene *s, bool masks, double margin_px, bool keep_phase) {
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_F32);
        p.proj_width = PW;
        p.proj_height = PH;
        p.phase_margin_px = margin_px;
        p.keep_phase = keep_phase;
        p.threads = 1;
        struct imp_sl_frames fr = { s->seq, (const struct imp_image *const *) s->img, s->n,
                                    masks ? (const struct imp_image *const *) s->sat : NULL };
        struct imp_sl_result *r = NULL;
        struct figures f = {};
        CHECK_OK(imp_sl_decode(&fr, &p, &r, NULL));
        double *sig_unf = malloc((size_t) CW * CH * sizeof *sig_unf);
        if (!r || !sig_unf) {
                free(sig_unf);
                return f;
        }
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        size_t o = (size_t) y * CW + x;
                        uint16_t fl = r->flags[o];
                        f.nonfinite += !isfinite(r->proj_x[o]) + !isfinite(r->proj_y[o]) +
                                       !isfinite(imp_sl_sigma(r->sigma_px[o]));
                        if (!(fl & IMP_SL_VALID_X) || !(fl & IMP_SL_VALID_Y))
                                continue;
                        f.valid++;
                        double conf = fmax(imp_sl_conf(r->confidence[o]), 1e-6);
                        double sig = fmax(SIGMA_TRI_PX / fmin(conf, 1.0), imp_sl_sigma(r->sigma_px[o]));
                        double e = fmax(fabs(r->proj_x[o] - true_u(x)), fabs(r->proj_y[o] - true_v(y)));
                        bool flagged = fl & (IMP_SL_PHASE_REJECTED | IMP_SL_SATURATED);
                        bool beyond = e > 3 * sig;
                        f.flagged += flagged;
                        f.beyond_flagged += flagged && beyond;
                        if (!flagged)
                                sig_unf[f.unflagged] = sig;
                        f.unflagged += !flagged;
                        f.beyond_unflagged += !flagged && beyond;
                        if (band_a(x)) {
                                f.a_pix++;
                                f.a_flagged += !!(fl & IMP_SL_PHASE_REJECTED);
                        }
                        if (band_b(x)) {
                                f.b_pix++;
                                f.b_flagged += !!(fl & IMP_SL_SATURATED);
                                f.b_err_max = fmax(f.b_err_max, e);
                        }
                }
        if (f.unflagged) {
                qsort(sig_unf, f.unflagged, sizeof *sig_unf, cmp_double);
                f.sigma_med_unflagged = sig_unf[f.unflagged / 2];
        }
        free(sig_unf);
        imp_sl_result_free(r);
        return f;
}

static void report(const char *what, const struct figures *f) {
        fprintf(stderr, "%s: %ld valid; unflagged %ld (%ld beyond 3σ), flagged %ld (%ld beyond 3σ); "
                "band A %ld/%ld phase-rejected, band B %ld/%ld saturated (max error %.3f px); "
                "median σ of the unflagged %.3f px\n", what, f->valid, f->unflagged,
                f->beyond_unflagged, f->flagged, f->beyond_flagged, f->a_flagged, f->a_pix, f->b_flagged,
                f->b_pix, f->b_err_max, f->sigma_med_unflagged);
}

int main(void) {
        struct scene s = {};
        render(&s);

        /* With every guard on. */
        struct figures f = decode(&s, true, 0.5, false);
        report("guards on", &f);
        CHECK_INT_EQ(f.nonfinite, 0);
        CHECK_GE(f.valid, 0.9 * CW * CH);
        CHECK_INT_EQ(f.a_flagged, f.a_pix);        /* every contradicting pixel says so */
        CHECK_INT_EQ(f.b_flagged, f.b_pix);        /* every clipped pixel says so */
        CHECK_LE(f.beyond_unflagged, 0.01 * f.unflagged);
        CHECK_LE(f.beyond_flagged, 0.01 * f.flagged);   /* and even the flagged ones' σ covers */
        CHECK_LE(f.sigma_med_unflagged, 0.15);          /* the good pixels keep a useful σ */

        /* The per-pixel phase check off (and the axis-level guard, which would otherwise
         * throw away every pixel's phase for band A's sake): band A keeps a phase 1.5 px
         * off with a phase σ. */
        struct figures off_a = decode(&s, true, INFINITY, true);
        report("phase check off", &off_a);
        /* Then the σ of every pixel is honest only by being useless (the axis's phase error
         * estimate swallows band A) — or, where it is not, it is dishonest. */
        CHECK_INT_EQ(off_a.a_flagged, 0);
        CHECK(off_a.sigma_med_unflagged > 3 * f.sigma_med_unflagged ||
              off_a.beyond_unflagged > 0.01 * off_a.unflagged);

        /* No saturation masks: f32 values cannot say they were clipped, band B goes
         * unflagged (its σ then rests on the confidence alone). */
        struct figures off_b = decode(&s, false, 0.5, false);
        report("saturation masks off", &off_b);
        CHECK_INT_EQ(off_b.b_flagged, 0);

        for (int i = 0; i < s.n; i++) {
                imp_image_free(s.img[i]);
                imp_image_free(s.sat[i]);
        }
        free(s.img);
        free(s.sat);
        free(s.seq);
        return TEST_DONE();
}
