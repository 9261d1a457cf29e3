/* Shadow fill end to end (docs/geometry.md "Shadow fill"): the small appearance
 * scene (12 × 8 mm canvas in a 1 mm raised frame, projector off axis, dome) rendered by
 * `impasto sim render`, processed by imp_process_capture() with the fill off and on, and
 * compared with the truth. Asserts that the fill adds canvas (mask IoU up by ≥ 0.01,
 * filled texels in the mask) without any copy texel over the truth's frame, that the
 * measured texels are unchanged, and that the filled heights and normals are close to the
 * truth. ~10 s (release). */
#include <math.h>
#include <stdlib.h>
#include <unistd.h>
#include <jansson.h>
#include "compare.h"
#include "image.h"
#include "process.h"
#include "test.h"

/* Copy texels (mask ≥ 0.5) whose canvas position falls on a truth sample outside the
 * truth canvas mask: texels on the frame. */
static long texels_on_frame(const char *copy, const char *truth) {
        char path[4096];
        char **cn = NULL, **tn = NULL;
        struct imp_image *ci = NULL, *ti = NULL;
        long n = -1;
        snprintf(path, sizeof path, "%s/heightfield.exr", copy);
        CHECK_OK(imp_exr_read(path, &ci, &cn, NULL));
        snprintf(path, sizeof path, "%s/heightfield.exr", truth);
        CHECK_OK(imp_exr_read(path, &ti, &tn, NULL));
        snprintf(path, sizeof path, "%s/copy.json", copy);
        json_t *cj = json_load_file(path, 0, NULL);
        snprintf(path, sizeof path, "%s/truth.json", truth);
        json_t *tj = json_load_file(path, 0, NULL);
        CHECK(ci && ti && cj && tj);
        if (ci && ti && cj && tj) {
                double M[16], cp = json_real_value(json_object_get(cj, "pitch_mm"));
                double tp = json_real_value(json_object_get(tj, "pitch_mm"));
                double to[2] = { json_real_value(json_array_get(json_object_get(tj, "origin_mm"), 0)),
                                 json_real_value(json_array_get(json_object_get(tj, "origin_mm"), 1)) };
                for (int k = 0; k < 16; k++)
                        M[k] = json_real_value(json_array_get(json_object_get(cj, "canvas_to_world"), k));
                int cm = imp_image_channel_index(cn, "mask"), ch = imp_image_channel_index(cn, "height");
                int tm = imp_image_channel_index(tn, "mask");
                n = 0;
                for (int j = 0; j < ci->height; j++)
                        for (int i = 0; i < ci->width; i++) {
                                const float *p = imp_image_f32(ci, i, j);
                                if (!(p[cm] >= 0.5))
                                        continue;
                                double x = M[3] + i * cp * M[0] + j * cp * M[1] + p[ch] * M[2];
                                double y = M[7] + i * cp * M[4] + j * cp * M[5] + p[ch] * M[6];
                                long ti_ = lround((x - to[0]) / tp), tj_ = lround((y - to[1]) / tp);
                                n += ti_ < 0 || tj_ < 0 || ti_ >= ti->width || tj_ >= ti->height ||
                                     imp_image_f32(ti, (int) ti_, (int) tj_)[tm] < 0.5;
                        }
        }
        json_decref(cj);
        json_decref(tj);
        imp_strv_free(cn);
        imp_strv_free(tn);
        imp_image_free(ci);
        imp_image_free(ti);
        return n;
}

int main(void) {
        const char *tmp = test_tmpdir();
        char bin[4096], cmd[16384], set[4200], truth[4300], off[4200], on[4200];
        snprintf(bin, sizeof bin, "%s/cli/impasto", IMPASTO_BINARY_DIR);
        if (access(bin, X_OK) != 0)
                TEST_SKIP("%s not built", bin);
        snprintf(set, sizeof set, "%s/set", tmp);
        snprintf(truth, sizeof truth, "%s/truth", set);
        snprintf(off, sizeof off, "%s/copy-off", tmp);
        snprintf(on, sizeof on, "%s/copy-on", tmp);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s/tests/data/appearance-small.cfg "
                 "--plan %s/tests/data/appearance-small-plan.cfg --out %s --seed 5 --threads 2 --quiet",
                 bin, IMPASTO_SOURCE_DIR, IMPASTO_SOURCE_DIR, set);
        CHECK_INT_EQ(system(cmd), 0);

        struct imp_process_options o;
        imp_process_options_default(&o);
        CHECK_INT_GE(o.heightfield.shadow_fill_px, 1);   /* on by default */
        struct imp_error err = {};
        struct imp_compare_result a = {}, b = {};
        o.heightfield.shadow_fill_px = 0;
        CHECK_OK(imp_process_capture(set, off, &o, &err));
        imp_process_options_default(&o);
        CHECK_OK(imp_process_capture(set, on, &o, &err));
        CHECK_OK(imp_compare_dirs(off, truth, &a, &err));
        CHECK_OK(imp_compare_dirs(on, truth, &b, &err));
        long frame_off = texels_on_frame(off, truth), frame_on = texels_on_frame(on, truth);
        fprintf(stderr, "fill off: IoU %.4f, %zu texels, height %.2f um, normal %.2f deg, %ld on the frame\n",
                a.mask_iou, a.n_compared, a.height_rmse_um, a.normal_err_deg_mean, frame_off);
        fprintf(stderr, "fill on:  IoU %.4f, %zu texels (%zu filled: height %.2f um, normal %.2f deg), "
                "measured height %.2f um, normal %.2f deg, %ld on the frame\n", b.mask_iou, b.n_compared,
                b.n_filled, b.height_rmse_um_filled, b.normal_err_deg_mean_filled, b.height_rmse_um_measured,
                b.normal_err_deg_mean_measured, frame_on);
        CHECK_INT_EQ(a.n_filled, 0);
        CHECK_INT_GE(b.n_filled, 1000);
        CHECK_GE(b.mask_iou, a.mask_iou + 0.01);
        CHECK_INT_EQ(frame_off, 0);
        CHECK_INT_EQ(frame_on, 0);                          /* the fill stays off the frame */
        CHECK_INT_EQ(b.n_compared - b.n_filled, a.n_compared);   /* measured texels unchanged */
        CHECK_NEAR(b.height_rmse_um_measured, a.height_rmse_um, 0.5);
        CHECK_LE(b.height_rmse_um_filled, 20.0);            /* integrated, not flat-extended */
        CHECK_LE(b.normal_err_deg_mean_filled, 6.0);
        CHECK_INT_EQ(b.nan_count, 0);
        if (!getenv("IMPASTO_KEEP_TEST_OUTPUT")) {
                snprintf(cmd, sizeof cmd, "rm -rf %s", tmp);
                CHECK_INT_EQ(system(cmd), 0);
        }
        return TEST_DONE();
}
