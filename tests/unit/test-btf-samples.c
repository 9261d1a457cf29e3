/* Radiance sample extraction: near-field irradiance and local directions against hand
 * computation, self-shadow rejection behind a tall step (count equal to the geometric
 * count), the ray's refined hit point, HIDDEN behind a wall, saturation flags. */
#include <stdlib.h>

#include "btf.h"
#include "hdr.h"
#include "unit/btf-synth.h"
#include "unit/test.h"

enum { W = 200, H = 100, NL = 48, CAM = 64 };
#define PITCH 0.5
#define STEP_U 120                     /* heights 10 mm from this column on */
#define STEP_H 10.0
#define TEX_U 110                      /* the test texel: 5 mm in front of the step */
#define TEX_V 50

static float height[W * H], normal[3 * W * H];
static struct imp_rig_light lights[NL];
static struct imp_image *frames[NL], *valid[NL];

static void setup_heightfield(struct imp_btf_heightfield *hf) {
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        height[v * W + u] = u >= STEP_U ? STEP_H : 0.0f;
                        normal[3 * (v * W + u) + 2] = 1.0f;
                }
        /* The test texel sits at the world origin, under the dome centre. */
        *hf = (struct imp_btf_heightfield) { .width = W, .height = H, .pitch_mm = PITCH, .height_mm = height,
                .normal = normal, .canvas_to_world = { 1, 0, 0, -TEX_U * PITCH, 0, 1, 0, -TEX_V * PITCH,
                                                       0, 0, 1, 0, 0, 0, 0, 1 } };
}

static void test_irradiance(void) {
        struct imp_rig_light L = { .pos_mm = { 0, 0, 500 }, .intensity = 2.0, .axis = { 0, 0, -1 }, .profile_exp = 2 };
        const double X[3] = { 100, 0, 0 };
        double r2 = 100.0 * 100.0 + 500.0 * 500.0, c = 500.0 / sqrt(r2);
        CHECK_NEAR(imp_btf_light_irradiance(&L, X), 2.0 * 1e6 / r2 * c * c, 1e-12);
        L.profile_exp = 0.0;
        CHECK_NEAR(imp_btf_light_irradiance(&L, X), 2.0 * 1e6 / r2, 1e-12);
        L.axis[2] = 1.0;                                /* pointing away: no light */
        L.profile_exp = 1.0;
        CHECK_NEAR(imp_btf_light_irradiance(&L, X), 0.0, 0.0);
}

/* Geometric count of the lights the step hides from canvas point P: the surface profile
 * is 0 up to x0 − pitch, rises linearly to STEP_H at x0 and stays there, so a straight ray
 * passes below it iff it is below STEP_H where it crosses x0 inside the grid. */
static int expected_unblocked(const double P[3], const double Lc[NL][3], double bias) {
        double x0 = STEP_U * PITCH, ymax = (H - 1) * PITCH;
        int n = 0;
        for (int j = 0; j < NL; j++) {
                double d[3] = { Lc[j][0] - P[0], Lc[j][1] - P[1], Lc[j][2] - P[2] };
                bool blocked = false;
                if (d[0] > 0.0) {
                        double s = (x0 - P[0]) / d[0], y = P[1] + s * d[1], z = P[2] + s * d[2];
                        if (y >= 0.0 && y <= ymax) {
                                CHECK_MSG(fabs(z - STEP_H) > 0.5, "light %d grazes the step edge (z %g)", j, z);
                                blocked = z < STEP_H - bias;
                        }
                }
                n += !blocked;
        }
        return n;
}

static void test_shadows(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                         const struct imp_btf_sample_params *sp) {
        _cleanup_btf_samples_ struct imp_btf_samples *s = NULL;
        CHECK_OK(imp_btf_samples_new(4, NL, &s));
        double Lc[NL][3];
        for (int j = 0; j < NL; j++) {
                Lc[j][0] = lights[j].pos_mm[0] + TEX_U * PITCH;
                Lc[j][1] = lights[j].pos_mm[1] + TEX_V * PITCH;
                Lc[j][2] = lights[j].pos_mm[2];
        }
        const double P[3] = { TEX_U * PITCH, TEX_V * PITCH, 0.0 };
        int expect = expected_unblocked(P, Lc, sp->shadow_bias_texels * PITCH);
        CHECK_OK(imp_btf_samples_extract(hf, cap, sp, TEX_U, TEX_V, 1, 1, s));
        fprintf(stderr, "texel (%d, %d): %d samples, %d shadowed, expected %d unshadowed\n", TEX_U, TEX_V,
                s->count[0], s->n_shadowed[0], expect);
        CHECK(expect > 0 && expect < NL);               /* the step hides some lights, not all */
        CHECK_INT_EQ(s->count[0], expect);
        CHECK_INT_EQ(s->n_shadowed[0], NL - expect);
        CHECK_INT_EQ(s->flags[0], 0);

        /* The refined hit of a horizontal ray along +x on the flat: where the ramp in
         * front of the step first exceeds the bias (bisection to step / 2^8). */
        const double d[3] = { 1, 0, 0 }, o[3] = { P[0], P[1], 0.0 };
        double t = -1.0, bias = sp->shadow_bias_texels * PITCH;
        CHECK(imp_btf_heightfield_ray(hf, sp, STEP_H, o, d, 1000.0, &t));
        double x_hit = STEP_U * PITCH - PITCH + bias / STEP_H * PITCH;
        CHECK_NEAR(t, x_hit - P[0], sp->march_step_texels * PITCH / 256.0 + 1e-9);
        const double up[3] = { 0, 0, 1 };
        CHECK(!imp_btf_heightfield_ray(hf, sp, STEP_H, o, up, 1000.0, NULL));

        /* An unshadowed texel far from the step: all lights, and the numbers by hand. */
        CHECK_OK(imp_btf_samples_extract(hf, cap, sp, 10, TEX_V, 1, 1, s));
        CHECK_INT_EQ(s->count[0], NL);
        const double Q[3] = { 10 * PITCH, TEX_V * PITCH, 0.0 };
        const double Qw[3] = { Q[0] - TEX_U * PITCH, Q[1] - TEX_V * PITCH, 0.0 };
        for (int j = 0; j < NL; j += 7) {
                const struct imp_btf_sample *q = &s->samples[j];
                double w[3] = { Lc[j][0] - Q[0], Lc[j][1] - Q[1], Lc[j][2] - Q[2] };
                double r = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
                for (int i = 0; i < 3; i++)
                        CHECK_NEAR(q->l[i], w[i] / r, 1e-6);   /* flat: local frame = canvas frame */
                double E = lights[j].intensity * 1e6 / (r * r);
                CHECK_NEAR(q->e_cos, E * w[2] / r, 1e-6 * E);
                CHECK_NEAR(q->value[0], 0.5, 1e-6);
                double vw[3] = { -Qw[0], -Qw[1], 300.0 }, vr = sqrt(vw[0] * vw[0] + vw[1] * vw[1] + vw[2] * vw[2]);
                CHECK_NEAR(q->v[0], vw[0] / vr, 1e-6);
                CHECK_NEAR(q->v[2], vw[2] / vr, 1e-6);
        }

        /* Frame 3 saturated: the sample is dropped and the texel flagged. */
        for (int y = 0; y < CAM; y++)
                memset(imp_image_row(valid[3], y), IMP_BTF_PIX_SATURATED, CAM);
        CHECK_OK(imp_btf_samples_extract(hf, cap, sp, 10, TEX_V, 1, 1, s));
        CHECK_INT_EQ(s->count[0], NL - 1);
        CHECK(s->flags[0] & IMP_BTF_SATURATED);
        for (int y = 0; y < CAM; y++)
                memset(imp_image_row(valid[3], y), 0, CAM);
}

/* A camera low over the step: the texel in front of it is HIDDEN, one on top is not. */
static void test_hidden(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *sp) {
        struct imp_pinhole cam;
        const double eye[3] = { 200, 0, 100 }, target[3] = { 0, 0, 0 };
        synth_camera(&cam, eye, target, CAM, CAM, 40.0);
        struct imp_btf_capture cap = { .camera = &cam, .lights = lights, .n_lights = NL,
                                       .frames = (const struct imp_image *const *) frames };
        _cleanup_btf_samples_ struct imp_btf_samples *s = NULL;
        CHECK_OK(imp_btf_samples_new(4, NL, &s));
        CHECK_OK(imp_btf_samples_extract(hf, &cap, sp, TEX_U, TEX_V, 1, 1, s));
        CHECK_INT_EQ(s->flags[0], IMP_BTF_HIDDEN);
        CHECK_INT_EQ(s->count[0], 0);
        CHECK_OK(imp_btf_samples_extract(hf, &cap, sp, STEP_U + 10, TEX_V, 1, 1, s));
        CHECK(!(s->flags[0] & IMP_BTF_HIDDEN));
        CHECK_INT_GE(s->count[0], 1);

        /* Error paths: a tile outside the grid, a too small buffer, a non-rigid transform. */
        CHECK_ERR(imp_btf_samples_extract(hf, &cap, sp, W - 1, 0, 2, 1, s), -EINVAL);
        CHECK_ERR(imp_btf_samples_extract(hf, &cap, sp, 0, 0, 3, 2, s), -E2BIG);
        struct imp_btf_heightfield bad = *hf;
        bad.canvas_to_world[0] = 2.0;
        CHECK_ERR(imp_btf_samples_extract(&bad, &cap, sp, 0, 0, 1, 1, s), -EINVAL);
}

/* Validity images from HDR merge flags: any channel SATURATED → PIX_SATURATED, any DARK →
 * PIX_INVALID, interpolation-only flags → valid. */
static void test_valid_from_hdr(void) {
        struct imp_image *fl = NULL, *v = NULL;
        CHECK_OK(imp_image_new(4, 1, 3, IMP_PIX_U8, &fl));
        if (!fl)
                return;
        memset(fl->data, 0, 12);
        imp_image_u8(fl, 1, 0)[2] = IMP_HDR_SATURATED;
        imp_image_u8(fl, 2, 0)[0] = IMP_HDR_DARK;
        imp_image_u8(fl, 3, 0)[1] = IMP_HDR_INTERPOLATED_FLAGGED;
        CHECK_OK(imp_btf_valid_from_hdr(fl, &v));
        if (v) {
                CHECK_INT_EQ(v->channels, 1);
                CHECK_INT_EQ(*imp_image_u8(v, 0, 0), 0);
                CHECK_INT_EQ(*imp_image_u8(v, 1, 0), IMP_BTF_PIX_SATURATED);
                CHECK_INT_EQ(*imp_image_u8(v, 2, 0), IMP_BTF_PIX_INVALID);
                CHECK_INT_EQ(*imp_image_u8(v, 3, 0), 0);
        }
        CHECK_ERR(imp_btf_valid_from_hdr(NULL, &v), -EINVAL);
        imp_image_free(v);
        imp_image_free(fl);
}

int main(void) {
        test_valid_from_hdr();
        const double centre[3] = { 0, 0, 0 }, elev[3] = { 15, 35, 60 };
        CHECK_INT_EQ(synth_dome(lights, elev, 3, 16, 500.0, centre, 1.0, 0.0), NL);
        struct imp_btf_heightfield hf;
        setup_heightfield(&hf);
        struct imp_pinhole cam;
        const double eye[3] = { 0, 0, 300 };
        synth_camera(&cam, eye, centre, CAM, CAM, 40.0);
        for (int j = 0; j < NL; j++) {
                CHECK_OK(imp_image_new(CAM, CAM, 3, IMP_PIX_F32, &frames[j]));
                CHECK_OK(imp_image_new(CAM, CAM, 1, IMP_PIX_U8, &valid[j]));
                for (int y = 0; y < CAM; y++)
                        for (int x = 0; x < 3 * CAM; x++)
                                ((float *) imp_image_row(frames[j], y))[x] = 0.5f;
        }
        struct imp_btf_capture cap = { .camera = &cam, .lights = lights, .n_lights = NL,
                                       .frames = (const struct imp_image *const *) frames,
                                       .valid = (const struct imp_image *const *) valid };
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);

        test_irradiance();
        test_shadows(&hf, &cap, &sp);
        test_hidden(&hf, &sp);
        for (int j = 0; j < NL; j++) {
                imp_image_free(frames[j]);
                imp_image_free(valid[j]);
        }
        return TEST_DONE();
}
