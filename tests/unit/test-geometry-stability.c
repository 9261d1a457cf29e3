/* Hard numerical cases of the geometry pipeline: a perfectly flat canvas, a canvas tilted
 * by 30°, a relief that is one cliff, a canvas 2000×20 samples, a single line of points,
 * pixels saturated / dark in every exposure, garbage projector coordinates. Each must give
 * finite values or an explicit invalid flag / error, never NaN or Inf in an output array. */
#include <math.h>
#include <string.h>
#include "boxes.h"
#include "hdr.h"
#include "heightfield.h"
#include "triangulate.h"
#include "unit/test.h"

static size_t count_nonfinite_f(const float *v, size_t n) {
        size_t k = 0;
        for (size_t i = 0; i < n; i++)
                k += !isfinite(v[i]);
        return k;
}

/* Grid of w × h points at pitch p, z = f(x) (x in mm from the left edge), rotated about
 * the world y axis by tilt_deg; camera 800 mm above along the rotated normal. */
static void make_range(int w, int h, double p, double tilt_deg, double (*f)(double, double),
                       struct imp_range_image *r) {
        CHECK_OK(imp_range_image_init(r, w, h));
        double a = tilt_deg * M_PI / 180, c = cos(a), s = sin(a);
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double x = i * p, y = j * p, z = f ? f(x, y) : 0;
                        size_t k = (size_t) j * w + i;
                        r->xyz[3 * k] = (float) (c * x + s * z);
                        r->xyz[3 * k + 1] = (float) y;
                        r->xyz[3 * k + 2] = (float) (-s * x + c * z);
                        r->sigma_mm[k] = 0.005f;
                        r->valid[k] = IMP_RANGE_BOTH;
                }
        r->n_valid = (size_t) w * h;
        double cx = 0.5 * (w - 1) * p, cy = 0.5 * (h - 1) * p;
        r->camera_centre_mm[0] = c * cx + s * 800;
        r->camera_centre_mm[1] = cy;
        r->camera_centre_mm[2] = -s * cx + c * 800;
}

static void check_hf_finite(const char *what, const struct imp_heightfield *hf) {
        size_t n = (size_t) hf->nx * hf->ny, bad = count_nonfinite_f(hf->height_mm, n) + count_nonfinite_f(hf->nx_, n) +
                                                 count_nonfinite_f(hf->ny_, n) + count_nonfinite_f(hf->sigma_mm, n);
        for (int k = 0; k < 16; k++)
                bad += !isfinite(hf->canvas_to_world[k]);
        bad += !isfinite(hf->plane_rms_mm) + !isfinite(hf->footprint_mm) + !isfinite(hf->pitch_mm);
        fprintf(stderr, "%s: grid %dx%d, %zu mask texels, plane rms %.3g mm, flags %#x, non-finite %zu\n", what,
                hf->nx, hf->ny, hf->n_mask_texels, hf->plane_rms_mm, hf->flags, bad);
        CHECK_INT_EQ(bad, 0);
        for (size_t i = 0; i < n; i++)
                if (hf->mask[i]) {
                        CHECK_LE(hf->nx_[i] * hf->nx_[i] + hf->ny_[i] * hf->ny_[i], 1.0 + 1e-6);
                        break;
                }
        struct imp_boxes b = {};
        int r = imp_boxes_classify(hf, NULL, &b);
        CHECK(r == 0 || r == -ENODATA);
        if (r == 0) {
                CHECK_FINITE(b.H_mm);
                CHECK_FINITE(b.h_ref_mm);
                CHECK_FINITE(b.delta0_mm);
                for (size_t k = 0; k < b.n_boxes; k++)
                        CHECK_FINITE(b.boxes[k].hmax_mm);
        }
        imp_boxes_done(&b);
}

static double cliff(double x, double y) { return x > 12.0 ? 2.0 : 0.0; }
static double gentle(double x, double y) { return 0.05 * sin(x / 3) * cos(y / 2); }

static void test_flat(void) {
        struct imp_range_image r = {};
        make_range(200, 150, 0.2, 0, NULL, &r);
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, NULL, &hf));
        check_hf_finite("flat", &hf);
        float mx = 0;
        for (size_t i = 0; i < (size_t) hf.nx * hf.ny; i++)
                mx = fmaxf(mx, fabsf(hf.height_mm[i]));
        CHECK_LE(mx, 1e-4);
        CHECK_NEAR(hf.canvas_to_world[10], 1.0, 1e-9);   /* ez = world z */
        struct imp_boxes b = {};
        CHECK_OK(imp_boxes_classify(&hf, NULL, &b));
        CHECK_INT_EQ(b.n_boxes, 0);   /* H = 0: no significant relief, no boxes */
        imp_boxes_done(&b);
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

static void test_tilted(void) {
        struct imp_range_image r = {};
        make_range(200, 150, 0.2, 30, gentle, &r);
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, NULL, &hf));
        check_hf_finite("tilted 30°", &hf);
        CHECK_NEAR(hf.canvas_to_world[10], cos(30 * M_PI / 180), 1e-3);
        CHECK_NEAR(hf.pitch_mm, 0.2, 0.01);
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

static void test_cliff(void) {
        struct imp_range_image r = {};
        make_range(200, 150, 0.2, 0, cliff, &r);
        struct imp_heightfield hf = {};
        int k = imp_heightfield_from_range(&r, NULL, &hf);
        CHECK(k == 0 || k == -ENODATA);
        if (k == 0)
                check_hf_finite("one cliff", &hf);
        imp_heightfield_done(&hf);
        /* Without extraction the cliff stays in; the mesh edge across it is longer than
         * max_edge_factor × footprint, so the wall is not rasterised either way. */
        struct imp_heightfield_options o;
        imp_heightfield_options_default(&o);
        o.skip_extraction = true;
        CHECK_OK(imp_heightfield_from_range(&r, &o, &hf));
        check_hf_finite("one cliff, no extraction", &hf);
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

static void test_elongated(void) {
        struct imp_range_image r = {};
        make_range(2000, 20, 0.2, 0, gentle, &r);
        struct imp_heightfield_options o;
        imp_heightfield_options_default(&o);
        o.erode_px = 2;
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, &o, &hf));
        check_hf_finite("2000x20", &hf);
        CHECK_GE(hf.nx, 1900);
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);

        /* A single line of points: no plane, no triangles → explicit -ENODATA. */
        make_range(2000, 1, 0.2, 0, NULL, &r);
        struct imp_heightfield keep = { .nx = 3 };
        o.skip_extraction = true;
        CHECK_ERR(imp_heightfield_from_range(&r, &o, &keep), -ENODATA);
        CHECK_INT_EQ(keep.nx, 3);
        imp_range_image_done(&r);
}

static void test_hdr_extremes(void) {
        const struct imp_sensor s = { .bits = 12, .black_level_dn = 64, .gain_e_per_dn = 2, .read_noise_e = 3,
                                      .full_well_e = 10000, .quantum_scale = 1e6 };
        struct imp_image *f[3];
        struct imp_hdr_exposure st[3];
        for (int k = 0; k < 3; k++) {
                CHECK_OK(imp_image_new(16, 8, 3, IMP_PIX_U16, &f[k]));
                st[k] = (struct imp_hdr_exposure) { .frame = f[k], .exposure_us = 100.0 * (1 << (2 * k)) };
                for (int y = 0; y < 8; y++)
                        for (int x = 0; x < 16; x++)
                                for (int c = 0; c < 3; c++)   /* rows 0–3 clipped, rows 4–7 at black */
                                        imp_image_u16(f[k], x, y)[c] = y < 4 ? 4095 : (x & 1 ? 64 : 0);
        }
        struct imp_hdr_result res = {};
        CHECK_OK(imp_hdr_merge(st, 3, &s, NULL, &res));
        size_t n = 16 * 8 * 3;
        CHECK_INT_EQ(count_nonfinite_f(res.value->data, n) + count_nonfinite_f(res.variance->data, n), 0);
        for (int y = 0; y < 8; y++)
                for (int x = 0; x < 16; x++)
                        for (int c = 0; c < 3; c++) {
                                uint8_t fl = imp_image_u8(res.flags, x, y)[c];
                                float v = imp_image_f32(res.value, x, y)[c];
                                CHECK_INT_EQ(fl, y < 4 ? IMP_HDR_SATURATED : IMP_HDR_DARK);
                                if (y < 4)
                                        CHECK_GE(v, 30.0);   /* lower bound from the 100 µs exposure */
                                else
                                        CHECK_NEAR(v, 0, 0);
                        }
        CHECK_INT_EQ(res.n_saturated, 16 * 4 * 3);
        CHECK_INT_EQ(res.n_dark, 16 * 4 * 3);
        imp_hdr_result_done(&res);
        /* Zero read noise and a degenerate sensor: still finite. */
        struct imp_sensor s0 = s;
        s0.read_noise_e = 0;
        CHECK_OK(imp_hdr_merge(st, 3, &s0, NULL, &res));
        CHECK_INT_EQ(count_nonfinite_f(res.value->data, n) + count_nonfinite_f(res.variance->data, n), 0);
        imp_hdr_result_done(&res);
        for (int k = 0; k < 3; k++)
                imp_image_free(f[k]);
}

static void test_triangulate_garbage(void) {
        struct imp_pinhole cam = { .width = 64, .height = 48, .fx = 200, .fy = 200, .cx = 31.5, .cy = 23.5 };
        struct imp_pinhole proj = { .width = 256, .height = 256, .fx = 500, .fy = 500, .cx = 127.5, .cy = 127.5, .k1 = 0.3 };
        double eye_c[3] = { 0, 0, 600 }, eye_p[3] = { 200, 0, 560 }, tgt[3] = { 0, 0, 0 }, right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&cam, eye_c, tgt, right);
        imp_pinhole_look_at(&proj, eye_p, tgt, right);
        static float px[64 * 48], py[64 * 48];
        const float garbage[] = { NAN, INFINITY, -INFINITY, 1e30f, -1e30f, 0, -1, 1e6f, 127.5f };
        for (size_t i = 0; i < 64 * 48; i++) {
                px[i] = garbage[i % ARRAY_SIZE(garbage)];
                py[i] = garbage[(i / 3) % ARRAY_SIZE(garbage)];
        }
        struct imp_projector_coords pc = { .width = 64, .height = 48, .proj_x = px, .proj_y = py };
        struct imp_range_image r = {};
        CHECK_OK(imp_triangulate(&cam, &proj, &pc, NULL, &r));
        size_t n = 64 * 48;
        CHECK_INT_EQ(count_nonfinite_f(r.xyz, 3 * n) + count_nonfinite_f(r.sigma_mm, n), 0);
        fprintf(stderr, "garbage projector coordinates: %zu of %zu valid, all finite\n", r.n_valid, n);
        imp_range_image_done(&r);
}

int main(void) {
        test_flat();
        test_tilted();
        test_cliff();
        test_elongated();
        test_hdr_extremes();
        test_triangulate_garbage();
        return TEST_DONE();
}
