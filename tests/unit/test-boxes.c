/* Relief boxes on a synthetic heightfield: two bumps above a slightly noisy canvas, a few
 * isolated specks above δ0 (removed as small components), a deep pit (must not move the
 * reference). Checks coverage (every significant texel inside a box), no box without a
 * significant texel, hmax and (umax, vmax) by brute force, the flat case, boxes.json. */
#include <math.h>
#include <string.h>
#include "boxes.h"
#include "json-util.h"
#include "unit/test.h"

#define NX 203
#define NY 151

static void make_hf(struct imp_heightfield *hf, bool flat) {
        *hf = (struct imp_heightfield) { .nx = NX, .ny = NY, .pitch_mm = 0.1 };
        size_t n = (size_t) NX * NY;
        hf->height_mm = calloc(n, sizeof(float));
        hf->nx_ = calloc(n, sizeof(float));
        hf->ny_ = calloc(n, sizeof(float));
        hf->sigma_mm = calloc(n, sizeof(float));
        hf->mask = calloc(n, 1);
        uint32_t seed = 7;
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        size_t t = (size_t) j * NX + i;
                        hf->mask[t] = i > 1 && j > 1 && i < NX - 2 && j < NY - 2;
                        if (flat)
                                continue;
                        seed = seed * 1664525u + 1013904223u;
                        double noise = 0.01 * ((seed >> 8) / 16777216.0 - 0.5);
                        double a = exp(-(pow(i - 50, 2) + pow(j - 40, 2)) / (2 * 8.0 * 8.0));
                        double b = 0.6 * exp(-(pow(i - 150, 2) + pow(j - 100, 2)) / (2 * 12.0 * 12.0));
                        hf->height_mm[t] = (float) (-0.2 + noise + a + b);
                }
        if (!flat) {
                hf->height_mm[(size_t) 120 * NX + 30] = 0.9f;   /* specks: 1 and 2 texels */
                hf->height_mm[(size_t) 20 * NX + 180] = 0.8f;
                hf->height_mm[(size_t) 20 * NX + 181] = 0.8f;
                hf->height_mm[(size_t) 75 * NX + 100] = -5.0f;  /* a pit */
        }
}

static void test_classify(void) {
        struct imp_heightfield hf;
        make_hf(&hf, false);
        struct imp_boxes b = {};
        CHECK_OK(imp_boxes_classify(&hf, NULL, &b));
        fprintf(stderr, "h_ref %.4f H %.4f δ0 %.4f: %zu significant texels, %zu components (%zu removed), %zu boxes of %dx%d cells\n",
                b.h_ref_mm, b.H_mm, b.delta0_mm, b.n_significant, b.n_components, b.n_components_removed, b.n_boxes,
                b.cells_u, b.cells_v);
        CHECK_NEAR(b.h_ref_mm, -0.2, 0.01);          /* 5th percentile: canvas level, not the pit */
        CHECK_NEAR(b.H_mm, 1.1, 0.02);               /* the 0.9 speck is the canvas maximum (seed: H = max height) */
        CHECK_NEAR(b.delta0_mm, 0.3 * b.H_mm, 1e-9);
        CHECK_INT_EQ(b.n_components_removed, 2);
        CHECK_INT_EQ(b.significant[(size_t) 120 * NX + 30], 0);
        CHECK_INT_EQ(b.cells_u, (NX + 19) / 20);

        /* Significant = mask, above δ0, and not a speck. */
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        size_t t = (size_t) j * NX + i;
                        bool above = hf.mask[t] && hf.height_mm[t] - b.h_ref_mm > b.delta0_mm;
                        bool speck = (i == 30 && j == 120) || (j == 20 && (i == 180 || i == 181));
                        CHECK_INT_EQ(b.significant[t], above && !speck);
                }
        /* Coverage and no empty boxes. */
        size_t covered = 0;
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        if (!b.significant[(size_t) j * NX + i])
                                continue;
                        int inside = 0;
                        for (size_t k = 0; k < b.n_boxes; k++) {
                                const struct imp_box *x = &b.boxes[k];
                                inside += i >= x->u0 && i < x->u0 + x->w && j >= x->v0 && j < x->v0 + x->h;
                        }
                        CHECK_INT_EQ(inside, 1);
                        covered++;
                }
        CHECK_INT_EQ(covered, b.n_significant);
        for (size_t k = 0; k < b.n_boxes; k++) {
                const struct imp_box *x = &b.boxes[k];
                size_t sig = 0;
                float mx = -INFINITY;
                for (int v = x->v0; v < x->v0 + x->h; v++)
                        for (int u = x->u0; u < x->u0 + x->w; u++) {
                                size_t t = (size_t) v * NX + u;
                                sig += b.significant[t];
                                if (hf.mask[t])
                                        mx = fmaxf(mx, hf.height_mm[t]);
                        }
                CHECK_GE(sig, 1);
                CHECK_INT_EQ(sig, x->n_significant);
                CHECK_NEAR(x->hmax_mm, mx, 0);
                CHECK_NEAR(hf.height_mm[(size_t) x->vmax * NX + x->umax], mx, 0);
                CHECK(x->umax >= x->u0 && x->umax < x->u0 + x->w && x->vmax >= x->v0 && x->vmax < x->v0 + x->h);
        }
        /* Cells without significant texels have no box. */
        size_t cells_with = 0;
        for (int cv = 0; cv < b.cells_v; cv++)
                for (int cu = 0; cu < b.cells_u; cu++) {
                        bool any = false;
                        for (int v = cv * 20; v < IMP_MIN(cv * 20 + 20, NY); v++)
                                for (int u = cu * 20; u < IMP_MIN(cu * 20 + 20, NX); u++)
                                        any |= b.significant[(size_t) v * NX + u];
                        cells_with += any;
                }
        CHECK_INT_EQ(cells_with, b.n_boxes);

        /* boxes.json */
        char path[1024];
        snprintf(path, sizeof path, "%s/boxes.json", test_tmpdir());
        struct imp_error err = {};
        CHECK_OK(imp_boxes_save(&b, path, &err));
        json_t *j = NULL;
        CHECK_OK(imp_json_load(path, &j, &err));
        if (j) {
                CHECK_INT_EQ(json_array_size(json_object_get(j, "boxes")), b.n_boxes);
                CHECK_INT_EQ(json_integer_value(json_object_get(j, "cell_px")), 20);
                json_t *b0 = json_array_get(json_object_get(j, "boxes"), 0);
                CHECK_NEAR(json_real_value(json_object_get(b0, "hmax")), b.boxes[0].hmax_mm, 1e-6);
                json_decref(j);
        }

        /* Smaller cells: more boxes, still covering. */
        struct imp_boxes_options o;
        imp_boxes_options_default(&o);
        o.cell_px = 5;
        struct imp_boxes b5 = {};
        CHECK_OK(imp_boxes_classify(&hf, &o, &b5));
        CHECK_GE(b5.n_boxes, b.n_boxes * 4);
        CHECK_INT_EQ(b5.n_significant, b.n_significant);
        imp_boxes_done(&b5);
        imp_boxes_done(&b);
        imp_heightfield_done(&hf);
}

static void test_flat_and_errors(void) {
        struct imp_heightfield hf;
        make_hf(&hf, true);
        struct imp_boxes b = {};
        CHECK_OK(imp_boxes_classify(&hf, NULL, &b));
        CHECK_INT_EQ(b.n_boxes, 0);
        CHECK_INT_EQ(b.n_significant, 0);
        CHECK_NEAR(b.H_mm, 0, 0);
        imp_boxes_done(&b);
        struct imp_boxes keep = { .n_boxes = 5 };
        struct imp_boxes_options o;
        imp_boxes_options_default(&o);
        o.cell_px = 0;
        CHECK_ERR(imp_boxes_classify(&hf, &o, &keep), -EINVAL);
        memset(hf.mask, 0, (size_t) NX * NY);
        CHECK_ERR(imp_boxes_classify(&hf, NULL, &keep), -ENODATA);
        CHECK_INT_EQ(keep.n_boxes, 5);
        imp_heightfield_done(&hf);
}

/* A flat canvas whose heights are only noise (0.4 µm, with σ saying so): no boxes. With
 * the noise floor off (noise_k = 0, δ0 = delta_frac · H alone) the noise's extremes make
 * boxes: the floor is what keeps them away. */
static void test_flat_noise(void) {
        struct imp_heightfield hf;
        make_hf(&hf, true);
        uint64_t rng = 3;
        for (size_t t = 0; t < (size_t) NX * NY; t++) {
                hf.height_mm[t] = (float) (0.0004 * test_nrand(&rng));
                hf.sigma_mm[t] = 0.0004f;
        }
        struct imp_boxes b = {}, nofloor = {};
        CHECK_OK(imp_boxes_classify(&hf, NULL, &b));
        fprintf(stderr, "flat noisy canvas: H %.2f µm, δ0 %.2f µm (floor %.2f µm), %zu boxes\n",
                b.H_mm * 1000, b.delta0_mm * 1000, b.delta0_floor_mm * 1000, b.n_boxes);
        CHECK_INT_EQ(b.n_boxes, 0);
        CHECK(b.below_noise);
        CHECK_NEAR(b.delta0_floor_mm, 6 * 0.0004, 1e-7);
        struct imp_boxes_options o;
        imp_boxes_options_default(&o);
        o.noise_k = 0;
        CHECK_OK(imp_boxes_classify(&hf, &o, &nofloor));
        fprintf(stderr, "without the floor: δ0 %.2f µm, %zu boxes\n", nofloor.delta0_mm * 1000, nofloor.n_boxes);
        CHECK(nofloor.n_boxes > 0);
        imp_boxes_done(&b);
        imp_boxes_done(&nofloor);
        imp_heightfield_done(&hf);
}

int main(void) {
        test_classify();
        test_flat_and_errors();
        test_flat_noise();
        return TEST_DONE();
}
