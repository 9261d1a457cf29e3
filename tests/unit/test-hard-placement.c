/* Canvas placement under a deep box frame, on a synthetic range image (no rendering): a
 * 12 × 8 mm canvas with gentle relief at z = 0, vertical walls of height H sampled by 20
 * range pixels each, and a 4 mm frame top at z = H, camera 500 mm above. With H = 20 mm
 * the PCA of every point (the seed's first plane) has its smallest axis along world x or y
 * — the failure the robust plane fixes. Checked: the canvas normal within 1° of +z, the
 * mask covers ≥ 90 % of the canvas's texels and holds no frame or wall (no height above
 * 0.5 mm); the same range image rotated 60° about y is refused (-ENODATA, the message
 * names the tilt) and, rotated 25°, is placed right. */
#include <math.h>
#include <string.h>
#include "heightfield.h"
#include "unit/test.h"

#define P        0.1                  /* mm per range pixel on the canvas */
#define CW       120                  /* canvas pixels */
#define CH       80
#define WALL     20                   /* wall pixels on each side */
#define FRAME    40                   /* frame-top pixels on each side */

static double relief(double x, double y) { return 0.05 * sin(x * 1.3) * cos(y * 0.9); }

/* Pixel (i, j) → point: along each axis the pixel index maps to a position and a "level"
 * 0 (canvas), 0..1 (wall) or 1 (frame top). */
static void axis_pos(int i, int n_canvas, double *ret_pos, double *ret_level) {
        int a = FRAME + WALL, b = FRAME + WALL + n_canvas;
        if (i < FRAME) {
                *ret_pos = -(FRAME - i) * P, *ret_level = 1;
        } else if (i < a) {
                *ret_pos = 0, *ret_level = 1 - (double) (i - FRAME) / WALL;
        } else if (i < b) {
                *ret_pos = (i - a) * P, *ret_level = 0;
        } else if (i < b + WALL) {
                *ret_pos = (n_canvas - 1) * P, *ret_level = (double) (i - b + 1) / WALL;
        } else {
                *ret_pos = (n_canvas - 1) * P + (i - b - WALL + 1) * P, *ret_level = 1;
        }
}

static void make_range(double H, double tilt_deg, struct imp_range_image *r) {
        int w = CW + 2 * (WALL + FRAME), h = CH + 2 * (WALL + FRAME);
        CHECK_OK(imp_range_image_init(r, w, h));
        double a = tilt_deg * M_PI / 180, c = cos(a), s = sin(a);
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double x, y, lx, ly;
                        axis_pos(i, CW, &x, &lx);
                        axis_pos(j, CH, &y, &ly);
                        double z = fmax(lx, ly) * H + (lx == 0 && ly == 0 ? relief(x, y) : 0);
                        size_t k = (size_t) j * w + i;
                        r->xyz[3 * k] = (float) (c * x + s * z);   /* rotation about y */
                        r->xyz[3 * k + 1] = (float) y;
                        r->xyz[3 * k + 2] = (float) (-s * x + c * z);
                        r->sigma_mm[k] = 0.005f;
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                }
        double C[3] = { 0.5 * CW * P, 0.5 * CH * P, 500 };
        r->camera_centre_mm[0] = c * C[0] + s * C[2];
        r->camera_centre_mm[1] = C[1];
        r->camera_centre_mm[2] = -s * C[0] + c * C[2];
}

static void check_placed(double tilt_deg) {
        struct imp_range_image r = {};
        make_range(20, tilt_deg, &r);
        struct imp_heightfield hf = {};
        struct imp_error err = {};
        int k = imp_heightfield_extract(&r, NULL, &hf, &err);
        CHECK_MSG(k == 0, "tilt %.0f°: %s", tilt_deg, err.msg);
        if (k == 0) {
                double a = tilt_deg * M_PI / 180, ez[3] = { hf.canvas_to_world[2], hf.canvas_to_world[6],
                                                            hf.canvas_to_world[10] };
                double want[3] = { sin(a), 0, cos(a) };
                double ang = acos(fmin(1, ez[0] * want[0] + ez[1] * want[1] + ez[2] * want[2])) * 180 / M_PI;
                size_t high = 0;
                for (size_t t = 0; t < (size_t) hf.nx * hf.ny; t++)
                        high += hf.mask[t] && fabs(hf.height_mm[t]) > 0.5;
                double cover = (double) hf.n_mask_texels * hf.pitch_mm * hf.pitch_mm / ((CW - 1) * (CH - 1) * P * P);
                fprintf(stderr, "tilt %.0f°: canvas normal %.3f° off, %zu mask texels (%.1f %% of the canvas), "
                        "%zu above 0.5 mm, tilt reported %.2f°\n", tilt_deg, ang, hf.n_mask_texels, 100 * cover,
                        high, hf.plane_tilt_deg);
                CHECK_LE(ang, 1.0);
                CHECK_GE(cover, 0.9);
                CHECK_INT_EQ(high, 0);
        }
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

int main(void) {
        check_placed(0);
        check_placed(25);
        /* A canvas 60° off the rig's pose is not a plausible placement: refused with why. */
        struct imp_range_image r = {};
        make_range(20, 60, &r);
        struct imp_heightfield keep = { .nx = 7 };
        struct imp_error err = {};
        CHECK_ERR(imp_heightfield_extract(&r, NULL, &keep, &err), -ENODATA);
        CHECK_MSG(strstr(err.msg, "off the rig's canvas normal") != NULL, "message: %s", err.msg);
        if (keep.nx != 7)
                fprintf(stderr, "tilt 60°: placed with tilt %.1f°, %zu texels, plane rms %.3f mm, flags %#x\n",
                        keep.plane_tilt_deg, keep.n_mask_texels, keep.plane_rms_mm, keep.flags);
        CHECK_INT_EQ(keep.nx, 7);
        fprintf(stderr, "tilt 60°: %s\n", err.msg);
        imp_range_image_done(&r);
        return TEST_DONE();
}
