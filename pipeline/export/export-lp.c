/* The raw dome stack with its light directions for RTI tools (export.h). */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "captureset.h"
#include "export.h"
#include "image.h"
#include "json-util.h"

#define LP_MAX_EXPOSURES 16
#define LP_SATURATED_MAX 0.005        /* fraction of a frame's pixels */

/* Frame records of the first camera's first tile, indexed [light][exposure index]. */
struct stack {
        int n_lights, n_exp;
        long (*rec)[LP_MAX_EXPOSURES];     /* record index or -1 */
        const char *camera;
};

static int find_stack(const struct imp_captureset *cs, struct stack *st, struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        if (rig->n_cameras < 1 || rig->n_lights < 1)
                return imp_error_set(err, -EBADMSG, "%s: the rig has no camera or no dome lights",
                                     imp_captureset_dir(cs));
        st->camera = rig->cameras[0].name;
        st->n_lights = rig->n_lights;
        st->rec = malloc(sizeof *st->rec * (size_t) rig->n_lights);
        if (!st->rec)
                return imp_error_set(err, -ENOMEM, "out of memory");
        memset(st->rec, 0xff, sizeof *st->rec * (size_t) rig->n_lights);
        st->n_exp = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *r = imp_captureset_record(cs, i);
                if (strcmp(r->step, "dome") || strcmp(r->camera, st->camera) || r->tile != 0 || r->light < 0)
                        continue;
                int l = -1;
                for (int k = 0; k < rig->n_lights; k++)
                        if (rig->lights[k].id == r->light)
                                l = k;
                if (l < 0 || r->exposure_index < 0 || r->exposure_index >= LP_MAX_EXPOSURES)
                        continue;
                st->rec[l][r->exposure_index] = (long) i;
                st->n_exp = IMP_MAX(st->n_exp, r->exposure_index + 1);
        }
        for (int l = 0; l < st->n_lights; l++) {
                bool any = false;
                for (int e = 0; e < st->n_exp; e++)
                        any |= st->rec[l][e] >= 0;
                if (!any)
                        return imp_error_set(err, -EBADMSG, "%s: no dome frame of %s for light %d",
                                             imp_captureset_dir(cs), st->camera, rig->lights[l].id);
        }
        return 0;
}

static double saturated_fraction(const struct imp_image *f, int bits) {
        double sat = (double) ((1 << bits) - 1);
        size_t n = 0, total = (size_t) f->width * f->height * f->channels;
        for (int y = 0; y < f->height; y++)
                for (int x = 0; x < f->width; x++)
                        for (int c = 0; c < f->channels; c++)
                                n += imp_image_u16(f, x, y)[c] >= sat;
        return total ? (double) n / (double) total : 0;
}

/* The longest exposure at which every light has a frame and none saturates. */
static int pick_exposure(const struct imp_captureset *cs, const struct stack *st, int bits, struct imp_error *err) {
        for (int e = st->n_exp - 1; e >= 0; e--) {
                bool ok = true;
                for (int l = 0; ok && l < st->n_lights; l++) {
                        if (st->rec[l][e] < 0) {
                                ok = false;
                                break;
                        }
                        _cleanup_image_ struct imp_image *f = NULL;
                        int r = imp_captureset_load_frame(cs, (size_t) st->rec[l][e], &f, err);
                        if (r < 0)
                                return r;
                        ok = saturated_fraction(f, bits) <= LP_SATURATED_MAX;
                }
                if (ok || e == 0)
                        return e;
        }
        return 0;
}

/* The RTI frame: origin O = the canvas point on the camera's optical axis; z the canvas
 * normal (towards the camera), x the image's right projected on the canvas, y = z × x
 * (image up for a camera facing the canvas). Rows of B are world directions. */
static int rti_frame(const struct imp_copy *c, const struct imp_pinhole *cam, double O[3], double B[9],
                     double *ret_dist, struct imp_error *err) {
        const double *M = c->canvas_to_world;
        double P0[3], n[3] = { M[2], M[6], M[10] }, C[3];
        for (int a = 0; a < 3; a++)
                P0[a] = M[4 * a + 2] * c->plane_mm + M[4 * a + 3];
        imp_pinhole_centre(cam, C);
        const double *z = &cam->R[6];  /* optical axis, world */
        double dn = z[0] * n[0] + z[1] * n[1] + z[2] * n[2];
        if (fabs(dn) < 1e-9)
                return imp_error_set(err, -EBADMSG, "the camera looks along the canvas: no RTI frame");
        double t = ((P0[0] - C[0]) * n[0] + (P0[1] - C[1]) * n[1] + (P0[2] - C[2]) * n[2]) / dn;
        double s = dn < 0 ? 1 : -1;   /* the normal towards the camera */
        double x[3], xn = 0, *y = &B[3];
        const double *r = &cam->R[0];
        double rn = r[0] * n[0] + r[1] * n[1] + r[2] * n[2];
        for (int a = 0; a < 3; a++) {
                O[a] = C[a] + t * z[a];
                B[6 + a] = s * n[a];
                x[a] = r[a] - rn * n[a];
                xn += x[a] * x[a];
        }
        xn = sqrt(xn);
        if (!(xn > 1e-9))
                return imp_error_set(err, -EBADMSG, "the image's x axis is along the canvas normal: no RTI frame");
        for (int a = 0; a < 3; a++)
                B[a] = x[a] / xn;
        y[0] = B[7] * B[2] - B[8] * B[1];
        y[1] = B[8] * B[0] - B[6] * B[2];
        y[2] = B[6] * B[1] - B[7] * B[0];
        *ret_dist = fabs(t);
        return 0;
}

/* A linear 16-bit copy of a raw frame: (v − black) stretched to 0..65535. */
static int write_linear(const struct imp_image *f, const struct imp_sensor *s, const char *path,
                        struct imp_error *err) {
        _cleanup_image_ struct imp_image *o = NULL;
        int r = imp_image_new(f->width, f->height, f->channels, IMP_PIX_U16, &o);
        if (r < 0)
                return imp_error_set(err, r, "out of memory");
        double top = (double) ((1 << s->bits) - 1), scale = 65535.0 / fmax(top - s->black_level_dn, 1);
        for (int y = 0; y < f->height; y++)
                for (int x = 0; x < f->width; x++)
                        for (int c = 0; c < f->channels; c++) {
                                double v = (imp_image_u16(f, x, y)[c] - s->black_level_dn) * scale;
                                imp_image_u16(o, x, y)[c] = (uint16_t) lround(IMP_CLAMP(v, 0.0, 65535.0));
                        }
        return imp_png_write(path, o, err);
}

static json_t *xyz(const double v[3]) {
        return json_pack("{s:f, s:f, s:f}", "x", v[0], "y", v[1], "z", v[2]);
}

/* lights.lp and lights.dome from the rig's light positions. */
static int write_lights(const struct imp_rig *rig, const double O[3], const double B[9], double image_width_mm,
                        const char *dir, struct imp_error *err) {
        char path[PATH_MAX];
        snprintf(path, sizeof path, "%s/lights.lp", dir);
        FILE *lp = fopen(path, "we");
        if (!lp)
                return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        fprintf(lp, "%d\n", rig->n_lights);
        json_t *dirs = json_array(), *pos = json_array(), *adj = json_array(), *inten = json_array();
        double mean[3] = { 0, 0, 0 }, radius = 0;
        for (int l = 0; l < rig->n_lights; l++)
                for (int q = 0; q < 3; q++)
                        mean[q] += rig->lights[l].intensity * rig->lights[l].colour[q] / rig->n_lights;
        for (int l = 0; l < rig->n_lights; l++) {
                const struct imp_rig_light *L = &rig->lights[l];
                double d[3] = { L->pos_mm[0] - O[0], L->pos_mm[1] - O[1], L->pos_mm[2] - O[2] }, p[3], u[3];
                for (int a = 0; a < 3; a++)
                        p[a] = B[3 * a] * d[0] + B[3 * a + 1] * d[1] + B[3 * a + 2] * d[2];
                double len = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
                for (int a = 0; a < 3; a++)
                        u[a] = p[a] / len;
                radius += len / rig->n_lights;
                fprintf(lp, "images/light-%03d.png %.9f %.9f %.9f\n", l, u[0], u[1], u[2]);
                json_array_append_new(dirs, xyz(u));
                json_array_append_new(pos, xyz(p));
                double a3[3];
                for (int q = 0; q < 3; q++) {
                        double li = L->intensity * L->colour[q];
                        a3[q] = li > 0 ? mean[q] / li : 1;
                }
                json_array_append_new(adj, json_pack("{s:f, s:f, s:f}", "r", a3[0], "g", a3[1], "b", a3[2]));
                json_array_append_new(inten, json_pack("{s:i, s:f}", "id", L->id, "intensity", L->intensity));
        }
        bool ok = !ferror(lp);
        ok = (fclose(lp) == 0) && ok;
        _cleanup_json_ json_t *dome = json_pack(
                "{s:s, s:s, s:s, s:f, s:f, s:f, s:s, s:o, s:o, s:o, s:o, s:o}", "label", "impasto rig", "notes",
                "positions in mm from the canvas point at the image centre; z the canvas normal, x the image's "
                "right on the canvas, y = z x x; ledAdjust = mean LED intensity / this LED's",
                "units", "mm", "imageWidth", image_width_mm, "domeDiameter", 2 * radius, "verticalOffset", 0.0,
                "lightConfiguration", "lights3d", "directions", dirs, "positions3d", pos,
                "positionsSphere", json_deep_copy(pos), "ledAdjust", adj, "impastoIntensities", inten);
        if (!ok)
                return imp_error_set(err, -EIO, "%s: write failed", path);
        snprintf(path, sizeof path, "%s/lights.dome", dir);
        return dome ? imp_json_save_atomic(path, dome, err) : imp_error_set(err, -ENOMEM, "out of memory");
}

int imp_export_lp(const struct imp_copy *c, const char *capset_dir, const char *dir, int exposure_index,
                  struct imp_lp_summary *ret, struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(capset_dir, &cs, err);
        if (r < 0)
                return r;
        struct stack st = {};
        if ((r = find_stack(cs, &st, err)) < 0) {
                free(st.rec);
                return r;
        }
        const struct imp_rig *rig = imp_captureset_rig(cs);
        const struct imp_rig_camera *cam = &rig->cameras[0];
        int e = exposure_index;
        if (e >= st.n_exp) {
                free(st.rec);
                return imp_error_set(err, -EINVAL, "exposure index %d: the dome stack has %d exposures", e, st.n_exp);
        }
        if (e < 0 && (e = pick_exposure(cs, &st, cam->sensor.bits, err)) < 0) {
                free(st.rec);
                return e;
        }
        double O[3], B[9], dist = 0;
        char path[PATH_MAX];
        snprintf(path, sizeof path, "%s/images", dir);
        if ((r = rti_frame(c, &cam->model, O, B, &dist, err)) < 0) {
                free(st.rec);
                return r;
        }
        if ((r = imp_mkdir_p(path, 0755)) < 0) {
                free(st.rec);
                return imp_error_set(err, r, "%s: %s", path, strerror(-r));
        }
        for (int l = 0; r >= 0 && l < st.n_lights; l++) {
                if (st.rec[l][e] < 0) {
                        r = imp_error_set(err, -EBADMSG, "%s: light %d has no frame at exposure index %d", capset_dir,
                                          rig->lights[l].id, e);
                        break;
                }
                _cleanup_image_ struct imp_image *f = NULL;
                snprintf(path, sizeof path, "%s/images/light-%03d.png", dir, l);
                if ((r = imp_captureset_load_frame(cs, (size_t) st.rec[l][e], &f, err)) >= 0)
                        r = write_linear(f, &cam->sensor, path, err);
        }
        double width_mm = cam->model.width * dist / cam->model.fx;
        if (r >= 0)
                r = write_lights(rig, O, B, width_mm, dir, err);
        if (r >= 0 && ret)
                *ret = (struct imp_lp_summary) { .n_lights = (size_t) st.n_lights, .exposure_index = e,
                                                 .exposure_us = imp_captureset_record(cs, (size_t) st.rec[0][e])->exposure_us,
                                                 .width = cam->model.width, .height = cam->model.height,
                                                 .image_width_mm = width_mm };
        free(st.rec);
        return r;
}
