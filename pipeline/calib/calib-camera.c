/* Camera-only calibration, the C half (calib-camera.h): input images and capture-set frames
 * to 8-bit grey, the result's JSON and summary, and its rig.json. The fit lives in
 * pipeline/calib/cv/cv-calib-camera.cpp. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include "calib-camera.h"
#include "numerics.h"
#include "captureset.h"
#include "rig.h"

static const double LUMA[3] = { 0.2126, 0.7152, 0.0722 };   /* Rec. 709 */
#define P99_SAMPLE_STEP 3                                    /* every 3rd pixel for the percentile */

void imp_calib_camera_warn(struct imp_calib_camera *r, const char *fmt, ...) {
        if (r->n_warnings >= IMP_CALIB_MAX_WARNINGS) {
                snprintf(r->warnings[IMP_CALIB_MAX_WARNINGS - 1], IMP_CALIB_WARNING_LEN,
                         "more warnings were dropped");
                return;
        }
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(r->warnings[r->n_warnings++], IMP_CALIB_WARNING_LEN, fmt, ap);
        va_end(ap);
}

int imp_calib_image_to_u8(const struct imp_image *im, double black, struct imp_image **ret,
                          struct imp_error *err) {
        if (!im || !im->data || im->channels < 1 || im->width < 1 || im->height < 1)
                return imp_error_set(err, -EINVAL, "image to 8 bits: bad image");
        const size_t n = (size_t) im->width * im->height;
        float *lum = malloc(n * sizeof *lum), *sample = malloc((n / P99_SAMPLE_STEP + 1) * sizeof *sample);
        if (!lum || !sample) {
                free(lum);
                free(sample);
                return -ENOMEM;
        }
        const int nc = im->channels >= 3 ? 3 : 1;
        size_t ns = 0;
        for (int y = 0; y < im->height; y++)
                for (int x = 0; x < im->width; x++) {
                        double v = 0;
                        for (int c = 0; c < nc; c++)
                                v += (nc == 3 ? LUMA[c] : 1.0) * imp_image_get(im, x, y, c);
                        size_t i = (size_t) y * im->width + x;
                        lum[i] = isfinite(v) ? (float) v : 0.f;
                        if (i % P99_SAMPLE_STEP == 0)
                                sample[ns++] = lum[i];
                }
        qsort(sample, ns, sizeof *sample, imp_cmp_float);
        double p99 = sample[(size_t) (0.99 * (double) (ns - 1))];
        free(sample);
        if (!(p99 > black) || !((p99 - black) > 1e-6 * fmax(fabs(p99), 1e-30))) {
                free(lum);
                return imp_error_set(err, -EDOM, "the image is dark or flat (99th percentile %g, black "
                                     "level %g)", p99, black);
        }
        struct imp_image *out = NULL;
        int r = imp_image_new(im->width, im->height, 1, IMP_PIX_U8, &out);
        if (r < 0) {
                free(lum);
                return r;
        }
        const double scale = IMP_CALIB_U8_WHITE / (p99 - black);
        for (int y = 0; y < im->height; y++)
                for (int x = 0; x < im->width; x++)
                        *imp_image_u8(out, x, y) = (uint8_t) IMP_CLAMP(
                                lround((lum[(size_t) y * im->width + x] - black) * scale), 0, 255);
        free(lum);
        *ret = out;
        return 0;
}

/* Preference of a frame as the calibration frame: white projector frame 3, dome or flat
 * frame 2, anything else lit 1, dark or black 0. */
static int frame_rank(const struct imp_frame_record *rec) {
        if (rec->pattern.kind == IMP_PAT_WHITE)
                return 3;
        if (!strcmp(rec->step, "dark") || rec->pattern.kind == IMP_PAT_BLACK)
                return 0;
        if (!strcmp(rec->step, "dome") || !strcmp(rec->step, "flat"))
                return 2;
        return 1;
}

int imp_calib_camera_set_frame(const char *dir, const char *camera, struct imp_image **ret,
                               long *ret_record, struct imp_rig *ret_rig, struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(dir, &cs, err);
        if (r < 0)
                return r;
        const struct imp_rig *rig = imp_captureset_rig(cs);
        int ci = camera ? -1 : 0;
        for (int c = 0; camera && c < rig->n_cameras; c++)
                if (!strcmp(rig->cameras[c].name, camera))
                        ci = c;
        if (ci < 0 || rig->n_cameras < 1)
                return imp_error_set(err, -ENOENT, "capture set %s: no camera \"%s\" in its rig.json", dir,
                                     camera ? camera : "(any)");
        long best = -1;
        int best_rank = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                int k = frame_rank(rec);
                if (strcmp(rec->camera, rig->cameras[ci].name) || k <= best_rank)
                        continue;
                best = (long) i;
                best_rank = k;
        }
        if (best < 0)
                return imp_error_set(err, -ENOENT, "capture set %s: no lit frame of camera %s (a white, "
                                     "dome or flat frame; e.g. config/plans/camera-target.cfg)", dir,
                                     rig->cameras[ci].name);
        _cleanup_image_ struct imp_image *raw = NULL;
        r = imp_captureset_load_frame(cs, (size_t) best, &raw, err);
        if (r < 0)
                return r;
        r = imp_calib_image_to_u8(raw, rig->cameras[ci].sensor.black_level_dn, ret, err);
        if (r < 0)
                return imp_error_prefix(err, "capture set %s, %s: ", dir, imp_captureset_record(cs, (size_t) best)->file);
        if (ret_rig && (r = imp_rig_copy(rig, ret_rig)) < 0) {
                imp_image_free(*ret);
                *ret = NULL;
                return imp_error_set(err, r, "capture set %s: out of memory", dir);
        }
        if (ret_record)
                *ret_record = best;
        return 0;
}

json_t *imp_calib_camera_to_json(const struct imp_calib_camera *r) {
        json_t *views = json_array(), *warn = json_array();
        for (int i = 0; i < r->n_views; i++) {
                const struct imp_calib_camera_view *v = &r->views[i];
                json_t *o = json_pack("{s:s, s:b, s:b}", "name", v->name, "found", v->found, "used", v->used);
                if (o && v->found) {
                        json_object_set_new(o, "rms_px", json_real(v->rms_px));
                        json_object_set_new(o, "tilt_deg", json_real(v->tilt_deg));
                        json_object_set_new(o, "rvec", json_pack("[f, f, f]", v->rvec[0], v->rvec[1], v->rvec[2]));
                        json_object_set_new(o, "tvec", json_pack("[f, f, f]", v->tvec[0], v->tvec[1], v->tvec[2]));
                }
                if (o && !v->used)
                        json_object_set_new(o, "skipped_because", json_string(v->why));
                json_array_append_new(views, o);
        }
        for (int i = 0; i < r->n_warnings; i++)
                json_array_append_new(warn, json_string(r->warnings[i]));
        return json_pack("{s:s, s:o, s:i, s:i, s:i, s:i, s:o, s:o}",
                         "method", "OpenCV findChessboardCorners + calibrateCamera, refined by Ceres "
                                   "(robust loss, outliers dropped) when camera.refinement says so",
                         "camera", imp_calib_intrinsics_to_json(&r->camera), "views_given", r->n_views,
                         "views_found", r->n_found, "views_used", r->n_used, "views_rejected", r->n_rejected,
                         "views", views, "warnings", warn);
}

void imp_calib_camera_print(const struct imp_calib_camera *r, FILE *f) {
        const struct imp_calib_intrinsics *in = &r->camera;
        fprintf(f, "views: %d given, board found in %d, %d used, %d rejected as outliers\n", r->n_views,
                r->n_found, r->n_used, r->n_rejected);
        for (int i = 0; i < r->n_views; i++) {
                const struct imp_calib_camera_view *v = &r->views[i];
                if (v->found)
                        fprintf(f, "  %s: RMS %.4f px, tilt %.1f°%s%s\n", v->name, v->rms_px, v->tilt_deg,
                                v->used ? "" : " — not used: ", v->used ? "" : v->why);
                else
                        fprintf(f, "  %s: not used: %s\n", v->name, v->why);
        }
        fprintf(f, "camera (%dx%d, %d views, %d points):\n", in->width, in->height, in->n_views, in->n_points);
        fprintf(f, "  fx %10.3f ± %.3f   fy %10.3f ± %.3f px (1σ)\n", in->fx, in->std[0], in->fy, in->std[1]);
        fprintf(f, "  cx %10.3f ± %.3f   cy %10.3f ± %.3f px\n", in->cx, in->std[2], in->cy, in->std[3]);
        fprintf(f, "  k1 %.5f ± %.5f  k2 %.5f%s ± %.5f  p1 %.6f ± %.6f  p2 %.6f ± %.6f  k3 %.5f%s\n",
                in->dist[0], in->std[4], in->dist[1], in->k2_fixed ? " (held fixed)" : "", in->std[5],
                in->dist[2], in->std[6], in->dist[3], in->std[7], in->dist[4], in->k3_fixed ? " (held fixed)" : "");
        fprintf(f, "  RMS %.4f px, worst %.4f px (view %d, point %d), largest board tilt %.1f°\n", in->rms_px,
                in->worst_px, in->worst_view, in->worst_point, in->max_tilt_deg);
        if (in->ceres_refined)
                fprintf(f, "  refined by Ceres (robust loss): %d outlier point%s dropped\n", in->n_outliers,
                        in->n_outliers == 1 ? "" : "s");
        fprintf(f, "  projection uncertainty (1σ%s): %.3f px at the centre, %.3f px at a corner\n",
                in->ceres_refined ? ", mrcal-style" : "", in->proj_unc_centre_px, in->proj_unc_corner_px);
        for (int i = 0; i < r->n_warnings; i++)
                fprintf(f, "warning: %s\n", r->warnings[i]);
}

int imp_calib_camera_rig(const struct imp_calib_camera *r, const char *name, const struct imp_rig *base,
                         struct imp_rig *ret, struct imp_error *err) {
        if (!r || !ret)
                return imp_error_set(err, -EINVAL, "rig output: bad arguments");
        struct imp_rig rig = { .n_cameras = 1 };
        if (base) {
                int k = imp_rig_copy(base, &rig);
                if (k < 0)
                        return imp_error_set(err, k, "rig output: out of memory");
        } else {
                struct imp_rig_camera *c = &rig.cameras[0];
                snprintf(c->name, sizeof c->name, "%s", name ? name : "camera0");
                c->model.R[0] = c->model.R[4] = c->model.R[8] = 1;   /* world = camera frame */
                /* Not calibrated here: neutral placeholders for an 8-bit camera. */
                c->sensor = (struct imp_sensor) { .bits = 8, .gain_e_per_dn = 1, .full_well_e = 255,
                                                  .quantum_scale = 1 };
        }
        int ci = name ? -1 : 0;
        for (int c = 0; name && c < rig.n_cameras; c++)
                if (!strcmp(rig.cameras[c].name, name))
                        ci = c;
        if (ci < 0 || rig.n_cameras < 1) {
                imp_rig_free(&rig);
                return imp_error_set(err, -ENOENT, "rig output: the rig has no camera \"%s\"", name ? name : "");
        }
        imp_calib_intrinsics_to_pinhole(&r->camera, &rig.cameras[ci].model);
        *ret = rig;
        return 0;
}
