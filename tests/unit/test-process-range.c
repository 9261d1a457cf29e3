/* imp_range_from_set (process-range.h) decodes with coords_only: no light maps are
 * allocated or written, and the range image and the maps it returns are those of a decode
 * with every map, byte for byte. The frames are a Gray-code sequence (OpenCV's order, 8-bit,
 * with inverses: the byte-lane path) rendered on a plane the camera and the projector both
 * see, imported with `impasto import sl`'s library call. */
#include <errno.h>
#include <math.h>
#include <sys/stat.h>
#include "captureset.h"
#include "import-sl.h"
#include "process-range.h"
#include "test.h"

enum { CW = 40, CH = 30, PW = 16, PH = 16 };
#define PLANE_Z_MM 300.0
#define PROJ_X_MM 30.0          /* projector centre, world x: a 5.7° triangulation angle */
#define PROJ_F 400.0
#define PROJ_CX 48.0            /* the camera's view, x ∈ [−6, 6] mm, on projector columns 0–16 */

static struct imp_rig make_rig(void) {
        struct imp_rig rig = { .n_cameras = 1, .has_projector = true };
        snprintf(rig.cameras[0].name, sizeof rig.cameras[0].name, "camera0");
        rig.cameras[0].model = (struct imp_pinhole) { CW, CH, 1000, 1000, CW / 2.0, CH / 2.0,
                                                      .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 } };
        rig.cameras[0].sensor = (struct imp_sensor) { .bits = 8, .gain_e_per_dn = 1, .full_well_e = 256,
                                                      .quantum_scale = 1 };
        snprintf(rig.projector.name, sizeof rig.projector.name, "projector");
        rig.projector.model = (struct imp_pinhole) { PW, PH, PROJ_F, PROJ_F, PROJ_CX, PH / 2.0,
                                                     .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }, .t = { -PROJ_X_MM, 0, 0 } };
        rig.projector.gamma = 1;
        return rig;
}

/* Frame i of the sequence as the camera sees it on the plane z = PLANE_Z_MM: 30 DN dark,
 * 230 DN lit; the camera's left columns see the projector's first columns. */
static struct imp_image *render(const struct imp_pattern *pat) {
        struct imp_image *img = NULL;
        if (imp_image_new(CW, CH, 1, IMP_PIX_U8, &img) < 0)
                exit(2);
        for (int y = 0; y < CH; y++)
                for (int x = 0; x < CW; x++) {
                        double X = (x + 0.5 - CW / 2.0) / 1000 * PLANE_Z_MM, Y = (y + 0.5 - CH / 2.0) / 1000 * PLANE_Z_MM;
                        int px = (int) floor(PROJ_F * (X - PROJ_X_MM) / PLANE_Z_MM + PROJ_CX);
                        int py = (int) floor(PROJ_F * Y / PLANE_Z_MM + PH / 2.0);
                        *imp_image_u8(img, x, y) = (uint8_t) lround(30 + 200 * imp_sl_pattern_value(pat, px, py));
                }
        return img;
}

/* The sequence rendered, written as PNGs in dir, imported into out. */
static int make_set(const char *base, const char *out, struct imp_pattern **ret_seq, struct imp_image ***ret_imgs,
                    int *ret_n) {
        char rig_path[512], frames[512];
        snprintf(rig_path, sizeof rig_path, "%s/rig.json", base);
        snprintf(frames, sizeof frames, "%s/frames", base);
        struct imp_rig rig = make_rig();
        struct imp_error err = {};
        if (imp_rig_save(rig_path, &rig, &err) < 0 || mkdir(frames, 0755) < 0)
                return -EIO;
        int n = 0;
        struct imp_pattern *seq = NULL;
        if (imp_sl_sequence(PW, PH, 0, NULL, 0, &seq, &n) < 0)
                return -ENOMEM;
        struct imp_image **imgs = calloc(n, sizeof *imgs);
        for (int i = 0; i < n; i++) {
                char path[600];
                imgs[i] = render(&seq[i]);
                snprintf(path, sizeof path, "%s/graycode_%02d.png", frames, i);
                if (imp_png_write(path, imgs[i], &err) < 0)
                        return -EIO;
        }
        struct imp_import_sl_options o = { frames, IMP_SL_ORDER_OPENCV_GRAYCODE, PW, PH, rig_path };
        int r = imp_import_sl(&o, out, &err);
        CHECK_MSG(r >= 0, "import: %s", err.msg);
        *ret_seq = seq;
        *ret_imgs = imgs;
        *ret_n = n;
        return r;
}

static bool same_floats(const float *a, const float *b, size_t n) {
        return !memcmp(a, b, n * sizeof *a);
}

int main(void) {
        const char *base = test_tmpdir();
        char out[512];
        snprintf(out, sizeof out, "%s/set", base);
        struct imp_pattern *seq = NULL;
        struct imp_image **imgs = NULL;
        int n = 0;
        CHECK_OK(make_set(base, out, &seq, &imgs, &n));
        if (!imgs)
                return TEST_DONE();
        struct imp_error err = {};
        struct imp_range_image rg = {};
        struct imp_sl_result *sl = NULL;
        int r = imp_range_from_set(out, &rg, &sl, &err);
        CHECK_MSG(r >= 0, "range: %s", err.msg);
        if (r < 0)
                return TEST_DONE();
        const size_t np = (size_t) CW * CH;
        CHECK_MSG(!sl->direct && !sl->global && !sl->modulation, "imp_range_from_set decodes coords_only");
        /* every camera pixel sees a lit projector pixel: all of them decode and triangulate */
        CHECK_INT_EQ(sl->n_valid_xy, np);
        CHECK_INT_EQ(rg.n_valid, np);

        /* the full decode of the same frames with the same parameters, triangulated alike */
        struct imp_rig rig = make_rig();
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_U8);
        p.proj_width = PW;
        p.proj_height = PH;
        struct imp_sl_frames fr = { seq, (const struct imp_image *const *) imgs, n };
        struct imp_sl_result *full = NULL;
        CHECK_OK(imp_sl_decode(&fr, &p, &full, &err));
        struct imp_projector_coords pc;
        struct imp_triangulate_options to;
        struct imp_range_image rf = {};
        imp_projector_coords_from_sl(full, &pc);
        imp_triangulate_options_default(&to);
        CHECK_OK(imp_triangulate(&rig.cameras[0].model, &rig.projector.model, &pc, &to, &rf));
        CHECK(full->direct != NULL);
        CHECK_MSG(same_floats(sl->proj_x, full->proj_x, np) && same_floats(sl->proj_y, full->proj_y, np) &&
                  !memcmp(sl->confidence, full->confidence, np * sizeof *sl->confidence) &&
                  !memcmp(sl->sigma_px, full->sigma_px, np * sizeof *sl->sigma_px) &&
                  !memcmp(sl->flags, full->flags, np * sizeof *sl->flags) && sl->n_valid_x == full->n_valid_x &&
                  sl->n_valid_y == full->n_valid_y && sl->n_shadow == full->n_shadow,
                  "the decoder's maps and counts equal the full decode's");
        CHECK_MSG(rf.width == rg.width && rf.height == rg.height && rf.n_valid == rg.n_valid &&
                  same_floats(rf.xyz, rg.xyz, 3 * np) && same_floats(rf.sigma_mm, rg.sigma_mm, np) &&
                  !memcmp(rf.valid, rg.valid, np) && !memcmp(rf.flags, rg.flags, np * sizeof *rf.flags),
                  "the range image equals the full decode's, byte for byte");
        /* the plane at PLANE_Z_MM within a projector column's depth quantum (σ says how much) */
        size_t t = (size_t) (CH / 2) * CW + CW / 2;
        CHECK_NEAR(rg.xyz[3 * t + 2], PLANE_Z_MM, 4 * rg.sigma_mm[t] + 1);
        imp_range_image_done(&rg);
        imp_range_image_done(&rf);
        imp_sl_result_free(sl);
        imp_sl_result_free(full);
        for (int i = 0; i < n; i++)
                imp_image_free(imgs[i]);
        free(imgs);
        free(seq);
        return TEST_DONE();
}
