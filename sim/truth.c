/* Ground truth of a simulated capture: the sampled painting (heights, normals, canvas
 * mask, per-texel Lafortune parameters), the true calibration and per-camera projector
 * correspondences, in DIR/truth/ (format in render.h and docs/capture-set.md). */
#include <stdio.h>
#include <string.h>
#include "json-util.h"
#include "render.h"

static int write_exr(const char *dir, const char *name, const struct imp_image *img,
                     const char *const *names, struct imp_error *err) {
        char path[1024];
        if (snprintf(path, sizeof path, "%s/%s", dir, name) >= (int) sizeof path)
                return imp_error_set(err, -ENAMETOOLONG, "%s/%s: path too long", dir, name);
        return imp_exr_write(path, img, names, false, err);
}

static json_t *truth_json(const struct imp_scene *scene) {
        const struct imp_sim_surface *s = imp_scene_surface(scene);
        json_t *fx = json_array();
        for (int i = 0; i < IMP_FX_COUNT; i++)
                if (imp_scene_has_effect(scene, i))
                        json_array_append_new(fx, json_string(imp_sim_effect_name(i)));
        return json_pack("{s:s, s:f, s:[f,f], s:i, s:i, s:[f,f], s:[f,f], s:f, s:I, s:o, s:f, s:f}",
                         "scene", imp_scene_name(scene), "pitch_mm", s->pitch_mm,
                         "origin_mm", s->origin_mm[0], s->origin_mm[1], "nx", s->nx, "ny", s->ny,
                         "canvas_min_mm", s->canvas_min_mm[0], s->canvas_min_mm[1],
                         "canvas_max_mm", s->canvas_max_mm[0], s->canvas_max_mm[1],
                         "frame_height_mm", imp_scene_frame_height_mm(scene),
                         "seed", (json_int_t) imp_scene_seed(scene), "effects", fx,
                         "min_height_mm", imp_scene_min_height_mm(scene),
                         "max_height_mm", imp_scene_max_height_mm(scene));
}

static int write_painting(const struct imp_scene *scene, const char *dir, struct imp_error *err) {
        const struct imp_sim_surface *s = imp_scene_surface(scene);
        const float *N = imp_scene_normals(scene);
        _cleanup_image_ struct imp_image *hf = NULL, *rd = NULL, *rs = NULL, *lobe = NULL;
        int r;
        if ((r = imp_image_new(s->nx, s->ny, 5, IMP_PIX_F32, &hf)) < 0 ||
            (r = imp_image_new(s->nx, s->ny, 3, IMP_PIX_F32, &rd)) < 0 ||
            (r = imp_image_new(s->nx, s->ny, 3, IMP_PIX_F32, &rs)) < 0 ||
            (r = imp_image_new(s->nx, s->ny, 4, IMP_PIX_F32, &lobe)) < 0)
                return imp_error_set(err, r, "truth: cannot allocate %d x %d images", s->nx, s->ny);
        for (int y = 0; y < s->ny; y++)
                for (int x = 0; x < s->nx; x++) {
                        size_t k = (size_t) y * s->nx + x;
                        float *h = imp_image_f32(hf, x, y);
                        h[0] = s->height_mm[k];
                        h[1] = N[3 * k];
                        h[2] = N[3 * k + 1];
                        h[3] = N[3 * k + 2];
                        h[4] = s->is_frame[k] ? 0.f : 1.f;
                        struct imp_lafortune b;
                        imp_scene_texel_brdf(scene, k, &b);
                        float *d = imp_image_f32(rd, x, y), *sp = imp_image_f32(rs, x, y), *l = imp_image_f32(lobe, x, y);
                        for (int c = 0; c < 3; c++) {
                                d[c] = b.rho_d[c];
                                sp[c] = b.rho_s[c];
                        }
                        l[0] = b.cx;
                        l[1] = b.cy;
                        l[2] = b.cz;
                        l[3] = b.k;
                }
        static const char *const hn[] = { "height", "nx", "ny", "nz", "mask" };
        static const char *const rgb[] = { "R", "G", "B" };
        static const char *const ln[] = { "cx", "cy", "cz", "k" };
        if ((r = write_exr(dir, "heightfield.exr", hf, hn, err)) < 0 ||
            (r = write_exr(dir, "rho_d.exr", rd, rgb, err)) < 0 ||
            (r = write_exr(dir, "rho_s.exr", rs, rgb, err)) < 0 ||
            (r = write_exr(dir, "lobe.exr", lobe, ln, err)) < 0)
                return r;
        return 0;
}

int imp_sim_write_truth(const struct imp_scene *scene, struct imp_render *rd, const char *dir,
                        struct imp_error *err) {
        char tdir[1024], path[1100];
        int r = imp_sim_write_painting_truth(scene, dir, err);     /* truth/, truth.json, the painting */
        if (r < 0)
                return r;
        snprintf(tdir, sizeof tdir, "%s/truth", dir);
        const struct imp_rig *rig = imp_render_rig(rd);
        snprintf(path, sizeof path, "%s/rig.json", tdir);
        if ((r = imp_rig_save(path, rig, err)) < 0)
                return r;
        for (int i = 0; rig->has_projector && i < rig->n_cameras; i++) {
                _cleanup_image_ struct imp_image *corr = NULL;
                static const char *const cn[] = { "proj_x", "proj_y", "valid", "depth_mm" };
                if ((r = imp_render_correspondence(rd, i, &corr)) < 0)
                        return imp_error_set(err, r, "camera %s: correspondence: %s", rig->cameras[i].name, strerror(-r));
                char name[64];
                snprintf(name, sizeof name, "correspondence-%s.exr", rig->cameras[i].name);
                if ((r = write_exr(tdir, name, corr, cn, err)) < 0)
                        return r;
        }
        return 0;
}

int imp_sim_write_painting_truth(const struct imp_scene *scene, const char *dir, struct imp_error *err) {
        char tdir[1024], path[1100];
        if (snprintf(tdir, sizeof tdir, "%s/truth", dir) >= (int) sizeof tdir)
                return imp_error_set(err, -ENAMETOOLONG, "%s: path too long", dir);
        int r = imp_mkdir_p(tdir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", tdir, strerror(-r));
        _cleanup_json_ json_t *j = truth_json(scene);
        if (!j)
                return imp_error_set(err, -ENOMEM, "truth.json: out of memory");
        snprintf(path, sizeof path, "%s/truth.json", tdir);
        if ((r = imp_json_save_atomic(path, j, err)) < 0)
                return r;
        return write_painting(scene, tdir, err);
}
