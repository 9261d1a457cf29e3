/* The Lanczos re-read of imp_photometric_normals() (pipeline/appearance/photometric.c) reads
 * mono frames from a copy interleaved by light, one band of texel rows at a time; 3-channel
 * frames are read as they are. Both must give the same values and decisions: the same
 * capture as mono frames and as the same frames replicated into three channels gives
 * bit-identical normals, σ and flags, on a relief over three bands whose texels run off the
 * frame's top and bottom, with invalid, saturated and non-finite pixels, coloured lights and
 * a second run with no validity masks. */
#include <string.h>
#include "btf-synth.h"
#include "photometric.h"
#include "test.h"

enum { W = 90, H = 150, CW = 120, CH = 130, NL = 24 };

static const double pitch = 0.051, eye[3] = { 0, 0, 300 };

/* Shading normal of a flat canvas with grooves of 4 pixels (as in test-photometric.c). */
static void groove_normal(double x, double y, double n[3]) {
        double g = 0.35 * cos(2 * M_PI * (x + 0.25 * y) / 0.2), l = sqrt(g * g * 1.0625 + 1);
        n[0] = -g / l, n[1] = -0.25 * g / l, n[2] = 1 / l;
}

/* Frame j of the grooved canvas at z = 0 (Lambertian, ρ 0.6, 1 % noise, a few NaN and
 * saturated pixels) as mono and as RGB (each channel the mono value), and its validity
 * mask (a few pixels flagged saturated or invalid). */
static void make_frame(const struct imp_pinhole *cam, const struct imp_rig_light *L, int j, uint64_t *rng,
                       struct imp_image **mono, struct imp_image **rgb, struct imp_image **valid) {
        CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, mono));
        CHECK_OK(imp_image_new(CW, CH, 3, IMP_PIX_F32, rgb));
        CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_U8, valid));
        for (int py = 0; py < CH; py++)
                for (int px = 0; px < CW; px++) {
                        double d[3] = { (px - cam->cx) / cam->fx, (py - cam->cy) / cam->fy, 1 }, dw[3], n[3], wl[3], r = 0;
                        for (int i = 0; i < 3; i++)
                                dw[i] = cam->R[i] * d[0] + cam->R[3 + i] * d[1] + cam->R[6 + i] * d[2];
                        double t = -eye[2] / dw[2], P[3] = { eye[0] + t * dw[0], eye[1] + t * dw[1], 0 };
                        groove_normal(P[0], P[1], n);
                        for (int i = 0; i < 3; i++) {
                                wl[i] = L[j].pos_mm[i] - P[i];
                                r += wl[i] * wl[i];
                        }
                        double c = (n[0] * wl[0] + n[1] * wl[1] + n[2] * wl[2]) / sqrt(r);
                        float v = (float) (0.6 * L[j].colour[0] * imp_btf_light_irradiance(&L[j], P) * fmax(0, c) *
                                           (1 + 0.01 * synth_gauss(rng)));
                        double q = synth_uniform(rng);
                        if (q < 0.002)
                                v = NAN;
                        else if (q < 0.004)
                                v = 2.0f;                  /* above the saturation value */
                        *imp_image_f32(*mono, px, py) = v;
                        for (int k = 0; k < 3; k++)
                                imp_image_f32(*rgb, px, py)[k] = v;
                        q = synth_uniform(rng);
                        *imp_image_u8(*valid, px, py) = q < 0.002 ? IMP_BTF_PIX_SATURATED : q < 0.004 ? IMP_BTF_PIX_INVALID : 0;
                }
}

struct result {
        float normal[3 * W * H], sigma[W * H];
        uint16_t flags[W * H];
        struct imp_photometric_stats st;
};

static void run(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap, struct result *res) {
        struct imp_btf_sample_params sp;
        struct imp_photometric_params p;
        imp_btf_sample_params_default(&sp);
        sp.saturation_value = 1.5;
        imp_photometric_params_default(&p);
        p.lanczos = 3;
        memset(res, 0, sizeof *res);
        struct imp_photometric_out po = { .normal = res->normal, .flags = res->flags, .sigma_deg = res->sigma };
        CHECK_OK(imp_photometric_normals(hf, cap, &sp, &p, &po, &res->st));
}

static void compare(const struct result *a, const struct result *b) {
        CHECK_INT_EQ(a->st.n_resampled, b->st.n_resampled);
        CHECK_INT_EQ(a->st.n_refined, b->st.n_refined);
        CHECK_INT_EQ(a->st.n_masked, b->st.n_masked);
        CHECK(memcmp(a->flags, b->flags, sizeof a->flags) == 0);
        CHECK(memcmp(a->normal, b->normal, sizeof a->normal) == 0);
        CHECK(memcmp(a->sigma, b->sigma, sizeof a->sigma) == 0);
}

int main(void) {
        struct imp_rig_light L[NL];
        static const double elev[3] = { 25, 45, 70 }, centre[3] = { 0, 0, 0 };
        CHECK_INT_EQ(synth_dome(L, elev, 3, 8, 600.0, centre, 1.0, 0.0), NL);
        for (int j = 0; j < NL; j += 3)
                L[j].colour[0] = L[j].colour[1] = L[j].colour[2] = 0.7;
        struct imp_pinhole cam;
        const double target[3] = { 0, 0, 0 };
        synth_camera(&cam, eye, target, CW, CH, 6000.0);
        uint64_t rng = 0x2545f4914f6cdd1dULL;
        struct imp_image *mono[NL], *rgb[NL], *valid[NL];
        for (int j = 0; j < NL; j++)
                make_frame(&cam, L, j, &rng, &mono[j], &rgb[j], &valid[j]);

        static float hgt[W * H], nrm[3 * W * H];
        for (int t = 0; t < W * H; t++)
                hgt[t] = 0, nrm[3 * t] = nrm[3 * t + 1] = 0, nrm[3 * t + 2] = 1;
        /* 150 rows at 0.051 mm against 130 pixels at 0.05 mm: the grid runs off the frame */
        struct imp_btf_heightfield hf = { W, H, pitch, hgt, nrm, NULL,
                                          { 1, 0, 0, -0.5 * (W - 1) * pitch, 0, 1, 0, -0.5 * (H - 1) * pitch, 0, 0, 1, 0, 0, 0, 0, 1 } };
        static struct result a, b;
        for (int masks = 1; masks >= 0; masks--) {
                const struct imp_image *const *vm = masks ? (const struct imp_image *const *) valid : NULL;
                struct imp_btf_capture cm = { &cam, L, NL, (const struct imp_image *const *) mono, vm };
                struct imp_btf_capture cr = { &cam, L, NL, (const struct imp_image *const *) rgb, vm };
                run(&hf, &cm, &a);
                run(&hf, &cr, &b);
                compare(&a, &b);
                printf("masks %d: %ld texels refined, %ld samples re-read (mono), %ld (RGB)\n", masks,
                       a.st.n_refined, a.st.n_resampled, b.st.n_resampled);
                CHECK_GE(a.st.n_refined, W * H / 2);
                CHECK_GE(a.st.n_resampled, (long) W * H * 4);
        }
        for (int j = 0; j < NL; j++) {
                imp_image_free(mono[j]);
                imp_image_free(rgb[j]);
                imp_image_free(valid[j]);
        }
        return TEST_DONE();
}
