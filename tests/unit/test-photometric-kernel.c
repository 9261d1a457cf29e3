/* Where the photometric normal map puts features sharper than the camera's pixels, for
 * every kernel of the re-read (pipeline/appearance/photometric.c): the painting rig's
 * camera (0.1 mm pixels from 300 mm, 60 × 40 mm field) and 12-light dome over a canvas of
 * narrow steep ridges in both directions (Gaussian profile σ 0.05 mm, slope up to 0.4, real
 * heights), each pixel point-sampled where its ray meets the relief (as the simulator
 * renders), Lambertian with 1 % noise, the copy holding the true heights. The copy's
 * normals are fitted to the truth's as t(x + s·x + d): s is the map's scale about the field
 * centre, measured on a strip across the whole field in x and one in y. The painting's
 * tiles show s ≈ −1 to −2·10⁻⁴ (docs/mosaic.md): kernel ringing on undersampled relief
 * alone does not make it. */
#include <errno.h>
#include <stdlib.h>
#include "btf-synth.h"
#include "numerics.h"
#include "photometric.h"
#include "test.h"

enum { LONG = 1180, TALL = 780, SHORT = 60, CW = 610, CH = 410, NL = 12 };
#define MAX_SCALE 2e-5              /* 0.6 µm at the field's edge */

static const double pitch = 0.05, eye[3] = { 0, 0, 300 };
#define RIDGE_SIGMA 0.05              /* mm */
#define RIDGE_SPACING 0.83            /* mm, not a multiple of the pixel */
#define RIDGE_SLOPE 0.4               /* the profile's steepest slope */
#define RIDGE_TILT 0.07               /* ridges run along y + this × x */

/* Height slope of one ridge family at coordinate q across it. */
static double ridge_slope(double q) {
        double a = RIDGE_SLOPE * RIDGE_SIGMA * exp(0.5), k = floor(q / RIDGE_SPACING + 0.5), d = q - k * RIDGE_SPACING;
        return -a * d / (RIDGE_SIGMA * RIDGE_SIGMA) * exp(-0.5 * d * d / (RIDGE_SIGMA * RIDGE_SIGMA));
}

static double ridge_height(double q) {
        double a = RIDGE_SLOPE * RIDGE_SIGMA * exp(0.5), k = floor(q / RIDGE_SPACING + 0.5), d = q - k * RIDGE_SPACING;
        return a * exp(-0.5 * d * d / (RIDGE_SIGMA * RIDGE_SIGMA));
}
static double height_at(double x, double y) {
        return (ridge_height(x + RIDGE_TILT * y) + ridge_height(y - RIDGE_TILT * x + 0.31));
}

/* Truth normal at canvas (x, y): ridges along y and ridges along x, both tilted. */
static void ridge(double x, double y, double n[3]) {
        double sa = ridge_slope(x + RIDGE_TILT * y), sb = ridge_slope(y - RIDGE_TILT * x + 0.31);
        double hx = sa - RIDGE_TILT * sb, hy = RIDGE_TILT * sa + sb, l = sqrt(1 + hx * hx + hy * hy);
        n[0] = -hx / l, n[1] = -hy / l, n[2] = 1 / l;
}

static void render(const struct imp_pinhole *cam, const struct imp_rig_light *L, uint64_t *rng,
                   struct imp_image **frames) {
        for (int j = 0; j < NL; j++) {
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, &frames[j]));
                for (int py = 0; py < CH; py++)
                        for (int px = 0; px < CW; px++) {
                                double d[3] = { (px - cam->cx) / cam->fx, (py - cam->cy) / cam->fy, 1 }, dw[3], n[3], wl[3],
                                       r = 0;
                                for (int i = 0; i < 3; i++)
                                        dw[i] = cam->R[i] * d[0] + cam->R[3 + i] * d[1] + cam->R[6 + i] * d[2];
                                double t = -eye[2] / dw[2], P[3] = { eye[0] + t * dw[0], eye[1] + t * dw[1], 0 };
                                for (int it = 0; it < 20; it++) {   /* the ray meets z = h(x, y) */
                                        P[2] = height_at(P[0], P[1]);
                                        t = (P[2] - eye[2]) / dw[2];
                                        P[0] = eye[0] + t * dw[0], P[1] = eye[1] + t * dw[1];
                                }
                                ridge(P[0], P[1], n);
                                for (int i = 0; i < 3; i++) {
                                        wl[i] = L[j].pos_mm[i] - P[i];
                                        r += wl[i] * wl[i];
                                }
                                double c = (n[0] * wl[0] + n[1] * wl[1] + n[2] * wl[2]) / sqrt(r);
                                *imp_image_f32(frames[j], px, py) =
                                        (float) (0.6 * imp_btf_light_irradiance(&L[j], P) * fmax(0, c) * (1 + 0.01 * synth_gauss(rng)));
                        }
        }
}

/* Least squares of c − t = g·t + (s_x·x + d_x)·∂t/∂x + (s_y·y + d_y)·∂t/∂y + o (n_x and
 * n_y, o per channel) over the refined texels; ret_s: (s_x, s_y), the map's scale about the
 * field centre (> 0: features moved outwards). */
static void fit_scale(const struct imp_btf_heightfield *hf, const float *out, const uint16_t *flags,
                      double ret_s[2], int *ret_n) {
        enum { K = 7 };
        double A[K * K] = { 0 }, b[K] = { 0 }, e = 1e-4;
        int n = 0;
        for (int t = 0; t < hf->width * hf->height; t++) {
                if (flags[t] & IMP_PN_KEPT)
                        continue;
                double x = hf->canvas_to_world[3] + (t % hf->width) * pitch, y = hf->canvas_to_world[7] + (t / hf->width) * pitch,
                       nt[3], nx[2][3], ny[2][3];
                ridge(x, y, nt);
                ridge(x + e, y, nx[0]), ridge(x - e, y, nx[1]), ridge(x, y + e, ny[0]), ridge(x, y - e, ny[1]);
                for (int q = 0; q < 2; q++) {
                        double gx = (nx[0][q] - nx[1][q]) / (2 * e), gy = (ny[0][q] - ny[1][q]) / (2 * e);
                        double J[K] = { nt[q], x * gx, gx, y * gy, gy, q == 0, q == 1 }, r = out[3 * t + q] - nt[q];
                        for (int i = 0; i < K; i++) {
                                b[i] += J[i] * r;
                                for (int j = 0; j < K; j++)
                                        A[K * i + j] += J[i] * J[j];
                        }
                }
                n++;
        }
        CHECK(imp_cholesky_factor(K, A));
        imp_cholesky_solve(K, A, b);
        ret_s[0] = b[1], ret_s[1] = b[3];
        *ret_n = n;
}

/* A w × h texel copy centred on the field holding the true heights and normals. */
static struct imp_btf_heightfield strip(int w, int h, float *hgt, float *nrm) {
        for (int t = 0; t < w * h; t++) {
                double x = -0.5 * (w - 1) * pitch + (t % w) * pitch, y = -0.5 * (h - 1) * pitch + (t / w) * pitch, nt[3];
                hgt[t] = (float) height_at(x, y);
                ridge(x, y, nt);
                for (int c = 0; c < 3; c++)
                        nrm[3 * t + c] = (float) nt[c];
        }
        return (struct imp_btf_heightfield) {
                w, h, pitch, hgt, nrm, NULL,
                { 1, 0, 0, -0.5 * (w - 1) * pitch, 0, 1, 0, -0.5 * (h - 1) * pitch, 0, 0, 1, 0, 0, 0, 0, 1 } };
}

/* The scale along axis a of kernel (kernel, order) on strip hf. */
static double scale_of(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap, int kernel, int order,
                       int a) {
        static float out[3 * LONG * SHORT];
        static uint16_t flags[LONG * SHORT];
        struct imp_btf_sample_params sp;
        struct imp_photometric_params p;
        imp_btf_sample_params_default(&sp);
        imp_photometric_params_default(&p);
        p.kernel = kernel;
        p.lanczos = order;
        struct imp_photometric_out po = { .normal = out, .flags = flags };
        CHECK_OK(imp_photometric_normals(hf, cap, &sp, &p, &po, NULL));
        double s[2];
        int n;
        fit_scale(hf, out, flags, s, &n);
        CHECK_GE(n, hf->width * hf->height * 9 / 10);
        return s[a];
}

int main(void) {
        struct imp_rig_light L[NL];
        static const double elev[2] = { 25, 55 }, centre[3] = { 0, 0, 0 }, target[3] = { 0, 0, 0 };
        CHECK_INT_EQ(synth_dome(L, elev, 2, 6, 500.0, centre, 0.25, 1.0), NL);
        struct imp_pinhole cam;
        synth_camera(&cam, eye, target, CW, CH, 3000.0);   /* 0.1 mm pixels at z = 0 */
        uint64_t rng = 0x9e3779b97f4a7c15ULL;
        struct imp_image *frames[NL];
        render(&cam, L, &rng, frames);
        struct imp_btf_capture cap = { &cam, L, NL, (const struct imp_image *const *) frames, NULL };
        static float hgt[LONG * SHORT], nrm[3 * LONG * SHORT];
        static const struct { const char *name; int kernel, order; } K[] = {
                { "bilinear", IMP_PN_KERNEL_LANCZOS, 0 },
                { "Lanczos-3", IMP_PN_KERNEL_LANCZOS, 3 },
                { "Lanczos-2", IMP_PN_KERNEL_LANCZOS, 2 },
                { "Lanczos-3 clamped", IMP_PN_KERNEL_LANCZOS_CLAMPED, 3 },
                { "Mitchell", IMP_PN_KERNEL_MITCHELL, 3 },
                { "B-spline", IMP_PN_KERNEL_BSPLINE, 3 },
                { "prefiltered Lanczos-3", IMP_PN_KERNEL_PREFILTERED, 3 },
        };
        for (size_t k = 0; k < sizeof K / sizeof *K; k++) {
                /* x on a strip across the field (59 × 3 mm), y on one down it (3 × 39 mm) */
                struct imp_btf_heightfield hx = strip(LONG, SHORT, hgt, nrm);
                double sx = scale_of(&hx, &cap, K[k].kernel, K[k].order, 0);
                struct imp_btf_heightfield hy = strip(SHORT, TALL, hgt, nrm);
                double sy = scale_of(&hy, &cap, K[k].kernel, K[k].order, 1);
                printf("%-22s scale x %+.2e y %+.2e\n", K[k].name, sx, sy);
                CHECK_LE(fabs(sx), MAX_SCALE);
                CHECK_LE(fabs(sy), MAX_SCALE);
        }
        struct imp_photometric_params bad;
        imp_photometric_params_default(&bad);
        bad.kernel = IMP_PN_KERNEL_PREFILTERED;
        bad.lanczos = 4;   /* the window would be 10 pixels */
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        struct imp_btf_heightfield hx = strip(LONG, SHORT, hgt, nrm);
        static float out[3 * LONG * SHORT];
        struct imp_photometric_out po = { .normal = out };
        CHECK_ERR(imp_photometric_normals(&hx, &cap, &sp, &bad, &po, NULL), -EINVAL);
        bad.kernel = 99;
        bad.lanczos = 3;
        CHECK_ERR(imp_photometric_normals(&hx, &cap, &sp, &bad, &po, NULL), -EINVAL);
        for (int j = 0; j < NL; j++)
                imp_image_free(frames[j]);
        return 0;
}
