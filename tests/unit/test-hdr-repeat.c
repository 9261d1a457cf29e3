/* HDR merge of repeated exposures (a plan's dome `repeat`): two frames A and B of one
 * exposure plus a longer one C, merged as three separate samples, must give the value and
 * variance of the merge of their mean M = (A + B) / 2 declared as n_frames = 2 (what
 * pipeline/process.c passes for repeats), in both the table path and the dark-frame path;
 * and declaring n_frames halves the noise variance of a frame (ignoring it would not). */
#include <math.h>
#include <stdint.h>
#include "hdr.h"
#include "unit/test.h"

static const struct imp_sensor SENSOR = {
        .bits = 12, .black_level_dn = 64, .gain_e_per_dn = 2.0, .read_noise_e = 3.0,
        .full_well_e = 10000, .quantum_scale = 1e6,
};
#define W 64
#define H 64

/* A frame of radiance ramp 0.3..1.8 at t_us with Gaussian noise of the sensor's shot and
 * read noise. */
static struct imp_image *frame(double t_us, uint64_t *rng) {
        struct imp_image *f = NULL;
        if (imp_image_new(W, H, 1, IMP_PIX_U16, &f) < 0)
                exit(2);
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++) {
                        double V = 0.3 + 1.5 * (y * W + x) / (double) (W * H);
                        double e = V * SENSOR.quantum_scale * t_us * 1e-6;
                        e += sqrt(e + SENSOR.read_noise_e * SENSOR.read_noise_e) * test_nrand(rng);
                        *imp_image_u16(f, x, y) = (uint16_t) lround(e / SENSOR.gain_e_per_dn + SENSOR.black_level_dn);
                }
        return f;
}

static void compare(const struct imp_hdr_result *a, const struct imp_hdr_result *b, double vtol, double vartol) {
        int bad_v = 0, bad_var = 0;
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++) {
                        double va = *imp_image_f32(a->value, x, y), vb = *imp_image_f32(b->value, x, y);
                        double sa = *imp_image_f32(a->variance, x, y), sb = *imp_image_f32(b->variance, x, y);
                        bad_v += !(fabs(va - vb) <= vtol * fabs(va));
                        bad_var += !(fabs(sa - sb) <= vartol * sa);
                }
        CHECK_INT_EQ(bad_v, 0);
        CHECK_INT_EQ(bad_var, 0);
}

int main(void) {
        uint64_t rng = 20261122;
        struct imp_image *a = frame(1000, &rng), *b = frame(1000, &rng), *c = frame(4000, &rng), *m = NULL, *dark = NULL;
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U16, &m));
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U16, &dark));
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++) {
                        uint16_t *pb = imp_image_u16(b, x, y), pa = *imp_image_u16(a, x, y);
                        *pb += (pa + *pb) & 1;          /* an even sum: the mean is exact */
                        *imp_image_u16(m, x, y) = (uint16_t) ((pa + *pb) / 2);
                        *imp_image_u16(dark, x, y) = 64;
                }
        struct imp_hdr_exposure sep[3] = { { a, 1000, 0, 0 }, { b, 1000, 0, 0 }, { c, 4000, 0, 0 } };
        struct imp_hdr_exposure avg[2] = { { m, 1000, 0, 2 }, { c, 4000, 0, 0 } };
        struct imp_hdr_options opt;
        imp_hdr_options_default(&opt);
        for (int path = 0; path < 2; path++) {
                opt.dark = path ? dark : NULL;  /* table path, then the per-pixel dark path */
                struct imp_hdr_result r1 = { 0 }, r2 = { 0 }, r3 = { 0 };
                CHECK_OK(imp_hdr_merge(sep, 3, &SENSOR, &opt, &r1));
                CHECK_OK(imp_hdr_merge(avg, 2, &SENSOR, &opt, &r2));
                /* The two differ only by the quantisation of one mean vs two frames and by
                 * pass 1's weights: far below the noise. */
                compare(&r1, &r2, 1e-3, 2e-2);
                /* Declared as a single frame, M's noise would count twice over. */
                struct imp_hdr_exposure one = { m, 1000, 0, 1 }, two = { m, 1000, 0, 2 };
                CHECK_OK(imp_hdr_merge(&one, 1, &SENSOR, &opt, &r3));
                imp_hdr_result_done(&r2);
                CHECK_OK(imp_hdr_merge(&two, 1, &SENSOR, &opt, &r2));
                int n_half = 0;
                for (int y = 0; y < H; y++)
                        for (int x = 0; x < W; x++) {
                                double q = *imp_image_f32(r2.variance, x, y) / *imp_image_f32(r3.variance, x, y);
                                n_half += q > 0.49 && q < 0.53;
                                CHECK_NEAR(*imp_image_f32(r2.value, x, y), *imp_image_f32(r3.value, x, y),
                                           1e-4 * *imp_image_f32(r3.value, x, y));
                        }
                CHECK_INT_EQ(n_half, W * H);
                imp_hdr_result_done(&r1);
                imp_hdr_result_done(&r2);
                imp_hdr_result_done(&r3);
        }
        imp_image_free(a);
        imp_image_free(b);
        imp_image_free(c);
        imp_image_free(m);
        imp_image_free(dark);
        return TEST_DONE();
}
