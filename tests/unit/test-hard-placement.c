/* Canvas placement on synthetic range images (no rendering). Under a deep box frame: a
 * 12 × 8 mm canvas with gentle relief at z = 0, vertical walls of height H sampled by 20
 * range pixels each, and a 4 mm frame top at z = H, camera 500 mm above. With H = 20 mm
 * the PCA of every point (the seed's first plane) has its smallest axis along world x or y
 * — the failure the robust plane fixes. Checked: the canvas normal within 1° of +z, the
 * mask covers ≥ 90 % of the canvas's texels and holds no frame or wall (no height above
 * 0.5 mm); the same range image rotated 60° about y is refused (-ENODATA, the message
 * names the tilt) and, rotated 25°, is placed right. A frame flush with the canvas, darker
 * or paler, is cut off at its albedo step; a canvas whose albedo drifts towards its edge
 * is not trimmed; relief does not tilt the base plane; range noise does not grow the
 * pitch. */
#include <math.h>
#include <string.h>
#include "compare.h"
#include "frame-edge.h"
#include "heightfield.h"
#include "image.h"
#include "json-util.h"
#include "numerics.h"
#include "macro.h"
#include "unit/test.h"

#define P        0.1                  /* mm per range pixel on the canvas */
#define CW       120                  /* canvas pixels */
#define CH       80
#define WALL     20                   /* wall pixels on each side */
#define FRAME    40                   /* frame-top pixels on each side */

static double relief(double x, double y) { return 0.05 * sin(x * 1.3) * cos(y * 0.9); }

/* Pixel (i, j) → point: along each axis the pixel index maps to a position and a "level"
 * 0 (canvas), 0..1 (wall) or 1 (frame top). */
static void axis_pos(int i, int n_canvas, double *ret_pos, double *ret_level) {
        int a = FRAME + WALL, b = FRAME + WALL + n_canvas;
        if (i < FRAME) {
                *ret_pos = -(FRAME - i) * P, *ret_level = 1;
        } else if (i < a) {
                *ret_pos = 0, *ret_level = 1 - (double) (i - FRAME) / WALL;
        } else if (i < b) {
                *ret_pos = (i - a) * P, *ret_level = 0;
        } else if (i < b + WALL) {
                *ret_pos = (n_canvas - 1) * P, *ret_level = (double) (i - b + 1) / WALL;
        } else {
                *ret_pos = (n_canvas - 1) * P + (i - b - WALL + 1) * P, *ret_level = 1;
        }
}

static void make_range(double H, double tilt_deg, struct imp_range_image *r) {
        int w = CW + 2 * (WALL + FRAME), h = CH + 2 * (WALL + FRAME);
        CHECK_OK(imp_range_image_init(r, w, h));
        double a = tilt_deg * M_PI / 180, c = cos(a), s = sin(a);
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double x, y, lx, ly;
                        axis_pos(i, CW, &x, &lx);
                        axis_pos(j, CH, &y, &ly);
                        double z = fmax(lx, ly) * H + (lx == 0 && ly == 0 ? relief(x, y) : 0);
                        size_t k = (size_t) j * w + i;
                        r->xyz[3 * k] = (float) (c * x + s * z);   /* rotation about y */
                        r->xyz[3 * k + 1] = (float) y;
                        r->xyz[3 * k + 2] = (float) (-s * x + c * z);
                        r->sigma_mm[k] = 0.005f;
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                }
        double C[3] = { 0.5 * CW * P, 0.5 * CH * P, 500 };
        r->camera_centre_mm[0] = c * C[0] + s * C[2];
        r->camera_centre_mm[1] = C[1];
        r->camera_centre_mm[2] = -s * C[0] + c * C[2];
}

static void check_placed(double tilt_deg) {
        struct imp_range_image r = {};
        make_range(20, tilt_deg, &r);
        struct imp_heightfield hf = {};
        struct imp_error err = {};
        int k = imp_heightfield_extract(&r, NULL, &hf, &err);
        CHECK_MSG(k == 0, "tilt %.0f°: %s", tilt_deg, err.msg);
        if (k == 0) {
                double a = tilt_deg * M_PI / 180, ez[3] = { hf.canvas_to_world[2], hf.canvas_to_world[6],
                                                            hf.canvas_to_world[10] };
                double want[3] = { sin(a), 0, cos(a) };
                double ang = acos(fmin(1, ez[0] * want[0] + ez[1] * want[1] + ez[2] * want[2])) * 180 / M_PI;
                size_t high = 0;
                for (size_t t = 0; t < (size_t) hf.nx * hf.ny; t++)
                        high += hf.mask[t] && fabs(hf.height_mm[t]) > 0.5;
                double cover = (double) hf.n_mask_texels * hf.pitch_mm * hf.pitch_mm / ((CW - 1) * (CH - 1) * P * P);
                fprintf(stderr, "tilt %.0f°: canvas normal %.3f° off, %zu mask texels (%.1f %% of the canvas), "
                        "%zu above 0.5 mm, tilt reported %.2f°\n", tilt_deg, ang, hf.n_mask_texels, 100 * cover,
                        high, hf.plane_tilt_deg);
                CHECK_LE(ang, 1.0);
                CHECK_GE(cover, 0.9);
                CHECK_INT_EQ(high, 0);
        }
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

/* ---- a frame flush with the canvas, the base plane, the pitch on a noisy scan ---- */

static uint64_t rng_state = 0x2545f4914f6cdd1dull;
static double rnd(void) {              /* uniform in [-0.5, 0.5) */
        rng_state ^= rng_state << 13, rng_state ^= rng_state >> 7, rng_state ^= rng_state << 17;
        return (double) (rng_state >> 11) / (double) (1ull << 53) - 0.5;
}

/* A 0.5 mm ridge with a cliff on one side, off the canvas's centre, from x = 2 to 9 mm
 * with gentle ends (like the hard scenes'). */
static double ridge_amp = 1;          /* × 0.5 mm */
static double ridge(double x, double y) {
        double d = y - 3.0 - 0.1 * x, e = fmin(fmax(fmin(x - 2.0, 9.0 - x), 0.0), 1.0);
        return ridge_amp * sin(0.5 * M_PI * e) * (d < 0 ? 0.5 * exp(-d * d / 0.5) : d < 0.05 ? 0.5 * (1 - d / 0.05) : 0);
}

/* Flat grid: canvas CW × CH pixels with relief, and `frame` pixels of flat frame at z = 0
 * around it (no wall). albedo (may be NULL): canvas 0.6 ± 3 % texture, frame `frame_rho`
 * ± 0.5 %. z noise σ ≈ noise_mm along the (near-vertical) ray. */
static void make_flat(int frame, double frame_rho, double noise_mm, struct imp_range_image *r, float **albedo) {
        int w = CW + 2 * frame, h = CH + 2 * frame;
        CHECK_OK(imp_range_image_init(r, w, h));
        if (albedo)
                *albedo = malloc((size_t) w * h * sizeof(float));
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double x = (i - frame) * P, y = (j - frame) * P;
                        bool on_canvas = i >= frame && i < frame + CW && j >= frame && j < frame + CH;
                        double z = on_canvas ? relief(x, y) + ridge(x, y) : 0;
                        z += noise_mm * sqrt(12.0) * rnd();
                        size_t k = (size_t) j * w + i;
                        r->xyz[3 * k] = (float) x, r->xyz[3 * k + 1] = (float) y, r->xyz[3 * k + 2] = (float) z;
                        r->sigma_mm[k] = 0.005f;
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                        if (albedo)
                                (*albedo)[k] = (float) (on_canvas ? 0.6 * (1 + 0.1 * rnd()) : frame_rho * (1 + 0.02 * rnd()));
                }
        r->camera_centre_mm[0] = 0.5 * CW * P, r->camera_centre_mm[1] = 0.5 * CH * P, r->camera_centre_mm[2] = 500;
}

/* Fraction of the mask's texels whose world point lies off the canvas (on the frame) and
 * the mask's cover of the canvas. */
static void frame_figures(const struct imp_heightfield *hf, double *ret_frame, double *ret_cover) {
        const double *M = hf->canvas_to_world;
        size_t on_frame = 0;
        for (int j = 0; j < hf->ny; j++)
                for (int i = 0; i < hf->nx; i++) {
                        size_t t = (size_t) j * hf->nx + i;
                        if (!hf->mask[t])
                                continue;
                        double u = i * hf->pitch_mm, v = j * hf->pitch_mm;
                        double x = M[0] * u + M[1] * v + M[2] * hf->height_mm[t] + M[3];
                        double y = M[4] * u + M[5] * v + M[6] * hf->height_mm[t] + M[7];
                        on_frame += x < -0.5 * P || y < -0.5 * P || x > (CW - 0.5) * P || y > (CH - 0.5) * P;
                }
        *ret_frame = hf->n_mask_texels ? (double) on_frame / hf->n_mask_texels : 1;
        *ret_cover = (double) (hf->n_mask_texels - on_frame) * hf->pitch_mm * hf->pitch_mm / ((CW - 1) * (CH - 1) * P * P);
}

/* A flush frame is cut off at its albedo step (at most 1 % of the mask on the frame, at
 * least 85 % of the canvas kept), darker or paler than the paint; without the albedo
 * the fill runs over it (the failure this guards against; more than 20 % frame). */
static void check_flush(double frame_rho) {
        struct imp_range_image r = {};
        _cleanup_free_ float *albedo = NULL;
        make_flat(30, frame_rho, 0.003, &r, &albedo);
        struct imp_heightfield_options opt;
        imp_heightfield_options_default(&opt);
        for (int with = 0; with < 2; with++) {
                opt.albedo = with ? albedo : NULL;
                struct imp_heightfield hf = {};
                struct imp_error err = {};
                int k = imp_heightfield_extract(&r, &opt, &hf, &err);
                CHECK_MSG(k == 0, "flush frame ρ %.2f: %s", frame_rho, err.msg);
                if (k != 0)
                        continue;
                double frame, cover;
                frame_figures(&hf, &frame, &cover);
                fprintf(stderr, "flush frame ρ %.2f, %s albedo: %.2f %% of the mask on the frame, %.1f %% of "
                        "the canvas covered, %zu points trimmed\n", frame_rho, with ? "with" : "without",
                        100 * frame, 100 * cover, hf.n_frame_trimmed);
                if (with) {
                        CHECK_LE(frame, 0.01);
                        CHECK_GE(cover, 0.85);
                        CHECK((hf.flags & IMP_HF_FRAME_TRIMMED) != 0);
                } else
                        CHECK_GE(frame, 0.2);
                imp_heightfield_done(&hf);
        }
        imp_range_image_done(&r);
}

/* No frame, paint whose albedo drifts slowly towards the edge (shading near a wall): no
 * trim (the mask keeps ≥ 95 % of the canvas). */
static void check_no_false_trim(void) {
        struct imp_range_image r = {};
        _cleanup_free_ float *albedo = NULL;
        make_flat(0, 0, 0.003, &r, &albedo);
        for (int j = 0; j < CH; j++)
                for (int i = 0; i < CW; i++) {
                        double e = fmin(fmin(i, CW - 1 - i), fmin(j, CH - 1 - j)) * P;   /* mm from the edge */
                        albedo[(size_t) j * CW + i] *= (float) (0.75 + 0.25 * fmin(e / 3.0, 1.0));
                }
        struct imp_heightfield_options opt;
        imp_heightfield_options_default(&opt);
        opt.albedo = albedo;
        struct imp_heightfield hf = {};
        struct imp_error err = {};
        int k = imp_heightfield_extract(&r, &opt, &hf, &err);
        CHECK_MSG(k == 0, "shaded canvas: %s", err.msg);
        if (k == 0) {
                double frame, cover;
                frame_figures(&hf, &frame, &cover);
                fprintf(stderr, "shaded canvas, no frame: %zu points trimmed, %.1f %% covered\n", hf.n_frame_trimmed,
                        100 * cover);
                CHECK_INT_EQ(hf.n_frame_trimmed, 0);
                CHECK_GE(cover, 0.9);
        }
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

/* An untilted canvas whose relief (a 2 mm ridge with a cliff, off centre) tilts the
 * least-squares plane through it 0.73°: the base plane stays within 0.35° of +z (0.24°). A noisy scan
 * (σ 0.05 mm along the ray): the pitch stays within 2.5 % of the 0.1 mm footprint, while the
 * 3-D neighbour distance grows more than 5 %. */
static void check_base_and_pitch(void) {
        struct imp_range_image r = {};
        ridge_amp = 4;
        make_flat(0, 0, 0.0, &r, NULL);
        ridge_amp = 1;
        struct imp_heightfield hf = {};
        struct imp_error err = {};
        int k = imp_heightfield_extract(&r, NULL, &hf, &err);
        CHECK_MSG(k == 0, "ridge: %s", err.msg);
        if (k == 0) {
                double ang = acos(fmin(1, fabs(hf.canvas_to_world[10]))) * 180 / M_PI;
                fprintf(stderr, "ridge off centre: canvas normal %.3f° off +z\n", ang);
                CHECK_LE(ang, 0.35);
        }
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
        make_flat(0, 0, 0.05, &r, NULL);
        k = imp_heightfield_extract(&r, NULL, &hf, &err);
        CHECK_MSG(k == 0, "noisy: %s", err.msg);
        if (k == 0) {
                fprintf(stderr, "noisy scan: pitch %.4f mm, 3-D neighbour distance %.4f mm (footprint %.3f)\n",
                        hf.pitch_mm, hf.neighbour_mm, P);
                CHECK_LE(fabs(hf.pitch_mm - P), 0.025 * P);
                CHECK_GE(hf.neighbour_mm, 1.05 * P);
        }
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

/* compare's placement_deg on a truth canvas tilted 10° in x (slope 0.176) with the
 * cliff-sided ridge and a border column whose normals were taken across a frame step
 * (n_z 0.05): a copy on the true plane measures within 0.1° (the mean unit normal said
 * 1.4° for the ridge alone; the mean slope is thrown by the border column). */
#define TP 0.05
#define TN 200
static void check_compare_truth_plane(void) {
        char truth[512], copy[512], path[1024];
        snprintf(truth, sizeof truth, "%s/truth", test_tmpdir());
        snprintf(copy, sizeof copy, "%s/copy", test_tmpdir());
        CHECK_OK(imp_mkdir_p(truth, 0755));
        _cleanup_image_ struct imp_image *img = NULL;
        CHECK_OK(imp_image_new(TN, TN, 5, IMP_PIX_F32, &img));
        const double slope = 0.176;
        for (int j = 0; j < TN; j++)
                for (int i = 0; i < TN; i++) {
                        double x = i * TP, y = j * TP, e = 1e-4;
                        double hx = slope + (ridge(x + e, y) - ridge(x - e, y)) / (2 * e);
                        double hy = (ridge(x, y + e) - ridge(x, y - e)) / (2 * e);
                        double n[3] = { -hx, -hy, 1 };
                        if (i == TN - 1)   /* across the frame step */
                                n[0] = -20, n[1] = 0, n[2] = 1;
                        imp_normalize3(n);
                        float *p = imp_image_f32(img, i, j);
                        p[0] = (float) (slope * x + ridge(x, y)), p[1] = (float) n[0], p[2] = (float) n[1];
                        p[3] = (float) n[2], p[4] = 1;
                }
        static const char *const names[] = { "height", "nx", "ny", "nz", "mask" };
        snprintf(path, sizeof path, "%s/heightfield.exr", truth);
        CHECK_OK(imp_exr_write(path, img, names, false, NULL));
        _cleanup_json_ json_t *tj = json_pack("{s:f,s:[f,f],s:i,s:i}", "pitch_mm", TP, "origin_mm", 0.0, 0.0, "nx", TN,
                                              "ny", TN);
        snprintf(path, sizeof path, "%s/truth.json", truth);
        CHECK_OK(imp_json_save_atomic(path, tj, NULL));
        /* The copy: 8 × 8 texels of 1 mm on the plane z = slope·x, from (1, 1). */
        struct imp_heightfield hf = { .nx = 8, .ny = 8, .pitch_mm = 1 };
        size_t n = 64;
        hf.height_mm = calloc(n, sizeof(float)), hf.nx_ = calloc(n, sizeof(float)), hf.ny_ = calloc(n, sizeof(float));
        hf.sigma_mm = calloc(n, sizeof(float)), hf.sigma_n_deg = calloc(n, sizeof(float));
        hf.texel_flags = calloc(n, sizeof(uint16_t)), hf.mask = malloc(n);
        CHECK(hf.height_mm && hf.nx_ && hf.ny_ && hf.sigma_mm && hf.sigma_n_deg && hf.texel_flags && hf.mask);
        memset(hf.mask, 1, n);
        double ez[3] = { -slope, 0, 1 }, ex[3], ey[3];
        imp_normalize3(ez);
        imp_canvas_axes(ez, ex, ey);
        double o[3] = { 1, 1, slope };
        for (int q = 0; q < 3; q++) {
                hf.canvas_to_world[4 * q] = ex[q], hf.canvas_to_world[4 * q + 1] = ey[q];
                hf.canvas_to_world[4 * q + 2] = ez[q], hf.canvas_to_world[4 * q + 3] = o[q];
        }
        hf.canvas_to_world[15] = 1;
        struct imp_error err = {};
        CHECK_MSG(imp_heightfield_save(&hf, copy, &err) >= 0, "save: %s", err.msg);
        imp_heightfield_done(&hf);
        struct imp_compare_result cr = {};
        int k = imp_compare_dirs(copy, truth, &cr, &err);
        CHECK_MSG(k == 0, "compare: %s", err.msg);
        fprintf(stderr, "compare: copy on the true plane measured %.3f° off\n", cr.placement_deg);
        CHECK(cr.placement_deg >= 0);
        CHECK_LE(cr.placement_deg, 0.1);
}

int main(void) {
        check_compare_truth_plane();
        check_placed(0);
        check_placed(25);
        check_flush(0.3);
        check_flush(0.9);
        check_no_false_trim();
        check_base_and_pitch();
        /* A canvas 60° off the rig's pose is not a plausible placement: refused with why. */
        struct imp_range_image r = {};
        make_range(20, 60, &r);
        struct imp_heightfield keep = { .nx = 7 };
        struct imp_error err = {};
        CHECK_ERR(imp_heightfield_extract(&r, NULL, &keep, &err), -ENODATA);
        CHECK_MSG(strstr(err.msg, "off the rig's canvas normal") != NULL, "message: %s", err.msg);
        if (keep.nx != 7)
                fprintf(stderr, "tilt 60°: placed with tilt %.1f°, %zu texels, plane rms %.3f mm, flags %#x\n",
                        keep.plane_tilt_deg, keep.n_mask_texels, keep.plane_rms_mm, keep.flags);
        CHECK_INT_EQ(keep.nx, 7);
        fprintf(stderr, "tilt 60°: %s\n", err.msg);
        imp_range_image_done(&r);
        return TEST_DONE();
}
