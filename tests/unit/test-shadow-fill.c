/* Projector-shadow fill (heightfield.h shadow_fill_px, fuse.h mask value 2): a
 * synthetic range image of a painted canvas inside a raised frame, with the canvas strip
 * along the right frame wall undecoded (projector shadow). Checks that the fill covers the
 * strip and nothing of the frame, that it fills nothing when the frame has a gap or there
 * is no frame, that holes inside the canvas stay holes, that imp_fuse_heights integrates
 * the strip's heights from the normals (position weight 0 on it), and that
 * imp_heightfield_drop_filled removes what it is told and what is cut off. */
#include <math.h>
#include <string.h>
#include "fuse.h"
#include "heightfield.h"
#include "unit/test.h"

#define PITCH 0.1                     /* range grid spacing, mm */
#define FRAME_W 3.0
#define FRAME_H 4.0
#define STRIP_MM 1.5                  /* projector shadow along the right wall */
#define FILL_PX 30
static const double CMIN[2] = { -15, -10 }, CMAX[2] = { 15, 10 };

static double relief(double x, double y) {
        double r2 = (x - 5) * (x - 5) + (y - 2) * (y - 2);
        return 0.15 * sin(2 * M_PI * x / 6) * cos(2 * M_PI * y / 5) + 0.4 * exp(-r2 / 8);
}
static void relief_normal(double x, double y, double n[3]) {
        const double e = 1e-5;
        double gx = (relief(x + e, y) - relief(x - e, y)) / (2 * e), gy = (relief(x, y + e) - relief(x, y - e)) / (2 * e);
        double l = sqrt(gx * gx + gy * gy + 1);
        n[0] = -gx / l, n[1] = -gy / l, n[2] = 1 / l;
}
static bool in_canvas(double x, double y) { return x >= CMIN[0] && x <= CMAX[0] && y >= CMIN[1] && y <= CMAX[1]; }
static bool in_strip(double x, double y) { return in_canvas(x, y) && x > CMAX[0] - STRIP_MM; }

enum scene { FRAMED, FRAME_GAP, NO_FRAME };

/* Orthographic range image; invalid: the strip, a hole inside the canvas, and (FRAME_GAP)
 * a 2 mm gap through the right frame, (NO_FRAME) everything but the canvas. */
static void make_range(enum scene sc, struct imp_range_image *r) {
        int w = (int) ((CMAX[0] - CMIN[0] + 2 * FRAME_W) / PITCH) + 1;
        int h = (int) ((CMAX[1] - CMIN[1] + 2 * FRAME_W) / PITCH) + 1;
        CHECK_OK(imp_range_image_init(r, w, h));
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double x = CMIN[0] - FRAME_W + i * PITCH, y = CMIN[1] - FRAME_W + j * PITCH;
                        size_t k = (size_t) j * w + i;
                        bool canvas = in_canvas(x, y);
                        if (in_strip(x, y) || hypot(x + 6, y + 4) < 1.0 ||
                            (sc == FRAME_GAP && !canvas && x > CMAX[0] && fabs(y) < 1.0) || (sc == NO_FRAME && !canvas))
                                continue;
                        r->xyz[3 * k] = (float) x, r->xyz[3 * k + 1] = (float) y;
                        r->xyz[3 * k + 2] = (float) (canvas ? relief(x, y) : FRAME_H);
                        r->sigma_mm[k] = 0.005f;
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                }
        r->camera_centre_mm[2] = 500;
}

static void texel_world(const struct imp_heightfield *hf, int i, int j, double h, double W[3]) {
        const double *M = hf->canvas_to_world;
        for (int q = 0; q < 3; q++)
                W[q] = M[4 * q] * i * hf->pitch_mm + M[4 * q + 1] * j * hf->pitch_mm + M[4 * q + 2] * h + M[4 * q + 3];
}

struct counts { long strip_filled, strip_texels, off_canvas, hole, filled, measured; };

static struct counts count(const struct imp_heightfield *hf) {
        struct counts c = {};
        for (int j = 0; j < hf->ny; j++)
                for (int i = 0; i < hf->nx; i++) {
                        size_t t = (size_t) j * hf->nx + i;
                        double W[3];
                        texel_world(hf, i, j, 0, W);
                        bool strip = in_strip(W[0], W[1]) && W[0] < CMAX[0] - 0.5 * PITCH;
                        c.strip_texels += strip;
                        c.strip_filled += strip && hf->mask[t] == IMP_HF_MASK_FILLED;
                        /* beyond half a texel off the canvas = on the frame */
                        c.off_canvas += hf->mask[t] && (W[0] < CMIN[0] - 0.5 * PITCH || W[0] > CMAX[0] + 0.5 * PITCH ||
                                                       W[1] < CMIN[1] - 0.5 * PITCH || W[1] > CMAX[1] + 0.5 * PITCH);
                        c.hole += hf->mask[t] && hypot(W[0] + 6, W[1] + 4) < 0.8;
                        c.filled += hf->mask[t] == IMP_HF_MASK_FILLED;
                        c.measured += hf->mask[t] == IMP_HF_MASK_MEASURED;
                        CHECK(hf->mask[t] <= IMP_HF_MASK_FILLED);
                }
        return c;
}

/* RMS of world z − relief over the filled strip texels. */
static double strip_rmse(const struct imp_heightfield *hf) {
        double ss = 0;
        long n = 0;
        for (int j = 0; j < hf->ny; j++)
                for (int i = 0; i < hf->nx; i++) {
                        size_t t = (size_t) j * hf->nx + i;
                        if (hf->mask[t] != IMP_HF_MASK_FILLED)
                                continue;
                        double W[3];
                        texel_world(hf, i, j, hf->height_mm[t], W);
                        ss += (W[2] - relief(W[0], W[1])) * (W[2] - relief(W[0], W[1]));
                        n++;
                }
        return n ? sqrt(ss / n) : INFINITY;
}

static void test_framed(void) {
        struct imp_range_image r = {};
        make_range(FRAMED, &r);
        struct imp_heightfield_options o;
        imp_heightfield_options_default(&o);
        struct imp_heightfield off = {}, on = {};
        CHECK_OK(imp_heightfield_from_range(&r, &o, &off));
        o.shadow_fill_px = FILL_PX;
        CHECK_OK(imp_heightfield_from_range(&r, &o, &on));
        struct counts a = count(&off), b = count(&on);
        fprintf(stderr, "off: %ld measured, %ld filled; on: %ld measured, %ld filled, strip %ld/%ld, "
                "off canvas %ld, hole %ld; frame threshold %.3f mm\n", a.measured, a.filled, b.measured, b.filled,
                b.strip_filled, b.strip_texels, b.off_canvas, b.hole, on.frame_height_mm);
        CHECK_INT_EQ(a.filled, 0);
        CHECK_INT_EQ(a.strip_filled, 0);
        CHECK_INT_EQ(b.measured, a.measured);          /* the fill only adds */
        CHECK_INT_EQ(on.n_filled_texels, b.filled);
        CHECK_INT_EQ(on.n_mask_texels, b.filled + b.measured);
        CHECK_INT_GE(b.strip_texels, 14 * 195);   /* ~14.5 columns × ~200 rows, by the grid phase */
        CHECK_GE((double) b.strip_filled, 0.97 * b.strip_texels);   /* the strip is covered... */
        CHECK_INT_EQ(b.off_canvas, 0);                              /* ...and nothing of the frame */
        CHECK_INT_EQ(b.hole, 0);                                    /* inner holes stay holes */
        CHECK_LE((double) b.filled, b.strip_texels + 4.0 * (on.nx + on.ny));   /* strip + the 2-texel rim */
        CHECK(on.frame_height_mm > 0.5 && on.frame_height_mm < FRAME_H);
        /* Filled texels: larger σ than the measured ones, growing away from the edge. */
        double smax_meas = 0, smin_fill = INFINITY;
        for (size_t t = 0; t < (size_t) on.nx * on.ny; t++) {
                if (on.mask[t] == IMP_HF_MASK_MEASURED)
                        smax_meas = fmax(smax_meas, on.sigma_mm[t]);
                if (on.mask[t] == IMP_HF_MASK_FILLED && on.nx_[t] == 0)
                        smin_fill = fmin(smin_fill, on.sigma_mm[t]);
        }
        CHECK(smin_fill >= smax_meas);

        /* Fusion with the true normals: the strip's heights come from the normals. */
        size_t n = (size_t) on.nx * on.ny;
        float *nrm = malloc(n * 3 * sizeof *nrm);
        CHECK(nrm != NULL);
        if (!nrm)
                return;
        const double *M = on.canvas_to_world;
        for (int j = 0; j < on.ny; j++)
                for (int i = 0; i < on.nx; i++) {
                        size_t t = (size_t) j * on.nx + i;
                        double W[3], nw[3];
                        texel_world(&on, i, j, on.height_mm[t], W);
                        relief_normal(W[0], W[1], nw);
                        for (int q = 0; q < 3; q++)
                                nrm[3 * t + q] = (float) (nw[0] * M[q] + nw[1] * M[4 + q] + nw[2] * M[8 + q]);
                }
        double before = strip_rmse(&on);
        struct imp_fuse_params fp;
        struct imp_fuse_stats st;
        imp_fuse_params_default(&fp);
        CHECK_OK(imp_fuse_heights(on.nx, on.ny, on.pitch_mm, on.height_mm, nrm, on.sigma_mm, on.mask, &fp, NULL, &st));
        double after = strip_rmse(&on);
        fprintf(stderr, "strip height rmse: flat extension %.1f µm, fused %.1f µm (%d iterations)\n",
                before * 1000, after * 1000, st.iterations);
        CHECK_GE(before, 0.02);
        CHECK_LE(after, 0.004);
        CHECK_LE(after, 0.1 * before);
        /* A position term on the strip (mask value 1) would pin it to the flat start. */
        float *h1 = malloc(n * sizeof *h1);
        uint8_t *m1 = malloc(n);
        CHECK(h1 && m1);
        if (h1 && m1) {
                struct imp_heightfield tmp = on;
                memcpy(m1, on.mask, n);
                for (size_t t = 0; t < n; t++)
                        m1[t] = m1[t] != 0;
                CHECK_OK(imp_heightfield_from_range(&r, &o, &tmp));
                memcpy(h1, tmp.height_mm, n * sizeof *h1);
                CHECK_OK(imp_fuse_heights(tmp.nx, tmp.ny, tmp.pitch_mm, h1, nrm, tmp.sigma_mm, m1, &fp, NULL, NULL));
                memcpy(tmp.height_mm, h1, n * sizeof *h1);
                double pinned = strip_rmse(&tmp);
                fprintf(stderr, "strip height rmse with a position term on the strip: %.1f µm\n", pinned * 1000);
                CHECK_GE(pinned, 2 * after);
                imp_heightfield_done(&tmp);
        }
        free(h1);
        free(m1);
        free(nrm);

        /* Dropping: a 3-texel band next to the measured edge cuts the strip off, so the
         * rest of it goes too. */
        uint8_t *drop = calloc(n, 1);
        CHECK(drop != NULL);
        if (drop) {
                long band = 0;
                for (int j = 0; j < on.ny; j++)
                        for (int i = 0; i < on.nx; i++) {
                                double W[3];
                                texel_world(&on, i, j, 0, W);
                                bool in = W[0] > CMAX[0] - STRIP_MM - PITCH && W[0] < CMAX[0] - STRIP_MM + 2.5 * PITCH;
                                drop[(size_t) j * on.nx + i] = in;
                                band += in && on.mask[(size_t) j * on.nx + i] == IMP_HF_MASK_FILLED;
                        }
                long filled_before = (long) on.n_filled_texels;
                imp_heightfield_drop_filled(&on, drop);
                struct counts c = count(&on);
                CHECK_INT_GE(band, 3 * 150);
                CHECK_INT_EQ(c.strip_filled, 0);
                CHECK_INT_EQ(c.measured, b.measured);
                CHECK_INT_EQ(on.n_filled_texels, c.filled);
                CHECK(c.filled < filled_before - b.strip_filled / 2);
                imp_heightfield_drop_filled(&on, NULL);
                CHECK_INT_EQ(on.n_filled_texels, 0);
                CHECK_INT_EQ(on.n_mask_texels, b.measured);
                free(drop);
        }
        imp_heightfield_done(&off);
        imp_heightfield_done(&on);
        imp_range_image_done(&r);
}

/* A gap in the frame or no frame: the region is not enclosed, nothing of the strip is
 * filled (the fill never runs out onto what it cannot bound). */
static void test_unbounded(enum scene sc) {
        struct imp_range_image r = {};
        make_range(sc, &r);
        struct imp_heightfield_options o;
        imp_heightfield_options_default(&o);
        o.shadow_fill_px = FILL_PX;
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, &o, &hf));
        struct counts c = count(&hf);
        fprintf(stderr, "%s: %ld filled, strip %ld, off canvas %ld\n", sc == FRAME_GAP ? "frame gap" : "no frame",
                c.filled, c.strip_filled, c.off_canvas);
        CHECK_INT_EQ(c.strip_filled, 0);
        CHECK_INT_EQ(c.off_canvas, 0);
        if (sc == NO_FRAME)
                CHECK_INT_EQ(c.filled, 0);
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

int main(void) {
        test_framed();
        test_unbounded(FRAME_GAP);
        test_unbounded(NO_FRAME);
        struct imp_range_image r = {};
        make_range(FRAMED, &r);
        struct imp_heightfield_options o;
        imp_heightfield_options_default(&o);
        o.shadow_fill_px = -1;
        struct imp_heightfield hf = {};
        CHECK_ERR(imp_heightfield_from_range(&r, &o, &hf), -EINVAL);
        imp_range_image_done(&r);
        return TEST_DONE();
}
