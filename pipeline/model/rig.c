/* The rig model: OpenCV pinhole projection with Brown–Conrady distortion, its inverse
 * (pixel → ray) by Newton iteration, poses, and rig.json — the one description of the
 * hardware that the simulator, the calibration and the pipeline share. */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "json-util.h"
#include "numerics.h"
#include "rig.h"

#define RIG_FORMAT "impasto-rig"
#define RIG_VERSION 1
#define UNDISTORT_MAX_ITER 50
/* Normalised-coordinate tolerance: 1e-12 is ~1e-9 px for focal lengths below 1000 px. */
#define UNDISTORT_TOL 1e-12
#define ROTATION_TOL 1e-6

void imp_rig_free(struct imp_rig *rig) {
        if (!rig)
                return;
        free(rig->lights);
        rig->lights = NULL;
        rig->n_lights = 0;
}

int imp_rig_copy(const struct imp_rig *src, struct imp_rig *ret) {
        struct imp_rig r = *src;
        r.lights = NULL;
        if (src->n_lights > 0) {
                r.lights = malloc(sizeof *r.lights * (size_t) src->n_lights);
                if (!r.lights)
                        return -ENOMEM;
                memcpy(r.lights, src->lights, sizeof *r.lights * (size_t) src->n_lights);
        }
        *ret = r;
        return 0;
}

/* ---- projection ---- */

static void distort(const struct imp_pinhole *m, double x, double y, double *xd, double *yd) {
        double r2 = x * x + y * y;
        double radial = 1 + r2 * (m->k1 + r2 * (m->k2 + r2 * m->k3));
        *xd = x * radial + 2 * m->p1 * x * y + m->p2 * (r2 + 2 * x * x);
        *yd = y * radial + m->p1 * (r2 + 2 * y * y) + 2 * m->p2 * x * y;
}

bool imp_pinhole_project(const struct imp_pinhole *m, const double X[3], double ret_px[2]) {
        const double *R = m->R;
        double Xc = R[0] * X[0] + R[1] * X[1] + R[2] * X[2] + m->t[0];
        double Yc = R[3] * X[0] + R[4] * X[1] + R[5] * X[2] + m->t[1];
        double Zc = R[6] * X[0] + R[7] * X[1] + R[8] * X[2] + m->t[2];
        if (!(Zc > 0))
                return false;
        double xd, yd;
        distort(m, Xc / Zc, Yc / Zc, &xd, &yd);
        ret_px[0] = m->fx * xd + m->cx;
        ret_px[1] = m->fy * yd + m->cy;
        return true;
}

/* Solves distort(x, y) = (xd, yd) by Newton's method with the analytic Jacobian, starting
 * from the distorted point itself. Converges quadratically for the moderate distortion of
 * measurement lenses; where the Jacobian is singular (beyond the lens's valid field) it
 * stops and returns the best iterate, which is finite. */
static void undistort(const struct imp_pinhole *m, double xd, double yd, double *ret_x,
                      double *ret_y) {
        double x = xd, y = yd;
        for (int it = 0; it < UNDISTORT_MAX_ITER; it++) {
                double fx_, fy_;
                distort(m, x, y, &fx_, &fy_);
                double ex = fx_ - xd, ey = fy_ - yd;
                if (fabs(ex) < UNDISTORT_TOL && fabs(ey) < UNDISTORT_TOL)
                        break;
                double r2 = x * x + y * y;
                double radial = 1 + r2 * (m->k1 + r2 * (m->k2 + r2 * m->k3));
                double dradial = m->k1 + r2 * (2 * m->k2 + 3 * r2 * m->k3); /* d radial / d r2 */
                double j00 = radial + 2 * x * x * dradial + 2 * m->p1 * y + 6 * m->p2 * x;
                double j01 = 2 * x * y * dradial + 2 * m->p1 * x + 2 * m->p2 * y;
                double j10 = 2 * x * y * dradial + 2 * m->p1 * x + 2 * m->p2 * y;
                double j11 = radial + 2 * y * y * dradial + 6 * m->p1 * y + 2 * m->p2 * x;
                double det = j00 * j11 - j01 * j10;
                if (!(fabs(det) > 1e-12))
                        break;
                double nx = x - (j11 * ex - j01 * ey) / det;
                double ny = y - (-j10 * ex + j00 * ey) / det;
                if (!isfinite(nx) || !isfinite(ny))
                        break;
                x = nx;
                y = ny;
        }
        *ret_x = x;
        *ret_y = y;
}

void imp_pinhole_ray_device(const struct imp_pinhole *m, const double px[2], double ret_dir[3]) {
        double x, y;
        undistort(m, (px[0] - m->cx) / m->fx, (px[1] - m->cy) / m->fy, &x, &y);
        double n = sqrt(x * x + y * y + 1);
        ret_dir[0] = x / n;
        ret_dir[1] = y / n;
        ret_dir[2] = 1 / n;
}

void imp_pinhole_centre(const struct imp_pinhole *m, double ret_C[3]) {
        const double *R = m->R, *t = m->t;
        for (int i = 0; i < 3; i++)
                ret_C[i] = -(R[i] * t[0] + R[3 + i] * t[1] + R[6 + i] * t[2]);
}

void imp_pinhole_ray_world(const struct imp_pinhole *m, const double px[2], double ret_origin[3],
                           double ret_dir[3]) {
        double d[3];
        imp_pinhole_ray_device(m, px, d);
        const double *R = m->R;
        imp_pinhole_centre(m, ret_origin);
        for (int i = 0; i < 3; i++)
                ret_dir[i] = R[i] * d[0] + R[3 + i] * d[1] + R[6 + i] * d[2];
}

/* Unlike imp_normalize3, refuses near-zero vectors (a look-at with the eye on the target). */
static bool normalize3(double v[3]) {
        double n = sqrt(imp_dot3(v, v));
        if (!(n > 1e-12))
                return false;
        for (int i = 0; i < 3; i++)
                v[i] /= n;
        return true;
}

void imp_pinhole_look_at(struct imp_pinhole *m, const double eye[3], const double target[3],
                         const double right[3]) {
        double z[3] = { target[0] - eye[0], target[1] - eye[1], target[2] - eye[2] };
        if (!normalize3(z)) {
                z[0] = 0, z[1] = 0, z[2] = -1;  /* degenerate: look down at the canvas */
        }
        /* x: `right` with its component along the view removed; if `right` is parallel to
         * the view, any perpendicular axis will do. */
        double x[3], d = imp_dot3(right, z);
        for (int i = 0; i < 3; i++)
                x[i] = right[i] - d * z[i];
        if (!normalize3(x)) {
                static const double axes[3][3] = { { 1, 0, 0 }, { 0, 1, 0 }, { 0, 0, 1 } };
                for (int a = 0; a < 3; a++) {
                        double e = imp_dot3(axes[a], z);
                        for (int i = 0; i < 3; i++)
                                x[i] = axes[a][i] - e * z[i];
                        if (normalize3(x))
                                break;
                }
        }
        double y[3];
        imp_cross3(z, x, y);   /* right-handed: x × y = z, so y points down in the image */
        for (int i = 0; i < 3; i++) {
                m->R[i] = x[i];
                m->R[3 + i] = y[i];
                m->R[6 + i] = z[i];
        }
        for (int i = 0; i < 3; i++)
                m->t[i] = -imp_dot3(&m->R[3 * i], eye);
}

/* ---- rig.json ---- */

static json_t *doubles_json(const double *v, int n) {
        json_t *a = json_array();
        for (int i = 0; i < n; i++)
                json_array_append_new(a, json_real(v[i]));
        return a;
}

static json_t *pinhole_json(const struct imp_pinhole *m) {
        return json_pack("{s:i, s:i, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:o, s:o}",
                         "width", m->width, "height", m->height, "fx", m->fx, "fy", m->fy,
                         "cx", m->cx, "cy", m->cy, "k1", m->k1, "k2", m->k2, "p1", m->p1,
                         "p2", m->p2, "k3", m->k3, "R", doubles_json(m->R, 9),
                         "t", doubles_json(m->t, 3));
}

static json_t *sensor_json(const struct imp_sensor *s) {
        return json_pack("{s:i, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:b}", "bits", s->bits,
                         "black_level_dn", s->black_level_dn, "gain_e_per_dn", s->gain_e_per_dn,
                         "read_noise_e", s->read_noise_e, "full_well_e", s->full_well_e,
                         "dark_current_e_per_s", s->dark_current_e_per_s, "prnu", s->prnu,
                         "quantum_scale", s->quantum_scale, "readout_us", s->readout_us,
                         "bayer", (int) s->bayer);
}

json_t *imp_rig_to_json(const struct imp_rig *rig) {
        json_t *cams = json_array(), *lights = json_array();
        for (int i = 0; i < rig->n_cameras; i++) {
                const struct imp_rig_camera *c = &rig->cameras[i];
                json_array_append_new(cams, json_pack("{s:s, s:o, s:o}", "name", c->name,
                                                      "model", pinhole_json(&c->model),
                                                      "sensor", sensor_json(&c->sensor)));
        }
        for (int i = 0; i < rig->n_lights; i++) {
                const struct imp_rig_light *l = &rig->lights[i];
                json_array_append_new(lights,
                                      json_pack("{s:i, s:o, s:f, s:o, s:o, s:f}", "id", l->id,
                                                "pos_mm", doubles_json(l->pos_mm, 3),
                                                "intensity", l->intensity,
                                                "colour", doubles_json(l->colour, 3),
                                                "axis", doubles_json(l->axis, 3),
                                                "profile_exp", l->profile_exp));
        }
        json_t *proj = json_null();
        if (rig->has_projector) {
                const struct imp_rig_projector *p = &rig->projector;
                json_decref(proj);
                proj = json_pack("{s:s, s:o, s:f, s:f, s:f, s:f}", "name", p->name,
                                 "model", pinhole_json(&p->model), "gamma", p->gamma,
                                 "black_level", p->black_level, "intensity", p->intensity,
                                 "defocus_px", p->defocus_px);
        }
        return json_pack("{s:s, s:i, s:o, s:o, s:o, s:f}", "format", RIG_FORMAT,
                         "version", RIG_VERSION, "cameras", cams, "projector", proj,
                         "lights", lights, "settle_us", rig->settle_us);
}

/* Field readers that carry the document and path prefix ("rig.json: cameras[0].model."). */
struct rd {
        const char *prefix;
        struct imp_error *err;
};

static int rd_double(struct rd *d, const json_t *o, const char *key, double min, double max,
                     double *ret) {
        double v = 0;
        int r = imp_json_get_double(o, key, true, &v, d->prefix, d->err);
        if (r < 0)
                return r;
        if (!(v >= min && v <= max))
                return imp_error_set(d->err, -EINVAL, "%s%s: expected a number in [%g, %g], got %.10g",
                                     d->prefix, key, min, max, v);
        *ret = v;
        return 0;
}

static int rd_int(struct rd *d, const json_t *o, const char *key, long long min, long long max,
                  int *ret) {
        long long v = 0;
        int r = imp_json_get_int(o, key, true, &v, d->prefix, d->err);
        if (r < 0)
                return r;
        if (v < min || v > max)
                return imp_error_set(d->err, -EINVAL, "%s%s: expected an integer in [%lld, %lld], got %lld",
                                     d->prefix, key, min, max, v);
        *ret = (int) v;
        return 0;
}

static int rd_name(struct rd *d, const json_t *o, const char *key, char *buf, size_t size) {
        const char *s;
        int r = imp_json_get_string(o, key, true, &s, d->prefix, d->err);
        if (r < 0)
                return r;
        if (strlen(s) >= size)
                return imp_error_set(d->err, -EINVAL, "%s%s: expected at most %zu characters, got %zu",
                                     d->prefix, key, size - 1, strlen(s));
        strcpy(buf, s);
        return 0;
}

static int rd_bool(struct rd *d, const json_t *o, const char *key, bool *ret) {
        json_t *v = json_object_get(o, key);
        if (!v)
                return imp_error_set(d->err, -ENOENT, "%s%s: missing (required)", d->prefix, key);
        if (!json_is_boolean(v))
                return imp_error_set(d->err, -EINVAL, "%s%s: expected true or false", d->prefix, key);
        *ret = json_is_true(v);
        return 0;
}

static int rd_object(struct rd *d, const json_t *o, const char *key, json_t **ret) {
        json_t *v = json_object_get(o, key);
        if (!v)
                return imp_error_set(d->err, -ENOENT, "%s%s: missing (required)", d->prefix, key);
        if (!json_is_object(v))
                return imp_error_set(d->err, -EINVAL, "%s%s: expected an object", d->prefix, key);
        *ret = v;
        return 0;
}

static int pinhole_from(struct rd *d, const json_t *o, struct imp_pinhole *m) {
        int r;
        const double big = 1e9;
        if ((r = rd_int(d, o, "width", 1, 1 << 20, &m->width)) < 0 ||
            (r = rd_int(d, o, "height", 1, 1 << 20, &m->height)) < 0 ||
            (r = rd_double(d, o, "fx", 1e-9, big, &m->fx)) < 0 ||
            (r = rd_double(d, o, "fy", 1e-9, big, &m->fy)) < 0 ||
            (r = rd_double(d, o, "cx", -big, big, &m->cx)) < 0 ||
            (r = rd_double(d, o, "cy", -big, big, &m->cy)) < 0 ||
            (r = rd_double(d, o, "k1", -big, big, &m->k1)) < 0 ||
            (r = rd_double(d, o, "k2", -big, big, &m->k2)) < 0 ||
            (r = rd_double(d, o, "p1", -big, big, &m->p1)) < 0 ||
            (r = rd_double(d, o, "p2", -big, big, &m->p2)) < 0 ||
            (r = rd_double(d, o, "k3", -big, big, &m->k3)) < 0 ||
            (r = imp_json_get_doubles(o, "R", true, 9, m->R, d->prefix, d->err)) < 0 ||
            (r = imp_json_get_doubles(o, "t", true, 3, m->t, d->prefix, d->err)) < 0)
                return r;
        /* A hand-edited or corrupted pose must not pass silently: R Rᵀ = I. */
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        double s = imp_dot3(&m->R[3 * i], &m->R[3 * j]);
                        if (!(fabs(s - (i == j)) < ROTATION_TOL))
                                return imp_error_set(d->err, -EINVAL,
                                                     "%sR: expected a rotation matrix (orthonormal rows)",
                                                     d->prefix);
                }
        return 0;
}

static int sensor_from(struct rd *d, const json_t *o, struct imp_sensor *s) {
        int r;
        if ((r = rd_int(d, o, "bits", 8, 16, &s->bits)) < 0)
                return r;
        if (s->bits % 2)
                return imp_error_set(d->err, -EINVAL, "%sbits: expected 8, 10, 12, 14 or 16, got %d",
                                     d->prefix, s->bits);
        if ((r = rd_double(d, o, "black_level_dn", 0, 65535, &s->black_level_dn)) < 0 ||
            (r = rd_double(d, o, "gain_e_per_dn", 1e-9, 1e9, &s->gain_e_per_dn)) < 0 ||
            (r = rd_double(d, o, "read_noise_e", 0, 1e9, &s->read_noise_e)) < 0 ||
            (r = rd_double(d, o, "full_well_e", 1e-9, 1e12, &s->full_well_e)) < 0 ||
            (r = rd_double(d, o, "dark_current_e_per_s", 0, 1e12, &s->dark_current_e_per_s)) < 0 ||
            (r = rd_double(d, o, "prnu", 0, 1, &s->prnu)) < 0 ||
            (r = rd_double(d, o, "quantum_scale", 0, 1e18, &s->quantum_scale)) < 0 ||
            (r = rd_double(d, o, "readout_us", 0, 1e12, &s->readout_us)) < 0 ||
            (r = rd_bool(d, o, "bayer", &s->bayer)) < 0)
                return r;
        return 0;
}

/* Reads sub-object `key` of `o` with the prefix extended by "KEY.". */
static int with_sub(struct rd *d, const json_t *o, const char *key,
                    int (*fn)(struct rd *, const json_t *, void *), void *out) {
        json_t *sub = NULL;
        int r = rd_object(d, o, key, &sub);
        if (r < 0)
                return r;
        char prefix[512];
        snprintf(prefix, sizeof prefix, "%s%s.", d->prefix, key);
        struct rd sd = { prefix, d->err };
        return fn(&sd, sub, out);
}

static int pinhole_cb(struct rd *d, const json_t *o, void *out) { return pinhole_from(d, o, out); }
static int sensor_cb(struct rd *d, const json_t *o, void *out) { return sensor_from(d, o, out); }

static int camera_from(struct rd *d, const json_t *o, struct imp_rig_camera *c) {
        int r;
        if ((r = rd_name(d, o, "name", c->name, sizeof c->name)) < 0 ||
            (r = with_sub(d, o, "model", pinhole_cb, &c->model)) < 0 ||
            (r = with_sub(d, o, "sensor", sensor_cb, &c->sensor)) < 0)
                return r;
        return 0;
}

static int projector_from(struct rd *d, const json_t *o, struct imp_rig_projector *p) {
        int r;
        if ((r = rd_name(d, o, "name", p->name, sizeof p->name)) < 0 ||
            (r = with_sub(d, o, "model", pinhole_cb, &p->model)) < 0 ||
            (r = rd_double(d, o, "gamma", 0.01, 100, &p->gamma)) < 0 ||
            (r = rd_double(d, o, "black_level", 0, 1, &p->black_level)) < 0 ||
            (r = rd_double(d, o, "intensity", 0, 1e18, &p->intensity)) < 0 ||
            (r = rd_double(d, o, "defocus_px", 0, 1e6, &p->defocus_px)) < 0)
                return r;
        return 0;
}

static int light_from(struct rd *d, const json_t *o, struct imp_rig_light *l) {
        int r;
        if ((r = rd_int(d, o, "id", 0, 1 << 20, &l->id)) < 0 ||
            (r = imp_json_get_doubles(o, "pos_mm", true, 3, l->pos_mm, d->prefix, d->err)) < 0 ||
            (r = rd_double(d, o, "intensity", 0, 1e18, &l->intensity)) < 0 ||
            (r = imp_json_get_doubles(o, "colour", true, 3, l->colour, d->prefix, d->err)) < 0 ||
            (r = imp_json_get_doubles(o, "axis", true, 3, l->axis, d->prefix, d->err)) < 0 ||
            (r = rd_double(d, o, "profile_exp", 0, 1e6, &l->profile_exp)) < 0)
                return r;
        return 0;
}

static int array_member(struct rd *d, const json_t *o, const char *key, size_t max, json_t **ret) {
        json_t *a = json_object_get(o, key);
        if (!a)
                return imp_error_set(d->err, -ENOENT, "%s%s: missing (required)", d->prefix, key);
        if (!json_is_array(a))
                return imp_error_set(d->err, -EINVAL, "%s%s: expected an array", d->prefix, key);
        if (json_array_size(a) > max)
                return imp_error_set(d->err, -EINVAL, "%s%s: expected at most %zu entries, got %zu",
                                     d->prefix, key, max, json_array_size(a));
        *ret = a;
        return 0;
}

/* Element i of array `key` as an object, with the prefix "KEY[i]." in *buf. */
static int element(struct rd *d, const json_t *a, const char *key, size_t i, char *buf,
                   size_t size, json_t **ret) {
        snprintf(buf, size, "%s%s[%zu].", d->prefix, key, i);
        json_t *e = json_array_get(a, i);
        if (!json_is_object(e))
                return imp_error_set(d->err, -EINVAL, "%s%s[%zu]: expected an object", d->prefix,
                                     key, i);
        *ret = e;
        return 0;
}

static int rig_from(struct rd *d, const json_t *j, struct imp_rig *rig) {
        int r;
        const char *format = NULL;
        long long version = RIG_VERSION;
        if ((r = imp_json_get_string(j, "format", false, &format, d->prefix, d->err)) < 0 ||
            (r = imp_json_get_int(j, "version", false, &version, d->prefix, d->err)) < 0)
                return r;
        if (format && strcmp(format, RIG_FORMAT) != 0)
                return imp_error_set(d->err, -EINVAL, "%sformat: expected \"%s\", got \"%s\"",
                                     d->prefix, RIG_FORMAT, format);
        if (version != RIG_VERSION)
                return imp_error_set(d->err, -EPROTONOSUPPORT,
                                     "%sversion: %lld is not supported (this build reads %d)",
                                     d->prefix, version, RIG_VERSION);

        json_t *a = NULL, *e = NULL;
        char prefix[384];   /* d->prefix (< 256) + "cameras[N]." */
        if ((r = array_member(d, j, "cameras", ARRAY_SIZE(rig->cameras), &a)) < 0)
                return r;
        rig->n_cameras = (int) json_array_size(a);
        for (size_t i = 0; i < json_array_size(a); i++) {
                if ((r = element(d, a, "cameras", i, prefix, sizeof prefix, &e)) < 0)
                        return r;
                struct rd sd = { prefix, d->err };
                if ((r = camera_from(&sd, e, &rig->cameras[i])) < 0)
                        return r;
        }

        json_t *p = json_object_get(j, "projector");
        rig->has_projector = p && !json_is_null(p);
        if (rig->has_projector) {
                snprintf(prefix, sizeof prefix, "%sprojector.", d->prefix);
                if (!json_is_object(p))
                        return imp_error_set(d->err, -EINVAL, "%sprojector: expected an object or null",
                                             d->prefix);
                struct rd sd = { prefix, d->err };
                if ((r = projector_from(&sd, p, &rig->projector)) < 0)
                        return r;
        }

        if ((r = array_member(d, j, "lights", 1 << 16, &a)) < 0)
                return r;
        if (json_array_size(a) > 0) {
                rig->lights = calloc(json_array_size(a), sizeof *rig->lights);
                if (!rig->lights)
                        return imp_error_set(d->err, -ENOMEM, "%slights: out of memory", d->prefix);
        }
        rig->n_lights = (int) json_array_size(a);
        for (size_t i = 0; i < json_array_size(a); i++) {
                if ((r = element(d, a, "lights", i, prefix, sizeof prefix, &e)) < 0)
                        return r;
                struct rd sd = { prefix, d->err };
                if ((r = light_from(&sd, e, &rig->lights[i])) < 0)
                        return r;
        }
        return rd_double(d, j, "settle_us", 0, 1e12, &rig->settle_us);
}

int imp_rig_from_json(const json_t *j, const char *what, struct imp_rig *ret,
                      struct imp_error *err) {
        char prefix[256];
        snprintf(prefix, sizeof prefix, "%s: ", what ? what : "rig");
        struct rd d = { prefix, err };
        if (!json_is_object(j))
                return imp_error_set(err, -EINVAL, "%s: expected an object", what ? what : "rig");
        struct imp_rig rig = {};
        int r = rig_from(&d, j, &rig);
        if (r < 0) {
                imp_rig_free(&rig);
                return r;
        }
        *ret = rig;
        return 0;
}

int imp_rig_load(const char *path, struct imp_rig *ret, struct imp_error *err) {
        _cleanup_json_ json_t *j = NULL;
        int r = imp_json_load(path, &j, err);
        if (r < 0)
                return r;
        return imp_rig_from_json(j, path, ret, err);
}

int imp_rig_save(const char *path, const struct imp_rig *rig, struct imp_error *err) {
        _cleanup_json_ json_t *j = imp_rig_to_json(rig);
        if (!j)
                return imp_error_set(err, -ENOMEM, "%s: cannot encode the rig", path);
        return imp_json_save_atomic(path, j, err);
}
