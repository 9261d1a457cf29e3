/* The canvas under high impasto (heightfield.c relief_pockets) on synthetic range images:
 * a 12 × 8 mm canvas (0.05 mm per range pixel) in a frame standing FRAME_H proud (its
 * walls unmeasured: a strip of invalid pixels), crossed from frame to frame by three bars
 * of paint 5 mm high (above relief_max_mm) with vertical walls and an undecoded shadow
 * strip beside each, so that the ground is cut into four pockets and the seed fill from
 * the centre reaches one of them (main kept ~20 % of the canvas). Checked: the mask holds
 * at least 85 % of the measured canvas points and the bars' tops, no texel of the frame,
 * and its outline (convex hull) holds the shadow strips as its only holes;
 * with a frame only 0.3 mm proud (a pocket's level, but not the canvas's) likewise; with
 * no bars, or bars only 0.2 mm high beside the same strips of missing range, the mask is
 * what the seed fill alone gives (no relief points). */
#include <math.h>
#include <string.h>
#include "heightfield.h"
#include "numerics.h"
#include "unit/test.h"

#define P       0.05                  /* mm per range pixel */
#define CW      240                   /* canvas pixels */
#define CH      160
#define WALL    4                     /* unmeasured frame-wall pixels on each side */
#define FRAME   40                    /* frame-top pixels on each side */
#define BAR_W   16                    /* paint bar width, pixels */
#define SHADOW  3                     /* undecoded pixels beside each bar */
static double bar_h = 5.0;            /* mm */

static const int bar_x[3] = { 40, 100, 170 };   /* canvas pixel where each bar starts */

static double relief(double x, double y) { return 0.03 * sin(x * 1.3) * cos(y * 0.9); }

/* Canvas pixel ci (−1 off the canvas): 0 ground, 1 bar top, 2 shadow. */
static int paint_at(int ci) {
        for (int b = 0; b < 3; b++) {
                if (ci >= bar_x[b] && ci < bar_x[b] + BAR_W)
                        return 1;
                if (ci >= bar_x[b] - SHADOW && ci < bar_x[b] + BAR_W + SHADOW)
                        return 2;
        }
        return 0;
}

static void make_range(double frame_h, bool bars, struct imp_range_image *r, size_t *ret_canvas_valid) {
        int o = FRAME + WALL, w = CW + 2 * o, h = CH + 2 * o;
        CHECK_OK(imp_range_image_init(r, w, h));
        *ret_canvas_valid = 0;
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        int ci = i - o, cj = j - o;
                        bool on_canvas = ci >= 0 && ci < CW && cj >= 0 && cj < CH;
                        bool wall = !on_canvas && i >= FRAME && i < w - FRAME && j >= FRAME && j < h - FRAME;
                        int paint = on_canvas && bars ? paint_at(ci) : 0;
                        if (wall || paint == 2)
                                continue;
                        double x = ci * P, y = cj * P;
                        double z = on_canvas ? relief(x, y) + (paint == 1 ? bar_h : 0) : frame_h;
                        size_t k = (size_t) j * w + i;
                        r->xyz[3 * k] = (float) x, r->xyz[3 * k + 1] = (float) y, r->xyz[3 * k + 2] = (float) z;
                        r->sigma_mm[k] = 0.005f;
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                        *ret_canvas_valid += on_canvas;
                }
        r->camera_centre_mm[0] = 0.5 * CW * P, r->camera_centre_mm[1] = 0.5 * CH * P, r->camera_centre_mm[2] = 300;
}

static void check_relief(double frame_h, bool bars) {
        struct imp_range_image r = {};
        size_t canvas_valid;
        make_range(frame_h, bars, &r, &canvas_valid);
        struct imp_heightfield hf = {};
        struct imp_error err = {};
        int k = imp_heightfield_extract(&r, NULL, &hf, &err);
        CHECK_MSG(k == 0, "frame %.1f mm: %s", frame_h, err.msg);
        if (k == 0) {
                /* Texels off the canvas (the frame) by their canvas-frame position: the grid's
                 * origin is at the mask's lower corner, the canvas spans [0, 12] × [0, 8] mm. */
                const double *M = hf.canvas_to_world;
                size_t frame = 0, tops = 0;
                for (int j = 0; j < hf.ny; j++)
                        for (int i = 0; i < hf.nx; i++) {
                                size_t t = (size_t) j * hf.nx + i;
                                if (!hf.mask[t])
                                        continue;
                                double W[3];
                                for (int q = 0; q < 3; q++)
                                        W[q] = M[4 * q] * i * hf.pitch_mm + M[4 * q + 1] * j * hf.pitch_mm +
                                               M[4 * q + 2] * hf.height_mm[t] + M[4 * q + 3];
                                frame += W[0] < -0.5 * P || W[0] > (CW - 0.5) * P || W[1] < -0.5 * P ||
                                         W[1] > (CH - 0.5) * P;
                                tops += W[2] > bar_h - 0.5;
                        }
                double kept = (double) hf.n_canvas_points / canvas_valid;
                /* The holes within the outline: the bars' shadow strips (7.5 % of the canvas) and the
                 * mesh edges across them. */
                double holes = 1 - (double) hf.n_mask_texels / (double) hf.n_outline_texels;
                fprintf(stderr, "%zu of %zu texels within the outline have none (%.1f %%)\n",
                        hf.n_outline_texels - hf.n_mask_texels, hf.n_outline_texels, 100 * holes);
                CHECK_GE(hf.n_outline_texels, hf.n_mask_texels);
                if (bar_h >= 1)
                        CHECK(bars ? holes > 0.04 && holes < 0.15 : holes < 0.01);
                fprintf(stderr, "frame %.1f mm, %s: %zu of %zu canvas points kept (%.1f %%), %zu relief points, "
                        "%zu texels on bar tops, %zu on the frame\n", frame_h, bars ? "bars" : "no bars",
                        hf.n_canvas_points, canvas_valid, 100 * kept, hf.n_relief_points, tops, frame);
                CHECK_INT_EQ(frame, 0);
                if (bars && bar_h < 1) {
                        CHECK_INT_EQ(hf.n_relief_points, 0);
                        CHECK_LE(kept, 0.5);
                } else if (bars) {
                        CHECK_GE(kept, 0.85);
                        CHECK_GE(tops, (size_t) (0.8 * 3 * BAR_W * CH * P * P / (hf.pitch_mm * hf.pitch_mm)));
                } else {
                        CHECK_GE(kept, 0.95);
                        CHECK_INT_EQ(hf.n_relief_points, 0);
                }
        }
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

int main(void) {
        check_relief(8.0, true);
        check_relief(0.3, true);
        check_relief(8.0, false);
        /* The same strips of missing range with no paint beside them (dark paint, ambient
         * light): no relief's pockets, the seed fill's canvas as it was. */
        bar_h = 0.2;
        check_relief(8.0, true);
        return TEST_DONE();
}
