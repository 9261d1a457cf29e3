/* Simulated photometric stacks and their export (bench-import-sim.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "bench-import-sim.h"
#include "captureset.h"
#include "hdr.h"
#include "json-util.h"
#include "process-photometric.h"
#include "render.h"
#include "scene.h"

#define EXPORT_HEADROOM 0.95          /* the brightest unsaturated value maps to this × 65535:
                                         below the import's 2 % saturation margin */

static int write_truth(struct imp_render *rd, const struct imp_pinhole *m, const char *dir, struct imp_error *err) {
        _cleanup_image_ struct imp_image *n = NULL, *mask = NULL;
        int r;
        if ((r = imp_image_new(m->width, m->height, 4, IMP_PIX_F32, &n)) < 0 ||
            (r = imp_image_new(m->width, m->height, 1, IMP_PIX_U8, &mask)) < 0)
                return imp_error_set(err, r, "truth: cannot allocate");
        for (int y = 0; y < m->height; y++)
                for (int x = 0; x < m->width; x++) {
                        double p[3], w[3], c[3];
                        float *o = imp_image_f32(n, x, y);
                        if (imp_render_view_point(rd, 0, x, y, p, w) < 0) {
                                o[0] = o[1] = o[2] = o[3] = NAN;
                                continue;
                        }
                        for (int j = 0; j < 3; j++)
                                c[j] = m->R[3 * j] * w[0] + m->R[3 * j + 1] * w[1] + m->R[3 * j + 2] * w[2];
                        o[0] = (float) c[0], o[1] = (float) -c[1], o[2] = (float) -c[2];
                        o[3] = (float) p[2];   /* height above the canvas plane, mm */
                        *imp_image_u8(mask, x, y) = 255;
                }
        static const char *const names[] = { "nx", "ny", "nz", "height" };
        char path[4200];
        snprintf(path, sizeof path, "%s/truth-normals.exr", dir);
        if ((r = imp_exr_write(path, n, names, false, err)) < 0)
                return r;
        snprintf(path, sizeof path, "%s/truth-mask.png", dir);
        return imp_png_write(path, mask, err);
}

int sim_dome_capture(const char *scene_path, double exposure_us, const char *dir, struct imp_error *err) {
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        _cleanup_(imp_render_freep) struct imp_render *rd = NULL;
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_scene_load(scene_path, &scene, err);
        if (r < 0 || (r = imp_render_new(scene, &rd, err)) < 0)
                return r;
        const struct imp_rig *rig = imp_render_rig(rd);
        if ((r = imp_captureset_create(dir, rig, NULL, &cs, err)) < 0)
                return r;
        for (int i = 0; i < rig->n_lights; i++) {
                struct imp_frame_record rec = { .seq = i, .light = rig->lights[i].id, .exposure_us = exposure_us };
                snprintf(rec.step, sizeof rec.step, "dome");
                snprintf(rec.camera, sizeof rec.camera, "%s", rig->cameras[0].name);
                _cleanup_image_ struct imp_image *frame = NULL;
                if ((r = imp_render_frame(rd, &rec, &frame, err)) < 0 ||
                    (r = imp_captureset_add_frame(cs, &rec, frame, err)) < 0)
                        return r;
        }
        return write_truth(rd, &rig->cameras[0].model, dir, err);
}

/* The largest unsaturated linear value of the sweep. */
static double sweep_max(const struct imp_po_dome *d) {
        double vmax = 0;
        for (int i = 0; i < d->n; i++)
                for (int y = 0; y < d->height; y++)
                        for (int x = 0; x < d->width; x++)
                                for (int c = 0; c < d->channels; c++)
                                        if (!(imp_image_u8(d->flags[i], x, y)[c] & IMP_HDR_SATURATED))
                                                vmax = fmax(vmax, imp_image_f32(d->value[i], x, y)[c]);
        return vmax;
}

static int write_images(const struct imp_po_dome *d, double scale, const char *out_dir, struct imp_error *err) {
        for (int i = 0; i < d->n; i++) {
                _cleanup_image_ struct imp_image *img = NULL;
                int r = imp_image_new(d->width, d->height, d->channels, IMP_PIX_U16, &img);
                if (r < 0)
                        return imp_error_set(err, r, "export: cannot allocate");
                for (int y = 0; y < d->height; y++)
                        for (int x = 0; x < d->width; x++)
                                for (int c = 0; c < d->channels; c++) {
                                        uint8_t f = imp_image_u8(d->flags[i], x, y)[c];
                                        double v = imp_image_f32(d->value[i], x, y)[c] * scale;
                                        v = f & IMP_HDR_SATURATED ? 65535 : f & IMP_HDR_DARK ? 0 : fmin(65534, fmax(0, v));
                                        imp_image_u16(img, x, y)[c] = (uint16_t) lround(v);
                                }
                char path[4200];
                snprintf(path, sizeof path, "%s/img-%03d.png", out_dir, i);
                if ((r = imp_png_write(path, img, err)) < 0)
                        return r;
        }
        return 0;
}

/* lights.lp (positions relative to the point under the image centre) and intensities.txt
 * (the light's intensity per channel × the 16-bit scale, so that V/E is unchanged). */
static int write_lights(const struct imp_po_dome *d, double scale, const double X0[3], const char *out_dir,
                        struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%s/lights.lp", out_dir);
        _cleanup_fclose_ FILE *lp = fopen(path, "we");
        snprintf(path, sizeof path, "%s/intensities.txt", out_dir);
        _cleanup_fclose_ FILE *it = fopen(path, "we");
        if (!lp || !it)
                return imp_error_set(err, -errno, "%s: cannot write: %s", out_dir, strerror(errno));
        fprintf(lp, "%d\n", d->n);
        for (int i = 0; i < d->n; i++) {
                const struct imp_rig_light *L = &d->lights[i];
                fprintf(lp, "img-%03d.png %.9g %.9g %.9g\n", i, L->pos_mm[0] - X0[0], L->pos_mm[1] - X0[1],
                        L->pos_mm[2] - X0[2]);
                double k = L->intensity * scale / 65535.0;
                fprintf(it, "%.9g %.9g %.9g\n", k * L->colour[0], k * L->colour[1], k * L->colour[2]);
        }
        if (fflush(lp) || fflush(it))
                return imp_error_set(err, -EIO, "%s: write failed", out_dir);
        return 0;
}

int sim_export_stack(const char *capture_dir, const char *out_dir, struct sim_export_info *ret, struct imp_error *err) {
        struct imp_po_dome d = {};
        int r = imp_po_dome_load(capture_dir, &d, err);
        if (r < 0)
                return r;
        double X0[3], C[3];
        const struct imp_pinhole *m = &d.camera.model;
        if ((r = imp_mkdir_p(out_dir, 0755)) < 0)
                imp_error_set(err, r, "%s: cannot create", out_dir);
        else if (!imp_po_pixel_point(m, (m->width - 1) / 2.0, (m->height - 1) / 2.0, X0))
                r = imp_error_set(err, -EINVAL, "%s: the camera does not see z = 0", capture_dir);
        double vmax = sweep_max(&d), scale = vmax > 0 ? EXPORT_HEADROOM * 65535 / vmax : 1;
        if (r >= 0 && (r = write_images(&d, scale, out_dir, err)) >= 0 && (r = write_lights(&d, scale, X0, out_dir, err)) >= 0) {
                imp_pinhole_centre(m, C);
                *ret = (struct sim_export_info) { d.pixel_mm, C[2] - X0[2], d.n, d.width, d.height };
        }
        imp_po_dome_done(&d);
        return r;
}
