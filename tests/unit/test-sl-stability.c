/* Hard cases for the structured-light decoder: pixels the projector does not reach,
 * pixels saturated in every frame, pixels dark in every frame, a depth discontinuity that
 * jumps by half a phase period exactly where the phase wraps, and non-finite f32 samples.
 * Every output must be finite and every such pixel must carry an explicit flag. */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include "structured-light.h"
#include "test.h"

#define PW 64
#define PH 48
#define CW 96
#define CH 72
#define PERIOD 16.0
#define JUMP_X 32       /* camera column of the discontinuity: u = 16 (a phase wrap) */

enum region { R_NORMAL, R_UNREACHED, R_SATURATED, R_DARK, R_MIXED };

static enum region region(int x, int y) {
        if (x < 12)
                return R_UNREACHED;
        if (y < 8)
                return R_SATURATED;
        if (y < 16)
                return R_DARK;
        if (x == JUMP_X)
                return R_MIXED;
        return R_NORMAL;
}

/* Surface left of the discontinuity maps u = x/2, right of it u = x/2 + P/2. */
static double true_u(double cx) { return cx / 2 + (cx >= JUMP_X ? PERIOD / 2 : 0); }
static double true_v(double cy) { return cy / 2; }

static double intensity(const struct imp_pattern *pat, double u, double v) {
        if (pat->kind == IMP_PAT_PHASE) {
                double c = pat->axis == 0 ? u : v;
                return 0.5 + 0.5 * cos(2 * M_PI * c / pat->period_px + 2 * M_PI * pat->step / pat->steps);
        }
        return imp_sl_pattern_value(pat, (int) floor(u), (int) floor(v));
}

static double pixel(const struct imp_pattern *pat, int x, int y) {
        switch (region(x, y)) {
        case R_UNREACHED:
                return 30;
        case R_SATURATED:
                return 255;
        case R_DARK:
                return 0;
        case R_MIXED: {
                /* Half the pixel sees each surface. */
                double a = intensity(pat, true_u(JUMP_X - 0.25), true_v(y + 0.5));
                double b = intensity(pat, true_u(JUMP_X + 0.25), true_v(y + 0.5));
                return 20 + 200 * 0.5 * (a + b);
        }
        default:
                return 20 + 200 * intensity(pat, true_u(x + 0.5), true_v(y + 0.5));
        }
}

static void check_finite(const struct imp_sl_result *r, const char *what) {
        long bad = 0, badconf = 0;
        size_t n = (size_t) r->width * r->height;
        for (size_t o = 0; o < n; o++) {
                bad += !isfinite(r->proj_x[o]) + !isfinite(r->proj_y[o]) + !isfinite(imp_sl_sigma(r->sigma_px[o])) +
                       !isfinite(r->direct[o]) + !isfinite(r->global[o]) + !isfinite(r->modulation[o]);
                badconf += r->confidence[o] && !(r->flags[o] & (IMP_SL_VALID_X | IMP_SL_VALID_Y));
        }
        fprintf(stderr, "%s: %ld non-finite outputs, %ld nonzero confidences without a valid axis\n", what, bad, badconf);
        CHECK_INT_EQ(bad, 0);
        CHECK_INT_EQ(badconf, 0);
}

static void check_regions(const struct imp_sl_result *r) {
        long n[5] = { 0 }, wrong[5] = { 0 }, good = 0, near_jump = 0, near_ok = 0;
        const int explain = IMP_SL_LOW_MODULATION | IMP_SL_DISAGREE | IMP_SL_UNDECODABLE | IMP_SL_WEAK_BIT;
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        size_t o = (size_t) y * CW + x;
                        int f = r->flags[o];
                        bool valid = f & (IMP_SL_VALID_X | IMP_SL_VALID_Y);
                        enum region g = region(x, y);
                        n[g]++;
                        switch (g) {
                        case R_UNREACHED:
                        case R_DARK:
                                wrong[g] += valid || !(f & IMP_SL_SHADOW) || r->confidence[o] != 0;
                                break;
                        case R_SATURATED:
                                wrong[g] += valid || !(f & IMP_SL_SATURATED) || !(f & IMP_SL_SHADOW);
                                break;
                        case R_MIXED:
                                /* Either refused, or kept with a flag saying how weak it is. */
                                wrong[g] += (f & IMP_SL_SUBPIXEL_X) || !(f & explain);
                                break;
                        case R_NORMAL: {
                                double ex = r->proj_x[o] - true_u(x + 0.5), ey = r->proj_y[o] - true_v(y + 0.5);
                                bool ok = (f & IMP_SL_SUBPIXEL_X) && (f & IMP_SL_SUBPIXEL_Y) &&
                                          fabs(ex) < 0.05 && fabs(ey) < 0.05;
                                good += ok;
                                if (abs(x - JUMP_X) == 1) {
                                        near_jump++;
                                        near_ok += ok;
                                }
                                break;
                        }
                        }
                }
        static const char *names[] = { "normal", "unreached", "saturated", "dark", "mixed" };
        for (int g = R_UNREACHED; g <= R_MIXED; g++) {
                fprintf(stderr, "region %s: %ld pixels, %ld without the expected flags\n", names[g], n[g], wrong[g]);
                CHECK_INT_EQ(wrong[g], 0);
        }
        fprintf(stderr, "normal pixels within 0.05 px: %ld of %ld; beside the jump (u = 16⁻ | 24⁺): %ld of %ld\n",
                good, n[R_NORMAL], near_ok, near_jump);
        CHECK_INT_EQ(good, n[R_NORMAL]);
        CHECK_INT_EQ(near_ok, near_jump);
}

int main(void) {
        double periods[] = { PERIOD };
        struct imp_pattern *seq = NULL;
        int n = 0;
        CHECK_OK(imp_sl_sequence(PW, PH, 4, periods, 1, &seq, &n));
        struct imp_image **img = calloc(n, sizeof *img), **imgf = calloc(n, sizeof *imgf);
        for (int i = 0; i < n; i++) {
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_U8, &img[i]));
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, &imgf[i]));
                for (int y = 0; y < CH; y++)
                        for (int x = 0; x < CW; x++) {
                                double v = pixel(&seq[i], x, y);
                                *imp_image_u8(img[i], x, y) = (uint8_t) lround(v);
                                *imp_image_f32(imgf[i], x, y) = (float) v;
                        }
        }
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_U8);
        p.proj_width = PW;
        p.proj_height = PH;
        struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img, n };
        struct imp_error err = { 0 };
        _cleanup_(imp_sl_result_freep) struct imp_sl_result *r = NULL;
        CHECK_OK(imp_sl_decode(&fr, &p, &r, &err));
        if (r) {
                check_finite(r, "u8");
                check_regions(r);
                long vx = 0;
                for (size_t o = 0; o < (size_t) CW * CH; o++)
                        vx += !!(r->flags[o] & IMP_SL_VALID_X);
                CHECK_INT_EQ(vx, r->n_valid_x);
        }

        /* f32 frames with NaN and ±Inf samples: treated as 0, nothing non-finite comes out. */
        *imp_image_f32(imgf[0], 50, 40) = NAN;
        *imp_image_f32(imgf[3], 51, 40) = INFINITY;
        *imp_image_f32(imgf[n - 1], 52, 40) = -INFINITY;
        *imp_image_f32(imgf[n - 2], 53, 40) = NAN;
        struct imp_sl_params pf = p;          /* same DN scale: the f32 frames hold 0..255 */
        pf.saturation = 255;
        struct imp_sl_frames ff = { seq, (const struct imp_image *const *) imgf, n };
        _cleanup_(imp_sl_result_freep) struct imp_sl_result *rf = NULL;
        CHECK_OK(imp_sl_decode(&ff, &pf, &rf, &err));
        if (rf)
                check_finite(rf, "f32 with NaN/Inf samples");

        /* Everything constant: all shadow, nothing valid, still finite. */
        for (int i = 0; i < n; i++)
                memset(img[i]->data, 77, img[i]->stride * CH);
        _cleanup_(imp_sl_result_freep) struct imp_sl_result *rc = NULL;
        CHECK_OK(imp_sl_decode(&fr, &p, &rc, &err));
        if (rc) {
                check_finite(rc, "constant frames");
                CHECK_INT_EQ(rc->n_valid_x + rc->n_valid_y, 0);
                CHECK_INT_EQ(rc->n_shadow, (size_t) CW * CH);
        }
        /* The same without robust classification and without a shadow threshold. */
        p.robust = false;
        p.shadow_threshold = -1;
        p.min_bit_contrast = 0;
        _cleanup_(imp_sl_result_freep) struct imp_sl_result *rn = NULL;
        CHECK_OK(imp_sl_decode(&fr, &p, &rn, &err));
        if (rn)
                check_finite(rn, "constant frames, no thresholds");

        for (int i = 0; i < n; i++) {
                imp_image_free(img[i]);
                imp_image_free(imgf[i]);
        }
        free(img);
        free(imgf);
        free(seq);
        return TEST_DONE();
}
