/* Hybrid renderer (seed §5): the three modes agree on a flat copy and match V = E·cosθ·f;
 * relief mapping displaces a block's silhouette by its parallax; the adaptive α switches
 * with distance and angle; no NaN for grazing rays or a camera below the plane. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "relief-render.h"
#include "unit/test.h"

#define PITCH 0.5
#define NX 160
#define NY 100

struct copy_buf {
        float h[NX * NY], nx[NX * NY], ny[NX * NY];
        struct imp_lafortune brdf[NX * NY];
        struct imp_relief_box boxes[4];
        struct imp_relief_copy copy;
};

static void copy_init(struct copy_buf *b, size_t n_boxes) {
        memset(b, 0, sizeof *b);
        for (int k = 0; k < NX * NY; k++)
                b->brdf[k] = (struct imp_lafortune) { .rho_d = { 1, 1, 1 }, .cx = -1, .cy = -1, .cz = 1, .k = 10 };
        b->copy = (struct imp_relief_copy) {
                .nx = NX, .ny = NY, .pitch_mm = PITCH, .height_mm = b->h, .normal_x = b->nx,
                .normal_y = b->ny, .brdf = b->brdf, .boxes = b->boxes, .n_boxes = n_boxes,
                .delta0_mm = 0,
                .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 },
        };
}

/* Block of height hb over texels [70, 89] × [40, 59], albedo 1 on it and `floor` around,
 * inside one box [60, 99] × [30, 69]. */
static void block_init(struct copy_buf *b, float hb, float floor_albedo) {
        copy_init(b, 1);
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        bool in = i >= 70 && i < 90 && j >= 40 && j < 60;
                        b->h[j * NX + i] = in ? hb : 0;
                        float a = in ? 1 : floor_albedo;
                        b->brdf[j * NX + i].rho_d[0] = b->brdf[j * NX + i].rho_d[1] = b->brdf[j * NX + i].rho_d[2] = a;
                        b->brdf[j * NX + i].rho_s[0] = 0;
                }
        b->boxes[0] = (struct imp_relief_box) { .u0 = 60, .v0 = 30, .w = 40, .h = 40, .hmax_mm = hb,
                                                 .umax = 80, .vmax = 50 };
}

static struct imp_pinhole view_at(const double eye[3], const double target[3], int w, int h, double f) {
        struct imp_pinhole m = { .width = w, .height = h, .fx = f, .fy = f, .cx = (w - 1) / 2.0,
                                 .cy = (h - 1) / 2.0 };
        double right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&m, eye, target, right);
        return m;
}

static struct imp_rig_light light_at(double x, double y, double z, double exp) {
        struct imp_rig_light l = { .pos_mm = { x, y, z }, .intensity = 1, .colour = { 1, 1, 1 },
                                   .axis = { 0, 0, -1 }, .profile_exp = exp };
        return l;
}

static struct imp_image *render(const struct imp_relief_scene *s, const struct imp_pinhole *v,
                                const struct imp_rig_light *l, enum imp_relief_mode mode, bool shadows,
                                int channels, struct imp_image **ret_alpha, struct imp_relief_stats *st) {
        struct imp_relief_options o;
        imp_relief_options_default(&o);
        o.mode = mode;
        o.K = 1000;
        o.shadows = shadows;
        struct imp_image *img = NULL;
        CHECK_OK(imp_image_new(v->width, v->height, channels, IMP_PIX_F32, &img));
        if (ret_alpha)
                CHECK_OK(imp_image_new(v->width, v->height, 1, IMP_PIX_F32, ret_alpha));
        CHECK_OK(imp_relief_render(s, v, l, &o, img, ret_alpha ? *ret_alpha : NULL, st));
        return img;
}

static double max_diff(const struct imp_image *a, const struct imp_image *b) {
        double m = 0;
        for (int y = 0; y < a->height; y++)
                for (int x = 0; x < a->width; x++)
                        for (int c = 0; c < a->channels; c++)
                                m = fmax(m, fabs(imp_image_f32(a, x, y)[c] - imp_image_f32(b, x, y)[c]));
        return m;
}

static size_t count_nonfinite(const struct imp_image *a) {
        size_t n = 0;
        for (int y = 0; y < a->height; y++)
                for (int x = 0; x < a->width * a->channels; x++)
                        n += !isfinite(((float *) imp_image_row(a, y))[x]);
        return n;
}

/* Flat copy, no boxes: the three modes are the same image and match the analytic V. */
static void test_flat(void) {
        static struct copy_buf b;
        copy_init(&b, 0);
        for (int k = 0; k < NX * NY; k++)
                b.brdf[k] = (struct imp_lafortune) { .rho_d = { 1, 1, 1 } };   /* white Lambertian */
        struct imp_relief_scene *s = NULL;
        CHECK_OK(imp_relief_scene_new(&b.copy, &s));
        double eye[3] = { 30, 10, 200 }, target[3] = { 40, 25, 0 };
        struct imp_pinhole v = view_at(eye, target, 160, 120, 300);
        struct imp_rig_light l = light_at(20, 30, 250, 2);
        struct imp_image *im[3];
        for (int m = 0; m < 3; m++)
                im[m] = render(s, &v, &l, (enum imp_relief_mode) m, false, 3, NULL, NULL);
        CHECK_LE(max_diff(im[0], im[1]), 1e-5);
        CHECK_LE(max_diff(im[0], im[2]), 1e-5);
        /* Analytic V = E · cos θl with E = intensity (1000/d)² cos^p(angle to axis). */
        int n_checked = 0;
        double worst = 0;
        for (int py = 0; py < v.height; py += 7)
                for (int px = 0; px < v.width; px += 9) {
                        double pp[2] = { px, py }, o[3], d[3];
                        imp_pinhole_ray_world(&v, pp, o, d);
                        double t = -o[2] / d[2];
                        double P[3] = { o[0] + t * d[0], o[1] + t * d[1], 0 };
                        double expect = 0;
                        if (P[0] >= -0.5 * PITCH && P[0] < (NX - 0.5) * PITCH && P[1] >= -0.5 * PITCH &&
                            P[1] < (NY - 0.5) * PITCH) {
                                double L[3] = { l.pos_mm[0] - P[0], l.pos_mm[1] - P[1], l.pos_mm[2] - P[2] };
                                double dist = sqrt(L[0] * L[0] + L[1] * L[1] + L[2] * L[2]);
                                double cos_l = L[2] / dist, cos_ax = L[2] / dist;
                                expect = 1e6 / (dist * dist) * pow(cos_ax, 2) * cos_l;
                                n_checked++;
                        }
                        for (int c = 0; c < 3; c++) {
                                double got = imp_image_f32(im[0], px, py)[c];
                                worst = fmax(worst, fabs(got - expect) / fmax(expect, 1e-3));
                        }
                }
        CHECK_INT_GE(n_checked, 100);
        CHECK_LE(worst, 1e-5);
        for (int m = 0; m < 3; m++)
                imp_image_free(im[m]);

        /* A box over flat relief: the relief search lands on the box floor = the bump plane. */
        b.copy.n_boxes = 1;
        b.boxes[0] = (struct imp_relief_box) { .u0 = 50, .v0 = 20, .w = 40, .h = 40, .umax = 60, .vmax = 30 };
        struct imp_relief_scene *s2 = NULL;
        CHECK_OK(imp_relief_scene_new(&b.copy, &s2));
        struct imp_relief_stats st;
        struct imp_image *bump = render(s2, &v, &l, IMP_RELIEF_BUMP_ONLY, false, 1, NULL, NULL);
        struct imp_image *rel = render(s2, &v, &l, IMP_RELIEF_RELIEF_ALL, false, 1, NULL, &st);
        CHECK_INT_GE(st.n_pixels_relief, 500);
        CHECK_LE(max_diff(bump, rel), 1e-5 * 30);  /* values ~ 30: 1e-5 relative */
        imp_image_free(bump);
        imp_image_free(rel);
        imp_relief_scene_free(s2);
        imp_relief_scene_free(s);
}

static int last_lit(const struct imp_image *img, int row) {
        for (int x = img->width - 1; x >= 0; x--)
                if (imp_image_f32(img, x, row)[0] > 0)
                        return x;
        return -1;
}

/* The block's far edge moves by hb·tan θ / pitch texels (measured on the plane z = 0). */
static void test_parallax(void) {
        static struct copy_buf b;
        const double hb = 2.0, theta = 40 * M_PI / 180;
        block_init(&b, (float) hb, 0);
        struct imp_relief_scene *s = NULL;
        CHECK_OK(imp_relief_scene_new(&b.copy, &s));
        double target[3] = { 40, 25, 0 }, D = 300;
        double eye[3] = { target[0] - D * sin(theta), target[1], D * cos(theta) };
        struct imp_pinhole v = view_at(eye, target, 600, 300, 2000);
        struct imp_rig_light l = light_at(-60, 25, 300, 0);
        struct imp_image *bump = render(s, &v, &l, IMP_RELIEF_BUMP_ONLY, false, 1, NULL, NULL);
        struct imp_image *rel = render(s, &v, &l, IMP_RELIEF_RELIEF_ALL, false, 1, NULL, NULL);
        int row = (int) v.cy;
        int eb = last_lit(bump, row), er = last_lit(rel, row);
        CHECK_INT_GE(eb, 0);
        CHECK_INT_GE(er, 0);
        double pb[2] = { eb + 0.5, row }, pr[2] = { er + 0.5, row }, o[3], db[3], dr[3];
        imp_pinhole_ray_world(&v, pb, o, db);
        double xb = o[0] - o[2] / db[2] * db[0];
        imp_pinhole_ray_world(&v, pr, o, dr);
        double xr = o[0] - o[2] / dr[2] * dr[0];
        double expect = hb * (dr[0] / -dr[2]) / PITCH;
        double got = (xr - xb) / PITCH;
        fprintf(stderr, "parallax: bump edge x %.3f mm, relief %.3f mm: %.2f texels, expected %.2f\n",
                xb, xr, got, expect);
        CHECK_NEAR(xb / PITCH, 89.5, 1.0);
        CHECK_NEAR(got, expect, 1.0);
        CHECK(count_nonfinite(rel) == 0);
        imp_image_free(bump);
        imp_image_free(rel);

        /* Shadows: a low light from −x darkens floor behind the block (floor albedo 0.5). */
        block_init(&b, (float) hb, 0.5f);
        struct imp_rig_light low = light_at(-300, 25, 40, 0);
        struct imp_image *lit = render(s, &v, &low, IMP_RELIEF_RELIEF_ALL, false, 1, NULL, NULL);
        struct imp_image *sh = render(s, &v, &low, IMP_RELIEF_RELIEF_ALL, true, 1, NULL, NULL);
        size_t n_dark = 0;
        for (int y = 0; y < v.height; y++)
                for (int x = 0; x < v.width; x++)
                        n_dark += imp_image_f32(lit, x, y)[0] > 0 && imp_image_f32(sh, x, y)[0] == 0;
        fprintf(stderr, "shadows: %zu pixels shadowed\n", n_dark);
        CHECK_INT_GE(n_dark, 500);
        CHECK(count_nonfinite(sh) == 0);
        imp_image_free(lit);
        imp_image_free(sh);
        imp_relief_scene_free(s);
}

/* α = 0 far away (ADAPTIVE = BUMP), α = 1 close and grazing (ADAPTIVE = RELIEF). */
static void test_adaptive(void) {
        static struct copy_buf b;
        block_init(&b, 2.0f, 0.3f);
        struct imp_relief_scene *s = NULL;
        CHECK_OK(imp_relief_scene_new(&b.copy, &s));
        struct imp_relief_options o;
        imp_relief_options_default(&o);
        o.K = 1000;
        double target[3] = { 40, 25, 0 };
        struct imp_rig_light l = light_at(-60, 25, 300, 0);
        float a = -1;

        double far[3] = { 40, 25, 1e5 };
        struct imp_pinhole vf = view_at(far, target, 200, 150, 1e5);
        CHECK_INT_EQ(imp_relief_box_alpha(s, &vf, &o, &a), 0);
        CHECK_NEAR(a, 0, 0);
        struct imp_relief_stats st;
        struct imp_image *alpha = NULL;
        struct imp_image *ad = render(s, &vf, &l, IMP_RELIEF_ADAPTIVE, false, 3, &alpha, &st);
        struct imp_image *bu = render(s, &vf, &l, IMP_RELIEF_BUMP_ONLY, false, 3, NULL, NULL);
        CHECK_INT_EQ(st.n_boxes_drawn, 0);
        CHECK_INT_GE(st.n_pixels_hit, 1000);
        CHECK_LE(max_diff(ad, bu), 1e-6);
        imp_image_free(ad);
        imp_image_free(bu);
        imp_image_free(alpha);

        double th = 75 * M_PI / 180, D = 100;
        double near[3] = { 40 - D * sin(th), 25, D * cos(th) };
        struct imp_pinhole vn = view_at(near, target, 300, 200, 600);
        CHECK_INT_EQ(imp_relief_box_alpha(s, &vn, &o, &a), 0);
        CHECK_NEAR(a, 1, 0);
        ad = render(s, &vn, &l, IMP_RELIEF_ADAPTIVE, false, 3, &alpha, &st);
        struct imp_image *re = render(s, &vn, &l, IMP_RELIEF_RELIEF_ALL, false, 3, NULL, NULL);
        CHECK_INT_EQ(st.n_boxes_drawn, 1);
        CHECK_INT_GE(st.n_pixels_relief, 1000);
        CHECK_LE(max_diff(ad, re), 1e-6);
        imp_image_free(ad);
        imp_image_free(re);
        imp_image_free(alpha);

        /* In between: frontal at 1600 mm, I 2 mm up: K·r = 1000 · 2 / 1598 ≈ 1.25 → α ≈ 0.5. */
        double mid[3] = { 40, 25, 1600 };
        struct imp_pinhole vm = view_at(mid, target, 100, 100, 2000);
        CHECK_INT_EQ(imp_relief_box_alpha(s, &vm, &o, &a), 0);
        double r = 2.0 / 1598.0;
        CHECK_NEAR(a, (1000 * r - 0.5) / 1.5, 1e-3);
        imp_relief_scene_free(s);
}

/* Grazing rays and cameras on / below the plane: finite values, zeros and a flag. */
static void test_degenerate(void) {
        static struct copy_buf b;
        block_init(&b, 2.0f, 0.3f);
        struct imp_relief_scene *s = NULL;
        CHECK_OK(imp_relief_scene_new(&b.copy, &s));
        struct imp_rig_light l = light_at(-60, 25, 300, 3);
        double target[3] = { 40, 25, 0 };
        double graze[3] = { 40, -200, 1e-3 };
        struct imp_pinhole vg = view_at(graze, target, 200, 150, 300);
        for (int m = 0; m < 3; m++) {
                struct imp_relief_stats st;
                struct imp_image *alpha = NULL;
                struct imp_image *im = render(s, &vg, &l, (enum imp_relief_mode) m, true, 3, &alpha, &st);
                CHECK(count_nonfinite(im) == 0);
                CHECK(count_nonfinite(alpha) == 0);
                CHECK_INT_EQ(st.flags, 0);
                imp_image_free(im);
                imp_image_free(alpha);
        }
        double zs[2] = { -50, 0 };
        for (int k = 0; k < 2; k++) {
                double below[3] = { 40, 10, zs[k] };
                double up[3] = { 40, 25, 30 };
                struct imp_pinhole vb = view_at(below, up, 120, 90, 200);
                struct imp_relief_stats st;
                struct imp_image *alpha = NULL;
                struct imp_image *im = render(s, &vb, &l, IMP_RELIEF_RELIEF_ALL, false, 3, &alpha, &st);
                CHECK_INT_EQ(st.flags, IMP_RELIEF_CAMERA_BELOW);
                double m = 0;
                for (int y = 0; y < im->height; y++)
                        for (int x = 0; x < im->width; x++)
                                m = fmax(m, fabs(imp_image_f32(im, x, y)[0]) + fabs(imp_image_f32(alpha, x, y)[0]));
                CHECK_NEAR(m, 0, 0);
                imp_image_free(im);
                imp_image_free(alpha);
        }
        imp_relief_scene_free(s);
}

static void test_errors(void) {
        static struct copy_buf b;
        block_init(&b, 2.0f, 0.3f);
        struct imp_relief_scene *s = NULL;
        b.boxes[1] = b.boxes[0];
        b.boxes[1].u0 += 10;               /* overlaps box 0 */
        b.copy.n_boxes = 2;
        CHECK_ERR(imp_relief_scene_new(&b.copy, &s), -EINVAL);
        b.boxes[1].u0 = NX - 10;           /* leaves the grid */
        CHECK_ERR(imp_relief_scene_new(&b.copy, &s), -EINVAL);
        b.copy.n_boxes = 1;
        b.h[5] = NAN;
        CHECK_ERR(imp_relief_scene_new(&b.copy, &s), -EINVAL);
        b.h[5] = 0;
        b.copy.canvas_to_world[0] = 2;     /* not rigid */
        CHECK_ERR(imp_relief_scene_new(&b.copy, &s), -EINVAL);
        b.copy.canvas_to_world[0] = 1;
        CHECK(s == NULL);
        CHECK_OK(imp_relief_scene_new(&b.copy, &s));
        double eye[3] = { 40, 25, 200 }, target[3] = { 40, 25, 0 };
        struct imp_pinhole v = view_at(eye, target, 64, 48, 200);
        struct imp_rig_light l = light_at(0, 0, 200, 0);
        struct imp_relief_options o;
        imp_relief_options_default(&o);
        struct imp_image *img = NULL;
        CHECK_OK(imp_image_new(63, 48, 1, IMP_PIX_F32, &img));
        CHECK_ERR(imp_relief_render(s, &v, &l, &o, img, NULL, NULL), -EINVAL);
        imp_image_free(img);
        CHECK_OK(imp_image_new(64, 48, 1, IMP_PIX_F32, &img));
        o.eps_max = 0.1;                   /* below eps_min */
        CHECK_ERR(imp_relief_render(s, &v, &l, &o, img, NULL, NULL), -EINVAL);
        imp_relief_options_default(&o);
        l.intensity = NAN;
        CHECK_ERR(imp_relief_render(s, &v, &l, &o, img, NULL, NULL), -EINVAL);
        imp_image_free(img);
        imp_relief_scene_free(s);
        imp_relief_scene_free(NULL);
}

int main(void) {
        test_flat();
        test_parallax();
        test_adaptive();
        test_degenerate();
        test_errors();
        return TEST_DONE();
}
