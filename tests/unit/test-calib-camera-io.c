/* The C half of the camera-only calibration (pipeline/calib/calib-camera.c), no OpenCV, so it
 * runs under ASan: input images to 8-bit grey (u16, float, colour; flat images refused),
 * the choice of a capture set's calibration frame (white > dome > other lit; never dark),
 * the rig.json output (with and without a base rig) and the JSON of a result. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib-camera.h"
#include "captureset.h"
#include "rig.h"
#include "test.h"

#define W 40
#define H 30
#define BLACK_DN 64.0

static void to_u8(void) {
        struct imp_error err = {};
        struct imp_image *u16 = NULL, *out = NULL;
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U16, &u16));
        /* a ramp of 1200 values over the black level: p99 ≈ 64 + 0.99 · 1199 */
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        *imp_image_u16(u16, x, y) = (uint16_t) (BLACK_DN + y * W + x);
        CHECK_OK(imp_calib_image_to_u8(u16, BLACK_DN, &out, &err));
        if (out) {
                CHECK_INT_EQ(out->type, IMP_PIX_U8);
                CHECK_INT_EQ(out->channels, 1);
                CHECK_INT_EQ(*imp_image_u8(out, 0, 0), 0);                       /* black → 0 */
                double p99 = 0.99 * (W * H - 1);
                CHECK_NEAR(*imp_image_u8(out, W / 2, H / 2), lround((H / 2 * W + W / 2) * IMP_CALIB_U8_WHITE / p99), 2);
                CHECK_NEAR(*imp_image_u8(out, W - 1, H - 1), (W * H - 1) * IMP_CALIB_U8_WHITE / p99, 2);
        }
        imp_image_free(out);
        out = NULL;
        /* flat: refused, untouched */
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        *imp_image_u16(u16, x, y) = (uint16_t) BLACK_DN;
        CHECK_ERR(imp_calib_image_to_u8(u16, BLACK_DN, &out, &err), -EDOM);
        CHECK_STR_CONTAINS(err.msg, "dark or flat");
        CHECK(out == NULL);
        imp_image_free(u16);

        /* colour float: Rec. 709 luma; a pure-green pixel gives 0.7152 of the white one */
        struct imp_image *rgb = NULL;
        CHECK_OK(imp_image_new(W, H, 3, IMP_PIX_F32, &rgb));
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        for (int c = 0; c < 3; c++)
                                imp_image_f32(rgb, x, y)[c] = x < W / 2 ? 1.0f : (c == 1 ? 1.0f : 0.0f);
        CHECK_OK(imp_calib_image_to_u8(rgb, 0, &out, &err));
        if (out) {
                CHECK_INT_EQ(*imp_image_u8(out, 0, 0), lround(IMP_CALIB_U8_WHITE));
                CHECK_NEAR(*imp_image_u8(out, W - 1, 0), 0.7152 * IMP_CALIB_U8_WHITE, 1);
        }
        imp_image_free(out);
        imp_image_free(rgb);
}

static struct imp_rig two_cameras(void) {
        struct imp_rig rig = { .n_cameras = 2 };
        for (int c = 0; c < 2; c++) {
                struct imp_rig_camera *cam = &rig.cameras[c];
                snprintf(cam->name, sizeof cam->name, "cam%c", 'A' + c);
                cam->model = (struct imp_pinhole) { .width = W, .height = H, .fx = 100 + c, .fy = 100 + c,
                                                    .cx = W / 2.0, .cy = H / 2.0, .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 },
                                                    .t = { 1, 2, 300 + c } };
                cam->sensor = (struct imp_sensor) { .bits = 12, .black_level_dn = BLACK_DN, .gain_e_per_dn = 2.5,
                                                    .full_well_e = 10000, .quantum_scale = 1 };
        }
        return rig;
}

/* Adds a frame of camera `cam` whose pixels are level + x (so its content tells which). */
static void add(struct imp_captureset *cs, long long seq, const char *cam, const char *step, int kind, int level) {
        struct imp_frame_record r = { .seq = seq, .light = -1, .exposure_us = 1000 };
        snprintf(r.step, sizeof r.step, "%s", step);
        snprintf(r.camera, sizeof r.camera, "%s", cam);
        r.pattern.kind = kind;
        struct imp_image *im = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U16, &im));
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        *imp_image_u16(im, x, y) = (uint16_t) (level + 10 * x);
        CHECK_OK(imp_captureset_add_frame(cs, &r, im, &err));
        imp_image_free(im);
}

static void set_frame(void) {
        char dir[512];
        snprintf(dir, sizeof dir, "%s/set", test_tmpdir());
        struct imp_rig rig = two_cameras();
        struct imp_captureset *cs = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_captureset_create(dir, &rig, NULL, &cs, &err));
        if (!cs)
                return;
        add(cs, 0, "camA", "dark", IMP_PAT_NONE, 64);
        struct imp_image *u8 = NULL;
        long rec = -1;
        /* only dark frames: nothing to calibrate from */
        imp_captureset_close(cs);
        CHECK_ERR(imp_calib_camera_set_frame(dir, NULL, &u8, &rec, NULL, &err), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, "no lit frame of camera camA");
        CHECK_OK(imp_captureset_open(dir, &cs, &err));
        add(cs, 1, "camA", "structured-light", IMP_PAT_BLACK, 70);
        add(cs, 2, "camA", "dome", IMP_PAT_NONE, 500);
        add(cs, 3, "camB", "structured-light", IMP_PAT_WHITE, 900);
        imp_captureset_close(cs);
        /* camA: the dome frame (the white one is camB's) */
        struct imp_rig got = {};
        CHECK_OK(imp_calib_camera_set_frame(dir, "camA", &u8, &rec, &got, &err));
        CHECK_INT_EQ(rec, 2);
        CHECK_INT_EQ(got.n_cameras, 2);
        imp_rig_free(&got);
        imp_image_free(u8);
        u8 = NULL;
        /* camB: its white frame */
        CHECK_OK(imp_calib_camera_set_frame(dir, "camB", &u8, &rec, NULL, &err));
        CHECK_INT_EQ(rec, 3);
        imp_image_free(u8);
        u8 = NULL;
        /* a white frame of camA beats its dome frame */
        CHECK_OK(imp_captureset_open(dir, &cs, &err));
        add(cs, 4, "camA", "structured-light", IMP_PAT_WHITE, 800);
        imp_captureset_close(cs);
        CHECK_OK(imp_calib_camera_set_frame(dir, NULL, &u8, &rec, NULL, &err));
        CHECK_INT_EQ(rec, 4);
        imp_image_free(u8);
        u8 = NULL;
        CHECK_ERR(imp_calib_camera_set_frame(dir, "camZ", &u8, &rec, NULL, &err), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, "no camera \"camZ\"");
        CHECK_ERR(imp_calib_camera_set_frame("/nonexistent/set", NULL, &u8, &rec, NULL, &err), -ENOENT);
        CHECK(u8 == NULL);
        imp_rig_free(&rig);
}

static void result_out(void) {
        static struct imp_calib_camera res;
        res.camera = (struct imp_calib_intrinsics) { .width = W, .height = H, .fx = 123, .fy = 124, .cx = 19,
                                                     .cy = 14, .dist = { -0.1, 0.05, 0.001, -0.001, 0 } };
        res.n_views = 2;
        res.n_found = res.n_used = 1;
        snprintf(res.views[0].name, sizeof res.views[0].name, "a.png");
        res.views[0].found = res.views[0].used = true;
        res.views[0].rms_px = 0.05;
        snprintf(res.views[1].name, sizeof res.views[1].name, "b.png");
        snprintf(res.views[1].why, sizeof res.views[1].why, "no chessboard");
        imp_calib_camera_warn(&res, "camera: only %d view", 1);
        for (int i = 0; i < IMP_CALIB_MAX_WARNINGS + 3; i++)
                imp_calib_camera_warn(&res, "filler %d", i);
        CHECK_INT_EQ(res.n_warnings, IMP_CALIB_MAX_WARNINGS);
        CHECK_STR_EQ(res.warnings[IMP_CALIB_MAX_WARNINGS - 1], "more warnings were dropped");

        json_t *j = imp_calib_camera_to_json(&res);
        CHECK(j != NULL);
        json_t *v = json_object_get(j, "views");
        CHECK_INT_EQ(json_array_size(v), 2);
        CHECK(json_is_false(json_object_get(json_array_get(v, 1), "found")));
        CHECK_STR_EQ(json_string_value(json_object_get(json_array_get(v, 1), "skipped_because")), "no chessboard");
        CHECK_NEAR(json_number_value(json_object_get(json_object_get(j, "camera"), "fx")), 123, 0);
        CHECK_STR_EQ(json_string_value(json_array_get(json_object_get(j, "warnings"), 0)), "camera: only 1 view");
        json_decref(j);
        char *text = NULL;
        size_t len = 0;
        FILE *f = open_memstream(&text, &len);
        imp_calib_camera_print(&res, f);
        fclose(f);
        CHECK_STR_CONTAINS(text, "b.png: not used: no chessboard");
        free(text);

        /* rig.json: the named camera of the base gets the intrinsics, the rest is kept */
        struct imp_rig base = two_cameras(), out = {};
        struct imp_error err = {};
        CHECK_OK(imp_calib_camera_rig(&res, "camB", &base, &out, &err));
        CHECK_NEAR(out.cameras[1].model.fx, 123, 0);
        CHECK_NEAR(out.cameras[1].model.k1, -0.1, 0);
        CHECK_NEAR(out.cameras[1].model.t[2], 301, 0);          /* pose kept */
        CHECK_NEAR(out.cameras[0].model.fx, 100, 0);            /* other camera untouched */
        CHECK_NEAR(out.cameras[1].sensor.black_level_dn, BLACK_DN, 0);
        imp_rig_free(&out);
        CHECK_ERR(imp_calib_camera_rig(&res, "camZ", &base, &out, &err), -ENOENT);
        /* no base: one camera at the origin */
        CHECK_OK(imp_calib_camera_rig(&res, NULL, NULL, &out, &err));
        CHECK_INT_EQ(out.n_cameras, 1);
        CHECK_STR_EQ(out.cameras[0].name, "camera0");
        CHECK_NEAR(out.cameras[0].model.R[8], 1, 0);
        CHECK_NEAR(out.cameras[0].model.cy, 14, 0);
        imp_rig_free(&out);
        imp_rig_free(&base);
}

int main(void) {
        to_u8();
        set_frame();
        result_out();
        return TEST_DONE();
}
