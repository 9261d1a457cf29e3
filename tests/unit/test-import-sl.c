/* Import of OpenCV Gray-code sequences (pipeline/model/import-sl.h): the frame count and
 * the calibration checked against the frames, OpenCV's order mapped onto pattern
 * descriptors, and (when ../shared/data/procam-graycode is present) a real capture
 * imported and turned into a range image whose board points lie on a plane. */
#include <errno.h>
#include <sys/stat.h>
#include "captureset.h"
#include "import-sl.h"
#include "process-range.h"
#include "test.h"


/* A rig.json with a W×H camera and a PW×PH projector 100 mm to the side. */
static void write_rig(const char *path, int w, int h, int pw, int ph) {
        struct imp_rig rig = { .n_cameras = 1, .has_projector = true };
        snprintf(rig.cameras[0].name, sizeof rig.cameras[0].name, "camera0");
        rig.cameras[0].model = (struct imp_pinhole) { w, h, 1000, 1000, w / 2.0, h / 2.0, .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 } };
        rig.cameras[0].sensor = (struct imp_sensor) { .bits = 8, .gain_e_per_dn = 1, .full_well_e = 256, .quantum_scale = 1 };
        snprintf(rig.projector.name, sizeof rig.projector.name, "projector");
        rig.projector.model = (struct imp_pinhole) { pw, ph, 800, 800, pw / 2.0, ph / 2.0, .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 },
                                                     .t = { -100, 0, 0 } };
        rig.projector.gamma = 1;
        struct imp_error err = {};
        if (imp_rig_save(path, &rig, &err) < 0) {
                fprintf(stderr, "%s\n", err.msg);
                exit(2);
        }
}

static void write_frames(const char *dir, int n, int w, int h, int odd_w) {
        mkdir(dir, 0755);
        for (int i = 0; i < n; i++) {
                struct imp_image *img;
                struct imp_error err = {};
                if (imp_image_new(i == odd_w ? w + 1 : w, h, 1, IMP_PIX_U8, &img) < 0)
                        exit(2);
                memset(img->data, i * 3, img->stride * h);
                char path[600];
                snprintf(path, sizeof path, "%s/graycode_%02d.png", dir, i);
                if (imp_png_write(path, img, &err) < 0)
                        exit(2);
                imp_image_free(img);
        }
}

static int import(const char *frames, const char *calib, int pw, int ph, const char *out, struct imp_error *err) {
        struct imp_import_sl_options o = { frames, IMP_SL_ORDER_OPENCV_GRAYCODE, pw, ph, calib };
        imp_error_clear(err);
        return imp_import_sl(&o, out, err);
}

static void test_synthetic(const char *base) {
        char rig[512], rig_bad[512], frames[512], short_dir[512], odd[512], out[512];
        snprintf(rig, sizeof rig, "%s/rig.json", base);
        snprintf(rig_bad, sizeof rig_bad, "%s/rig-bad.json", base);
        write_rig(rig, 40, 30, 16, 8);
        write_rig(rig_bad, 40, 30, 32, 8);
        CHECK_INT_EQ(imp_import_sl_frame_count(IMP_SL_ORDER_OPENCV_GRAYCODE, 16, 8), 2 * (4 + 3) + 2);
        CHECK_INT_EQ(imp_import_sl_frame_count(IMP_SL_ORDER_OPENCV_GRAYCODE, 1024, 768), 42);
        snprintf(frames, sizeof frames, "%s/frames", base);
        snprintf(short_dir, sizeof short_dir, "%s/short", base);
        snprintf(odd, sizeof odd, "%s/odd", base);
        write_frames(frames, 16, 40, 30, -1);
        write_frames(short_dir, 15, 40, 30, -1);
        write_frames(odd, 16, 40, 30, 7);
        struct imp_error err = {};
        snprintf(out, sizeof out, "%s/o1", base);
        CHECK_ERR(import(short_dir, rig, 16, 8, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "15 images, expected 16");
        snprintf(out, sizeof out, "%s/o2", base);
        CHECK_ERR(import(frames, rig_bad, 16, 8, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "the projector is 32x8, --projector says 16x8");
        snprintf(out, sizeof out, "%s/o3", base);
        CHECK_ERR(import(odd, rig, 16, 8, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "graycode_07.png: 41x30 8-bit");
        snprintf(out, sizeof out, "%s/o4", base);
        CHECK_ERR(import(frames, "/nonexistent/rig.json", 16, 8, out, &err), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, "/nonexistent/rig.json");
        write_rig(rig_bad, 41, 30, 16, 8);
        snprintf(out, sizeof out, "%s/o5", base);
        CHECK_ERR(import(frames, rig_bad, 16, 8, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "is 41x30, the frames 40x30");
        /* the good one: OpenCV's order as pattern descriptors */
        snprintf(out, sizeof out, "%s/good", base);
        CHECK_OK(import(frames, rig, 16, 8, out, &err));
        struct imp_captureset *cs = NULL;
        CHECK_OK(imp_captureset_open(out, &cs, &err));
        if (!cs)
                return;
        CHECK_INT_EQ(imp_captureset_count(cs), 16);
        const struct imp_pattern *p3 = &imp_captureset_record(cs, 3)->pattern, *p9 = &imp_captureset_record(cs, 9)->pattern;
        CHECK_INT_EQ(p3->kind, IMP_PAT_GRAY);
        CHECK_INT_EQ(p3->axis, 0);
        CHECK_INT_EQ(p3->bit, 1);
        CHECK_INT_EQ(p3->inverse, 1);
        CHECK_INT_EQ(p9->axis, 1);       /* 2·4 column planes, then rows */
        CHECK_INT_EQ(p9->bit, 0);
        CHECK_INT_EQ(p9->inverse, 1);
        CHECK_INT_EQ(imp_captureset_record(cs, 14)->pattern.kind, IMP_PAT_WHITE);
        CHECK_INT_EQ(imp_captureset_record(cs, 15)->pattern.kind, IMP_PAT_BLACK);
        imp_captureset_close(cs);
}

/* A real capture: imported with a rig.json of the same camera and projector sizes (an
 * approximate calibration is enough here: the test checks the decode and the triangulated
 * board, the bench gives the accuracy figure with a real calibration). */
static void test_real(const char *base) {
        char frames[512], rig[512], out[512];
        const char *shared = getenv("IMPASTO_SHARED_DIR");   /* a worktree's ../shared may not exist */
        snprintf(frames, sizeof frames, "%s/data/procam-graycode/sample_data/capture_0", shared ? shared : IMPASTO_SHARED_DIR);
        struct stat st;
        if (stat(frames, &st) < 0) {
                fprintf(stderr, "SKIP real capture: %s absent\n", frames);
                return;
        }
        snprintf(rig, sizeof rig, "%s/rig-real.json", base);
        write_rig(rig, 1280, 1024, 1024, 768);
        snprintf(out, sizeof out, "%s/real", base);
        struct imp_error err = {};
        CHECK_OK(import(frames, rig, 1024, 768, out, &err));
        struct imp_range_image rg = {};
        struct imp_sl_result *sl = NULL;
        int r = imp_range_from_set(out, &rg, &sl, &err);
        CHECK_MSG(r >= 0, "range: %s", err.msg);
        if (r < 0)
                return;
        /* the board and the wall behind it decode: 888591 x / 873294 y pixels at the time
         * of writing; a wrong pattern order decodes almost nothing consistently */
        CHECK_GE((double) sl->n_valid_xy, 0.5 * rg.width * rg.height);
        CHECK_GE((double) rg.n_valid, 0.3 * rg.width * rg.height);   /* 469374 with this rig */
        /* decoded columns rise left to right (the projector is upright): a mirrored or
         * shuffled bit order breaks this */
        size_t rising = 0, pairs = 0;
        for (int y = 0; y < rg.height; y += 16)
                for (int x = 0; x + 16 < rg.width; x += 16) {
                        size_t a = (size_t) y * rg.width + x, b = a + 16;
                        if ((sl->flags[a] & IMP_SL_VALID_X) && (sl->flags[b] & IMP_SL_VALID_X)) {
                                pairs++;
                                rising += sl->proj_x[b] > sl->proj_x[a];
                        }
                }
        CHECK_INT_GE(pairs, 1000);
        CHECK_GE((double) rising, 0.9 * pairs);
        imp_range_image_done(&rg);
        imp_sl_result_free(sl);
}

int main(void) {
        const char *base = test_tmpdir();
        test_synthetic(base);
        test_real(base);
        return TEST_DONE();
}
