/* Mirror-sphere detection and cut-sphere fits (pipeline/calib/calib-lights.c) on
 * analytic renders of the demo camera (1400×1000, f 6000 px, 300 mm above the canvas, with
 * lens distortion): the per-pixel maximum image of a light calibration — a bright board, dark
 * sphere bodies with highlights inside — ray-cast with 3×3 supersampling and noise.
 * Detection must find exactly the spheres (not a dark square, a disc cut by the frame or a
 * small blot), sub-pixel; the 3D centre from the known radius must be within 2 µm for balls
 * (a dark square in the crop next to one: edge outliers rejected), half balls and spherical
 * caps (the fit modelling the rim); fitting a cut sphere as a ball must be worse. */
#include <math.h>
#include <stdint.h>
#include "calib-lights.h"
#include "test.h"

#define BG 1000.0
#define BODY 30.0
#define NOISE 3.0
#define MAX_FOUND 16

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static double nrand(void) { return test_nrand(&rng_state); }
static double dot(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static struct imp_pinhole camera(void) {
        struct imp_pinhole m = { .width = 1400, .height = 1000, .fx = 6000, .fy = 6000, .cx = 699.5, .cy = 499.5,
                                 .k1 = -0.08, .k2 = 0.02, .p1 = 0.0002, .p2 = -0.0001 };
        double eye[3] = { 30, 20, 300 }, at[3] = { 30, 20, 0 }, right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&m, eye, at, right);
        return m;
}

/* A sphere of radius r at C, cut by z = C_z + cut (NAN: whole): does the ray hit its solid? */
static bool hits(const double O[3], const double d[3], const double C[3], double r, double cut) {
        double w[3] = { O[0] - C[0], O[1] - C[1], O[2] - C[2] }, b = dot(w, d), c = dot(w, w) - r * r;
        if (b * b - c < 0)
                return false;
        double t = -b - sqrt(b * b - c);
        return t > 0 && (isnan(cut) || O[2] + t * d[2] >= C[2] + cut);
}

struct object {
        double C[3], r, cut;
};

/* The max image: board, dark objects, a ring of highlights inside each sphere, a dark square. */
static struct imp_image *render(const struct imp_pinhole *cam, const struct object *obj, int n, const double sq[4]) {
        struct imp_image *img = NULL;
        if (imp_image_new(cam->width, cam->height, 1, IMP_PIX_F32, &img) < 0)
                exit(2);
        for (int y = 0; y < cam->height; y++)
                for (int x = 0; x < cam->width; x++) {
                        double s = 0;
                        for (int j = 0; j < 3; j++)
                                for (int i = 0; i < 3; i++) {
                                        double px[2] = { x + (i - 1) / 3.0, y + (j - 1) / 3.0 }, O[3], d[3];
                                        imp_pinhole_ray_world(cam, px, O, d);
                                        double t = -O[2] / d[2], gx = O[0] + t * d[0], gy = O[1] + t * d[1];
                                        bool dark = gx >= sq[0] && gx <= sq[2] && gy >= sq[1] && gy <= sq[3];
                                        for (int k = 0; k < n && !dark; k++)
                                                dark = hits(O, d, obj[k].C, obj[k].r, obj[k].cut);
                                        s += dark ? BODY : BG;
                                }
                        *imp_image_f32(img, x, y) = (float) (s / 9 + NOISE * nrand());
                }
        /* highlights: 12 bright spots on a ring at half the image radius of each sphere */
        for (int k = 0; k < n; k++) {
                double c[2], top[3] = { obj[k].C[0], obj[k].C[1], obj[k].C[2] + obj[k].r };
                if (!imp_pinhole_project(cam, top, c))
                        continue;
                for (int h = 0; h < 12; h++) {
                        double sx = c[0] + 60 * cos(h * M_PI / 6), sy = c[1] + 60 * sin(h * M_PI / 6);
                        for (int y = (int) sy - 5; y <= (int) sy + 5; y++)
                                for (int x = (int) sx - 5; x <= (int) sx + 5; x++)
                                        if (x >= 0 && y >= 0 && x < img->width && y < img->height)
                                                *imp_image_f32(img, x, y) += (float) (3000 * exp(-((x - sx) * (x - sx) + (y - sy) * (y - sy)) / 4));
                }
        }
        return img;
}

/* Detects, then fits each detected sphere from a crop; returns the worst 3D centre error
 * (matching each truth object to the nearest fit). */
static double detect_and_fit(const struct imp_pinhole *cam, const struct imp_image *img, const struct object *obj, int n,
                             double r_mm, double cut_fit, int *ret_found) {
        struct imp_frame_view v = { img, 0, 0 };
        struct imp_sphere_circle c[MAX_FOUND];
        int found = imp_lights_sphere_detect(&v, 80, 240, c, MAX_FOUND);
        *ret_found = found;
        double worst = 0;
        for (int k = 0; k < n; k++) {
                double best = INFINITY;
                for (int s = 0; s < found && s < MAX_FOUND; s++) {
                        int half = (int) (1.3 * c[s].radius_px + 6);
                        int x0 = (int) c[s].centre_px[0] - half, y0 = (int) c[s].centre_px[1] - half;
                        struct imp_image *crop = NULL;
                        CHECK_OK(imp_image_new(2 * half, 2 * half, 1, IMP_PIX_F32, &crop));
                        for (int y = 0; y < 2 * half; y++)
                                for (int x = 0; x < 2 * half; x++)
                                        *imp_image_f32(crop, x, y) = *imp_image_f32(img, x0 + x, y0 + y);
                        struct imp_frame_view cv = { crop, x0, y0 };
                        struct imp_sphere sp;
                        struct imp_error err = { 0 };
                        if (imp_lights_sphere_fit(cam, &cv, r_mm, obj[k].C[2], cut_fit, &sp, &err) == 0) {
                                double e = sqrt((sp.centre_mm[0] - obj[k].C[0]) * (sp.centre_mm[0] - obj[k].C[0]) +
                                                (sp.centre_mm[1] - obj[k].C[1]) * (sp.centre_mm[1] - obj[k].C[1]) +
                                                (sp.centre_mm[2] - obj[k].C[2]) * (sp.centre_mm[2] - obj[k].C[2]));
                                best = fmin(best, e);
                        }
                        imp_image_free(crop);
                }
                worst = fmax(worst, best);
        }
        return worst;
}

/* Cut spheres (all of one radius and cut): detected, fitted within 2 µm with the cut
 * modelled, and at least `worse` times worse fitted as whole balls. */
static void check_cut(const struct imp_pinhole *cam, const char *what, const struct object *obj, int n, double worse) {
        struct imp_image *img = render(cam, obj, n, (const double[4]) { 0, 0, -1, -1 });
        int found;
        double ecut = detect_and_fit(cam, img, obj, n, obj[0].r, obj[0].cut, &found);
        CHECK_INT_EQ(found, n);
        double eball = detect_and_fit(cam, img, obj, n, obj[0].r, NAN, &found);
        fprintf(stderr, "%s: worst 3D centre error %.5f mm with the cut modelled, %.4f mm fitted as balls\n", what, ecut,
                eball);
        CHECK_LE(ecut, 0.002);
        CHECK_GE(eball, worse * ecut);
        imp_image_free(img);
}

int main(void) {
        struct imp_pinhole cam = camera();

        /* balls of radius 7 resting on the board, spread to the corners of the view; a dark
         * square, a ball cut by the frame's edge and a small blot must not be detected */
        const struct object balls[] = { { { 8.5, 8.5, 7 }, 7, NAN }, { { 51.5, 8.5, 7 }, 7, NAN },
                                        { { 30, 20, 7 }, 7, NAN }, { { 8.5, 31.5, 7 }, 7, NAN },
                                        { { 51.5, 31.5, 7 }, 7, NAN } };
        const struct object distractors[] = { { { 30, 45.5, 7 }, 7, NAN },    /* cut by the frame */
                                              { { 19, 20, 1.5 }, 1.5, NAN } }; /* too small */
        struct object all[7];
        for (int k = 0; k < 5; k++) all[k] = balls[k];
        all[5] = distractors[0];
        all[6] = distractors[1];
        const double square[4] = { 38, 17, 44, 23 };
        struct imp_image *img = render(&cam, all, 7, square);
        struct imp_frame_view v = { img, 0, 0 };
        struct imp_sphere_circle c[MAX_FOUND];
        int found = imp_lights_sphere_detect(&v, 80, 240, c, MAX_FOUND);
        CHECK_INT_EQ(found, 5);
        for (int s = 0; s < found && s < 5; s++) {
                /* reading order: rows of a quarter image height, then x */
                if (s > 0)
                        CHECK(floor(c[s].centre_px[1] / 250) > floor(c[s - 1].centre_px[1] / 250) ||
                              c[s].centre_px[0] > c[s - 1].centre_px[0]);
                double best = INFINITY;
                for (int k = 0; k < 5; k++) {
                        double p[2];
                        CHECK(imp_pinhole_project(&cam, balls[k].C, p));
                        best = fmin(best, hypot(p[0] - c[s].centre_px[0], p[1] - c[s].centre_px[1]));
                }
                fprintf(stderr, "circle %d: (%.3f, %.3f) r %.3f px, rms %.3f px, %d edges, %.3f px from the projected centre\n",
                        s, c[s].centre_px[0], c[s].centre_px[1], c[s].radius_px, c[s].rms_px, c[s].n_edge, best);
                /* the outline of an off-axis sphere is a slight ellipse around the projected centre */
                CHECK_LE(best, 0.5);
                CHECK_LE(c[s].rms_px, 0.5);
                CHECK_NEAR(c[s].radius_px, 7 * 6000 / (300 - 7.0), 0.5);   /* a ball resting on the board */
        }
        int n;
        double e = detect_and_fit(&cam, img, balls, 5, 7, NAN, &n);
        fprintf(stderr, "balls: worst 3D centre error %.5f mm\n", e);
        CHECK_LE(e, 0.002);
        /* max < found: only max written, the count still says how many */
        CHECK_INT_EQ(imp_lights_sphere_detect(&v, 80, 240, c, 2), 5);
        /* the small blot is a sphere too when that size is asked for; nothing this big */
        CHECK_INT_EQ(imp_lights_sphere_detect(&v, 20, 60, c, MAX_FOUND), 1);
        CHECK_INT_EQ(imp_lights_sphere_detect(&v, 300, 400, c, MAX_FOUND), 0);
        CHECK_ERR(imp_lights_sphere_detect(&v, 0, 60, c, MAX_FOUND), -EINVAL);
        imp_image_free(img);

        /* spherical caps (r 10, centre 7 mm under the board): the rim is the outline */
        const struct object caps[] = { { { 8.7, 8.7, -7 }, 10, 7 }, { { 51.3, 31.3, -7 }, 10, 7 }, { { 30, 20, -7 }, 10, 7 } };
        check_cut(&cam, "caps", caps, 3, 10);
        /* half balls (cut 0) off the axis: the equator hides the near side's tangent */
        const struct object halves[] = { { { 8.5, 8.5, 0 }, 7, 0 }, { { 51.5, 31.5, 0 }, 7, 0 } };
        check_cut(&cam, "half balls", halves, 2, 3);
        return TEST_DONE();
}
