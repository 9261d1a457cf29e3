/* The extractor's shadow and camera rays (btf-samples.c: the horizon's two parts, the
 * march started short of or stopped past IMP_BTF_HORIZON_SPLIT texels of run, the max
 * pyramid's skips) against the plain march (imp_btf_heightfield_ray: every sample point
 * from the texel on, no pyramid), on a relief of one-texel ridges along both axes and a
 * diagonal, sparse tall spikes, a cliff and noise, lit by point lights down to 2° of elevation all
 * around and seen by an oblique camera: every decision an extraction records (struct
 * imp_btf_rays) is the plain march's. The relief has blocked rays that a march started
 * one texel of run past the split (of those the near part lets start there) or stopped one
 * texel short of it (of those the far part lets stop there) would find clear: a start or a
 * stop one texel more aggressive changes decisions, and this test sees it. */
#include <stdlib.h>

#include "btf.h"
#include "unit/btf-synth.h"
#include "unit/test.h"

enum { W = 96, H = 84, RINGS = 20, NL = 24 * RINGS, CW = 64, CH = 64 };
#define PITCH 0.05

static float height[W * H], normal[3 * W * H];
static struct imp_rig_light lights[NL];
static struct imp_image *frames[NL];

static void setup_relief(struct imp_btf_heightfield *hf, uint64_t *rng) {
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        double h = 0.05 * sin(u / 5.0) * cos(v / 7.0) + 0.01 * synth_uniform(rng);
                        if (u % 17 == 3)
                                h += 0.04 + 0.04 * synth_uniform(rng);   /* one-texel ridges along v */
                        if (v % 13 == 5)
                                h += 0.03 + 0.04 * synth_uniform(rng);   /* … along u */
                        if (u - v == 20 || u - v == 21)
                                h += 0.06;                               /* a diagonal ridge */
                        if (u >= 70 && v >= 50)
                                h += 0.1;                                /* a cliff */
                        if (synth_uniform(rng) < 0.004)
                                h += 0.3 + 0.4 * synth_uniform(rng);     /* sparse spikes */
                        height[v * W + u] = (float) h;
                        normal[3 * (v * W + u) + 2] = 1.0f;
                }
        *hf = (struct imp_btf_heightfield) { .width = W, .height = H, .pitch_mm = PITCH, .height_mm = height,
                .normal = normal, .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 } };
}

struct counts {
        long rays, blocked, wrong, near_only, far_only, start_edge, stop_edge;
};

/* One decision of the extraction against the plain march of the same ray (the extractor's
 * operations: w = target − P, r = |w|, d = w / r); the edges count the blocked rays a
 * march would find clear if it started a texel of run past the split when the near part
 * clears the ray before it, or stopped a texel short of the split when the far part clears
 * it after (the march of a more aggressive split). */
static void check(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *sp, double hmax,
                  const float near[4], const float far[4], const double P[3], const double target[3], bool got,
                  struct counts *c) {
        double w[3] = { target[0] - P[0], target[1] - P[1], target[2] - P[2] };
        double r = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]), d[3] = { w[0] / r, w[1] / r, w[2] / r }, t = 0;
        bool ref = imp_btf_heightfield_ray(hf, sp, hmax, P, d, r, &t);
        double run = sqrt(d[0] * d[0] + d[1] * d[1]), s = t * run / PITCH;
        int q = (d[0] < 0.0) | (d[1] < 0.0) << 1;
        bool n = d[2] >= (double) near[q] * run, f = d[2] >= (double) far[q] * run;
        c->rays++;
        c->blocked += ref;
        c->near_only += n && !f;
        c->far_only += f && !n;
        if (ref && n && !f) {
                /* the march from the first sample point a texel of run past the split */
                double step = sp->march_step_texels * PITCH;
                double t1 = ceil((IMP_BTF_HORIZON_SPLIT + 1) * PITCH / (run * step)) * step;
                const double o1[3] = { P[0] + t1 * d[0], P[1] + t1 * d[1], P[2] + t1 * d[2] };
                c->start_edge += t1 < r && !imp_btf_heightfield_ray(hf, sp, hmax, o1, d, r - t1, NULL);
        }
        if (ref && f && !n)   /* the march stopped a texel of run short of the split */
                c->stop_edge += !imp_btf_heightfield_ray(hf, sp, hmax, P, d, (IMP_BTF_HORIZON_SPLIT - 1) * PITCH / run,
                                                         NULL);
        if (got != ref && c->wrong++ < 5)
                fprintf(stderr, "P (%.3f %.3f %.4f) d (%.6f %.6f %.6f): extraction %d, march %d (hit at %.3f texels)\n",
                        P[0], P[1], P[2], d[0], d[1], d[2], got, ref, s);
}

static void test_decisions(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                           const double eye[3]) {
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        _cleanup_(imp_btf_rays_freep) struct imp_btf_rays *rays = NULL;
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        _cleanup_(imp_btf_horizon_freep) struct imp_btf_horizon *hz = NULL;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
        CHECK_OK(imp_btf_rays_new(W, H, NL, &rays));
        sp.rays = rays;
        sp.rays_mode = IMP_BTF_RAYS_RECORD;
        CHECK_OK(imp_btf_hf_pyramid_new(hf, &py));
        CHECK_OK(imp_btf_horizon_new(hf, 0.0, &hz));   /* the pyramid's */
        CHECK_OK(imp_btf_extractor_new(hf, cap, &sp, py, &x));
        _cleanup_free_ struct imp_btf_sample *out = malloc(NL * sizeof *out);
        CHECK(out);
        const double hmax = imp_btf_heightfield_hmax(hf);
        struct counts lc = {}, cc = {};
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        uint16_t flags, shadowed;
                        (void) imp_btf_extract_texel(x, u, v, out, &flags, &shadowed);
                        const size_t i = (size_t) v * W + u;
                        const double P[3] = { u * PITCH, v * PITCH, height[i] };
                        float near[4], far[4];
                        CHECK(imp_btf_horizon_split(hz, u, v, near, far));
                        if (rays->camera[i] != IMP_BTF_CAM_UNKNOWN)
                                check(hf, &sp, hmax, near, far, P, eye, rays->camera[i] == IMP_BTF_CAM_BLOCKED, &cc);
                        for (int j = 0; j < NL; j++) {
                                uint64_t bit = (uint64_t) 1 << (j & 63);
                                const uint64_t *kn = rays->known + i * rays->words, *bl = rays->blocked + i * rays->words;
                                if (kn[j >> 6] & bit)
                                        check(hf, &sp, hmax, near, far, P, lights[j].pos_mm, bl[j >> 6] & bit, &lc);
                        }
                }
        fprintf(stderr, "light rays: %ld decided, %ld blocked, %ld wrong; near part only %ld, far part only %ld; "
                "clear for a march a texel past the split %ld, short of it %ld\n", lc.rays, lc.blocked, lc.wrong,
                lc.near_only, lc.far_only, lc.start_edge, lc.stop_edge);
        fprintf(stderr, "camera rays: %ld decided, %ld blocked, %ld wrong; near only %ld, far only %ld; edges %ld, %ld\n",
                cc.rays, cc.blocked, cc.wrong, cc.near_only, cc.far_only, cc.start_edge, cc.stop_edge);
        CHECK_INT_EQ(lc.wrong, 0);
        CHECK_INT_EQ(cc.wrong, 0);
        /* Most texels decided every light; the cases the split serves occur. */
        CHECK_INT_GE(lc.rays, (long) W * H * NL / 2);
        CHECK_INT_GE(lc.blocked, lc.rays / 50);
        CHECK_INT_GE(lc.near_only, 1000);
        CHECK_INT_GE(lc.far_only, 1000);
        CHECK_INT_GE(lc.start_edge, 10);
        CHECK_INT_GE(lc.stop_edge, 3);
        CHECK_INT_GE(cc.rays, (long) W * H / 2);
        CHECK_INT_GE(cc.blocked, 20);
}

int main(void) {
        uint64_t rng = 0x2545f4914f6cdd1dULL;
        const double centre[3] = { 0.5 * W * PITCH, 0.5 * H * PITCH, 0 };
        double elev[RINGS];
        for (int i = 0; i < RINGS; i++)
                elev[i] = 2.0 + 2.0 * i + 0.37 * (i % 3);   /* 2° to ≈ 40°, dense: grazing rays at many slopes */
        CHECK_INT_EQ(synth_dome(lights, elev, RINGS, 24, 400.0, centre, 1.0, 0.0), NL);
        struct imp_btf_heightfield hf;
        setup_relief(&hf, &rng);
        struct imp_pinhole cam;
        /* oblique: ≈ 30° above the canvas, from −u */
        const double eye[3] = { centre[0] - 260.0, centre[1] + 40.0, 150.0 };
        synth_camera(&cam, eye, centre, CW, CH, 700.0);
        for (int j = 0; j < NL; j++) {
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, &frames[j]));
                for (int y = 0; y < CH; y++)
                        for (int x = 0; x < CW; x++)
                                *imp_image_f32(frames[j], x, y) = 0.5f;
        }
        struct imp_btf_capture cap = { .camera = &cam, .lights = lights, .n_lights = NL,
                                       .frames = (const struct imp_image *const *) frames };
        test_decisions(&hf, &cap, eye);
        for (int j = 0; j < NL; j++)
                imp_image_free(frames[j]);
        return TEST_DONE();
}
