/* `impasto calibrate lights`: dome light positions, intensities and colours from a capture
 * set of mirror spheres on a white target (one frame per light), written into a copy of
 * the set's rig.json and an RTI .lp file; `impasto calibrate radiometric`: the camera's
 * photon transfer from a set of flat-field pairs and dark frames. The numerics live in
 * pipeline/calib-lights.c and pipeline/calib-radiometric.c; see docs/calibration-lights.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib-lights.h"
#include "calib-radiometric.h"
#include "calibrate-ext.h"
#include "captureset.h"
#include "log.h"
#include "rig.h"

#define EXIT_USAGE 2
#define EXIT_BADINPUT 3
#define MAX_SPHERES 16
#define CROP_MARGIN 1.3               /* crop half-size in sphere image radii */
#define CROP_PAD_PX 6
#define PATCH_PX 16                   /* intensity: patches of this size … */
#define PATCH_STEP_PX 48              /* … on a grid of this step */
#define DISC_MARGIN_MM 1.0            /* canvas excluded around a sphere's footprint */
#define SHADOW_MARGIN_MM 0.5          /* extra radius when testing a sphere's shadow */
#define LIT_FRACTION 0.5              /* target pixels must exceed this × the 90th percentile */

struct sphere_spec {
        double x, y, r, z;            /* centre (x, y, z) mm, radius mm */
};

struct crop {
        int x0, y0, w, h;
};

struct lights_args {
        const char *set, *rig, *lp, *out, *camera;
        struct sphere_spec spheres[MAX_SPHERES];
        int n_spheres;
        double plane_z_mm;
        double white[4];              /* x0, y0, x1, y1 on the canvas; x1 < x0 → none */
        double dome[4];               /* centre x, y, z and radius mm; radius 0 → not given */
        bool json, lp_near_field;
};

static void usage_lights(FILE *f) {
        fprintf(f, "usage: impasto calibrate lights --set DIR --spheres \"X,Y,R[,Z];...\" [--camera NAME]\n"
                   "                                [--rig RIG.json] [--plane-z MM (0)] [--white X0,Y0,X1,Y1]\n"
                   "                                [--dome CX,CY,CZ,R] [--lp OUT.lp] [--lp-near-field] [--json]\n"
                   "                                [--out RIG.json]\n"
                   "  --spheres: centre (X, Y) on the canvas, radius R, centre height Z (default R: a ball\n"
                   "             resting on the canvas; 0 for the simulator's hemispheres), mm\n"
                   "  --rig:     camera model and sensor from this file instead of the set's rig.json\n"
                   "  --white:   canvas rectangle (mm) of the white target for the intensities\n"
                   "             (default: every lit canvas pixel off the spheres and their shadows)\n"
                   "  --dome:    the dome's centre and radius (mm): each light is put where its direction\n"
                   "             from the centre meets the dome, since spheres a few cm apart fix the\n"
                   "             direction of a light 0.5 m away well but its range poorly\n");
}

static void usage_radiometric(FILE *f) {
        fprintf(f, "usage: impasto calibrate radiometric --set DIR [--camera NAME] [--roi X,Y,W,H]\n"
                   "                                     [--json] [--out RIG.json]\n"
                   "  the set: pairs of equal frames (same exposure, gain, light, pattern) at rising\n"
                   "  exposures, and dark frames (those at the shortest dark exposure are used)\n");
}

static int parse_list(const char *opt, const char *s, double *v, int min_n, int max_n, int *ret_n) {
        int n = 0;
        const char *p = s;
        while (*p && n < max_n) {
                char *end;
                v[n] = strtod(p, &end);
                if (end == p || !isfinite(v[n]))
                        break;
                n++;
                p = end;
                if (*p == ',')
                        p++;
                else
                        break;
        }
        if (*p || n < min_n) {
                log_error("%s: expected %d to %d numbers separated by commas, got '%s'", opt, min_n, max_n, s);
                return -EINVAL;
        }
        *ret_n = n;
        return 0;
}

static int parse_spheres(const char *s, struct lights_args *a) {
        char buf[1024];
        if (snprintf(buf, sizeof buf, "%s", s) >= (int) sizeof buf) {
                log_error("--spheres: too long");
                return -EINVAL;
        }
        char *save = NULL;
        for (char *tok = strtok_r(buf, ";", &save); tok; tok = strtok_r(NULL, ";", &save)) {
                double v[4];
                int n;
                if (a->n_spheres == MAX_SPHERES) {
                        log_error("--spheres: at most %d", MAX_SPHERES);
                        return -EINVAL;
                }
                if (parse_list("--spheres", tok, v, 3, 4, &n) < 0)
                        return -EINVAL;
                if (!(v[2] > 0)) {
                        log_error("--spheres: radius must be > 0, got %g", v[2]);
                        return -EINVAL;
                }
                a->spheres[a->n_spheres++] = (struct sphere_spec) { v[0], v[1], v[2], n == 4 ? v[3] : v[2] };
        }
        if (!a->n_spheres) {
                log_error("--spheres: no sphere given");
                return -EINVAL;
        }
        return 0;
}

static int camera_index(const struct imp_rig *rig, const char *name) {
        if (!name)
                return rig->n_cameras > 0 ? 0 : -ENOENT;
        for (int i = 0; i < rig->n_cameras; i++)
                if (!strcmp(rig->cameras[i].name, name))
                        return i;
        return -ENOENT;
}

/* Mean of the camera's dark frames at `exposure_us` (any exposure when < 0), per pixel, as
 * f32; NULL (and 0) when the set has none. */
static int mean_dark(const struct imp_captureset *cs, const char *cam, double exposure_us, struct imp_image **ret,
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

/* ---- lights ---- */

struct light_frame {
        size_t index;                 /* record */
        int light;                    /* rig light index */
};

static bool sphere_shadows(const struct sphere_spec *sp, const double p[3], const double L[3]) {
        double d[3] = { L[0] - p[0], L[1] - p[1], L[2] - p[2] }, c[3] = { sp->x - p[0], sp->y - p[1], sp->z - p[2] };
        double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        double t = IMP_CLAMP((c[0] * d[0] + c[1] * d[1] + c[2] * d[2]) / dd, 0.0, 1.0);
        double e[3] = { c[0] - t * d[0], c[1] - t * d[1], c[2] - t * d[2] };
        double rr = sp->r + SHADOW_MARGIN_MM;
        return e[0] * e[0] + e[1] * e[1] + e[2] * e[2] < rr * rr;
}

static int cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return (x > y) - (x < y);
}

/* The radiometric values of a frame on the white target's pixels, NAN elsewhere: off the
 * spheres, out of their shadows from light position L, inside --white (if given), and lit
 * (> LIT_FRACTION × the 90th percentile, which drops pixels off the target). */
static int white_values(const struct imp_image *f, const struct imp_image *dark, const struct imp_rig_camera *cam,
                        const struct lights_args *a, const double L[3], double exposure_us, double gain_db,
                        struct imp_image **ret) {
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
                        if (dark)
                                dn += cam->sensor.black_level_dn - *imp_image_f32(dark, x, y);
                        float val = (float) imp_radiometric_dn_to_value(&cam->sensor, exposure_us, gain_db, dn);
                        *imp_image_f32(v, x, y) = val;
                        sorted[m++] = val;
                }
        qsort(sorted, m, sizeof *sorted, cmp_float);
        double lit = LIT_FRACTION * sorted[m * 9 / 10];
        for (int y = 0; y < f->height; y++)
                for (int x = 0; x < f->width; x++) {
                        float *val = imp_image_f32(v, x, y);
                        double px[2] = { x, y }, O[3], d[3];
                        imp_pinhole_ray_world(&cam->model, px, O, d);
                        double t = fabs(d[2]) > 1e-12 ? (a->plane_z_mm - O[2]) / d[2] : -1;
                        double p[3] = { O[0] + t * d[0], O[1] + t * d[1], a->plane_z_mm };
                        bool ok = *val > lit && t > 0;
                        if (ok && a->white[2] > a->white[0])
                                ok = p[0] >= a->white[0] && p[0] <= a->white[2] && p[1] >= a->white[1] &&
                                     p[1] <= a->white[3];
                        for (int s = 0; ok && s < a->n_spheres; s++) {
                                const struct sphere_spec *sp = &a->spheres[s];
                                ok = hypot(p[0] - sp->x, p[1] - sp->y) > sp->r + DISC_MARGIN_MM && !sphere_shadows(sp, p, L);
                        }
                        if (!ok)
                                *val = NAN;
                }
        *ret = TAKE_PTR(v);
        return 0;
}

/* Intensity over a grid of small patches (the per-pixel ray costs an undistortion, so the
 * target is sampled rather than read whole), pooled by pixel count. */
static int light_intensity(const struct imp_image *v, const struct imp_rig_camera *cam, double plane_z_mm,
                           const struct imp_rig_light *nominal, const double pos[3], struct imp_light_intensity *ret) {
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
                        if (imp_lights_intensity(&cam->model, &view, plane_z_mm, pos, nominal->axis,
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

/* The image window that holds sphere s with a margin, clipped to the frame. */
static struct crop sphere_crop(const struct imp_pinhole *m, const struct sphere_spec *sp) {
        double C[3] = { sp->x, sp->y, sp->z }, px[2] = { -1, -1 }, cam_c[3];
        imp_pinhole_project(m, C, px);
        imp_pinhole_centre(m, cam_c);
        double dist = sqrt((C[0] - cam_c[0]) * (C[0] - cam_c[0]) + (C[1] - cam_c[1]) * (C[1] - cam_c[1]) +
                           (C[2] - cam_c[2]) * (C[2] - cam_c[2]));
        double half = CROP_MARGIN * sp->r * m->fx / dist + CROP_PAD_PX;
        int x0 = (int) IMP_MAX(0.0, floor(px[0] - half)), y0 = (int) IMP_MAX(0.0, floor(px[1] - half));
        int x1 = (int) IMP_MIN((double) m->width, ceil(px[0] + half)), y1 = (int) IMP_MIN((double) m->height, ceil(px[1] + half));
        return (struct crop) { x0, y0, IMP_MAX(0, x1 - x0), IMP_MAX(0, y1 - y0) };
}

/* Dark-subtracted DN of a crop, f32. */
static int crop_dn(const struct imp_image *f, const struct imp_image *dark, double black, const struct crop *c,
                   struct imp_image **ret) {
        int r = imp_image_new(c->w, c->h, 1, IMP_PIX_F32, ret);
        if (r < 0)
                return r;
        for (int y = 0; y < c->h; y++)
                for (int x = 0; x < c->w; x++)
                        *imp_image_f32(*ret, x, y) = (float) (imp_image_get(f, c->x0 + x, c->y0 + y, 0) -
                                                              (dark ? *imp_image_f32(dark, c->x0 + x, c->y0 + y) : black));
        return 0;
}

struct light_result {
        int id;
        bool have_pos, have_intensity;
        struct imp_light_estimate est;
        struct imp_light_intensity li;
        int n_highlights, n_saturated;
};

static json_t *light_json(const struct light_result *lr) {
        json_t *j = json_pack("{s:i, s:b, s:i, s:i}", "id", lr->id, "located", lr->have_pos, "highlights",
                              lr->n_highlights, "saturated_highlights", lr->n_saturated);
        if (lr->have_pos) {
                const struct imp_light_estimate *e = &lr->est;
                json_object_set_new(j, "pos_mm", json_pack("[f, f, f]", e->pos_mm[0], e->pos_mm[1], e->pos_mm[2]));
                json_object_set_new(j, "sigma_mm", json_real(e->sigma_mm));
                json_object_set_new(j, "rms_mm", json_real(e->rms_mm));
                json_object_set_new(j, "cond", json_real(e->cond));
                json_object_set_new(j, "flags", json_pack("{s:b, s:b, s:b, s:b}",
                        "ill_conditioned", !!(e->flags & IMP_LIGHT_ILL_CONDITIONED),
                        "few_rays", !!(e->flags & IMP_LIGHT_FEW_RAYS),
                        "saturated", !!(e->flags & IMP_LIGHT_SATURATED), "behind", !!(e->flags & IMP_LIGHT_BEHIND)));
        }
        if (lr->have_intensity) {
                json_object_set_new(j, "intensity", json_real(lr->li.intensity));
                json_object_set_new(j, "colour", json_pack("[f, f, f]", lr->li.colour[0], lr->li.colour[1], lr->li.colour[2]));
                json_object_set_new(j, "intensity_rel_sigma", json_real(lr->li.rel_sigma));
                json_object_set_new(j, "intensity_pixels", json_integer(lr->li.n_pixels));
        }
        return j;
}

/* Sphere silhouettes from the per-pixel maximum over the light frames: the white canvas is
 * lit in some frame everywhere (so no shadow touches the outline), the mirror body stays
 * dark, and highlights lie well inside the rim. */
static int fit_spheres(const struct imp_captureset *cs, const struct light_frame *lf, int n_lf,
                       const struct imp_image *dark, const struct imp_rig_camera *cam, const struct lights_args *a,
                       const struct crop *crops, struct imp_sphere *sph, struct imp_error *err) {
        struct imp_image *mx[MAX_SPHERES] = { 0 };
        int r = 0;
        for (int s = 0; s < a->n_spheres && r >= 0; s++)
                r = imp_image_new(crops[s].w, crops[s].h, 1, IMP_PIX_F32, &mx[s]);
        for (int i = 0; i < n_lf && r >= 0; i++) {
                _cleanup_image_ struct imp_image *f = NULL;
                r = imp_captureset_load_frame(cs, lf[i].index, &f, err);
                for (int s = 0; s < a->n_spheres && r >= 0; s++) {
                        _cleanup_image_ struct imp_image *c = NULL;
                        r = crop_dn(f, dark, cam->sensor.black_level_dn, &crops[s], &c);
                        for (int y = 0; r >= 0 && y < c->height; y++)
                                for (int x = 0; x < c->width; x++)
                                        *imp_image_f32(mx[s], x, y) = IMP_MAX(*imp_image_f32(mx[s], x, y), *imp_image_f32(c, x, y));
                }
        }
        for (int s = 0; s < a->n_spheres && r >= 0; s++) {
                struct imp_frame_view v = { mx[s], crops[s].x0, crops[s].y0 };
                r = imp_lights_sphere_fit(&cam->model, &v, a->spheres[s].r, a->spheres[s].z - a->spheres[s].r, &sph[s], err);
                if (r < 0)
                        imp_error_prefix(err, "sphere %d at (%g, %g): ", s, a->spheres[s].x, a->spheres[s].y);
        }
        for (int s = 0; s < a->n_spheres; s++)
                imp_image_free(mx[s]);
        return r;
}

static int locate_light(const struct imp_image *f, const struct imp_image *dark, const struct imp_rig_camera *cam,
                        const struct lights_args *a, const struct crop *crops, const struct imp_sphere *sph,
                        struct light_result *lr) {
        double o[MAX_SPHERES][3], d[MAX_SPHERES][3], sg[MAX_SPHERES];
        double sat = ldexp(1.0, cam->sensor.bits) - 1 - cam->sensor.black_level_dn;
        int n = 0;
        for (int s = 0; s < a->n_spheres; s++) {
                _cleanup_image_ struct imp_image *c = NULL;
                int r = crop_dn(f, dark, cam->sensor.black_level_dn, &crops[s], &c);
                if (r < 0)
                        return r;
                struct imp_frame_view v = { c, crops[s].x0, crops[s].y0 };
                struct imp_highlight h;
                if (imp_lights_highlight(&v, &sph[s], sat, &h) < 0)
                        continue;   /* this sphere does not reflect the light to the camera */
                if (imp_lights_reflect(&cam->model, &sph[s], h.px, h.sigma_px, o[n], d[n], &sg[n]) < 0)
                        continue;
                lr->n_saturated += h.saturated;
                n++;
        }
        lr->n_highlights = n;
        if (n == 0)
                return 0;
        int r = imp_lights_triangulate(n, (const double (*)[3]) o, (const double (*)[3]) d, sg, NULL, &lr->est);
        if (r < 0)
                return r;
        lr->have_pos = true;
        return 0;
}

static int lp_centre(const struct imp_rig_camera *cam, double plane_z, double ret[3]) {
        double px[2] = { 0.5 * (cam->model.width - 1), 0.5 * (cam->model.height - 1) }, O[3], d[3];
        imp_pinhole_ray_world(&cam->model, px, O, d);
        if (!(fabs(d[2]) > 1e-12))
                return -EDOM;
        double t = (plane_z - O[2]) / d[2];
        ret[0] = O[0] + t * d[0];
        ret[1] = O[1] + t * d[1];
        ret[2] = plane_z;
        return 0;
}

static int write_outputs(const struct lights_args *a, const struct imp_rig *set_rig, const struct imp_rig_camera *cam,
                         const struct light_result *res, const struct light_frame *lf, int n_lf,
                         const struct imp_captureset *cs) {
        struct imp_error err = {};
        struct imp_rig rig;
        if (imp_rig_copy(set_rig, &rig) < 0) {
                log_error("calibrate lights: out of memory");
                return 1;
        }
        for (int i = 0; i < n_lf; i++) {
                struct imp_rig_light *L = &rig.lights[lf[i].light];
                if (res[i].have_pos)
                        memcpy(L->pos_mm, res[i].est.pos_mm, sizeof L->pos_mm);
                if (res[i].have_intensity) {
                        L->intensity = res[i].li.intensity;
                        memcpy(L->colour, res[i].li.colour, sizeof L->colour);
                }
        }
        int ret = 0, r;
        if (a->out && (r = imp_rig_save(a->out, &rig, &err)) < 0) {
                log_error_errno(r, "calibrate lights: %s", err.msg);
                ret = 1;
        }
        if (a->lp) {
                _cleanup_free_ struct imp_rig_light *L = calloc((size_t) n_lf, sizeof *L);
                _cleanup_free_ const char **names = calloc((size_t) n_lf, sizeof *names);
                double centre[3];
                if (!L || !names)
                        return log_error("calibrate lights: out of memory"), 1;
                for (int i = 0; i < n_lf; i++) {
                        L[i] = rig.lights[lf[i].light];
                        const char *file = imp_captureset_record(cs, lf[i].index)->file;
                        const char *slash = strrchr(file, '/');
                        names[i] = slash ? slash + 1 : file;
                }
                r = lp_centre(cam, a->plane_z_mm, centre);
                if (r >= 0)
                        r = imp_lights_lp_write(a->lp, n_lf, L, names, centre, a->lp_near_field, &err);
                if (r < 0) {
                        log_error_errno(r, "calibrate lights: %s", err.msg[0] ? err.msg : "--lp: %m");
                        ret = 1;
                }
        }
        imp_rig_free(&rig);
        return ret;
}

static void report_lights(const struct lights_args *a, const struct imp_sphere *sph, const struct light_result *res,
                          int n_lf) {
        if (a->json) {
                json_t *j = json_object(), *js = json_array(), *jl = json_array();
                for (int s = 0; s < a->n_spheres; s++)
                        json_array_append_new(js, json_pack("{s:[f, f, f], s:f, s:[f, f], s:f, s:f, s:i}",
                                "centre_mm", sph[s].centre_mm[0], sph[s].centre_mm[1], sph[s].centre_mm[2],
                                "radius_mm", sph[s].radius_mm, "image_centre_px", sph[s].image_centre_px[0],
                                sph[s].image_centre_px[1], "image_radius_px", sph[s].image_radius_px,
                                "edge_rms_px", sph[s].rms_px, "edge_points", sph[s].n_edge));
                for (int i = 0; i < n_lf; i++)
                        json_array_append_new(jl, light_json(&res[i]));
                json_object_set_new(j, "spheres", js);
                json_object_set_new(j, "lights", jl);
                json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
                fputc('\n', stdout);
                json_decref(j);
                return;
        }
        for (int s = 0; s < a->n_spheres; s++)
                printf("sphere %d: centre (%.4f, %.4f, %.4f) mm, image (%.2f, %.2f) px r %.2f px, edge rms %.3f px\n", s,
                       sph[s].centre_mm[0], sph[s].centre_mm[1], sph[s].centre_mm[2], sph[s].image_centre_px[0],
                       sph[s].image_centre_px[1], sph[s].image_radius_px, sph[s].rms_px);
        for (int i = 0; i < n_lf; i++) {
                const struct light_result *lr = &res[i];
                printf("light %3d:", lr->id);
                if (lr->have_pos)
                        printf(" (%8.2f, %8.2f, %8.2f) mm ± %.2f, %d rays%s", lr->est.pos_mm[0], lr->est.pos_mm[1],
                               lr->est.pos_mm[2], lr->est.sigma_mm, lr->est.n_rays,
                               lr->est.flags & IMP_LIGHT_ILL_CONDITIONED ? " ILL-CONDITIONED" : "");
                else
                        printf(" not located (no highlight)");
                if (lr->have_intensity)
                        printf(", intensity %.5f ± %.2f %%", lr->li.intensity, 100 * lr->li.rel_sigma);
                putchar('\n');
        }
}

/* Keeps the direction of `pos` from the dome centre, sets its range to the dome radius. */
static void onto_dome(const double dome[4], double pos[3]) {
        double d[3] = { pos[0] - dome[0], pos[1] - dome[1], pos[2] - dome[2] };
        double len = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        if (!(len > 0))
                return;
        for (int k = 0; k < 3; k++)
                pos[k] = dome[k] + d[k] * dome[3] / len;
}

static int run_lights(const struct lights_args *a) {
        struct imp_error err = {};
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(a->set, &cs, &err);
        if (r < 0)
                return log_error("calibrate lights: %s", err.msg), EXIT_BADINPUT;
        struct imp_rig file_rig = {};
        const struct imp_rig *set_rig = imp_captureset_rig(cs);
        if (a->rig) {
                if ((r = imp_rig_load(a->rig, &file_rig, &err)) < 0)
                        return log_error("calibrate lights: %s", err.msg), EXIT_BADINPUT;
        }
        const struct imp_rig *cam_rig = a->rig ? &file_rig : set_rig;
        int ci = camera_index(cam_rig, a->camera);
        int ret = EXIT_BADINPUT;
        struct light_frame *lf = NULL;
        struct light_result *res = NULL;
        struct imp_image *dark = NULL;
        if (ci < 0) {
                log_error("calibrate lights: no camera '%s' in the rig", a->camera ? a->camera : "(any)");
                goto out_rig;
        }
        const struct imp_rig_camera *cam = &cam_rig->cameras[ci];
        /* the first frame of each dome light seen by this camera */
        lf = calloc(imp_captureset_count(cs) + 1, sizeof *lf);
        res = calloc(imp_captureset_count(cs) + 1, sizeof *res);
        if (!lf || !res) {
                ret = 1;
                goto out_rig;
        }
        int n_lf = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (rec->light < 0 || strcmp(rec->camera, cam->name) || rec->pattern.kind != IMP_PAT_NONE)
                        continue;
                int li = -1;
                for (int k = 0; k < set_rig->n_lights; k++)
                        if (set_rig->lights[k].id == rec->light)
                                li = k;
                bool seen = false;
                for (int k = 0; k < n_lf; k++)
                        seen |= lf[k].light == li;
                if (li >= 0 && !seen)
                        lf[n_lf++] = (struct light_frame) { i, li };
        }
        if (!n_lf) {
                log_error("calibrate lights: %s has no dome frames of camera %s", a->set, cam->name);
                goto out_rig;
        }
        r = mean_dark(cs, cam->name, -1, &dark, &err);
        if (r < 0) {
                log_error("calibrate lights: %s", err.msg);
                goto out_rig;
        }
        if (r == 0)
                log_warning("%s: no dark frames, using the black level %.1f DN", a->set, cam->sensor.black_level_dn);
        struct crop crops[MAX_SPHERES];
        struct imp_sphere sph[MAX_SPHERES];
        for (int s = 0; s < a->n_spheres; s++) {
                crops[s] = sphere_crop(&cam->model, &a->spheres[s]);
                if (crops[s].w < 16 || crops[s].h < 16) {
                        log_error("calibrate lights: sphere %d at (%g, %g) is not in the view of %s", s, a->spheres[s].x,
                                  a->spheres[s].y, cam->name);
                        goto out_rig;
                }
        }
        r = fit_spheres(cs, lf, n_lf, dark, cam, a, crops, sph, &err);
        if (r < 0) {
                log_error("calibrate lights: %s", err.msg);
                goto out_rig;
        }
        for (int i = 0; i < n_lf; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, lf[i].index);
                const struct imp_rig_light *nominal = &set_rig->lights[lf[i].light];
                _cleanup_image_ struct imp_image *f = NULL, *v = NULL;
                res[i].id = nominal->id;
                r = imp_captureset_load_frame(cs, lf[i].index, &f, &err);
                if (r >= 0)
                        r = locate_light(f, dark, cam, a, crops, sph, &res[i]);
                if (r < 0) {
                        log_error("calibrate lights: light %d: %s", nominal->id, err.msg[0] ? err.msg : strerror(-r));
                        ret = 1;
                        goto out_rig;
                }
                if (res[i].have_pos && a->dome[3] > 0)
                        onto_dome(a->dome, res[i].est.pos_mm);
                if (!res[i].have_pos) {
                        log_warning("light %d: no highlight on any sphere, keeping the nominal position, ignoring",
                                    nominal->id);
                        continue;
                }
                r = white_values(f, dark, cam, a, res[i].est.pos_mm, rec->exposure_us, rec->gain_db, &v);
                if (r >= 0)
                        r = light_intensity(v, cam, a->plane_z_mm, nominal, res[i].est.pos_mm, &res[i].li);
                if (r == -ENOENT)
                        log_warning("light %d: no white target pixel, intensity not measured, ignoring", nominal->id);
                else if (r < 0) {
                        ret = 1;
                        goto out_rig;
                }
                res[i].have_intensity = r >= 0;
        }
        report_lights(a, sph, res, n_lf);
        ret = write_outputs(a, set_rig, cam, res, lf, n_lf, cs);
out_rig:
        imp_image_free(dark);
        free(lf);
        free(res);
        if (a->rig)
                imp_rig_free(&file_rig);
        return ret;
}

int imp_calibrate_lights_main(int argc, char **argv) {
        struct lights_args a = { .white = { 0, 0, -1, -1 } };
        for (int i = 1; i < argc; i++) {
                const char *o = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                int n;
                if (!strcmp(o, "--help") || !strcmp(o, "-h"))
                        return usage_lights(stdout), 0;
                if (!strcmp(o, "--json")) {
                        a.json = true;
                        continue;
                }
                if (!strcmp(o, "--lp-near-field")) {
                        a.lp_near_field = true;
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", o);
                        return usage_lights(stderr), EXIT_USAGE;
                }
                i++;
                if (!strcmp(o, "--set"))
                        a.set = val;
                else if (!strcmp(o, "--rig"))
                        a.rig = val;
                else if (!strcmp(o, "--lp"))
                        a.lp = val;
                else if (!strcmp(o, "--out"))
                        a.out = val;
                else if (!strcmp(o, "--camera"))
                        a.camera = val;
                else if (!strcmp(o, "--spheres")) {
                        if (parse_spheres(val, &a) < 0)
                                return EXIT_USAGE;
                } else if (!strcmp(o, "--plane-z")) {
                        if (parse_list(o, val, &a.plane_z_mm, 1, 1, &n) < 0)
                                return EXIT_USAGE;
                } else if (!strcmp(o, "--dome")) {
                        if (parse_list(o, val, a.dome, 4, 4, &n) < 0)
                                return EXIT_USAGE;
                        if (!(a.dome[3] > 0)) {
                                log_error("--dome: the radius must be > 0");
                                return EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--white")) {
                        if (parse_list(o, val, a.white, 4, 4, &n) < 0)
                                return EXIT_USAGE;
                        if (!(a.white[2] > a.white[0] && a.white[3] > a.white[1])) {
                                log_error("--white: expected X0 < X1 and Y0 < Y1");
                                return EXIT_USAGE;
                        }
                } else {
                        log_error("unknown option '%s'", o);
                        return usage_lights(stderr), EXIT_USAGE;
                }
        }
        if (!a.set || !a.n_spheres) {
                log_error("calibrate lights: --set and --spheres are required (sphere detection is not "
                          "implemented: give their positions)");
                return usage_lights(stderr), EXIT_USAGE;
        }
        return run_lights(&a);
}

/* ---- radiometric ---- */

static bool same_light(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return !strcmp(a->camera, b->camera) && a->light == b->light && fabs(a->exposure_us - b->exposure_us) <= 1e-9 * a->exposure_us &&
               a->gain_db == b->gain_db && !memcmp(&a->pattern, &b->pattern, sizeof a->pattern) && !strcmp(a->step, b->step);
}

static int cmp_level(const void *x, const void *y) {
        const struct imp_ptc_level *a = x, *b = y;
        return (a->exposure_us > b->exposure_us) - (a->exposure_us < b->exposure_us);
}

static void free_frames(struct imp_image **v, int n) {
        for (int i = 0; i < n; i++)
                imp_image_free(v[i]);
}

static int run_radiometric(const char *set, const char *camera, const int roi[4], bool json, const char *out) {
        struct imp_error err = {};
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(set, &cs, &err);
        if (r < 0)
                return log_error("calibrate radiometric: %s", err.msg), EXIT_BADINPUT;
        const struct imp_rig *rig = imp_captureset_rig(cs);
        int ci = camera_index(rig, camera);
        if (ci < 0)
                return log_error("calibrate radiometric: no camera '%s' in %s/rig.json", camera ? camera : "(any)", set),
                       EXIT_BADINPUT;
        const char *cam = rig->cameras[ci].name;
        size_t n = imp_captureset_count(cs);
        static struct imp_image *frames[4 * IMP_PTC_MAX_LEVELS + 64];
        static struct imp_ptc_level levels[IMP_PTC_MAX_LEVELS];
        int nf = 0, nl = 0, nd = 0, ret = EXIT_BADINPUT;
        double gain_db = NAN, dark_exp = INFINITY;
        _cleanup_free_ bool *used = calloc(n + 1, sizeof *used);
        if (!used)
                return 1;
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (!strcmp(rec->step, "dark") && !strcmp(rec->camera, cam))
                        dark_exp = IMP_MIN(dark_exp, rec->exposure_us);
        }
        /* flat pairs: each frame with the next unused one taken in the same light */
        for (size_t i = 0; i < n && nl < IMP_PTC_MAX_LEVELS; i++) {
                const struct imp_frame_record *a = imp_captureset_record(cs, i);
                if (used[i] || strcmp(a->camera, cam) || !strcmp(a->step, "dark"))
                        continue;
                for (size_t k = i + 1; k < n; k++) {
                        const struct imp_frame_record *b = imp_captureset_record(cs, k);
                        if (used[k] || !same_light(a, b))
                                continue;
                        if (!isnan(gain_db) && a->gain_db != gain_db) {
                                log_error("calibrate radiometric: %s: frames at gains %g and %g dB", set, gain_db, a->gain_db);
                                goto out;
                        }
                        gain_db = a->gain_db;
                        used[i] = used[k] = true;
                        if ((r = imp_captureset_load_frame(cs, i, &frames[nf], &err)) < 0 ||
                            (r = imp_captureset_load_frame(cs, k, &frames[nf + 1], &err)) < 0) {
                                log_error("calibrate radiometric: %s", err.msg);
                                goto out;
                        }
                        levels[nl++] = (struct imp_ptc_level) { a->exposure_us, frames[nf], frames[nf + 1] };
                        nf += 2;
                        break;
                }
        }
        int first_dark = nf;
        for (size_t i = 0; i < n && nd < 64; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (strcmp(rec->step, "dark") || strcmp(rec->camera, cam) || rec->exposure_us != dark_exp)
                        continue;
                if ((r = imp_captureset_load_frame(cs, i, &frames[nf], &err)) < 0) {
                        log_error("calibrate radiometric: %s", err.msg);
                        goto out;
                }
                nf++, nd++;
        }
        if (nl == 0 || nd == 0) {
                log_error("calibrate radiometric: %s: need pairs of equal flat frames and dark frames (found %d "
                          "pairs, %d darks of %s)", set, nl, nd, cam);
                goto out;
        }
        qsort(levels, (size_t) nl, sizeof *levels, cmp_level);
        struct imp_ptc_input in = { .bits = rig->cameras[ci].sensor.bits, .gain_db = gain_db, .n_levels = nl,
                                    .levels = levels, .n_darks = nd,
                                    .darks = (const struct imp_image *const *) &frames[first_dark],
                                    .roi = { roi[0], roi[1], roi[2], roi[3] } };
        static struct imp_ptc_result res;
        if ((r = imp_radiometric_ptc(&in, &res, &err)) < 0) {
                log_error("calibrate radiometric: %s", err.msg);
                goto out;
        }
        if (json) {
                json_t *j = imp_radiometric_ptc_to_json(&res);
                json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
                fputc('\n', stdout);
                json_decref(j);
        } else {
                printf("%s (%d levels, %d darks): black %.3f DN, gain %.4f ± %.4f e/DN (0 dB), read noise %.3f e "
                       "(dark pair %.3f, intercept %.3f), full well %.0f e, nonlinearity %.3f %%%s%s\n",
                       cam, nl, nd, res.sensor.black_level_dn, res.sensor.gain_e_per_dn, res.gain_sigma_e_per_dn,
                       res.sensor.read_noise_e, res.read_noise_dark_e, res.read_noise_fit_e, res.sensor.full_well_e,
                       res.max_nonlinearity_pct, res.flags & IMP_PTC_FEW_LEVELS ? ", FEW LEVELS" : "",
                       res.flags & IMP_PTC_SATURATION_FOUND ? "" : ", saturation not reached (full well is a lower bound)");
        }
        ret = 0;
        if (out) {
                struct imp_rig copy;
                if (imp_rig_copy(rig, &copy) < 0) {
                        ret = 1;
                        goto out;
                }
                struct imp_sensor *s = &copy.cameras[ci].sensor;
                s->black_level_dn = res.sensor.black_level_dn;
                s->gain_e_per_dn = res.sensor.gain_e_per_dn;
                s->read_noise_e = res.sensor.read_noise_e;
                if (res.flags & IMP_PTC_SATURATION_FOUND)
                        s->full_well_e = res.sensor.full_well_e;
                if ((r = imp_rig_save(out, &copy, &err)) < 0) {
                        log_error_errno(r, "calibrate radiometric: %s", err.msg);
                        ret = 1;
                }
                imp_rig_free(&copy);
        }
out:
        free_frames(frames, nf);
        return ret;
}

int imp_calibrate_radiometric_main(int argc, char **argv) {
        const char *set = NULL, *camera = NULL, *out = NULL;
        int roi[4] = { 0, 0, 0, 0 };
        bool json = false;
        for (int i = 1; i < argc; i++) {
                const char *o = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                if (!strcmp(o, "--help") || !strcmp(o, "-h"))
                        return usage_radiometric(stdout), 0;
                if (!strcmp(o, "--json")) {
                        json = true;
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", o);
                        return usage_radiometric(stderr), EXIT_USAGE;
                }
                i++;
                if (!strcmp(o, "--set"))
                        set = val;
                else if (!strcmp(o, "--camera"))
                        camera = val;
                else if (!strcmp(o, "--out"))
                        out = val;
                else if (!strcmp(o, "--roi")) {
                        double v[4];
                        int n;
                        if (parse_list(o, val, v, 4, 4, &n) < 0)
                                return EXIT_USAGE;
                        for (int k = 0; k < 4; k++)
                                roi[k] = (int) v[k];
                        if (roi[0] < 0 || roi[1] < 0 || roi[2] <= 0 || roi[3] <= 0) {
                                log_error("--roi: expected X, Y >= 0 and W, H > 0");
                                return EXIT_USAGE;
                        }
                } else {
                        log_error("unknown option '%s'", o);
                        return usage_radiometric(stderr), EXIT_USAGE;
                }
        }
        if (!set) {
                log_error("calibrate radiometric: --set is required");
                return usage_radiometric(stderr), EXIT_USAGE;
        }
        return run_radiometric(set, camera, roi, json, out);
}
