/* HDR merge: a synthetic scene of known radiance levels, noise drawn per the sensor model
 * (Poisson shot noise, Gaussian read noise, quantisation, clipping), 3 exposures. Checks:
 * unbiased (|mean/V − 1| < 0.5 % per level), carried variance = measured variance within
 * 10 %, better than the best single exposure, saturation/dark flags, dark frame + flat
 * field, Bayer demosaic, argument errors. */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include "hdr.h"
#include "unit/test.h"

static uint64_t rng_state = 0x9e3779b97f4a7c15ULL;
static double urand(void) {
        uint64_t z = (rng_state += 0x9e3779b97f4a7c15ULL);
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
        z ^= z >> 31;
        return ((z >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}
static double nrand(void) { return sqrt(-2 * log(urand())) * cos(2 * M_PI * urand()); }
static double poisson(double lam) {
        if (lam <= 0)
                return 0;
        if (lam < 40) {
                double L = exp(-lam), p = 1;
                int k = 0;
                do {
                        k++;
                        p *= urand();
                } while (p > L);
                return k - 1;
        }
        return fmax(0, round(lam + sqrt(lam) * nrand()));   /* normal approx., exact variance */
}

static const struct imp_sensor SENSOR = {
        .bits = 12, .black_level_dn = 64, .gain_e_per_dn = 2.0, .read_noise_e = 3.0,
        .full_well_e = 10000, .dark_current_e_per_s = 0, .quantum_scale = 1e6,
};

static uint16_t draw_dn(const struct imp_sensor *s, double V, double t_us, double gain_db, double flat,
                        double off) {
        double g = imp_hdr_e_per_dn(s, gain_db);
        double e = fmin(poisson(V * s->quantum_scale * t_us * 1e-6 * flat), s->full_well_e);
        e += s->read_noise_e * nrand();
        double dn = round(e / g + off);
        double max = (1 << s->bits) - 1;
        return (uint16_t) IMP_CLAMP(dn, 0, max);
}

#define LEVEL_PX 4096   /* pixels per radiance level: 64 × 64 */
static const double LEVELS[] = { 0.05, 0.1, 0.2, 0.5, 1.0, 2.5, 5.0, 10.0, 20.0 };
#define N_LEVELS ((int) ARRAY_SIZE(LEVELS))
static const double EXPOSURES_US[3] = { 250, 1000, 4000 };

static void test_unbiased_and_variance(void) {
        int w = 64, h = 64 * (N_LEVELS + 2);   /* + one saturated and one dark block */
        struct imp_image *f[3];
        struct imp_hdr_exposure st[3];
        for (int k = 0; k < 3; k++) {
                CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_U16, &f[k]));
                st[k] = (struct imp_hdr_exposure) { .frame = f[k], .exposure_us = EXPOSURES_US[k] };
        }
        for (int y = 0; y < h; y++) {
                int lv = y / 64;
                double V = lv < N_LEVELS ? LEVELS[lv] : lv == N_LEVELS ? 1000.0 : 0.0;
                for (int x = 0; x < w; x++)
                        for (int k = 0; k < 3; k++)
                                *imp_image_u16(f[k], x, y) = draw_dn(&SENSOR, V, EXPOSURES_US[k], 0, 1, SENSOR.black_level_dn);
        }
        struct imp_hdr_result res = {};
        CHECK_OK(imp_hdr_merge(st, 3, &SENSOR, NULL, &res));
        CHECK_INT_EQ(res.value->channels, 1);
        for (int lv = 0; lv < N_LEVELS; lv++) {
                double V = LEVELS[lv], s = 0, s2 = 0, cv = 0;
                int flagged = 0;
                for (int y = lv * 64; y < lv * 64 + 64; y++)
                        for (int x = 0; x < w; x++) {
                                double v = *imp_image_f32(res.value, x, y);
                                s += v, s2 += v * v;
                                cv += *imp_image_f32(res.variance, x, y);
                                flagged += *imp_image_u8(res.flags, x, y) != 0;
                        }
                double mean = s / LEVEL_PX, var = (s2 - s * s / LEVEL_PX) / (LEVEL_PX - 1);
                cv /= LEVEL_PX;
                /* Best single exposure: the longest one whose mean stays 5 σ below the
                 * saturation threshold; its variance from the model (exact, no clipping). */
                double best_var = INFINITY;
                int usable = 0;
                for (int k = 0; k < 3; k++) {
                        double t = EXPOSURES_US[k] * 1e-6, e = V * SENSOR.quantum_scale * t;
                        double ve = e + SENSOR.read_noise_e * SENSOR.read_noise_e + SENSOR.gain_e_per_dn * SENSOR.gain_e_per_dn / 12;
                        if (e + 5 * sqrt(ve) < 0.98 * 4031 * SENSOR.gain_e_per_dn) {
                                best_var = fmin(best_var, ve / pow(SENSOR.quantum_scale * t, 2));
                                usable++;
                        }
                }
                fprintf(stderr, "V=%6.2f mean=%.5f rel.err=%+.4f%% var meas=%.3e carried=%.3e ratio=%.3f best-single=%.3e gain=%.2fx\n",
                        V, mean, 100 * (mean / V - 1), var, cv, var / cv, best_var, best_var / var);
                CHECK_INT_EQ(flagged, 0);
                CHECK_LE(fabs(mean / V - 1), 0.005);
                CHECK_LE(fabs(var / cv - 1), 0.10);
                /* Two or more usable exposures: strictly better (here ≥ 1.2×); one: the
                 * same within the 5 % sampling error of a 4096-pixel variance. */
                if (usable >= 2)
                        CHECK_LE(var, best_var / 1.15);
                else
                        CHECK_LE(var, best_var * 1.05);
        }
        /* Saturated everywhere: flagged, finite lower bound ≤ truth. */
        for (int y = N_LEVELS * 64; y < N_LEVELS * 64 + 64; y += 7)
                for (int x = 0; x < w; x += 5) {
                        double v = *imp_image_f32(res.value, x, y);
                        CHECK_INT_EQ(*imp_image_u8(res.flags, x, y), IMP_HDR_SATURATED);
                        CHECK_FINITE(v);
                        CHECK_FINITE(*imp_image_f32(res.variance, x, y));
                        CHECK_GE(v, 25.0);     /* ≈ 0.98·8062 e / (1e6 · 250 µs) = 31.6 */
                        CHECK_LE(v, 1000.0);
                }
        for (int y = (N_LEVELS + 1) * 64; y < h; y += 7)
                for (int x = 0; x < w; x += 5) {
                        /* V = 0: flagged DARK with value 0, unless read noise alone crossed
                         * 3 σ (≈ 0.4 % of pixels): then a small unflagged value. */
                        uint8_t fl = *imp_image_u8(res.flags, x, y);
                        double v = *imp_image_f32(res.value, x, y);
                        CHECK(fl == IMP_HDR_DARK || fl == 0);
                        CHECK_NEAR(v, 0.0, fl ? 0.0 : 0.05);
                        CHECK_FINITE(*imp_image_f32(res.variance, x, y));
                }
        CHECK_INT_EQ(res.n_saturated, 64 * 64);
        CHECK_GE(res.n_dark, 0.99 * 64 * 64);
        imp_hdr_result_done(&res);
        for (int k = 0; k < 3; k++)
                imp_image_free(f[k]);
}

/* Per-pixel dark offsets and a flat field; with gains differing per exposure. */
static void test_dark_flat_gain(void) {
        int w = 128, h = 128;
        struct imp_image *f[3], *dark, *flat;
        struct imp_hdr_exposure st[3];
        const double gain_db[3] = { 0, 6, 12 };
        CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_F32, &dark));
        CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_F32, &flat));
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        *imp_image_f32(dark, x, y) = 60 + (x * 7 + y * 3) % 11;
                        *imp_image_f32(flat, x, y) = 0.7f + 0.6f * x / (w - 1);
                }
        for (int k = 0; k < 3; k++) {
                CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_U16, &f[k]));
                st[k] = (struct imp_hdr_exposure) { .frame = f[k], .exposure_us = EXPOSURES_US[k], .gain_db = gain_db[k] };
                for (int y = 0; y < h; y++)
                        for (int x = 0; x < w; x++)
                                *imp_image_u16(f[k], x, y) = draw_dn(&SENSOR, 0.8, EXPOSURES_US[k], gain_db[k],
                                                                     *imp_image_f32(flat, x, y), *imp_image_f32(dark, x, y));
        }
        struct imp_hdr_options o;
        imp_hdr_options_default(&o);
        o.dark = dark, o.flat = flat;
        struct imp_hdr_result res = {};
        CHECK_OK(imp_hdr_merge(st, 3, &SENSOR, &o, &res));
        double s = 0;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++)
                        s += *imp_image_f32(res.value, x, y);
        double mean = s / (w * h);
        fprintf(stderr, "dark+flat+gains: mean %.5f (truth 0.8)\n", mean);
        CHECK_LE(fabs(mean / 0.8 - 1), 0.005);
        imp_hdr_result_done(&res);
        for (int k = 0; k < 3; k++)
                imp_image_free(f[k]);
        imp_image_free(dark);
        imp_image_free(flat);
}

static void test_bayer(void) {
        struct imp_sensor s = SENSOR;
        s.bayer = true;
        s.read_noise_e = 0;   /* noise-free apart from quantisation */
        int w = 32, h = 24;
        const double rgb[3] = { 1.0, 0.5, 0.25 };
        struct imp_image *f;
        CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_U16, &f));
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        int c = (y & 1) == 0 ? ((x & 1) == 0 ? 0 : 1) : ((x & 1) == 0 ? 1 : 2);
                        double e = rgb[c] * s.quantum_scale * 2000e-6;
                        *imp_image_u16(f, x, y) = (uint16_t) lround(e / s.gain_e_per_dn + s.black_level_dn);
                }
        struct imp_hdr_exposure st = { .frame = f, .exposure_us = 2000 };
        struct imp_hdr_result res = {};
        CHECK_OK(imp_hdr_merge(&st, 1, &s, NULL, &res));
        CHECK_INT_EQ(res.value->channels, 3);
        for (int y = 0; y < h; y += 3)
                for (int x = 0; x < w; x += 3)
                        for (int c = 0; c < 3; c++)
                                CHECK_NEAR(*(imp_image_f32(res.value, x, y) + c), rgb[c], 2e-3);
        imp_hdr_result_done(&res);
        imp_image_free(f);
}

static void test_errors(void) {
        struct imp_image *f, *g;
        CHECK_OK(imp_image_new(8, 8, 1, IMP_PIX_U16, &f));
        CHECK_OK(imp_image_new(9, 8, 1, IMP_PIX_U16, &g));
        struct imp_hdr_exposure st[2] = { { .frame = f, .exposure_us = 100 }, { .frame = g, .exposure_us = 100 } };
        struct imp_hdr_result res = { .n_dark = 12345 };
        CHECK_ERR(imp_hdr_merge(st, 2, &SENSOR, NULL, &res), -EINVAL);
        CHECK_INT_EQ(res.n_dark, 12345);   /* untouched on failure */
        st[1].frame = f;
        st[1].exposure_us = 0;
        CHECK_ERR(imp_hdr_merge(st, 2, &SENSOR, NULL, &res), -EINVAL);
        CHECK_ERR(imp_hdr_merge(st, 0, &SENSOR, NULL, &res), -EINVAL);
        struct imp_sensor bad = SENSOR;
        bad.quantum_scale = 0;
        CHECK_ERR(imp_hdr_merge(st, 1, &bad, NULL, &res), -EINVAL);
        imp_image_free(f);
        imp_image_free(g);
}

static bool same_bytes(const struct imp_image *a, const struct imp_image *b) {
        return a && b && a->width == b->width && a->height == b->height && a->channels == b->channels &&
               a->type == b->type && a->stride == b->stride &&
               !memcmp(a->data, b->data, a->stride * (size_t) a->height);
}

/* A spare of the result's layout filled with junk (NaN, 0xa5 flags) that every sample must
 * overwrite. */
static void junk_spare(struct imp_hdr_result *sp, int w, int h) {
        CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_F32, &sp->variance));
        CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_U8, &sp->flags));
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        *imp_image_f32(sp->variance, x, y) = NAN;
                        *imp_image_u8(sp->flags, x, y) = 0xa5;
                }
}

/* A 3-exposure stack of w x h frames over saturated, dark and ramp bands, with a dark frame. */
static void band_stack(int w, int h, struct imp_image *f[3], struct imp_image **dark, struct imp_hdr_exposure st[3]) {
        CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_F32, dark));
        for (int k = 0; k < 3; k++) {
                CHECK_OK(imp_image_new(w, h, 1, IMP_PIX_U16, &f[k]));
                st[k] = (struct imp_hdr_exposure) { .frame = f[k], .exposure_us = EXPOSURES_US[k] };
        }
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        double V = y < 64 ? 1000.0 : y < 128 ? 0.0 : 0.02 * (1 + x);   /* saturated, dark, a ramp */
                        *imp_image_f32(*dark, x, y) = 60 + (x * 7 + y * 3) % 11;
                        for (int k = 0; k < 3; k++)
                                *imp_image_u16(f[k], x, y) = draw_dn(&SENSOR, V, EXPOSURES_US[k], 0, 1, SENSOR.black_level_dn);
                }
}

/* options.recycle: the variance and flags of an earlier result (junk-filled here) are
 * written into, taken over (the same images), and the result is byte for byte that of a
 * fresh merge, on the table path and on the dark-frame path; a spare of another layout is
 * left in place and the merge allocates. */
static void test_recycle(void) {
        int w = 67, h = 64 * 3;
        struct imp_image *f[3], *dark;
        struct imp_hdr_exposure st[3];
        band_stack(w, h, f, &dark, st);
        for (int with_dark = 0; with_dark < 2; with_dark++) {
                struct imp_hdr_options o;
                imp_hdr_options_default(&o);
                o.dark = with_dark ? dark : NULL;
                struct imp_hdr_result fresh = {}, got = {}, spare = {}, other = {};
                CHECK_OK(imp_hdr_merge(st, 3, &SENSOR, &o, &fresh));
                junk_spare(&spare, w, h);
                const struct imp_image *var0 = spare.variance, *fl0 = spare.flags;
                o.recycle = &spare;
                CHECK_OK(imp_hdr_merge(st, 3, &SENSOR, &o, &got));
                CHECK_MSG(got.variance == var0 && got.flags == fl0 && !spare.variance && !spare.flags,
                          "recycle (dark %d): the spare images were not taken over", with_dark);
                CHECK_MSG(same_bytes(fresh.value, got.value) && same_bytes(fresh.variance, got.variance) &&
                          same_bytes(fresh.flags, got.flags), "recycle (dark %d): result differs from a fresh merge",
                          with_dark);
                CHECK(fresh.n_saturated == got.n_saturated && fresh.n_dark == got.n_dark && fresh.n_dark > 0 &&
                      fresh.n_saturated > 0);
                imp_hdr_result_done(&got);
                junk_spare(&other, w + 1, h);   /* another layout: left, not written */
                var0 = other.variance;
                o.recycle = &other;
                CHECK_OK(imp_hdr_merge(st, 3, &SENSOR, &o, &got));
                CHECK(other.variance == var0 && got.variance != var0 && same_bytes(fresh.variance, got.variance));
                imp_hdr_result_done(&got);
                imp_hdr_result_done(&other);
                imp_hdr_result_done(&spare);
                imp_hdr_result_done(&fresh);
        }
        for (int k = 0; k < 3; k++)
                imp_image_free(f[k]);
        imp_image_free(dark);
}

/* options.arena: the value image is allocated in the arena (in_arena, inside its mapped
 * bytes) and equals a heap merge byte for byte, with and without the dark frame and through
 * the Bayer demosaic (where the 3-channel result is the arena's); the variance and flags stay
 * on the heap; the arena is freed as a whole after the result. */
static void test_arena(void) {
        struct imp_image *f[3], *dark;
        struct imp_hdr_exposure st[3];
        band_stack(67, 64 * 3, f, &dark, st);
        for (int mode = 0; mode < 3; mode++) {   /* table path, dark-frame path, Bayer */
                struct imp_sensor s = SENSOR;
                s.bayer = mode == 2;
                struct imp_hdr_options o;
                imp_hdr_options_default(&o);
                o.dark = mode == 1 ? dark : NULL;
                struct imp_hdr_result heap = {}, got = {};
                CHECK_OK(imp_hdr_merge(st, 3, &s, &o, &heap));
                struct imp_image_arena *a = NULL;
                CHECK_OK(imp_image_arena_new(&a));
                o.arena = a;
                CHECK_OK(imp_hdr_merge(st, 3, &s, &o, &got));
                CHECK_MSG(got.value && got.value->in_arena && !got.variance->in_arena && !got.flags->in_arena,
                          "arena (mode %d): the value image is not the arena's", mode);
                CHECK_MSG(imp_image_arena_mapped(a) > 0, "arena (mode %d): nothing mapped", mode);
                CHECK_INT_EQ(got.value->channels, mode == 2 ? 3 : 1);
                CHECK_MSG(same_bytes(heap.value, got.value) && same_bytes(heap.variance, got.variance) &&
                          same_bytes(heap.flags, got.flags), "arena (mode %d): result differs from a heap merge", mode);
                imp_hdr_result_done(&got);
                imp_image_arena_free(a);
                imp_hdr_result_done(&heap);
        }
        for (int k = 0; k < 3; k++)
                imp_image_free(f[k]);
        imp_image_free(dark);
}

int main(void) {
        test_unbiased_and_variance();
        test_dark_flat_gain();
        test_bayer();
        test_errors();
        test_recycle();
        test_arena();
        return TEST_DONE();
}
