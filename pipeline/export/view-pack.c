/* Packing a copy into half-float textures for the browser viewer (view-pack.h). */
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "json-util.h"
#include "quality.h"
#include "view-pack.h"

uint16_t imp_half_from_float(float f) {
        uint32_t x;
        memcpy(&x, &f, 4);
        uint32_t sign = (x >> 16) & 0x8000u, e = (x >> 23) & 0xffu, m = x & 0x7fffffu;
        if (e == 0xff)
                return (uint16_t) (sign | 0x7c00u | (m ? 0x200u : 0));
        int ee = (int) e - 127 + 15;
        if (ee >= 31)
                return (uint16_t) (sign | 0x7c00u);
        if (ee <= 0) {                /* subnormal half or zero */
                if (ee < -10)
                        return (uint16_t) sign;
                m |= 0x800000u;
                int shift = 14 - ee;
                uint32_t hm = m >> shift, rem = m & ((1u << shift) - 1), half = 1u << (shift - 1);
                if (rem > half || (rem == half && (hm & 1)))
                        hm++;
                return (uint16_t) (sign | hm);
        }
        uint32_t hm = m >> 13, rem = m & 0x1fffu;
        uint32_t h = sign | ((uint32_t) ee << 10) | hm;
        if (rem > 0x1000u || (rem == 0x1000u && (hm & 1)))
                h++;                  /* may carry into the exponent: still correct */
        return (uint16_t) h;
}

float imp_half_to_float(uint16_t h) {
        uint32_t sign = (uint32_t) (h & 0x8000u) << 16, e = (h >> 10) & 0x1fu, m = h & 0x3ffu;
        float f;
        if (e == 0)
                f = ldexpf((float) m, -24);
        else if (e == 31)
                f = m ? NAN : INFINITY;
        else
                f = ldexpf((float) (m | 0x400u), (int) e - 25);
        uint32_t x;
        memcpy(&x, &f, 4);
        x |= sign;
        memcpy(&f, &x, 4);
        return f;
}

void imp_view_pack_done(struct imp_view_pack *p) {
        if (!p)
                return;
        free(p->data);
        free(p->meta);
        memset(p, 0, sizeof *p);
}

static void fill_textures(const struct imp_copy *c, uint16_t *d) {
        size_t n = (size_t) c->nx * c->ny;
        for (size_t k = 0; k < n; k++) {
                const struct imp_lafortune *b = &c->brdf[k];
                float v[IMP_VIEW_PACK_TEXTURES][4] = {
                        { (float) (c->height[k] - c->plane_mm), c->normal_x[k], c->normal_y[k], c->mask[k] },
                        { b->rho_d[0], b->rho_d[1], b->rho_d[2], c->sigma[k] },
                        { b->rho_s[0], b->rho_s[1], b->rho_s[2], (float) c->texel_flags[k] },
                        { b->cx, b->cy, b->cz, b->k },
                };
                for (int t = 0; t < IMP_VIEW_PACK_TEXTURES; t++)
                        for (int q = 0; q < 4; q++)
                                d[((size_t) t * n + k) * 4 + q] = imp_half_from_float(v[t][q]);
        }
}

static int cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return (x > y) - (x < y);
}

/* Height range over the mask and the 99th percentile of σ (the overlays' scales). */
static int ranges(const struct imp_copy *c, double *hmin, double *hmax, double *s99) {
        size_t n = (size_t) c->nx * c->ny, m = 0;
        float *s = malloc(sizeof *s * (c->n_mask ? c->n_mask : 1));
        if (!s)
                return -ENOMEM;
        *hmin = *hmax = c->plane_mm;
        for (size_t k = 0; k < n; k++)
                if (c->mask[k]) {
                        if (m == 0 || c->height[k] < *hmin)
                                *hmin = c->height[k];
                        if (m == 0 || c->height[k] > *hmax)
                                *hmax = c->height[k];
                        s[m++] = c->sigma[k];
                }
        qsort(s, m, sizeof *s, cmp_float);
        *s99 = m ? s[(size_t) floor(0.99 * (double) (m - 1))] : 0;
        free(s);
        return 0;
}

/* The box top as the CPU renderer computes it: max of hmax, the plane and its heights. */
static double box_top(const struct imp_copy *c, const struct imp_relief_box *x) {
        double top = IMP_MAX((double) x->hmax_mm, c->plane_mm);
        for (int j = x->v0; j < x->v0 + x->h; j++)
                for (int i = x->u0; i < x->u0 + x->w; i++)
                        top = IMP_MAX(top, (double) c->height[(size_t) j * c->nx + i]);
        return top;
}

static json_t *meta_json(const struct imp_copy *c, double hmin, double hmax, double s99) {
        json_t *boxes = json_array(), *flags = json_array();
        for (size_t b = 0; b < c->n_boxes; b++) {
                const struct imp_relief_box *x = &c->boxes[b];
                json_array_append_new(boxes, json_pack("[iiiifiif]", x->u0, x->v0, x->w, x->h, (double) x->hmax_mm,
                                                       x->umax, x->vmax, box_top(c, x)));
        }
        for (unsigned f = 0; f < IMP_TEXEL_FLAG_COUNT; f++)
                json_array_append_new(flags, json_string(imp_texel_flag_name(f)));
        return json_pack("{s:s, s:i, s:i, s:i, s:f, s:f, s:f, s:f, s:f, s:f, s:f, s:b, s:I, s:o, s:o, s:[ssss]}",
                         "format", "impasto-view", "version", 1, "nx", c->nx, "ny", c->ny, "pitch_mm", c->pitch_mm,
                         "plane_mm", c->plane_mm, "h_ref_mm", c->h_ref_mm, "delta0_mm", c->delta0_mm,
                         "height_min_mm", hmin, "height_max_mm", hmax, "sigma_p99_mm", s99, "has_flags",
                         c->has_flags, "n_mask", (json_int_t) c->n_mask, "boxes", boxes, "flag_names", flags,
                         "textures", "surface", "diffuse", "specular", "lobe");
}

int imp_view_pack_build(const struct imp_copy *c, struct imp_view_pack *p, struct imp_error *err) {
        memset(p, 0, sizeof *p);
        size_t n = (size_t) c->nx * c->ny;
        double hmin, hmax, s99;
        p->size = n * 4 * IMP_VIEW_PACK_TEXTURES * sizeof(uint16_t);
        p->data = malloc(p->size);
        if (!p->data || ranges(c, &hmin, &hmax, &s99) < 0) {
                imp_view_pack_done(p);
                return imp_error_set(err, -ENOMEM, "out of memory packing a %dx%d copy", c->nx, c->ny);
        }
        fill_textures(c, p->data);
        _cleanup_json_ json_t *meta = meta_json(c, hmin, hmax, s99);
        p->meta = meta ? json_dumps(meta, JSON_COMPACT | JSON_REAL_PRECISION(10)) : NULL;
        if (!p->meta) {
                imp_view_pack_done(p);
                return imp_error_set(err, -ENOMEM, "out of memory describing the copy");
        }
        p->meta_size = strlen(p->meta);
        return 0;
}

static int read_whole(const char *path, void **ret, size_t *ret_size, struct imp_error *err) {
        _cleanup_close_ int fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0)
                return errno == ENOENT ? -ENOENT : imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        struct stat st;
        if (fstat(fd, &st) < 0)
                return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        char *buf = malloc((size_t) st.st_size + 1);
        if (!buf)
                return imp_error_set(err, -ENOMEM, "out of memory");
        size_t got = 0;
        while (got < (size_t) st.st_size) {
                ssize_t k = read(fd, buf + got, (size_t) st.st_size - got);
                if (k < 0 && errno == EINTR)
                        continue;
                if (k <= 0) {
                        free(buf);
                        return imp_error_set(err, -EIO, "%s: short read", path);
                }
                got += (size_t) k;
        }
        buf[got] = 0;
        *ret = buf;
        *ret_size = got;
        return 0;
}

int imp_view_pack_cache_load(const char *dir, const char *key, struct imp_view_pack *p, struct imp_error *err) {
        memset(p, 0, sizeof *p);
        char path[PATH_MAX];
        void *meta = NULL, *data = NULL;
        size_t meta_size, size;
        snprintf(path, sizeof path, "%s/%s.json", dir, key);
        int r = read_whole(path, &meta, &meta_size, err);
        if (r < 0)
                return r;
        snprintf(path, sizeof path, "%s/%s.bin", dir, key);
        if ((r = read_whole(path, &data, &size, err)) < 0) {
                free(meta);
                return r;
        }
        p->meta = meta, p->meta_size = meta_size, p->data = data, p->size = size;
        /* the blob's size must be what the description's grid says */
        _cleanup_json_ json_t *j = json_loads(meta, 0, NULL);
        json_int_t nx = j ? json_integer_value(json_object_get(j, "nx")) : 0;
        json_int_t ny = j ? json_integer_value(json_object_get(j, "ny")) : 0;
        if (nx < 1 || ny < 1 || size != (size_t) nx * (size_t) ny * 4 * IMP_VIEW_PACK_TEXTURES * sizeof(uint16_t)) {
                imp_view_pack_done(p);
                return imp_error_set(err, -EBADMSG, "%s: does not match its description", path);
        }
        return 0;
}

int imp_view_pack_cache_save(const char *dir, const char *key, const struct imp_view_pack *p,
                             struct imp_error *err) {
        char path[PATH_MAX];
        int r = imp_mkdir_p(dir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: %s", dir, strerror(-r));
        snprintf(path, sizeof path, "%s/%s.bin", dir, key);
        if ((r = imp_file_write_atomic(path, p->data, p->size, err)) < 0)
                return r;
        snprintf(path, sizeof path, "%s/%s.json", dir, key);
        return imp_file_write_atomic(path, p->meta, p->meta_size, err);
}

int imp_view_pack_key(const char *copy_dir, char *ret, size_t size, struct imp_error *err) {
        static const char *const files[] = { "copy.json", "boxes.json", "heightfield.exr", "rho_d.exr",
                                             "rho_s.exr", "lobe.exr", "fit-flags.exr" };
        char real[PATH_MAX], path[PATH_MAX + 64], buf[PATH_MAX + 200];
        if (!realpath(copy_dir, real))
                return imp_error_set(err, -errno, "%s: %s", copy_dir, strerror(errno));
        uint64_t h = 1469598103934665603ull;
        for (size_t f = 0; f < ARRAY_SIZE(files); f++) {
                struct stat st = { 0 };
                snprintf(path, sizeof path, "%s/%s", real, files[f]);
                if (stat(path, &st) < 0 && errno != ENOENT)
                        return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
                int n = snprintf(buf, sizeof buf, "%s|%lld|%lld.%09ld|v1", path, (long long) st.st_size,
                                 (long long) st.st_mtim.tv_sec, st.st_mtim.tv_nsec);
                for (int i = 0; i < n && i < (int) sizeof buf; i++)
                        h = (h ^ (uint8_t) buf[i]) * 1099511628211ull;
        }
        if (size < 17)
                return imp_error_set(err, -EINVAL, "key buffer too small");
        snprintf(ret, size, "%016llx", (unsigned long long) h);
        return 0;
}
