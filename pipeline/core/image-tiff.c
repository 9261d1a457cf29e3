/* TIFF reading and writing with libtiff: u8, u16 or f32 samples, 1-4 channels, contiguous
 * strips, deflate-compressed; metadata (JSON for frames) in the ImageDescription tag.
 * libtiff's handlers print to stderr; ours keep the first message in a thread-local buffer. */
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <pthread.h>
#include <stdarg.h>
#include <string.h>
#include <sys/stat.h>
#include <tiffio.h>
#include <unistd.h>
#include <zstd.h>
#include "image.h"

static _Thread_local char tiff_msg[512];

static void on_tiff_error(const char *module, const char *fmt, va_list ap) {
        if (tiff_msg[0])
                return;         /* the first message is the specific one */
        int n = module ? snprintf(tiff_msg, sizeof tiff_msg, "%s: ", module) : 0;
        if (n < 0 || (size_t) n >= sizeof tiff_msg)
                n = 0;
        vsnprintf(tiff_msg + n, sizeof tiff_msg - (size_t) n, fmt, ap);
}

static void on_tiff_warning(const char *module, const char *fmt, va_list ap) {
        /* Warnings (unknown tags, ...) do not stop reading: dropped. */
        (void) module; (void) fmt; (void) ap;
}

static void install_handlers_once(void) {
        TIFFSetErrorHandler(on_tiff_error);
        TIFFSetWarningHandler(on_tiff_warning);
}

/* Silences libtiff for this process and clears this thread's message. */
static void tiff_begin(void) {
        static pthread_once_t once = PTHREAD_ONCE_INIT;
        pthread_once(&once, install_handlers_once);
        tiff_msg[0] = 0;
}

static const char *tiff_last_error(void) {
        return tiff_msg[0] ? tiff_msg : "no detail from libtiff";
}

static void tiff_closep(TIFF **t) {
        if (*t)
                TIFFClose(*t);
}

static const char *sample_format_name(uint16_t format) {
        switch (format) {
        case SAMPLEFORMAT_UINT:         return "unsigned integer";
        case SAMPLEFORMAT_INT:          return "signed integer";
        case SAMPLEFORMAT_IEEEFP:       return "IEEE float";
        case SAMPLEFORMAT_VOID:         return "untyped";
        }
        return "complex or unknown";
}

/* Checks the layout against what imp_image can hold; fills channels and type. */
static int tiff_layout(TIFF *tif, const char *path, int *ret_channels, enum imp_pixel_type *ret_type,
                       struct imp_error *err) {
        uint16_t spp = 1, bps = 1, format = SAMPLEFORMAT_UINT, planar = PLANARCONFIG_CONTIG;
        uint16_t photometric = PHOTOMETRIC_MINISBLACK;

        TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &spp);
        TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &bps);
        TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &format);
        TIFFGetFieldDefaulted(tif, TIFFTAG_PLANARCONFIG, &planar);
        TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &photometric);

        if (spp < 1 || spp > 4)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported TIFF layout: %u samples per "
                                     "pixel (expected 1 to 4)", path, spp);
        if (format == SAMPLEFORMAT_IEEEFP && bps == 32)
                *ret_type = IMP_PIX_F32;
        else if (format == SAMPLEFORMAT_UINT && bps == 8)
                *ret_type = IMP_PIX_U8;
        else if (format == SAMPLEFORMAT_UINT && bps == 16)
                *ret_type = IMP_PIX_U16;
        else
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported TIFF layout: %u bits per "
                                     "sample (expected 8, 16 or 32-bit float; sample format is %s)",
                                     path, bps, sample_format_name(format));
        if (planar != PLANARCONFIG_CONTIG && spp > 1)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported TIFF layout: separate "
                                     "planes (expected contiguous samples)", path);
        if (TIFFIsTiled(tif))
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported TIFF layout: tiled "
                                     "(expected strips)", path);
        if (photometric != PHOTOMETRIC_MINISBLACK && photometric != PHOTOMETRIC_RGB)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported TIFF layout: photometric "
                                     "interpretation %u (expected min-is-black or RGB)", path,
                                     photometric);
        *ret_channels = spp;
        return 0;
}

/* Decodes into *io when it has the file's layout (width, height, channels, type), else into
 * a new image that replaces it. */
static int tiff_read_pixels(TIFF *tif, const char *path, struct imp_image **io, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        uint32_t width = 0, height = 0;
        enum imp_pixel_type type = IMP_PIX_U8;
        int channels = 0, r;

        if (!TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &width) ||
            !TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &height))
                return imp_error_set(err, -EBADMSG, "%s: TIFF without image size", path);
        r = tiff_layout(tif, path, &channels, &type, err);
        if (r < 0)
                return r;
        if (width > IMP_IMAGE_MAX_SIDE || height > IMP_IMAGE_MAX_SIDE)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: TIFF image of %ux%u pixels is too large "
                                     "(expected at most %d per side)", path, width, height,
                                     IMP_IMAGE_MAX_SIDE);
        struct imp_image *old = *io;
        if (old && old->width == (int) width && old->height == (int) height && old->channels == channels &&
            old->type == type)
                img = TAKE_PTR(*io);   /* every row is overwritten below */
        else
                r = imp_image_new((int) width, (int) height, channels, type, &img);
        if (r == -EINVAL)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: TIFF image too large (expected at "
                                     "most %zu bytes of pixels)", path, IMP_IMAGE_MAX_BYTES);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot allocate a %ux%u image: %s", path,
                                     width, height, strerror(-r));
        if ((uint64_t) TIFFScanlineSize64(tif) != img->stride)
                return imp_error_set(err, -EBADMSG, "%s: TIFF scanline of %" PRIu64 " bytes "
                                     "(expected %zu)", path, (uint64_t) TIFFScanlineSize64(tif),
                                     img->stride);
        for (uint32_t y = 0; y < height; y++)
                if (TIFFReadScanline(tif, imp_image_row(img, (int) y), y, 0) < 0)
                        return imp_error_set(err, -EBADMSG, "%s: truncated or corrupt TIFF data "
                                             "at row %u: %s", path, y, tiff_last_error());
        imp_image_free(*io);
        *io = TAKE_PTR(img);
        return 0;
}

int imp_tiff_read(const char *path, struct imp_image **ret, char **ret_description,
                  struct imp_error *err) {
        if (!ret)
                return imp_error_set(err, -EINVAL, "imp_tiff_read: no path or result given");
        struct imp_image *img = NULL;
        int r = imp_tiff_read_reuse(path, &img, ret_description, err);
        if (r < 0) {
                imp_image_free(img);
                return r;
        }
        *ret = img;
        return 0;
}

int imp_tiff_read_reuse(const char *path, struct imp_image **io, char **ret_description,
                        struct imp_error *err) {
        _cleanup_(tiff_closep) TIFF *tif = NULL;
        _cleanup_free_ char *description = NULL;
        _cleanup_close_ int fd = -1;
        struct stat st;
        int r;

        if (!path || !io)
                return imp_error_set(err, -EINVAL, "imp_tiff_read: no path or result given");
        fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0 || fstat(fd, &st) < 0) {
                r = negative_errno();
                return imp_error_set(err, r, "%s: cannot open TIFF file: %s", path, strerror(-r));
        }
        if (st.st_size == 0)
                return imp_error_set(err, -EBADMSG, "%s: empty file (expected a TIFF image)", path);

        tiff_begin();
        tif = TIFFFdOpen(fd, path, "r");
        if (!tif)
                return imp_error_set(err, -EBADMSG, "%s: not a valid TIFF file: %s", path,
                                     tiff_last_error());
        fd = -1;        /* TIFFClose() closes it now */

        r = tiff_read_pixels(tif, path, io, err);
        if (r < 0)
                return r;
        if (ret_description) {
                const char *d = NULL;
                if (TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &d) && d) {
                        description = strdup(d);
                        if (!description)
                                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
                }
                *ret_description = TAKE_PTR(description);
        }
        return 0;
}

static int tiff_set_layout(TIFF *tif, const struct imp_image *img, const char *description, bool fast) {
        static const uint16_t alpha[] = { EXTRASAMPLE_UNASSALPHA };
        uint16_t bps = (uint16_t) (8 * imp_pixel_type_size(img->type));
        uint16_t format = img->type == IMP_PIX_F32 ? SAMPLEFORMAT_IEEEFP : SAMPLEFORMAT_UINT;
        uint16_t predictor = img->type == IMP_PIX_F32 ? PREDICTOR_FLOATINGPOINT : PREDICTOR_HORIZONTAL;
        bool ok = true;

        ok = ok && TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, (uint32_t) img->width);
        ok = ok && TIFFSetField(tif, TIFFTAG_IMAGELENGTH, (uint32_t) img->height);
        ok = ok && TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, (uint16_t) img->channels);
        ok = ok && TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, bps);
        ok = ok && TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, format);
        ok = ok && TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
        ok = ok && TIFFSetField(tif, TIFFTAG_PHOTOMETRIC,
                                img->channels >= 3 ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK);
        if (img->channels == 2 || img->channels == 4)
                ok = ok && TIFFSetField(tif, TIFFTAG_EXTRASAMPLES, (uint16_t) 1, alpha);
        /* fast (frames as they are captured): Zstandard level 1, about 3x less CPU than
         * deflate level 1 for files within ~1 % of its size (docs/bench-capture.md),
         * when this libtiff has it. */
        bool zstd = fast && TIFFIsCODECConfigured(COMPRESSION_ZSTD);
        ok = ok && TIFFSetField(tif, TIFFTAG_COMPRESSION, zstd ? COMPRESSION_ZSTD : COMPRESSION_ADOBE_DEFLATE);
        ok = ok && TIFFSetField(tif, TIFFTAG_PREDICTOR, predictor);
        /* Deflate level 1: 2-3x less CPU than the default 6 and, after the predictor, files
         * within a few % of its size (issue #7: encoding was most of impastod's CPU/frame). */
        if (zstd)
                ok = ok && TIFFSetField(tif, TIFFTAG_ZSTD_LEVEL, 1);
        else
                ok = ok && TIFFSetField(tif, TIFFTAG_ZIPQUALITY, 1);
        /* Strips of about 64 KiB (256 KiB for frames: fewer Zstandard frames, a little less
         * CPU): written whole (tiff_write_pixels), 8x fewer than libtiff's 8 KiB default,
         * so fewer write/seek calls per frame. */
        size_t row_bytes = (size_t) img->width * (size_t) img->channels * imp_pixel_type_size(img->type);
        ok = ok && TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP,
                                (uint32_t) IMP_MAX((size_t) 1, (size_t) (fast ? 262144 : 65536) / IMP_MAX(row_bytes, (size_t) 1)));
        ok = ok && TIFFSetField(tif, TIFFTAG_SOFTWARE, "impasto");
        if (description)
                ok = ok && TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, description);
        return ok ? 0 : -EINVAL;
}

/* After a failed libtiff write: a full store is said as such (ENOSPC, EDQUOT), not as EIO. */
static int tiff_write_errno(void) {
        return errno == ENOSPC || errno == EDQUOT ? -errno : -EIO;
}

/* Rows [y, y + n) of an integer image into `out` through TIFF's horizontal predictor
 * (Predictor 2: each sample minus the one `channels` before it in the row, modulo 2^bits). */
static void predict_rows(const struct imp_image *img, int y, int n, uint8_t *out) {
        size_t w = (size_t) img->width * (size_t) img->channels, c = (size_t) img->channels;
        for (int k = 0; k < n; k++) {
                if (img->type == IMP_PIX_U16) {
                        const uint16_t *in = imp_image_row(img, y + k);
                        uint16_t *o = (uint16_t *) (void *) out + (size_t) k * w;
                        memcpy(o, in, c * sizeof *o);
                        for (size_t x = c; x < w; x++)
                                o[x] = (uint16_t) (in[x] - in[x - c]);
                } else {
                        const uint8_t *in = imp_image_row(img, y + k);
                        uint8_t *o = out + (size_t) k * w;
                        memcpy(o, in, c);
                        for (size_t x = c; x < w; x++)
                                o[x] = (uint8_t) (in[x] - in[x - c]);
                }
        }
}

/* The fast path for integer samples: predictor and Zstandard level 1 done here, one call
 * each per strip, and the strip written raw. The file is the same as libtiff's own
 * encoder would write (Compression ZSTD, Predictor 2, one Zstandard frame per strip) but
 * without its copy of each strip and its streaming encoder: about half the CPU
 * (bench/bench-tiff.c). */
static pthread_key_t cctx_key;

static void cctx_free(void *p) {
        ZSTD_freeCCtx(p);
}

static void cctx_key_once(void) {
        (void) pthread_key_create(&cctx_key, cctx_free);
}

/* One compression context per thread, kept: a new one per frame would allocate and fault
 * in its tables (about a MiB at level 1) every time. Freed when the thread exits. */
static ZSTD_CCtx *thread_cctx(void) {
        static pthread_once_t once = PTHREAD_ONCE_INIT;
        pthread_once(&once, cctx_key_once);
        ZSTD_CCtx *c = pthread_getspecific(cctx_key);
        if (!c && (c = ZSTD_createCCtx()) && pthread_setspecific(cctx_key, c) != 0) {
                ZSTD_freeCCtx(c);
                c = NULL;
        }
        return c;
}

static int write_strips_zstd(TIFF *tif, const char *path, const struct imp_image *img, uint32_t rows,
                             size_t row_bytes, uint8_t *strip, struct imp_error *err) {
        size_t cap = ZSTD_compressBound(row_bytes * rows);
        _cleanup_free_ uint8_t *packed = malloc(cap);
        ZSTD_CCtx *cctx = thread_cctx();
        int r = 0;
        if (!packed || !cctx)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        for (int y = 0; y < img->height && r == 0; y += (int) rows) {
                int n = IMP_MIN((int) rows, img->height - y);
                predict_rows(img, y, n, strip);
                size_t z = ZSTD_compressCCtx(cctx, packed, cap, strip, (size_t) n * row_bytes, 1);
                if (ZSTD_isError(z))
                        r = imp_error_set(err, -EIO, "%s: Zstandard: %s", path, ZSTD_getErrorName(z));
                else if (TIFFWriteRawStrip(tif, TIFFComputeStrip(tif, (uint32_t) y, 0), packed, (tmsize_t) z) < 0) {
                        r = tiff_write_errno();
                        r = imp_error_set(err, r, "%s: cannot write TIFF rows %d-%d: %s (%s)", path, y, y + n - 1,
                                          tiff_last_error(), strerror(-r));
                }
        }
        return r;
}

static int tiff_write_pixels(TIFF *tif, const char *path, const struct imp_image *img,
                             const char *description, bool fast, struct imp_error *err) {
        if (tiff_set_layout(tif, img, description, fast) < 0)
                return imp_error_set(err, -EINVAL, "%s: cannot set TIFF tags: %s", path,
                                     tiff_last_error());
        /* Whole strips, so that libtiff compresses each in one call (with libdeflate when it
         * has it, much faster than zlib fed row by row). The horizontal predictor encodes in
         * place: each strip goes through a copy. */
        uint32_t rows = 1;
        TIFFGetField(tif, TIFFTAG_ROWSPERSTRIP, &rows);
        size_t row_bytes = (size_t) img->width * (size_t) img->channels * imp_pixel_type_size(img->type);
        _cleanup_free_ uint8_t *strip = malloc(row_bytes * rows);
        if (!strip)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        uint16_t compression = 0;
        TIFFGetField(tif, TIFFTAG_COMPRESSION, &compression);
        if (compression == COMPRESSION_ZSTD && img->type != IMP_PIX_F32) {
                int r = write_strips_zstd(tif, path, img, rows, row_bytes, strip, err);
                if (r < 0)
                        return r;
                goto flush;
        }
        for (int y = 0; y < img->height; y += (int) rows) {
                int n = IMP_MIN((int) rows, img->height - y);
                for (int k = 0; k < n; k++)
                        memcpy(strip + (size_t) k * row_bytes, imp_image_row(img, y + k), row_bytes);
                if (TIFFWriteEncodedStrip(tif, TIFFComputeStrip(tif, (uint32_t) y, 0), strip,
                                          (tmsize_t) ((size_t) n * row_bytes)) < 0) {
                        int r = tiff_write_errno();
                        return imp_error_set(err, r, "%s: cannot write TIFF rows %d-%d: %s (%s)", path, y,
                                             y + n - 1, tiff_last_error(), strerror(-r));
                }
        }
flush:
        if (!TIFFFlush(tif)) {
                int r = tiff_write_errno();
                return imp_error_set(err, r, "%s: cannot write TIFF file: %s (%s)", path,
                                     tiff_last_error(), strerror(-r));
        }
        return 0;
}

static int tiff_write(const char *path, const struct imp_image *img, const char *description, bool fast,
                      struct imp_error *err) {
        TIFF *tif;
        int fd, r;

        if (!path || !img)
                return imp_error_set(err, -EINVAL, "imp_tiff_write: no path or image given");
        if (img->channels < 1 || img->channels > 4)
                return imp_error_set(err, -EINVAL, "%s: cannot store %d channels as TIFF "
                                     "(expected 1 to 4)", path, img->channels);
        fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
        if (fd < 0) {
                r = negative_errno();
                return imp_error_set(err, r, "%s: cannot create TIFF file: %s", path, strerror(-r));
        }
        tiff_begin();
        tif = TIFFFdOpen(fd, path, "w");
        if (!tif) {
                r = tiff_write_errno();
                close(fd);
                (void) unlink(path);
                return imp_error_set(err, r, "%s: cannot start TIFF file: %s (%s)", path,
                                     tiff_last_error(), strerror(-r));
        }
        r = tiff_write_pixels(tif, path, img, description, fast, err);
        TIFFClose(tif);         /* also closes fd */
        if (r < 0)
                (void) unlink(path);
        return r;
}

int imp_tiff_write(const char *path, const struct imp_image *img, const char *description,
                   struct imp_error *err) {
        return tiff_write(path, img, description, false, err);
}

int imp_tiff_write_fast(const char *path, const struct imp_image *img, const char *description,
                        struct imp_error *err) {
        return tiff_write(path, img, description, true, err);
}
