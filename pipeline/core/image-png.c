/* PNG reading and writing with libpng: 8/16-bit, grey, grey+alpha, RGB, RGBA.
 * libpng reports errors by longjmp: every resource that must be released after a jump
 * lives in a volatile variable declared before setjmp(), and the jump target frees it. */
#include <errno.h>
#include <png.h>
#include <string.h>
#include <unistd.h>
#include "image.h"

#define PNG_SIGNATURE_BYTES 8

/* What libpng's error callback saw; reached through png_get_error_ptr(). */
struct png_errctx {
        char msg[256];
};

static void on_png_error(png_structp png, png_const_charp msg) {
        struct png_errctx *ctx = png_get_error_ptr(png);
        snprintf(ctx->msg, sizeof ctx->msg, "%s", msg);
        png_longjmp(png, 1);
}

static void on_png_warning(png_structp png, png_const_charp msg) {
        /* Warnings (e.g. unknown chunks, bad gamma) do not stop reading: ignored. */
        (void) png; (void) msg;
}

static int color_type_for_channels(int channels) {
        switch (channels) {
        case 1: return PNG_COLOR_TYPE_GRAY;
        case 2: return PNG_COLOR_TYPE_GRAY_ALPHA;
        case 3: return PNG_COLOR_TYPE_RGB;
        case 4: return PNG_COLOR_TYPE_RGB_ALPHA;
        }
        return -1;
}

/* Reads the rest of the file after the signature; f is positioned after it. */
static int png_read_stream(FILE *f, const char *path, struct imp_image **ret, struct imp_error *err) {
        struct png_errctx ctx = { .msg = "" };
        png_structp png;
        png_infop info;
        struct imp_image *volatile img = NULL;
        volatile int r = 0;

        png = png_create_read_struct(PNG_LIBPNG_VER_STRING, &ctx, on_png_error, on_png_warning);
        if (!png)
                return imp_error_set(err, -ENOMEM, "%s: cannot allocate PNG reader", path);
        info = png_create_info_struct(png);
        if (!info) {
                png_destroy_read_struct(&png, NULL, NULL);
                return imp_error_set(err, -ENOMEM, "%s: cannot allocate PNG reader", path);
        }
        if (setjmp(png_jmpbuf(png))) {
                if (r == 0)
                        r = imp_error_set(err, -EBADMSG,
                                          "%s: truncated or corrupt PNG file: %s", path, ctx.msg);
                imp_image_free(img);
                png_destroy_read_struct(&png, &info, NULL);
                return r;
        }

        png_init_io(png, f);
        png_set_sig_bytes(png, PNG_SIGNATURE_BYTES);
        png_read_info(png, info);

        /* Normalise to 8/16-bit grey, grey+alpha, RGB or RGBA: palettes and low bit
         * depths are expanded, transparency chunks become an alpha channel. */
        int color_type = png_get_color_type(png, info);
        int bit_depth = png_get_bit_depth(png, info);
        if (color_type == PNG_COLOR_TYPE_PALETTE)
                png_set_palette_to_rgb(png);
        if (color_type == PNG_COLOR_TYPE_GRAY && bit_depth < 8)
                png_set_expand_gray_1_2_4_to_8(png);
        if (png_get_valid(png, info, PNG_INFO_tRNS))
                png_set_tRNS_to_alpha(png);
        if (bit_depth == 16 && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__)
                png_set_swap(png);      /* PNG stores 16-bit samples big-endian */
        int passes = png_set_interlace_handling(png);
        png_read_update_info(png, info);

        png_uint_32 width = png_get_image_width(png, info);
        png_uint_32 height = png_get_image_height(png, info);
        int channels = png_get_channels(png, info);
        bit_depth = png_get_bit_depth(png, info);
        if (width > IMP_IMAGE_MAX_SIDE || height > IMP_IMAGE_MAX_SIDE) {
                r = imp_error_set(err, -EMEDIUMTYPE, "%s: PNG image of %ux%u pixels is too large "
                                  "(expected at most %d per side)", path, (unsigned) width,
                                  (unsigned) height, IMP_IMAGE_MAX_SIDE);
                png_longjmp(png, 1);
        }
        if ((bit_depth != 8 && bit_depth != 16) || channels < 1 || channels > 4) {
                r = imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported PNG layout: %d channels of "
                                  "%d bits (expected 1-4 channels of 8 or 16 bits)", path,
                                  channels, bit_depth);
                png_longjmp(png, 1);
        }

        struct imp_image *tmp = NULL;
        int q = imp_image_new((int) width, (int) height, channels,
                              bit_depth == 16 ? IMP_PIX_U16 : IMP_PIX_U8, &tmp);
        if (q < 0) {
                r = q == -EINVAL
                    ? imp_error_set(err, -EMEDIUMTYPE, "%s: PNG image too large (expected at most "
                                    "%zu bytes of pixels)", path, IMP_IMAGE_MAX_BYTES)
                    : imp_error_set(err, q, "%s: cannot allocate a %ux%u image: %s", path,
                                    (unsigned) width, (unsigned) height, strerror(-q));
                png_longjmp(png, 1);
        }
        img = tmp;
        if (png_get_rowbytes(png, info) != img->stride) {
                r = imp_error_set(err, -EMEDIUMTYPE, "%s: unexpected PNG row size %zu (expected %zu)",
                                  path, (size_t) png_get_rowbytes(png, info), img->stride);
                png_longjmp(png, 1);
        }

        /* Interlaced images are read in several passes over all rows. */
        for (int pass = 0; pass < passes; pass++)
                for (int y = 0; y < img->height; y++)
                        png_read_row(png, imp_image_row(img, y), NULL);
        png_read_end(png, NULL);

        png_destroy_read_struct(&png, &info, NULL);
        *ret = img;
        return 0;
}

int imp_png_read(const char *path, struct imp_image **ret, struct imp_error *err) {
        unsigned char sig[PNG_SIGNATURE_BYTES];
        _cleanup_fclose_ FILE *f = NULL;

        if (!path || !ret)
                return imp_error_set(err, -EINVAL, "imp_png_read: no path or result given");
        f = fopen(path, "rbe");
        if (!f) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: cannot open PNG file: %s", path, strerror(-r));
        }
        size_t n = fread(sig, 1, sizeof sig, f);
        if (ferror(f))
                return imp_error_set(err, -EIO, "%s: cannot read PNG file", path);
        if (n == 0)
                return imp_error_set(err, -EBADMSG, "%s: empty file (expected a PNG image)", path);
        if (n < sizeof sig || png_sig_cmp(sig, 0, sizeof sig) != 0)
                return imp_error_set(err, -EBADMSG, "%s: not a PNG file (expected the PNG signature)",
                                     path);
        return png_read_stream(f, path, ret, err);
}

/* zlib level and row filter of imp_png_write_fast; -1: libpng's defaults (level 6, the
 * filter chosen row by row among all five). */
struct png_coding {
        int level, filter;
};

static int png_write_stream(FILE *f, const char *path, const struct imp_image *img,
                            struct png_coding coding, struct imp_error *err) {
        struct png_errctx ctx = { .msg = "" };
        png_structp png;
        png_infop info;

        png = png_create_write_struct(PNG_LIBPNG_VER_STRING, &ctx, on_png_error, on_png_warning);
        if (!png)
                return imp_error_set(err, -ENOMEM, "%s: cannot allocate PNG writer", path);
        info = png_create_info_struct(png);
        if (!info) {
                png_destroy_write_struct(&png, NULL);
                return imp_error_set(err, -ENOMEM, "%s: cannot allocate PNG writer", path);
        }
        if (setjmp(png_jmpbuf(png))) {
                png_destroy_write_struct(&png, &info);
                return imp_error_set(err, -EIO, "%s: cannot write PNG: %s", path, ctx.msg);
        }

        int bit_depth = img->type == IMP_PIX_U16 ? 16 : 8;
        png_init_io(png, f);
        png_set_IHDR(png, info, (png_uint_32) img->width, (png_uint_32) img->height, bit_depth,
                     color_type_for_channels(img->channels), PNG_INTERLACE_NONE,
                     PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
        if (coding.level >= 0)
                png_set_compression_level(png, coding.level);
        if (coding.filter >= 0)
                png_set_filter(png, PNG_FILTER_TYPE_BASE, coding.filter);
        png_write_info(png, info);
        if (bit_depth == 16 && __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__)
                png_set_swap(png);
        for (int y = 0; y < img->height; y++)
                png_write_row(png, imp_image_row(img, y));
        png_write_end(png, info);
        png_destroy_write_struct(&png, &info);
        return 0;
}

static int png_write_coded(const char *path, const struct imp_image *img, struct png_coding coding,
                           struct imp_error *err) {
        int r;

        if (!path || !img)
                return imp_error_set(err, -EINVAL, "imp_png_write: no path or image given");
        if (img->type == IMP_PIX_F32 || img->channels < 1 || img->channels > 4)
                return imp_error_set(err, -EINVAL, "%s: cannot store a %s image with %d channels "
                                     "as PNG (expected u8 or u16 with 1-4 channels)", path,
                                     imp_pixel_type_name(img->type), img->channels);

        FILE *f = fopen(path, "wbe");
        if (!f) {
                r = negative_errno();
                return imp_error_set(err, r, "%s: cannot create PNG file: %s", path, strerror(-r));
        }
        r = png_write_stream(f, path, img, coding, err);
        if (fflush(f) != 0 && r >= 0) {
                r = negative_errno();
                imp_error_set(err, r, "%s: cannot write PNG file: %s", path, strerror(-r));
        }
        if (fclose(f) != 0 && r >= 0) {
                r = negative_errno();
                imp_error_set(err, r, "%s: cannot write PNG file: %s", path, strerror(-r));
        }
        if (r < 0)
                (void) unlink(path);
        return r;
}

int imp_png_write(const char *path, const struct imp_image *img, struct imp_error *err) {
        return png_write_coded(path, img, (struct png_coding) { -1, -1 }, err);
}

/* zlib level 3 and the Sub filter on every row: on the demo copy's six previews 3.3x less
 * CPU than libpng's defaults and 1 % smaller (measured in docs/processing-speed.md). */
int imp_png_write_fast(const char *path, const struct imp_image *img, struct imp_error *err) {
        return png_write_coded(path, img, (struct png_coding) { 3, PNG_FILTER_SUB }, err);
}
