/* The decoder's 16-bit maps: confidence in fixed point (imp_sl_conf16 / imp_sl_conf) and σ
 * in bfloat16 (imp_sl_sigma16 / imp_sl_sigma), within their stated bounds, on the encoders
 * alone and on decoded maps whose float values are known exactly.
 *
 * The scene: camera pixel (x, y) sees projector pixel (x, y); a lit sample is
 * DARK + span(x, y), a dark one DARK, except the finest column plane (and its inverse), whose
 * lit sample has a contrast of 3-99 % of the span. Every bit is decided by its sign (L_d ≥ 80 >
 * L_g = 2·DARK), so confidence is exactly the float cm / span (cm that plane's contrast), and
 * σ of a Gray centre is q/√12 with q = 1. Decoded from u8 (byte-lane combine), u16 (integer
 * path) and f32 frames (float path), and with 4-step phase frames (the phase path, σ raised
 * to the axis's measured error). A wrong scale on either side (65536, 255, a float read as
 * its upper half the other way round) puts a value outside its bound. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "structured-light.h"
#include "test.h"

#define W 100           /* camera = projector */
#define H 40
#define DARK 20
#define CONF_TOL (0.51 / IMP_SL_CONF_ONE)      /* stated in structured-light.h */
#define SIGMA_REL 0x1p-8                        /* likewise */
#define INV_SQRT12 0.28867513f

static int span_at(int x, int y) {
        return 80 + (x * 13 + y * 7) % 150;    /* 80..229: lit ≤ 249 < 255 */
}

/* The finest column plane's lit sample: 3-99 % of the span, at least 6 (> min_bit_contrast). */
static int weak_lit(int x, int y) {
        int s = span_at(x, y), c = s * ((x + 3 * y) % 97 + 3) / 100;
        return DARK + (c < 6 ? 6 : c);
}

static void test_encoders(void) {
        uint64_t rng = 0x1234567;
        double worst_c = 0, worst_s = 0;
        for (int i = 0; i < 200000; i++) {
                float c = i < 65536 ? (float) i / 65535.0f : (float) test_urand(&rng);
                double ec = fabs((double) imp_sl_conf(imp_sl_conf16(c)) - c);
                worst_c = ec > worst_c ? ec : worst_c;
                float s = (float) (exp(40 * test_urand(&rng) - 20));   /* 2e-9 .. 5e8 */
                double es = fabs((double) imp_sl_sigma(imp_sl_sigma16(s)) - s) / s;
                worst_s = es > worst_s ? es : worst_s;
        }
        fprintf(stderr, "encoders: confidence error ≤ %.3g (bound %.3g), σ relative ≤ %.3g (bound %.3g)\n",
                worst_c, CONF_TOL, worst_s, SIGMA_REL);
        CHECK_LE(worst_c, CONF_TOL);
        CHECK_LE(worst_s, SIGMA_REL);
        CHECK_INT_EQ(imp_sl_conf16(0.0f), 0);
        CHECK_INT_EQ(imp_sl_conf16(1.0f), IMP_SL_CONF_ONE);
        CHECK_INT_EQ(imp_sl_conf16(NAN), 0);
        CHECK_INT_EQ(imp_sl_conf16(2.0f), IMP_SL_CONF_ONE);
        CHECK(imp_sl_conf(IMP_SL_CONF_ONE) == 1.0f);
        CHECK(imp_sl_sigma(imp_sl_sigma16(0.0f)) == 0.0f);
        CHECK(imp_sl_sigma(imp_sl_sigma16(0.375f)) == 0.375f);     /* 8 significant bits: exact */
        CHECK(imp_sl_sigma(imp_sl_sigma16(INFINITY)) == INFINITY);
}

/* A phase frame's projector intensity at camera pixel (x, y), which sees the projector at
 * x + f, y + f on the axis: f = 0.15 or 0.85, so that the phase's mean squared distance to
 * the Gray centre, 0.1225, exceeds the 1/12 of a uniform position (a measured phase error of
 * √(0.1225 − 1/12) ≈ 0.2 px, below the Gray code's 0.29: the phase is kept). */
static double phase_value(const struct imp_pattern *pat, int x, int y) {
        int c = pat->axis == 0 ? x : y;
        double f = (x + 3 * y + pat->axis) % 2 ? 0.85 : 0.15;
        return 0.5 + 0.5 * cos(2 * M_PI * (c + f) / pat->period_px + 2 * M_PI * pat->step / pat->steps);
}

/* The frames of the scene in type t (values as they are: u16 and f32 hold 0..255 too). */
static void make_frames(const struct imp_pattern *seq, int n, enum imp_pixel_type t, struct imp_image **img) {
        for (int i = 0; i < n; i++) {
                CHECK_OK(imp_image_new(W, H, 1, t, &img[i]));
                const struct imp_pattern *pat = &seq[i];
                bool finest_x = pat->kind == IMP_PAT_GRAY && pat->axis == 0 && pat->bit == pat->nbits - 1;
                for (int y = 0; y < H; y++)
                        for (int x = 0; x < W; x++) {
                                double v = imp_sl_pattern_value(pat, x, y);
                                double lit = finest_x ? weak_lit(x, y) : DARK + span_at(x, y);
                                double s = pat->kind == IMP_PAT_PHASE ? round(DARK + span_at(x, y) * phase_value(pat, x, y))
                                                                      : v > 0.5 ? lit : DARK;
                                if (t == IMP_PIX_U8)
                                        *imp_image_u8(img[i], x, y) = (uint8_t) s;
                                else if (t == IMP_PIX_U16)
                                        *imp_image_u16(img[i], x, y) = (uint16_t) s;
                                else
                                        *imp_image_f32(img[i], x, y) = (float) s;
                        }
        }
}

static struct imp_sl_result *decode(const struct imp_pattern *seq, int n, enum imp_pixel_type t) {
        struct imp_image *img[64];
        make_frames(seq, n, t, img);
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_U8);          /* thresholds in the frames' 0..255 */
        p.proj_width = W;
        p.proj_height = H;
        p.threads = 1;
        struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img, n, NULL };
        struct imp_sl_result *r = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_sl_decode(&fr, &p, &r, &err));
        for (int i = 0; i < n; i++)
                imp_image_free(img[i]);
        return r;
}

/* Gray only: every pixel valid, confidence = cm / span as the decoder's float, σ = 1/√12. */
static void check_gray(const struct imp_sl_result *r, const char *what) {
        if (!r)
                return;
        long valid = 0, conf_exact = 0, sig_exact = 0;
        double worst_c = 0, worst_s = 0;
        const float sig = INV_SQRT12 * 1.0f;
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++) {
                        size_t o = (size_t) y * W + x;
                        valid += (r->flags[o] & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) == (IMP_SL_VALID_X | IMP_SL_VALID_Y) &&
                                 r->proj_x[o] == x + 0.5f && r->proj_y[o] == y + 0.5f;
                        float c = (float) (weak_lit(x, y) - DARK) / (float) span_at(x, y);
                        double ec = fabs((double) imp_sl_conf(r->confidence[o]) - c);
                        double es = fabs((double) imp_sl_sigma(r->sigma_px[o]) - sig) / sig;
                        worst_c = ec > worst_c ? ec : worst_c;
                        worst_s = es > worst_s ? es : worst_s;
                        conf_exact += r->confidence[o] == imp_sl_conf16(c);
                        sig_exact += r->sigma_px[o] == imp_sl_sigma16(sig);
                }
        fprintf(stderr, "%s: %ld of %d valid at their own projector pixel; confidence error ≤ %.3g, "
                "σ relative ≤ %.3g; %ld / %ld encoded as the float rounded once\n", what, valid, W * H,
                worst_c, worst_s, conf_exact, sig_exact);
        CHECK_INT_EQ(valid, W * H);
        CHECK_LE(worst_c, CONF_TOL);
        CHECK_LE(worst_s, SIGMA_REL);
        CHECK_INT_EQ(conf_exact, W * H);
        CHECK_INT_EQ(sig_exact, W * H);
}

/* With phase: σ of a pixel refined by phase on both axes is the larger measured phase error,
 * rounded once; confidence is 0 exactly where no axis is valid. */
static void check_phase(const struct imp_sl_result *r) {
        if (!r)
                return;
        const float e = fmaxf(r->phase_err_px[0], r->phase_err_px[1]);
        long sub = 0, sig_ok = 0, conf_bad = 0;
        for (size_t o = 0; o < (size_t) W * H; o++) {
                uint16_t f = r->flags[o];
                const uint16_t both = IMP_SL_VALID_X | IMP_SL_VALID_Y | IMP_SL_SUBPIXEL_X | IMP_SL_SUBPIXEL_Y;
                conf_bad += !(f & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) != !r->confidence[o];
                if ((f & both) != both)
                        continue;
                sub++;
                double s = imp_sl_sigma(r->sigma_px[o]);
                sig_ok += r->sigma_px[o] == imp_sl_sigma16(e) && fabs(s - e) <= SIGMA_REL * e;
        }
        fprintf(stderr, "phase: error %.4f / %.4f px, %ld pixels refined on both axes, %ld with σ = the error "
                "within 2^-8; %ld with confidence 0 ≠ no valid axis\n", r->phase_err_px[0], r->phase_err_px[1],
                sub, sig_ok, conf_bad);
        CHECK(e > 0);
        CHECK_INT_GE(sub, W * H / 2);
        CHECK_INT_EQ(sig_ok, sub);
        CHECK_INT_EQ(conf_bad, 0);
}

int main(void) {
        test_encoders();
        struct imp_pattern *seq = NULL;
        int n = 0;
        CHECK_OK(imp_sl_sequence(W, H, 0, NULL, 0, &seq, &n));
        static const struct { enum imp_pixel_type t; const char *what; } types[] = {
                { IMP_PIX_U8, "u8" }, { IMP_PIX_U16, "u16" }, { IMP_PIX_F32, "f32" } };
        for (size_t i = 0; i < sizeof types / sizeof *types; i++) {
                struct imp_sl_result *r = decode(seq, n, types[i].t);
                check_gray(r, types[i].what);
                imp_sl_result_free(r);
        }
        free(seq);
        const double period = 16;
        CHECK_OK(imp_sl_sequence(W, H, 4, &period, 1, &seq, &n));
        struct imp_sl_result *r = decode(seq, n, IMP_PIX_U8);
        check_phase(r);
        imp_sl_result_free(r);
        free(seq);
        return TEST_DONE();
}
