/* Reading a whole digital copy (copy-load.h). The conventions match `impasto render`: off
 * the mask, texels sit on the bump plane with black paint, so every value is finite. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "boxes.h"
#include "copy-load.h"
#include "image.h"
#include "json-util.h"

#define COPY_MAX_SIDE (1 << 20)

void imp_copy_done(struct imp_copy *c) {
        if (!c)
                return;
        free(c->height);
        free(c->normal_x);
        free(c->normal_y);
        free(c->sigma);
        free(c->mask);
        free(c->texel_flags);
        free(c->fit_flags);
        free(c->brdf);
        free(c->boxes);
        memset(c, 0, sizeof *c);
}

/* Reads DIR/FILE and finds channels CHANS (and, when ret_opt is not NULL, the optional channel
 * OPT: *ret_opt −1 when absent); the size must be w×h. */
static int read_exr_opt(const char *dir, const char *file, const char *const *chans, int n, const char *opt, int w,
                        int h, struct imp_image **ret, int *ret_c, int *ret_opt, struct imp_error *err) {
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", dir, file);
        char **names = NULL;
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_exr_read(path, &img, &names, err);
        if (r < 0)
                return r;
        for (int i = 0; i < n; i++)
                if ((ret_c[i] = imp_image_channel_index(names, chans[i])) < 0) {
                        imp_strv_free(names);
                        return imp_error_set(err, -EBADMSG, "%s: channel \"%s\" missing", path, chans[i]);
                }
        if (ret_opt)
                *ret_opt = imp_image_channel_index(names, opt);
        imp_strv_free(names);
        if (img->width != w || img->height != h)
                return imp_error_set(err, -EBADMSG, "%s: %dx%d, copy.json says %dx%d", path, img->width,
                                     img->height, w, h);
        *ret = TAKE_PTR(img);
        return 0;
}

static int read_exr(const char *dir, const char *file, const char *const *chans, int n, int w, int h,
                    struct imp_image **ret, int *ret_c, struct imp_error *err) {
        return read_exr_opt(dir, file, chans, n, NULL, w, h, ret, ret_c, NULL, err);
}

static float finite_or(double v, float dflt) {
        return isfinite(v) ? (float) v : dflt;
}

static int load_grid(const char *dir, struct imp_copy *c, struct imp_error *err) {
        char path[4096];
        _cleanup_json_ json_t *cj = NULL;
        snprintf(path, sizeof path, "%s/copy.json", dir);
        struct stat st;
        if (stat(dir, &st) < 0)
                return imp_error_set(err, -errno, "%s: %s", dir, strerror(errno));
        if (!S_ISDIR(st.st_mode))
                return imp_error_set(err, -ENOTDIR, "%s: not a directory (expected a digital copy)", dir);
        int r = imp_json_load(path, &cj, err);
        if (r < 0)
                return r;
        long long nx, ny;
        double pitch;
        if ((r = imp_json_get_int(cj, "nx", true, &nx, path, err)) < 0 ||
            (r = imp_json_get_int(cj, "ny", true, &ny, path, err)) < 0 ||
            (r = imp_json_get_double(cj, "pitch_mm", true, &pitch, path, err)) < 0)
                return r;
        if (nx < 1 || ny < 1 || nx > COPY_MAX_SIDE || ny > COPY_MAX_SIDE || !(pitch > 0) || !isfinite(pitch))
                return imp_error_set(err, -EBADMSG, "%s: expected nx, ny in 1..%d and pitch_mm > 0, got %lldx%lld at %g",
                                     path, COPY_MAX_SIDE, nx, ny, pitch);
        c->nx = (int) nx, c->ny = (int) ny, c->pitch_mm = pitch;
        static const double I[16] = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 };
        memcpy(c->canvas_to_world, I, sizeof I);
        if ((r = imp_json_get_doubles(cj, "canvas_to_world", false, 16, c->canvas_to_world, path, err)) < 0)
                return r;
        for (int i = 0; i < 16; i++)
                if (!isfinite(c->canvas_to_world[i]))
                        return imp_error_set(err, -EBADMSG, "%s: canvas_to_world: expected finite numbers", path);
        return 0;
}

static int load_boxes(const char *dir, struct imp_copy *c, struct imp_error *err) {
        char path[4096];
        _cleanup_json_ json_t *bj = NULL;
        snprintf(path, sizeof path, "%s/boxes.json", dir);
        int r = imp_json_load(path, &bj, err);
        if (r < 0)
                return r;
        if ((r = imp_json_get_double(bj, "h_ref", true, &c->h_ref_mm, path, err)) < 0 ||
            (r = imp_json_get_double(bj, "delta0", true, &c->delta0_mm, path, err)) < 0)
                return r;
        if (!isfinite(c->h_ref_mm) || !isfinite(c->delta0_mm))
                return imp_error_set(err, -EBADMSG, "%s: h_ref and delta0 must be finite", path);
        c->plane_mm = c->h_ref_mm + c->delta0_mm;
        json_t *arr = json_object_get(bj, "boxes");
        if (arr && !json_is_array(arr))
                return imp_error_set(err, -EBADMSG, "%s: boxes: expected an array", path);
        size_t nb = arr ? json_array_size(arr) : 0;
        c->boxes = calloc(nb ? nb : 1, sizeof *c->boxes);
        if (!c->boxes)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t b = 0; b < nb; b++) {
                json_t *o = json_array_get(arr, b);
                char what[4200];
                snprintf(what, sizeof what, "%s: boxes[%zu].", path, b);
                long long u0, v0, w, h, um, vm;
                double hmax;
                if ((r = imp_json_get_int(o, "u0", true, &u0, what, err)) < 0 ||
                    (r = imp_json_get_int(o, "v0", true, &v0, what, err)) < 0 ||
                    (r = imp_json_get_int(o, "w", true, &w, what, err)) < 0 ||
                    (r = imp_json_get_int(o, "h", true, &h, what, err)) < 0 ||
                    (r = imp_json_get_int(o, "umax", true, &um, what, err)) < 0 ||
                    (r = imp_json_get_int(o, "vmax", true, &vm, what, err)) < 0 ||
                    (r = imp_json_get_double(o, "hmax", true, &hmax, what, err)) < 0)
                        return r;
                if (w < 1 || h < 1 || u0 < 0 || v0 < 0 || u0 + w > c->nx || v0 + h > c->ny || um < 0 ||
                    um >= c->nx || vm < 0 || vm >= c->ny || !isfinite(hmax))
                        return imp_error_set(err, -EBADMSG, "%sexpected a box inside the %dx%d grid, got u0 %lld v0 %lld w %lld h %lld",
                                             what, c->nx, c->ny, u0, v0, w, h);
                c->boxes[b] = (struct imp_relief_box) { (int) u0, (int) v0, (int) w, (int) h, (float) hmax,
                                                        (int) um, (int) vm };
        }
        c->n_boxes = nb;
        return 0;
}

static int alloc_maps(struct imp_copy *c, struct imp_error *err) {
        size_t n = (size_t) c->nx * c->ny;
        c->height = malloc(n * sizeof(float));
        c->normal_x = malloc(n * sizeof(float));
        c->normal_y = malloc(n * sizeof(float));
        c->sigma = malloc(n * sizeof(float));
        c->mask = calloc(n, 1);
        c->texel_flags = calloc(n, sizeof *c->texel_flags);
        c->fit_flags = calloc(n, sizeof *c->fit_flags);
        c->brdf = calloc(n, sizeof *c->brdf);
        if (!c->height || !c->normal_x || !c->normal_y || !c->sigma || !c->mask || !c->texel_flags || !c->fit_flags ||
            !c->brdf)
                return imp_error_set(err, -ENOMEM, "out of memory for a %dx%d copy", c->nx, c->ny);
        return 0;
}

/* A flags channel's value as bits: 0 unless a finite positive integer below 2^16. */
static uint16_t flag_bits(float v) {
        return isfinite(v) && v > 0 && v < 65536 ? (uint16_t) lrintf(v) : 0;
}

/* fit-flags.exr is optional: older copies have none. */
static int load_fit_flags(const char *dir, struct imp_copy *c, struct imp_error *err) {
        char path[4096];
        snprintf(path, sizeof path, "%s/fit-flags.exr", dir);
        if (access(path, F_OK) < 0)
                return 0;
        static const char *const FL[] = { "flags" };
        _cleanup_image_ struct imp_image *fl = NULL;
        int cf;
        int r = read_exr(dir, "fit-flags.exr", FL, 1, c->nx, c->ny, &fl, &cf, err);
        if (r < 0)
                return r;
        for (int j = 0; j < c->ny; j++)
                for (int i = 0; i < c->nx; i++) {
                        float v = imp_image_f32(fl, i, j)[cf];
                        c->fit_flags[(size_t) j * c->nx + i] = flag_bits(v);
                }
        c->has_fit_flags = true;
        return 0;
}

int imp_copy_load(const char *dir, struct imp_copy *c, struct imp_error *err) {
        memset(c, 0, sizeof *c);
        int r;
        if ((r = load_grid(dir, c, err)) < 0 || (r = load_boxes(dir, c, err)) < 0)
                return r;
        static const char *const HF[] = { "height", "nx", "ny", "sigma", "mask" }, *const RGB[] = { "R", "G", "B" },
                                 *const LOBE[] = { "cx", "cy", "cz", "k" };
        _cleanup_image_ struct imp_image *hf = NULL, *rd = NULL, *rs = NULL, *lo = NULL;
        int ch[5], cd[3], cs[3], cl[4], cf;
        if ((r = read_exr_opt(dir, "heightfield.exr", HF, 5, "flags", c->nx, c->ny, &hf, ch, &cf, err)) < 0 ||
            (r = read_exr(dir, "rho_d.exr", RGB, 3, c->nx, c->ny, &rd, cd, err)) < 0 ||
            (r = read_exr(dir, "rho_s.exr", RGB, 3, c->nx, c->ny, &rs, cs, err)) < 0 ||
            (r = read_exr(dir, "lobe.exr", LOBE, 4, c->nx, c->ny, &lo, cl, err)) < 0 ||
            /* only now: the maps are copy.json's size, so a damaged nx, ny costs no memory */
            (r = alloc_maps(c, err)) < 0 || (r = load_fit_flags(dir, c, err)) < 0)
                return r;
        float plane = (float) c->plane_mm;
        for (int j = 0; j < c->ny; j++)
                for (int i = 0; i < c->nx; i++) {
                        size_t k = (size_t) j * c->nx + i;
                        const float *p = imp_image_f32(hf, i, j);
                        bool in = p[ch[4]] >= 0.5f && isfinite(p[ch[0]]);
                        c->mask[k] = in ? (uint8_t) IMP_CLAMP(lrintf(p[ch[4]]), 1, 255) : 0;
                        c->n_mask += in;
                        c->height[k] = in ? p[ch[0]] : plane;
                        c->normal_x[k] = in ? finite_or(p[ch[1]], 0) : 0;
                        c->normal_y[k] = in ? finite_or(p[ch[2]], 0) : 0;
                        c->sigma[k] = in ? fmaxf(finite_or(p[ch[3]], 0), 0) : 0;
                        c->texel_flags[k] = in && cf >= 0 ? flag_bits(p[cf]) : 0;
                        struct imp_lafortune *b = &c->brdf[k];
                        const float *d = imp_image_f32(rd, i, j), *s = imp_image_f32(rs, i, j);
                        const float *l = imp_image_f32(lo, i, j);
                        for (int q = 0; q < 3; q++) {
                                b->rho_d[q] = in ? fmaxf(finite_or(d[cd[q]], 0), 0) : 0;
                                b->rho_s[q] = in ? fmaxf(finite_or(s[cs[q]], 0), 0) : 0;
                        }
                        b->cx = finite_or(l[cl[0]], -1), b->cy = finite_or(l[cl[1]], -1);
                        b->cz = finite_or(l[cl[2]], 1), b->k = fmaxf(finite_or(l[cl[3]], 1), 0);
                }
        c->has_flags = cf >= 0;
        return 0;
}

void imp_copy_relief(const struct imp_copy *c, struct imp_relief_copy *ret) {
        *ret = (struct imp_relief_copy) {
                .nx = c->nx, .ny = c->ny, .pitch_mm = c->pitch_mm, .height_mm = c->height,
                .normal_x = c->normal_x, .normal_y = c->normal_y, .brdf = c->brdf, .boxes = c->boxes,
                .n_boxes = c->n_boxes, .delta0_mm = c->plane_mm,
                .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 },
        };
}

int imp_copy_reclassify(struct imp_copy *c, int cell_px, struct imp_error *err) {
        size_t n = (size_t) c->nx * c->ny;
        double hmax = -INFINITY;
        _cleanup_free_ float *h = malloc(sizeof *h * n);
        if (!h)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t k = 0; k < n; k++) {
                h[k] = c->mask[k] ? c->height[k] : 0;
                if (c->mask[k])
                        hmax = IMP_MAX(hmax, (double) c->height[k]);
        }
        struct imp_heightfield hf = { .nx = c->nx, .ny = c->ny, .pitch_mm = c->pitch_mm, .height_mm = h,
                                      .nx_ = c->normal_x, .ny_ = c->normal_y, .sigma_mm = c->sigma, .mask = c->mask };
        struct imp_boxes_options opt;
        imp_boxes_options_default(&opt);
        opt.cell_px = cell_px;
        if (hmax > c->h_ref_mm)          /* keep the copy's δ0 / H */
                opt.delta_frac = IMP_CLAMP(c->delta0_mm / (hmax - c->h_ref_mm), 0.0, 1.0);
        struct imp_boxes b = { 0 };
        int r = imp_boxes_classify(&hf, &opt, &b);
        if (r < 0)
                return imp_error_set(err, r, "relief boxes of %d texels: %s", cell_px, strerror(-r));
        struct imp_relief_box *nb = calloc(b.n_boxes ? b.n_boxes : 1, sizeof *nb);
        if (!nb) {
                imp_boxes_done(&b);
                return imp_error_set(err, -ENOMEM, "out of memory");
        }
        for (size_t i = 0; i < b.n_boxes; i++) {
                const struct imp_box *x = &b.boxes[i];
                nb[i] = (struct imp_relief_box) { x->u0, x->v0, x->w, x->h, x->hmax_mm, x->umax, x->vmax };
        }
        free(c->boxes);
        c->boxes = nb;
        c->n_boxes = b.n_boxes;
        c->h_ref_mm = b.h_ref_mm;
        c->delta0_mm = b.delta0_mm;
        c->plane_mm = b.h_ref_mm + b.delta0_mm;
        for (size_t k = 0; k < n; k++)
                if (!c->mask[k])
                        c->height[k] = (float) c->plane_mm;
        imp_boxes_done(&b);
        return 0;
}
