/* Dome light calibration on analytic renders: three glossy black spheres (r 10 mm) on the
 * canvas seen by a 6000×4000 camera 450 mm above, 48 lights on a 500 mm hemisphere (rings
 * at 15°, 35°, 60°). Silhouettes are ray-cast (3×3 supersampling, 4 % reflectance body,
 * noise σ 2 on a background of 1000); each highlight is a Gaussian spot (σ 1.3 px) at the
 * projection of the exact specular point. Tolerances: light position 1 mm,
 * intensity 2 %; sphere centre 0.05 mm; .lp round trip 1e-6. */
#include <math.h>
#include <stdint.h>
#include "calib-lights.h"
#include "test.h"

#define CROP 400
#define BG 1000.0
#define BODY (0.04 * BG)
#define NOISE 2.0
#define SPOT_SIGMA_PX 1.3
#define SPOT_PEAK 3000.0
#define R_SPHERE 10.0
#define N_SPHERES 3
#define N_LIGHTS 48

static uint64_t rng_state = 0x2545f4914f6cdd1dull;
static double nrand(void) { return test_nrand(&rng_state); }
static double dot(const double a[3], const double b[3]) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

static struct imp_pinhole camera(void) {
        struct imp_pinhole m = { .width = 6000, .height = 4000, .fx = 6750, .fy = 6750, .cx = 2999.5, .cy = 1999.5 };
        double eye[3] = { 0, 0, 450 }, at[3] = { 0, 0, 0 }, right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&m, eye, at, right);
        return m;
}

static bool hits(const double O[3], const double d[3], const double C[3], double r) {
        double w[3] = { O[0] - C[0], O[1] - C[1], O[2] - C[2] }, b = dot(w, d), c = dot(w, w) - r * r;
        return b * b - c >= 0 && -b > 0;
}

/* Silhouette frame: a crop centred on the sphere's projection. */
static struct imp_image *render_silhouette(const struct imp_pinhole *cam, const double C[3], int x0, int y0) {
        struct imp_image *img = NULL;
        if (imp_image_new(CROP, CROP, 1, IMP_PIX_F32, &img) < 0) exit(2);
        for (int y = 0; y < CROP; y++)
                for (int x = 0; x < CROP; x++) {
                        double s = 0;
                        for (int j = 0; j < 3; j++)
                                for (int i = 0; i < 3; i++) {
                                        double px[2] = { x0 + x + (i - 1) / 3.0, y0 + y + (j - 1) / 3.0 }, O[3], d[3];
                                        imp_pinhole_ray_world(cam, px, O, d);
                                        s += hits(O, d, C, R_SPHERE) ? BODY : BG;
                                }
                        *imp_image_f32(img, x, y) = (float) (s / 9 + NOISE * nrand());
                }
        return img;
}

/* Exact specular point of light L on sphere C seen from E (fixed point on the bisector). */
static void specular_point(const double C[3], const double E[3], const double L[3], double P[3]) {
        double n[3] = { 0, 0, 1 };
        for (int it = 0; it < 200; it++) {
                for (int k = 0; k < 3; k++) P[k] = C[k] + R_SPHERE * n[k];
                double a[3], b[3];
                for (int k = 0; k < 3; k++) { a[k] = E[k] - P[k]; b[k] = L[k] - P[k]; }
                double la = sqrt(dot(a, a)), lb = sqrt(dot(b, b)), m[3];
                for (int k = 0; k < 3; k++) m[k] = a[k] / la + b[k] / lb;
                double lm = sqrt(dot(m, m));
                for (int k = 0; k < 3; k++) n[k] = m[k] / lm;
        }
        for (int k = 0; k < 3; k++) P[k] = C[k] + R_SPHERE * n[k];
}

/* Highlight frame: body, background, Gaussian spot at spot_px (full-frame), clipped at sat. */
static void render_highlight(struct imp_image *img, const struct imp_pinhole *cam, const double C[3], int x0, int y0,
                             const double spot_px[2], double peak, double sat) {
        for (int y = 0; y < CROP; y++)
                for (int x = 0; x < CROP; x++) {
                        double px[2] = { x0 + x, y0 + y }, O[3], d[3];
                        imp_pinhole_ray_world(cam, px, O, d);
                        double v = hits(O, d, C, R_SPHERE) ? BODY : BG;
                        double dx = px[0] - spot_px[0], dy = px[1] - spot_px[1];
                        v += peak * exp(-(dx * dx + dy * dy) / (2 * SPOT_SIGMA_PX * SPOT_SIGMA_PX)) + NOISE * nrand();
                        *imp_image_f32(img, x, y) = (float) fmin(v, sat);
                }
}

int main(void) {
        struct imp_pinhole cam = camera();
        double E[3];
        imp_pinhole_centre(&cam, E);
        const double centres[N_SPHERES][3] = { { -110, -70, R_SPHERE }, { 110, -70, R_SPHERE }, { 0, 90, R_SPHERE } };
        struct imp_rig_light lights[N_LIGHTS];
        const double elev[3] = { 15, 35, 60 };
        for (int i = 0; i < N_LIGHTS; i++) {
                int ring = i / 16, k = i % 16;
                double el = elev[ring] * M_PI / 180, az = 2 * M_PI * (k + 0.5 * ring) / 16;
                lights[i] = (struct imp_rig_light) { .id = i, .pos_mm = { 500 * cos(el) * cos(az), 500 * cos(el) * sin(az),
                                                                          500 * sin(el) },
                                                     .intensity = 0.25 * (1 + 0.1 * sin(i)), .colour = { 1.05, 0.95, 1.0 } };
        }

        /* spheres from silhouettes */
        struct imp_sphere sph[N_SPHERES];
        int x0[N_SPHERES], y0[N_SPHERES];
        for (int s = 0; s < N_SPHERES; s++) {
                double px[2];
                CHECK(imp_pinhole_project(&cam, centres[s], px));
                x0[s] = (int) px[0] - CROP / 2 + 7 * s - 5;   /* not centred: detection must not rely on it */
                y0[s] = (int) px[1] - CROP / 2 - 4 * s + 3;
                struct imp_image *img = render_silhouette(&cam, centres[s], x0[s], y0[s]);
                struct imp_frame_view v = { img, x0[s], y0[s] };
                struct imp_error err = { 0 };
                CHECK_OK(imp_lights_sphere_fit(&cam, &v, R_SPHERE, R_SPHERE, NAN, &sph[s], &err));
                double e = hypot(hypot(sph[s].centre_mm[0] - centres[s][0], sph[s].centre_mm[1] - centres[s][1]),
                                 sph[s].centre_mm[2] - centres[s][2]);
                fprintf(stderr, "sphere %d: centre error %.4f mm, %d edges, rms %.3f px, radius %.1f px\n", s, e,
                        sph[s].n_edge, sph[s].rms_px, sph[s].image_radius_px);
                CHECK_LE(e, 0.05);
                CHECK_LE(sph[s].rms_px, 0.2);
                /* free fit (no plane): still close, depth is the weak direction */
                struct imp_sphere fr;
                CHECK_OK(imp_lights_sphere_fit(&cam, &v, R_SPHERE, NAN, NAN, &fr, &err));
                CHECK_LE(fabs(fr.centre_mm[2] - centres[s][2]), 2.0);
                imp_image_free(img);
        }

        /* highlights → rays → light positions */
        struct imp_image *hl = NULL;
        CHECK_OK(imp_image_new(CROP, CROP, 1, IMP_PIX_F32, &hl));
        double worst = 0, sum2 = 0, worst_px = 0, worst_sigma = 0;
        struct imp_light_estimate est[N_LIGHTS];
        for (int i = 0; i < N_LIGHTS; i++) {
                double o[N_SPHERES][3], d[N_SPHERES][3], sg[N_SPHERES];
                int n = 0;
                for (int s = 0; s < N_SPHERES; s++) {
                        double P[3], spot[2];
                        specular_point(centres[s], E, lights[i].pos_mm, P);
                        CHECK(imp_pinhole_project(&cam, P, spot));
                        render_highlight(hl, &cam, centres[s], x0[s], y0[s], spot, SPOT_PEAK, INFINITY);
                        struct imp_frame_view v = { hl, x0[s], y0[s] };
                        struct imp_highlight h;
                        CHECK_OK(imp_lights_highlight(&v, &sph[s], INFINITY, &h));
                        worst_px = fmax(worst_px, hypot(h.px[0] - spot[0], h.px[1] - spot[1]));
                        CHECK(!h.saturated);
                        CHECK_OK(imp_lights_reflect(&cam, &sph[s], h.px, h.sigma_px, o[n], d[n], &sg[n]));
                        n++;
                }
                CHECK_OK(imp_lights_triangulate(n, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &est[i]));
                double e = hypot(hypot(est[i].pos_mm[0] - lights[i].pos_mm[0], est[i].pos_mm[1] - lights[i].pos_mm[1]),
                                 est[i].pos_mm[2] - lights[i].pos_mm[2]);
                worst = fmax(worst, e);
                worst_sigma = fmax(worst_sigma, est[i].sigma_mm);
                sum2 += e * e;
                CHECK_MSG(e <= 1.0, "light %d: position error %.3f mm > 1 mm (σ %.3f, cond %.1f)", i, e, est[i].sigma_mm,
                          est[i].cond);
                CHECK_MSG(est[i].flags == 0, "light %d: flags %#x", i, est[i].flags);
        }
        fprintf(stderr, "light positions: RMS %.3f mm, worst %.3f mm (limit 1), worst highlight %.4f px, worst σ %.3f mm\n",
                sqrt(sum2 / N_LIGHTS), worst, worst_px, worst_sigma);
        imp_image_free(hl);

        /* intensity and colour from a white Lambertian target (a 200×200 view of z = 0) */
        struct imp_image *wt = NULL;
        CHECK_OK(imp_image_new(200, 200, 3, IMP_PIX_F32, &wt));
        double worst_i = 0, worst_c = 0;
        for (int i = 0; i < N_LIGHTS; i++) {
                const int tx0 = 2900, ty0 = 1900;
                for (int y = 0; y < 200; y++)
                        for (int x = 0; x < 200; x++) {
                                double px[2] = { tx0 + x, ty0 + y }, O[3], d[3];
                                imp_pinhole_ray_world(&cam, px, O, d);
                                double t = -O[2] / d[2], l[3];
                                for (int k = 0; k < 3; k++) l[k] = lights[i].pos_mm[k] - O[k] - t * d[k];
                                double dist = sqrt(dot(l, l)), Ei = lights[i].intensity * 1e6 / (dist * dist);
                                for (int c = 0; c < 3; c++)
                                        imp_image_f32(wt, x, y)[c] = (float) (Ei * lights[i].colour[c] * l[2] / dist *
                                                                              (1 + 0.005 * nrand()));
                        }
                struct imp_frame_view v = { wt, tx0, ty0 };
                struct imp_light_intensity li;
                CHECK_OK(imp_lights_intensity(&cam, &v, 0.0, est[i].pos_mm, NULL, 0, &li));
                double e = fabs(li.intensity / lights[i].intensity - 1);
                worst_i = fmax(worst_i, e);
                for (int c = 0; c < 3; c++) worst_c = fmax(worst_c, fabs(li.colour[c] - lights[i].colour[c]));
                CHECK_MSG(e <= 0.02, "light %d: intensity %.5f vs %.5f", i, li.intensity, lights[i].intensity);
        }
        fprintf(stderr, "intensity: worst relative error %.4f (limit 0.02), colour worst %.4f\n", worst_i, worst_c);
        CHECK_LE(worst_c, 0.01);
        imp_image_free(wt);

        /* .lp round trip: standard (directions) and near-field (mm) */
        char path[512];
        struct imp_error err = { 0 };
        const double centre[3] = { 0, 0, 0 };
        for (int nf = 0; nf < 2; nf++) {
                snprintf(path, sizeof path, "%s/lights-%d.lp", test_tmpdir(), nf);
                CHECK_OK(imp_lights_lp_write(path, N_LIGHTS, lights, NULL, centre, nf, &err));
                int n = 0;
                struct imp_rig_light *L = NULL;
                char **names = NULL;
                bool near = !nf;
                CHECK_OK(imp_lights_lp_read(path, centre, 500, &n, &L, &names, &near, &err));
                CHECK_INT_EQ(n, N_LIGHTS);
                CHECK(near == (bool) nf);
                double wdev = 0;
                for (int i = 0; L && i < n; i++)
                        for (int k = 0; k < 3; k++) wdev = fmax(wdev, fabs(L[i].pos_mm[k] - lights[i].pos_mm[k]));
                CHECK_LE(wdev, 1e-6);
                CHECK_STR_EQ(names ? names[7] : NULL, "light_007.png");
                free(L);
                imp_strv_free(names);
        }
        /* a first line of the standard form, written by hand, and bad files */
        snprintf(path, sizeof path, "%s/rti.lp", test_tmpdir());
        FILE *f = fopen(path, "w");
        fprintf(f, "2\nimg_0.jpg 0 0 2\nimg_1.jpg 1 0 1\n");
        fclose(f);
        int n = 0;
        struct imp_rig_light *L = NULL;
        CHECK_OK(imp_lights_lp_read(path, centre, 500, &n, &L, NULL, NULL, &err));
        CHECK_INT_EQ(n, 2);
        CHECK_NEAR(L ? L[0].pos_mm[2] : 0, 500, 1e-9);
        CHECK_NEAR(L ? L[1].pos_mm[0] : 0, 500 / sqrt(2), 1e-9);
        free(L);
        f = fopen(path, "w");
        fprintf(f, "3\nimg_0.jpg 0 0 1\nimg_1.jpg 1 zero 1\n");
        fclose(f);
        L = NULL;
        CHECK_ERR(imp_lights_lp_read(path, centre, 500, &n, &L, NULL, NULL, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, ":3:");
        CHECK(L == NULL);
        return TEST_DONE();
}
