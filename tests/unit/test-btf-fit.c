/* The per-texel Lafortune fit against synthetic texels with a known BRDF under a 48-light
 * near-field dome (rings at 15°, 35°, 60°, radius 500 mm; camera 300 mm above the dome
 * centre; 1 % relative noise), the single-viewpoint Cx = Cy detection, and the tiled
 * driver end to end on rendered frames. Tolerances are stated where they are checked. */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "btf.h"
#include "numerics.h"
#include "unit/btf-synth.h"
#include "unit/test.h"

#define NOISE_REL 0.01
#define RHO_D_MEDIAN_REL_TOL 0.03     /* median relative error of ρd */
#define K_REL_TOL 0.20                /* k where ρs ≥ 0.1 and the lobe is determined */
#define RERENDER_RMSE_TOL 0.02        /* re-rendered V/E, fraction of white */

static const double elev[3] = { 15, 35, 60 };
static struct imp_rig_light lights[48];
static const double eye_top[3] = { 0, 0, 300 };

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

static const struct imp_lafortune materials[3] = {
        { .rho_d = { 0.60f, 0.45f, 0.30f }, .rho_s = { 0, 0, 0 }, .cx = -1, .cy = -1, .cz = 1, .k = 10 },
        { .rho_d = { 0.35f, 0.30f, 0.25f }, .rho_s = { 0.4f, 0.4f, 0.4f }, .cx = -1, .cy = -1, .cz = 1, .k = 20 },
        { .rho_d = { 0.20f, 0.25f, 0.30f }, .rho_s = { 0.8f, 0.8f, 0.8f }, .cx = -1, .cy = -1, .cz = 1, .k = 100 },
};
static const char *material_names[3] = { "matte", "semi-glossy k=20", "glossy k=100" };

/* RMS over the sampled directions of (fit − truth) · cos θl, i.e. V/E in white units. */
static double rerender_rmse(const struct imp_btf_sample *s, int n, const struct imp_lafortune *truth,
                            const struct imp_btf_texel *t) {
        struct imp_lafortune fit = { .cx = t->cx, .cy = t->cy, .cz = t->cz, .k = t->k };
        memcpy(fit.rho_d, t->rho_d, sizeof fit.rho_d);
        memcpy(fit.rho_s, t->rho_s, sizeof fit.rho_s);
        double ss = 0.0;
        for (int i = 0; i < n; i++) {
                double v[3] = { s[i].v[0], s[i].v[1], s[i].v[2] }, l[3] = { s[i].l[0], s[i].l[1], s[i].l[2] };
                for (int c = 0; c < 3; c++) {
                        double d = (imp_lafortune_eval(&fit, c, v, l) - imp_lafortune_eval(truth, c, v, l)) * l[2];
                        ss += d * d;
                }
        }
        return n ? sqrt(ss / (3.0 * n)) : 0.0;
}

static void test_accuracy(void) {
        struct imp_btf_fit_params p;
        imp_btf_fit_params_default(&p);
        static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
        static double rel_rho_d[3 * 49 * 3];
        int n_rel = 0;
        uint64_t rng = 12345;
        const double n_up[3] = { 0, 0, 1 };

        for (int m = 0; m < 3; m++) {
                int n_k = 0, n_k_ok = 0, n_uncertain = 0, n_matte = 0, n_tex = 0, n_peak_low = 0;
                double ss_rr = 0.0, worst_k = 0.0;
                for (int gy = -3; gy <= 3; gy++)
                        for (int gx = -3; gx <= 3; gx++) {
                                double P[3] = { 50.0 * gx, 50.0 * gy, 0.0 };
                                int n = synth_samples(P, n_up, eye_top, lights, 48, &materials[m], NOISE_REL, &rng, s);
                                struct imp_btf_texel t;
                                CHECK_OK(imp_btf_fit_texel(s, n, &p, &t));
                                n_tex++;
                                for (int c = 0; c < 3; c++) {
                                        CHECK_FINITE(t.rho_d[c]);
                                        CHECK_FINITE(t.rho_s[c]);
                                        rel_rho_d[n_rel++] = fabs(t.rho_d[c] - materials[m].rho_d[c]) / materials[m].rho_d[c];
                                }
                                CHECK_FINITE(t.k);
                                CHECK_FINITE(t.cond);
                                n_matte += !!(t.flags & IMP_BTF_MATTE);
                                /* No peak far above the data (docs/btf-fit.md §5): the brightest
                                 * lobe value the samples saw is ≥ peak_seen_min of the peak (1). */
                                if (!(t.flags & (IMP_BTF_MATTE | IMP_BTF_FEW_SAMPLES | IMP_BTF_K_BOUND))) {
                                        struct imp_lafortune b = { .cx = t.cx, .cy = t.cy, .cz = t.cz, .k = t.k };
                                        double seen = 0.0;
                                        for (int i = 0; i < n; i++) {
                                                double v[3] = { s[i].v[0], s[i].v[1], s[i].v[2] };
                                                double l[3] = { s[i].l[0], s[i].l[1], s[i].l[2] };
                                                seen = fmax(seen, imp_lafortune_lobe(&b, v, l));
                                        }
                                        n_peak_low += !(seen >= 0.99 * p.peak_seen_min);
                                }
                                double rr = rerender_rmse(s, n, &materials[m], &t);
                                ss_rr += rr * rr;
                                if (materials[m].rho_s[0] >= 0.1) {
                                        if (t.flags & (IMP_BTF_LOBE_UNCERTAIN | IMP_BTF_MATTE)) {
                                                n_uncertain++;
                                        } else {
                                                double e = fabs(t.k - materials[m].k) / materials[m].k;
                                                worst_k = fmax(worst_k, e);
                                                n_k++;
                                                n_k_ok += e <= K_REL_TOL;
                                                CHECK_MSG(e <= K_REL_TOL, "%s at (%g, %g): k %g vs %g", material_names[m],
                                                          P[0], P[1], t.k, materials[m].k);
                                        }
                                }
                        }
                double rmse = sqrt(ss_rr / n_tex);
                fprintf(stderr, "%-17s: re-rendered RMSE %.4f, MATTE %d/%d, k checked %d (worst rel err %.3f), "
                        "lobe flagged uncertain %d\n", material_names[m], rmse, n_matte, n_tex, n_k, worst_k, n_uncertain);
                CHECK_LE(rmse, RERENDER_RMSE_TOL);
                CHECK_INT_EQ(n_peak_low, 0);
                if (materials[m].rho_s[0] == 0.0)
                        CHECK_GE(n_matte, 0.9 * n_tex);          /* matte recognised as such */
                else
                        CHECK_GE(n_k, 0.3 * n_tex);  /* not vacuous: ≥ 30 % of texels see the lobe well */
        }
        qsort(rel_rho_d, n_rel, sizeof *rel_rho_d, cmp_double);
        double median = rel_rho_d[n_rel / 2];
        fprintf(stderr, "rho_d relative error: median %.4f, 90th percentile %.4f\n", median,
                rel_rho_d[(int) (0.9 * n_rel)]);
        CHECK_LE(median, RHO_D_MEDIAN_REL_TOL);
}

/* Camera straight above the texel: v = n, so Cx vx lx and Cy vy ly vanish and cannot be
 * told apart; a texel on the camera's x axis has vy = 0. Two oblique cameras fix it. */
static void test_single_viewpoint(void) {
        struct imp_btf_fit_params p;
        imp_btf_fit_params_default(&p);
        static struct imp_btf_sample s[2 * 48];
        uint64_t rng = 777;
        const double n_up[3] = { 0, 0, 1 };
        struct imp_btf_texel t;

        const double below[2][3] = { { 0, 0, 0 }, { 100, 0, 0 } };
        for (int i = 0; i < 2; i++) {
                int n = synth_samples(below[i], n_up, eye_top, lights, 48, &materials[1], NOISE_REL, &rng, s);
                CHECK_OK(imp_btf_fit_texel(s, n, &p, &t));
                CHECK_MSG(t.flags & IMP_BTF_CX_EQ_CY, "texel (%g, %g): flags 0x%x, expected CX_EQ_CY",
                          below[i][0], below[i][1], t.flags);
                CHECK_NEAR(t.cx, t.cy, 1e-6);
                CHECK(!(t.flags & IMP_BTF_MATTE));
        }

        /* Anisotropic lobe seen from two oblique viewpoints: separable. */
        struct imp_lafortune aniso = materials[1];
        aniso.cx = -1.0f;
        aniso.cy = -0.85f;
        aniso.k = 20;
        const double P[3] = { 0, 0, 0 }, eye_a[3] = { -180, -60, 300 }, eye_b[3] = { 60, 200, 300 };
        int n = synth_samples(P, n_up, eye_a, lights, 48, &aniso, NOISE_REL, &rng, s);
        n += synth_samples(P, n_up, eye_b, lights, 48, &aniso, NOISE_REL, &rng, s + n);
        CHECK_OK(imp_btf_fit_texel(s, n, &p, &t));
        fprintf(stderr, "two views: C = (%.3f, %.3f, %.3f), k = %.1f, flags 0x%x, cond %.3g\n", t.cx, t.cy, t.cz,
                t.k, t.flags, t.cond);
        CHECK(!(t.flags & IMP_BTF_CX_EQ_CY));
        CHECK_NEAR(t.cx, -1.0, 0.1);                    /* tolerances: 0.1 on C, 20 % on k */
        CHECK_NEAR(t.cy, -0.85, 0.1);
        CHECK_NEAR(t.cz, 1.0, 0.1);
        CHECK_NEAR(t.k, 20.0, 0.2 * 20.0);
}

/* The tiled driver on frames rendered from a flat canvas: left half matte, right half
 * semi-glossy; 16-texel tiles so that partial tiles occur. */
struct halves { double split_x; };
static void brdf_halves(double x, double y, void *ctx, struct imp_lafortune *ret) {
        const struct halves *h = ctx;
        *ret = x < h->split_x ? materials[0] : materials[1];
}

/* n frames of the two-material flat canvas (brdf_halves) under the first n lights, the
 * capture over them and default parameters. */
static void halves_capture(const struct imp_pinhole *cam, struct halves *hv, uint64_t seed, struct imp_image **frames,
                           int n, struct imp_btf_capture *cap, struct imp_btf_sample_params *sp,
                           struct imp_btf_fit_params *fp) {
        uint64_t rng = seed;
        for (int j = 0; j < n; j++) {
                CHECK_OK(imp_image_new(cam->width, cam->height, 3, IMP_PIX_F32, &frames[j]));
                synth_render_flat(cam, &lights[j], 0.0, brdf_halves, hv, NOISE_REL, &rng, frames[j]);
        }
        *cap = (struct imp_btf_capture) { .camera = cam, .lights = lights, .n_lights = n,
                                          .frames = (const struct imp_image *const *) frames };
        imp_btf_sample_params_default(sp);
        imp_btf_fit_params_default(fp);
}

static void test_grid_end_to_end(void) {
        enum { W = 50, H = 40, NL = 48 };
        const double pitch = 0.5, origin[3] = { 70, 30, 0 };
        static float height[W * H], normal[3 * W * H];
        for (int i = 0; i < W * H; i++) {
                normal[3 * i + 2] = 1.0f;
        }
        struct imp_btf_heightfield hf = { .width = W, .height = H, .pitch_mm = pitch, .height_mm = height,
                                          .normal = normal,
                                          .canvas_to_world = { 1, 0, 0, origin[0], 0, 1, 0, origin[1],
                                                               0, 0, 1, origin[2], 0, 0, 0, 1 } };
        struct imp_pinhole cam;
        const double target[3] = { origin[0] + 0.5 * W * pitch, origin[1] + 0.5 * H * pitch, 0 };
        synth_camera(&cam, eye_top, target, 200, 160, 2400.0);
        struct halves hv = { origin[0] + 0.5 * W * pitch };
        struct imp_image *frames[NL] = { 0 };
        struct imp_btf_capture cap;
        struct imp_btf_sample_params sp;
        struct imp_btf_fit_params fp;
        halves_capture(&cam, &hv, 99, frames, NL, &cap, &sp, &fp);
        static struct imp_btf_texel tex[W * H];
        struct imp_btf_stats st;
        CHECK_OK(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 16, tex, &st));
        fprintf(stderr, "grid: fitted %ld, matte %ld, hidden %ld, few %ld, samples %ld, shadowed %ld\n", st.n_fitted,
                st.n_matte, st.n_hidden, st.n_few, st.n_samples, st.n_shadowed);
        CHECK_INT_EQ(st.n_fitted, W * H);
        CHECK_INT_EQ(st.n_hidden, 0);
        CHECK_INT_EQ(st.n_shadowed, 0);                 /* flat: nothing casts a shadow */
        CHECK_INT_EQ(st.n_samples, (long) W * H * NL);
        int bad = 0;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        const struct imp_btf_texel *t = &tex[v * W + u];
                        double x = origin[0] + u * pitch;
                        if (fabs(x - hv.split_x) < 2.0 * pitch)
                                continue;       /* bilinear taps straddle the boundary */
                        const struct imp_lafortune *m = x < hv.split_x ? &materials[0] : &materials[1];
                        for (int c = 0; c < 3; c++)
                                bad += !(fabs(t->rho_d[c] - m->rho_d[c]) <= 0.05 * m->rho_d[c]);  /* 5 % each */
                        bad += m->rho_s[0] == 0.0f ? !(t->flags & IMP_BTF_MATTE) : !!(t->flags & IMP_BTF_MATTE);
                }
        fprintf(stderr, "grid: %d texel checks off\n", bad);
        CHECK_LE(bad, 0.01 * W * H);                    /* ≤ 1 % of checks off */
        for (int j = 0; j < NL; j++)
                imp_image_free(frames[j]);
}

/* The driver fuses extraction and fit in one parallel loop (imp_btf_extractor): its
 * texels must be byte for byte those of the tile-wise path it replaced — extract a tile
 * with imp_btf_samples_extract(), fit each texel, default lobe for hidden and masked
 * texels, then imp_btf_fill() — on a relief that shadows and hides texels. */
static void test_grid_fused_equals_tiles(void) {
        enum { W = 48, H = 36, NL = 48, T = 16 };
        const double pitch = 0.05, origin[3] = { -1.2, -0.9, 0 };
        static float height[W * H], normal[3 * W * H];
        static uint8_t mask[W * H];
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        /* a ridge 0.8 mm high along v (long shadows from the 15° ring) */
                        double x = (u - 20) * pitch, hgt = 0.8 * exp(-x * x / 0.02);
                        height[v * W + u] = (float) hgt;
                        double g = -2.0 * x / 0.02 * hgt, n = sqrt(1 + g * g);
                        normal[3 * (v * W + u)] = (float) (-g / n);
                        normal[3 * (v * W + u) + 2] = (float) (1 / n);
                        mask[v * W + u] = !(u < 3 && v < 3);   /* a masked corner */
                }
        struct imp_btf_heightfield hf = { .width = W, .height = H, .pitch_mm = pitch, .height_mm = height,
                                          .normal = normal, .mask = mask,
                                          .canvas_to_world = { 1, 0, 0, origin[0], 0, 1, 0, origin[1],
                                                               0, 0, 1, origin[2], 0, 0, 0, 1 } };
        struct imp_pinhole cam;
        const double eye[3] = { 150, 0, 300 }, target[3] = { 0, 0, 0 };   /* oblique: hides texels */
        synth_camera(&cam, eye, target, 160, 120, 4000.0);
        struct halves hv = { 0.0 };
        struct imp_image *frames[NL] = { 0 };
        struct imp_btf_capture cap;
        struct imp_btf_sample_params sp;
        struct imp_btf_fit_params fp;
        halves_capture(&cam, &hv, 7, frames, NL, &cap, &sp, &fp);
        static struct imp_btf_texel fused[W * H], tiles[W * H];
        struct imp_btf_stats st;
        CHECK_OK(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 0, fused, &st));

        struct imp_btf_samples *smp = NULL;
        CHECK_OK(imp_btf_samples_new(T * T, NL, &smp));
        long n_samples = 0, n_shadowed = 0;
        for (int y0 = 0; y0 < H && smp; y0 += T)
                for (int x0 = 0; x0 < W; x0 += T) {
                        int w = IMP_MIN(T, W - x0), h = IMP_MIN(T, H - y0);
                        CHECK_OK(imp_btf_samples_extract(&hf, &cap, &sp, x0, y0, w, h, smp));
                        for (int i = 0; i < w * h; i++) {
                                struct imp_btf_texel *t = &tiles[(y0 + i / w) * W + x0 + i % w];
                                n_samples += smp->count[i];
                                n_shadowed += smp->n_shadowed[i];
                                if (smp->flags[i] & (IMP_BTF_MASKED | IMP_BTF_HIDDEN)) {
                                        *t = (struct imp_btf_texel) { .cx = -1, .cy = -1, .cz = 1,
                                                                      .k = (float) fp.k_default, .flags = smp->flags[i] };
                                        continue;
                                }
                                CHECK_OK(imp_btf_fit_texel(smp->samples + (size_t) i * smp->max_per_texel, smp->count[i],
                                                           &fp, t));
                                t->flags |= smp->flags[i];
                        }
                }
        imp_btf_samples_free(smp);
        CHECK(imp_btf_fill(tiles, W, H) >= 0);
        fprintf(stderr, "fused vs tiles: samples %ld / %ld, shadowed %ld / %ld, hidden %ld, masked %ld\n", st.n_samples,
                n_samples, st.n_shadowed, n_shadowed, st.n_hidden, st.n_masked);
        CHECK_INT_EQ(st.n_samples, n_samples);
        CHECK_INT_EQ(st.n_shadowed, n_shadowed);
        CHECK(st.n_shadowed > 0);                        /* the ridge shadows */
        CHECK(st.n_hidden > 0);                          /* and hides from the oblique camera */
        CHECK_INT_EQ(st.n_masked, 9);
        int differ = 0;
        for (int i = 0; i < W * H; i++)
                differ += memcmp(&fused[i], &tiles[i], sizeof fused[i]) != 0;
        CHECK_INT_EQ(differ, 0);
        for (int j = 0; j < NL; j++)
                imp_image_free(frames[j]);
}

/* The selection behind the robust scale counts ranks 16 candidates at a time, ties
 * broken by position: against a quickselect on arrays of 1..130 values drawn from a few
 * levels (many ties, blocks of 16 crossed), every k. Exact equality. */
static void test_kth_smallest(void) {
        enum { NMAX = 130 };
        float v[NMAX], copy[NMAX];
        uint64_t rng = 7;
        int wrong = 0, checked = 0;
        for (int n = 1; n <= NMAX; n++)
                for (int levels = 1; levels <= 64; levels *= 4) {
                        for (int i = 0; i < n; i++)
                                v[i] = (float) (int) (levels * synth_uniform(&rng)) * 0.25f;
                        for (int k = 0; k < n; k++) {
                                memcpy(copy, v, n * sizeof *v);
                                float want = imp_select_kth_float(copy, (size_t) n, (size_t) k);
                                float got = imp_btf_kth_smallest(v, n, k);
                                wrong += got != want;
                                checked++;
                        }
                }
        CHECK_INT_EQ(wrong, 0);
        CHECK_INT_EQ(checked, 4 * NMAX * (NMAX + 1) / 2);
        CHECK(isnan(imp_btf_kth_smallest(v, 5, 5)));
        CHECK(isnan(imp_btf_kth_smallest(v, 0, 0)));
}

/* Samples that cannot enter the fit (a non-finite field, E cos θl ≤ 0, the light at or
 * below the horizon) are dropped: interleaved with the usable ones they give the texel of
 * the usable ones alone, byte for byte (the all-usable case takes the vector loading
 * path, the other the compacting one). Per material, at 8 texel positions. */
static void test_unusable_samples_dropped(void) {
        enum { NS = 48 };
        struct imp_btf_sample s[NS], mixed[2 * NS];
        struct imp_btf_fit_params fp;
        imp_btf_fit_params_default(&fp);
        uint64_t rng = 11;
        int differ = 0, fitted = 0;
        for (int m = 0; m < 3; m++)
                for (int pos = 0; pos < 8; pos++) {
                        const double P[3] = { -100.0 + 25.0 * pos, 40.0 - 10.0 * pos, 0 }, up[3] = { 0, 0, 1 };
                        int n = synth_samples(P, up, eye_top, lights, NS, &materials[m], NOISE_REL, &rng, s);
                        int k = 0;
                        for (int i = 0; i < n; i++) {
                                mixed[k++] = s[i];
                                struct imp_btf_sample bad = s[i];
                                switch (i % 5) {
                                case 0: bad.value[i % 3] = NAN; break;
                                case 1: bad.e_cos = 0.0f; break;
                                case 2: bad.l[2] = -0.1f; break;
                                case 3: bad.v[i % 3] = INFINITY; break;
                                default: bad.l[i % 2] = -INFINITY; break;
                                }
                                if (i % 2)
                                        mixed[k++] = bad;
                        }
                        struct imp_btf_texel a, b;
                        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &a));
                        CHECK_OK(imp_btf_fit_texel(mixed, k, &fp, &b));
                        CHECK_INT_EQ(b.n_samples, n);
                        differ += memcmp(&a, &b, sizeof a) != 0;
                        fitted += !(a.flags & (IMP_BTF_MATTE | IMP_BTF_FEW_SAMPLES));
                }
        CHECK_INT_EQ(differ, 0);
        CHECK_INT_GE(fitted, 8);      /* the lobe path ran, not only the matte one */
}

/* The fit pads a texel's samples to whole vectors with samples that add exact zeros:
 * a texel fitted right after another with more samples (whose geometry and values are
 * left in the workspace past this texel's samples) is the texel fitted after another one,
 * byte for byte, for every sample count modulo 16, per material. */
static void test_padding_adds_nothing(void) {
        struct imp_btf_sample s[48], big[2][2 * 48];
        struct imp_btf_fit_params fp;
        imp_btf_fit_params_default(&fp);
        uint64_t rng = 99;
        const double up[3] = { 0, 0, 1 }, eye2[2][3] = { { -150, 80, 300 }, { 120, 140, 250 } };
        const double Pb[2][3] = { { 20, -30, 0 }, { -110, 90, 0 } };
        int nb[2];
        for (int v = 0; v < 2; v++) {           /* two unlike texels: glossy and bright matte */
                const struct imp_lafortune *mb = &materials[v ? 0 : 2];
                nb[v] = synth_samples(Pb[v], up, eye_top, lights, 48, mb, NOISE_REL, &rng, big[v]);
                nb[v] += synth_samples(Pb[v], up, eye2[v], lights, 48, mb, NOISE_REL, &rng, big[v] + nb[v]);
                for (int i = 0; i < nb[v]; i++)
                        for (int c = 0; c < 3; c++)
                                big[v][i].value[c] *= v ? 3.0f : 0.5f;
        }
        int differ = 0, fitted = 0, cases = 0;
        for (int m = 0; m < 3; m++)
                for (int rem = 1; rem < 16; rem++) {
                        const double P[3] = { -90.0 + 12.0 * rem, 30.0 - 5.0 * rem, 0 };
                        int n = synth_samples(P, up, eye_top, lights, 48, &materials[m], NOISE_REL, &rng, s);
                        n = IMP_MIN(n, 32 + rem);
                        if (n % 16 == 0 || n >= nb[0] || n >= nb[1])
                                continue;
                        struct imp_btf_texel a, b, poison;
                        CHECK_OK(imp_btf_fit_texel(big[0], nb[0], &fp, &poison));
                        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &a));
                        CHECK_OK(imp_btf_fit_texel(big[1], nb[1], &fp, &poison));
                        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &b));
                        differ += memcmp(&a, &b, sizeof a) != 0;
                        fitted += !(a.flags & (IMP_BTF_MATTE | IMP_BTF_FEW_SAMPLES));
                        cases++;
                }
        CHECK_INT_GE(cases, 30);
        CHECK_INT_EQ(differ, 0);
        CHECK_INT_GE(fitted, 10);     /* the lobe path ran, not only the matte one */
}

int main(void) {
        const double centre[3] = { 0, 0, 0 };
        CHECK_INT_EQ(synth_dome(lights, elev, 3, 16, 500.0, centre, 1.0, 0.0), 48);
        test_accuracy();
        test_single_viewpoint();
        test_grid_end_to_end();
        test_grid_fused_equals_tiles();
        test_kth_smallest();
        test_unusable_samples_dropped();
        test_padding_adds_nothing();
        return TEST_DONE();
}
