/* Bad input to the image readers and writers: missing, empty, truncated, mistyped,
 * corrupted and unsupported files. Each must fail with the documented errno and a message
 * naming the file and what was expected, leave the result untouched, print nothing, and
 * neither crash nor leak (run under ASan). */
#include <fcntl.h>
#include <dirent.h>
#include <sys/stat.h>
#include <tiffio.h>
#include <unistd.h>
#include "image.h"
#include "test.h"

static const char *tmp_path(const char *name) {
        static char buf[4][512];
        static int i;
        i = (i + 1) % 4;
        snprintf(buf[i], sizeof buf[i], "%s/%s", test_tmpdir(), name);
        return buf[i];
}

/* Library code must not print: stderr goes to a file around each call, and any byte
 * that lands there is counted (and shown). */
static long stray_stderr_bytes;

static const char *stderr_path(void) {
        static char buf[512];
        if (!buf[0])
                snprintf(buf, sizeof buf, "%s/stderr.txt", test_tmpdir());
        return buf;
}

static int quiet_begin(void) {
        fflush(stderr);
        int saved = dup(2);
        int fd = open(stderr_path(), O_WRONLY | O_CREAT | O_TRUNC, 0600);
        dup2(fd, 2);
        close(fd);
        return saved;
}

static void quiet_end(int saved) {
        fflush(stderr);
        dup2(saved, 2);
        close(saved);
        char buf[512] = "";
        FILE *f = fopen(stderr_path(), "r");
        size_t n = f ? fread(buf, 1, sizeof buf - 1, f) : 0;
        if (f)
                fclose(f);
        if (n > 0) {
                stray_stderr_bytes += (long) n;
                fprintf(stderr, "stray stderr output: %s\n", buf);
        }
}

#define QUIET(expr) ({ int saved_ = quiet_begin(); int quiet_r_ = (expr); quiet_end(saved_); quiet_r_; })

enum fmt { PNG, TIFF_, EXR };
static const char *const fmt_name[] = { "png", "tiff", "exr" };
static const char *const exr_names[] = { "R", "G", "B", "A" };

/* Reads `path` as format f with every out-parameter set to a sentinel; checks it fails
 * with `expected_code`, leaves them untouched, and names the file in the message. */
static void expect_failure(enum fmt f, const char *path, int expected_code, const char *msg_part) {
        struct imp_image *sentinel = (struct imp_image *) (uintptr_t) 0x10, *img = sentinel;
        char *desc_sentinel = (char *) (uintptr_t) 0x20, *desc = desc_sentinel;
        char **names_sentinel = (char **) (uintptr_t) 0x30, **names = names_sentinel;
        struct imp_error err = { 0 };
        int r = 0;

        switch (f) {
        case PNG:   r = QUIET(imp_png_read(path, &img, &err)); break;
        case TIFF_: r = QUIET(imp_tiff_read(path, &img, &desc, &err)); break;
        case EXR:   r = QUIET(imp_exr_read(path, &img, &names, &err)); break;
        }
        CHECK_MSG(r == expected_code, "%s reader on %s: returned %d (%s), expected %d (%s); msg: %s",
                  fmt_name[f], path, r, strerror(-r), expected_code, strerror(-expected_code), err.msg);
        CHECK_INT_EQ(err.code, expected_code);
        CHECK_STR_CONTAINS(err.msg, path);
        if (msg_part)
                CHECK_STR_CONTAINS(err.msg, msg_part);
        CHECK(img == sentinel);
        CHECK(desc == desc_sentinel);
        CHECK(names == names_sentinel);
        if (r == 0) {   /* must not happen; avoid leaking what was returned */
                imp_image_free(img);
                if (desc != desc_sentinel)
                        free(desc);
                if (names != names_sentinel)
                        imp_strv_free(names);
        }
}

/* A valid file of format f whose pixels do not compress (noise), so that cutting it
 * anywhere leaves missing pixel data. */
static const char *write_valid(enum fmt f, const char *name) {
        _cleanup_image_ struct imp_image *img = NULL;
        const char *p = tmp_path(name);
        uint32_t s = 99;
        CHECK_OK(imp_image_new(64, 48, 4, f == EXR ? IMP_PIX_F32 : IMP_PIX_U16, &img));
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        for (int c = 0; c < 4; c++) {
                                s = s * 1664525u + 1013904223u;
                                if (f == EXR)
                                        imp_image_f32(img, x, y)[c] = (float) (s >> 8) / 1000.0f;
                                else
                                        imp_image_u16(img, x, y)[c] = (uint16_t) (s >> 16);
                        }
        switch (f) {
        case PNG:   CHECK_OK(imp_png_write(p, img, NULL)); break;
        case TIFF_: CHECK_OK(imp_tiff_write(p, img, "{\"a\":1}", NULL)); break;
        case EXR:   CHECK_OK(imp_exr_write(p, img, exr_names, false, NULL)); break;
        }
        return p;
}

static off_t file_size(const char *p) {
        struct stat st;
        return stat(p, &st) == 0 ? st.st_size : -1;
}

static void write_text(const char *p, const char *text) {
        FILE *f = fopen(p, "w");
        CHECK(f != NULL);
        if (f) {
                fputs(text, f);
                fclose(f);
        }
}

static void copy_file(const char *from, const char *to) {
        char buf[4096];
        FILE *in = fopen(from, "rb"), *out = fopen(to, "wb");
        CHECK(in && out);
        size_t n;
        while (in && out && (n = fread(buf, 1, sizeof buf, in)) > 0)
                fwrite(buf, 1, n, out);
        if (in)
                fclose(in);
        if (out)
                fclose(out);
}

static void test_missing_and_empty(void) {
        for (enum fmt f = PNG; f <= EXR; f++) {
                char name[64];
                snprintf(name, sizeof name, "does-not-exist.%s", fmt_name[f]);
                expect_failure(f, tmp_path(name), -ENOENT, "No such file");

                snprintf(name, sizeof name, "empty.%s", fmt_name[f]);
                write_text(tmp_path(name), "");
                expect_failure(f, tmp_path(name), -EBADMSG, "empty file");
        }
        struct imp_image *img = NULL;
        struct imp_error err = { 0 };
        CHECK_ERR(imp_image_read(tmp_path("nope.tif"), &img, &err), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, "nope.tif");
}

static void test_truncated(void) {
        static const char *const names[] = { "trunc.png", "trunc.tiff", "trunc.exr" };
        for (enum fmt f = PNG; f <= EXR; f++) {
                const char *p = write_valid(f, names[f]);
                off_t size = file_size(p);
                CHECK_GE(size, 4096);
                /* cut in half: header intact, pixel data missing */
                CHECK_OK(truncate(p, size / 2));
                expect_failure(f, p, -EBADMSG, NULL);
                /* cut inside the header */
                CHECK_OK(truncate(p, 20));
                expect_failure(f, p, -EBADMSG, NULL);
        }
}

static void test_wrong_type(void) {
        const char *png = write_valid(PNG, "real.png");
        const char *fake_tiff = tmp_path("png-named.tiff");
        copy_file(png, fake_tiff);
        expect_failure(TIFF_, fake_tiff, -EBADMSG, "not a valid TIFF");

        const char *text_exr = tmp_path("text.exr"), *text_png = tmp_path("text.png");
        const char *text_tif = tmp_path("text.tif");
        static const char text[] = "this is a text file, not an image\nsecond line\n";
        write_text(text_exr, text);
        write_text(text_png, text);
        write_text(text_tif, text);
        expect_failure(EXR, text_exr, -EBADMSG, "not a valid OpenEXR");
        expect_failure(PNG, text_png, -EBADMSG, "expected the PNG signature");
        expect_failure(TIFF_, text_tif, -EBADMSG, "not a valid TIFF");

        /* imp_image_read trusts the extension and reports the mismatch */
        struct imp_image *img = NULL;
        struct imp_error err = { 0 };
        CHECK_ERR(QUIET(imp_image_read(fake_tiff, &img, &err)), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "png-named.tiff");
        CHECK(img == NULL);
}

/* TIFFs that are valid but that imp_image cannot hold, written with plain libtiff. */
static void write_raw_tiff(const char *p, uint16_t spp, uint16_t bps, uint16_t format, bool tiled) {
        TIFF *tif = TIFFOpen(p, "w");
        CHECK(tif != NULL);
        if (!tif)
                return;
        enum { W = 16, H = 16 };
        TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, W);
        TIFFSetField(tif, TIFFTAG_IMAGELENGTH, H);
        TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, spp);
        TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, bps);
        TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, format);
        TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
        TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, spp >= 3 ? PHOTOMETRIC_RGB : PHOTOMETRIC_MINISBLACK);
        if (spp > 3) {
                uint16_t extra[8] = { 0 };
                TIFFSetField(tif, TIFFTAG_EXTRASAMPLES, (uint16_t) (spp - 3), extra);
        }
        size_t row = (size_t) W * spp * bps / 8;
        uint8_t *buf = calloc(1, row * H);
        if (tiled) {
                TIFFSetField(tif, TIFFTAG_TILEWIDTH, 16);
                TIFFSetField(tif, TIFFTAG_TILELENGTH, 16);
                TIFFWriteEncodedTile(tif, 0, buf, (tmsize_t) (row * H));
        } else {
                TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, H);
                for (int y = 0; y < H; y++)
                        TIFFWriteScanline(tif, buf + (size_t) y * row, (uint32_t) y, 0);
        }
        free(buf);
        TIFFClose(tif);
}

/* A header claiming 60000x60000 RGBA u16 (28.8 GB) over a few bytes of "data". */
static void write_huge_tiff(const char *p) {
        TIFF *tif = TIFFOpen(p, "w");
        CHECK(tif != NULL);
        if (!tif)
                return;
        static const uint16_t alpha[] = { EXTRASAMPLE_UNASSALPHA };
        TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 60000);
        TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 60000);
        TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 4);
        TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 16);
        TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
        TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_RGB);
        TIFFSetField(tif, TIFFTAG_EXTRASAMPLES, 1, alpha);
        TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
        TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 60000);
        uint8_t junk[16] = { 0x78, 0x9c };
        TIFFWriteRawStrip(tif, 0, junk, sizeof junk);
        TIFFClose(tif);
}

static void test_unsupported_layouts(void) {
        const char *p5 = tmp_path("five.tiff"), *p32 = tmp_path("int32.tiff");
        const char *ptile = tmp_path("tiled.tiff"), *p64 = tmp_path("double.tiff");
        write_raw_tiff(p5, 5, 8, SAMPLEFORMAT_UINT, false);
        write_raw_tiff(p32, 1, 32, SAMPLEFORMAT_UINT, false);
        write_raw_tiff(ptile, 1, 8, SAMPLEFORMAT_UINT, true);
        write_raw_tiff(p64, 1, 64, SAMPLEFORMAT_IEEEFP, false);
        expect_failure(TIFF_, p5, -EMEDIUMTYPE, "unsupported TIFF layout: 5 samples per pixel (expected 1 to 4)");
        expect_failure(TIFF_, p32, -EMEDIUMTYPE,
                       "unsupported TIFF layout: 32 bits per sample (expected 8, 16 or 32-bit float");
        expect_failure(TIFF_, p32, -EMEDIUMTYPE, "unsigned integer");
        expect_failure(TIFF_, p64, -EMEDIUMTYPE, "64 bits per sample");
        expect_failure(TIFF_, ptile, -EMEDIUMTYPE, "tiled (expected strips)");
        const char *phuge = tmp_path("huge.tiff");
        write_huge_tiff(phuge);
        expect_failure(TIFF_, phuge, -EMEDIUMTYPE, "too large");
}

/* Flipped bytes all over a valid file: any outcome but a crash, a leak or output; a
 * failure has a message naming the file. */
static void test_corrupted(void) {
        static const char *const names[] = { "fuzz.png", "fuzz.tiff", "fuzz.exr" };
        for (enum fmt f = PNG; f <= EXR; f++) {
                const char *orig = write_valid(f, names[f]);
                off_t size = file_size(orig);
                uint8_t *data = malloc((size_t) size);
                FILE *in = fopen(orig, "rb");
                CHECK(in && data && fread(data, 1, (size_t) size, in) == (size_t) size);
                if (in)
                        fclose(in);
                const char *p = tmp_path(f == PNG ? "bad.png" : f == TIFF_ ? "bad.tiff" : "bad.exr");
                uint32_t s = 7 + (uint32_t) f;
                int failures = 0;
                for (int iter = 0; data && iter < 40; iter++) {
                        FILE *out = fopen(p, "wb");
                        if (!out)
                                break;
                        fwrite(data, 1, (size_t) size, out);
                        for (int k = 0; k < 4; k++) {   /* 4 random bytes, header included */
                                s = s * 1664525u + 1013904223u;
                                long at = (long) ((s >> 8) % (uint32_t) (iter < 20 ? IMP_MIN(size, 400) : size));
                                fseek(out, at, SEEK_SET);
                                fputc((int) (s >> 24) & 0xff, out);
                        }
                        fclose(out);

                        struct imp_image *img = NULL;
                        char **ch = NULL, *desc = NULL;
                        struct imp_error err = { 0 };
                        int r = f == PNG ? QUIET(imp_png_read(p, &img, &err))
                              : f == TIFF_ ? QUIET(imp_tiff_read(p, &img, &desc, &err))
                              : QUIET(imp_exr_read(p, &img, &ch, &err));
                        if (r < 0) {
                                failures++;
                                CHECK_STR_CONTAINS(err.msg, p);
                                CHECK(img == NULL);
                        }
                        imp_image_free(img);
                        imp_strv_free(ch);
                        free(desc);
                }
                fprintf(stderr, "corrupted %s: %d of 40 refused\n", fmt_name[f], failures);
                free(data);
        }
}

static int count_dir_entries(const char *dir) {
        DIR *d = opendir(dir);
        int n = 0;
        struct dirent *e;
        while (d && (e = readdir(d)))
                n += e->d_name[0] != '.';
        if (d)
                closedir(d);
        return n;
}

static void test_bad_writes(void) {
        _cleanup_image_ struct imp_image *f32 = NULL, *u8 = NULL, *many = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_image_new(4, 4, 3, IMP_PIX_F32, &f32));
        CHECK_OK(imp_image_new(4, 4, 3, IMP_PIX_U8, &u8));
        CHECK_OK(imp_image_new(4, 4, 5, IMP_PIX_U16, &many));

        CHECK_ERR(imp_png_write(tmp_path("f.png"), f32, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "expected u8 or u16");
        CHECK_ERR(imp_png_write(tmp_path("m.png"), many, &err), -EINVAL);
        CHECK_ERR(imp_tiff_write(tmp_path("m.tiff"), many, NULL, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "m.tiff");
        CHECK_ERR(imp_exr_write(tmp_path("u.exr"), u8, exr_names, false, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "expected f32");
        static const char *const dup_names[] = { "R", "G", "R" };
        CHECK_ERR(imp_exr_write(tmp_path("d.exr"), f32, dup_names, false, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "\"R\" used twice");
        CHECK_ERR(imp_exr_write(tmp_path("n.exr"), f32, NULL, false, &err), -EINVAL);

        /* into a directory that does not exist */
        char missing_dir[600];
        snprintf(missing_dir, sizeof missing_dir, "%s/no/such/dir/x", test_tmpdir());
        char p[700];
        snprintf(p, sizeof p, "%s.png", missing_dir);
        CHECK_ERR(imp_png_write(p, u8, &err), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, p);
        snprintf(p, sizeof p, "%s.tiff", missing_dir);
        CHECK_ERR(QUIET(imp_tiff_write(p, u8, NULL, &err)), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, p);
        snprintf(p, sizeof p, "%s.exr", missing_dir);
        CHECK_ERR(QUIET(imp_exr_write(p, f32, exr_names, false, &err)), -ENOENT);
        CHECK_STR_CONTAINS(err.msg, p);
        static const char *const long_names[] = { "R", "G", "a-channel-name-much-longer-than-the-31-bytes-EXR-allows" };
        CHECK_ERR(QUIET(imp_exr_write(tmp_path("long.exr"), f32, long_names, false, &err)), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "long.exr");

        /* a failed EXR write leaves no file (nor temporary file) behind */
        char dir[600];
        snprintf(dir, sizeof dir, "%s/clean", test_tmpdir());
        CHECK_OK(mkdir(dir, 0700));
        snprintf(p, sizeof p, "%s/d.exr", dir);
        CHECK_ERR(imp_exr_write(p, f32, dup_names, false, &err), -EINVAL);
        CHECK_ERR(QUIET(imp_exr_write(p, f32, long_names, false, &err)), -EINVAL); /* after start */
        CHECK_INT_EQ(count_dir_entries(dir), 0);
        CHECK_OK(imp_exr_write(p, f32, exr_names, false, &err));
        CHECK_INT_EQ(count_dir_entries(dir), 1);
}

int main(void) {
        test_missing_and_empty();
        test_truncated();
        test_wrong_type();
        test_unsupported_layouts();
        test_corrupted();
        test_bad_writes();
        CHECK_INT_EQ(stray_stderr_bytes, 0);
        return TEST_DONE();
}
