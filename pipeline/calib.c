/* Projector–camera calibration results: JSON, a readable summary and rig.json output.
 * The numbers come from the OpenCV shim (pipeline/cv/cv-calib.h); nothing here fits. */
#include <errno.h>
#include <math.h>
#include <string.h>
#include "calib.h"
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
        json_t *std = json_pack("{s:f, s:f, s:f, s:f, s:o}", "fx", s[0], "fy", s[1], "cx", s[2],
                                "cy", s[3], "dist", doubles(s + 4, 5));
        json_t *cov = doubles(in->cov, IMP_CALIB_N_INTR * IMP_CALIB_N_INTR);
        json_t *unc = json_pack("{s:f, s:f}", "centre_px", in->proj_unc_centre_px,
                                "corner_px", in->proj_unc_corner_px);
        json_t *worst = json_pack("{s:f, s:i, s:i}", "px", in->worst_px, "view", in->worst_view,
                                  "point", in->worst_point);
        return json_pack("{s:i, s:i, s:f, s:f, s:f, s:f, s:o, s:f, s:f, s:o, s:o, s:o, s:o, "
                         "s:i, s:i, s:f, s:o, s:b}",
                         "width", in->width, "height", in->height, "fx", in->fx, "fy", in->fy,
                         "cx", in->cx, "cy", in->cy, "dist", doubles(in->dist, 5),
                         "rms_px", in->rms_px, "sigma_px", in->sigma_px, "std", std,
                         "covariance", cov, "projection_uncertainty", unc, "worst_residual", worst,
                         "n_views", in->n_views, "n_points", in->n_points,
                         "max_tilt_deg", in->max_tilt_deg,
                         "flags", flags_json(in->flags),
                         "confident", !(in->flags & (IMP_CALIB_FOCAL_UNDETERMINED |
                                                     IMP_CALIB_PP_UNDETERMINED | IMP_CALIB_FEW_VIEWS |
                                                     IMP_CALIB_RANK_DEFICIENT)));
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
        return json_pack("{s:s, s:o, s:o, s:o, s:i, s:i, s:i, s:o, s:o}",
                         "method", "Moreno-Taubin local homographies; OpenCV calibrateCamera, "
                                   "stereoCalibrate(CALIB_FIX_INTRINSIC)",
                         "camera", imp_calib_intrinsics_to_json(&r->camera),
                         "projector", imp_calib_intrinsics_to_json(&r->projector),
                         "stereo", stereo, "window_px", 2 * r->window_half_px + 1,
                         "captures_given", r->n_captures, "captures_used", r->n_used,
                         "captures", caps, "warnings", warn);
}

static void print_device(FILE *f, const char *who, const struct imp_calib_intrinsics *in) {
        fprintf(f, "%s (%dx%d, %d views, %d points):\n", who, in->width, in->height, in->n_views,
                in->n_points);
        fprintf(f, "  fx %10.3f ± %.3f   fy %10.3f ± %.3f px (1σ)\n", in->fx, in->std[0], in->fy,
                in->std[1]);
        fprintf(f, "  cx %10.3f ± %.3f   cy %10.3f ± %.3f px\n", in->cx, in->std[2], in->cy,
                in->std[3]);
        fprintf(f, "  k1 %.5f  k2 %.5f  p1 %.6f  p2 %.6f  k3 %.5f\n", in->dist[0], in->dist[1],
                in->dist[2], in->dist[3], in->dist[4]);
        fprintf(f, "  largest board tilt %.1f°\n", in->max_tilt_deg);
        fprintf(f, "  RMS %.4f px, worst %.4f px (view %d, point %d)\n", in->rms_px, in->worst_px,
                in->worst_view, in->worst_point);
        fprintf(f, "  projection uncertainty (1σ): %.3f px at the centre, %.3f px at a corner\n",
                in->proj_unc_centre_px, in->proj_unc_corner_px);
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
