/* Hybrid renderer speed (seed §6, Tables 1–2) on a synthetic 1200 × 800-texel copy with
 * ridges: best-of-3 ms per 1-Mpix frame (1000 × 1000, CPU, OpenMP threads) per mode and view, and
 * per box size n for the adaptive mode. Copy generation is not timed.
 * Usage: bench-relief [frame_side_px] (default 1000). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "relief-render.h"

#define NX 1200
#define NY 800
#define PITCH_MM 0.25
#define DELTA_FRAC 0.3

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Brush ridges: a few oblique strokes plus low paint texture; max about 1 mm. */
static double relief_mm(int i, int j) {
        double x = i * PITCH_MM, y = j * PITCH_MM;
        double stroke = pow(fmax(0, sin(0.35 * x + 0.12 * y) * cos(0.05 * y - 0.02 * x)), 6);
        return 0.9 * stroke + 0.08 * sin(2.1 * x) * sin(1.7 * y) + 0.08;
}

struct copy {
        float *h, *nx, *ny;
        struct imp_lafortune *brdf;
        struct imp_relief_box *boxes;
        size_t n_boxes;
        double H, delta0;
};

static void make_copy(struct copy *c) {
        size_t n = (size_t) NX * NY;
        c->h = malloc(n * sizeof *c->h);
        c->nx = malloc(n * sizeof *c->nx);
        c->ny = malloc(n * sizeof *c->ny);
        c->brdf = malloc(n * sizeof *c->brdf);
        c->boxes = malloc(n * sizeof *c->boxes);  /* upper bound for n = 1 */
        if (!c->h || !c->nx || !c->ny || !c->brdf || !c->boxes) {
                fprintf(stderr, "out of memory\n");
                exit(1);
        }
        c->H = 0;
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        c->h[(size_t) j * NX + i] = (float) relief_mm(i, j);
                        c->H = fmax(c->H, relief_mm(i, j));
                }
        c->delta0 = DELTA_FRAC * c->H;
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        size_t k = (size_t) j * NX + i;
                        double gx = (c->h[j * NX + (i < NX - 1 ? i + 1 : i)] - c->h[j * NX + (i > 0 ? i - 1 : i)]) / (2 * PITCH_MM);
                        double gy = (c->h[(j < NY - 1 ? j + 1 : j) * NX + i] - c->h[(j > 0 ? j - 1 : j) * NX + i]) / (2 * PITCH_MM);
                        double s = 1 / sqrt(1 + gx * gx + gy * gy);
                        c->nx[k] = (float) (-gx * s);
                        c->ny[k] = (float) (-gy * s);
                        float a = (float) (0.4 + 0.3 * sin(0.02 * i) * cos(0.03 * j));
                        c->brdf[k] = (struct imp_lafortune) { .rho_d = { a, 0.8f * a, 0.6f * a },
                                                              .rho_s = { 0.3f, 0.3f, 0.3f },
                                                              .cx = -1, .cy = -1, .cz = 1, .k = 20 };
                }
}

/* Seed §4.3: an n × n cell holding a texel above δ0 becomes a box. */
static void make_boxes(struct copy *c, int n) {
        c->n_boxes = 0;
        for (int v0 = 0; v0 < NY; v0 += n)
                for (int u0 = 0; u0 < NX; u0 += n) {
                        struct imp_relief_box b = { .u0 = u0, .v0 = v0, .w = n < NX - u0 ? n : NX - u0,
                                                    .h = n < NY - v0 ? n : NY - v0, .hmax_mm = -1 };
                        for (int j = v0; j < v0 + b.h; j++)
                                for (int i = u0; i < u0 + b.w; i++)
                                        if (c->h[(size_t) j * NX + i] > b.hmax_mm) {
                                                b.hmax_mm = c->h[(size_t) j * NX + i];
                                                b.umax = i, b.vmax = j;
                                        }
                        if (b.hmax_mm > c->delta0)
                                c->boxes[c->n_boxes++] = b;
                }
}

struct view { const char *dist, *angle; double D_mm, theta_deg; };

static struct imp_pinhole camera(const struct view *v, int side) {
        double f = side;                          /* 90°-ish wide: 2·atan(0.5) ≈ 53° */
        double target[3] = { NX * PITCH_MM / 2, NY * PITCH_MM / 2, 0 };
        double th = v->theta_deg * M_PI / 180;
        double eye[3] = { target[0] - v->D_mm * sin(th), target[1], v->D_mm * cos(th) };
        struct imp_pinhole m = { .width = side, .height = side, .fx = f, .fy = f,
                                 .cx = (side - 1) / 2.0, .cy = (side - 1) / 2.0 };
        double right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&m, eye, target, right);
        return m;
}

static double time_frame(const struct imp_relief_scene *s, const struct imp_pinhole *cam,
                         const struct imp_rig_light *l, enum imp_relief_mode mode,
                         struct imp_image *img, struct imp_relief_stats *st) {
        struct imp_relief_options o;
        imp_relief_options_default(&o);
        o.mode = mode;
        double best = INFINITY;         /* best of 3: the cores are shared */
        for (int rep = 0; rep < 3; rep++) {
                double t0 = now_s();
                int r = imp_relief_render(s, cam, l, &o, img, NULL, st);
                double dt = now_s() - t0;
                if (r < 0) {
                        fprintf(stderr, "render: %d\n", r);
                        exit(1);
                }
                best = fmin(best, dt);
        }
        return best * 1e3 / (img->width * (double) img->height / 1e6);   /* ms per Mpix */
}

static struct imp_relief_scene *scene(struct copy *c, int n) {
        make_boxes(c, n);
        struct imp_relief_copy cp = {
                .nx = NX, .ny = NY, .pitch_mm = PITCH_MM, .height_mm = c->h, .normal_x = c->nx,
                .normal_y = c->ny, .brdf = c->brdf, .boxes = c->boxes, .n_boxes = c->n_boxes,
                .delta0_mm = c->delta0,
                .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 },
        };
        struct imp_relief_scene *s = NULL;
        int r = imp_relief_scene_new(&cp, &s);
        if (r < 0) {
                fprintf(stderr, "scene: %d\n", r);
                exit(1);
        }
        return s;
}

int main(int argc, char **argv) {
        int side = argc > 1 ? atoi(argv[1]) : 1000;
        if (side < 64 || side > 4096) {
                fprintf(stderr, "frame side must be 64..4096\n");
                return 2;
        }
        struct copy c;
        make_copy(&c);
        struct imp_image *img = NULL;
        if (imp_image_new(side, side, 3, IMP_PIX_F32, &img) < 0)
                return 1;
        struct imp_rig_light light = { .pos_mm = { NX * PITCH_MM / 2 - 200, NY * PITCH_MM / 2 + 100, 400 },
                                       .intensity = 1, .colour = { 1, 1, 1 }, .axis = { 0.4, -0.2, -0.9 },
                                       .profile_exp = 1 };
        /* near: 1/4 of the copy's width fills the frame; in shot: all of it; far: 1/5. */
        const struct view views[] = {
                { "near", "grazing", 80, 70 },  { "near", "front", 80, 0 },
                { "in shot", "grazing", 320, 70 }, { "in shot", "front", 320, 0 },
                { "far", "grazing", 1500, 70 }, { "far", "front", 1500, 0 },
        };
        printf("copy %d x %d texels, pitch %.2f mm, H %.2f mm, delta0 %.2f mm; frame %d x %d px; ms per Mpix\n\n",
               NX, NY, PITCH_MM, c.H, c.delta0, side, side);

        /* Table 1 shape: n = 20, every mode and view. */
        struct imp_relief_scene *s = scene(&c, 20);
        printf("Table 1 (box size 20, %zu boxes)\n", c.n_boxes);
        printf("| %-8s | %-7s | %8s | %8s | %8s | %12s |\n", "dist.", "angle", "bump", "relief",
               "adaptive", "boxes drawn");
        printf("|----------|---------|----------|----------|----------|--------------|\n");
        for (size_t k = 0; k < sizeof views / sizeof *views; k++) {
                struct imp_pinhole cam = camera(&views[k], side);
                struct imp_relief_stats st;
                double tb = time_frame(s, &cam, &light, IMP_RELIEF_BUMP_ONLY, img, &st);
                double tr = time_frame(s, &cam, &light, IMP_RELIEF_RELIEF_ALL, img, &st);
                double ta = time_frame(s, &cam, &light, IMP_RELIEF_ADAPTIVE, img, &st);
                printf("| %-8s | %-7s | %8.1f | %8.1f | %8.1f | %5zu / %-5zu |\n", views[k].dist,
                       views[k].angle, tb, tr, ta, st.n_boxes_drawn, c.n_boxes);
                fflush(stdout);
        }
        imp_relief_scene_free(s);

        /* Table 2 shape: adaptive mode per box size, in-shot distance, three angles. */
        const struct view t2[] = { { "in shot", "front", 320, 0 }, { "in shot", "interm.", 320, 45 },
                                   { "in shot", "grazing", 320, 70 } };
        const int sizes[] = { 5, 10, 20, 50, 100 };
        printf("\nTable 2 (adaptive / relief-all, in shot; ms per Mpix)\n");
        printf("| %-8s | %7s | %17s | %17s | %17s |\n", "box size", "# boxes", "front", "intermediate",
               "grazing");
        printf("|----------|---------|-------------------|-------------------|-------------------|\n");
        for (size_t k = 0; k < sizeof sizes / sizeof *sizes; k++) {
                s = scene(&c, sizes[k]);
                printf("| %3d x %-3d| %7zu |", sizes[k], sizes[k], c.n_boxes);
                for (size_t a = 0; a < 3; a++) {
                        struct imp_pinhole cam = camera(&t2[a], side);
                        struct imp_relief_stats st;
                        double ta = time_frame(s, &cam, &light, IMP_RELIEF_ADAPTIVE, img, &st);
                        double tr = time_frame(s, &cam, &light, IMP_RELIEF_RELIEF_ALL, img, &st);
                        printf(" %7.1f / %7.1f |", ta, tr);
                }
                printf("\n");
                fflush(stdout);
                imp_relief_scene_free(s);
        }
        imp_image_free(img);
        free(c.h), free(c.nx), free(c.ny), free(c.brdf), free(c.boxes);
        return 0;
}
