/* Ground truth of a simulated capture: the sampled painting (heights, normals, canvas
 * mask, per-texel Lafortune parameters), the true calibration and per-camera projector
 * correspondences, in DIR/truth/ (format in render.h and docs/capture-set.md). */
#include <math.h>
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

/* The truth's grid: the surface's samples, or for a tile's window on the painting's lattice
 * (a placed surface) the world grid of the window at the same pitch, whose samples are the
 * surface's points under them (what `impasto compare` reads in the tile's world frame). */
struct truth_grid {
        int nx, ny;
        double pitch_mm, origin_mm[2], canvas_min_mm[2], canvas_max_mm[2];
};

static struct truth_grid grid_of(const struct imp_scene *scene) {
        const struct imp_sim_surface *s = imp_scene_surface(scene);
        struct truth_grid g = { .nx = s->nx, .ny = s->ny, .pitch_mm = s->pitch_mm,
                                .origin_mm = { s->origin_mm[0], s->origin_mm[1] },
                                .canvas_min_mm = { s->canvas_min_mm[0], s->canvas_min_mm[1] },
                                .canvas_max_mm = { s->canvas_max_mm[0], s->canvas_max_mm[1] } };
        if (!s->placed)
                return g;
        double w[4];
        imp_scene_window(scene, w);
        g.nx = (int) ceil((w[2] - w[0]) / s->pitch_mm - 1e-9) + 1;
        g.ny = (int) ceil((w[3] - w[1]) / s->pitch_mm - 1e-9) + 1;
        for (int a = 0; a < 2; a++) {
                g.origin_mm[a] = g.canvas_min_mm[a] = w[a];
                g.canvas_max_mm[a] = w[a] + ((a ? g.ny : g.nx) - 1) * s->pitch_mm;
        }
        return g;
}

static json_t *truth_json(const struct imp_scene *scene) {
        const struct truth_grid g = grid_of(scene), *s = &g;
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

/* One truth texel of a placed surface at world (x, y): height, normal and BRDF bilinear in the
 * four samples around the point (as the renderer shades a hit there), the normal in world. */
static void placed_texel(const struct imp_scene *scene, double x, double y, float h[5], struct imp_lafortune *ret_b) {
        const struct imp_sim_surface *s = imp_scene_surface(scene);
        const float *N = imp_scene_normals(scene);
        double w[2] = { x, y }, l[2];
        imp_sim_surface_to_lattice(s, w, l);
        double fx = IMP_CLAMP((l[0] - s->origin_mm[0]) / s->pitch_mm, 0, s->nx - 1);
        double fy = IMP_CLAMP((l[1] - s->origin_mm[1]) / s->pitch_mm, 0, s->ny - 1);
        int i0 = (int) fx, j0 = (int) fy, i1 = IMP_MIN(i0 + 1, s->nx - 1), j1 = IMP_MIN(j0 + 1, s->ny - 1);
        double ax = fx - i0, ay = fy - j0;
        size_t k[4] = { (size_t) j0 * s->nx + i0, (size_t) j0 * s->nx + i1, (size_t) j1 * s->nx + i0,
                        (size_t) j1 * s->nx + i1 };
        double wt[4] = { (1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay }, n[3] = { 0, 0, 0 }, frame = 0;
        struct imp_lafortune b = { 0 };
        for (int q = 0; q < 4; q++) {
                struct imp_lafortune bq;
                imp_scene_texel_brdf(scene, k[q], &bq);
                for (int c = 0; c < 3; c++) {
                        n[c] += wt[q] * N[3 * k[q] + c];
                        b.rho_d[c] += (float) (wt[q] * bq.rho_d[c]);
                        b.rho_s[c] += (float) (wt[q] * bq.rho_s[c]);
                }
                b.cx += (float) (wt[q] * bq.cx);
                b.cy += (float) (wt[q] * bq.cy);
                b.cz += (float) (wt[q] * bq.cz);
                b.k += (float) (wt[q] * bq.k);
                frame = IMP_MAX(frame, s->is_frame[k[q]] ? wt[q] : 0);
        }
        double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]), nl[2] = { n[0], n[1] }, nw[2];
        imp_sim_surface_dir_to_world(s, nl, nw);
        h[0] = (float) imp_sim_surface_height(s, l[0], l[1]);
        h[1] = (float) (len > 0 ? nw[0] / len : 0);
        h[2] = (float) (len > 0 ? nw[1] / len : 0);
        h[3] = (float) (len > 0 ? n[2] / len : 1);
        h[4] = frame >= 0.5 ? 0.f : 1.f;
        *ret_b = b;
}

static int write_painting(const struct imp_scene *scene, const char *dir, struct imp_error *err) {
        const struct truth_grid g = grid_of(scene), *s = &g;
        const struct imp_sim_surface *sf = imp_scene_surface(scene);
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
                        struct imp_lafortune b;
                        if (sf->placed) {
                                placed_texel(scene, s->origin_mm[0] + x * s->pitch_mm, s->origin_mm[1] + y * s->pitch_mm,
                                             h, &b);
                        } else {
                                h[0] = sf->height_mm[k];
                                h[1] = N[3 * k];
                                h[2] = N[3 * k + 1];
                                h[3] = N[3 * k + 2];
                                h[4] = sf->is_frame[k] ? 0.f : 1.f;
                                imp_scene_texel_brdf(scene, k, &b);
                        }
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
