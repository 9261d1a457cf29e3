/* Real projector–camera Gray-code captures (../shared/data/procam-graycode, from
 * kamino410/procam-calibration): impasto's decoder against OpenCV's GrayCodePattern on
 * the same frames, and the pattern order checked by decoding the projected patterns. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include "cv-graycode.h"
#include "structured-light.h"
#include "test.h"

#define PROJ_W 1024
#define PROJ_H 768
#define NFRAMES 42
#define DATA IMPASTO_SHARED_DIR "/data/procam-graycode/sample_data"
/* The thresholds of procam-calibration's calibrate.py (-black_thr 40, -white_thr 5). */
#define BLACK_THR 40
#define WHITE_THR 5

static int load_set(const char *dir, const char *prefix, struct imp_image **imgs) {
        for (int i = 0; i < NFRAMES; i++) {
                char path[512];
                snprintf(path, sizeof path, "%s/%s%02d.png", dir, prefix, i);
                struct imp_error err = { 0 };
                int r = imp_png_read(path, &imgs[i], &err);
                if (r < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        return r;
                }
        }
        return 0;
}

static void free_set(struct imp_image **imgs) {
        for (int i = 0; i < NFRAMES; i++) {
                imp_image_free(imgs[i]);
                imgs[i] = NULL;
        }
}

static struct imp_sl_params params_u8(void) {
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_U8);
        p.proj_width = PROJ_W;
        p.proj_height = PROJ_H;
        p.shadow_threshold = BLACK_THR;
        p.min_bit_contrast = WHITE_THR;
        return p;
}

/* impasto's pattern model, OpenCV's generator and the shipped PNGs must be one thing. */
static void test_pattern_order(struct imp_pattern *seq, int nseq) {
        struct imp_image **cvp = NULL;
        size_t ncv = 0;
        struct imp_error err = { 0 };
        CHECK_OK(imp_cv_graycode_generate(PROJ_W, PROJ_H, &cvp, &ncv, &err));
        CHECK_INT_EQ(ncv, 40);
        CHECK_INT_EQ(imp_cv_graycode_count(PROJ_W, PROJ_H), 40);
        struct imp_image *png[NFRAMES] = { 0 };
        if (load_set(DATA "/graycode_pattern", "pattern_", png) < 0) {
                CHECK_MSG(0, "cannot load the pattern PNGs");
                imp_cv_graycode_images_free(cvp, ncv);
                return;
        }
        long diff_cv = 0, diff_model = 0;
        for (int i = 0; i < nseq && i < NFRAMES; i++)
                for (int y = 0; y < PROJ_H; y++)
                        for (int x = 0; x < PROJ_W; x++) {
                                int v = *imp_image_u8(png[i], x, y);
                                int m = imp_sl_pattern_value(&seq[i], x, y) > 0.5 ? 255 : 0;
                                diff_model += v != m;
                                if (i < (int) ncv)
                                        diff_cv += v != *imp_image_u8(cvp[i], x, y);
                        }
        CHECK_INT_EQ(diff_cv, 0);
        CHECK_INT_EQ(diff_model, 0);
        imp_cv_graycode_images_free(cvp, ncv);

        /* The patterns decoded as if captured: every projector pixel is its own code. */
        struct imp_sl_params p = params_u8();
        struct imp_sl_frames fr = { seq, (const struct imp_image *const *) png, NFRAMES };
        _cleanup_(imp_sl_result_freep) struct imp_sl_result *res = NULL;
        CHECK_OK(imp_sl_decode(&fr, &p, &res, &err));
        if (res) {
                long exact = 0;
                for (int y = 0; y < PROJ_H; y++)
                        for (int x = 0; x < PROJ_W; x++) {
                                size_t o = (size_t) y * PROJ_W + x;
                                exact += (res->flags[o] & IMP_SL_VALID_X) && (res->flags[o] & IMP_SL_VALID_Y) &&
                                         res->proj_x[o] == x + 0.5f && res->proj_y[o] == y + 0.5f;
                        }
                fprintf(stderr, "patterns decoded as captures: %ld / %d exact\n", exact, PROJ_W * PROJ_H);
                CHECK_INT_EQ(exact, PROJ_W * PROJ_H);
        }
        free_set(png);
}

int main(void) {
        FILE *probe = fopen(DATA "/capture_0/graycode_00.png", "rb");
        if (!probe)
                TEST_SKIP("no procam data at %s", DATA);
        fclose(probe);

        struct imp_pattern *seq = NULL;
        int nseq = 0;
        CHECK_OK(imp_sl_sequence(PROJ_W, PROJ_H, 0, NULL, 0, &seq, &nseq));
        CHECK_INT_EQ(nseq, NFRAMES);
        test_pattern_order(seq, nseq);

        long tot_both = 0, tot_agree = 0, tot_imp = 0, tot_cv = 0;
        for (int cap = 0; cap < 5; cap++) {
                struct imp_image *img[NFRAMES] = { 0 };
                char dir[256];
                snprintf(dir, sizeof dir, DATA "/capture_%d", cap);
                if (load_set(dir, "graycode_", img) < 0) {
                        CHECK_MSG(0, "capture %d: cannot load", cap);
                        continue;
                }
                int w = img[0]->width, h = img[0]->height;
                size_t n = (size_t) w * h;
                struct imp_sl_params p = params_u8();
                struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img, NFRAMES };
                struct imp_error err = { 0 };
                _cleanup_(imp_sl_result_freep) struct imp_sl_result *res = NULL;
                CHECK_OK(imp_sl_decode(&fr, &p, &res, &err));

                _cleanup_free_ int32_t *cx = malloc(n * sizeof *cx), *cy = malloc(n * sizeof *cy);
                _cleanup_free_ uint8_t *cv = malloc(n);
                size_t ncv = 0;
                CHECK(cx && cy && cv);
                if (!res || !cx || !cy || !cv) {
                        free_set(img);
                        continue;
                }
                CHECK_OK(imp_cv_graycode_decode(PROJ_W, PROJ_H, (const struct imp_image *const *) img, 40,
                                                img[40], img[41], BLACK_THR, WHITE_THR, cx, cy, cv,
                                                &ncv, &err));
                long both = 0, agree = 0, nimp = 0, cv_only = 0;
                for (size_t o = 0; o < n; o++) {
                        bool iv = (res->flags[o] & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) ==
                                  (IMP_SL_VALID_X | IMP_SL_VALID_Y);
                        nimp += iv;
                        cv_only += cv[o] && !iv;
                        if (!iv || !cv[o])
                                continue;
                        both++;
                        agree += (int) res->proj_x[o] == cx[o] && (int) res->proj_y[o] == cy[o];
                }
                double pct = both ? 100.0 * agree / both : 0;
                fprintf(stderr, "capture %d: impasto %ld, OpenCV %zu, both %ld, agree %ld (%.3f%%), "
                        "OpenCV-only %ld, weak-bit %zu\n", cap, nimp, ncv, both, agree, pct, cv_only,
                        res->n_weak);
                CHECK_GE(pct, 99.0);
                CHECK_INT_GE(nimp, (long) ncv);
                CHECK_INT_GE(both, 100000);
                tot_both += both;
                tot_agree += agree;
                tot_imp += nimp;
                tot_cv += (long) ncv;
                free_set(img);
        }
        fprintf(stderr, "all captures: impasto %ld, OpenCV %ld decoded; agreement %.3f%% of %ld\n",
                tot_imp, tot_cv, tot_both ? 100.0 * tot_agree / tot_both : 0.0, tot_both);
        free(seq);
        return TEST_DONE();
}
