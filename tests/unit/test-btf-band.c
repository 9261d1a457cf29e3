/* The frames interleaved by light (struct imp_btf_band) that both appearance stages read
 * their taps from: on a rough relief with a wall (shadowed and hidden texels), frames
 * with NaN, saturated and masked pixels and texels projecting off the frame, every texel's
 * samples, flags, shadowed count and light indices from the band equal, bit for bit, those
 * read from the frames; each sample's light index names the light it came from; and the
 * BTF fit of the grid (which reads bands for mono frames) equals the fit of the same frames
 * as RGB (which read the frames). */
#include <stdlib.h>

#include "btf.h"
#include "unit/btf-synth.h"
#include "unit/test.h"

enum { W = 120, H = 150, NL = 36, CW = 112, CH = 170 };
#define PITCH 0.1

static float height[W * H], normal[3 * W * H];
static uint8_t mask[W * H];
static struct imp_rig_light lights[NL];
static struct imp_image *mono[NL], *rgb[NL], *valid[NL];

static void setup_heightfield(struct imp_btf_heightfield *hf, uint64_t *rng) {
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        double h = 0.3 * sin(u / 7.0) * cos(v / 5.0) + 0.02 * synth_uniform(rng);
                        if (u >= 60 && u <= 62)
                                h += 2.0;   /* a wall: long shadows, hidden texels behind it */
                        height[v * W + u] = (float) h;
                        mask[v * W + u] = synth_uniform(rng) < 0.02 ? 0 : 1;
                }
        height[40 * W + 30] = NAN;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        int u0 = u > 0 ? u - 1 : u, u1 = u < W - 1 ? u + 1 : u;
                        int v0 = v > 0 ? v - 1 : v, v1 = v < H - 1 ? v + 1 : v;
                        double gx = (height[v * W + u1] - height[v * W + u0]) / ((u1 - u0) * PITCH);
                        double gy = (height[v1 * W + u] - height[v0 * W + u]) / ((v1 - v0) * PITCH);
                        if (!isfinite(gx) || !isfinite(gy))
                                gx = gy = 0;
                        double n = sqrt(gx * gx + gy * gy + 1);
                        float *q = &normal[3 * (v * W + u)];
                        q[0] = (float) (-gx / n), q[1] = (float) (-gy / n), q[2] = (float) (1 / n);
                }
        /* canvas (0, 0) at world (−W·pitch/2, −H·pitch/2, 0) */
        *hf = (struct imp_btf_heightfield) { .width = W, .height = H, .pitch_mm = PITCH, .height_mm = height,
                .normal = normal, .mask = mask, .canvas_to_world = { 1, 0, 0, -W * PITCH / 2, 0, 1, 0, -H * PITCH / 2,
                                                                     0, 0, 1, 0, 0, 0, 0, 1 } };
}

/* Mono frames with values up to 1.003 (saturation 1.0 below: 0.3 % saturated by value),
 * 1 % NaN, 1.5 % masked pixels (saturated, invalid or both; few enough that a texel's
 * SATURATED flag depends on which tap decides); rgb[] the same values in 3 channels. */
static void setup_frames(uint64_t *rng) {
        for (int j = 0; j < NL; j++) {
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, &mono[j]));
                CHECK_OK(imp_image_new(CW, CH, 3, IMP_PIX_F32, &rgb[j]));
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_U8, &valid[j]));
                for (int y = 0; y < CH; y++)
                        for (int x = 0; x < CW; x++) {
                                double r = synth_uniform(rng);
                                float val = r < 0.01 ? NAN : (float) (1.003 * synth_uniform(rng));
                                uint8_t fl = 0;
                                if (r > 0.985)
                                        fl = r > 0.997 ? IMP_BTF_PIX_SATURATED : r > 0.989 ? IMP_BTF_PIX_INVALID
                                                      : IMP_BTF_PIX_SATURATED | IMP_BTF_PIX_INVALID;
                                *imp_image_f32(mono[j], x, y) = val;
                                for (int c = 0; c < 3; c++)
                                        imp_image_f32(rgb[j], x, y)[c] = val;
                                *imp_image_u8(valid[j], x, y) = fl;
                        }
        }
}

struct texel_out {
        struct imp_btf_sample s[NL];
        uint16_t light[NL], flags, shadowed;
        int n;
};

static void extract(const struct imp_btf_extractor *x, const struct imp_btf_band *b, int u, int v,
                    struct texel_out *t) {
        memset(t, 0, sizeof *t);
        t->n = imp_btf_extract_texel_band(x, b, u, v, t->s, t->light, &t->flags, &t->shadowed);
}

static bool same(const struct texel_out *a, const struct texel_out *b) {
        return a->n == b->n && a->flags == b->flags && a->shadowed == b->shadowed &&
               !memcmp(a->s, b->s, a->n * sizeof *a->s) && !memcmp(a->light, b->light, a->n * sizeof *a->light);
}

/* Sample s of texel (u, v) is light light[s]'s: a capture of that light alone gives it. */
static bool light_right(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                        const struct imp_btf_sample_params *sp, const struct imp_btf_hf_pyramid *py,
                        const struct texel_out *t, int u, int v) {
        for (int s = 0; s < t->n; s++) {
                int j = t->light[s];
                struct imp_btf_capture one = { cap->camera, &cap->lights[j], 1, &cap->frames[j], &cap->valid[j] };
                _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x1 = NULL;
                struct imp_btf_sample smp[1];
                uint16_t fl, sh;
                if (imp_btf_extractor_new(hf, &one, sp, py, &x1) < 0 || imp_btf_extract_texel(x1, u, v, smp, &fl, &sh) != 1 ||
                    memcmp(smp, &t->s[s], sizeof *smp))
                        return false;
        }
        return true;
}

static void test_extraction(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *sp) {
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
        CHECK_OK(imp_btf_hf_pyramid_new(hf, &py));
        CHECK_OK(imp_btf_extractor_new(hf, cap, sp, py, &x));
        struct imp_btf_band b = {};
        long differ = 0, samples = 0, shadowed = 0, hidden = 0, saturated = 0, wrong_light = 0, poisoned = 0;
        static struct texel_out a, t;
        for (int v0 = 0; v0 < H; v0 += IMP_BTF_BAND_ROWS) {
                int rows = IMP_MIN(IMP_BTF_BAND_ROWS, H - v0);
                CHECK(imp_btf_band_load(x, v0, rows, 1, &b));
                for (int v = v0; v < v0 + rows; v++)
                        for (int u = 0; u < W; u++) {
                                extract(x, NULL, u, v, &a);
                                extract(x, &b, u, v, &t);
                                differ += !same(&a, &t);
                                samples += a.n;
                                shadowed += a.shadowed;
                                hidden += !!(a.flags & IMP_BTF_HIDDEN);
                                saturated += !!(a.flags & IMP_BTF_SATURATED);
                                if ((u + v) % 11 == 0)
                                        wrong_light += !light_right(hf, cap, sp, py, &a, u, v);
                        }
                /* the band is what was read: values changed there change the samples */
                for (size_t k = 0; k < (size_t) b.cols * b.rows * b.L; k++)
                        b.v[k] += 0.25f;
                for (int v = v0; v < v0 + rows; v++)
                        for (int u = 0; u < W; u++) {
                                extract(x, NULL, u, v, &a);
                                extract(x, &b, u, v, &t);
                                poisoned += a.n > 0 && !same(&a, &t);
                        }
        }
        imp_btf_band_done(&b);
        fprintf(stderr, "band: %ld samples, %ld shadowed, %ld hidden, %ld saturated texels; %ld differ, "
                "%ld with a wrong light, %ld read the changed band\n", samples, shadowed, hidden, saturated,
                differ, wrong_light, poisoned);
        CHECK_INT_EQ(differ, 0);
        CHECK_INT_EQ(wrong_light, 0);
        /* the scene exercises what the band must get right */
        CHECK_INT_GE(samples, 100000);
        CHECK_INT_GE(shadowed, 1000);
        CHECK_INT_GE(hidden, 100);
        CHECK_INT_GE(saturated, 1000);
        CHECK_INT_GE(poisoned, (long) W * H / 2);
}

static void test_fit_grid(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                          const struct imp_btf_sample_params *sp) {
        struct imp_btf_fit_params fp;
        imp_btf_fit_params_default(&fp);
        struct imp_btf_capture crgb = *cap;
        crgb.frames = (const struct imp_image *const *) rgb;
        _cleanup_free_ struct imp_btf_texel *tm = calloc(W * H, sizeof *tm), *tr = calloc(W * H, sizeof *tr);
        struct imp_btf_stats sm, sr;
        CHECK_OK(imp_btf_fit_grid(hf, cap, sp, &fp, 0, tm, &sm));
        CHECK_OK(imp_btf_fit_grid(hf, &crgb, sp, &fp, 0, tr, &sr));
        CHECK(!memcmp(tm, tr, (size_t) W * H * sizeof *tm));
        CHECK(!memcmp(&sm, &sr, sizeof sm));
        CHECK_INT_GE(sm.n_fitted, W * H / 2);
        /* RGB frames are not interleaved: the fit read them from the frames */
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
        CHECK_OK(imp_btf_hf_pyramid_new(hf, &py));
        CHECK_OK(imp_btf_extractor_new(hf, &crgb, sp, py, &x));
        struct imp_btf_band b = {};
        CHECK(!imp_btf_band_load(x, 0, 8, 1, &b));
        imp_btf_band_done(&b);
}

int main(void) {
        uint64_t rng = 0x9e3779b97f4a7c15ULL;
        const double centre[3] = { 0, 0, 0 }, elev[3] = { 12, 35, 65 };
        CHECK_INT_EQ(synth_dome(lights, elev, 3, 12, 500.0, centre, 1.0, 1.0), NL);
        struct imp_btf_heightfield hf;
        setup_heightfield(&hf, &rng);
        struct imp_pinhole cam;
        const double eye[3] = { 1.5, 0, 300 };
        synth_camera(&cam, eye, centre, CW, CH, 3000.0);   /* ≈ 1 pixel a texel */
        setup_frames(&rng);
        struct imp_btf_capture cap = { .camera = &cam, .lights = lights, .n_lights = NL,
                                       .frames = (const struct imp_image *const *) mono,
                                       .valid = (const struct imp_image *const *) valid };
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        sp.saturation_value = 1.0;
        test_extraction(&hf, &cap, &sp);
        test_fit_grid(&hf, &cap, &sp);
        for (int j = 0; j < NL; j++) {
                imp_image_free(mono[j]);
                imp_image_free(rgb[j]);
                imp_image_free(valid[j]);
        }
        return TEST_DONE();
}
