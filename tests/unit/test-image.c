/* Tests of the image type and its file formats: allocation limits, copies, conversion,
 * and exact round trips through PNG (8/16-bit), TIFF (u8/u16/f32 + description) and
 * OpenEXR (FLOAT bit-exact, HALF within half precision), odd sizes, 1-5 channels. */
#include <openexr.h>
#include <png.h>
#include <tiffio.h>
#include <zlib.h>
#include "image.h"
#include "test.h"

static const char *tmp_path(const char *name) {
        static char buf[4][512];
        static int i;
        i = (i + 1) % 4;
        snprintf(buf[i], sizeof buf[i], "%s/%s", test_tmpdir(), name);
        return buf[i];
}

/* Deterministic sample pattern covering 0 and the type's maximum. */
static void fill_pattern(struct imp_image *img, unsigned seed) {
        uint32_t s = seed * 2654435761u + 1;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        for (int c = 0; c < img->channels; c++) {
                                s = s * 1664525u + 1013904223u;
                                bool corner = (x + y + c) % 7 == 0, other = (x + y + c) % 7 == 1;
                                switch (img->type) {
                                case IMP_PIX_U8:
                                        imp_image_u8(img, x, y)[c] = corner ? 255 : other ? 0 : (uint8_t) (s >> 24);
                                        break;
                                case IMP_PIX_U16:
                                        imp_image_u16(img, x, y)[c] = corner ? 65535 : other ? 0 : (uint16_t) (s >> 16);
                                        break;
                                case IMP_PIX_F32: {
                                        /* wide dynamic range, both signs, odd mantissas */
                                        float v = ((float) (s >> 8) / 16777216.0f - 0.5f) *
                                                  powf(10.0f, (float) ((int) (s % 13) - 6));
                                        imp_image_f32(img, x, y)[c] = corner ? 1e-30f : v;
                                        break;
                                }
                                }
                        }
}

static bool same_pixels(const struct imp_image *a, const struct imp_image *b) {
        if (a->width != b->width || a->height != b->height || a->channels != b->channels ||
            a->type != b->type)
                return false;
        size_t row = (size_t) a->width * a->channels * imp_pixel_type_size(a->type);
        for (int y = 0; y < a->height; y++)
                if (memcmp(imp_image_row(a, y), imp_image_row(b, y), row) != 0)
                        return false;
        return true;
}

static void test_new_and_helpers(void) {
        struct imp_image *sentinel = (struct imp_image *) (uintptr_t) 0x1, *img = sentinel;

        CHECK_ERR(imp_image_new(0, 5, 1, IMP_PIX_U8, &img), -EINVAL);
        CHECK_ERR(imp_image_new(5, -1, 1, IMP_PIX_U8, &img), -EINVAL);
        CHECK_ERR(imp_image_new(5, 5, 0, IMP_PIX_U8, &img), -EINVAL);
        CHECK_ERR(imp_image_new(IMP_IMAGE_MAX_SIDE + 1, 1, 1, IMP_PIX_U8, &img), -EINVAL);
        CHECK_ERR(imp_image_new(IMP_IMAGE_MAX_SIDE, IMP_IMAGE_MAX_SIDE, 4, IMP_PIX_F32, &img), -EINVAL);
        CHECK_ERR(imp_image_new(5, 5, 1, (enum imp_pixel_type) 42, &img), -EINVAL);
        CHECK(img == sentinel);         /* untouched on failure */

        _cleanup_image_ struct imp_image *a = NULL, *b = NULL, *f = NULL;
        CHECK_OK(imp_image_new(7, 3, 3, IMP_PIX_U16, &a));
        if (!a)
                return;
        CHECK_INT_EQ(a->stride, 7 * 3 * 2);
        CHECK(imp_image_get(a, 6, 2, 2) == 0.0);        /* zeroed */
        fill_pattern(a, 1);
        imp_image_u16(a, 6, 2)[2] = 65535;
        imp_image_u16(a, 0, 1)[1] = 1234;
        CHECK(imp_image_get(a, 6, 2, 2) == 65535.0);
        CHECK(imp_image_get(a, 0, 1, 1) == 1234.0);

        CHECK_OK(imp_image_dup(a, &b));
        CHECK(b && b->data != a->data && same_pixels(a, b));
        CHECK_OK(imp_image_to_f32(a, &f));
        CHECK(f && f->type == IMP_PIX_F32 && f->channels == 3);
        bool all = f != NULL;
        for (int y = 0; all && y < 3; y++)
                for (int x = 0; x < 7; x++)
                        for (int c = 0; c < 3; c++)
                                all = all && imp_image_f32(f, x, y)[c] == imp_image_u16(a, x, y)[c];
        CHECK(all);
        CHECK(f && imp_image_f32(f, 6, 2)[2] == 65535.0f);

        _cleanup_image_ struct imp_image *u8 = NULL, *u8f = NULL;
        CHECK_OK(imp_image_new(2, 1, 1, IMP_PIX_U8, &u8));
        imp_image_u8(u8, 1, 0)[0] = 255;
        CHECK_OK(imp_image_to_f32(u8, &u8f));
        CHECK(u8f && imp_image_f32(u8f, 1, 0)[0] == 255.0f && imp_image_f32(u8f, 0, 0)[0] == 0.0f);

        char *names[] = { "A", "height", "nx", NULL };
        CHECK_INT_EQ(imp_image_channel_index(names, "nx"), 2);
        CHECK_INT_EQ(imp_image_channel_index(names, "A"), 0);
        CHECK_ERR(imp_image_channel_index(names, "ny"), -ENOENT);
        CHECK_STR_EQ(imp_pixel_type_name(IMP_PIX_U16), "u16");
        CHECK_INT_EQ(imp_pixel_type_size(IMP_PIX_F32), 4);
}

static void test_png_roundtrip(void) {
        static const int sizes[][2] = { { 1, 1 }, { 7, 3 }, { 1001, 17 } };
        for (int t = 0; t < 2; t++)
                for (int ch = 1; ch <= 4; ch++)
                        for (size_t s = 0; s < ARRAY_SIZE(sizes); s++) {
                                enum imp_pixel_type type = t ? IMP_PIX_U16 : IMP_PIX_U8;
                                _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                                struct imp_error err = { 0 };
                                const char *p = tmp_path("rt.png");
                                CHECK_OK(imp_image_new(sizes[s][0], sizes[s][1], ch, type, &a));
                                fill_pattern(a, (unsigned) (ch + 10 * s));
                                CHECK_OK(imp_png_write(p, a, &err));
                                CHECK_OK(imp_png_read(p, &b, &err));
                                CHECK_MSG(b && same_pixels(a, b), "PNG %s %d channels %dx%d differs (%s)",
                                          imp_pixel_type_name(type), ch, sizes[s][0], sizes[s][1], err.msg);
                        }
}

/* Reads a PNG with plain libpng, no transforms: the raw (big-endian) sample bytes. */
static void test_png_16bit_is_big_endian(void) {
        _cleanup_image_ struct imp_image *a = NULL;
        const char *p = tmp_path("be.png");
        CHECK_OK(imp_image_new(2, 1, 1, IMP_PIX_U16, &a));
        imp_image_u16(a, 0, 0)[0] = 0x1234;
        imp_image_u16(a, 1, 0)[0] = 0xfe01;
        CHECK_OK(imp_png_write(p, a, NULL));

        FILE *f = fopen(p, "rb");
        CHECK(f != NULL);
        if (!f)
                return;
        png_structp png = png_create_read_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
        png_infop info = png_create_info_struct(png);
        png_init_io(png, f);
        png_read_png(png, info, PNG_TRANSFORM_IDENTITY, NULL);
        png_bytepp rows = png_get_rows(png, info);
        CHECK_INT_EQ(png_get_bit_depth(png, info), 16);
        CHECK_INT_EQ(png_get_color_type(png, info), PNG_COLOR_TYPE_GRAY);
        CHECK_INT_EQ(rows[0][0], 0x12);
        CHECK_INT_EQ(rows[0][1], 0x34);
        CHECK_INT_EQ(rows[0][2], 0xfe);
        CHECK_INT_EQ(rows[0][3], 0x01);
        png_destroy_read_struct(&png, &info, NULL);
        fclose(f);
}

/* A palette PNG (written with plain libpng) is read as RGB. */
static void test_png_palette(void) {
        const char *p = tmp_path("palette.png");
        FILE *f = fopen(p, "wb");
        CHECK(f != NULL);
        if (!f)
                return;
        png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
        png_infop info = png_create_info_struct(png);
        png_color pal[2] = { { 10, 20, 30 }, { 200, 150, 100 } };
        png_init_io(png, f);
        png_set_IHDR(png, info, 3, 1, 8, PNG_COLOR_TYPE_PALETTE, PNG_INTERLACE_NONE,
                     PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
        png_set_PLTE(png, info, pal, 2);
        png_write_info(png, info);
        png_byte row[3] = { 0, 1, 1 };
        png_write_row(png, row);
        png_write_end(png, info);
        png_destroy_write_struct(&png, &info);
        fclose(f);

        _cleanup_image_ struct imp_image *img = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_png_read(p, &img, &err));
        CHECK(img && img->channels == 3 && img->type == IMP_PIX_U8);
        if (!img)
                return;
        CHECK_INT_EQ(imp_image_u8(img, 0, 0)[2], 30);
        CHECK_INT_EQ(imp_image_u8(img, 2, 0)[0], 200);
        CHECK_INT_EQ(imp_image_u8(img, 1, 0)[1], 150);
}

static void test_tiff_roundtrip(void) {
        static const int sizes[][2] = { { 1, 1 }, { 7, 3 }, { 1001, 17 } };
        static const enum imp_pixel_type types[] = { IMP_PIX_U8, IMP_PIX_U16, IMP_PIX_F32 };
        for (size_t t = 0; t < ARRAY_SIZE(types); t++)
                for (int ch = 1; ch <= 4; ch++)
                        for (size_t s = 0; s < 2 * ARRAY_SIZE(sizes); s++) {
                                /* the second round: imp_tiff_write_fast, the capture frames' writer */
                                bool fast = s >= ARRAY_SIZE(sizes);
                                _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                                static char unset[] = "unset";
                                char *desc = unset;
                                struct imp_error err = { 0 };
                                const char *p = tmp_path("rt.tiff");
                                const int *sz = sizes[s % ARRAY_SIZE(sizes)];
                                CHECK_OK(imp_image_new(sz[0], sz[1], ch, types[t], &a));
                                fill_pattern(a, (unsigned) (ch + 10 * s + 100 * t));
                                CHECK_OK(fast ? imp_tiff_write_fast(p, a, NULL, &err) : imp_tiff_write(p, a, NULL, &err));
                                CHECK_OK(imp_tiff_read(p, &b, &desc, &err));
                                CHECK(desc == NULL);
                                if (desc != unset)
                                        free(desc);
                                CHECK_MSG(b && same_pixels(a, b), "TIFF%s %s %d channels %dx%d differs (%s)",
                                          fast ? " (fast)" : "", imp_pixel_type_name(types[t]), ch, sz[0], sz[1],
                                          err.msg);
                        }
}

/* imp_tiff_read_reuse: into an image of the file's layout (junk-filled) it decodes in place
 * (the same image, its bytes those imp_tiff_read returns); an image of another layout is
 * replaced by a new one holding the same pixels; both the capture writer's frames (Zstandard,
 * predictor) and plain ones, u16 and f32. */
static void test_tiff_read_reuse(void) {
        static const enum imp_pixel_type types[] = { IMP_PIX_U16, IMP_PIX_F32 };
        for (size_t t = 0; t < ARRAY_SIZE(types); t++)
                for (int fast = 0; fast < 2; fast++) {
                        if (fast && types[t] != IMP_PIX_U16)
                                continue;
                        _cleanup_image_ struct imp_image *a = NULL, *want = NULL, *io = NULL, *wrong = NULL;
                        struct imp_error err = { 0 };
                        const char *p = tmp_path("reuse.tiff");
                        CHECK_OK(imp_image_new(301, 77, 1, types[t], &a));
                        fill_pattern(a, 31u + (unsigned) t);
                        CHECK_OK(fast ? imp_tiff_write_fast(p, a, NULL, &err) : imp_tiff_write(p, a, NULL, &err));
                        CHECK_OK(imp_tiff_read(p, &want, NULL, &err));
                        CHECK_OK(imp_image_new(301, 77, 1, types[t], &io));
                        memset(io->data, 0xa5, io->stride * (size_t) io->height);
                        const struct imp_image *before = io;
                        CHECK_OK(imp_tiff_read_reuse(p, &io, NULL, &err));
                        CHECK_MSG(io == before, "reuse: a new image was allocated for the same layout");
                        CHECK_MSG(same_pixels(io, want) && same_pixels(io, a), "reuse (%s, fast %d): pixels differ",
                                  imp_pixel_type_name(types[t]), fast);
                        CHECK_OK(imp_image_new(300, 77, 1, types[t], &wrong));
                        CHECK_OK(imp_tiff_read_reuse(p, &wrong, NULL, &err));
                        CHECK(wrong && wrong->width == 301 && same_pixels(wrong, want));
                }
}

/* Frames as the capture set stores them (imp_tiff_write_fast): another reader sees Zstandard
 * and the horizontal predictor, and libtiff's own decoder gives back every sample of a
 * camera-like frame (ramps, noise, full scale, several strips). */
static void test_tiff_fast_frame(void) {
        if (!TIFFIsCODECConfigured(COMPRESSION_ZSTD))
                return;         /* the writer falls back to deflate: covered above */
        _cleanup_image_ struct imp_image *a = NULL;
        struct imp_error err = { 0 };
        const char *p = tmp_path("frame.tif");
        CHECK_OK(imp_image_new(640, 480, 1, IMP_PIX_U16, &a));
        uint32_t st = 12345;
        for (int y = 0; y < 480; y++)
                for (int x = 0; x < 640; x++) {
                        st = st * 1664525u + 1013904223u;
                        int v = 20 * x + 7 * y + (int) (st >> 26) - 32;
                        imp_image_u16(a, x, y)[0] = (uint16_t) (x == 5 ? 65535 : v < 0 ? 0 : v > 65535 ? 65535 : v);
                }
        CHECK_OK(imp_tiff_write_fast(p, a, "{\"seq\":1}", &err));
        TIFF *tif = TIFFOpen(p, "r");
        CHECK(tif != NULL);
        if (!tif)
                return;
        uint16_t comp = 0, pred = 0;
        CHECK(TIFFGetField(tif, TIFFTAG_COMPRESSION, &comp));
        CHECK(TIFFGetField(tif, TIFFTAG_PREDICTOR, &pred));
        CHECK_INT_EQ(comp, COMPRESSION_ZSTD);
        CHECK_INT_EQ(pred, PREDICTOR_HORIZONTAL);
        CHECK(TIFFNumberOfStrips(tif) > 1);
        _cleanup_free_ uint16_t *row = malloc((size_t) TIFFScanlineSize(tif));
        int bad = 0;
        for (uint32_t y = 0; row && y < 480; y++) {
                if (TIFFReadScanline(tif, row, y, 0) < 0) {
                        bad++;
                        continue;
                }
                for (int x = 0; x < 640; x++)
                        bad += row[x] != imp_image_u16(a, x, (int) y)[0];
        }
        CHECK(row != NULL);
        CHECK_INT_EQ(bad, 0);
        TIFFClose(tif);
}

static void test_tiff_description(void) {
        static const char json[] = "{\"step\":3,\"camera\":\"cam0\",\"exposure_us\":12500,\"gain_db\":1.5}";
        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
        _cleanup_free_ char *desc = NULL;
        struct imp_error err = { 0 };
        const char *p = tmp_path("desc.tif");
        CHECK_OK(imp_image_new(5, 4, 1, IMP_PIX_U16, &a));
        fill_pattern(a, 7);
        CHECK_OK(imp_tiff_write(p, a, json, &err));
        CHECK_OK(imp_tiff_read(p, &b, &desc, &err));
        CHECK_STR_EQ(desc, json);
        CHECK(b && same_pixels(a, b));

        /* The tags other readers see. */
        TIFF *tif = TIFFOpen(p, "r");
        CHECK(tif != NULL);
        if (!tif)
                return;
        const char *sw = NULL;
        uint16_t bps = 0, spp = 0;
        CHECK(TIFFGetField(tif, TIFFTAG_SOFTWARE, &sw));
        CHECK_STR_EQ(sw, "impasto");
        TIFFGetField(tif, TIFFTAG_BITSPERSAMPLE, &bps);
        TIFFGetField(tif, TIFFTAG_SAMPLESPERPIXEL, &spp);
        CHECK_INT_EQ(bps, 16);
        CHECK_INT_EQ(spp, 1);
        CHECK(!TIFFIsTiled(tif));
        TIFFClose(tif);
}

static const char *const exr_names[] = { "R", "G", "B", "A", "height" };

/* Checks b (read back, channels in file order with names) against a (written with
 * exr_names[c] for channel c); tol_rel 0 means bit-exact. */
static bool exr_matches(const struct imp_image *a, const struct imp_image *b, char **names,
                        double tol_rel, bool half_exact) {
        if (!b || !names || b->width != a->width || b->height != a->height ||
            b->channels != a->channels || b->type != IMP_PIX_F32)
                return false;
        for (int c = 0; c < a->channels; c++) {
                int bc = imp_image_channel_index(names, exr_names[c]);
                if (bc < 0)
                        return false;
                for (int y = 0; y < a->height; y++)
                        for (int x = 0; x < a->width; x++) {
                                float va = imp_image_f32(a, x, y)[c], vb = imp_image_f32(b, x, y)[bc];
                                if (tol_rel == 0 || half_exact) {
                                        if (memcmp(&va, &vb, sizeof va) != 0)
                                                return false;
                                } else if (!(fabs(va - vb) <= tol_rel * fabs(va)))
                                        return false;
                        }
        }
        return true;
}

static void test_exr_float_roundtrip(void) {
        static const int sizes[][2] = { { 1, 1 }, { 7, 3 }, { 1001, 17 } };
        for (int ch = 1; ch <= 5; ch++)
                for (size_t s = 0; s < ARRAY_SIZE(sizes); s++) {
                        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                        char **names = NULL;
                        struct imp_error err = { 0 };
                        const char *p = tmp_path("rt.exr");
                        CHECK_OK(imp_image_new(sizes[s][0], sizes[s][1], ch, IMP_PIX_F32, &a));
                        fill_pattern(a, (unsigned) (ch + 10 * s));
                        CHECK_OK(imp_exr_write(p, a, exr_names, false, &err));
                        CHECK_OK(imp_exr_read(p, &b, &names, &err));
                        CHECK_MSG(exr_matches(a, b, names, 0, false),
                                  "EXR float %d channels %dx%d differs (%s)", ch, sizes[s][0],
                                  sizes[s][1], err.msg);
                        if (names) {
                                int n = 0;
                                while (names[n])
                                        n++;
                                CHECK_INT_EQ(n, ch);
                        }
                        imp_strv_free(names);
                }
}

/* The whole file's bytes (malloc'd) in *ret, its size returned; 0 when unreadable. */
static size_t file_bytes(const char *path, uint8_t **ret) {
        *ret = NULL;
        FILE *f = fopen(path, "rb");
        if (!f)
                return 0;
        size_t n = 0, cap = 0;
        uint8_t *buf = NULL;
        for (;;) {
                if (n == cap) {
                        uint8_t *nb = realloc(buf, cap = cap ? 2 * cap : 1 << 16);
                        if (!nb)
                                break;
                        buf = nb;
                }
                size_t got = fread(buf + n, 1, cap - n, f);
                if (got == 0)
                        break;
                n += got;
        }
        fclose(f);
        *ret = buf;
        return n;
}

/* The PNG's IDAT chunks concatenated (the zlib stream); 0 when the file is not a PNG. */
static size_t png_idat(const uint8_t *buf, size_t n, uint8_t *out, size_t cap) {
        size_t pos = 8, got = 0;
        while (pos + 12 <= n) {
                size_t len = (size_t) buf[pos] << 24 | (size_t) buf[pos + 1] << 16 | (size_t) buf[pos + 2] << 8 | buf[pos + 3];
                if (pos + 12 + len > n)
                        return 0;
                if (!memcmp(buf + pos + 4, "IDAT", 4) && got + len <= cap) {
                        memcpy(out + got, buf + pos + 8, len);
                        got += len;
                }
                pos += 12 + len;
        }
        return got;
}

/* imp_png_write_fast: the same pixels back (8/16-bit, 1-4 channels), every row Sub-filtered
 * (filter byte 1) and the zlib stream marked as a fast level (FLEVEL 1: levels 2-5), where
 * libpng's defaults (imp_png_write) give FLEVEL 2 and mixed filters on this pattern. */
static void test_png_fast(void) {
        for (int t = 0; t < 2; t++)
                for (int ch = 1; ch <= 4; ch++) {
                        enum imp_pixel_type type = t ? IMP_PIX_U16 : IMP_PIX_U8;
                        int w = 301, h = 23, row = 1 + w * ch * (t ? 2 : 1);
                        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                        struct imp_error err = { 0 };
                        const char *p = tmp_path("fast.png");
                        CHECK_OK(imp_image_new(w, h, ch, type, &a));
                        fill_pattern(a, (unsigned) (ch + 3 * t));
                        for (int y = 0; y < h / 2; y++)   /* smooth rows, where Sub is not what the default picks */
                                for (int x = 0; x < w; x++)
                                        for (int c = 0; c < ch; c++) {
                                                if (t)
                                                        imp_image_u16(a, x, y)[c] = (uint16_t) (x * 100 + c);
                                                else
                                                        imp_image_u8(a, x, y)[c] = (uint8_t) (y * 7 + c);
                                        }
                        for (int fast = 0; fast < 2; fast++) {
                                CHECK_OK(fast ? imp_png_write_fast(p, a, &err) : imp_png_write(p, a, &err));
                                CHECK_OK(imp_png_read(p, &b, &err));
                                CHECK_MSG(b && same_pixels(a, b), "PNG (fast %d) %s %d channels differs (%s)", fast,
                                          imp_pixel_type_name(type), ch, err.msg);
                                imp_image_free(b);
                                b = NULL;
                                _cleanup_free_ uint8_t *file = NULL, *z = malloc(1 << 20), *raw = malloc((size_t) row * h);
                                size_t n = file_bytes(p, &file), nz = file && z ? png_idat(file, n, z, 1 << 20) : 0;
                                uLongf n_raw = (uLongf) row * h;
                                CHECK(nz > 2 && raw && uncompress(raw, &n_raw, z, nz) == Z_OK && n_raw == (uLongf) row * h);
                                if (!(nz > 2 && raw && n_raw == (uLongf) row * h))
                                        continue;
                                int flevel = z[1] >> 6, n_sub = 0;
                                for (int y = 0; y < h; y++)
                                        n_sub += raw[(size_t) y * row] == PNG_FILTER_VALUE_SUB;
                                if (fast) {
                                        CHECK_MSG(flevel == 1, "fast PNG: zlib FLEVEL %d, expected 1 (levels 2-5)", flevel);
                                        CHECK_MSG(n_sub == h, "fast PNG: %d of %d rows Sub-filtered", n_sub, h);
                                } else {   /* the assertions above can tell the two writers apart */
                                        CHECK_MSG(flevel == 2 && n_sub < h, "default PNG: FLEVEL %d, %d of %d rows Sub",
                                                  flevel, n_sub, h);
                                }
                        }
                }
}

/* Chunks compressed on several threads (imp_exr_write_threads) give the very file the
 * single-threaded encoder writes, byte for byte, float and half, with more chunks than the
 * writer keeps in flight (64) and a last chunk of fewer lines; the file reads back. */
static void test_exr_threads_same_bytes(void) {
        static const int threads[] = { 2, 3, 8, 0 };
        for (int half = 0; half < 2; half++) {
                _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                struct imp_error err = { 0 };
                char **got_names = NULL;
                CHECK_OK(imp_image_new(53, 16 * 70 + 5, 5, IMP_PIX_F32, &a));
                fill_pattern(a, 7u + (unsigned) half);
                const char *p1 = tmp_path("serial.exr"), *pn = tmp_path("threads.exr");
                CHECK_OK(imp_exr_write_threads(p1, a, exr_names, half, 1, &err));
                _cleanup_free_ uint8_t *want = NULL;
                size_t n_want = file_bytes(p1, &want);
                CHECK(n_want > 1000);
                for (size_t t = 0; t < ARRAY_SIZE(threads); t++) {
                        CHECK_OK(imp_exr_write_threads(pn, a, exr_names, half, threads[t], &err));
                        _cleanup_free_ uint8_t *got = NULL;
                        size_t n_got = file_bytes(pn, &got);
                        CHECK_MSG(n_got == n_want && got && want && !memcmp(got, want, n_want),
                                  "EXR %s on %d threads: %zu bytes, not the serial file's %zu (or they differ)",
                                  half ? "half" : "float", threads[t], n_got, n_want);
                }
                CHECK_OK(imp_exr_read(pn, &b, &got_names, &err));
                if (!half)
                        CHECK_MSG(exr_matches(a, b, got_names, 0, false), "EXR written on threads reads back different (%s)",
                                  err.msg);
                imp_strv_free(got_names);
        }
}

static void fill_half_values(struct imp_image *img, bool representable) {
        uint32_t s = 12345;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        for (int c = 0; c < img->channels; c++) {
                                s = s * 1664525u + 1013904223u;
                                float v;
                                if (representable)      /* 11 significant bits, exponent in range */
                                        v = (float) ((int) (s >> 21) - 1024) * ldexpf(1.0f, (int) (s % 20) - 14);
                                else                    /* arbitrary values in the normal half range */
                                        v = ((float) (s >> 8) / 16777216.0f + 0.1f) *
                                            powf(10.0f, (float) ((int) (s % 6) - 2)) * ((s & 1) ? -1.0f : 1.0f);
                                imp_image_f32(img, x, y)[c] = v;
                        }
}

static void test_exr_half_roundtrip(void) {
        static const int sizes[][2] = { { 1, 1 }, { 7, 3 }, { 1001, 17 } };
        for (int exact = 0; exact < 2; exact++)
                for (int ch = 1; ch <= 5; ch++)
                        for (size_t s = 0; s < ARRAY_SIZE(sizes); s++) {
                                _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                                char **names = NULL;
                                struct imp_error err = { 0 };
                                const char *p = tmp_path("half.exr");
                                CHECK_OK(imp_image_new(sizes[s][0], sizes[s][1], ch, IMP_PIX_F32, &a));
                                fill_half_values(a, exact);
                                CHECK_OK(imp_exr_write(p, a, exr_names, true, &err));
                                CHECK_OK(imp_exr_read(p, &b, &names, &err));
                                /* round to nearest: relative error at most 2^-11 */
                                CHECK_MSG(exr_matches(a, b, names, ldexp(1.0, -11), exact),
                                          "EXR half (%s) %d channels %dx%d differs (%s)",
                                          exact ? "representable" : "rounded", ch, sizes[s][0],
                                          sizes[s][1], err.msg);
                                imp_strv_free(names);
                        }
        /* The test's tolerance is tight enough to see a wrong conversion: 1/3 is not exact. */
        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
        const char *p = tmp_path("third.exr");
        CHECK_OK(imp_image_new(1, 1, 1, IMP_PIX_F32, &a));
        imp_image_f32(a, 0, 0)[0] = 1.0f / 3.0f;
        CHECK_OK(imp_exr_write(p, a, exr_names, true, NULL));
        CHECK_OK(imp_exr_read(p, &b, NULL, NULL));
        CHECK(b && imp_image_f32(b, 0, 0)[0] != 1.0f / 3.0f);
        CHECK(b && fabs(imp_image_f32(b, 0, 0)[0] - 1.0 / 3.0) <= ldexp(1.0 / 3.0, -11));
}

/* The file itself: ZIP, scanline, the requested pixel types, channels named as asked. */
static void test_exr_file_layout(void) {
        static const char *const names[] = { "height", "nx", "ny" };
        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
        char **got = NULL;
        const char *p = tmp_path("layout.exr");
        CHECK_OK(imp_image_new(9, 5, 3, IMP_PIX_F32, &a));
        for (int y = 0; y < 5; y++)
                for (int x = 0; x < 9; x++) {
                        imp_image_f32(a, x, y)[0] = (float) (x + 10 * y);       /* height */
                        imp_image_f32(a, x, y)[1] = -0.25f;                    /* nx */
                        imp_image_f32(a, x, y)[2] = 0.5f;                      /* ny */
                }
        CHECK_OK(imp_exr_write(p, a, names, true, NULL));

        exr_context_t ctxt = NULL;
        exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
        CHECK_INT_EQ(exr_start_read(&ctxt, p, &init), EXR_ERR_SUCCESS);
        if (ctxt) {
                exr_compression_t comp = EXR_COMPRESSION_NONE;
                exr_storage_t storage = EXR_STORAGE_DEEP_TILED;
                const exr_attr_chlist_t *cl = NULL;
                exr_get_compression(ctxt, 0, &comp);
                exr_get_storage(ctxt, 0, &storage);
                exr_get_channels(ctxt, 0, &cl);
                CHECK_INT_EQ(comp, EXR_COMPRESSION_ZIP);
                CHECK_INT_EQ(storage, EXR_STORAGE_SCANLINE);
                CHECK(cl && cl->num_channels == 3);
                for (int c = 0; cl && c < cl->num_channels; c++)
                        CHECK_INT_EQ(cl->entries[c].pixel_type, EXR_PIXEL_HALF);
                exr_finish(&ctxt);
        }

        CHECK_OK(imp_exr_read(p, &b, &got, NULL));
        CHECK(got && got[0] && got[1] && got[2] && !got[3]);
        if (b && got) {
                int h = imp_image_channel_index(got, "height"), ny = imp_image_channel_index(got, "ny");
                CHECK(h >= 0 && ny >= 0);
                if (h >= 0 && ny >= 0) {
                        CHECK(imp_image_f32(b, 8, 4)[h] == 48.0f);
                        CHECK(imp_image_f32(b, 3, 2)[ny] == 0.5f);
                }
        }
        imp_strv_free(got);
}

/* A UINT channel (written directly with the C API) reads as float. */
static void test_exr_uint_channel(void) {
        const char *p = tmp_path("uint.exr");
        enum { W = 5, H = 3 };
        uint32_t px[H][W];
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        px[y][x] = (uint32_t) (x * 1000 + y);
        px[2][4] = 16777216u;    /* 2^24: still exact as float */

        exr_context_t ctxt = NULL;
        exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
        int part = 0;
        CHECK_INT_EQ(exr_start_write(&ctxt, p, EXR_WRITE_FILE_DIRECTLY, &init), EXR_ERR_SUCCESS);
        if (!ctxt)
                return;
        exr_add_part(ctxt, "image", EXR_STORAGE_SCANLINE, &part);
        exr_initialize_required_attr_simple(ctxt, part, W, H, EXR_COMPRESSION_NONE);
        exr_add_channel(ctxt, part, "id", EXR_PIXEL_UINT, EXR_PERCEPTUALLY_LINEAR, 1, 1);
        CHECK_INT_EQ(exr_write_header(ctxt), EXR_ERR_SUCCESS);
        exr_chunk_info_t ci;
        exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
        CHECK_INT_EQ(exr_write_scanline_chunk_info(ctxt, part, 0, &ci), EXR_ERR_SUCCESS);
        CHECK_INT_EQ(exr_encoding_initialize(ctxt, part, &ci, &enc), EXR_ERR_SUCCESS);
        enc.channels[0].encode_from_ptr = (const uint8_t *) &px[ci.start_y][0];
        enc.channels[0].user_pixel_stride = 4;
        enc.channels[0].user_line_stride = W * 4;
        enc.channels[0].user_data_type = EXR_PIXEL_UINT;
        enc.channels[0].user_bytes_per_element = 4;
        CHECK_INT_EQ(exr_encoding_choose_default_routines(ctxt, part, &enc), EXR_ERR_SUCCESS);
        CHECK_INT_EQ(exr_encoding_run(ctxt, part, &enc), EXR_ERR_SUCCESS);
        /* NONE compression: one line per chunk */
        for (int y = 1; y < H; y++) {
                CHECK_INT_EQ(exr_write_scanline_chunk_info(ctxt, part, y, &ci), EXR_ERR_SUCCESS);
                CHECK_INT_EQ(exr_encoding_update(ctxt, part, &ci, &enc), EXR_ERR_SUCCESS);
                enc.channels[0].encode_from_ptr = (const uint8_t *) &px[ci.start_y][0];
                CHECK_INT_EQ(exr_encoding_run(ctxt, part, &enc), EXR_ERR_SUCCESS);
        }
        exr_encoding_destroy(ctxt, &enc);
        CHECK_INT_EQ(exr_finish(&ctxt), EXR_ERR_SUCCESS);

        _cleanup_image_ struct imp_image *b = NULL;
        char **names = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_exr_read(p, &b, &names, &err));
        CHECK(names && names[0] && strcmp(names[0], "id") == 0 && !names[1]);
        bool all = b && b->width == W && b->height == H && b->channels == 1;
        for (int y = 0; all && y < H; y++)
                for (int x = 0; x < W; x++)
                        all = all && imp_image_f32(b, x, y)[0] == (float) px[y][x];
        CHECK_MSG(all, "UINT channel read back wrong (%s)", err.msg);
        imp_strv_free(names);
}

static void test_read_by_extension(void) {
        _cleanup_image_ struct imp_image *a = NULL, *f = NULL;
        CHECK_OK(imp_image_new(4, 3, 3, IMP_PIX_U16, &a));
        fill_pattern(a, 3);
        CHECK_OK(imp_image_to_f32(a, &f));

        const char *png = tmp_path("ext.png"), *tif = tmp_path("ext.TIFF"), *exr = tmp_path("ext.exr");
        CHECK_OK(imp_png_write(png, a, NULL));
        CHECK_OK(imp_tiff_write(tif, a, "x", NULL));
        CHECK_OK(imp_exr_write(exr, f, exr_names, false, NULL));

        _cleanup_image_ struct imp_image *b = NULL, *c = NULL, *d = NULL;
        CHECK_OK(imp_image_read(png, &b, NULL));
        CHECK(b && same_pixels(a, b));
        CHECK_OK(imp_image_read(tif, &c, NULL));
        CHECK(c && same_pixels(a, c));
        CHECK_OK(imp_image_read(exr, &d, NULL));
        CHECK(d && d->type == IMP_PIX_F32 && d->channels == 3);
        /* the EXR's channels come back B, G, R (sorted): R is the last one */
        CHECK(d && imp_image_f32(d, 3, 2)[2] == (float) imp_image_u16(a, 3, 2)[0]);

        struct imp_error err = { 0 };
        struct imp_image *untouched = NULL;
        CHECK_ERR(imp_image_read(tmp_path("x.jpg"), &untouched, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "x.jpg");
        CHECK_STR_CONTAINS(err.msg, "expected .png");
        CHECK(untouched == NULL);
}

int main(void) {
        test_new_and_helpers();
        test_png_roundtrip();
        test_png_16bit_is_big_endian();
        test_png_palette();
        test_png_fast();
        test_tiff_roundtrip();
        test_tiff_fast_frame();
        test_tiff_description();
        test_exr_float_roundtrip();
        test_exr_half_roundtrip();
        test_exr_file_layout();
        test_exr_uint_channel();
        test_exr_threads_same_bytes();
        test_tiff_read_reuse();
        test_read_by_extension();
        return TEST_DONE();
}
