/* `impasto calibrate lights`: dome light positions, intensities and colours from a capture
 * set of mirror spheres on a white target (one frame per light), written into a copy of
 * the set's rig.json and an RTI .lp file; `impasto calibrate radiometric`: the camera's
 * photon transfer from a set of flat-field pairs and dark frames, and the projector's gamma
 * from white, black and phase-shift frames of a flat target. The numerics live in
 * pipeline/calib/calib-lights.c and pipeline/calib/calib-radiometric.c; see docs/calibration-lights.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib-lights.h"
#include "calib-lights-joint.h"
#include "calib-radiometric.h"
#include "calibrate-ext.h"
#include "captureset.h"
#include "log.h"
#include "rig.h"

#define EXIT_USAGE 2
#define EXIT_BADINPUT 3
#define MAX_SPHERES 16
#define MAX_SETS 8
#define MAX_RAYS (MAX_SETS * MAX_SPHERES)
#define CROP_MARGIN 1.3               /* crop half-size in sphere image radii */
#define CROP_PAD_PX 6
#define DETECT_RADIUS_LO 0.6          /* detection: image radii accepted, × the expected one */
#define DETECT_RADIUS_HI 1.6
#define PATCH_PX 16                   /* intensity: patches of this size … */
#define PATCH_STEP_PX 48              /* … on a grid of this step */
#define DISC_MARGIN_MM 1.0            /* canvas excluded around a sphere's footprint */
#define SHADOW_MARGIN_MM 0.5          /* extra radius when testing a sphere's shadow */
#define LIT_FRACTION 0.5              /* target pixels must exceed this × the 90th percentile */
#define SAT_MARGIN_SIGMA 4.0          /* saturation: clip level less this many read-noise σ */

struct sphere_spec {
        double x, y, r, z;            /* centre (x, y, z) mm, radius mm */
};

struct crop {
        int x0, y0, w, h;
};

struct set_spec {
        const char *dir;
        double plane_z_mm;            /* the board's height in this capture */
};

struct lights_args {
        const char *rig, *lp, *out, *camera, *import_lp;
        struct set_spec sets[MAX_SETS];
        int n_sets;
        struct sphere_spec spheres[MAX_SPHERES];
        int n_spheres;                /* given positions (one set); 0 → detect */
        double sphere_radius_mm;      /* detection: the spheres' radius */
        double sphere_cut_mm;         /* the board cuts the spheres this far above their centres; NAN: balls */
        double plane_z_mm;            /* default board height of a --set without @Z */
        double white[4];              /* x0, y0, x1, y1 on the canvas; x1 < x0 → none */
        double dome[4];               /* centre x, y, z and radius mm; radius 0 → not given */
        bool json, lp_near_field;
        bool no_joint;                /* --no-joint: per-light triangulation only */
        double held_z_sigma_mm;       /* --board-sigma: 1σ of a board height (mirror centre z); 0 → default */
};

static void usage_lights(FILE *f) {
        fprintf(f, "usage: impasto calibrate lights --set DIR[@Z] [--set DIR[@Z]...] (--sphere-radius R | --spheres\n"
                   "                                \"X,Y,R[,Z];...\") [--sphere-cut H | --hemispheres] [--camera NAME]\n"
                   "                                [--rig RIG.json] [--plane-z MM (0)] [--white X0,Y0,X1,Y1]\n"
                   "                                [--dome CX,CY,CZ,R] [--no-joint] [--board-sigma MM]\n"
                   "                                [--lp OUT.lp] [--lp-near-field] [--json] [--out RIG.json]\n"
                   "       impasto calibrate lights --import-lp IN.lp [--rig RIG.json | --set DIR] [--dome CX,CY,CZ,R]\n"
                   "                                --out RIG.json\n"
                   "  --set:     a capture of mirror spheres on a white board, one frame per light (more\n"
                   "             exposures per light: the longest unsaturated highlight is used); @Z the\n"
                   "             board's height in mm (default --plane-z). Several sets (the spheres moved\n"
                   "             or the board raised) pool their rays per light.\n"
                   "  --sphere-radius: detect the spheres in each set (radius R mm, balls resting on the board)\n"
                   "  --sphere-cut H: the board cuts the spheres H mm above their centres (0: half balls, as\n"
                   "             --hemispheres; 0 < H < R: spherical caps, convex mirrors); default: balls\n"
                   "  --spheres: positions instead of detection (one set): centre (X, Y), radius R,\n"
                   "             centre height Z (default R), mm\n"
                   "  --rig:     camera model and sensor from this file instead of the set's rig.json;\n"
                   "             --out writes a copy of this rig with the lights replaced\n"
                   "  --white:   canvas rectangle (mm) of the white target for the intensities (first set)\n"
                   "             (default: every lit canvas pixel off the spheres and their shadows)\n"
                   "  --dome:    the dome's centre and radius (mm): each light is also put where its\n"
                   "             direction from the centre meets the dome (constrained estimate)\n"
                   "  --no-joint: skip the joint refinement of all lights and mirror centres from the\n"
                   "             highlights they share (default: refine; docs/calibration-lights.md)\n"
                   "  --board-sigma: 1σ of each capture's board height, i.e. of the mirror centres'\n"
                   "             heights, in the joint refinement (default 0.001 mm: the heights held)\n"
                   "  --import-lp: write the positions of an RTI .lp file into a copy of the rig (standard\n"
                   "             files are directions: put at --dome's radius from its centre)\n");
}

static void usage_radiometric(FILE *f) {
        fprintf(f, "usage: impasto calibrate radiometric (--set DIR | --projector-set DIR | both) [--camera NAME]\n"
                   "                                     [--roi X,Y,W,H] [--json] [--out RIG.json [--rig BASE.json]]\n"
                   "  --set:     the camera's photon transfer: pairs of equal frames (same exposure, gain,\n"
                   "             light, pattern) at rising exposures, and dark frames (those at the\n"
                   "             shortest dark exposure are used); --roi limits it to a window\n"
                   "  --projector-set: the projector's gamma: a flat diffuse target lit by the projector,\n"
                   "             with white, black and N >= 3 phase-shift frames (config/plans/\n"
                   "             projector-gamma.cfg); the longest period's steps on one axis, at the\n"
                   "             longest exposure whose white frame does not clip; and its black level\n"
                   "             (black / white above the sensor's black level: --set's, else the set's)\n"
                   "  --out:     a copy of the projector set's rig (else the set's) with the camera's sensor\n"
                   "             and the projector's gamma and black level replaced; with --rig, a copy of BASE.json\n"
                   "             instead (its camera of the same name gets the sensor)\n"
                   "exit status: 0 done (flags and sigmas say how far to trust it), 1 failure, 2 usage,\n"
                   "             3 bad input (a set missing the frames it needs, mismatched frames),\n"
                   "             6 the projector's gamma not determined (its root outside [0.3, 5]):\n"
                   "             reported with the flag at_bound; --out is written with the base's gamma\n");
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

/* DIR or DIR@Z. */
static int parse_set(const char *s, struct lights_args *a) {
        if (a->n_sets == MAX_SETS) {
                log_error("--set: at most %d", MAX_SETS);
                return -EINVAL;
        }
        struct set_spec *sp = &a->sets[a->n_sets];
        const char *at = strrchr(s, '@');
        sp->plane_z_mm = NAN;
        if (at) {
                char *end;
                sp->plane_z_mm = strtod(at + 1, &end);
                if (end == at + 1 || *end || !isfinite(sp->plane_z_mm)) {
                        log_error("--set %s: expected DIR or DIR@Z (Z the board height in mm)", s);
                        return -EINVAL;
                }
                if (!(sp->dir = strndup(s, (size_t) (at - s))))
                        return -ENOMEM;
        } else if (!(sp->dir = strdup(s)))
                return -ENOMEM;
        a->n_sets++;
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


/* ---- lights ---- */

/* One dome light's frames in a capture: the longest exposure (silhouettes, intensity) and
 * the others, longest first (highlights: the longest unsaturated one is used). */
#define MAX_EXPOSURES 8
struct light_frame {
        int light;                    /* index into the first set's rig lights */
        int n;
        size_t index[MAX_EXPOSURES];  /* records, exposure descending */
};

/* One --set: its frames, dark, camera and spheres. */
struct capture {
        const char *dir;
        double plane_z_mm;
        struct imp_captureset *cs;
        const struct imp_rig_camera *cam;
        struct light_frame *lf;
        int n_lf;
        struct imp_image *dark;       /* mean dark (f32) or NULL */
        double sat;                   /* clip level of a dark-subtracted pixel, DN */
        int n_spheres;
        struct crop crops[MAX_SPHERES];
        struct imp_sphere sph[MAX_SPHERES];
};

static bool sphere_shadows(const struct imp_sphere *sp, const double p[3], const double L[3]) {
        const double *C = sp->centre_mm;
        double d[3] = { L[0] - p[0], L[1] - p[1], L[2] - p[2] }, c[3] = { C[0] - p[0], C[1] - p[1], C[2] - p[2] };
        double dd = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        double t = IMP_CLAMP((c[0] * d[0] + c[1] * d[1] + c[2] * d[2]) / dd, 0.0, 1.0);
        double e[3] = { c[0] - t * d[0], c[1] - t * d[1], c[2] - t * d[2] };
        double rr = sp->radius_mm + SHADOW_MARGIN_MM;
        return e[0] * e[0] + e[1] * e[1] + e[2] * e[2] < rr * rr;
}

static int cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return (x > y) - (x < y);
}

/* The radiometric values of a frame on the white target's pixels, NAN elsewhere: off the
 * spheres, out of their shadows from light position L, inside --white (if given), and lit
 * (> LIT_FRACTION × the 90th percentile, which drops pixels off the target). */
static int white_values(const struct imp_image *f, const struct capture *cp, const struct lights_args *a,
                        const double L[3], double exposure_us, double gain_db, struct imp_image **ret) {
        const struct imp_rig_camera *cam = cp->cam;
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
                        if (cp->dark)
                                dn += cam->sensor.black_level_dn - *imp_image_f32(cp->dark, x, y);
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
                        double t = fabs(d[2]) > 1e-12 ? (cp->plane_z_mm - O[2]) / d[2] : -1;
                        double p[3] = { O[0] + t * d[0], O[1] + t * d[1], cp->plane_z_mm };
                        bool ok = *val > lit && t > 0;
                        if (ok && a->white[2] > a->white[0])
                                ok = p[0] >= a->white[0] && p[0] <= a->white[2] && p[1] >= a->white[1] &&
                                     p[1] <= a->white[3];
                        for (int s = 0; ok && s < cp->n_spheres; s++) {
                                const struct imp_sphere *sp = &cp->sph[s];
                                ok = hypot(p[0] - sp->centre_mm[0], p[1] - sp->centre_mm[1]) > sp->radius_mm + DISC_MARGIN_MM &&
                                     !sphere_shadows(sp, p, L);
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


/* The image window around an image circle with a margin, clipped to the frame. */
static struct crop circle_crop(const struct imp_pinhole *m, const double c[2], double rho) {
        double half = CROP_MARGIN * rho + CROP_PAD_PX;
        int x0 = (int) IMP_MAX(0.0, floor(c[0] - half)), y0 = (int) IMP_MAX(0.0, floor(c[1] - half));
        int x1 = (int) IMP_MIN((double) m->width, ceil(c[0] + half)), y1 = (int) IMP_MIN((double) m->height, ceil(c[1] + half));
        return (struct crop) { x0, y0, IMP_MAX(0, x1 - x0), IMP_MAX(0, y1 - y0) };
}

/* Apparent radius (px) of a sphere of radius r whose centre is at height z under the camera. */
static double image_radius(const struct imp_pinhole *m, double r, double z) {
        double cc[3];
        imp_pinhole_centre(m, cc);
        return r * m->fx / IMP_MAX(fabs(cc[2] - z), r);
}

/* The crop that holds a given sphere. */
static struct crop sphere_crop(const struct imp_pinhole *m, const struct sphere_spec *sp) {
        double C[3] = { sp->x, sp->y, sp->z }, px[2] = { -1, -1 }, cam_c[3];
        imp_pinhole_project(m, C, px);
        imp_pinhole_centre(m, cam_c);
        double dist = sqrt((C[0] - cam_c[0]) * (C[0] - cam_c[0]) + (C[1] - cam_c[1]) * (C[1] - cam_c[1]) +
                           (C[2] - cam_c[2]) * (C[2] - cam_c[2]));
        return circle_crop(m, px, sp->r * m->fx / dist);
}

static void capture_free(struct capture *cp) {
        imp_captureset_close(cp->cs);
        imp_image_free(cp->dark);
        free(cp->lf);
        *cp = (struct capture) { 0 };
}

static int rig_light_index(const struct imp_rig *rig, int id) {
        for (int k = 0; k < rig->n_lights; k++)
                if (rig->lights[k].id == id)
                        return k;
        return -1;
}

/* Opens a set: camera, the dome-light frames (grouped per light, exposure descending; lights
 * indexed in `lights_rig`), mean dark, clip level. */
static int capture_open(struct capture *cp, const struct set_spec *spec, const struct lights_args *a,
                        const struct imp_rig *file_rig, const struct imp_rig *lights_rig) {
        struct imp_error err = {};
        *cp = (struct capture) { .dir = spec->dir, .plane_z_mm = isfinite(spec->plane_z_mm) ? spec->plane_z_mm : a->plane_z_mm };
        int r = imp_captureset_open(spec->dir, &cp->cs, &err);
        if (r < 0)
                return log_error("calibrate lights: %s", err.msg), r;
        const struct imp_rig *set_rig = imp_captureset_rig(cp->cs);
        if (!lights_rig)
                lights_rig = set_rig;
        const struct imp_rig *cam_rig = file_rig ? file_rig : set_rig;
        int ci = camera_index(cam_rig, a->camera);
        if (ci < 0)
                return log_error("calibrate lights: no camera '%s' in the rig of %s", a->camera ? a->camera : "(any)",
                                 spec->dir), -ENOENT;
        cp->cam = &cam_rig->cameras[ci];
        size_t nrec = imp_captureset_count(cp->cs);
        if (!(cp->lf = calloc(nrec + 1, sizeof *cp->lf)))
                return -ENOMEM;
        for (size_t i = 0; i < nrec; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cp->cs, i);
                if (rec->light < 0 || strcmp(rec->camera, cp->cam->name) || rec->pattern.kind != IMP_PAT_NONE)
                        continue;
                int li = rig_light_index(lights_rig, rec->light), k = 0;
                if (li < 0)
                        continue;
                while (k < cp->n_lf && cp->lf[k].light != li)
                        k++;
                struct light_frame *L = &cp->lf[k];
                if (k == cp->n_lf)
                        *L = (struct light_frame) { .light = li }, cp->n_lf++;
                if (L->n == MAX_EXPOSURES)
                        continue;
                int j = L->n++;   /* insert keeping exposure descending */
                while (j > 0 && imp_captureset_record(cp->cs, L->index[j - 1])->exposure_us < rec->exposure_us) {
                        L->index[j] = L->index[j - 1];
                        j--;
                }
                L->index[j] = i;
        }
        if (!cp->n_lf)
                return log_error("calibrate lights: %s has no dome frames of camera %s", spec->dir, cp->cam->name), -ENOENT;
        r = mean_dark(cp->cs, cp->cam->name, -1, &cp->dark, &err);
        if (r < 0)
                return log_error("calibrate lights: %s", err.msg), r;
        if (r == 0)
                log_warning("%s: no dark frames, using the black level %.1f DN", spec->dir, cp->cam->sensor.black_level_dn);
        const struct imp_sensor *sn = &cp->cam->sensor;
        double gain = sn->gain_e_per_dn > 0 ? sn->gain_e_per_dn : 1;
        double clip = ldexp(1.0, sn->bits) - 1 - sn->black_level_dn;
        if (sn->full_well_e > 0)
                clip = IMP_MIN(clip, sn->full_well_e / gain);
        cp->sat = clip - SAT_MARGIN_SIGMA * IMP_MAX(sn->read_noise_e / gain, 1.0);
        return 0;
}

/* Per-pixel maximum of the dark-subtracted longest-exposure frames of every light: the
 * white board is lit in some frame everywhere (so no cast shadow touches an outline), the
 * mirror bodies stay dark but for their highlights, which lie well inside the rims. */
static int max_image(const struct capture *cp, struct imp_image **ret, struct imp_error *err) {
        const struct imp_pinhole *m = &cp->cam->model;
        struct crop all = { 0, 0, m->width, m->height };
        _cleanup_image_ struct imp_image *mx = NULL;
        int r = 0;
        for (int i = 0; i < cp->n_lf && r >= 0; i++) {
                _cleanup_image_ struct imp_image *f = NULL, *c = NULL;
                r = imp_captureset_load_frame(cp->cs, cp->lf[i].index[0], &f, err);
                if (r >= 0 && (f->width != m->width || f->height != m->height))
                        r = imp_error_set(err, -EINVAL, "%s: frames are %dx%d, the camera model %dx%d", cp->dir, f->width,
                                          f->height, m->width, m->height);
                if (r >= 0)
                        r = crop_dn(f, cp->dark, cp->cam->sensor.black_level_dn, &all, &c);
                if (r < 0)
                        break;
                if (!mx) {
                        mx = TAKE_PTR(c);
                        continue;
                }
                for (int y = 0; y < c->height; y++)
                        for (int x = 0; x < c->width; x++)
                                *imp_image_f32(mx, x, y) = IMP_MAX(*imp_image_f32(mx, x, y), *imp_image_f32(c, x, y));
        }
        if (r >= 0)
                *ret = TAKE_PTR(mx);
        return r;
}

static int crop_image(const struct imp_image *img, const struct crop *c, struct imp_image **ret) {
        int r = imp_image_new(c->w, c->h, 1, IMP_PIX_F32, ret);
        for (int y = 0; r >= 0 && y < c->h; y++)
                for (int x = 0; x < c->w; x++)
                        *imp_image_f32(*ret, x, y) = *imp_image_f32(img, c->x0 + x, c->y0 + y);
        return r;
}

/* Spheres of a capture: given (--spheres) or detected in the max image; then each centre
 * from its silhouette. A detected sphere whose fit fails is dropped with a warning. */
static int capture_spheres(struct capture *cp, const struct lights_args *a) {
        struct imp_error err = {};
        const struct imp_pinhole *m = &cp->cam->model;
        _cleanup_image_ struct imp_image *mx = NULL;
        int r = max_image(cp, &mx, &err);
        if (r < 0)
                return log_error("calibrate lights: %s", err.msg), r;
        double radius[MAX_SPHERES], cz[MAX_SPHERES];
        int n = 0;
        if (a->n_spheres) {
                for (int s = 0; s < a->n_spheres; s++) {
                        cp->crops[s] = sphere_crop(m, &a->spheres[s]);
                        radius[s] = a->spheres[s].r;
                        cz[s] = a->spheres[s].z;
                        if (cp->crops[s].w < 16 || cp->crops[s].h < 16)
                                return log_error("calibrate lights: sphere %d at (%g, %g) is not in the view of %s", s,
                                                 a->spheres[s].x, a->spheres[s].y, cp->cam->name), -EDOM;
                }
                n = a->n_spheres;
        } else {
                struct imp_sphere_circle circ[MAX_SPHERES];
                double r = a->sphere_radius_mm, cut = a->sphere_cut_mm;
                double rz = cp->plane_z_mm + (isfinite(cut) ? -cut : r);
                double rho = isfinite(cut) ? image_radius(m, sqrt(r * r - cut * cut), cp->plane_z_mm) : image_radius(m, r, rz);
                struct imp_frame_view v = { mx, 0, 0 };
                int found = imp_lights_sphere_detect(&v, DETECT_RADIUS_LO * rho, DETECT_RADIUS_HI * rho, circ, MAX_SPHERES);
                if (found < 0)
                        return log_error_errno(found, "calibrate lights: %s: sphere detection failed", cp->dir), found;
                if (found > MAX_SPHERES)
                        log_warning("%s: %d spheres found, using the first %d", cp->dir, found, MAX_SPHERES);
                n = IMP_MIN(found, MAX_SPHERES);
                for (int s = 0; s < n; s++) {
                        cp->crops[s] = circle_crop(m, circ[s].centre_px, circ[s].radius_px);
                        radius[s] = a->sphere_radius_mm;
                        cz[s] = rz;
                        log_info("%s: sphere %d at (%.2f, %.2f) px, radius %.2f px (expected %.1f), edge rms %.3f px, %d "
                                 "edges", cp->dir, s, circ[s].centre_px[0], circ[s].centre_px[1], circ[s].radius_px, rho,
                                 circ[s].rms_px, circ[s].n_edge);
                }
        }
        int kept = 0;
        for (int s = 0; s < n; s++) {
                _cleanup_image_ struct imp_image *c = NULL;
                if ((r = crop_image(mx, &cp->crops[s], &c)) < 0)
                        return r;
                struct imp_frame_view v = { c, cp->crops[s].x0, cp->crops[s].y0 };
                r = imp_lights_sphere_fit(m, &v, radius[s], cz[s], a->sphere_cut_mm, &cp->sph[kept], &err);
                if (r < 0 && a->n_spheres)
                        return log_error("calibrate lights: %s: sphere %d at (%g, %g): %s", cp->dir, s, a->spheres[s].x,
                                         a->spheres[s].y, err.msg), r;
                if (r < 0) {
                        log_warning("%s: sphere %d: %s, ignoring it", cp->dir, s, err.msg);
                        continue;
                }
                cp->crops[kept++] = cp->crops[s];
        }
        cp->n_spheres = kept;
        if (!kept)
                return log_error("calibrate lights: %s: no mirror sphere found (expected radius %g mm)", cp->dir,
                                 a->n_spheres ? a->spheres[0].r : a->sphere_radius_mm), -ENOENT;
        return 0;
}

/* Rays and highlight counts of one light. */
struct light_result {
        int id;
        bool have_pos, have_intensity, have_dome;
        struct imp_light_estimate est;    /* free least squares */
        struct imp_light_estimate dome;   /* moved onto the dome (--dome), covariance projected */
        struct imp_light_intensity li;
        int n_highlights, n_saturated;
        double o[MAX_RAYS][3], d[MAX_RAYS][3], sg[MAX_RAYS];
        /* the highlights behind the rays, for the joint refinement */
        double px[MAX_RAYS][2], spx[MAX_RAYS];
        int mirror[MAX_RAYS];             /* index into the flattened mirrors of all captures */
        bool hsat[MAX_RAYS];
        bool have_joint;
        struct imp_light_estimate tri;    /* per-light triangulation (est is the joint one when have_joint) */
        int n_outliers;                   /* highlights the joint refinement rejected */
};

/* The highlight of one light on one sphere: from the longest exposure whose highlight is
 * not saturated; when every exposure saturates, the shortest one's (flagged, σ inflated). */
static int sphere_highlight(const struct capture *cp, struct imp_image *const *frames, int n_frames, int s,
                            struct imp_highlight *ret) {
        int r = -ENOENT;
        for (int e = 0; e < n_frames; e++) {
                _cleanup_image_ struct imp_image *c = NULL;
                int q = crop_dn(frames[e], cp->dark, cp->cam->sensor.black_level_dn, &cp->crops[s], &c);
                if (q < 0)
                        return q;
                struct imp_frame_view v = { c, cp->crops[s].x0, cp->crops[s].y0 };
                struct imp_highlight h;
                if (imp_lights_highlight(&v, &cp->sph[s], cp->sat, &h) < 0)
                        continue;
                *ret = h;
                r = 0;
                if (!h.saturated)
                        break;
        }
        return r;
}

/* Adds the reflected rays of every sphere of a capture for light frame lf to lr. */
static int capture_rays(const struct capture *cp, int mirror0, const struct light_frame *lf, struct light_result *lr,
                        struct imp_error *err) {
        struct imp_image *frames[MAX_EXPOSURES] = { 0 };
        int r = 0;
        for (int e = 0; e < lf->n && r >= 0; e++)
                r = imp_captureset_load_frame(cp->cs, lf->index[e], &frames[e], err);
        for (int s = 0; s < cp->n_spheres && r >= 0 && lr->n_highlights < MAX_RAYS; s++) {
                struct imp_highlight h;
                int n = lr->n_highlights, q = sphere_highlight(cp, frames, lf->n, s, &h);
                if (q == -ENOENT)
                        continue;   /* this sphere does not reflect the light to the camera */
                if (q < 0) {
                        r = q;
                        break;
                }
                if (imp_lights_reflect(&cp->cam->model, &cp->sph[s], h.px, h.sigma_px, lr->o[n], lr->d[n], &lr->sg[n]) < 0)
                        continue;
                lr->n_saturated += h.saturated;
                memcpy(lr->px[n], h.px, sizeof h.px);
                lr->spx[n] = h.sigma_px;
                lr->hsat[n] = h.saturated;
                lr->mirror[n] = mirror0 + s;
                lr->n_highlights++;
        }
        for (int e = 0; e < lf->n; e++)
                imp_image_free(frames[e]);
        return r;
}

/* The position on the dome (its centre and radius in dome[4]) along the direction of est
 * from the centre, with the covariance mapped by that projection's Jacobian
 * (R/|X − c|)(I − n nᵀ): the range is the dome's, only the direction is uncertain. */
static void onto_dome(const double dome[4], const struct imp_light_estimate *est, struct imp_light_estimate *ret) {
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

/* The joint refinement's outcome, for the report. */
struct joint_out {
        bool done;
        struct imp_joint_report rep;
        int mirror0[MAX_SETS];            /* first flattened mirror index of each capture */
        struct imp_joint_centre c[MAX_SETS * MAX_SPHERES];
};

/* Every located light and every mirror of every capture refined together from the highlights
 * (pipeline/calib/calib-lights-joint.c); the per-light triangulation is kept in lr->tri. */
static int joint_refine(const struct lights_args *a, const struct capture *caps, int n_caps, struct light_result *res,
                        int n, struct joint_out *jo) {
        static struct imp_joint_mirror mir[MAX_SETS * MAX_SPHERES];
        int nm = 0, no = 0, r;
        for (int c = 0; c < n_caps; c++) {
                jo->mirror0[c] = nm;
                for (int s = 0; s < caps[c].n_spheres; s++)
                        mir[nm++] = (struct imp_joint_mirror) { .cam = &caps[c].cam->model, .sphere = caps[c].sph[s] };
        }
        for (int i = 0; i < n; i++)
                no += res[i].have_pos ? res[i].n_highlights : 0;
        _cleanup_free_ struct imp_joint_obs *obs = calloc((size_t) no + 1, sizeof *obs);
        _cleanup_free_ struct imp_light_estimate *in = calloc((size_t) n + 1, sizeof *in);
        _cleanup_free_ struct imp_light_estimate *out = calloc((size_t) n + 1, sizeof *out);
        _cleanup_free_ bool *outlier = calloc((size_t) no + 1, sizeof *outlier);
        if (!obs || !in || !out || !outlier)
                return -ENOMEM;
        no = 0;
        for (int i = 0; i < n; i++) {
                const struct light_result *lr = &res[i];
                in[i] = lr->est;
                for (int k = 0; lr->have_pos && k < lr->n_highlights; k++)
                        obs[no++] = (struct imp_joint_obs) { .light = i, .mirror = lr->mirror[k], .px = { lr->px[k][0],
                                                             lr->px[k][1] }, .sigma_px = lr->spx[k], .saturated = lr->hsat[k] };
        }
        struct imp_joint_opts opts = { .held_z_sigma_mm = a->held_z_sigma_mm };
        if ((r = imp_lights_joint_refine(n, in, nm, mir, no, obs, &opts, out, jo->c, NULL, outlier, &jo->rep)) < 0)
                return r;
        for (int k = 0; k < no; k++)
                res[obs[k].light].n_outliers += outlier[k];
        for (int i = 0; i < n; i++) {
                struct light_result *lr = &res[i];
                if (!lr->have_pos)
                        continue;
                lr->tri = lr->est;
                lr->est = out[i];
                lr->have_joint = true;
        }
        jo->done = true;
        const struct imp_joint_report *rp = &jo->rep;
        log_info("joint refinement: %d highlights, %d outliers, %d iterations; RMS %.4f → %.4f px (σ scale %.2f); "
                 "mirror centres moved %.2f µm RMS, %.2f µm max; cond %.3g, from the highlights alone %.3g", rp->n_obs,
                 rp->n_outliers, rp->iterations, rp->rms_px_before, rp->rms_px_after, rp->scale,
                 1000 * rp->centre_shift_rms_mm, 1000 * rp->centre_shift_max_mm, rp->cond, rp->cond_data);
        if (rp->flags & IMP_JOINT_NOT_CONVERGED)
                log_warning("joint refinement: not converged in %d iterations, using its last values", rp->iterations);
        if (rp->flags & IMP_JOINT_WEAK_CENTRES)
                log_warning("joint refinement: the highlights alone do not determine the mirror centres (cond %.3g): "
                            "they stay near their silhouette fits", rp->cond_data);
        if (rp->flags & IMP_JOINT_ILL_CONDITIONED)
                log_warning("joint refinement: ill-conditioned (cond %.3g)", rp->cond);
        return 0;
}

static json_t *estimate_json(const struct imp_light_estimate *e) {
        const double *c = e->cov_mm2;
        return json_pack("{s:[f, f, f], s:f, s:[f, f, f, f, f, f, f, f, f]}", "pos_mm", e->pos_mm[0], e->pos_mm[1],
                         e->pos_mm[2], "sigma_mm", e->sigma_mm, "cov_mm2", c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7],
                         c[8]);
}

static json_t *light_json(const struct light_result *lr) {
        json_t *j = json_pack("{s:i, s:b, s:i, s:i}", "id", lr->id, "located", lr->have_pos, "highlights",
                              lr->n_highlights, "saturated_highlights", lr->n_saturated);
        if (lr->have_pos) {
                const struct imp_light_estimate *e = &lr->est;
                json_t *je = estimate_json(e);
                json_object_update(j, je);
                json_decref(je);
                json_object_set_new(j, "rms_mm", json_real(e->rms_mm));
                json_object_set_new(j, "cond", json_real(e->cond));
                json_object_set_new(j, "flags", json_pack("{s:b, s:b, s:b, s:b}",
                        "ill_conditioned", !!(e->flags & IMP_LIGHT_ILL_CONDITIONED),
                        "few_rays", !!(e->flags & IMP_LIGHT_FEW_RAYS),
                        "saturated", !!(e->flags & IMP_LIGHT_SATURATED), "behind", !!(e->flags & IMP_LIGHT_BEHIND)));
                if (lr->have_dome)
                        json_object_set_new(j, "dome", estimate_json(&lr->dome));
                if (lr->have_joint) {
                        json_t *jt = estimate_json(&lr->tri);
                        json_object_set_new(jt, "rms_mm", json_real(lr->tri.rms_mm));
                        json_object_set_new(jt, "cond", json_real(lr->tri.cond));
                        json_object_set_new(jt, "ill_conditioned", json_boolean(lr->tri.flags & IMP_LIGHT_ILL_CONDITIONED));
                        json_object_set_new(j, "triangulated", jt);
                        json_object_set_new(j, "joint_outliers", json_integer(lr->n_outliers));
                }
        }
        if (lr->have_intensity) {
                json_object_set_new(j, "intensity", json_real(lr->li.intensity));
                json_object_set_new(j, "colour", json_pack("[f, f, f]", lr->li.colour[0], lr->li.colour[1], lr->li.colour[2]));
                json_object_set_new(j, "intensity_rel_sigma", json_real(lr->li.rel_sigma));
                json_object_set_new(j, "intensity_pixels", json_integer(lr->li.n_pixels));
        }
        return j;
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

/* The estimates (indexed like set_rig's lights) go into a copy of `base` (--rig, else the
 * set's rig), matched by light id: the other devices are the base's. */
static int write_outputs(const struct lights_args *a, const struct imp_rig *base, const struct imp_rig *set_rig,
                         const struct capture *cp, const struct light_result *res) {
        struct imp_error err = {};
        struct imp_rig rig;
        _cleanup_free_ int *map = calloc((size_t) set_rig->n_lights + 1, sizeof *map);
        if (!map || imp_rig_copy(base, &rig) < 0) {
                log_error("calibrate lights: out of memory");
                return 1;
        }
        for (int i = 0; i < set_rig->n_lights; i++)
                if ((map[i] = rig_light_index(&rig, set_rig->lights[i].id)) < 0) {
                        log_error("calibrate lights: the rig of --rig has no light %d (the sets' rig has)",
                                  set_rig->lights[i].id);
                        imp_rig_free(&rig);
                        return EXIT_BADINPUT;
                }
        for (int i = 0; i < set_rig->n_lights; i++) {
                struct imp_rig_light *L = &rig.lights[map[i]];
                if (res[i].have_pos)
                        memcpy(L->pos_mm, res[i].have_dome ? res[i].dome.pos_mm : res[i].est.pos_mm, sizeof L->pos_mm);
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
                _cleanup_free_ struct imp_rig_light *L = calloc((size_t) cp->n_lf + 1, sizeof *L);
                _cleanup_free_ const char **names = calloc((size_t) cp->n_lf + 1, sizeof *names);
                double centre[3];
                if (!L || !names) {
                        imp_rig_free(&rig);
                        return log_error("calibrate lights: out of memory"), 1;
                }
                for (int i = 0; i < cp->n_lf; i++) {
                        L[i] = rig.lights[map[cp->lf[i].light]];
                        const char *file = imp_captureset_record(cp->cs, cp->lf[i].index[0])->file;
                        const char *slash = strrchr(file, '/');
                        names[i] = slash ? slash + 1 : file;
                }
                r = lp_centre(cp->cam, cp->plane_z_mm, centre);
                if (r >= 0)
                        r = imp_lights_lp_write(a->lp, cp->n_lf, L, names, centre, a->lp_near_field, &err);
                if (r < 0) {
                        log_error_errno(r, "calibrate lights: %s", err.msg[0] ? err.msg : "--lp: %m");
                        ret = 1;
                }
        }
        imp_rig_free(&rig);
        return ret;
}

static json_t *joint_json(const struct joint_out *jo) {
        const struct imp_joint_report *r = &jo->rep;
        return json_pack("{s:i, s:i, s:i, s:i, s:i, s:i, s:f, s:f, s:f, s:f, s:i, s:f, s:f, s:f, s:f, s:f, s:f, s:{s:b, s:b, s:b}}",
                         "iterations", r->iterations, "passes", r->passes, "highlights", r->n_obs, "outliers", r->n_outliers,
                         "lights", r->n_lights, "mirrors", r->n_mirrors, "rms_px_before", r->rms_px_before,
                         "rms_px_after", r->rms_px_after, "chi2_before", r->chi2_before, "chi2_after", r->chi2_after,
                         "dof", r->dof, "residual_scale", r->scale, "cov_scale", r->cov_scale, "cond", r->cond,
                         "cond_data", r->cond_data, "centre_shift_rms_mm", r->centre_shift_rms_mm,
                         "centre_shift_max_mm", r->centre_shift_max_mm, "flags", "not_converged",
                         !!(r->flags & IMP_JOINT_NOT_CONVERGED), "weak_centres", !!(r->flags & IMP_JOINT_WEAK_CENTRES),
                         "ill_conditioned", !!(r->flags & IMP_JOINT_ILL_CONDITIONED));
}

static void report_lights(const struct lights_args *a, const struct capture *caps, int n_caps,
                          const struct light_result *res, int n, const struct joint_out *jo) {
        if (a->json) {
                json_t *j = json_object(), *js = json_array(), *jl = json_array();
                for (int c = 0; c < n_caps; c++)
                        for (int s = 0; s < caps[c].n_spheres; s++) {
                                const struct imp_sphere *sp = &caps[c].sph[s];
                                json_array_append_new(js, json_pack("{s:s, s:[f, f, f], s:f, s:f, s:[f, f], s:f, s:f, s:i}",
                                        "set", caps[c].dir, "centre_mm", sp->centre_mm[0], sp->centre_mm[1], sp->centre_mm[2],
                                        "centre_sigma_mm", sp->centre_sigma_mm, "radius_mm", sp->radius_mm,
                                        "image_centre_px", sp->image_centre_px[0], sp->image_centre_px[1],
                                        "image_radius_px", sp->image_radius_px, "edge_rms_px", sp->rms_px,
                                        "edge_points", sp->n_edge));
                                if (jo->done) {
                                        const struct imp_joint_centre *jc = &jo->c[jo->mirror0[c] + s];
                                        json_t *e = json_array_get(js, json_array_size(js) - 1);
                                        json_object_set_new(e, "joint_centre_mm", json_pack("[f, f, f]", jc->centre_mm[0],
                                                            jc->centre_mm[1], jc->centre_mm[2]));
                                        json_object_set_new(e, "joint_centre_sigma_mm", json_real(jc->sigma_mm));
                                        json_object_set_new(e, "joint_shift_mm", json_real(jc->shift_mm));
                                }
                        }
                for (int i = 0; i < n; i++)
                        json_array_append_new(jl, light_json(&res[i]));
                json_object_set_new(j, "spheres", js);
                json_object_set_new(j, "lights", jl);
                if (jo->done)
                        json_object_set_new(j, "joint", joint_json(jo));
                json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
                fputc('\n', stdout);
                json_decref(j);
                return;
        }
        for (int c = 0; c < n_caps; c++)
                for (int s = 0; s < caps[c].n_spheres; s++) {
                        const struct imp_sphere *sp = &caps[c].sph[s];
                        printf("%s sphere %d: centre (%.4f, %.4f, %.4f) mm ± %.4f, image (%.2f, %.2f) px r %.2f px, edge "
                               "rms %.3f px\n", caps[c].dir, s, sp->centre_mm[0], sp->centre_mm[1], sp->centre_mm[2],
                               sp->centre_sigma_mm, sp->image_centre_px[0], sp->image_centre_px[1], sp->image_radius_px,
                               sp->rms_px);
                }
        if (jo->done)
                printf("joint refinement: %d highlights (%d outliers), %d lights, %d mirrors, %d iterations; RMS %.4f → "
                       "%.4f px; centres moved %.2f µm RMS, %.2f µm max; cond %.3g (highlights alone %.3g)%s\n",
                       jo->rep.n_obs, jo->rep.n_outliers, jo->rep.n_lights, jo->rep.n_mirrors, jo->rep.iterations,
                       jo->rep.rms_px_before, jo->rep.rms_px_after, 1000 * jo->rep.centre_shift_rms_mm,
                       1000 * jo->rep.centre_shift_max_mm, jo->rep.cond, jo->rep.cond_data,
                       jo->rep.flags & IMP_JOINT_WEAK_CENTRES ? ", WEAK CENTRES" : "");
        for (int i = 0; i < n; i++) {
                const struct light_result *lr = &res[i];
                printf("light %3d:", lr->id);
                if (lr->have_pos) {
                        const struct imp_light_estimate *e = lr->have_dome ? &lr->dome : &lr->est;
                        printf(" (%8.2f, %8.2f, %8.2f) mm ± %.2f%s, %d rays%s%s", e->pos_mm[0], e->pos_mm[1], e->pos_mm[2],
                               e->sigma_mm, lr->have_dome ? " on the dome" : "", lr->est.n_rays,
                               lr->est.flags & IMP_LIGHT_ILL_CONDITIONED ? " ILL-CONDITIONED" : "",
                               lr->n_saturated ? " (saturated highlights)" : "");
                } else
                        printf(" not located (no highlight)");
                if (lr->have_intensity)
                        printf(", intensity %.5f ± %.2f %%", lr->li.intensity, 100 * lr->li.rel_sigma);
                putchar('\n');
        }
}

static int run_lights(const struct lights_args *a) {
        struct imp_error err = {};
        struct imp_rig file_rig = {};
        if (a->rig && imp_rig_load(a->rig, &file_rig, &err) < 0)
                return log_error("calibrate lights: %s", err.msg), EXIT_BADINPUT;
        static struct capture caps[MAX_SETS];
        int ret = EXIT_BADINPUT, n_caps = 0, r;
        struct light_result *res = NULL;
        const struct imp_rig *rig0 = NULL;
        for (int c = 0; c < a->n_sets; c++, n_caps++)
                if (capture_open(&caps[c], &a->sets[c], a, a->rig ? &file_rig : NULL, rig0) < 0 ||
                    capture_spheres(&caps[c], a) < 0)
                        goto out;
                else if (!rig0)
                        rig0 = imp_captureset_rig(caps[0].cs);
        int n = rig0->n_lights;
        if (!(res = calloc((size_t) n + 1, sizeof *res))) {
                ret = 1;
                goto out;
        }
        for (int i = 0; i < n; i++)
                res[i].id = rig0->lights[i].id;
        /* rays of every light from every capture, pooled */
        for (int c = 0, m0 = 0; c < n_caps; m0 += caps[c].n_spheres, c++)
                for (int i = 0; i < caps[c].n_lf; i++) {
                        struct light_result *lr = &res[caps[c].lf[i].light];
                        if ((r = capture_rays(&caps[c], m0, &caps[c].lf[i], lr, &err)) < 0) {
                                log_error("calibrate lights: light %d: %s", lr->id, err.msg[0] ? err.msg : strerror(-r));
                                ret = 1;
                                goto out;
                        }
                }
        int n_ill = 0, n_sat = 0;
        for (int i = 0; i < n; i++) {
                struct light_result *lr = &res[i];
                if (!lr->n_highlights)
                        continue;
                if ((r = imp_lights_triangulate(lr->n_highlights, (const double (*)[3]) lr->o, (const double (*)[3]) lr->d,
                                                lr->sg, NULL, &lr->est)) < 0) {
                        log_error_errno(r, "calibrate lights: light %d: triangulation failed", lr->id);
                        ret = 1;
                        goto out;
                }
                lr->have_pos = true;
                if (lr->n_saturated)
                        lr->est.flags |= IMP_LIGHT_SATURATED, n_sat++;
        }
        static struct joint_out joint;
        joint.done = false;
        if (!a->no_joint && (r = joint_refine(a, caps, n_caps, res, n, &joint)) < 0) {
                log_error_errno(r, "calibrate lights: joint refinement failed");
                ret = 1;
                goto out;
        }
        for (int i = 0; i < n; i++) {
                struct light_result *lr = &res[i];
                if (!lr->have_pos)
                        continue;
                if (lr->est.flags & IMP_LIGHT_ILL_CONDITIONED) {
                        n_ill++;
                        log_warning("light %d: rays nearly parallel (cond %.3g, %d rays): its range is not determined "
                                    "(σ %.0f mm)%s", lr->id, lr->est.cond, lr->n_highlights, lr->est.sigma_mm,
                                    a->dome[3] > 0 ? ", the dome radius fixes it" : "; spread the spheres or add --dome");
                }
                if (a->dome[3] > 0) {
                        onto_dome(a->dome, &lr->est, &lr->dome);
                        lr->have_dome = true;
                }
        }
        if (n_sat)
                log_warning("%d lights used saturated highlights (centroid of the clipped blob, σ ≥ 0.25 px); add a "
                            "shorter exposure to the plan", n_sat);
        /* intensity and colour from the first capture's white board */
        const struct capture *c0 = &caps[0];
        for (int i = 0; i < c0->n_lf; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(c0->cs, c0->lf[i].index[0]);
                struct light_result *lr = &res[c0->lf[i].light];
                const struct imp_rig_light *nominal = &rig0->lights[c0->lf[i].light];
                if (!lr->have_pos) {
                        log_warning("light %d: no highlight on any sphere, keeping the nominal position, ignoring", lr->id);
                        continue;
                }
                const double *pos = lr->have_dome ? lr->dome.pos_mm : lr->est.pos_mm;
                _cleanup_image_ struct imp_image *f = NULL, *v = NULL;
                r = imp_captureset_load_frame(c0->cs, c0->lf[i].index[0], &f, &err);
                if (r >= 0)
                        r = white_values(f, c0, a, pos, rec->exposure_us, rec->gain_db, &v);
                if (r >= 0)
                        r = light_intensity(v, c0->cam, c0->plane_z_mm, nominal, pos, &lr->li);
                if (r == -ENOENT)
                        log_warning("light %d: no white target pixel, intensity not measured, ignoring", lr->id);
                else if (r < 0) {
                        log_error_errno(r, "calibrate lights: light %d: %s", lr->id, err.msg[0] ? err.msg : "intensity");
                        ret = 1;
                        goto out;
                }
                lr->have_intensity = r >= 0;
        }
        if (n_ill)
                log_warning("%d of %d lights ill-conditioned", n_ill, n);
        report_lights(a, caps, n_caps, res, n, &joint);
        ret = write_outputs(a, a->rig ? &file_rig : rig0, rig0, c0, res);
out:
        for (int c = 0; c < n_caps + (n_caps < a->n_sets); c++)
                capture_free(&caps[c]);
        free(res);
        if (a->rig)
                imp_rig_free(&file_rig);
        return ret;
}

/* --import-lp: an RTI light-position file into a copy of a rig, lights in file order. */
static int run_import_lp(const struct lights_args *a) {
        struct imp_error err = {};
        struct imp_rig rig = {};
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r;
        if (a->rig)
                r = imp_rig_load(a->rig, &rig, &err);
        else if ((r = imp_captureset_open(a->sets[0].dir, &cs, &err)) >= 0)
                r = imp_rig_copy(imp_captureset_rig(cs), &rig);
        if (r < 0)
                return log_error("calibrate lights: %s", err.msg[0] ? err.msg : "out of memory"), EXIT_BADINPUT;
        int n = 0, ret = EXIT_BADINPUT;
        struct imp_rig_light *L = NULL;
        bool near = false;
        r = imp_lights_lp_read(a->import_lp, a->dome, a->dome[3], &n, &L, NULL, &near, &err);
        if (r < 0)
                log_error("calibrate lights: %s", err.msg);
        else if (!near && !(a->dome[3] > 0))
                log_error("calibrate lights: %s holds directions: give --dome CX,CY,CZ,R to place them", a->import_lp);
        else if (n != rig.n_lights)
                log_error("calibrate lights: %s has %d lights, the rig %d", a->import_lp, n, rig.n_lights);
        else {
                for (int i = 0; i < n; i++)
                        memcpy(rig.lights[i].pos_mm, L[i].pos_mm, sizeof L[i].pos_mm);
                ret = 0;
                if ((r = imp_rig_save(a->out, &rig, &err)) < 0) {
                        log_error_errno(r, "calibrate lights: %s", err.msg);
                        ret = 1;
                } else
                        log_info("%s: %d light positions from %s (%s)", a->out, n, a->import_lp,
                                 near ? "near-field, mm" : "directions on the dome");
        }
        free(L);
        imp_rig_free(&rig);
        return ret;
}

static int lights_main(int argc, char **argv, struct lights_args *a) {
        for (int i = 1; i < argc; i++) {
                const char *o = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                int n;
                if (!strcmp(o, "--help") || !strcmp(o, "-h"))
                        return usage_lights(stdout), 0;
                if (!strcmp(o, "--json")) {
                        a->json = true;
                        continue;
                }
                if (!strcmp(o, "--lp-near-field")) {
                        a->lp_near_field = true;
                        continue;
                }
                if (!strcmp(o, "--no-joint")) {
                        a->no_joint = true;
                        continue;
                }
                if (!strcmp(o, "--hemispheres")) {
                        a->sphere_cut_mm = 0;
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", o);
                        return usage_lights(stderr), EXIT_USAGE;
                }
                i++;
                if (!strcmp(o, "--set")) {
                        if (parse_set(val, a) < 0)
                                return EXIT_USAGE;
                } else if (!strcmp(o, "--rig"))
                        a->rig = val;
                else if (!strcmp(o, "--lp"))
                        a->lp = val;
                else if (!strcmp(o, "--import-lp"))
                        a->import_lp = val;
                else if (!strcmp(o, "--out"))
                        a->out = val;
                else if (!strcmp(o, "--camera"))
                        a->camera = val;
                else if (!strcmp(o, "--spheres")) {
                        if (parse_spheres(val, a) < 0)
                                return EXIT_USAGE;
                } else if (!strcmp(o, "--sphere-radius")) {
                        if (parse_list(o, val, &a->sphere_radius_mm, 1, 1, &n) < 0 || !(a->sphere_radius_mm > 0)) {
                                log_error("--sphere-radius: expected a radius > 0 mm");
                                return EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--sphere-cut")) {
                        if (parse_list(o, val, &a->sphere_cut_mm, 1, 1, &n) < 0)
                                return EXIT_USAGE;
                } else if (!strcmp(o, "--board-sigma")) {
                        if (parse_list(o, val, &a->held_z_sigma_mm, 1, 1, &n) < 0 || !(a->held_z_sigma_mm > 0)) {
                                log_error("--board-sigma: expected a 1σ > 0 mm");
                                return EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--plane-z")) {
                        if (parse_list(o, val, &a->plane_z_mm, 1, 1, &n) < 0)
                                return EXIT_USAGE;
                } else if (!strcmp(o, "--dome")) {
                        if (parse_list(o, val, a->dome, 4, 4, &n) < 0)
                                return EXIT_USAGE;
                        if (!(a->dome[3] > 0)) {
                                log_error("--dome: the radius must be > 0");
                                return EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--white")) {
                        if (parse_list(o, val, a->white, 4, 4, &n) < 0)
                                return EXIT_USAGE;
                        if (!(a->white[2] > a->white[0] && a->white[3] > a->white[1])) {
                                log_error("--white: expected X0 < X1 and Y0 < Y1");
                                return EXIT_USAGE;
                        }
                } else {
                        log_error("unknown option '%s'", o);
                        return usage_lights(stderr), EXIT_USAGE;
                }
        }
        if (a->import_lp) {
                if (!a->out || (!a->rig && !a->n_sets)) {
                        log_error("calibrate lights: --import-lp needs --out and --rig or --set");
                        return usage_lights(stderr), EXIT_USAGE;
                }
                return run_import_lp(a);
        }
        if (!a->n_sets || (!a->n_spheres && !(a->sphere_radius_mm > 0))) {
                log_error("calibrate lights: --set and --sphere-radius (detection) or --spheres are required");
                return usage_lights(stderr), EXIT_USAGE;
        }
        if (a->n_spheres && a->n_sets > 1) {
                log_error("calibrate lights: --spheres gives positions in one set; with several sets use "
                          "--sphere-radius (detection)");
                return EXIT_USAGE;
        }
        return run_lights(a);
}

int imp_calibrate_lights_main(int argc, char **argv) {
        struct lights_args a = { .white = { 0, 0, -1, -1 }, .sphere_cut_mm = NAN };
        int r = lights_main(argc, argv, &a);
        for (int i = 0; i < a.n_sets; i++)
                free((char *) a.sets[i].dir);
        return r;
}

/* ---- radiometric ---- */

#define EXIT_FLAGGED 6                /* done, but the projector's gamma is not determined */
#define GAMMA_BIN_PHASE_RAD 0.07      /* a pixel bin spans at most this much pattern phase … */
#define GAMMA_BIN_MAX 8               /* … and at most this many pixels a side */
#define GAMMA_CONTRAST_FRAC 0.25      /* pixels kept: white − black above this × … */
#define GAMMA_CONTRAST_QUANTILE 0.99  /* … this quantile of white − black over the frame */
#define GAMMA_CONTRAST_MIN_SNR 5.0    /* … which must exceed the noise of white − black this many times
                                         (pure noise: ¼ of its 99th percentile is 0.8 σ) */
#define GAMMA_CLIP_FRAC_MAX 0.001     /* an exposure whose white frame clips more is passed over */
#define GAMMA_BLOCKS 8                /* gamma_sigma: the spread of GAMMA_BLOCKS² block estimates */
#define GAMMA_BLOCK_MIN_PX 16         /* a block needs this many kept bins */
#define GAMMA_MIN_BLOCKS 4            /* fewer usable blocks: σ not measured (few_blocks) */
#define GAMMA_SIGMA_NONE 1e30         /* "infinite", finite in JSON */
#define GAMMA_MAX_STEPS 64            /* the plan's limit on phase steps */
#define GAMMA_MAX_EXPOSURES 64        /* distinct exposures of one phase set considered */

/* The photon transfer of one camera (--set). */
struct ptc_run {
        struct imp_ptc_result res;
        char camera[32];
        int n_levels, n_darks;
        struct imp_rig rig;           /* the set's */
};

/* The projector's gamma (--projector-set). */
struct gamma_run {
        char camera[32];
        double gamma, gamma_sigma, period_px, exposure_us, gain_db, min_contrast_dn;
        /* b of the projector model emitted = b + (1 − b)·value^γ: the median over the kept
         * bins of (black − s)/(white − s), s the sensor's black level (the photon transfer's
         * when --set is given, else the set's rig's) */
        double black_level, sensor_black_dn;
        int status;                   /* imp_radiometric_projector_gamma(): 0, or 1 at the bound */
        int pixels, steps, axis, tile, blocks, clipped_px;
        int bin;                      /* pixels averaged bin × bin before the estimate */
        struct imp_rig rig;           /* the set's */
};

/* The set's frames of one gamma measurement, as record indices (-1: missing). */
struct gamma_frames {
        long white, black, step[GAMMA_MAX_STEPS];
};

static bool same_light(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return !strcmp(a->camera, b->camera) && a->light == b->light && fabs(a->exposure_us - b->exposure_us) <= 1e-9 * a->exposure_us &&
               a->gain_db == b->gain_db && !memcmp(&a->pattern, &b->pattern, sizeof a->pattern) && !strcmp(a->step, b->step);
}

static bool same_exposure(double a, double b) {
        return fabs(a - b) <= 1e-9 * fmax(a, b);
}

static int cmp_level(const void *x, const void *y) {
        const struct imp_ptc_level *a = x, *b = y;
        return (a->exposure_us > b->exposure_us) - (a->exposure_us < b->exposure_us);
}

static int cmp_double_desc(const void *x, const void *y) {
        double a = *(const double *) x, b = *(const double *) y;
        return (a < b) - (a > b);
}

static void free_frames(struct imp_image **v, int n) {
        for (int i = 0; i < n; i++)
                imp_image_free(v[i]);
}

/* Photon transfer from the pairs and darks of `set` into *ret (rig copied: the caller frees
 * ret->rig). Returns an exit code. */
static int measure_ptc(const char *set, const char *camera, const int roi[4], struct ptc_run *ret) {
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
        int nf = 0, nl = 0, nd = 0, ret_code = EXIT_BADINPUT;
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
        if ((r = imp_radiometric_ptc(&in, &ret->res, &err)) < 0) {
                log_error("calibrate radiometric: %s", err.msg);
                goto out;
        }
        if (imp_rig_copy(rig, &ret->rig) < 0) {
                ret_code = 1;
                goto out;
        }
        snprintf(ret->camera, sizeof ret->camera, "%s", cam);
        ret->n_levels = nl;
        ret->n_darks = nd;
        ret_code = 0;
out:
        free_frames(frames, nf);
        return ret_code;
}

/* The phase set to use: the longest period (the least blurred by the projector's and
 * camera's optics), then the most steps, then axis x before y. False when there is none. */
static bool pick_phase(const struct imp_captureset *cs, const char *cam, struct gamma_run *g) {
        bool found = false;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                const struct imp_pattern *p = &rec->pattern;
                if (strcmp(rec->camera, cam) || p->kind != IMP_PAT_PHASE || p->steps > GAMMA_MAX_STEPS)
                        continue;
                if (!found || p->period_px > g->period_px ||
                    (p->period_px == g->period_px && (p->steps > g->steps || (p->steps == g->steps && p->axis < g->axis)))) {
                        g->period_px = p->period_px;
                        g->steps = p->steps;
                        g->axis = p->axis;
                        g->tile = rec->tile;
                        found = true;
                }
        }
        return found;
}

static bool is_chosen_phase(const struct imp_frame_record *rec, const char *cam, const struct gamma_run *g) {
        const struct imp_pattern *p = &rec->pattern;
        return !strcmp(rec->camera, cam) && rec->tile == g->tile && p->kind == IMP_PAT_PHASE &&
               p->period_px == g->period_px && p->steps == g->steps && p->axis == g->axis;
}

/* White, black and every step of the chosen phase set at `exposure_us` (the first of
 * duplicates). Returns the number of frames missing, named in `what`. */
static int find_frames(const struct imp_captureset *cs, const char *cam, const struct gamma_run *g, double exposure_us,
                       struct gamma_frames *f, char *what, size_t len) {
        f->white = f->black = -1;
        for (int k = 0; k < g->steps; k++)
                f->step[k] = -1;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (strcmp(rec->camera, cam) || rec->tile != g->tile || !same_exposure(rec->exposure_us, exposure_us))
                        continue;
                if (rec->pattern.kind == IMP_PAT_WHITE && f->white < 0)
                        f->white = (long) i;
                else if (rec->pattern.kind == IMP_PAT_BLACK && f->black < 0)
                        f->black = (long) i;
                else if (is_chosen_phase(rec, cam, g) && rec->pattern.step >= 0 && rec->pattern.step < g->steps &&
                         f->step[rec->pattern.step] < 0)
                        f->step[rec->pattern.step] = (long) i;
        }
        int missing = 0, steps_missing = 0;
        size_t o = 0;
        what[0] = 0;
        if (f->white < 0)
                missing++, o += (size_t) snprintf(what + o, len - IMP_MIN(o, len), "the white frame, ");
        if (f->black < 0)
                missing++, o += (size_t) snprintf(what + o, len - IMP_MIN(o, len), "the black frame, ");
        for (int k = 0; k < g->steps; k++)
                steps_missing += f->step[k] < 0;
        if (steps_missing)
                o += (size_t) snprintf(what + o, len - IMP_MIN(o, len), "%d of the %d phase steps, ", steps_missing, g->steps);
        if (o >= 2 && o < len)
                what[o - 2] = 0;
        return missing + steps_missing;
}

static double clip_fraction(const struct imp_image *img, double clip_dn) {
        size_t n = 0;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        n += imp_image_get(img, x, y, 0) >= clip_dn;
        return (double) n / ((double) img->width * img->height);
}

/* F32 means of white, black and the steps over bin × bin pixel bins (the last partial row
 * and column dropped). Where any frame reaches the ADC clip code in a bin, its
 * white is set to its black: the bin has no contrast and is left out (a clipped white would
 * misplace every n_k there). Returns the number of such bins, or < 0. */
static int gamma_images(struct imp_image *const *raw, int n, int bin, double clip_dn, struct imp_image **f32) {
        const int w = raw[0]->width / bin, h = raw[0]->height / bin;
        for (int k = 0; k < n; k++)
                if (imp_image_new(w, h, 1, IMP_PIX_F32, &f32[k]) < 0) {
                        free_frames(f32, k);
                        memset(f32, 0, (size_t) k * sizeof *f32);
                        return -ENOMEM;
                }
        int clipped = 0;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        bool clip = false;
                        for (int k = 0; k < n; k++) {
                                double sum = 0;
                                for (int v = 0; v < bin; v++)
                                        for (int u = 0; u < bin; u++) {
                                                double dn = imp_image_get(raw[k], x * bin + u, y * bin + v, 0);
                                                sum += dn;
                                                clip |= dn >= clip_dn;
                                        }
                                *imp_image_f32(f32[k], x, y) = (float) (sum / (bin * bin));
                        }
                        if (clip) {
                                *imp_image_f32(f32[0], x, y) = *imp_image_f32(f32[1], x, y);
                                clipped++;
                        }
                }
        return clipped;
}

/* The bin size for the estimate. Averaging bin × bin pixels before normalising divides the
 * estimator's work by bin² and its one noise bias, through the division by white − black
 * (~σ²/contrast², −0.045 % on the demo target unbinned, −0.009 % in 3 × 3 bins), by about
 * as much. The mean over a bin stands for the pattern at its centre only while the phase varies little
 * across it (a profile averaged over Δφ changes by ~Δφ²/24): the bin is the most pixels
 * spanning GAMMA_BIN_PHASE_RAD at the median phase gradient of the kept pixels, with the
 * phase per pixel from the steps' first Fourier coefficient (N-step phase shifting). */
static int gamma_bin(struct imp_image *const *img, int n, double min_contrast, int *ret_bin) {
        const int w = img[0]->width, h = img[0]->height, steps = n - 2;
        _cleanup_free_ float *phase = malloc((size_t) w * h * sizeof *phase);
        _cleanup_free_ float *grad = malloc((size_t) w * h * sizeof *grad);
        if (!phase || !grad)
                return -ENOMEM;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        double s = 0, c = 0;
                        for (int k = 0; k < steps; k++) {
                                double v = *imp_image_f32(img[2 + k], x, y), a = 2 * M_PI * k / steps;
                                s += v * sin(a);
                                c += v * cos(a);
                        }
                        bool kept = *imp_image_f32(img[0], x, y) - *imp_image_f32(img[1], x, y) > min_contrast;
                        phase[(size_t) y * w + x] = kept ? (float) atan2(-s, c) : NAN;
                }
        size_t ng = 0;
        for (int y = 0; y + 1 < h; y++)
                for (int x = 0; x + 1 < w; x++) {
                        float p = phase[(size_t) y * w + x], px = phase[(size_t) y * w + x + 1],
                              py = phase[(size_t) (y + 1) * w + x];
                        if (isnan(p) || isnan(px) || isnan(py))
                                continue;
                        double dx = remainder(px - p, 2 * M_PI), dy = remainder(py - p, 2 * M_PI);
                        grad[ng++] = (float) hypot(dx, dy);
                }
        if (ng == 0) {
                *ret_bin = 1;
                return 0;
        }
        qsort(grad, ng, sizeof *grad, cmp_float);
        double g = grad[ng / 2];
        int bin = g > 0 ? (int) IMP_CLAMP(floor(GAMMA_BIN_PHASE_RAD / g), 1.0, (double) GAMMA_BIN_MAX) : GAMMA_BIN_MAX;
        *ret_bin = IMP_MAX(IMP_MIN(bin, IMP_MIN(w, h)), 1);
        return 0;
}

/* The contrast threshold: GAMMA_CONTRAST_FRAC of the GAMMA_CONTRAST_QUANTILE of white −
 * black over the frame (robust to a few hot pixels). -ENOENT (*ret and *ret_noise set) when
 * that threshold is within GAMMA_CONTRAST_MIN_SNR of the noise of white − black, estimated
 * as 1.4826·MAD of horizontal neighbours' differences / √2 (which a smooth signal leaves
 * alone): the projector does not light the target (a relative threshold alone would keep
 * the brightest noise). */
static int contrast_threshold(const struct imp_image *white, const struct imp_image *black, double *ret,
                              double *ret_noise) {
        const int w = white->width, h = white->height;
        size_t n = (size_t) w * h, m = 0;
        _cleanup_free_ float *c = malloc(n * sizeof *c), *dd = malloc(n * sizeof *dd);
        if (!c || !dd)
                return -ENOMEM;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        float d = *imp_image_f32(white, x, y) - *imp_image_f32(black, x, y);
                        c[(size_t) y * w + x] = d;
                        if (x > 0)
                                dd[m++] = fabsf(d - c[(size_t) y * w + x - 1]);
                }
        qsort(c, n, sizeof *c, cmp_float);
        *ret = GAMMA_CONTRAST_FRAC * c[(size_t) (GAMMA_CONTRAST_QUANTILE * (double) (n - 1))];
        *ret_noise = 0;
        if (m > 0) {
                qsort(dd, m, sizeof *dd, cmp_float);
                *ret_noise = 1.4826 * dd[m / 2] / M_SQRT2;
        }
        return *ret > GAMMA_CONTRAST_MIN_SNR * *ret_noise ? 0 : -ENOENT;
}

/* The spread of per-block estimates: the frame cut into GAMMA_BLOCKS × GAMMA_BLOCKS blocks,
 * gamma estimated in each with GAMMA_BLOCK_MIN_PX kept bins or more (and its root inside
 * the bounds); σ = sd(blocks) / √blocks. It holds the pixel noise and whatever varies
 * across the frame; a bias common to every pixel does not show in it. */
static int gamma_blocks(struct imp_image *const *img, int n, double min_contrast, double *ret_sigma, int *ret_blocks) {
        double est[GAMMA_BLOCKS * GAMMA_BLOCKS];
        int nb = 0, w = img[0]->width, h = img[0]->height, r = 0;
        struct imp_image *sub[2 + GAMMA_MAX_STEPS] = {};
        for (int by = 0; by < GAMMA_BLOCKS; by++)
                for (int bx = 0; bx < GAMMA_BLOCKS; bx++) {
                        int x0 = bx * w / GAMMA_BLOCKS, x1 = (bx + 1) * w / GAMMA_BLOCKS;
                        int y0 = by * h / GAMMA_BLOCKS, y1 = (by + 1) * h / GAMMA_BLOCKS;
                        if (x1 <= x0 || y1 <= y0)
                                continue;
                        for (int k = 0; k < n; k++) {
                                if ((r = imp_image_new(x1 - x0, y1 - y0, 1, IMP_PIX_F32, &sub[k])) < 0)
                                        goto out;
                                for (int y = y0; y < y1; y++)
                                        memcpy(imp_image_f32(sub[k], 0, y - y0), imp_image_f32(img[k], x0, y),
                                               (size_t) (x1 - x0) * sizeof(float));
                        }
                        double g;
                        int px = 0;
                        if (imp_radiometric_projector_gamma(sub[0], sub[1], (const struct imp_image *const *) &sub[2],
                                                            n - 2, min_contrast, &g, &px) == 0 &&
                            px >= GAMMA_BLOCK_MIN_PX)
                                est[nb++] = g;
                        free_frames(sub, n);
                        memset(sub, 0, sizeof sub);
                }
        double mean = 0, ss = 0;
        for (int i = 0; i < nb; i++)
                mean += est[i] / nb;
        for (int i = 0; i < nb; i++)
                ss += (est[i] - mean) * (est[i] - mean);
        *ret_sigma = nb >= GAMMA_MIN_BLOCKS ? sqrt(ss / (nb - 1) / nb) : GAMMA_SIGMA_NONE;
        *ret_blocks = nb;
out:
        free_frames(sub, n);
        return r;
}

/* The projector's black level b (struct gamma_run) from the kept bins of white and black. */
static int projector_black(const struct imp_image *white, const struct imp_image *black, double min_contrast,
                           double sensor_black_dn, double *ret) {
        size_t n = (size_t) white->width * white->height, m = 0;
        _cleanup_free_ float *r = malloc(n * sizeof *r);
        if (!r)
                return -ENOMEM;
        for (int y = 0; y < white->height; y++)
                for (int x = 0; x < white->width; x++) {
                        double w = *imp_image_f32(white, x, y), b = *imp_image_f32(black, x, y);
                        if (w - b > min_contrast && w - sensor_black_dn > 0)
                                r[m++] = (float) ((b - sensor_black_dn) / (w - sensor_black_dn));
                }
        if (m == 0)
                return -ENOENT;
        qsort(r, m, sizeof *r, cmp_float);
        *ret = IMP_CLAMP((double) r[m / 2], 0.0, 0.999);
        return 0;
}

/* The projector's gamma from the white, black and phase frames of `set` into *ret (rig
 * copied: the caller frees ret->rig); its black level above sensor_black_dn (NAN: the set's
 * rig's camera black level). Returns an exit code. */
static int measure_gamma(const char *set, const char *camera, double sensor_black_dn, struct gamma_run *ret) {
        struct imp_error err = {};
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        if (imp_captureset_open(set, &cs, &err) < 0)
                return log_error("calibrate radiometric: %s", err.msg), EXIT_BADINPUT;
        const struct imp_rig *rig = imp_captureset_rig(cs);
        int ci = camera_index(rig, camera);
        if (ci < 0)
                return log_error("calibrate radiometric: no camera '%s' in %s/rig.json", camera ? camera : "(any)", set),
                       EXIT_BADINPUT;
        if (!rig->has_projector)
                return log_error("calibrate radiometric: %s: the rig has no projector", set), EXIT_BADINPUT;
        const char *cam = rig->cameras[ci].name;
        struct gamma_run g = { .status = 0 };
        if (!pick_phase(cs, cam, &g))
                return log_error("calibrate radiometric: %s: no phase-shift frames of camera %s (the projector's "
                                 "gamma needs white, black and N >= 3 phase steps of one period: the plan's "
                                 "structured_light.phase, e.g. config/plans/projector-gamma.cfg)", set, cam),
                       EXIT_BADINPUT;
        if (g.steps < 3)
                return log_error("calibrate radiometric: %s: %d phase steps of period %g px; the gamma needs 3 or more",
                                 set, g.steps, g.period_px), EXIT_BADINPUT;
        /* exposures holding the chosen phase set, longest first */
        double exps[GAMMA_MAX_EXPOSURES];
        int ne = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (!is_chosen_phase(rec, cam, &g))
                        continue;
                bool seen = false;
                for (int e = 0; e < ne && !seen; e++)
                        seen = same_exposure(exps[e], rec->exposure_us);
                if (!seen && ne < (int) ARRAY_SIZE(exps))
                        exps[ne++] = rec->exposure_us;
        }
        qsort(exps, (size_t) ne, sizeof *exps, cmp_double_desc);
        /* the longest exposure with every frame whose white clips at most GAMMA_CLIP_FRAC_MAX
         * of the pixels (the most signal); else the shortest complete one */
        const double clip_dn = (1 << rig->cameras[ci].sensor.bits) - 1;
        struct gamma_frames f, chosen;
        char what[160], first_what[200] = "";
        bool have = false;
        for (int e = 0; e < ne; e++) {
                if (find_frames(cs, cam, &g, exps[e], &f, what, sizeof what) > 0) {
                        if (!first_what[0])
                                snprintf(first_what, sizeof first_what, "%s at %g us", what, exps[e]);
                        continue;
                }
                chosen = f;
                g.exposure_us = exps[e];
                have = true;
                _cleanup_image_ struct imp_image *wh = NULL;
                if (imp_captureset_load_frame(cs, (size_t) f.white, &wh, &err) < 0)
                        return log_error("calibrate radiometric: %s", err.msg), EXIT_BADINPUT;
                if (clip_fraction(wh, clip_dn) <= GAMMA_CLIP_FRAC_MAX)
                        break;
        }
        const char *axis_name = g.axis ? "y" : "x";
        if (!have)
                return log_error("calibrate radiometric: %s: camera %s: no complete phase set for the projector's gamma "
                                 "(period %g px along %s, %d steps): missing %s", set, cam, g.period_px, axis_name,
                                 g.steps, first_what), EXIT_BADINPUT;
        /* load: white, black, steps */
        const int n = 2 + g.steps;
        struct imp_image *raw[2 + GAMMA_MAX_STEPS] = {}, *img[2 + GAMMA_MAX_STEPS] = {};
        long idx[2 + GAMMA_MAX_STEPS] = { chosen.white, chosen.black };
        memcpy(&idx[2], chosen.step, (size_t) g.steps * sizeof *idx);
        int ret_code = EXIT_BADINPUT, r;
        for (int k = 0; k < n; k++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, (size_t) idx[k]);
                if (imp_captureset_load_frame(cs, (size_t) idx[k], &raw[k], &err) < 0) {
                        log_error("calibrate radiometric: %s", err.msg);
                        goto out;
                }
                if (raw[k]->width != raw[0]->width || raw[k]->height != raw[0]->height ||
                    raw[k]->channels != raw[0]->channels) {
                        log_error("calibrate radiometric: %s: %s is %d x %d x %d, the white frame %d x %d x %d", set,
                                  rec->file, raw[k]->width, raw[k]->height, raw[k]->channels, raw[0]->width,
                                  raw[0]->height, raw[0]->channels);
                        goto out;
                }
                if (k == 0)
                        g.gain_db = rec->gain_db;
                else if (rec->gain_db != g.gain_db) {
                        log_error("calibrate radiometric: %s: %s at gain %g dB, the white frame at %g dB", set,
                                  rec->file, rec->gain_db, g.gain_db);
                        goto out;
                }
        }
        if (raw[0]->channels != 1) {
                log_error("calibrate radiometric: %s: colour frames (%d channels): the gamma is measured on mono "
                          "frames", set, raw[0]->channels);
                goto out;
        }
        /* unbinned, for the phase gradient; then binned (docs/calibration-lights.md) */
        double noise_dn;
        if ((g.clipped_px = gamma_images(raw, n, 1, clip_dn, img)) < 0) {
                ret_code = 1;
                goto out;
        }
        if ((r = contrast_threshold(img[0], img[1], &g.min_contrast_dn, &noise_dn)) == -ENOENT) {
                log_error("calibrate radiometric: %s: white - black reaches %.1f DN (its 99th percentile) against "
                          "a noise of %.1f DN: the projector does not light the target (or the scene renders no "
                          "projector light)", set, g.min_contrast_dn / GAMMA_CONTRAST_FRAC, noise_dn);
                goto out;
        }
        if (r < 0 || gamma_bin(img, n, g.min_contrast_dn, &g.bin) < 0) {
                ret_code = 1;
                goto out;
        }
        if (g.bin > 1) {
                free_frames(img, n);
                memset(img, 0, sizeof img);
                if ((r = gamma_images(raw, n, g.bin, clip_dn, img)) < 0 ||
                    (r = contrast_threshold(img[0], img[1], &g.min_contrast_dn, &noise_dn)) < 0) {
                        ret_code = 1;
                        goto out;
                }
        }
        r = imp_radiometric_projector_gamma(img[0], img[1], (const struct imp_image *const *) &img[2], g.steps,
                                            g.min_contrast_dn, &g.gamma, &g.pixels);
        if (r == -ENOENT) {
                log_error("calibrate radiometric: %s: no pixel with white - black above %.1f DN: the projector does "
                          "not light the target", set, g.min_contrast_dn);
                goto out;
        }
        if (r < 0) {
                log_error_errno(r, "calibrate radiometric: %s: projector gamma: %m", set);
                ret_code = 1;
                goto out;
        }
        g.status = r;
        g.pixels *= g.bin * g.bin;
        g.sensor_black_dn = isnan(sensor_black_dn) ? rig->cameras[ci].sensor.black_level_dn : sensor_black_dn;
        if (projector_black(img[0], img[1], g.min_contrast_dn, g.sensor_black_dn, &g.black_level) < 0) {
                ret_code = 1;
                goto out;
        }
        if (gamma_blocks(img, n, g.min_contrast_dn, &g.gamma_sigma, &g.blocks) < 0) {
                ret_code = 1;
                goto out;
        }
        if (imp_rig_copy(rig, &g.rig) < 0) {
                ret_code = 1;
                goto out;
        }
        snprintf(g.camera, sizeof g.camera, "%s", cam);
        *ret = g;
        ret_code = 0;
out:
        free_frames(raw, n);
        free_frames(img, n);
        return ret_code;
}

static json_t *gamma_to_json(const struct gamma_run *g) {
        json_t *flags = json_array();
        if (g->status)
                json_array_append_new(flags, json_string("at_bound"));
        if (g->blocks < GAMMA_MIN_BLOCKS)
                json_array_append_new(flags, json_string("few_blocks"));
        return json_pack("{s:f, s:f, s:f, s:f, s:i, s:i, s:f, s:s, s:f, s:f, s:i, s:f, s:i, s:i, s:o}", "gamma",
                         g->gamma, "gamma_sigma", g->gamma_sigma, "black_level", g->black_level, "sensor_black_dn",
                         g->sensor_black_dn, "pixels", g->pixels, "steps", g->steps, "period_px",
                         g->period_px, "axis", g->axis ? "y" : "x", "exposure_us", g->exposure_us, "gain_db",
                         g->gain_db, "bin", g->bin, "min_contrast_dn", g->min_contrast_dn, "blocks", g->blocks,
                         "clipped_pixels", g->clipped_px, "flags", flags);
}

static void print_ptc(const struct ptc_run *p) {
        const struct imp_ptc_result *res = &p->res;
        printf("%s (%d levels, %d darks): black %.3f DN, gain %.4f ± %.4f e/DN (0 dB), read noise %.3f e "
               "(dark pair %.3f, intercept %.3f), full well %.0f e, nonlinearity %.3f %%%s%s\n",
               p->camera, p->n_levels, p->n_darks, res->sensor.black_level_dn, res->sensor.gain_e_per_dn,
               res->gain_sigma_e_per_dn, res->sensor.read_noise_e, res->read_noise_dark_e, res->read_noise_fit_e,
               res->sensor.full_well_e, res->max_nonlinearity_pct, res->flags & IMP_PTC_FEW_LEVELS ? ", FEW LEVELS" : "",
               res->flags & IMP_PTC_SATURATION_FOUND ? "" : ", saturation not reached (full well is a lower bound)");
}

static void print_gamma(const struct gamma_run *g) {
        char sigma[64] = "σ not measured";
        if (g->blocks >= GAMMA_MIN_BLOCKS)
                snprintf(sigma, sizeof sigma, "± %.4f", g->gamma_sigma);
        printf("projector %s (camera %s, %d phase steps of period %g px along %s, %g us): gamma %.4f %s "
               "(%d blocks) from %d pixels in %d x %d bins%s; black level %.5f of white\n", g->rig.projector.name,
               g->camera, g->steps, g->period_px, g->axis ? "y" : "x", g->exposure_us, g->gamma, sigma, g->blocks,
               g->pixels, g->bin, g->bin, g->status ? ", AT THE SEARCH BOUND (not determined)" : "", g->black_level);
}

/* Writes the rig: BASE (else the projector set's, else the photon-transfer set's) with the
 * estimates put in. Returns an exit code. */
static int write_rig(const char *out, const char *base, const struct ptc_run *ptc, const struct gamma_run *gm) {
        struct imp_error err = {};
        struct imp_rig copy;
        const char *from = base ? base : "the set's rig";
        if (base) {
                if (imp_rig_load(base, &copy, &err) < 0)
                        return log_error("calibrate radiometric: %s", err.msg), EXIT_BADINPUT;
        } else if (imp_rig_copy(gm ? &gm->rig : &ptc->rig, &copy) < 0)
                return 1;
        int ret = EXIT_BADINPUT;
        if (ptc) {
                int bi = camera_index(&copy, ptc->camera);
                if (bi < 0) {
                        log_error("calibrate radiometric: no camera '%s' in %s", ptc->camera, from);
                        goto out;
                }
                struct imp_sensor *s = &copy.cameras[bi].sensor;
                s->black_level_dn = ptc->res.sensor.black_level_dn;
                s->gain_e_per_dn = ptc->res.sensor.gain_e_per_dn;
                s->read_noise_e = ptc->res.sensor.read_noise_e;
                if (ptc->res.flags & IMP_PTC_SATURATION_FOUND)
                        s->full_well_e = ptc->res.sensor.full_well_e;
        }
        if (gm) {
                if (!copy.has_projector) {
                        log_error("calibrate radiometric: no projector in %s", from);
                        goto out;
                }
                if (gm->status == 0) {
                        copy.projector.gamma = gm->gamma;
                        copy.projector.black_level = gm->black_level;
                } else
                        log_warning("the projector's gamma is not determined: projector.gamma left at %g in %s",
                                    copy.projector.gamma, out);
        }
        int r = imp_rig_save(out, &copy, &err);
        if (r < 0) {
                log_error_errno(r, "calibrate radiometric: %s", err.msg);
                ret = 1;
        } else
                ret = 0;
out:
        imp_rig_free(&copy);
        return ret;
}

static int run_radiometric(const char *set, const char *pset, const char *camera, const int roi[4], bool json,
                           const char *out, const char *base) {
        static struct ptc_run ptc;
        static struct gamma_run gm;
        int ret;
        if (set && (ret = measure_ptc(set, camera, roi, &ptc)) != 0)
                return ret;
        if (pset && (ret = measure_gamma(pset, camera, set ? ptc.res.sensor.black_level_dn : NAN, &gm)) != 0) {
                if (set)
                        imp_rig_free(&ptc.rig);
                return ret;
        }
        if (json) {
                json_t *j = set ? imp_radiometric_ptc_to_json(&ptc.res) : json_object();
                if (pset)
                        json_object_set_new(j, "projector", gamma_to_json(&gm));
                json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
                fputc('\n', stdout);
                json_decref(j);
        } else {
                if (set)
                        print_ptc(&ptc);
                if (pset)
                        print_gamma(&gm);
        }
        if (pset && gm.status)
                log_warning("%s: the projector's gamma lies outside [0.3, 5] (the search's bound %g): not "
                            "determined; check that the set's frames are what their records say", pset, gm.gamma);
        else if (pset && gm.blocks < GAMMA_MIN_BLOCKS)
                log_warning("%s: only %d blocks with enough contrast: gamma_sigma not measured", pset, gm.blocks);
        if (pset && gm.clipped_px > 0)
                log_warning("%s: %d pixels clipped at %g us, left out", pset, gm.clipped_px, gm.exposure_us);
        ret = out ? write_rig(out, base, set ? &ptc : NULL, pset ? &gm : NULL) : 0;
        if (ret == 0 && pset && gm.status)
                ret = EXIT_FLAGGED;
        if (set)
                imp_rig_free(&ptc.rig);
        if (pset)
                imp_rig_free(&gm.rig);
        return ret;
}

int imp_calibrate_radiometric_main(int argc, char **argv) {
        const char *set = NULL, *pset = NULL, *camera = NULL, *out = NULL, *base = NULL;
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
                else if (!strcmp(o, "--projector-set"))
                        pset = val;
                else if (!strcmp(o, "--camera"))
                        camera = val;
                else if (!strcmp(o, "--out"))
                        out = val;
                else if (!strcmp(o, "--rig"))
                        base = val;
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
        if (!set && !pset) {
                log_error("calibrate radiometric: give --set, --projector-set or both");
                return usage_radiometric(stderr), EXIT_USAGE;
        }
        if (base && !out) {
                log_error("calibrate radiometric: --rig is the base of --out: give --out too");
                return usage_radiometric(stderr), EXIT_USAGE;
        }
        return run_radiometric(set, pset, camera, roi, json, out, base);
}
