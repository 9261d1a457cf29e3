/* The in-memory image (allocation, copies, sample access, conversion to float) and the
 * dispatch of imp_image_read() by file extension. The file formats themselves live in
 * image-png.c, image-tiff.c and image-exr.c. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include "image.h"

size_t imp_pixel_type_size(enum imp_pixel_type t) {
        switch (t) {
        case IMP_PIX_U8:  return 1;
        case IMP_PIX_U16: return 2;
        case IMP_PIX_F32: return 4;
        }
        return 0;
}

const char *imp_pixel_type_name(enum imp_pixel_type t) {
        switch (t) {
        case IMP_PIX_U8:  return "u8";
        case IMP_PIX_U16: return "u16";
        case IMP_PIX_F32: return "f32";
        }
        return "invalid";
}

int imp_image_layout(int width, int height, int channels, enum imp_pixel_type type,
                     size_t *ret_stride, size_t *ret_total) {
        size_t sample_size = imp_pixel_type_size(type);
        size_t stride, total;

        if (sample_size == 0)
                return -EINVAL;
        if (width <= 0 || height <= 0 || width > IMP_IMAGE_MAX_SIDE || height > IMP_IMAGE_MAX_SIDE)
                return -EINVAL;
        if (channels <= 0 || channels > IMP_IMAGE_MAX_CHANNELS)
                return -EINVAL;
        if (__builtin_mul_overflow((size_t) width * (size_t) channels, sample_size, &stride) ||
            __builtin_mul_overflow(stride, (size_t) height, &total) ||
            total > IMP_IMAGE_MAX_BYTES)
                return -EINVAL;
        *ret_stride = stride;
        *ret_total = total;
        return 0;
}

int imp_image_new(int width, int height, int channels, enum imp_pixel_type type,
                  struct imp_image **ret) {
        size_t stride, total;

        if (!ret)
                return -EINVAL;
        int r = imp_image_layout(width, height, channels, type, &stride, &total);
        if (r < 0)
                return r;

        struct imp_image *img = calloc(1, sizeof *img);
        if (!img)
                return -ENOMEM;
        img->data = calloc(1, total);
        if (!img->data) {
                free(img);
                return -ENOMEM;
        }
        img->width = width;
        img->height = height;
        img->channels = channels;
        img->type = type;
        img->stride = stride;
        *ret = img;
        return 0;
}

void imp_image_free(struct imp_image *img) {
        if (!img)
                return;
        if (!img->in_arena)
                free(img->data);
        free(img);
}

int imp_image_dup(const struct imp_image *src, struct imp_image **ret) {
        struct imp_image *img = NULL;
        int r;

        if (!src || !ret)
                return -EINVAL;
        r = imp_image_new(src->width, src->height, src->channels, src->type, &img);
        if (r < 0)
                return r;
        size_t row_bytes = img->stride;         /* the source may have a larger stride */
        for (int y = 0; y < src->height; y++)
                memcpy(imp_image_row(img, y), imp_image_row(src, y), row_bytes);
        *ret = img;
        return 0;
}

int imp_image_to_f32(const struct imp_image *src, struct imp_image **ret) {
        struct imp_image *img = NULL;
        int r;

        if (!src || !ret)
                return -EINVAL;
        r = imp_image_new(src->width, src->height, src->channels, IMP_PIX_F32, &img);
        if (r < 0)
                return r;
        size_t n = (size_t) src->width * (size_t) src->channels;
        for (int y = 0; y < src->height; y++) {
                float *out = imp_image_row(img, y);
                const void *in = imp_image_row(src, y);
                for (size_t i = 0; i < n; i++) {
                        switch (src->type) {
                        case IMP_PIX_U8:  out[i] = ((const uint8_t *) in)[i]; break;
                        case IMP_PIX_U16: out[i] = ((const uint16_t *) in)[i]; break;
                        case IMP_PIX_F32: out[i] = ((const float *) in)[i]; break;
                        }
                }
        }
        *ret = img;
        return 0;
}

double imp_image_get(const struct imp_image *img, int x, int y, int c) {
        switch (img->type) {
        case IMP_PIX_U8:  return imp_image_u8(img, x, y)[c];
        case IMP_PIX_U16: return imp_image_u16(img, x, y)[c];
        case IMP_PIX_F32: return imp_image_f32(img, x, y)[c];
        }
        return 0.0;
}

int imp_image_channel_index(char **names, const char *name) {
        if (!names || !name)
                return -EINVAL;
        for (int i = 0; names[i]; i++)
                if (strcmp(names[i], name) == 0)
                        return i;
        return -ENOENT;
}

void imp_strv_free(char **v) {
        if (!v)
                return;
        for (char **p = v; *p; p++)
                free(*p);
        free(v);
}

static bool has_suffix(const char *s, const char *suffix) {
        size_t n = strlen(s), m = strlen(suffix);
        return n >= m && strcasecmp(s + n - m, suffix) == 0;
}

int imp_image_read(const char *path, struct imp_image **ret, struct imp_error *err) {
        if (!path || !ret)
                return imp_error_set(err, -EINVAL, "imp_image_read: no path or result given");
        if (has_suffix(path, ".png"))
                return imp_png_read(path, ret, err);
        if (has_suffix(path, ".tif") || has_suffix(path, ".tiff"))
                return imp_tiff_read(path, ret, NULL, err);
        if (has_suffix(path, ".exr"))
                return imp_exr_read(path, ret, NULL, err);
        return imp_error_set(err, -EINVAL,
                             "%s: unknown image file extension (expected .png, .tif, .tiff or .exr)",
                             path);
}
