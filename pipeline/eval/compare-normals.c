/* Angular error of normal maps (compare-normals.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include "compare-normals.h"

static const char *extension(const char *path) {
        const char *dot = strrchr(path, '.'), *slash = strrchr(path, '/');
        return dot && (!slash || dot > slash) ? dot + 1 : "";
}

/* Channel indices of x, y, z in an EXR (z may be -1 when absent). */
static int exr_channels(char **names, int nch, int ret[3]) {
        static const char *const sets[][3] = { { "nx", "ny", "nz" }, { "X", "Y", "Z" }, { "R", "G", "B" } };
        for (size_t s = 0; s < sizeof sets / sizeof sets[0]; s++) {
                int a = imp_image_channel_index(names, sets[s][0]), b = imp_image_channel_index(names, sets[s][1]);
                if (a >= 0 && b >= 0) {
                        ret[0] = a;
                        ret[1] = b;
                        ret[2] = imp_image_channel_index(names, sets[s][2]);
                        return 0;
                }
        }
        if (nch < 3)
                return -EINVAL;
        ret[0] = 0, ret[1] = 1, ret[2] = 2;
        return 0;
}

/* n = (x, y, z) normalised into dst, NAN when it holds no direction. */
static void put(float *dst, double x, double y, double z) {
        double l = sqrt(x * x + y * y + z * z);
        bool ok = isfinite(l) && l > 1e-6;
        dst[0] = ok ? (float) (x / l) : NAN;
        dst[1] = ok ? (float) (y / l) : NAN;
        dst[2] = ok ? (float) (z / l) : NAN;
}

static int from_exr(const char *path, struct imp_image **ret, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        char **names = NULL;
        int r = imp_exr_read(path, &img, &names, err), ch[3];
        if (r < 0)
                return r;
        r = exr_channels(names, img->channels, ch);
        imp_strv_free(names);
        if (r < 0)
                return imp_error_set(err, -EINVAL, "%s: expected channels nx, ny (nz) or three channels, found %d",
                                     path, img->channels);
        struct imp_image *d;
        if ((r = imp_image_new(img->width, img->height, 3, IMP_PIX_F32, &d)) < 0)
                return imp_error_set(err, r, "%s: cannot allocate", path);
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        const float *p = imp_image_f32(img, x, y);
                        double nx = p[ch[0]], ny = p[ch[1]];
                        double nz = ch[2] >= 0 ? p[ch[2]] : sqrt(fmax(0.0, 1 - nx * nx - ny * ny));
                        put(imp_image_f32(d, x, y), nx, ny, nz);
                }
        *ret = d;
        return 0;
}

/* PNG or TIFF: float as is, integers as (n + 1) / 2. */
static int from_raster(const char *path, bool tiff, struct imp_image **ret, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        int r = tiff ? imp_tiff_read(path, &img, NULL, err) : imp_png_read(path, &img, err);
        if (r < 0)
                return r;
        if (img->channels < 3)
                return imp_error_set(err, -EINVAL, "%s: %d channel(s): expected 3 (x, y, z)", path, img->channels);
        double scale = img->type == IMP_PIX_U8 ? 255.0 : img->type == IMP_PIX_U16 ? 65535.0 : 0;
        struct imp_image *d;
        if ((r = imp_image_new(img->width, img->height, 3, IMP_PIX_F32, &d)) < 0)
                return imp_error_set(err, r, "%s: cannot allocate", path);
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        double v[3];
                        for (int c = 0; c < 3; c++) {
                                v[c] = imp_image_get(img, x, y, c);
                                if (scale > 0)
                                        v[c] = 2 * v[c] / scale - 1;
                        }
                        put(imp_image_f32(d, x, y), v[0], v[1], v[2]);
                }
        *ret = d;
        return 0;
}

int imp_normals_read(const char *path, struct imp_image **ret, struct imp_error *err) {
        struct stat st;
        if (stat(path, &st) < 0)
                return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        if (S_ISDIR(st.st_mode)) {
                char p[4200];
                snprintf(p, sizeof p, "%s/heightfield.exr", path);
                return from_exr(p, ret, err);
        }
        const char *ext = extension(path);
        if (!strcasecmp(ext, "exr"))
                return from_exr(path, ret, err);
        if (!strcasecmp(ext, "tif") || !strcasecmp(ext, "tiff"))
                return from_raster(path, true, ret, err);
        if (!strcasecmp(ext, "png"))
                return from_raster(path, false, ret, err);
        return imp_error_set(err, -EINVAL, "%s: expected a normal map (.exr, .tif, .tiff, .png) or a copy directory", path);
}

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

int imp_normals_compare(const struct imp_image *est, const struct imp_image *truth, const struct imp_image *mask,
                        struct imp_normals_cmp *ret) {
        if (!est || !truth || est->type != IMP_PIX_F32 || truth->type != IMP_PIX_F32 || est->channels != 3 ||
            truth->channels != 3 || est->width != truth->width || est->height != truth->height ||
            (mask && (mask->width != est->width || mask->height != est->height)))
                return -EINVAL;
        size_t cap = (size_t) est->width * est->height;
        _cleanup_free_ double *e = malloc((cap ? cap : 1) * sizeof *e);
        if (!e)
                return -ENOMEM;
        struct imp_normals_cmp c = {};
        double sum = 0, ss = 0;
        for (int y = 0; y < est->height; y++)
                for (int x = 0; x < est->width; x++) {
                        if (mask && !(imp_image_get(mask, x, y, 0) > 0))
                                continue;
                        const float *a = imp_image_f32(est, x, y), *b = imp_image_f32(truth, x, y);
                        double d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
                        if (!isfinite(d))
                                continue;
                        double deg = acos(fmax(-1.0, fmin(1.0, d))) * 180 / M_PI;
                        e[c.n++] = deg;
                        sum += deg;
                        ss += deg * deg;
                        c.within_10deg += deg <= 10;
                        c.within_20deg += deg <= 20;
                }
        if (c.n == 0)
                return -ENODATA;
        qsort(e, (size_t) c.n, sizeof *e, cmp_double);
        c.mean_deg = sum / c.n;
        c.rms_deg = sqrt(ss / c.n);
        c.median_deg = c.n & 1 ? e[c.n / 2] : 0.5 * (e[c.n / 2 - 1] + e[c.n / 2]);
        c.p90_deg = e[(size_t) (0.9 * (c.n - 1))];
        c.within_10deg /= c.n;
        c.within_20deg /= c.n;
        *ret = c;
        return 0;
}
