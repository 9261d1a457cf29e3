/* The heightfield's parallel parts against one thread: imp_heightfield_extract() on odd-sized
 * range images (a canvas in a raised frame with relief, points jittered by 0.45 of their
 * spacing so that neighbouring triangles overlap and the later one's values must win, some
 * points invalid, the camera turned in the canvas plane by 0° and 27° so that range rows run
 * along and across the grid rows) gives the same grid, texel by texel and bit for bit, and
 * the same statistics with 2 and 3 threads as with 1: a band of grid rows that two threads
 * both wrote in another order, or that none wrote, shows as a differing texel. */
#include <math.h>
#include <omp.h>
#include <string.h>
#include "heightfield.h"
#include "numerics.h"
#include "unit/test.h"

static uint64_t rng_state = 88172645463325252ULL;
static double uniform(void) {
        rng_state ^= rng_state << 13, rng_state ^= rng_state >> 7, rng_state ^= rng_state << 17;
        return (rng_state >> 11) * (1.0 / 9007199254740992.0);
}

/* w × h camera points 0.1 mm apart over a 1 mm proud frame around the canvas; turned by
 * deg about the view axis, seen from 500 mm. */
static void make_range(int w, int h, double deg, struct imp_range_image *r) {
        CHECK_OK(imp_range_image_init(r, w, h));
        double c = cos(deg * M_PI / 180), s = sin(deg * M_PI / 180), sp = 0.1;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t k = (size_t) y * w + x;
                        double jx = 0.45 * sp * (2 * uniform() - 1), jy = 0.45 * sp * (2 * uniform() - 1);
                        if (uniform() < 0.01)
                                continue;   /* invalid */
                        double u = (x - 0.5 * (w - 1)) * sp + jx, v = (y - 0.5 * (h - 1)) * sp + jy;
                        bool frame = x < 12 || y < 12 || x >= w - 12 || y >= h - 12;
                        double z = frame ? 1.0 : 0.05 * sin(u * 1.3) * cos(v * 0.9) + 0.004 * (2 * uniform() - 1);
                        r->xyz[3 * k] = (float) (c * u - s * v);
                        r->xyz[3 * k + 1] = (float) (s * u + c * v);
                        r->xyz[3 * k + 2] = (float) z;
                        r->sigma_mm[k] = (float) (0.002 + 0.001 * uniform());
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                }
        r->camera_centre_mm[2] = 500;
}

static size_t differing(const void *a, const void *b, size_t n, size_t size) {
        size_t d = 0;
        for (size_t i = 0; i < n; i++)
                d += memcmp((const char *) a + i * size, (const char *) b + i * size, size) != 0;
        return d;
}

static void same_grid(const struct imp_heightfield *a, const struct imp_heightfield *b, int threads) {
        CHECK_INT_EQ(a->nx, b->nx);
        CHECK_INT_EQ(a->ny, b->ny);
        if (a->nx != b->nx || a->ny != b->ny)
                return;
        size_t n = (size_t) a->nx * a->ny;
        size_t d = differing(a->height_mm, b->height_mm, n, 4) + differing(a->nx_, b->nx_, n, 4) +
                   differing(a->ny_, b->ny_, n, 4) + differing(a->sigma_mm, b->sigma_mm, n, 4) +
                   differing(a->sigma_n_deg, b->sigma_n_deg, n, 4) + differing(a->mask, b->mask, n, 1) +
                   differing(a->texel_flags, b->texel_flags, n, 2);
        CHECK_MSG(d == 0, "%d threads: %zu texel values differ from 1 thread's", threads, d);
        CHECK_INT_EQ(a->n_mask_texels, b->n_mask_texels);
        CHECK_INT_EQ(a->n_canvas_points, b->n_canvas_points);
        CHECK_INT_EQ(a->n_filled_texels, b->n_filled_texels);
        CHECK(memcmp(a->canvas_to_world, b->canvas_to_world, sizeof a->canvas_to_world) == 0);
        CHECK(a->plane_rms_mm == b->plane_rms_mm);
        CHECK(a->footprint_mm == b->footprint_mm && a->neighbour_mm == b->neighbour_mm);
        CHECK(a->frame_height_mm == b->frame_height_mm && a->pitch_mm == b->pitch_mm);
        CHECK(a->gradient_threshold_mm == b->gradient_threshold_mm);
}

static void test_case(int w, int h, double deg) {
        struct imp_range_image r = {};
        make_range(w, h, deg, &r);
        struct imp_heightfield ref = {};
        omp_set_num_threads(1);
        CHECK_OK(imp_heightfield_extract(&r, NULL, &ref, NULL));
        CHECK_GE(ref.n_mask_texels, (size_t) (0.5 * w * h));   /* the canvas was found */
        fprintf(stderr, "%d × %d at %g°: %d × %d texels, %zu on the mask\n", w, h, deg, ref.nx, ref.ny,
                ref.n_mask_texels);
        for (int t = 2; t <= 3; t++) {
                struct imp_heightfield hf = {};
                omp_set_num_threads(t);
                CHECK_OK(imp_heightfield_extract(&r, NULL, &hf, NULL));
                same_grid(&ref, &hf, t);
                imp_heightfield_done(&hf);
        }
        imp_heightfield_done(&ref);
        imp_range_image_done(&r);
}

int main(void) {
        omp_set_dynamic(0);
        test_case(301, 233, 0);
        test_case(277, 251, 27);
        return TEST_DONE();
}
