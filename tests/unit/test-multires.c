/* Multi-resolution view-dependent texture (pipeline/appearance/multires.c, seed 003 §4–7) on views
 * rendered here with exact projection of a known texture on the plane z = 0 (pixels are
 * area averages over their footprint): an overview at 1000 mm over the whole 200×150 mm
 * canvas, four tilted close-ups at 250 mm overlapping by 8 mm, a strip seen only by the
 * overview. Checks (1) depths and the layers they reach, (2) the finest layer against the
 * texture and the fill from the coarser layer in the gap, (3) no seam between close-ups of
 * different gain, (4) view dependence at a held-out direction, (5) finite values and empty
 * cells flagged, (6) the EXR pyramid round trip, and the error paths. */
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <time.h>
#include "json-util.h"
#include "multires.h"
#include "unit/test.h"

#define W_MM 200.0
#define H_MM 150.0
#define PIX_SS 3                  /* render: 3×3 sub-pixels per pixel (area average) */

/* ---- scene ---- */

static double tex_low(double x, double y, int c) {
        return 0.45 + 0.2 * sin(2 * M_PI * x / 47 + c) * cos(2 * M_PI * y / 31 + 0.5 * c) +
               0.1 * sin(2 * M_PI * (x + y) / 23 + 2 * c);
}
/* 1.5 mm detail: resolved by the close-ups (0.25 mm pixels), averaged out by the overview. */
static double tex(double x, double y, int c) {
        return tex_low(x, y, c) + 0.06 * sin(2 * M_PI * x / 1.5) * sin(2 * M_PI * y / 1.5);
}

/* Non-Lambertian scene: smooth albedo times a known function of the direction to the eye. */
static double albedo(double x, double y, int c) {
        return 0.5 + 0.2 * sin(2 * M_PI * x / 80 + c) * cos(2 * M_PI * y / 60);
}
static double gdir(const double om[3], int c) {
        return 1 + (0.4 + 0.1 * c) * om[0] - 0.25 * om[1];
}

static uint64_t rng = 0x9e3779b97f4a7c15ull;
static double urand(void) {
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        return ((rng >> 11) + 0.5) / 9007199254740992.0;
}
static double nrand(void) {
        return sqrt(-2 * log(urand())) * cos(2 * M_PI * urand());
}

static struct imp_pinhole cam(int w, int h, double f, const double eye[3], const double at[3]) {
        struct imp_pinhole m = { .width = w, .height = h, .fx = f, .fy = f,
                                 .cx = (w - 1) / 2.0, .cy = (h - 1) / 2.0 };
        imp_pinhole_look_at(&m, eye, at, (double[3]) { 1, 0, 0 });
        return m;
}

/* Renders the view: radiance at the plane point seen by each sub-pixel, averaged; gain and
 * Gaussian noise of sigma per pixel. */
enum scene { SCENE_TEX, SCENE_LOW, SCENE_VDEP };

static struct imp_image *render(const struct imp_pinhole *m, enum scene sc, double gain, double sigma) {
        struct imp_image *img = NULL;
        if (imp_image_new(m->width, m->height, 3, IMP_PIX_F32, &img) < 0)
                abort();
        double C[3];
        imp_pinhole_centre(m, C);
        for (int v = 0; v < m->height; v++)
                for (int u = 0; u < m->width; u++) {
                        double acc[3] = { 0, 0, 0 };
                        for (int b = 0; b < PIX_SS; b++)
                                for (int a = 0; a < PIX_SS; a++) {
                                        double d0 = (u - 0.5 + (a + 0.5) / PIX_SS - m->cx) / m->fx;
                                        double d1 = (v - 0.5 + (b + 0.5) / PIX_SS - m->cy) / m->fy;
                                        double D[3];
                                        for (int i = 0; i < 3; i++)
                                                D[i] = m->R[i] * d0 + m->R[3 + i] * d1 + m->R[6 + i];
                                        double t = -C[2] / D[2], x = C[0] + t * D[0], y = C[1] + t * D[1];
                                        double om[3] = { C[0] - x, C[1] - y, C[2] }, n = 0;
                                        for (int i = 0; i < 3; i++)
                                                n += om[i] * om[i];
                                        for (int i = 0; i < 3; i++)
                                                om[i] /= sqrt(n);
                                        for (int c = 0; c < 3; c++)
                                                acc[c] += sc == SCENE_VDEP ? albedo(x, y, c) * gdir(om, c)
                                                        : sc == SCENE_LOW ? tex_low(x, y, c) : tex(x, y, c);
                                }
                        float *p = imp_image_f32(img, u, v);
                        for (int c = 0; c < 3; c++)
                                p[c] = (float) (gain * acc[c] / (PIX_SS * PIX_SS) + sigma * nrand());
                }
        return img;
}

/* Texture averaged over cell (i, j) of side c. */
static double cell_truth_f(double (*f)(double, double, int), int i, int j, double c, int ch) {
        double s = 0;
        int k = 3;
        for (int b = 0; b < k; b++)
                for (int a = 0; a < k; a++)
                        s += f((i + (a + 0.5) / k) * c, (j + (b + 0.5) / k) * c, ch);
        return s / (k * k);
}
static double cell_truth(int i, int j, double c, int ch) {
        return cell_truth_f(tex, i, j, c, ch);
}

/* Whether canvas point (x, y) projects at least `inset` pixels inside the view's image. */
static bool inside_view(const struct imp_pinhole *m, double x, double y, double inset) {
        double px[2];
        if (!imp_pinhole_project(m, (double[3]) { x, y, 0 }, px))
                return false;
        return px[0] >= inset && px[1] >= inset && px[0] <= m->width - 1 - inset &&
               px[1] <= m->height - 1 - inset;
}

/* ---- the tiled scene ---- */

#define N_CLOSE 4
static const double close_centre[N_CLOSE][2] = { { 45, 40 }, { 117, 40 }, { 45, 92 }, { 117, 92 } };
#define OV_F 666.6667             /* 1000 mm / 1.5 mm per pixel */
#define CU_F 1000.0               /* 250 mm / 0.25 mm per pixel */

struct tiled {
        struct imp_pinhole cams[1 + N_CLOSE];
        struct imp_image *img[1 + N_CLOSE];
        struct imp_multires_view views[1 + N_CLOSE];
        int n;
};

static void tiled_make(struct tiled *t, enum scene sc, bool overview, int n_close,
                       const double *gains, double sigma) {
        *t = (struct tiled) {};
        if (overview) {
                t->cams[t->n] = cam(160, 120, OV_F, (double[3]) { 100, 75, 1000 }, (double[3]) { 100, 75, 0 });
                t->img[t->n] = render(&t->cams[t->n], sc, 1, 0);
                t->n++;
        }
        for (int k = 0; k < n_close; k++) {
                const double *c = close_centre[k];
                double eye[3] = { c[0] + 8, c[1] - 6, 250 }, at[3] = { c[0], c[1], 0 };
                t->cams[t->n] = cam(320, 240, CU_F, eye, at);
                t->img[t->n] = render(&t->cams[t->n], sc, gains ? gains[k] : 1, sigma);
                t->n++;
        }
        for (int v = 0; v < t->n; v++)
                t->views[v] = (struct imp_multires_view) { .image = t->img[v], .camera = t->cams[v] };
}

static void tiled_free(struct tiled *t) {
        for (int v = 0; v < t->n; v++)
                imp_image_free(t->img[v]);
}

static void opts(struct imp_multires_options *o) {
        imp_multires_options_default(o);
        o->width_mm = W_MM;
        o->height_mm = H_MM;
}

static void check_finite(const struct imp_multires *mr) {
        int bad = 0;
        for (int L = 0; L < imp_multires_n_layers(mr); L++) {
                struct imp_multires_layer_info info;
                CHECK_OK(imp_multires_layer_info(mr, L, &info));
                int n = imp_multires_hemi_n(mr);
                for (int j = 0; j < info.ny; j++)
                        for (int i = 0; i < info.nx; i++) {
                                float rgb[3], cov, dir, w;
                                imp_multires_cell(mr, L, i, j, rgb, &cov, &dir);
                                bad += !isfinite(rgb[0]) || !isfinite(rgb[1]) || !isfinite(rgb[2]) ||
                                       !isfinite(cov) || !isfinite(dir) || cov < 0 || cov > 1;
                                if (!info.has_hemi)
                                        continue;
                                for (int b = 0; b < n; b++)
                                        for (int a = 0; a < n; a++) {
                                                imp_multires_hemi(mr, L, i, j, a, b, rgb, &w);
                                                bad += !isfinite(rgb[0]) || !isfinite(rgb[1]) ||
                                                       !isfinite(rgb[2]) || !isfinite(w) || w < 0;
                                        }
                        }
        }
        CHECK_INT_EQ(bad, 0);
}

/* (1), (2), (5) on the full tiled scene. */
static void test_tiled(void) {
        struct tiled t;
        tiled_make(&t, SCENE_TEX, true, N_CLOSE, NULL, 0.004);
        struct imp_multires_options o;
        opts(&o);
        _cleanup_multires_ struct imp_multires *mr = NULL;
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        CHECK_OK(imp_multires_build(&o, t.views, t.n, &mr));
        clock_gettime(CLOCK_MONOTONIC, &t1);
        fprintf(stderr, "build (5 views, 8 layers): %.2f s\n", (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9);
        if (!mr) {
                tiled_free(&t);
                return;
        }
        /* (1) the depth metric: d = log2(c0 / pixel footprint) */
        double d_ov, fp_ov, d_cu, fp_cu;
        CHECK_OK(imp_multires_view_stats(mr, 0, &d_ov, &fp_ov));
        CHECK_OK(imp_multires_view_stats(mr, 1, &d_cu, &fp_cu));
        fprintf(stderr, "depth: overview %.4f (footprint %.4f mm), close-up %.4f (%.4f mm)\n",
                d_ov, fp_ov, d_cu, fp_cu);
        CHECK_NEAR(fp_ov, 1000 / OV_F, 0.03);
        CHECK_NEAR(d_ov, log2(25 / (1000 / OV_F)), 0.03);
        CHECK_NEAR(fp_cu, 250.2 / CU_F, 0.005);
        CHECK_NEAR(d_cu, log2(25 / (250.2 / CU_F)), 0.03);
        int top = (int) ceil(d_cu), ovtop = (int) ceil(d_ov);
        CHECK_INT_EQ(imp_multires_n_layers(mr), top + 1);
        struct imp_multires_layer_info fin;
        CHECK_OK(imp_multires_layer_info(mr, top, &fin));
        CHECK_LE(fin.cell_mm, fp_cu);
        CHECK(fp_cu < 2 * fin.cell_mm);
        fprintf(stderr, "layers %d, finest cell %.4f mm (%dx%d), hemisphere layer %d, %zu bytes\n",
                top + 1, fin.cell_mm, fin.nx, fin.ny, imp_multires_hemi_layer(mr), imp_multires_bytes(mr));

        /* finest layer with direct data, per region: close-ups → ceil(d_cu), gap → ceil(d_ov) */
        double se_cu = 0, se_gap = 0, fill_diff = 0;
        size_t n_cu = 0, n_gap = 0, bad_cu = 0, bad_gap = 0, not_filled = 0;
        for (int j = 0; j < fin.ny; j += 2)
                for (int i = 0; i < fin.nx; i += 2) {
                        double x = (i + 0.5) * fin.cell_mm, y = (j + 0.5) * fin.cell_mm;
                        if (x >= W_MM || y >= H_MM)
                                continue;
                        bool in_cu = false;
                        for (int k = 1; k <= N_CLOSE; k++)
                                in_cu |= inside_view(&t.cams[k], x, y, o.feather_px + 4);
                        bool in_gap = x > 170 && x < 195 && y > 20 && y < 130;
                        if (!in_cu && !in_gap)
                                continue;
                        int finest = -1;
                        for (int L = top; L >= 0 && finest < 0; L--) {
                                float dir;
                                int s = 1 << (top - L);
                                imp_multires_cell(mr, L, i / s, j / s, NULL, NULL, &dir);
                                if (dir > 0)
                                        finest = L;
                        }
                        float rgb[3], cov, dir;
                        imp_multires_cell(mr, top, i, j, rgb, &cov, &dir);
                        if (in_cu) {
                                bad_cu += finest != top;
                                for (int c = 0; c < 3; c++) {
                                        double e = rgb[c] - cell_truth(i, j, fin.cell_mm, c);
                                        se_cu += e * e;
                                }
                                n_cu += 3;
                        } else {
                                bad_gap += finest != ovtop;
                                not_filled += !(dir == 0 && cov > 0);
                                float coarse[3];
                                imp_multires_sample(mr, x, y, NULL, ovtop - 1, coarse, NULL);
                                for (int c = 0; c < 3; c++) {
                                        double e = rgb[c] - tex_low(x, y, c);
                                        se_gap += e * e;
                                        fill_diff += fabs(rgb[c] - coarse[c]);
                                }
                                n_gap += 3;
                        }
                }
        double rmse_cu = sqrt(se_cu / n_cu), rmse_gap = sqrt(se_gap / n_gap);
        fill_diff /= n_gap;
        fprintf(stderr, "finest layer: close-up RMSE %.5f over %zu samples, gap RMSE vs overview "
                "texture %.5f over %zu, mean |finest - layer %d| in gap %.5f\n",
                rmse_cu, n_cu, rmse_gap, n_gap, ovtop - 1, fill_diff);
        CHECK_INT_EQ(bad_cu, 0);
        CHECK_INT_EQ(bad_gap, 0);
        CHECK_INT_EQ(not_filled, 0);
        /* (2) tolerances (measured 0.0089 / 0.0087 / 0.0049): close-ups: the blur of the 0.25 mm
         * pixels and 0.2 mm cells on the 1.5 mm detail (amplitude 0.06) plus noise 0.004; gap:
         * the overview's 1.5 mm pixels and cells blur the ≥16 mm band and leave some of the
         * detail; the fill is the hat-upsampled layer-5 data of the overview. */
        CHECK_LE(rmse_cu, 0.012);
        CHECK_LE(rmse_gap, 0.013);
        CHECK_LE(fill_diff, 0.01);

        /* direct weights: the seed's depth percentages (interior, mask 1) */
        float dir;
        int s = 1 << (top - 4);
        imp_multires_cell(mr, top, (int) (40 / fin.cell_mm), (int) (35 / fin.cell_mm), NULL, NULL, &dir);
        CHECK_NEAR(dir, d_cu - floor(d_cu), 0.01);
        imp_multires_cell(mr, 4, (int) (185 / fin.cell_mm) / s, (int) (75 / fin.cell_mm) / s, NULL, NULL, &dir);
        CHECK_NEAR(dir, 1 - (d_ov - floor(d_ov)), 0.01);
        check_finite(mr);
        tiled_free(&t);
}

/* Column profile of value/truth at the finest layer over x ∈ [x0, x1], rows y ∈ [y0, y1];
 * returns the largest step between neighbouring columns and the two ends. */
static double seam_step(const struct imp_multires *mr, double x0, double x1, double y0, double y1,
                        double *ret_left, double *ret_right) {
        int top = imp_multires_n_layers(mr) - 1;
        struct imp_multires_layer_info fin;
        imp_multires_layer_info(mr, top, &fin);
        double c = fin.cell_mm, prev = NAN, step = 0;
        for (int i = (int) (x0 / c); i <= (int) (x1 / c); i++) {
                double r = 0;
                int n = 0;
                for (int j = (int) (y0 / c); j <= (int) (y1 / c); j++) {
                        float rgb[3];
                        imp_multires_cell(mr, top, i, j, rgb, NULL, NULL);
                        for (int ch = 0; ch < 3; ch++, n++)
                                r += rgb[ch] / cell_truth_f(tex_low, i, j, c, ch);
                }
                r /= n;
                if (getenv("MR_PROFILE"))
                        fprintf(stderr, "  x %.3f ratio %.5f\n", (i + 0.5) * c, r);
                if (isfinite(prev))
                        step = fmax(step, fabs(r - prev));
                else
                        *ret_left = r;
                prev = r;
        }
        *ret_right = prev;
        return step;
}

/* (3) close-ups A (gain 1) and B (gain 1.03) overlap over x ∈ [77, 85] mm. */
static void test_seams(void) {
        const double gains[2] = { 1.0, 1.03 };
        struct tiled t;
        tiled_make(&t, SCENE_LOW, true, 2, gains, 0.004);
        double step[2], left[2], right[2];
        for (int hard = 0; hard < 2; hard++) {
                struct imp_multires_options o;
                opts(&o);
                o.hemi_n = 0;
                if (hard)
                        o.feather_px = 0;
                _cleanup_multires_ struct imp_multires *mr = NULL;
                CHECK_OK(imp_multires_build(&o, t.views, t.n, &mr));
                if (!mr)
                        break;
                step[hard] = seam_step(mr, 70, 95, 18, 62, &left[hard], &right[hard]);
                fprintf(stderr, "seam (%s): largest column step of value/truth %.5f, left %.4f, right %.4f\n",
                        hard ? "hard mask" : "feathered", step[hard], left[hard], right[hard]);
        }
        /* the gain step is there (the test sees it) ... */
        CHECK_NEAR(left[0], 1.0, 0.006);
        CHECK_NEAR(right[0], 1.03, 0.006);
        /* ... and the fade spreads it: no step above 1/8 of it (a hard mask steps by about half) */
        CHECK_LE(step[0], 0.03 / 8);
        CHECK_GE(step[1], 0.03 / 4);
        tiled_free(&t);
}

/* (4) hemisphere arrays: 17 views on three rings, held-out direction between them. */
static void test_view_dependent(const char *dir) {
        enum { NV = 17 };
        struct imp_pinhole cams[NV];
        struct imp_image *imgs[NV];
        struct imp_multires_view views[NV];
        double at[3] = { 100, 75, 0 };
        for (int v = 0; v < NV; v++) {
                double th = v == 0 ? 0 : v <= 6 ? 22 : 45, ph = v == 0 ? 0 : v <= 6 ? v * 60 : (v - 7) * 36 + 18;
                th *= M_PI / 180, ph *= M_PI / 180;
                double eye[3] = { at[0] + 600 * sin(th) * cos(ph), at[1] + 600 * sin(th) * sin(ph), 600 * cos(th) };
                cams[v] = cam(200, 150, 400, eye, at);
                imgs[v] = render(&cams[v], SCENE_VDEP, 1, 0);
                views[v] = (struct imp_multires_view) { .image = imgs[v], .camera = cams[v] };
        }
        struct imp_multires_options o;
        opts(&o);
        o.hemi_layer = 3;
        /* 17 views 22° apart: a 12×12 array and a fade hat reaching about one view spacing
         * (measured: n 8 / fade 0.35 gives 4.5 %, n 12 / fade 0.25 about 2 %) */
        o.hemi_n = 12;
        o.fade_radius = 0.25;
        _cleanup_multires_ struct imp_multires *mr = NULL;
        CHECK_OK(imp_multires_build(&o, views, NV, &mr));
        if (mr) {
                CHECK_INT_EQ(imp_multires_hemi_layer(mr), 3);
                double th = 33 * M_PI / 180, ph = 100 * M_PI / 180;
                double eye[3] = { at[0] + 600 * sin(th) * cos(ph), at[1] + 600 * sin(th) * sin(ph), 600 * cos(th) };
                double se_dep = 0, se_ind = 0;
                size_t n = 0;
                for (double y = 15; y <= 135; y += 3.125)
                        for (double x = 20; x <= 180; x += 3.125) {
                                double om[3] = { eye[0] - x, eye[1] - y, eye[2] }, len = 0;
                                for (int i = 0; i < 3; i++)
                                        len += om[i] * om[i];
                                for (int i = 0; i < 3; i++)
                                        om[i] /= sqrt(len);
                                float dep[3], ind[3];
                                CHECK_OK(imp_multires_sample(mr, x, y, eye, 3, dep, NULL));
                                CHECK_OK(imp_multires_sample(mr, x, y, NULL, 3, ind, NULL));
                                for (int c = 0; c < 3; c++) {
                                        double truth = albedo(x, y, c) * gdir(om, c);
                                        se_dep += pow((dep[c] - truth) / truth, 2);
                                        se_ind += pow((ind[c] - truth) / truth, 2);
                                        n++;
                                }
                        }
                double e_dep = sqrt(se_dep / n), e_ind = sqrt(se_ind / n);
                fprintf(stderr, "held-out direction (33°, 100°): relative RMS error %.4f with the "
                        "hemisphere arrays, %.4f view-independent\n", e_dep, e_ind);
                CHECK_LE(e_dep, 0.03);
                CHECK_LE(e_dep, e_ind / 3);
                check_finite(mr);

                /* (6) round trip */
                struct imp_error err = {};
                int r = imp_multires_save(mr, dir, &err);
                CHECK_MSG(r == 0, "save: %s", err.msg);
                _cleanup_multires_ struct imp_multires *back = NULL;
                r = imp_multires_load(dir, &back, &err);
                CHECK_MSG(r == 0, "load: %s", err.msg);
                if (back) {
                        CHECK_INT_EQ(imp_multires_n_layers(back), imp_multires_n_layers(mr));
                        CHECK_INT_EQ(imp_multires_hemi_layer(back), 3);
                        size_t diff = 0;
                        for (int L = 0; L < imp_multires_n_layers(mr); L++) {
                                struct imp_multires_layer_info a, b;
                                imp_multires_layer_info(mr, L, &a);
                                imp_multires_layer_info(back, L, &b);
                                CHECK_INT_EQ(a.nx, b.nx);
                                CHECK_INT_EQ(a.n_direct, b.n_direct);
                                CHECK_INT_EQ(a.n_empty, b.n_empty);
                                for (int j = 0; j < a.ny; j++)
                                        for (int i = 0; i < a.nx; i++) {
                                                float p[5], q[5];
                                                imp_multires_cell(mr, L, i, j, p, p + 3, p + 4);
                                                imp_multires_cell(back, L, i, j, q, q + 3, q + 4);
                                                diff += memcmp(p, q, sizeof p) != 0;
                                                if (!a.has_hemi)
                                                        continue;
                                                for (int e = 0; e < 144; e++) {
                                                        imp_multires_hemi(mr, L, i, j, e % 12, e / 12, p, p + 3);
                                                        imp_multires_hemi(back, L, i, j, e % 12, e / 12, q, q + 3);
                                                        diff += memcmp(p, q, 4 * sizeof(float)) != 0;
                                                }
                                        }
                        }
                        CHECK_INT_EQ(diff, 0);
                        float a[3], b[3];
                        imp_multires_sample(mr, 61.3, 47.9, eye, 2.4, a, NULL);
                        imp_multires_sample(back, 61.3, 47.9, eye, 2.4, b, NULL);
                        CHECK(memcmp(a, b, sizeof a) == 0);
                }
        }
        for (int v = 0; v < NV; v++)
                imp_image_free(imgs[v]);
}

/* (5) a single close-up: everything outside it is empty (coverage 0, the seed's grey);
 * non-finite input pixels are skipped and counted. */
static void test_empty(void) {
        struct tiled t;
        tiled_make(&t, SCENE_TEX, false, 1, NULL, 0);
        for (int u = 100; u < 110; u++)
                imp_image_f32(t.img[0], u, 120)[1] = NAN;
        imp_image_f32(t.img[0], 5, 5)[0] = INFINITY;
        struct imp_multires_options o;
        opts(&o);
        o.hemi_layer = 2;
        _cleanup_multires_ struct imp_multires *mr = NULL;
        CHECK_OK(imp_multires_build(&o, t.views, t.n, &mr));
        if (mr) {
                CHECK_INT_EQ(imp_multires_nonfinite_px(mr), 11);
                check_finite(mr);
                size_t wrong = 0;
                for (int L = 0; L < imp_multires_n_layers(mr); L++) {
                        struct imp_multires_layer_info info;
                        imp_multires_layer_info(mr, L, &info);
                        CHECK(info.n_empty > 0);
                        for (int j = 0; j < info.ny; j++)
                                for (int i = 0; i < info.nx; i++) {
                                        double x0 = i * info.cell_mm, y0 = j * info.cell_mm;
                                        float rgb[3], cov;
                                        imp_multires_cell(mr, L, i, j, rgb, &cov, NULL);
                                        /* footprint of close-up A: x ∈ [~5, ~93], y ∈ [~4, ~76] */
                                        if (x0 > 100 || y0 > 80 || x0 >= W_MM || y0 >= H_MM)
                                                wrong += cov != 0 || rgb[0] != 0.5f || rgb[2] != 0.5f;
                                        if (x0 > 20 && x0 + info.cell_mm < 70 && y0 > 20 && y0 + info.cell_mm < 60)
                                                wrong += !(cov > 0.99f);
                                }
                }
                CHECK_INT_EQ(wrong, 0);
                float rgb[3], cov;
                CHECK_OK(imp_multires_sample(mr, 150, 120, NULL, 3.5, rgb, &cov));
                CHECK(cov == 0 && rgb[0] == 0.5f);
        }
        tiled_free(&t);
}

static void test_errors(const char *dir) {
        struct tiled t;
        tiled_make(&t, SCENE_TEX, false, 1, NULL, 0);
        struct imp_multires_options o;
        opts(&o);
        struct imp_multires *mr = (struct imp_multires *) 0x1;
        CHECK_ERR(imp_multires_build(&o, t.views, 0, &mr), -EINVAL);
        struct imp_multires_options bad = o;
        bad.width_mm = 0;
        CHECK_ERR(imp_multires_build(&bad, t.views, 1, &mr), -EINVAL);
        bad = o;
        bad.base_cell_mm = NAN;
        CHECK_ERR(imp_multires_build(&bad, t.views, 1, &mr), -EINVAL);
        struct imp_image *two = NULL;
        CHECK_OK(imp_image_new(8, 8, 2, IMP_PIX_F32, &two));
        struct imp_multires_view v = t.views[0];
        v.image = two;
        CHECK_ERR(imp_multires_build(&o, &v, 1, &mr), -EINVAL);
        imp_image_free(two);
        /* a view looking away from the canvas sees nothing */
        v = t.views[0];
        v.camera = cam(320, 240, CU_F, (double[3]) { 45, 40, 250 }, (double[3]) { 45, 40, 500 });
        CHECK_ERR(imp_multires_build(&o, &v, 1, &mr), -ENODATA);
        CHECK(mr == (struct imp_multires *) 0x1);   /* untouched on failure */

        struct imp_error err = {};
        char path[512];
        snprintf(path, sizeof path, "%s/none", dir);
        CHECK_ERR(imp_multires_load(path, &mr, &err), -ENOENT);
        snprintf(path, sizeof path, "%s/bad", dir);
        imp_mkdir_p(path, 0755);
        snprintf(path, sizeof path, "%s/bad/index.json", dir);
        FILE *f = fopen(path, "w");
        if (f) {
                fputs("{\"format\": \"impasto-multires\", \"n_layers\": 99}", f);
                fclose(f);
        }
        snprintf(path, sizeof path, "%s/bad", dir);
        CHECK_ERR(imp_multires_load(path, &mr, &err), -EBADMSG);
        CHECK(mr == (struct imp_multires *) 0x1);
        tiled_free(&t);
}

int main(void) {
        char dir[512];
        snprintf(dir, sizeof dir, "%s/pyramid", test_tmpdir());
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
#define TIMED(call) do { call; clock_gettime(CLOCK_MONOTONIC, &t1); \
        fprintf(stderr, "%s: %.2f s\n", #call, (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9); \
        t0 = t1; } while (0)
        TIMED(test_tiled());
        TIMED(test_seams());
        TIMED(test_view_dependent(dir));
        TIMED(test_empty());
        TIMED(test_errors(test_tmpdir()));
        return TEST_DONE();
}
