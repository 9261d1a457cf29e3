/* A synthetic painting cut into tile copies with known stage errors (mosaic.h): for the
 * tests and the bench, before the simulator's gantry exists. The relief is analytic, so
 * truth is exact anywhere and a painting of any size costs no memory. */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "image.h"
#include "json-util.h"
#include "macro.h"
#include "mosaic-blend.h"
#include "tiles.h"

void imp_mosaic_synth_default(struct imp_mosaic_synth *s) {
        *s = (struct imp_mosaic_synth) { .extent_mm = { 40, 26 }, .fov_mm = { 12, 8 }, .overlap = 0.2, .pitch_mm = 0.05,
                                         .sigma_mm = 0.05, .sigma_deg = 0.05, .noise_um = 1, .seed = 1, .brdf = true };
}

static uint64_t mix(uint64_t x) {
        x += 0x9e3779b97f4a7c15ull;
        x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
        x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
        return x ^ (x >> 31);
}

static double unit(uint64_t h) {
        return (h >> 11) * (1.0 / 9007199254740992.0);
}

/* Paint strokes: one elongated bump per 2 mm cell at a hashed place, height, size and
 * direction, plus a fine canvas weave. */
double imp_mosaic_synth_height(const struct imp_mosaic_synth *s, double x, double y) {
        const double cell = 2.0;
        long ci = (long) floor(x / cell), cj = (long) floor(y / cell);
        double h = 0.01 * sin(2 * M_PI * x / 0.7) * sin(2 * M_PI * y / 0.9);
        for (long j = cj - 2; j <= cj + 2; j++)
                for (long i = ci - 2; i <= ci + 2; i++) {
                        uint64_t k = mix(((uint64_t) (i + 100000) << 32) ^ (uint64_t) (j + 100000) ^ ((uint64_t) s->seed << 58));
                        double px = (i + unit(k)) * cell, py = (j + unit(mix(k + 1))) * cell;
                        double a = 0.05 + 0.25 * unit(mix(k + 2)), r = 0.5 + 1.0 * unit(mix(k + 3));
                        double ang = M_PI * unit(mix(k + 4)), c = cos(ang), sn = sin(ang);
                        double dx = x - px, dy = y - py, u = (c * dx + sn * dy) / (2 * r), v = (-sn * dx + c * dy) / r;
                        double d2 = u * u + v * v;
                        if (d2 < 9)
                                h += a * exp(-d2);
                }
        return h;
}

static void synth_albedo(const struct imp_mosaic_synth *s, double x, double y, float rgb[3]) {
        uint64_t k = mix(((uint64_t) (long) floor(x / 3 + 1e5) << 32) ^ (uint64_t) (long) floor(y / 3 + 1e5) ^ s->seed);
        for (int c = 0; c < 3; c++)
                rgb[c] = (float) (0.2 + 0.6 * unit(mix(k + c)) + 0.05 * sin(x * (c + 1)));
}

static double gauss(uint64_t *st) {
        *st = mix(*st);
        double u1 = fmax(unit(*st), 1e-300);
        *st = mix(*st);
        return sqrt(-2 * log(u1)) * cos(2 * M_PI * unit(*st));
}

/* The relief's gradient in the tile's frame at tile point (wx, wy) (central differences of
 * one texel, as the grid's). */
static void scaled_gradient(const struct imp_mosaic_synth *s, const double pose[4], double wx, double wy, double *gx,
                            double *gy) {
        double c = cos(pose[2]), sn = sin(pose[2]), h[4], d = s->pitch_mm;
        for (int k = 0; k < 4; k++) {
                double x = wx + (k == 0 ? d : k == 1 ? -d : 0), y = wy + (k == 2 ? d : k == 3 ? -d : 0);
                h[k] = (float) imp_mosaic_synth_height(s, pose[0] + c * x - sn * y, pose[1] + sn * x + c * y);
        }
        *gx = (h[0] - h[1]) / (2 * d), *gy = (h[2] - h[3]) / (2 * d);
}

/* One tile's copy: pose (x, y, θ, dz) true; texel (i, j) of a grid centred on the field. */
static int write_tile(const struct imp_mosaic_synth *s, const double pose[4], const char *dir, uint64_t *rng,
                      struct imp_error *err) {
        struct mosaic_out o = { 0 };
        struct mosaic_grid g = { .pitch_mm = s->pitch_mm };
        int nx = (int) lround(s->fov_mm[0] / s->pitch_mm), ny = (int) lround(s->fov_mm[1] / s->pitch_mm);
        if (mosaic_out_alloc(&o, nx, ny) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        o.origin_mm[0] = -0.5 * (nx - 1) * s->pitch_mm, o.origin_mm[1] = -0.5 * (ny - 1) * s->pitch_mm;
        double c = cos(pose[2]), sn = sin(pose[2]);
        int gx_n = nx + 2;
        float *hg = malloc((size_t) (nx + 2) * (ny + 2) * sizeof *hg);   /* true heights with a 1-texel border */
        if (!hg) {
                mosaic_out_done(&o);
                return imp_error_set(err, -ENOMEM, "out of memory");
        }
        for (int j = -1; j <= ny; j++)
                for (int i = -1; i <= nx; i++) {
                        double wx = o.origin_mm[0] + i * s->pitch_mm, wy = o.origin_mm[1] + j * s->pitch_mm;
                        hg[(size_t) (j + 1) * gx_n + i + 1] = (float) imp_mosaic_synth_height(s, pose[0] + c * wx - sn * wy,
                                                                                             pose[1] + sn * wx + c * wy);
                }
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t k = (size_t) j * nx + i, q = (size_t) (j + 1) * gx_n + i + 1;
                        double wx = o.origin_mm[0] + i * s->pitch_mm, wy = o.origin_mm[1] + j * s->pitch_mm;
                        double X = pose[0] + c * wx - sn * wy, Y = pose[1] + sn * wx + c * wy;
                        o.height[k] = (float) (hg[q] - pose[3] + 1e-3 * s->noise_um * gauss(rng));
                        /* the gradient in the tile's own frame: the normal is stored in it */
                        double gx = (hg[q + 1] - hg[q - 1]) / (2 * s->pitch_mm);
                        double gy = (hg[q + gx_n] - hg[q - gx_n]) / (2 * s->pitch_mm);
                        if (s->normal_scale != 0)
                                scaled_gradient(s, pose, (1 + s->normal_scale) * wx, (1 + s->normal_scale) * wy, &gx, &gy);
                        double nrm = sqrt(1 + gx * gx + gy * gy);
                        o.nx_[k] = (float) (-gx / nrm), o.ny_[k] = (float) (-gy / nrm);
                        o.sigma[k] = (float) (1e-3 * fmax(s->noise_um, 0.1));
                        o.mask[k] = 1;
                        synth_albedo(s, X, Y, o.brdf[k].rho_d);
                        for (int m = 0; m < 3; m++)
                                o.brdf[k].rho_s[m] = 0.04f;
                        o.brdf[k].cx = o.brdf[k].cy = -1, o.brdf[k].cz = 1, o.brdf[k].k = 20;
                }
        free(hg);
        int r = mosaic_out_write(&o, &g, dir, err);
        mosaic_out_done(&o);
        if (r < 0)
                return r;
        char path[4400];
        snprintf(path, sizeof path, "%s/boxes.json", dir);
        _cleanup_json_ json_t *b = json_pack("{s:f,s:f,s:[]}", "h_ref", 0.0, "delta0", 1.0, "boxes");
        return imp_json_save_atomic(path, b, err);
}

static int write_truth_exr(const struct imp_mosaic_synth *s, const char *dir, struct imp_error *err) {
        int nx = (int) lround(s->extent_mm[0] / s->pitch_mm), ny = (int) lround(s->extent_mm[1] / s->pitch_mm);
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_new(nx, ny, 1, IMP_PIX_F32, &img);
        if (r < 0)
                return imp_error_set(err, r, "truth %dx%d: %s", nx, ny, strerror(-r));
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++)
                        *imp_image_f32(img, i, j) = (float) imp_mosaic_synth_height(s, i * s->extent_mm[0] / nx,
                                                                                   j * s->extent_mm[1] / ny);
        static const char *const names[] = { "height" };
        char path[4300];
        snprintf(path, sizeof path, "%s/truth/height.exr", dir);
        return imp_exr_write(path, img, names, false, err);
}

int imp_mosaic_synth_write(const struct imp_mosaic_synth *s, const char *dir, struct imp_error *err) {
        struct imp_tile_options to;
        imp_tile_options_default(&to);
        to.extent_mm[0] = s->extent_mm[0], to.extent_mm[1] = s->extent_mm[1];
        to.fov_mm[0] = s->fov_mm[0], to.fov_mm[1] = s->fov_mm[1];
        to.overlap = s->overlap, to.edge_margin_mm = s->edge_margin_mm;
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *tp = NULL;
        int r = imp_tile_plan_new(&to, &tp, err);
        if (r < 0)
                return r;
        char path[4300];
        snprintf(path, sizeof path, "%s/truth", dir);
        r = imp_mkdir_p(path, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", path, strerror(-r));
        const double origin[2] = { 100, 50 };
        json_t *tiles = json_array(), *truth = json_array();
        _cleanup_json_ json_t *pj = json_pack("{s:s,s:i,s:[f,f],s:[f,f],s:f,s:f,s:[f,f],s:f,s:f,s:o}", "format", "impasto-painting",
                "version", 1, "extent_mm", s->extent_mm[0], s->extent_mm[1], "fov_mm", s->fov_mm[0], s->fov_mm[1],
                "overlap", s->overlap, "edge_margin_mm", s->edge_margin_mm, "origin_mm", origin[0], origin[1], "stage_sigma_mm", s->sigma_mm,
                "stage_sigma_deg", s->sigma_deg, "tiles", tiles);
        _cleanup_json_ json_t *tj = json_pack("{s:o}", "tiles", truth);
        uint64_t rng = mix(s->seed);
        for (size_t idx = 0; idx < imp_tile_plan_count(tp); idx++) {      /* serpentine rows, as the plan */
                const struct imp_tile *t = imp_tile_plan_tile(tp, idx);
                const double *ctr = t->center_mm;
                double pose[4] = { ctr[0] + s->sigma_mm * gauss(&rng), ctr[1] + s->sigma_mm * gauss(&rng),
                                   s->sigma_deg * M_PI / 180 * gauss(&rng), 0.005 * gauss(&rng) };
                char rel[64];
                snprintf(rel, sizeof rel, "copies/%04zu", idx);
                snprintf(path, sizeof path, "%s/%s", dir, rel);
                if ((r = write_tile(s, pose, path, &rng, err)) < 0)
                        return r;
                double st[3] = { origin[0] + ctr[0], origin[1] + ctr[1], 0 };
                json_array_append_new(tiles, json_pack("{s:I,s:i,s:i,s:[f,f],s:[f,f,f],s:[f,f,f],s:s,s:s}", "index",
                        (json_int_t) idx, "col", (int) t->col, "row", (int) t->row, "center_mm", ctr[0], ctr[1],
                        "commanded_mm", st[0], st[1], st[2], "readback_mm", st[0], st[1], st[2], "capture", "", "copy", rel));
                json_array_append_new(truth, json_pack("{s:I,s:f,s:f,s:f,s:f}", "index", (json_int_t) idx, "x_mm", pose[0],
                        "y_mm", pose[1], "theta_deg", pose[2] * 180 / M_PI, "dz_mm", pose[3]));
        }
        snprintf(path, sizeof path, "%s/truth/tile-poses.json", dir);
        if ((r = imp_json_save_atomic(path, tj, err)) < 0)
                return r;
        if (s->truth_exr && (r = write_truth_exr(s, dir, err)) < 0)
                return r;
        snprintf(path, sizeof path, "%s/painting.json", dir);
        return imp_json_save_atomic(path, pj, err);
}
