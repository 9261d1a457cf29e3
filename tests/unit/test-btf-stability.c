/* Hard cases of the per-texel fit: grazing lights, a mirror-like lobe, a perfectly matte
 * texel, a texel lit in only three frames, every sample saturated, a black texel, garbage
 * samples. Each must give finite values in every field and an honest flag. */
#include <stdlib.h>

#include "btf.h"
#include "quality.h"
#include "unit/btf-synth.h"
#include "unit/test.h"

static struct imp_rig_light dome[48];
static const double eye[3] = { 0, 0, 300 }, n_up[3] = { 0, 0, 1 };
static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
static struct imp_btf_fit_params fp;

static void check_finite(const struct imp_btf_texel *t, const char *what) {
        for (int c = 0; c < 3; c++) {
                CHECK_FINITE(t->rho_d[c]);
                CHECK_FINITE(t->rho_s[c]);
                CHECK_GE(t->rho_d[c], 0.0);
                CHECK_GE(t->rho_s[c], 0.0);
        }
        CHECK_FINITE(t->cx);
        CHECK_FINITE(t->cy);
        CHECK_FINITE(t->cz);
        CHECK_FINITE(t->k);
        CHECK_FINITE(t->rms);
        CHECK_FINITE(t->cond);
        CHECK(t->k >= fp.k_min && t->k <= fp.k_max);
        fprintf(stderr, "%-22s: n %3d flags 0x%03x rho_d %.3f rho_s %.3g C (%.2f %.2f %.2f) k %.1f rms %.4f cond %.3g\n",
                what, t->n_samples, t->flags, t->rho_d[0], t->rho_s[0], t->cx, t->cy, t->cz, t->k, t->rms, t->cond);
}

static const struct imp_lafortune semi = { .rho_d = { 0.3f, 0.3f, 0.3f }, .rho_s = { 0.4f, 0.4f, 0.4f },
                                           .cx = -1, .cy = -1, .cz = 1, .k = 20 };

static void test_grazing(void) {
        struct imp_rig_light L[32];
        const double elev[2] = { 2, 4.5 }, c[3] = { 0, 0, 0 };
        int nl = synth_dome(L, elev, 2, 16, 500.0, c, 1.0, 0.0);
        uint64_t rng = 5;
        const double P[3] = { 40, 30, 0 };
        int n = synth_samples(P, n_up, eye, L, nl, &semi, 0.01, &rng, s);
        struct imp_btf_texel t;
        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
        check_finite(&t, "grazing (< 5°)");
        CHECK_INT_EQ(t.n_samples, 32);
        CHECK_NEAR(t.rho_d[0], 0.3, 0.3 * 0.2);         /* 20 %: grazing data, weak but usable */
}

static void test_mirror(void) {
        struct imp_lafortune m = { .rho_d = { 0.05f, 0.05f, 0.05f }, .rho_s = { 1, 1, 1 }, .cx = -1, .cy = -1,
                                   .cz = 1, .k = 400 };
        uint64_t rng = 6;
        const double positions[3][3] = { { 100, 0, 0 }, { 57, 83, 0 }, { -130, 20, 0 } };
        for (int i = 0; i < 3; i++) {
                int n = synth_samples(positions[i], n_up, eye, dome, 48, &m, 0.01, &rng, s);
                struct imp_btf_texel t;
                CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
                check_finite(&t, "mirror-like k=400");
                bool honest = (t.flags & (IMP_BTF_LOBE_UNCERTAIN | IMP_BTF_K_BOUND | IMP_BTF_MATTE)) ||
                              fabs(t.k - 400.0) <= 0.2 * 400.0;
                CHECK_MSG(honest, "k %g without an uncertainty flag (0x%x)", t.k, t.flags);
                CHECK_NEAR(t.rho_d[0], 0.05, 0.05 * 0.1);
        }
}

static void test_matte_and_black(void) {
        struct imp_lafortune m = { .rho_d = { 0.5f, 0.4f, 0.3f }, .cx = -1, .cy = -1, .cz = 1, .k = 10 };
        uint64_t rng = 7;
        const double P[3] = { 60, -40, 0 };
        int n = synth_samples(P, n_up, eye, dome, 48, &m, 0.0, &rng, s);
        struct imp_btf_texel t;
        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
        check_finite(&t, "perfectly matte");
        CHECK(t.flags & IMP_BTF_MATTE);
        CHECK_NEAR(t.rho_s[0], 0.0, 0.0);
        CHECK_NEAR(t.rho_d[0], 0.5, 1e-4);

        struct imp_lafortune black = { .cx = -1, .cy = -1, .cz = 1, .k = 10 };
        n = synth_samples(P, n_up, eye, dome, 48, &black, 0.01, &rng, s);
        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
        check_finite(&t, "black");
        CHECK(t.flags & IMP_BTF_MATTE);
        CHECK_NEAR(t.rho_d[0], 0.0, 1e-6);

        /* Black with additive noise (negative values): clamped at 0, MATTE. */
        for (int i = 0; i < n; i++)
                for (int c = 0; c < 3; c++)
                        s[i].value[c] = (float) (0.001 * synth_gauss(&rng));
        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
        check_finite(&t, "black + noise");
        CHECK(t.flags & IMP_BTF_MATTE);
        CHECK_LE(t.rho_d[0], 0.002);
}

/* Nothing non-physical passes silently: paint reflecting 1.6× the light (a wrong light
 * intensity, a calibration slip) is fitted, finite, and flagged FIT_FAILED, which the
 * copy's texel flags carry; the same paint at 0.5 is not flagged; a k bound ≤ 0 is refused. */
static void test_non_physical(void) {
        struct imp_lafortune ok = { .rho_d = { 0.5f, 0.5f, 0.5f }, .rho_s = { 0.1f, 0.1f, 0.1f },
                                    .cx = -1, .cy = -1, .cz = 1, .k = 20 };
        struct imp_lafortune bright = ok;
        for (int c = 0; c < 3; c++)
                bright.rho_d[c] = 1.6f;
        uint64_t rng = 5;
        const double P[3] = { 10, 20, 0 };
        struct imp_btf_texel t;
        int n = synth_samples(P, n_up, eye, dome, 48, &ok, 0.005, &rng, s);
        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
        check_finite(&t, "physical");
        CHECK(!(t.flags & IMP_BTF_FIT_FAILED));
        CHECK(!(imp_btf_texel_flags(t.flags) & IMP_TEXEL_FIT_FAILED));
        n = synth_samples(P, n_up, eye, dome, 48, &bright, 0.005, &rng, s);
        CHECK_OK(imp_btf_fit_texel(s, n, &fp, &t));
        check_finite(&t, "ρd 1.6");
        CHECK(t.rho_d[0] > 1.0f);
        CHECK(t.flags & IMP_BTF_FIT_FAILED);
        CHECK(imp_btf_texel_flags(t.flags) & IMP_TEXEL_FIT_FAILED);
        CHECK_INT_EQ(imp_btf_texel_flags(IMP_BTF_MASKED | IMP_BTF_FIT_FAILED), 0);
        struct imp_btf_fit_params bad = fp;
        bad.k_min = 0;
        CHECK_ERR(imp_btf_fit_texel(s, n, &bad, &t), -EINVAL);
        bad.k_min = -1;
        CHECK_ERR(imp_btf_fit_texel(s, n, &bad, &t), -EINVAL);
}

static void test_few(void) {
        uint64_t rng = 8;
        const double P[3] = { 60, -40, 0 };
        int n = synth_samples(P, n_up, eye, dome, 48, &semi, 0.01, &rng, s);
        CHECK_INT_EQ(n, 48);
        struct imp_btf_texel t;
        CHECK_OK(imp_btf_fit_texel(s + 20, 3, &fp, &t));   /* lit in three frames only */
        check_finite(&t, "three samples");
        CHECK_INT_EQ(t.flags, IMP_BTF_FEW_SAMPLES);
        CHECK_INT_EQ(t.n_samples, 3);
        CHECK_OK(imp_btf_fit_texel(s, 0, &fp, &t));
        check_finite(&t, "no samples");
        CHECK_INT_EQ(t.flags, IMP_BTF_FEW_SAMPLES);

        /* Garbage samples are ignored, not propagated. */
        for (int i = 0; i < 10; i++) {
                s[i].value[0] = NAN;
                s[10 + i].e_cos = 0.0f;
                s[20 + i].l[2] = -0.1f;
                s[30 + i].v[1] = INFINITY;
        }
        CHECK_OK(imp_btf_fit_texel(s, 48, &fp, &t));
        check_finite(&t, "garbage mixed in");
        CHECK_INT_EQ(t.n_samples, 8);

        CHECK_ERR(imp_btf_fit_texel(s, IMP_BTF_MAX_SAMPLES + 1, &fp, &t), -E2BIG);
        struct imp_btf_fit_params bad = fp;
        bad.k_min = 0.0;
        CHECK_ERR(imp_btf_fit_texel(s, 10, &bad, &t), -EINVAL);
}

/* Every pixel saturated: no samples anywhere, SATURATED | FEW_SAMPLES, nothing to fill from. */
static void test_all_saturated(void) {
        enum { GW = 3, GH = 3, CAMPX = 32 };
        static float h[GW * GH], nrm[3 * GW * GH];
        for (int i = 0; i < GW * GH; i++)
                nrm[3 * i + 2] = 1.0f;
        struct imp_btf_heightfield hf = { .width = GW, .height = GH, .pitch_mm = 0.5, .height_mm = h, .normal = nrm,
                                          .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 } };
        struct imp_pinhole cam;
        const double target[3] = { 0.5, 0.5, 0 };
        synth_camera(&cam, eye, target, CAMPX, CAMPX, 2000.0);
        struct imp_image *frames[48] = { 0 };
        for (int j = 0; j < 48; j++) {
                CHECK_OK(imp_image_new(CAMPX, CAMPX, 1, IMP_PIX_F32, &frames[j]));
                for (int y = 0; y < CAMPX; y++)
                        for (int x = 0; x < CAMPX; x++)
                                *imp_image_f32(frames[j], x, y) = 4.0f;
        }
        struct imp_btf_capture cap = { .camera = &cam, .lights = dome, .n_lights = 48,
                                       .frames = (const struct imp_image *const *) frames };
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        sp.saturation_value = 4.0;
        struct imp_btf_texel tex[GW * GH];
        struct imp_btf_stats st;
        CHECK_OK(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 0, tex, &st));
        for (int i = 0; i < GW * GH; i++) {
                check_finite(&tex[i], "all saturated");
                CHECK_INT_EQ(tex[i].flags, IMP_BTF_FEW_SAMPLES | IMP_BTF_SATURATED);
                CHECK_INT_EQ(tex[i].n_samples, 0);
        }
        CHECK_INT_EQ(st.n_few, GW * GH);
        for (int j = 0; j < 48; j++)
                imp_image_free(frames[j]);
}

/* A hole of FEW_SAMPLES texels is filled from its ring, inwards. */
static void test_fill(void) {
        enum { FW = 7, FH = 7 };
        struct imp_btf_texel t[FW * FH];
        for (int i = 0; i < FW * FH; i++) {
                int u = i % FW, v = i / FW;
                bool hole = u >= 2 && u <= 4 && v >= 2 && v <= 4;
                t[i] = (struct imp_btf_texel) { .rho_d = { 0.4f, 0.4f, 0.4f }, .rho_s = { 0.2f, 0.2f, 0.2f },
                        .cx = -1, .cy = -1, .cz = 1, .k = 20, .rms = 0.01f, .cond = 5, .n_samples = 40 };
                if (hole)
                        t[i] = (struct imp_btf_texel) { .cx = -1, .cy = -1, .cz = 1, .k = 10,
                                                         .flags = IMP_BTF_FEW_SAMPLES };
        }
        t[0].flags = IMP_BTF_MASKED;
        t[0].rho_d[0] = 0.0f;
        CHECK_INT_EQ(imp_btf_fill(t, FW, FH), 9);
        for (int v = 2; v <= 4; v++)
                for (int u = 2; u <= 4; u++) {
                        const struct imp_btf_texel *q = &t[v * FW + u];
                        check_finite(q, "filled");
                        CHECK_INT_EQ(q->flags, IMP_BTF_FEW_SAMPLES | IMP_BTF_FILLED);
                        CHECK_NEAR(q->rho_d[0], 0.4, 1e-6);
                        CHECK_NEAR(q->k, 20.0, 1e-3);
                }
        CHECK_INT_EQ(t[0].flags, IMP_BTF_MASKED);
}

int main(void) {
        const double elev[3] = { 15, 35, 60 }, c[3] = { 0, 0, 0 };
        synth_dome(dome, elev, 3, 16, 500.0, c, 1.0, 0.0);
        imp_btf_fit_params_default(&fp);
        test_grazing();
        test_mirror();
        test_matte_and_black();
        test_few();
        test_all_saturated();
        test_fill();
        test_non_physical();
        return TEST_DONE();
}
