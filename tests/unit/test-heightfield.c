/* Heightfield extraction on synthetic range images: a painted canvas (smooth relief and a
 * bump) inside a frame standing 15 mm proud, sampled on a camera-like grid, optionally
 * tilted. Checks the canvas mask (frame removed, erosion, holes kept), the canvas frame
 * (normal towards the camera, x along world x), heights and normals against the analytic
 * surface, the pitch from the footprint, the EXR/copy.json output, and imp_compare_dirs
 * against a truth directory written here. */
#include <math.h>
#include <string.h>
#include "compare.h"
#include "numerics.h"
#include "heightfield.h"
#include "quality.h"
#include "image.h"
#include "json-util.h"
#include "unit/test.h"

#define PITCH 0.25
#define FRAME_W 8.0
#define FRAME_H 15.0
static const double CMIN[2] = { -50, -40 }, CMAX[2] = { 50, 40 };

static double relief(double x, double y) {
        double r2 = (x - 20) * (x - 20) + (y - 10) * (y - 10);
        return 0.3 * sin(2 * M_PI * x / 12) * cos(2 * M_PI * y / 9) + 1.0 * exp(-r2 / (2 * 4.0 * 4.0));
}
static bool in_canvas(double x, double y) { return x >= CMIN[0] && x <= CMAX[0] && y >= CMIN[1] && y <= CMAX[1]; }
static double surface(double x, double y) { return in_canvas(x, y) ? relief(x, y) : FRAME_H; }
static void relief_normal(double x, double y, double n[3]) {
        const double e = 1e-4;
        double gx = (relief(x + e, y) - relief(x - e, y)) / (2 * e), gy = (relief(x, y + e) - relief(x, y - e)) / (2 * e);
        double l = sqrt(gx * gx + gy * gy + 1);
        n[0] = -gx / l, n[1] = -gy / l, n[2] = 1 / l;
}

/* Rotation about the axis (1, 1, 0)/√2 by `deg`. */
static void tilt_matrix(double deg, double R[9]) {
        double a = deg * M_PI / 180, c = cos(a), s = sin(a), u[3] = { M_SQRT1_2, M_SQRT1_2, 0 };
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                        R[3 * i + j] = (i == j ? c : 0) + (1 - c) * u[i] * u[j];
        R[1] -= s * u[2], R[2] += s * u[1], R[3] += s * u[2], R[5] -= s * u[0], R[6] -= s * u[1], R[7] += s * u[0];
}
static void rot(const double R[9], const double v[3], double o[3]) {
        for (int i = 0; i < 3; i++)
                o[i] = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
}
static void rot_t(const double R[9], const double v[3], double o[3]) {
        for (int i = 0; i < 3; i++)
                o[i] = R[i] * v[0] + R[3 + i] * v[1] + R[6 + i] * v[2];
}

/* Range image over canvas + frame; a hole (invalid disk) of radius hole_r at (-20, -15). */
static void make_range(double tilt_deg, double hole_r, double R[9], struct imp_range_image *r) {
        int w = (int) ((CMAX[0] - CMIN[0] + 2 * FRAME_W) / PITCH) + 1;
        int h = (int) ((CMAX[1] - CMIN[1] + 2 * FRAME_W) / PITCH) + 1;
        tilt_matrix(tilt_deg, R);
        CHECK_OK(imp_range_image_init(r, w, h));
        for (int j = 0; j < h; j++)
                for (int i = 0; i < w; i++) {
                        double x = CMIN[0] - FRAME_W + i * PITCH, y = CMIN[1] - FRAME_W + j * PITCH;
                        size_t k = (size_t) j * w + i;
                        if (hypot(x + 20, y + 15) < hole_r)
                                continue;
                        double S[3] = { x, y, surface(x, y) }, W[3];
                        rot(R, S, W);
                        for (int c = 0; c < 3; c++)
                                r->xyz[3 * k + c] = (float) W[c];
                        r->sigma_mm[k] = 0.01f;
                        r->valid[k] = IMP_RANGE_BOTH;
                        r->n_valid++;
                }
        double C[3] = { 0, 0, 800 };
        rot(R, C, r->camera_centre_mm);
}

/* Canvas-frame point of texel (i, j) with height h, in the scene (untilted) frame. */
static void texel_scene(const struct imp_heightfield *hf, const double R[9], int i, int j, double h, double S[3]) {
        const double *M = hf->canvas_to_world;
        double c[3] = { i * hf->pitch_mm, j * hf->pitch_mm, h }, W[3];
        for (int q = 0; q < 3; q++)
                W[q] = M[4 * q] * c[0] + M[4 * q + 1] * c[1] + M[4 * q + 2] * c[2] + M[4 * q + 3];
        rot_t(R, W, S);
}

static void test_extraction(double tilt_deg) {
        double R[9];
        struct imp_range_image r = {};
        make_range(tilt_deg, 3.0, R, &r);
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, NULL, &hf));
        /* Frame: ez is the tilted z, ex the projection of world x. */
        const double *M = hf.canvas_to_world;
        double ez[3] = { M[2], M[6], M[10] }, ex[3] = { M[0], M[4], M[8] }, zt[3], z[3] = { 0, 0, 1 };
        rot(R, z, zt);
        CHECK_NEAR(ez[0] * zt[0] + ez[1] * zt[1] + ez[2] * zt[2], 1.0, 1e-4);
        /* ex ∝ x̂ − (x̂·ez) ez = (1 − ez₀², −ez₀ez₁, −ez₀ez₂): a unit vector with these ratios */
        CHECK_NEAR(ex[0] * ex[0] + ex[1] * ex[1] + ex[2] * ex[2], 1.0, 1e-9);
        CHECK_NEAR(ex[1] * (1 - ez[0] * ez[0]), -ex[0] * ez[0] * ez[1], 1e-9);
        CHECK_NEAR(ex[2] * (1 - ez[0] * ez[0]), -ex[0] * ez[0] * ez[2], 1e-9);
        CHECK_NEAR(ex[0] * ez[0] + ex[1] * ez[1] + ex[2] * ez[2], 0.0, 1e-9);
        CHECK_GE(ex[0], 0.99);
        CHECK_NEAR(hf.footprint_mm, PITCH, 0.02);
        CHECK_NEAR(hf.pitch_mm, fmin(hf.neighbour_mm, 1.02 * hf.footprint_mm), 0);   /* heightfield.h pitch_mm */

        /* Heights and normals against the surface, after removing the median offset. */
        size_t n = 0, outside = 0, in_hole = 0;
        double sum_err = 0, ss = 0, sum_ang = 0;
        _cleanup_free_ double *d = malloc((size_t) hf.nx * hf.ny * sizeof(double));
        for (int j = 0; j < hf.ny; j++)
                for (int i = 0; i < hf.nx; i++) {
                        size_t t = (size_t) j * hf.nx + i;
                        if (!hf.mask[t])
                                continue;
                        double S[3];
                        texel_scene(&hf, R, i, j, hf.height_mm[t], S);
                        if (!in_canvas(S[0], S[1])) {
                                outside++;
                                continue;
                        }
                        if (hypot(S[0] + 20, S[1] + 15) < 2.5)
                                in_hole++;
                        d[n] = S[2] - relief(S[0], S[1]);
                        sum_err += d[n];
                        n++;
                        double tn[3], nn[3], nw[3], ns[3];
                        relief_normal(S[0], S[1], tn);
                        nn[0] = hf.nx_[t], nn[1] = hf.ny_[t], nn[2] = sqrt(fmax(0, 1 - nn[0] * nn[0] - nn[1] * nn[1]));
                        for (int q = 0; q < 3; q++)
                                nw[q] = nn[0] * M[4 * q] + nn[1] * M[4 * q + 1] + nn[2] * M[4 * q + 2];
                        rot_t(R, nw, ns);
                        sum_ang += acos(fmin(1, ns[0] * tn[0] + ns[1] * tn[1] + ns[2] * tn[2])) * 180 / M_PI;
                        CHECK_FINITE(hf.sigma_mm[t]);
                }
        double mean = sum_err / n;
        for (size_t k = 0; k < n; k++)
                ss += (d[k] - mean) * (d[k] - mean);
        double rmse_um = sqrt(ss / n) * 1000, area_frac = n * hf.pitch_mm * hf.pitch_mm / ((CMAX[0] - CMIN[0]) * (CMAX[1] - CMIN[1]));
        fprintf(stderr, "tilt %.0f°: grid %dx%d pitch %.4f mm, %zu texels on canvas (%.1f %% of its area), %zu off, "
                "%zu in hole; height rmse %.2f µm; normal err %.3f° mean; plane rms %.3f mm, threshold %.3f mm\n",
                tilt_deg, hf.nx, hf.ny, hf.pitch_mm, n, 100 * area_frac, outside, in_hole, rmse_um, sum_ang / n,
                hf.plane_rms_mm, hf.gradient_threshold_mm);
        CHECK_INT_EQ(outside, 0);      /* frame removed */
        CHECK_INT_EQ(in_hole, 0);      /* no surface invented over the hole */
        /* Lost: the rim (3 px erosion + 1 px where the Sobel sees the frame step, ≈ 4.5 %)
         * and the 3 mm hole (0.35 %). */
        CHECK_GE(area_frac, 0.93);
        CHECK_LE(rmse_um, 5.0);        /* linear-mesh resampling of a 0.3 mm, 9–12 mm relief */
        CHECK_LE(sum_ang / n, 0.5);
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

static int write_truth(const char *dir) {
        const double tp = 0.1;
        int nx = (int) ((CMAX[0] - CMIN[0] + 2 * FRAME_W) / tp) + 1, ny = (int) ((CMAX[1] - CMIN[1] + 2 * FRAME_W) / tp) + 1;
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_new(nx, ny, 5, IMP_PIX_F32, &img);
        if (r < 0)
                return r;
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        double x = CMIN[0] - FRAME_W + i * tp, y = CMIN[1] - FRAME_W + j * tp, n[3] = { 0, 0, 1 };
                        if (in_canvas(x, y))
                                relief_normal(x, y, n);
                        float *p = imp_image_f32(img, i, j);
                        p[0] = (float) surface(x, y), p[1] = (float) n[0], p[2] = (float) n[1], p[3] = (float) n[2];
                        p[4] = in_canvas(x, y);
                }
        static const char *const names[] = { "height", "nx", "ny", "nz", "mask" };
        char path[1024];
        snprintf(path, sizeof path, "%s/heightfield.exr", dir);
        if ((r = imp_exr_write(path, img, names, false, NULL)) < 0)
                return r;
        _cleanup_json_ json_t *j = json_pack("{s:f,s:[f,f],s:i,s:i,s:[f,f],s:[f,f]}", "pitch_mm", tp, "origin_mm",
                                             CMIN[0] - FRAME_W, CMIN[1] - FRAME_W, "nx", nx, "ny", ny,
                                             "canvas_min_mm", CMIN[0], CMIN[1], "canvas_max_mm", CMAX[0], CMAX[1]);
        snprintf(path, sizeof path, "%s/truth.json", dir);
        return imp_json_save_atomic(path, j, NULL);
}

static void test_save_and_compare(void) {
        double R[9];
        struct imp_range_image r = {};
        make_range(0, 0, R, &r);
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, NULL, &hf));
        char copy[512], truth[512];
        snprintf(copy, sizeof copy, "%s/copy", test_tmpdir());
        snprintf(truth, sizeof truth, "%s/truth", test_tmpdir());
        struct imp_error err = {};
        int k = imp_heightfield_save(&hf, copy, &err);
        CHECK_MSG(k >= 0, "save: %s", err.msg);
        CHECK_OK(imp_mkdir_p(truth, 0755));
        CHECK_OK(write_truth(truth));

        char path[1024];
        snprintf(path, sizeof path, "%s/heightfield.exr", copy);
        struct imp_image *img = NULL;
        char **names = NULL;
        CHECK_OK(imp_exr_read(path, &img, &names, &err));
        if (img) {
                CHECK_INT_EQ(img->width, hf.nx);
                CHECK_INT_EQ(img->channels, 7);
                CHECK_INT_EQ(imp_image_channel_index(names, "sigma") >= 0, 1);
                CHECK_INT_EQ(imp_image_channel_index(names, "mask") >= 0, 1);
                int cf = imp_image_channel_index(names, "flags"), cs = imp_image_channel_index(names, "sigma_n_deg");
                int cm = imp_image_channel_index(names, "mask");
                CHECK(cf >= 0 && cs >= 0);
                /* Every canvas texel has a finite normal σ > 0; the rim is flagged frame-adjacent. */
                size_t bad_sn = 0, rim = 0;
                for (int y = 0; cf >= 0 && cs >= 0 && y < img->height; y++)
                        for (int x = 0; x < img->width; x++) {
                                const float *p = imp_image_f32(img, x, y);
                                if (p[cm] < 0.5)
                                        continue;
                                bad_sn += !(isfinite(p[cs]) && p[cs] > 0 && p[cs] < 90);
                                rim += ((unsigned) p[cf] & IMP_TEXEL_FRAME_ADJACENT) != 0;
                        }
                CHECK_INT_EQ(bad_sn, 0);
                fprintf(stderr, "canvas rim flagged frame-adjacent: %zu texels\n", rim);
                CHECK(rim > 0);
        }
        imp_image_free(img);
        imp_strv_free(names);
        snprintf(path, sizeof path, "%s/copy.json", copy);
        json_t *j = NULL;
        CHECK_OK(imp_json_load(path, &j, &err));
        if (j) {
                CHECK_STR_EQ(json_string_value(json_object_get(j, "units")), "mm");
                CHECK_INT_EQ(json_array_size(json_object_get(j, "canvas_to_world")), 16);
                CHECK(json_is_object(json_object_get(json_object_get(j, "stages"), "heightfield")));
                CHECK(json_is_object(json_object_get(j, "provenance")));
                json_decref(j);
        }

        struct imp_compare_result cr = {};
        k = imp_compare_dirs(copy, truth, &cr, &err);
        CHECK_MSG(k >= 0, "compare: %s", err.msg);
        _cleanup_json_ json_t *cj = imp_compare_result_to_json(&cr);
        _cleanup_free_ char *s = json_dumps(cj, JSON_COMPACT);
        fprintf(stderr, "compare: %s\n", s);
        CHECK_LE(cr.height_rmse_um, 5.0);
        CHECK_LE(cr.normal_err_deg_mean, 0.5);
        CHECK_GE(cr.mask_iou, 0.95);
        CHECK_INT_EQ(cr.nan_count, 0);
        CHECK_GE(cr.n_compared, 100000);

        /* Missing directory: an error with a message, result untouched. */
        struct imp_compare_result keep = { .mask_iou = 42 };
        CHECK(imp_compare_dirs("/nonexistent-impasto", truth, &keep, &err) < 0);
        CHECK_NEAR(keep.mask_iou, 42, 0);
        CHECK_STR_CONTAINS(err.msg, "nonexistent-impasto");
        imp_heightfield_done(&hf);
        imp_range_image_done(&r);
}

static void test_given_pitch_and_errors(void) {
        double R[9];
        struct imp_range_image r = {};
        make_range(0, 0, R, &r);
        struct imp_heightfield_options o;
        imp_heightfield_options_default(&o);
        o.pitch_mm = 0.5;
        struct imp_heightfield hf = {};
        CHECK_OK(imp_heightfield_from_range(&r, &o, &hf));
        CHECK_NEAR(hf.pitch_mm, 0.5, 0);
        CHECK_NEAR(hf.nx, (int) ((100 - 2 * 4 * PITCH) / 0.5) + 1, 2);   /* canvas minus the 4-px rim */
        imp_heightfield_done(&hf);

        struct imp_heightfield keep = { .nx = 99 };
        memset(r.valid, 0, (size_t) r.width * r.height);
        CHECK_ERR(imp_heightfield_from_range(&r, NULL, &keep), -ENODATA);
        CHECK_INT_EQ(keep.nx, 99);
        CHECK_ERR(imp_heightfield_from_range(NULL, NULL, &keep), -EINVAL);
        imp_range_image_done(&r);
}

static void test_eigen(void) {
        double A[9] = { 4, 1, 0.5, 1, 3, 0.2, 0.5, 0.2, 1 }, val[3], vec[9];
        imp_eigen_sym3(A, val, vec);
        CHECK_LE(val[0], val[1]);
        CHECK_LE(val[1], val[2]);
        for (int k = 0; k < 3; k++) {
                double Av[3];
                for (int i = 0; i < 3; i++)
                        Av[i] = A[3 * i] * vec[3 * k] + A[3 * i + 1] * vec[3 * k + 1] + A[3 * i + 2] * vec[3 * k + 2];
                for (int i = 0; i < 3; i++)
                        CHECK_NEAR(Av[i], val[k] * vec[3 * k + i], 1e-12);
        }
}

/* compare.c measures the copy normal against the truth normal at the same point (the
 * bilinear blend of the four surrounding truth samples, what the simulator shades with):
 * a copy on a grid that is not the truth's, holding exactly that normal, scores ~0°. The
 * nearest truth sample instead would be up to half a sample off: on grooves of 4 samples
 * per period with slopes up to 27° that was several degrees of error the copy did not
 * make. */
#define GROOVE_TP 0.05
static void groove_truth_normal(const float *tn, int tnx, double x, double y, double n[3]) {
        int i0 = (int) floor(x / GROOVE_TP), j0 = (int) floor(y / GROOVE_TP);
        double ax = x / GROOVE_TP - i0, ay = y / GROOVE_TP - j0, l = 0;
        for (int c = 0; c < 3; c++) {
                n[c] = (tn[3 * (j0 * tnx + i0) + c] * (1 - ax) + tn[3 * (j0 * tnx + i0 + 1) + c] * ax) * (1 - ay) +
                       (tn[3 * ((j0 + 1) * tnx + i0) + c] * (1 - ax) + tn[3 * ((j0 + 1) * tnx + i0 + 1) + c] * ax) * ay;
                l += n[c] * n[c];
        }
        for (int c = 0; c < 3; c++)
                n[c] /= sqrt(l);
}

static void test_compare_between_samples(void) {
        enum { TNX = 81, CNX = 70 };
        static float tn[3 * TNX * TNX];
        char copy[512], truth[512], path[1024];
        snprintf(copy, sizeof copy, "%s/copy-grooves", test_tmpdir());
        snprintf(truth, sizeof truth, "%s/truth-grooves", test_tmpdir());
        CHECK_OK(imp_mkdir_p(truth, 0755));
        struct imp_image *img = NULL;
        CHECK_OK(imp_image_new(TNX, TNX, 5, IMP_PIX_F32, &img));
        if (!img)
                return;
        for (int j = 0; j < TNX; j++)
                for (int i = 0; i < TNX; i++) {
                        double g = 0.5 * cos(2 * M_PI * i / 4.0), l = sqrt(g * g + 1);
                        float *p = imp_image_f32(img, i, j), *q = &tn[3 * (j * TNX + i)];
                        q[0] = (float) (-g / l), q[1] = 0, q[2] = (float) (1 / l);
                        p[0] = 0, p[1] = q[0], p[2] = q[1], p[3] = q[2], p[4] = 1;
                }
        static const char *const names[] = { "height", "nx", "ny", "nz", "mask" };
        snprintf(path, sizeof path, "%s/heightfield.exr", truth);
        CHECK_OK(imp_exr_write(path, img, names, false, NULL));
        imp_image_free(img);
        _cleanup_json_ json_t *tj = json_pack("{s:f,s:[f,f],s:i,s:i}", "pitch_mm", GROOVE_TP, "origin_mm", 0.0, 0.0,
                                               "nx", TNX, "ny", TNX);
        snprintf(path, sizeof path, "%s/truth.json", truth);
        CHECK_OK(imp_json_save_atomic(path, tj, NULL));

        /* The copy: 0.051 mm texels from (0.3, 0.3), normals blended from the truth. */
        struct imp_heightfield hf = { .nx = CNX, .ny = CNX, .pitch_mm = 0.051,
                                      .canvas_to_world = { 1, 0, 0, 0.3, 0, 1, 0, 0.3, 0, 0, 1, 0, 0, 0, 0, 1 } };
        size_t n = (size_t) CNX * CNX;
        hf.height_mm = calloc(n, sizeof(float)), hf.nx_ = calloc(n, sizeof(float)), hf.ny_ = calloc(n, sizeof(float));
        hf.sigma_mm = calloc(n, sizeof(float)), hf.mask = calloc(n, 1);
        CHECK(hf.height_mm && hf.nx_ && hf.ny_ && hf.sigma_mm && hf.mask);
        if (!hf.height_mm || !hf.nx_ || !hf.ny_ || !hf.sigma_mm || !hf.mask) {
                imp_heightfield_done(&hf);
                return;
        }
        for (int j = 0; j < CNX; j++)
                for (int i = 0; i < CNX; i++) {
                        double nn[3];
                        groove_truth_normal(tn, TNX, 0.3 + i * hf.pitch_mm, 0.3 + j * hf.pitch_mm, nn);
                        size_t t = (size_t) j * CNX + i;
                        hf.nx_[t] = (float) nn[0], hf.ny_[t] = (float) nn[1], hf.mask[t] = 1;
                }
        struct imp_error err = {};
        CHECK_OK(imp_heightfield_save(&hf, copy, &err));
        struct imp_compare_result cr = {};
        CHECK_OK(imp_compare_dirs(copy, truth, &cr, &err));
        fprintf(stderr, "copy between truth samples: normal error %.4f deg over %zu texels\n",
                cr.normal_err_deg_mean, cr.n_compared);
        CHECK_INT_EQ(cr.n_compared, n);
        CHECK_LE(cr.normal_err_deg_mean, 0.05);
        CHECK_LE(cr.height_rmse_um, 0.01);
        imp_heightfield_done(&hf);
}

int main(void) {
        test_eigen();
        test_extraction(0);
        test_extraction(10);
        test_save_and_compare();
        test_given_pitch_and_errors();
        test_compare_between_samples();
        return TEST_DONE();
}
