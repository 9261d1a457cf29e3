/* `impasto calibrate lights`: dome light positions, intensities and colours from capture
 * sets of mirror spheres on a white board (one frame per light), written into a copy of
 * the rig and an RTI .lp file. This file parses the options, opens the sets and reports;
 * the numerics are in pipeline/calib/calib-lights*.c (docs/calibration-lights.md). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib-lights.h"
#include "calib-lights-joint.h"
#include "calib-lights-target.h"
#include "calib-radiometric.h"
#include "calibrate-args.h"
#include "calibrate-ext.h"
#include "captureset.h"
#include "exit-codes.h"
#include "log.h"
#include "rig.h"

#define MAX_SPHERES 16
#define MAX_SETS 8
#define MAX_RAYS (MAX_SETS * MAX_SPHERES)
#define DETECT_RADIUS_LO 0.6          /* detection: image radii accepted, × the expected one */
#define DETECT_RADIUS_HI 1.6

struct sphere_spec {
        double x, y, r, z;            /* centre (x, y, z) mm, radius mm */
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
                if (imp_cli_parse_list("--spheres", tok, v, 3, 4, &n) < 0)
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
        struct imp_crop crops[MAX_SPHERES];
        struct imp_sphere sph[MAX_SPHERES];
};

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
        int ci = imp_cli_camera_index(cam_rig, a->camera);
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
        r = imp_lights_mean_dark(cp->cs, cp->cam->name, -1, &cp->dark, &err);
        if (r < 0)
                return log_error("calibrate lights: %s", err.msg), r;
        if (r == 0)
                log_warning("%s: no dark frames, using the black level %.1f DN", spec->dir, cp->cam->sensor.black_level_dn);
        cp->sat = imp_lights_clip_level(&cp->cam->sensor);
        return 0;
}

/* Per-pixel maximum of the dark-subtracted longest-exposure frames of every light: the
 * white board is lit in some frame everywhere (so no cast shadow touches an outline), the
 * mirror bodies stay dark but for their highlights, which lie well inside the rims. */
static int max_image(const struct capture *cp, struct imp_image **ret, struct imp_error *err) {
        const struct imp_pinhole *m = &cp->cam->model;
        struct imp_crop all = { 0, 0, m->width, m->height };
        _cleanup_image_ struct imp_image *mx = NULL;
        int r = 0;
        for (int i = 0; i < cp->n_lf && r >= 0; i++) {
                _cleanup_image_ struct imp_image *f = NULL, *c = NULL;
                r = imp_captureset_load_frame(cp->cs, cp->lf[i].index[0], &f, err);
                if (r >= 0 && (f->width != m->width || f->height != m->height))
                        r = imp_error_set(err, -EINVAL, "%s: frames are %dx%d, the camera model %dx%d", cp->dir, f->width,
                                          f->height, m->width, m->height);
                if (r >= 0)
                        r = imp_lights_crop_dn(f, cp->dark, cp->cam->sensor.black_level_dn, &all, &c);
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
                        cp->crops[s] = imp_lights_crop_sphere(m, (const double[3]) { a->spheres[s].x, a->spheres[s].y, a->spheres[s].z },
                                                      a->spheres[s].r);
                        radius[s] = a->spheres[s].r;
                        cz[s] = a->spheres[s].z;
                        if (cp->crops[s].w < 16 || cp->crops[s].h < 16)
                                return log_error("calibrate lights: sphere %d at (%g, %g) is not in the view of %s", s,
                                                 a->spheres[s].x, a->spheres[s].y, cp->cam->name), -EDOM;
                }
                n = a->n_spheres;
        } else {
                struct imp_sphere_circle circ[MAX_SPHERES];
                double r_mm = a->sphere_radius_mm, cut = a->sphere_cut_mm;
                double rz = cp->plane_z_mm + (isfinite(cut) ? -cut : r_mm);
                double rho = isfinite(cut) ? imp_lights_image_radius(m, sqrt(r_mm * r_mm - cut * cut), cp->plane_z_mm)
                                           : imp_lights_image_radius(m, r_mm, rz);
                struct imp_frame_view v = { mx, 0, 0 };
                int found = imp_lights_sphere_detect(&v, DETECT_RADIUS_LO * rho, DETECT_RADIUS_HI * rho, circ, MAX_SPHERES);
                if (found < 0)
                        return log_error_errno(found, "calibrate lights: %s: sphere detection failed", cp->dir), found;
                if (found > MAX_SPHERES)
                        log_warning("%s: %d spheres found, using the first %d", cp->dir, found, MAX_SPHERES);
                n = IMP_MIN(found, MAX_SPHERES);
                for (int s = 0; s < n; s++) {
                        cp->crops[s] = imp_lights_crop_circle(m, circ[s].centre_px, circ[s].radius_px);
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
                if ((r = imp_lights_crop_image(mx, &cp->crops[s], &c)) < 0)
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
                int q = imp_lights_crop_dn(frames[e], cp->dark, cp->cam->sensor.black_level_dn, &cp->crops[s], &c);
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
        _cleanup_free_ struct imp_joint_mirror *mir = calloc(MAX_SETS * MAX_SPHERES, sizeof *mir);
        int nm = 0, no = 0, r;
        if (!mir)
                return -ENOMEM;
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
                        return IMP_EXIT_BAD_INPUT;
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

/* Rays of every light from every capture, pooled: an exit code. */
static int collect_rays(const struct capture *caps, int n_caps, struct light_result *res) {
        struct imp_error err = {};
        for (int c = 0, m0 = 0; c < n_caps; m0 += caps[c].n_spheres, c++)
                for (int i = 0; i < caps[c].n_lf; i++) {
                        struct light_result *lr = &res[caps[c].lf[i].light];
                        int r = capture_rays(&caps[c], m0, &caps[c].lf[i], lr, &err);
                        if (r < 0)
                                return log_error("calibrate lights: light %d: %s", lr->id, err.msg[0] ? err.msg : strerror(-r)),
                                       IMP_EXIT_FAILURE;
                }
        return 0;
}

/* Per-light triangulation of the pooled rays: an exit code; *ret_n_sat: lights from
 * saturated highlights. */
static int triangulate_lights(struct light_result *res, int n, int *ret_n_sat) {
        int n_sat = 0;
        for (int i = 0; i < n; i++) {
                struct light_result *lr = &res[i];
                if (!lr->n_highlights)
                        continue;
                int r = imp_lights_triangulate(lr->n_highlights, (const double (*)[3]) lr->o, (const double (*)[3]) lr->d,
                                               lr->sg, NULL, &lr->est);
                if (r < 0)
                        return log_error_errno(r, "calibrate lights: light %d: triangulation failed", lr->id),
                               IMP_EXIT_FAILURE;
                lr->have_pos = true;
                if (lr->n_saturated)
                        lr->est.flags |= IMP_LIGHT_SATURATED, n_sat++;
        }
        *ret_n_sat = n_sat;
        return 0;
}

/* Warns about lights whose range is not determined; puts each onto the dome (--dome).
 * Returns the number of ill-conditioned lights. */
static int place_lights(const struct lights_args *a, struct light_result *res, int n) {
        int n_ill = 0;
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
                        imp_lights_onto_dome(a->dome, &lr->est, &lr->dome);
                        lr->have_dome = true;
                }
        }
        return n_ill;
}

/* Intensity and colour of every located light from the first capture's white board: an
 * exit code. */
static int measure_intensities(const struct lights_args *a, const struct capture *c0, const struct imp_rig *rig0,
                               struct light_result *res) {
        struct imp_error err = {};
        const struct imp_lights_board board = { .cam = c0->cam, .dark = c0->dark, .plane_z_mm = c0->plane_z_mm,
                                                .spheres = c0->sph, .n_spheres = c0->n_spheres,
                                                .white = a->white[2] > a->white[0] ? a->white : NULL };
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
                int r = imp_captureset_load_frame(c0->cs, c0->lf[i].index[0], &f, &err);
                if (r >= 0)
                        r = imp_lights_white_values(f, &board, pos, rec->exposure_us, rec->gain_db, &v);
                if (r >= 0)
                        r = imp_lights_intensity_pooled(v, c0->cam, c0->plane_z_mm, nominal, pos, &lr->li);
                if (r == -ENOENT)
                        log_warning("light %d: no white target pixel, intensity not measured, ignoring", lr->id);
                else if (r < 0)
                        return log_error_errno(r, "calibrate lights: light %d: %s", lr->id, err.msg[0] ? err.msg : "intensity"),
                               IMP_EXIT_FAILURE;
                lr->have_intensity = r >= 0;
        }
        return 0;
}

/* Locates the lights from the captures (opened, spheres found) and writes the outputs. */
static int locate_lights(const struct lights_args *a, const struct imp_rig *file_rig, struct capture *caps, int n_caps) {
        const struct imp_rig *rig0 = imp_captureset_rig(caps[0].cs);
        int n = rig0->n_lights, ret, r, n_sat = 0;
        _cleanup_free_ struct light_result *res = calloc((size_t) n + 1, sizeof *res);
        _cleanup_free_ struct joint_out *joint = calloc(1, sizeof *joint);
        if (!res || !joint)
                return IMP_EXIT_FAILURE;
        for (int i = 0; i < n; i++)
                res[i].id = rig0->lights[i].id;
        if ((ret = collect_rays(caps, n_caps, res)) != 0 || (ret = triangulate_lights(res, n, &n_sat)) != 0)
                return ret;
        if (!a->no_joint && (r = joint_refine(a, caps, n_caps, res, n, joint)) < 0)
                return log_error_errno(r, "calibrate lights: joint refinement failed"), IMP_EXIT_FAILURE;
        int n_ill = place_lights(a, res, n);
        if (n_sat)
                log_warning("%d lights used saturated highlights (centroid of the clipped blob, σ ≥ 0.25 px); add a "
                            "shorter exposure to the plan", n_sat);
        if ((ret = measure_intensities(a, &caps[0], rig0, res)) != 0)
                return ret;
        if (n_ill)
                log_warning("%d of %d lights ill-conditioned", n_ill, n);
        report_lights(a, caps, n_caps, res, n, joint);
        return write_outputs(a, file_rig ? file_rig : rig0, rig0, &caps[0], res);
}

static int run_lights(const struct lights_args *a) {
        struct imp_error err = {};
        struct imp_rig file_rig = {};
        if (a->rig && imp_rig_load(a->rig, &file_rig, &err) < 0)
                return log_error("calibrate lights: %s", err.msg), IMP_EXIT_BAD_INPUT;
        int ret = IMP_EXIT_BAD_INPUT, n_caps = 0;
        const struct imp_rig *rig0 = NULL;
        struct capture *caps = calloc(MAX_SETS, sizeof *caps);
        if (!caps) {
                ret = IMP_EXIT_FAILURE;
                goto out;
        }
        for (int c = 0; c < a->n_sets; c++, n_caps++)
                if (capture_open(&caps[c], &a->sets[c], a, a->rig ? &file_rig : NULL, rig0) < 0 ||
                    capture_spheres(&caps[c], a) < 0)
                        goto out;
                else if (!rig0)
                        rig0 = imp_captureset_rig(caps[0].cs);
        ret = locate_lights(a, a->rig ? &file_rig : NULL, caps, n_caps);
out:
        for (int c = 0; caps && c < n_caps + (n_caps < a->n_sets); c++)
                capture_free(&caps[c]);
        free(caps);
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
                return log_error("calibrate lights: %s", err.msg[0] ? err.msg : "out of memory"), IMP_EXIT_BAD_INPUT;
        int n = 0, ret = IMP_EXIT_BAD_INPUT;
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
                        return usage_lights(stderr), IMP_EXIT_USAGE;
                }
                i++;
                if (!strcmp(o, "--set")) {
                        if (parse_set(val, a) < 0)
                                return IMP_EXIT_USAGE;
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
                                return IMP_EXIT_USAGE;
                } else if (!strcmp(o, "--sphere-radius")) {
                        if (imp_cli_parse_list(o, val, &a->sphere_radius_mm, 1, 1, &n) < 0 || !(a->sphere_radius_mm > 0)) {
                                log_error("--sphere-radius: expected a radius > 0 mm");
                                return IMP_EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--sphere-cut")) {
                        if (imp_cli_parse_list(o, val, &a->sphere_cut_mm, 1, 1, &n) < 0)
                                return IMP_EXIT_USAGE;
                } else if (!strcmp(o, "--board-sigma")) {
                        if (imp_cli_parse_list(o, val, &a->held_z_sigma_mm, 1, 1, &n) < 0 || !(a->held_z_sigma_mm > 0)) {
                                log_error("--board-sigma: expected a 1σ > 0 mm");
                                return IMP_EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--plane-z")) {
                        if (imp_cli_parse_list(o, val, &a->plane_z_mm, 1, 1, &n) < 0)
                                return IMP_EXIT_USAGE;
                } else if (!strcmp(o, "--dome")) {
                        if (imp_cli_parse_list(o, val, a->dome, 4, 4, &n) < 0)
                                return IMP_EXIT_USAGE;
                        if (!(a->dome[3] > 0)) {
                                log_error("--dome: the radius must be > 0");
                                return IMP_EXIT_USAGE;
                        }
                } else if (!strcmp(o, "--white")) {
                        if (imp_cli_parse_list(o, val, a->white, 4, 4, &n) < 0)
                                return IMP_EXIT_USAGE;
                        if (!(a->white[2] > a->white[0] && a->white[3] > a->white[1])) {
                                log_error("--white: expected X0 < X1 and Y0 < Y1");
                                return IMP_EXIT_USAGE;
                        }
                } else {
                        log_error("unknown option '%s'", o);
                        return usage_lights(stderr), IMP_EXIT_USAGE;
                }
        }
        if (a->import_lp) {
                if (!a->out || (!a->rig && !a->n_sets)) {
                        log_error("calibrate lights: --import-lp needs --out and --rig or --set");
                        return usage_lights(stderr), IMP_EXIT_USAGE;
                }
                return run_import_lp(a);
        }
        if (!a->n_sets || (!a->n_spheres && !(a->sphere_radius_mm > 0))) {
                log_error("calibrate lights: --set and --sphere-radius (detection) or --spheres are required");
                return usage_lights(stderr), IMP_EXIT_USAGE;
        }
        if (a->n_spheres && a->n_sets > 1) {
                log_error("calibrate lights: --spheres gives positions in one set; with several sets use "
                          "--sphere-radius (detection)");
                return IMP_EXIT_USAGE;
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

