/* The light calibration target in whole frames (calib-lights-target.h): crops, darks,
 * the white board's values and the pooled intensity, the projection onto the dome. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "calib-lights-target.h"
#include "calib-radiometric.h"
#include "macro.h"
#include "numerics.h"

#define CROP_MARGIN 1.3               /* crop half-size in sphere image radii */
#define CROP_PAD_PX 6
#define PATCH_PX 16                   /* intensity: patches of this size … */
#define PATCH_STEP_PX 48              /* … on a grid of this step */
#define DISC_MARGIN_MM 1.0            /* board excluded around a sphere's footprint */
#define SHADOW_MARGIN_MM 0.5          /* extra radius when testing a sphere's shadow */
#define LIT_FRACTION 0.5              /* board pixels must exceed this × the 90th percentile */
#define SAT_MARGIN_SIGMA 4.0          /* saturation: clip level less this many read-noise σ */

struct imp_crop imp_lights_crop_circle(const struct imp_pinhole *m, const double c[2], double rho) {
        double half = CROP_MARGIN * rho + CROP_PAD_PX;
        int x0 = (int) IMP_MAX(0.0, floor(c[0] - half)), y0 = (int) IMP_MAX(0.0, floor(c[1] - half));
        int x1 = (int) IMP_MIN((double) m->width, ceil(c[0] + half)), y1 = (int) IMP_MIN((double) m->height, ceil(c[1] + half));
        return (struct imp_crop) { x0, y0, IMP_MAX(0, x1 - x0), IMP_MAX(0, y1 - y0) };
}

struct imp_crop imp_lights_crop_sphere(const struct imp_pinhole *m, const double centre_mm[3], double r_mm) {
        const double *C = centre_mm;
        double px[2] = { -1, -1 }, cam_c[3];
        imp_pinhole_project(m, C, px);
        imp_pinhole_centre(m, cam_c);
        double dist = sqrt((C[0] - cam_c[0]) * (C[0] - cam_c[0]) + (C[1] - cam_c[1]) * (C[1] - cam_c[1]) +
                           (C[2] - cam_c[2]) * (C[2] - cam_c[2]));
        return imp_lights_crop_circle(m, px, r_mm * m->fx / dist);
}

double imp_lights_image_radius(const struct imp_pinhole *m, double r_mm, double z_mm) {
        double cc[3];
        imp_pinhole_centre(m, cc);
        return r_mm * m->fx / IMP_MAX(fabs(cc[2] - z_mm), r_mm);
}

int imp_lights_crop_dn(const struct imp_image *f, const struct imp_image *dark, double black,
                       const struct imp_crop *c, struct imp_image **ret) {
        int r = imp_image_new(c->w, c->h, 1, IMP_PIX_F32, ret);
        if (r < 0)
                return r;
        for (int y = 0; y < c->h; y++)
                for (int x = 0; x < c->w; x++)
                        *imp_image_f32(*ret, x, y) = (float) (imp_image_get(f, c->x0 + x, c->y0 + y, 0) -
                                                              (dark ? *imp_image_f32(dark, c->x0 + x, c->y0 + y) : black));
        return 0;
}

int imp_lights_crop_image(const struct imp_image *img, const struct imp_crop *c, struct imp_image **ret) {
        int r = imp_image_new(c->w, c->h, 1, IMP_PIX_F32, ret);
        for (int y = 0; r >= 0 && y < c->h; y++)
                for (int x = 0; x < c->w; x++)
                        *imp_image_f32(*ret, x, y) = *imp_image_f32(img, c->x0 + x, c->y0 + y);
        return r;
}

int imp_lights_mean_dark(const struct imp_captureset *cs, const char *cam, double exposure_us, struct imp_image **ret,
                         struct imp_error *err) {
        struct imp_image *acc = NULL;
        int n = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (strcmp(rec->step, "dark") || strcmp(rec->camera, cam) ||
                    (exposure_us >= 0 && fabs(rec->exposure_us - exposure_us) > 1e-6 * exposure_us))
                        continue;
                _cleanup_image_ struct imp_image *f = NULL;
                int r = imp_captureset_load_frame(cs, i, &f, err);
                if (r >= 0 && !acc)
                        r = imp_image_new(f->width, f->height, 1, IMP_PIX_F32, &acc);
                if (r >= 0 && (f->width != acc->width || f->height != acc->height))
                        r = imp_error_set(err, -EINVAL, "%s: dark frame %s: size differs", imp_captureset_dir(cs), rec->file);
                if (r < 0) {
                        imp_image_free(acc);
                        return r;
                }
                for (int y = 0; y < f->height; y++)
                        for (int x = 0; x < f->width; x++)
                                *imp_image_f32(acc, x, y) += (float) imp_image_get(f, x, y, 0);
                n++;
        }
        if (acc)
                for (int y = 0; y < acc->height; y++)
                        for (int x = 0; x < acc->width; x++)
                                *imp_image_f32(acc, x, y) /= (float) n;
        *ret = acc;
        return n;
}

double imp_lights_clip_level(const struct imp_sensor *sn) {
        double gain = sn->gain_e_per_dn > 0 ? sn->gain_e_per_dn : 1;
        double clip = ldexp(1.0, sn->bits) - 1 - sn->black_level_dn;
        if (sn->full_well_e > 0)
                clip = IMP_MIN(clip, sn->full_well_e / gain);
        return clip - SAT_MARGIN_SIGMA * IMP_MAX(sn->read_noise_e / gain, 1.0);
}

bool imp_lights_sphere_shadows(const struct imp_sphere *sp, const double p[3], const double L[3]) {
        const double *C = sp->centre_mm;
        double d[3] = { L[0] - p[0], L[1] - p[1], L[2] - p[2] }, c[3] = { C[0] - p[0], C[1] - p[1], C[2] - p[2] };
        double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        double t = IMP_CLAMP((c[0] * d[0] + c[1] * d[1] + c[2] * d[2]) / dd, 0.0, 1.0);
        double e[3] = { c[0] - t * d[0], c[1] - t * d[1], c[2] - t * d[2] };
        double rr = sp->radius_mm + SHADOW_MARGIN_MM;
        return e[0] * e[0] + e[1] * e[1] + e[2] * e[2] < rr * rr;
}

int imp_lights_white_values(const struct imp_image *f, const struct imp_lights_board *board, const double L[3],
                            double exposure_us, double gain_db, struct imp_image **ret) {
        const struct imp_rig_camera *cam = board->cam;
        const double *white = board->white;
        _cleanup_image_ struct imp_image *v = NULL;
        int r = imp_image_new(f->width, f->height, 1, IMP_PIX_F32, &v);
        if (r < 0)
                return r;
        size_t n = (size_t) f->width * f->height, m = 0;
        _cleanup_free_ float *sorted = malloc(n * sizeof *sorted);
        if (!sorted)
                return -ENOMEM;
        for (int y = 0; y < f->height; y++)
                for (int x = 0; x < f->width; x++) {
                        double dn = imp_image_get(f, x, y, 0);
                        if (board->dark)
                                dn += cam->sensor.black_level_dn - *imp_image_f32(board->dark, x, y);
                        float val = (float) imp_radiometric_dn_to_value(&cam->sensor, exposure_us, gain_db, dn);
                        *imp_image_f32(v, x, y) = val;
                        sorted[m++] = val;
                }
        qsort(sorted, m, sizeof *sorted, imp_cmp_float);
        double lit = LIT_FRACTION * sorted[m * 9 / 10];
        for (int y = 0; y < f->height; y++)
                for (int x = 0; x < f->width; x++) {
                        float *val = imp_image_f32(v, x, y);
                        double px[2] = { x, y }, O[3], d[3];
                        imp_pinhole_ray_world(&cam->model, px, O, d);
                        double t = fabs(d[2]) > 1e-12 ? (board->plane_z_mm - O[2]) / d[2] : -1;
                        double p[3] = { O[0] + t * d[0], O[1] + t * d[1], board->plane_z_mm };
                        bool ok = *val > lit && t > 0;
                        if (ok && white)
                                ok = p[0] >= white[0] && p[0] <= white[2] && p[1] >= white[1] &&
                                     p[1] <= white[3];
                        for (int s = 0; ok && s < board->n_spheres; s++) {
                                const struct imp_sphere *sp = &board->spheres[s];
                                ok = hypot(p[0] - sp->centre_mm[0], p[1] - sp->centre_mm[1]) > sp->radius_mm + DISC_MARGIN_MM &&
                                     !imp_lights_sphere_shadows(sp, p, L);
                        }
                        if (!ok)
                                *val = NAN;
                }
        *ret = TAKE_PTR(v);
        return 0;
}

int imp_lights_intensity_pooled(const struct imp_image *v, const struct imp_rig_camera *cam, double plane_z_mm,
                                const struct imp_rig_light *nominal, const double pos_mm[3],
                                struct imp_light_intensity *ret) {
        _cleanup_image_ struct imp_image *patch = NULL;
        int r = imp_image_new(PATCH_PX, PATCH_PX, 1, IMP_PIX_F32, &patch);
        if (r < 0)
                return r;
        double s = 0, s2 = 0, col[3] = { 0 };
        long n = 0;
        for (int y0 = PATCH_STEP_PX / 2; y0 + PATCH_PX <= v->height; y0 += PATCH_STEP_PX)
                for (int x0 = PATCH_STEP_PX / 2; x0 + PATCH_PX <= v->width; x0 += PATCH_STEP_PX) {
                        for (int y = 0; y < PATCH_PX; y++)
                                for (int x = 0; x < PATCH_PX; x++)
                                        *imp_image_f32(patch, x, y) = *imp_image_f32(v, x0 + x, y0 + y);
                        struct imp_frame_view view = { patch, x0, y0 };
                        struct imp_light_intensity li;
                        if (imp_lights_intensity(&cam->model, &view, plane_z_mm, pos_mm, nominal->axis,
                                                 nominal->profile_exp, &li) < 0)
                                continue;
                        double var = li.rel_sigma * li.intensity * li.rel_sigma * li.intensity * li.n_pixels;
                        s += li.intensity * li.n_pixels;
                        s2 += (var + li.intensity * li.intensity) * li.n_pixels;
                        for (int c = 0; c < 3; c++)
                                col[c] += li.colour[c] * li.intensity * li.n_pixels;
                        n += li.n_pixels;
                }
        if (!n)
                return -ENOENT;
        double mean = s / n, var = IMP_MAX(s2 / n - mean * mean, 0.0);
        struct imp_light_intensity out = { .intensity = mean, .n_pixels = (int) n,
                                           .rel_sigma = mean > 0 ? sqrt(var / n) / mean : 1.0 };
        for (int c = 0; c < 3; c++)
                out.colour[c] = mean > 0 ? col[c] / s : 1.0;
        *ret = out;
        return 0;
}

void imp_lights_onto_dome(const double dome[4], const struct imp_light_estimate *est, struct imp_light_estimate *ret) {
        *ret = *est;
        double d[3] = { est->pos_mm[0] - dome[0], est->pos_mm[1] - dome[1], est->pos_mm[2] - dome[2] };
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        if (!(len > 0))
                return;
        double J[9], JC[9], C2[9], s = dome[3] / len;
        for (int k = 0; k < 3; k++)
                ret->pos_mm[k] = dome[k] + d[k] * s;
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++)
                        J[i * 3 + j] = s * ((i == j) - d[i] * d[j] / (len * len));
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        JC[i * 3 + j] = 0;
                        for (int k = 0; k < 3; k++)
                                JC[i * 3 + j] += J[i * 3 + k] * est->cov_mm2[k * 3 + j];
                }
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        C2[i * 3 + j] = 0;
                        for (int k = 0; k < 3; k++)
                                C2[i * 3 + j] += JC[i * 3 + k] * J[j * 3 + k];
                }
        memcpy(ret->cov_mm2, C2, sizeof C2);
        /* λmax of a covariance with one zero eigenvalue: λ1 + λ2 = trace, λ1 λ2 = the sum of
         * the principal 2×2 minors */
        double tr = C2[0] + C2[4] + C2[8], det2 = 0;
        for (int i = 0; i < 3; i++) {
                int a = (i + 1) % 3, b = (i + 2) % 3;
                det2 += C2[a * 3 + a] * C2[b * 3 + b] - C2[a * 3 + b] * C2[b * 3 + a];
        }
        double disc = IMP_MAX(tr * tr / 4 - det2, 0.0);
        ret->sigma_mm = sqrt(IMP_MAX(tr / 2 + sqrt(disc), 0.0));
}
