/* Structured-light decoding throughput: the 5 real procam captures (1280×1024, 42 frames
 * each) decoded by impasto (1 thread and all threads) and by OpenCV's GrayCodePattern
 * (shadow mask + getProjPixel per pixel, as its users call it), frames already in memory.
 * Prints Mpix/s (camera pixels per second), the speed ratios and peak RSS.
 * Usage: bench-decode [repeats] [data dir] */
#include <stdio.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "cv-graycode.h"
#include "structured-light.h"

#define NFRAMES 42
#define NCAP 5

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double peak_rss_mib(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return ru.ru_maxrss / 1024.0;       /* KiB on Linux */
}

int main(int argc, char **argv) {
        int repeats = argc > 1 ? atoi(argv[1]) : 3;
        const char *dir = argc > 2 ? argv[2] : IMPASTO_SHARED_DIR "/data/procam-graycode/sample_data";
        if (repeats < 1)
                repeats = 1;
        static struct imp_image *img[NCAP][NFRAMES];
        for (int c = 0; c < NCAP; c++)
                for (int i = 0; i < NFRAMES; i++) {
                        char path[512];
                        struct imp_error err = { 0 };
                        snprintf(path, sizeof path, "%s/capture_%d/graycode_%02d.png", dir, c, i);
                        if (imp_png_read(path, &img[c][i], &err) < 0) {
                                fprintf(stderr, "%s\n", err.msg);
                                return 1;
                        }
                }
        int w = img[0][0]->width, h = img[0][0]->height;
        double mpix = (double) w * h * NCAP / 1e6;
        fprintf(stderr, "loaded %d captures of %d frames, %dx%d; peak RSS %.1f MiB\n", NCAP,
                NFRAMES, w, h, peak_rss_mib());

        struct imp_pattern *seq = NULL;
        int nseq = 0;
        if (imp_sl_sequence(1024, 768, 0, NULL, 0, &seq, &nseq) < 0 || nseq != NFRAMES)
                return 1;
        struct imp_sl_params p;
        imp_sl_params_default(&p, IMP_PIX_U8);
        p.proj_width = 1024;
        p.proj_height = 768;

        int max_threads = 1;
#ifdef _OPENMP
        max_threads = omp_get_max_threads();
#endif
        double t_imp[2] = { 1e30, 1e30 };
        size_t valid_imp = 0;
        for (int mode = 0; mode < 2; mode++) {
                p.threads = mode == 0 ? 1 : max_threads;
                for (int rep = 0; rep < repeats; rep++) {
                        double t0 = now_s();
                        size_t valid = 0;
                        for (int c = 0; c < NCAP; c++) {
                                struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img[c], NFRAMES };
                                struct imp_sl_result *r = NULL;
                                struct imp_error err = { 0 };
                                if (imp_sl_decode(&fr, &p, &r, &err) < 0) {
                                        fprintf(stderr, "%s\n", err.msg);
                                        return 1;
                                }
                                valid += r->n_valid_xy;
                                imp_sl_result_free(r);
                        }
                        double t = now_s() - t0;
                        if (t < t_imp[mode])
                                t_imp[mode] = t;
                        valid_imp = valid;
                }
        }
        double rss_imp = peak_rss_mib();

        size_t n = (size_t) w * h, valid_cv = 0;
        int32_t *cx = malloc(n * sizeof *cx), *cy = malloc(n * sizeof *cy);
        uint8_t *cv = malloc(n);
        if (!cx || !cy || !cv)
                return 1;
        double t_cv = 1e30;
        int cv_repeats = repeats > 2 ? 2 : repeats;     /* OpenCV's loop is the slow one */
        for (int rep = 0; rep < cv_repeats; rep++) {
                double t0 = now_s();
                size_t valid = 0;
                for (int c = 0; c < NCAP; c++) {
                        size_t nv = 0;
                        struct imp_error err = { 0 };
                        if (imp_cv_graycode_decode(1024, 768, (const struct imp_image *const *) img[c], 40,
                                                   img[c][40], img[c][41], 40, 5, cx, cy, cv, &nv, &err) < 0) {
                                fprintf(stderr, "%s\n", err.msg);
                                return 1;
                        }
                        valid += nv;
                }
                double t = now_s() - t0;
                if (t < t_cv)
                        t_cv = t;
                valid_cv = valid;
        }

        printf("structured-light decode, %d captures × %dx%d × %d frames (u8), best of %d\n",
               NCAP, w, h, NFRAMES, repeats);
        printf("  impasto, 1 thread : %8.3f s  %8.1f Mpix/s  (%zu pixels decoded)\n", t_imp[0],
               mpix / t_imp[0], valid_imp);
        printf("  impasto, %d threads: %8.3f s  %8.1f Mpix/s\n", max_threads, t_imp[1], mpix / t_imp[1]);
        printf("  OpenCV getProjPixel: %7.3f s  %8.1f Mpix/s  (%zu pixels decoded)\n", t_cv,
               mpix / t_cv, valid_cv);
        printf("  speed ratio impasto/OpenCV: %.1fx (1 thread), %.1fx (%d threads)\n",
               t_cv / t_imp[0], t_cv / t_imp[1], max_threads);
        printf("  peak RSS: %.1f MiB after impasto, %.1f MiB at the end (frames: %.1f MiB)\n",
               rss_imp, peak_rss_mib(), (double) n * NFRAMES * NCAP / (1 << 20));
        free(cx);
        free(cy);
        free(cv);
        free(seq);
        for (int c = 0; c < NCAP; c++)
                for (int i = 0; i < NFRAMES; i++)
                        imp_image_free(img[c][i]);
        return 0;
}
