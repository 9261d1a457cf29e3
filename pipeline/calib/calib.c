/* Projector–camera calibration results: JSON, a readable summary and rig.json output.
 * The numbers come from the OpenCV shim (pipeline/calib/cv/cv-calib.h); nothing here fits. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "calib.h"
#include "calib-camera.h"
#include "captureset.h"
#include "json-util.h"
#include "rig.h"

static json_t *doubles(const double *v, int n) {
        json_t *a = json_array();
        for (int i = 0; a && i < n; i++)
                json_array_append_new(a, json_real(isfinite(v[i]) ? v[i] : 0.0));
        return a;
}

static json_t *flags_json(unsigned f) {
        json_t *a = json_array();
        if (f & IMP_CALIB_FOCAL_UNDETERMINED)
                json_array_append_new(a, json_string("focal_undetermined"));
        if (f & IMP_CALIB_PP_UNDETERMINED)
                json_array_append_new(a, json_string("principal_point_undetermined"));
        if (f & IMP_CALIB_FEW_VIEWS)
                json_array_append_new(a, json_string("few_views"));
        if (f & IMP_CALIB_RANK_DEFICIENT)
                json_array_append_new(a, json_string("rank_deficient"));
        return a;
}

json_t *imp_calib_intrinsics_to_json(const struct imp_calib_intrinsics *in) {
        const double *s = in->std;
        json_t *std = json_pack("{s:f, s:f, s:f, s:f, s:o, s:b, s:b}", "fx", s[0], "fy", s[1], "cx", s[2],
                                "cy", s[3], "dist", doubles(s + 4, 5), "k3_fixed", in->k3_fixed, "k2_fixed",
                                in->k2_fixed);
        json_t *cov = doubles(in->cov, IMP_CALIB_N_INTR * IMP_CALIB_N_INTR);
        json_t *unc = json_pack("{s:f, s:f}", "centre_px", in->proj_unc_centre_px,
                                "corner_px", in->proj_unc_corner_px);
        json_t *worst = json_pack("{s:f, s:i, s:i}", "px", in->worst_px, "view", in->worst_view,
                                  "point", in->worst_point);
        return json_pack("{s:i, s:i, s:f, s:f, s:f, s:f, s:o, s:f, s:f, s:o, s:o, s:o, s:o, "
                         "s:i, s:i, s:f, s:o, s:b, s:s, s:i}",
                         "width", in->width, "height", in->height, "fx", in->fx, "fy", in->fy,
                         "cx", in->cx, "cy", in->cy, "dist", doubles(in->dist, 5),
                         "rms_px", in->rms_px, "sigma_px", in->sigma_px, "std", std,
                         "covariance", cov, "projection_uncertainty", unc, "worst_residual", worst,
                         "n_views", in->n_views, "n_points", in->n_points,
                         "max_tilt_deg", in->max_tilt_deg,
                         "flags", flags_json(in->flags),
                         "confident", !(in->flags & (IMP_CALIB_FOCAL_UNDETERMINED |
                                                     IMP_CALIB_PP_UNDETERMINED | IMP_CALIB_FEW_VIEWS |
                                                     IMP_CALIB_RANK_DEFICIENT)),
                         "refinement", in->joint_refined ? "joint" : in->ceres_refined ? "ceres" : "opencv",
                         "outliers", in->n_outliers);
}

/* What the joint refinement did (calib.h, struct imp_calib_joint). */
static json_t *joint_json(const struct imp_calib_procam *r) {
        const struct imp_calib_joint *jt = &r->joint;
        json_t *refined = json_array();
        if (jt->attempted) {
                static const char *const what[] = { "camera intrinsics", "camera distortion",
                                                    "projector intrinsics", "projector distortion",
                                                    "board poses", "camera-projector pose" };
                for (size_t i = 0; i < sizeof what / sizeof what[0]; i++)
                        json_array_append_new(refined, json_string(what[i]));
        }
        json_t *held = json_array();
        if (jt->k3_fixed_camera)
                json_array_append_new(held, json_string("camera k3"));
        if (jt->k3_fixed_projector)
                json_array_append_new(held, json_string("projector k3"));
        if (jt->k2_fixed_camera)
                json_array_append_new(held, json_string("camera k2"));
        if (jt->k2_fixed_projector)
                json_array_append_new(held, json_string("projector k2"));
        json_t *o = json_pack("{s:b, s:b, s:b, s:i, s:{s:f, s:f, s:f}, s:{s:i, s:i}, s:o, s:o}",
                              "attempted", jt->attempted, "used", jt->used, "converged", jt->converged,
                              "iterations", jt->iterations, "rms_px", "camera", jt->rms_camera_px,
                              "projector", jt->rms_projector_px, "both", jt->rms_px, "outliers",
                              "camera", jt->outliers_camera, "projector", jt->outliers_projector,
                              "refined", refined, "held", held);
        if (o && !jt->used && jt->why_not_used[0])
                json_object_set_new(o, "fallback", json_string(jt->why_not_used));
        return o;
}

json_t *imp_calib_procam_to_json(const struct imp_calib_procam *r) {
        const struct imp_calib_stereo *s = &r->stereo;
        json_t *caps = json_array(), *warn = json_array();
        for (int i = 0; i < r->n_captures; i++) {
                const struct imp_calib_capture *c = &r->captures[i];
                json_t *o = json_pack("{s:s, s:b, s:i, s:i, s:i}", "dir", c->dir, "used", c->used,
                                      "corners_camera", c->n_corners_cam,
                                      "corners_projector", c->n_corners_proj,
                                      "decoded_px", c->n_decoded_px);
                if (o && !c->used)
                        json_object_set_new(o, "skipped_because", json_string(c->why));
                json_array_append_new(caps, o);
        }
        for (int i = 0; i < r->n_warnings; i++)
                json_array_append_new(warn, json_string(r->warnings[i]));
        double baseline = sqrt(s->t[0] * s->t[0] + s->t[1] * s->t[1] + s->t[2] * s->t[2]);
        json_t *stereo = json_pack("{s:f, s:o, s:o, s:f, s:f, s:i, s:s}", "rms_px", s->rms_px,
                                   "rotation", doubles(s->R, 9), "translation", doubles(s->t, 3),
                                   "baseline", baseline, "worst_view_rms_px", s->worst_view_rms_px,
                                   "worst_view", s->worst_view,
                                   "convention", "X_projector = R X_camera + t");
        if (stereo && s->have_std)
                json_object_set_new(stereo, "std", json_pack("{s:o, s:o, s:o}", "rotation_deg",
                                                             doubles(s->r_std_deg, 3), "translation",
                                                             doubles(s->t_std, 3), "covariance",
                                                             doubles(s->cov, 36)));
        json_t *j = json_pack("{s:s, s:o, s:o, s:o, s:i, s:i, s:i, s:o, s:o}",
                              "method", "Moreno-Taubin local homographies; OpenCV calibrateCamera, "
                                        "refined by Ceres (robust loss, outliers dropped) when "
                                        "camera/projector.refinement says so; "
                                        "stereoCalibrate(CALIB_FIX_INTRINSIC); then, when joint.used, "
                                        "one Ceres bundle adjustment of both devices, the board "
                                        "poses and the pose (values from it)",
                              "camera", imp_calib_intrinsics_to_json(&r->camera),
                              "projector", imp_calib_intrinsics_to_json(&r->projector),
                              "stereo", stereo, "window_px", 2 * r->window_half_px + 1,
                              "captures_given", r->n_captures, "captures_used", r->n_used,
                              "captures", caps, "warnings", warn);
        if (j)
                json_object_set_new(j, "joint", joint_json(r));
        if (j && r->have_world)
                json_object_set_new(j, "world", json_pack("{s:i, s:o, s:o, s:f, s:s}", "reference_capture",
                                                          r->reference, "rotation", doubles(r->world_R, 9),
                                                          "translation", doubles(r->world_t, 3),
                                                          "rms_px", r->world_rms_px, "convention",
                                                          "X_camera = R X_canvas + t"));
        return j;
}

static void print_device(FILE *f, const char *who, const struct imp_calib_intrinsics *in) {
        fprintf(f, "%s (%dx%d, %d views, %d points):\n", who, in->width, in->height, in->n_views,
                in->n_points);
        fprintf(f, "  fx %10.3f ± %.3f   fy %10.3f ± %.3f px (1σ)\n", in->fx, in->std[0], in->fy,
                in->std[1]);
        fprintf(f, "  cx %10.3f ± %.3f   cy %10.3f ± %.3f px\n", in->cx, in->std[2], in->cy,
                in->std[3]);
        fprintf(f, "  k1 %.5f  k2 %.5f%s  p1 %.6f  p2 %.6f  k3 %.5f%s\n", in->dist[0], in->dist[1],
                in->k2_fixed ? " (held fixed)" : "", in->dist[2], in->dist[3], in->dist[4],
                in->k3_fixed ? " (held fixed)" : "");
        fprintf(f, "  largest board tilt %.1f°\n", in->max_tilt_deg);
        fprintf(f, "  RMS %.4f px, worst %.4f px (view %d, point %d)\n", in->rms_px, in->worst_px,
                in->worst_view, in->worst_point);
        if (in->ceres_refined)
                fprintf(f, "  refined by Ceres (robust loss%s): %d outlier point%s dropped\n",
                        in->joint_refined ? ", jointly with the other device" : "", in->n_outliers,
                        in->n_outliers == 1 ? "" : "s");
        fprintf(f, "  projection uncertainty (1σ%s): %.3f px at the centre, %.3f px at a corner\n",
                in->ceres_refined ? ", mrcal-style" : "", in->proj_unc_centre_px, in->proj_unc_corner_px);
}

void imp_calib_procam_print(const struct imp_calib_procam *r, FILE *f) {
        const struct imp_calib_stereo *s = &r->stereo;
        fprintf(f, "captures: %d of %d used (homography window %d px)\n", r->n_used, r->n_captures,
                2 * r->window_half_px + 1);
        for (int i = 0; i < r->n_captures; i++) {
                const struct imp_calib_capture *c = &r->captures[i];
                if (c->used)
                        fprintf(f, "  %s: %d corners, %d mapped to the projector\n", c->dir,
                                c->n_corners_cam, c->n_corners_proj);
                else
                        fprintf(f, "  %s: skipped\n", c->dir);
        }
        print_device(f, "camera", &r->camera);
        print_device(f, "projector", &r->projector);
        fprintf(f, "stereo (X_projector = R X_camera + t): RMS %.4f px, worst view %d (%.4f px)\n",
                s->rms_px, s->worst_view, s->worst_view_rms_px);
        for (int i = 0; i < 3; i++)
                fprintf(f, "  [% .6f % .6f % .6f]   t %+.3f\n", s->R[3 * i], s->R[3 * i + 1],
                        s->R[3 * i + 2], s->t[i]);
        fprintf(f, "  baseline %.3f (board square units)\n",
                sqrt(s->t[0] * s->t[0] + s->t[1] * s->t[1] + s->t[2] * s->t[2]));
        if (s->have_std)
                fprintf(f, "  1σ: rotation (%.4f %.4f %.4f)°, translation (%.3f %.3f %.3f)\n", s->r_std_deg[0],
                        s->r_std_deg[1], s->r_std_deg[2], s->t_std[0], s->t_std[1], s->t_std[2]);
        if (r->joint.used)
                fprintf(f, "joint refinement (both devices, board poses, pose): %s after %d iterations, "
                        "RMS camera %.4f, projector %.4f px, outliers %d + %d\n",
                        r->joint.converged ? "converged" : "not converged", r->joint.iterations,
                        r->joint.rms_camera_px, r->joint.rms_projector_px, r->joint.outliers_camera,
                        r->joint.outliers_projector);
        else if (r->joint.why_not_used[0])
                fprintf(f, "joint refinement not used: %s\n", r->joint.why_not_used);
        if (r->have_world) {
                const double *R = r->world_R, *t = r->world_t;
                double C[3];
                for (int i = 0; i < 3; i++)
                        C[i] = -(R[i] * t[0] + R[3 + i] * t[1] + R[6 + i] * t[2]);
                fprintf(f, "camera on the canvas (reference capture %d, RMS %.4f px): centre (%.3f, %.3f, %.3f)\n",
                        r->reference, r->world_rms_px, C[0], C[1], C[2]);
        }
        for (int i = 0; i < r->n_warnings; i++)
                fprintf(f, "warning: %s\n", r->warnings[i]);
}

static void pinhole_from(struct imp_pinhole *m, const struct imp_calib_intrinsics *in) {
        m->width = in->width;
        m->height = in->height;
        m->fx = in->fx;
        m->fy = in->fy;
        m->cx = in->cx;
        m->cy = in->cy;
        m->k1 = in->dist[0];
        m->k2 = in->dist[1];
        m->p1 = in->dist[2];
        m->p2 = in->dist[3];
        m->k3 = in->dist[4];
}

/* Declared in calib-camera.h (the camera-only calibration's rig output). */
void imp_calib_intrinsics_to_pinhole(const struct imp_calib_intrinsics *in, struct imp_pinhole *m) {
        pinhole_from(m, in);
}

int imp_calib_procam_save_rig(const struct imp_calib_procam *r, double mm_per_unit, const char *path,
                              struct imp_error *err) {
        if (!r || !path || !(mm_per_unit > 0) || !isfinite(mm_per_unit))
                return imp_error_set(err, -EINVAL, "rig output: bad arguments");
        struct imp_rig rig = { .n_cameras = 1, .has_projector = true };
        struct imp_rig_camera *c = &rig.cameras[0];
        snprintf(c->name, sizeof c->name, "camera0");
        pinhole_from(&c->model, &r->camera);
        c->model.R[0] = c->model.R[4] = c->model.R[8] = 1;   /* world = camera frame */
        /* Sensor values are not calibrated here: neutral placeholders for an 8-bit camera. */
        c->sensor = (struct imp_sensor) { .bits = 8, .gain_e_per_dn = 1, .full_well_e = 255,
                                          .quantum_scale = 1 };
        struct imp_rig_projector *p = &rig.projector;
        snprintf(p->name, sizeof p->name, "projector");
        pinhole_from(&p->model, &r->projector);
        memcpy(p->model.R, r->stereo.R, sizeof p->model.R);
        for (int i = 0; i < 3; i++)
                p->model.t[i] = r->stereo.t[i] * mm_per_unit;
        p->gamma = 1;
        p->intensity = 1;
        return imp_rig_save(path, &rig, err);
}

int imp_calib_procam_rig(const struct imp_calib_procam *r, double mm_per_unit, const struct imp_rig *base,
                         struct imp_rig *ret, struct imp_error *err) {
        if (!r || !base || !ret || !(mm_per_unit > 0) || !isfinite(mm_per_unit) || base->n_cameras < 1 ||
            !base->has_projector)
                return imp_error_set(err, -EINVAL, "rig output: bad arguments (the base rig needs a "
                                     "camera and a projector)");
        struct imp_rig rig;
        int k = imp_rig_copy(base, &rig);
        if (k < 0)
                return imp_error_set(err, k, "rig output: out of memory");
        rig.n_cameras = 1;
        struct imp_pinhole *c = &rig.cameras[0].model, *p = &rig.projector.model;
        pinhole_from(c, &r->camera);
        pinhole_from(p, &r->projector);
        static const double I[9] = { 1, 0, 0, 0, 1, 0, 0, 0, 1 };
        const double *Rc = r->have_world ? r->world_R : I;
        double tc[3] = { 0, 0, 0 };
        for (int i = 0; i < 3 && r->have_world; i++)
                tc[i] = r->world_t[i] * mm_per_unit;
        memcpy(c->R, Rc, sizeof c->R);
        memcpy(c->t, tc, sizeof c->t);
        /* X_proj = Rs (Rc X + tc) + ts */
        const double *Rs = r->stereo.R;
        for (int i = 0; i < 3; i++) {
                for (int j = 0; j < 3; j++) {
                        double s = 0;
                        for (int q = 0; q < 3; q++)
                                s += Rs[3 * i + q] * Rc[3 * q + j];
                        p->R[3 * i + j] = s;
                }
                p->t[i] = Rs[3 * i] * tc[0] + Rs[3 * i + 1] * tc[1] + Rs[3 * i + 2] * tc[2] +
                          r->stereo.t[i] * mm_per_unit;
        }
        *ret = rig;
        return 0;
}

/* ---- capture sets as calibration input ---- */

struct calib_set {
        struct imp_captureset *cs;
        long frame[2 * 2 * 16 + 2];      /* record index per OpenCV frame index */
        double black_dn, scale;          /* u8 = (DN − black_dn) · scale */
};

struct imp_calib_sets {
        int n, n_pat;
        struct calib_set *s;
};

void imp_calib_sets_free(struct imp_calib_sets *s) {
        if (!s)
                return;
        for (int i = 0; i < s->n; i++)
                imp_captureset_close(s->s[i].cs);
        free(s->s);
        free(s);
}

static int ceil_log2(int v) {
        int b = 0;
        while ((1 << b) < v)
                b++;
        return b;
}

/* OpenCV's GrayCodePattern order: columns then rows, bit 0 (most significant) first, each
 * pattern followed by its inverse. */
static int opencv_index(const struct imp_pattern *p, int nbits_x) {
        return (p->axis ? 2 * nbits_x : 0) + 2 * p->bit + (p->inverse ? 1 : 0);
}

static int cmp_u16(const void *a, const void *b) {
        uint16_t x = *(const uint16_t *) a, y = *(const uint16_t *) b;
        return (x > y) - (x < y);
}

static int map_set(struct calib_set *cs, const char *dir, int nbits[2], int n_pat, struct imp_error *err) {
        size_t n = imp_captureset_count(cs->cs);
        const char *cam = NULL;
        double exposure = -1;
        for (int i = 0; i < n_pat + 2; i++)
                cs->frame[i] = -1;
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs->cs, i);
                const struct imp_pattern *p = &rec->pattern;
                int idx;
                if (p->kind == IMP_PAT_WHITE)
                        idx = n_pat;
                else if (p->kind == IMP_PAT_BLACK)
                        idx = n_pat + 1;
                else if (p->kind == IMP_PAT_GRAY && p->nbits == nbits[p->axis] && p->bit >= 0 && p->bit < p->nbits)
                        idx = opencv_index(p, nbits[0]);
                else
                        continue;
                if (!cam) {
                        cam = rec->camera;
                        exposure = rec->exposure_us;
                }
                if (strcmp(rec->camera, cam) || rec->exposure_us != exposure || cs->frame[idx] >= 0)
                        continue;   /* first camera, first exposure, first occurrence */
                cs->frame[idx] = (long) i;
        }
        for (int i = 0; i < n_pat + 2; i++)
                if (cs->frame[i] < 0) {
                        int nb = nbits[0];
                        if (i == n_pat || i == n_pat + 1)
                                return imp_error_set(err, -ENOENT, "capture set %s: no %s frame", dir,
                                                     i == n_pat ? "white" : "black");
                        return imp_error_set(err, -ENOENT, "capture set %s: no Gray-code frame for axis %c "
                                             "bit %d of %d%s (expected Gray code on both axes with "
                                             "inverses, %d + %d bits, e.g. config/plans/target.cfg)", dir,
                                             i < 2 * nb ? 'x' : 'y', (i % (2 * nb)) / 2,
                                             nbits[i < 2 * nb ? 0 : 1], i % 2 ? " (inverse)" : "",
                                             nbits[0], nbits[1]);
                }
        /* Normalisation from the white frame. */
        const struct imp_rig *rig = imp_captureset_rig(cs->cs);
        int ci = 0;
        for (int c = 0; c < rig->n_cameras; c++)
                if (cam && !strcmp(rig->cameras[c].name, cam))
                        ci = c;
        cs->black_dn = rig->n_cameras > 0 ? rig->cameras[ci].sensor.black_level_dn : 0;
        _cleanup_image_ struct imp_image *w = NULL;
        int r = imp_captureset_load_frame(cs->cs, (size_t) cs->frame[n_pat], &w, err);
        if (r < 0)
                return r;
        size_t np = (size_t) w->width * w->height;
        uint16_t *v = malloc(np * sizeof *v);
        if (!v)
                return -ENOMEM;
        for (int y = 0; y < w->height; y++)
                memcpy(v + (size_t) y * w->width, (const uint8_t *) w->data + (size_t) y * w->stride,
                       (size_t) w->width * sizeof *v);
        qsort(v, np, sizeof *v, cmp_u16);
        double p99 = v[(size_t) (0.99 * (double) (np - 1))];
        free(v);
        if (!(p99 > cs->black_dn + 16))
                return imp_error_set(err, -EDOM, "capture set %s: the white frame is dark (99th percentile "
                                     "%.0f DN, black level %.0f DN)", dir, p99, cs->black_dn);
        cs->scale = 200.0 / (p99 - cs->black_dn);   /* headroom: no clipped whites */
        return 0;
}

int imp_calib_sets_open(const char *const *dirs, int n, int proj_w, int proj_h,
                        struct imp_calib_sets **ret, struct imp_error *err) {
        int nbits[2] = { ceil_log2(proj_w), ceil_log2(proj_h) };
        if (n < 1 || proj_w < 2 || proj_h < 2 || nbits[0] > 16 || nbits[1] > 16)
                return imp_error_set(err, -EINVAL, "capture sets: bad arguments");
        struct imp_calib_sets *s = calloc(1, sizeof *s);
        if (!s || !(s->s = calloc((size_t) n, sizeof *s->s))) {
                free(s);
                return -ENOMEM;
        }
        s->n_pat = 2 * (nbits[0] + nbits[1]);
        for (int i = 0; i < n; i++) {
                int r = imp_captureset_open(dirs[i], &s->s[i].cs, err);
                if (r >= 0)
                        r = map_set(&s->s[i], dirs[i], nbits, s->n_pat, err);
                if (r < 0) {
                        s->n = i + 1;
                        imp_calib_sets_free(s);
                        return r;
                }
                s->n = i + 1;
        }
        *ret = s;
        return 0;
}

int imp_calib_sets_load(void *user, int capture, int index, struct imp_image **ret, struct imp_error *err) {
        struct imp_calib_sets *s = user;
        if (!s || capture < 0 || capture >= s->n || index < 0 || index >= s->n_pat + 2)
                return imp_error_set(err, -EINVAL, "capture sets: no frame %d of capture %d", index, capture);
        const struct calib_set *cs = &s->s[capture];
        _cleanup_image_ struct imp_image *raw = NULL;
        int r = imp_captureset_load_frame(cs->cs, (size_t) cs->frame[index], &raw, err);
        if (r < 0)
                return r;
        if (raw->type != IMP_PIX_U16 || raw->channels != 1)
                return imp_error_set(err, -EMEDIUMTYPE, "%s/%s: expected a 1-channel 16-bit frame",
                                     imp_captureset_dir(cs->cs), imp_captureset_record(cs->cs, (size_t) cs->frame[index])->file);
        struct imp_image *out = NULL;
        r = imp_image_new(raw->width, raw->height, 1, IMP_PIX_U8, &out);
        if (r < 0)
                return r;
        for (int y = 0; y < raw->height; y++) {
                const uint16_t *src = (const uint16_t *) ((const uint8_t *) raw->data + (size_t) y * raw->stride);
                uint8_t *dst = (uint8_t *) out->data + (size_t) y * out->stride;
                for (int x = 0; x < raw->width; x++) {
                        double v = (src[x] - cs->black_dn) * cs->scale;
                        dst[x] = (uint8_t) IMP_CLAMP(lround(v), 0, 255);
                }
        }
        *ret = out;
        return 0;
}

const struct imp_rig *imp_calib_sets_rig(const struct imp_calib_sets *s, int i) {
        return s && i >= 0 && i < s->n ? imp_captureset_rig(s->s[i].cs) : NULL;
}
