/* Capture-frame encoding benchmark: impasto's frame writer imp_tiff_write_fast
 * (horizontal predictor and Zstandard level 1 done in one pass per strip, strips written
 * raw) against libtiff's own encoder producing the same format (TIFFWriteEncodedStrip with
 * COMPRESSION_ZSTD, ZSTD_LEVEL 1, PREDICTOR_HORIZONTAL, the same 64 KiB strips: what
 * impasto used before), and impasto's archival writer imp_tiff_write (deflate level 1), on
 * the same frames, side by side in one process.
 *
 * Frames (1024 x 1024 Mono16 unless given): "camera" — a lit canvas as a 12-bit camera sees
 * it (a smooth gradient of 200..3500 DN with texture, shot noise at 2.5 e/DN and read noise
 * of 3 e), "flat" — a slowly varying image as arv-fake-gv-camera sends (a gradient with a
 * moving diagonal, no noise).
 *
 * Each round writes every frame with every method once, in a rotating order, to a file in
 * DIR (default /tmp; page cache, no fsync: the encoding is measured, not the disk). Per
 * method and frame: median CPU time of the process (CLOCK_PROCESS_CPUTIME_ID) per frame,
 * median of the paired ratio libtiff / impasto, file size; every file is read back with
 * imp_tiff_read and compared sample for sample (a mismatch is an error, exit 1). Peak RSS
 * of the whole run from getrusage.
 * Usage: bench-tiff [rounds (default 15)] [width height] [dir] */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <tiffio.h>
#include <time.h>
#include <unistd.h>
#include "image.h"
#include "numerics.h"

#define N_METHODS 3
#define N_FRAMES 2

static const char *const method_names[N_METHODS] = { "impasto fast (predictor+zstd, raw strips)",
                                                      "libtiff zstd encoder (peer)",
                                                      "impasto archival (deflate 1)" };
static const char *const frame_names[N_FRAMES] = { "camera", "flat" };

static double cpu_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
        return (double) ts.tv_sec + 1e-9 * (double) ts.tv_nsec;
}

/* Standard normal by Box–Muller from a 64-bit LCG. */
static double gauss(uint64_t *s) {
        *s = *s * 6364136223846793005ull + 1442695040888963407ull;
        double u1 = ((double) (*s >> 11) + 1.0) / 9007199254740993.0;
        *s = *s * 6364136223846793005ull + 1442695040888963407ull;
        double u2 = (double) (*s >> 11) / 9007199254740992.0;
        return sqrt(-2.0 * log(u1)) * cos(2.0 * M_PI * u2);
}

static void make_frame(struct imp_image *img, int kind) {
        uint64_t s = 42;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        double fx = (double) x / img->width, fy = (double) y / img->height, v;
                        if (kind == 0) {
                                double dn = 200 + 3300 * (0.5 * fx + 0.3 * fy) * (1 + 0.2 * sin(x * 0.37) * sin(y * 0.23));
                                double e = dn * 2.5;        /* electrons */
                                v = (e + sqrt(e) * gauss(&s) + 3.0 * gauss(&s)) / 2.5;
                        } else
                                v = 1000 + 20000 * fx + 10000 * fy + ((x + y) % 64 == 0 ? 5000 : 0);
                        imp_image_u16(img, x, y)[0] = (uint16_t) fmin(65535, fmax(0, round(v)));
                }
}

/* The peer: libtiff encodes (its predictor, its zstd codec), same tags and strips. */
static int write_libtiff_zstd(const char *path, const struct imp_image *img) {
        TIFF *tif = TIFFOpen(path, "w");
        if (!tif)
                return -1;
        size_t row_bytes = (size_t) img->width * 2;
        uint32_t rows = (uint32_t) (65536 / row_bytes);
        TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, (uint32_t) img->width);
        TIFFSetField(tif, TIFFTAG_IMAGELENGTH, (uint32_t) img->height);
        TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, (uint16_t) 1);
        TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, (uint16_t) 16);
        TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, SAMPLEFORMAT_UINT);
        TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
        TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
        TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ZSTD);
        TIFFSetField(tif, TIFFTAG_PREDICTOR, PREDICTOR_HORIZONTAL);
        TIFFSetField(tif, TIFFTAG_ZSTD_LEVEL, 1);
        TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, rows);
        uint8_t *strip = malloc(row_bytes * rows);
        int r = strip ? 0 : -1;
        for (int y = 0; r == 0 && y < img->height; y += (int) rows) {
                int n = img->height - y < (int) rows ? img->height - y : (int) rows;
                for (int k = 0; k < n; k++)
                        memcpy(strip + (size_t) k * row_bytes, imp_image_row(img, y + k), row_bytes);
                if (TIFFWriteEncodedStrip(tif, TIFFComputeStrip(tif, (uint32_t) y, 0), strip,
                                          (tmsize_t) ((size_t) n * row_bytes)) < 0)
                        r = -1;
        }
        free(strip);
        TIFFClose(tif);
        return r;
}

static int write_method(int m, const char *path, const struct imp_image *img) {
        struct imp_error err = { 0 };
        switch (m) {
        case 0: return imp_tiff_write_fast(path, img, NULL, &err);
        case 1: return write_libtiff_zstd(path, img);
        default: return imp_tiff_write(path, img, NULL, &err);
        }
}

static double median(double *v, int n) {
        qsort(v, (size_t) n, sizeof *v, imp_cmp_double);
        return imp_median_sorted(v, (size_t) n);
}

int main(int argc, char **argv) {
        int rounds = argc > 1 ? atoi(argv[1]) : 15, w = argc > 3 ? atoi(argv[2]) : 1024,
            h = argc > 3 ? atoi(argv[3]) : 1024;
        const char *dir = argc > 4 ? argv[4] : "/tmp";
        if (rounds < 1 || w < 2 || h < 2) {
                fprintf(stderr, "usage: bench-tiff [rounds] [width height] [dir]\n");
                return 2;
        }
        if (!TIFFIsCODECConfigured(COMPRESSION_ZSTD)) {
                fprintf(stderr, "bench-tiff: this libtiff has no Zstandard codec\n");
                return 77;
        }
        struct imp_image *frames[N_FRAMES];
        for (int f = 0; f < N_FRAMES; f++) {
                if (imp_image_new(w, h, 1, IMP_PIX_U16, &frames[f]) < 0)
                        return 1;
                make_frame(frames[f], f);
        }
        double *t = calloc((size_t) N_METHODS * N_FRAMES * rounds, sizeof *t);
        double *ratio = calloc((size_t) N_FRAMES * rounds, sizeof *ratio);
        long long size[N_METHODS][N_FRAMES] = { { 0 } };
        if (!t || !ratio)
                return 1;
        char path[4096];
        int bad = 0;
        for (int r = -1; r < rounds; r++)               /* round -1: warm-up */
                for (int f = 0; f < N_FRAMES; f++)
                        for (int k = 0; k < N_METHODS; k++) {
                                int m = (k + (r < 0 ? 0 : r)) % N_METHODS;
                                snprintf(path, sizeof path, "%s/bench-tiff-%d-%d.tif", dir, m, f);
                                double t0 = cpu_s();
                                if (write_method(m, path, frames[f]) < 0) {
                                        fprintf(stderr, "bench-tiff: %s: writing %s failed\n", method_names[m], path);
                                        return 1;
                                }
                                double dt = cpu_s() - t0;
                                if (r < 0) {
                                        struct stat st;
                                        struct imp_image *back = NULL;
                                        struct imp_error err = { 0 };
                                        if (stat(path, &st) == 0)
                                                size[m][f] = (long long) st.st_size;
                                        if (imp_tiff_read(path, &back, NULL, &err) < 0 || back->width != w ||
                                            back->height != h || back->type != IMP_PIX_U16)
                                                bad++;
                                        else
                                                for (int y = 0; y < h; y++)
                                                        bad += memcmp(imp_image_row(back, y), imp_image_row(frames[f], y),
                                                                      (size_t) w * 2) != 0;
                                        imp_image_free(back);
                                        continue;
                                }
                                t[((size_t) m * N_FRAMES + f) * rounds + r] = dt;
                        }
        for (int f = 0; f < N_FRAMES; f++)
                for (int r = 0; r < rounds; r++)
                        ratio[f * rounds + r] = t[((size_t) 1 * N_FRAMES + f) * rounds + r] /
                                                t[((size_t) 0 * N_FRAMES + f) * rounds + r];
        printf("bench-tiff: %dx%d Mono16, %d rounds, files in %s\n", w, h, rounds, dir);
        for (int f = 0; f < N_FRAMES; f++) {
                printf("frame %-7s", frame_names[f]);
                printf("  (paired ratio libtiff/impasto CPU: median %.2f)\n", median(ratio + f * rounds, rounds));
                for (int m = 0; m < N_METHODS; m++)
                        printf("  %-44s %7.2f ms CPU/frame  %9lld bytes\n", method_names[m],
                               1e3 * median(t + ((size_t) m * N_FRAMES + f) * rounds, rounds), size[m][f]);
        }
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        printf("peak RSS %.1f MiB; read-back mismatches: %d\n", ru.ru_maxrss / 1024.0, bad);
        for (int m = 0; m < N_METHODS; m++)
                for (int f = 0; f < N_FRAMES; f++) {
                        snprintf(path, sizeof path, "%s/bench-tiff-%d-%d.tif", dir, m, f);
                        unlink(path);
                }
        for (int f = 0; f < N_FRAMES; f++)
                imp_image_free(frames[f]);
        free(t);
        free(ratio);
        return bad ? 1 : 0;
}
