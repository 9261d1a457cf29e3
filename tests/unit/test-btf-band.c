/* The frames interleaved by light (struct imp_btf_band) that both appearance stages read
 * their taps from: on a rough relief with a wall (shadowed and hidden texels), frames
 * with NaN, saturated and masked pixels and texels projecting off the frame, every texel's
 * samples, flags, shadowed count and light indices from the band equal, bit for bit, those
 * read from the frames; each sample's light index names the light it came from; and the
 * BTF fit of the grid (which reads bands for mono frames) equals the fit of the same frames
 * as RGB (which read the frames); values given by the caller replace exactly the bilinear
 * values of their lights' samples (imp_btf_extract_texel_given()); the per-light
 * geometry computed in vector lanes equals the one-light-at-a-time formulas; and ray
 * decisions recorded by one extraction and reused by another (struct imp_btf_rays) give
 * the marching extraction's samples and fit. */
#include <errno.h>
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

/* imp_btf_extract_texel_given(): the caller's values replace the bilinear ones of the
 * lights it gives, nothing else changes. Given for about two lights in three (a marker
 * value per texel and light), from the band (taps' states only) and from the frames: the
 * samples that exist, their geometry, flags, shadowed counts and lights are the full
 * extraction's, including where a given light's taps are NaN, saturated or masked (such a
 * sample stays out), and with a dark_value (whose test reads the bilinear value). */
static void test_given(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                       const struct imp_btf_sample_params *sp0) {
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        CHECK_OK(imp_btf_hf_pyramid_new(hf, &py));
        static struct texel_out a, t;
        float given[NL][3];
        uint8_t ok[NL];
        for (int dark = 0; dark < 2; dark++) {
                struct imp_btf_sample_params sp = *sp0;
                if (dark)
                        sp.dark_value = 0.2;   /* ≈ 2 % of the samples (4 taps averaged) are darker */
                _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
                CHECK_OK(imp_btf_extractor_new(hf, cap, &sp, py, &x));
                struct imp_btf_band b = {};
                long differ = 0, replaced = 0, kept = 0, refused = 0, total = 0;
                for (int v0 = 0; v0 < H; v0 += IMP_BTF_BAND_ROWS) {
                        int rows = IMP_MIN(IMP_BTF_BAND_ROWS, H - v0);
                        CHECK(imp_btf_band_load(x, v0, rows, 1, &b));
                        for (int v = v0; v < v0 + rows; v++)
                                for (int u = 0; u < W; u++) {
                                        extract(x, NULL, u, v, &a);
                                        total += a.n;
                                        for (int j = 0; j < NL; j++) {
                                                ok[j] = (j + u + 2 * v) % 3 != 0;
                                                for (int c = 0; c < 3; c++)
                                                        given[j][c] = 100.0f + j + 0.25f * c + 0.001f * (u % 7);
                                        }
                                        /* given lights that the full extraction drops (bad taps, dark, rays) */
                                        for (int j = 0, s = 0; j < NL; j++) {
                                                bool in = s < a.n && a.light[s] == j;
                                                refused += ok[j] && !in;
                                                s += in;
                                        }
                                        for (int from_band = 0; from_band < 2; from_band++) {
                                                memset(&t, 0, sizeof t);
                                                t.n = imp_btf_extract_texel_given(x, from_band ? &b : NULL, u, v,
                                                                                  (const float (*)[3]) given, ok, t.s,
                                                                                  t.light, &t.flags, &t.shadowed);
                                                bool d = t.n != a.n || t.flags != a.flags || t.shadowed != a.shadowed ||
                                                         memcmp(t.light, a.light, a.n * sizeof *a.light);
                                                for (int s = 0; !d && s < a.n; s++) {
                                                        int j = a.light[s];
                                                        const float *want = ok[j] ? given[j] : a.s[s].value;
                                                        d = memcmp(t.s[s].v, a.s[s].v, sizeof a.s[s].v) ||
                                                            memcmp(t.s[s].l, a.s[s].l, sizeof a.s[s].l) ||
                                                            t.s[s].e_cos != a.s[s].e_cos ||
                                                            memcmp(t.s[s].value, want, sizeof a.s[s].value);
                                                        replaced += ok[j] && from_band;
                                                        kept += !ok[j] && from_band;
                                                }
                                                differ += d;
                                        }
                                }
                }
                imp_btf_band_done(&b);
                fprintf(stderr, "given (dark_value %g): %ld samples, %ld replaced, %ld kept, %ld given but "
                        "refused; %ld texels differ\n", sp.dark_value, total, replaced, kept, refused, differ);
                CHECK_INT_EQ(differ, 0);
                CHECK_INT_GE(replaced, total / 2);
                CHECK_INT_GE(kept, total / 5);
                CHECK_INT_GE(refused, 10000);
        }
}

/* Light j's geometry at texel (u, v) as the extractor computed it one light at a time
 * before it did so in vector lanes (the canvas-to-world map: identity rotation), from the
 * public pieces: its local direction lloc, e_cos and whether the plain march (no pyramid,
 * no horizon) finds it shadowed. False: no sample of it (attached shadow, too dim). */
static bool reference_light(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *sp, double hmax, int u, int v, int j, double lloc[3],
                            double *e_cos, bool *shadowed) {
        size_t idx = (size_t) v * W + u;
        double n[3] = { hf->normal[3 * idx], hf->normal[3 * idx + 1], hf->normal[3 * idx + 2] };
        double nl = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), tb[3], bb[3], wl[3], Pw[3], r = 0;
        for (int i = 0; i < 3; i++)
                n[i] /= nl;
        imp_local_frame(n, tb, bb);
        const double *M = hf->canvas_to_world;
        double P[3] = { u * hf->pitch_mm, v * hf->pitch_mm, hf->height_mm[idx] };
        for (int i = 0; i < 3; i++) {
                Pw[i] = M[4 * i] * P[0] + M[4 * i + 1] * P[1] + M[4 * i + 2] * P[2] + M[4 * i + 3];
                double y[3] = { cap->lights[j].pos_mm[0] - M[3], cap->lights[j].pos_mm[1] - M[7],
                                cap->lights[j].pos_mm[2] - M[11] };
                wl[i] = M[i] * y[0] + M[4 + i] * y[1] + M[8 + i] * y[2] - P[i];
                r += wl[i] * wl[i];
        }
        r = sqrt(r);
        for (int i = 0; i < 3; i++)
                wl[i] /= r;
        imp_to_local(tb, bb, n, wl, lloc);
        if (!(lloc[2] >= sp->min_cos_l))
                return false;
        *e_cos = imp_btf_light_irradiance(&cap->lights[j], Pw) * lloc[2];
        if (!(*e_cos >= sp->min_e_cos))
                return false;
        *shadowed = imp_btf_heightfield_ray(hf, sp, hmax, P, wl, r, NULL);
        return true;
}

/* The extractor's per-light geometry (directions, irradiance with each profile exponent,
 * the horizon's clearing and the march) equals the one-light-at-a-time reference bit for
 * bit: every sample's l and e_cos, every texel's shadowed count; profile exponents 0, 1, 2
 * (the lanes' own formula) and then 1.5 on one light (pow()). */
static void test_light_geometry(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap0,
                                const struct imp_btf_sample_params *sp) {
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        CHECK_OK(imp_btf_hf_pyramid_new(hf, &py));
        double hmax = imp_btf_heightfield_hmax(hf);
        static struct imp_rig_light L[NL];
        static struct texel_out a;
        for (int pow_light = 0; pow_light < 2; pow_light++) {
                for (int j = 0; j < NL; j++) {
                        L[j] = cap0->lights[j];
                        L[j].profile_exp = j % 3;
                }
                if (pow_light)
                        L[5].profile_exp = 1.5;
                struct imp_btf_capture cap = *cap0;
                cap.lights = L;
                _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
                CHECK_OK(imp_btf_extractor_new(hf, &cap, sp, py, &x));
                long differ = 0, samples = 0, shadowed = 0;
                for (int v = 0; v < H; v += 2)
                        for (int u = 0; u < W; u++) {
                                extract(x, NULL, u, v, &a);
                                if (a.flags & (IMP_BTF_MASKED | IMP_BTF_HIDDEN))
                                        continue;
                                int sh = 0;
                                for (int j = 0, s = 0; j < NL; j++) {
                                        double ll[3] = { 0, 0, 0 }, e_cos = 0;
                                        bool shd = false;
                                        bool lit = reference_light(hf, &cap, sp, hmax, u, v, j, ll, &e_cos, &shd);
                                        sh += lit && shd;
                                        if (s >= a.n || a.light[s] != j)
                                                continue;
                                        const struct imp_btf_sample *q = &a.s[s++];
                                        differ += !lit || shd || q->e_cos != (float) e_cos ||
                                                  q->l[0] != (float) ll[0] || q->l[1] != (float) ll[1] ||
                                                  q->l[2] != (float) ll[2];
                                }
                                differ += sh != a.shadowed;
                                samples += a.n;
                                shadowed += sh;
                        }
                fprintf(stderr, "light geometry (pow %d): %ld samples, %ld shadowed; %ld differ\n", pow_light, samples,
                        shadowed, differ);
                CHECK_INT_EQ(differ, 0);
                CHECK_INT_GE(samples, 50000);
                CHECK_INT_GE(shadowed, 500);
        }
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

/* Shared ray decisions (struct imp_btf_rays): recorded by an extraction on the geometric
 * normals, reused by one on other normals over the same heights (the fit after the
 * photometric stage), the samples, flags and shadowed counts equal bit for bit those of an
 * extraction that marches every ray, and so does the grid's fit; the record is what is
 * read: its shadow bits moved by one light, or its camera outcomes inverted, change the
 * samples; a record of the wrong size is refused. */
static void tilted_normals(const float *n0, float *n1) {
        for (int i = 0; i < W * H; i++) {
                double a = 0.15 * sin(0.37 * i), b = 0.15 * cos(0.23 * i);   /* up to ≈ 12° */
                double q[3] = { n0[3 * i] + a, n0[3 * i + 1] + b, n0[3 * i + 2] };
                double l = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
                for (int k = 0; k < 3; k++)
                        n1[3 * i + k] = (float) (q[k] / l);
        }
}

static long extract_all_hz(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                           const struct imp_btf_sample_params *sp, bool horizon, struct texel_out *out) {
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
        CHECK_OK(imp_btf_hf_pyramid_new_horizon(hf, horizon, &py));
        CHECK_OK(imp_btf_extractor_new(hf, cap, sp, py, &x));
        long shadowed = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : shadowed)
        for (int i = 0; i < W * H; i++) {
                extract(x, NULL, i % W, i / W, &out[i]);
                shadowed += out[i].shadowed;
        }
        return shadowed;
}

static long extract_all(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                        const struct imp_btf_sample_params *sp, struct texel_out *out) {
        return extract_all_hz(hf, cap, sp, true, out);
}

static long differing(const struct texel_out *a, const struct texel_out *b) {
        long d = 0;
        for (int i = 0; i < W * H; i++)
                d += !same(&a[i], &b[i]);
        return d;
}

static void test_rays(const struct imp_btf_heightfield *hf0, const struct imp_btf_capture *cap,
                      const struct imp_btf_sample_params *sp0) {
        _cleanup_free_ struct texel_out *ref = calloc(W * H, sizeof *ref), *got = calloc(W * H, sizeof *got);
        _cleanup_free_ float *n1 = malloc(3 * W * H * sizeof *n1);
        _cleanup_(imp_btf_rays_freep) struct imp_btf_rays *rays = NULL;
        CHECK(ref && got && n1);
        CHECK_OK(imp_btf_rays_new(W, H, NL, &rays));
        struct imp_btf_sample_params sp = *sp0;
        sp.rays = rays;
        sp.rays_mode = IMP_BTF_RAYS_RECORD;
        (void) extract_all(hf0, cap, &sp, got);   /* the photometric stage: geometric normals */
        long known = 0, blocked = 0, cam = 0;
        for (int i = 0; i < W * H * rays->words; i++) {
                known += __builtin_popcountll(rays->known[i]);
                blocked += __builtin_popcountll(rays->blocked[i]);
        }
        for (int i = 0; i < W * H; i++)
                cam += rays->camera[i] != IMP_BTF_CAM_UNKNOWN;
        struct imp_btf_heightfield hf = *hf0;
        tilted_normals(hf0->normal, n1);
        hf.normal = n1;
        struct imp_btf_sample_params plain = *sp0;
        long shadowed = extract_all(&hf, cap, &plain, ref);   /* the fit, marching */
        sp.rays_mode = IMP_BTF_RAYS_REUSE;
        long d_same = (extract_all(&hf, cap, &sp, got), differing(ref, got));
        /* the fit of the grid */
        struct imp_btf_fit_params fp;
        imp_btf_fit_params_default(&fp);
        _cleanup_free_ struct imp_btf_texel *ta = calloc(W * H, sizeof *ta), *tb = calloc(W * H, sizeof *tb);
        struct imp_btf_stats sa, sb;
        CHECK_OK(imp_btf_fit_grid(&hf, cap, &plain, &fp, 0, ta, &sa));
        CHECK_OK(imp_btf_fit_grid(&hf, cap, &sp, &fp, 0, tb, &sb));
        CHECK(!memcmp(ta, tb, (size_t) W * H * sizeof *ta));
        CHECK(!memcmp(&sa, &sb, sizeof sa));
        /* without the horizon (the fit's pyramid when it reuses rays): every ray marched,
         * the same decisions; the fit on a record with every other texel's decisions
         * erased (those rays marched there, without the horizon) the same bit for bit */
        long d_nohz = (extract_all_hz(&hf, cap, &plain, false, got), differing(ref, got));
        CHECK_INT_EQ(d_nohz, 0);
        _cleanup_(imp_btf_rays_freep) struct imp_btf_rays *part = NULL;
        CHECK_OK(imp_btf_rays_new(W, H, NL, &part));
        long erased = 0;
        for (int i = 0; i < W * H; i++) {
                bool keep = i % 2 == 0;
                for (int k = 0; k < rays->words; k++) {
                        size_t o = (size_t) i * rays->words + k;
                        part->known[o] = keep ? rays->known[o] : 0;
                        part->blocked[o] = keep ? rays->blocked[o] : 0;
                        erased += keep ? 0 : __builtin_popcountll(rays->known[o]);
                }
                part->camera[i] = keep ? rays->camera[i] : IMP_BTF_CAM_UNKNOWN;
        }
        struct imp_btf_sample_params spp = sp;
        spp.rays = part;
        CHECK_OK(imp_btf_fit_grid(&hf, cap, &spp, &fp, 0, tb, &sb));
        CHECK(!memcmp(ta, tb, (size_t) W * H * sizeof *ta));
        CHECK(!memcmp(&sa, &sb, sizeof sa));
        CHECK_INT_GE(erased, known / 3);
        /* off by one light: every texel's shadow bits moved to the next light */
        for (int i = 0; i < W * H * rays->words; i++)
                rays->blocked[i] = (rays->blocked[i] << 1) & rays->known[i];
        long d_shift = (extract_all(&hf, cap, &sp, got), differing(ref, got));
        for (int i = 0; i < W * H * rays->words; i++)
                rays->blocked[i] = (rays->blocked[i] >> 1) & rays->known[i];
        for (int i = 0; i < W * H; i++)
                rays->camera[i] = rays->camera[i] == IMP_BTF_CAM_CLEAR ? IMP_BTF_CAM_BLOCKED
                                  : rays->camera[i] == IMP_BTF_CAM_BLOCKED ? IMP_BTF_CAM_CLEAR : IMP_BTF_CAM_UNKNOWN;
        long d_cam = (extract_all(&hf, cap, &sp, got), differing(ref, got));
        fprintf(stderr, "rays: %ld decided, %ld blocked, %ld camera rays recorded; reused on tilted normals: "
                "%ld shadowed, %ld texels differ; bits off by one light: %ld differ, camera inverted: %ld\n",
                known, blocked, cam, shadowed, d_same, d_shift, d_cam);
        CHECK_INT_EQ(d_same, 0);
        CHECK_INT_GE(known, (long) W * H * NL / 3);
        CHECK_INT_GE(blocked, 1000);
        CHECK_INT_GE(d_shift, 1000);
        CHECK_INT_GE(d_cam, (long) W * H / 2);
        /* a record of another grid or light count is refused */
        _cleanup_(imp_btf_rays_freep) struct imp_btf_rays *small = NULL;
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        struct imp_btf_extractor *x = NULL;
        CHECK_OK(imp_btf_rays_new(W, H, NL - 1, &small));
        CHECK_OK(imp_btf_hf_pyramid_new(&hf, &py));
        sp.rays = small;
        CHECK_INT_EQ(imp_btf_extractor_new(&hf, cap, &sp, py, &x), -EINVAL);
        CHECK_INT_EQ(imp_btf_rays_new(0, H, NL, &small), -EINVAL);
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
        test_given(&hf, &cap, &sp);
        test_light_geometry(&hf, &cap, &sp);
        test_fit_grid(&hf, &cap, &sp);
        test_rays(&hf, &cap, &sp);
        for (int j = 0; j < NL; j++) {
                imp_image_free(mono[j]);
                imp_image_free(rgb[j]);
                imp_image_free(valid[j]);
        }
        return TEST_DONE();
}
