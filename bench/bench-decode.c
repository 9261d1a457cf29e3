/* Structured-light decoding throughput: the 5 real procam captures (1280×1024, 42 frames
 * each) decoded by impasto (1 thread and all threads) and by OpenCV's GrayCodePattern
 * (shadow mask + getProjPixel per pixel, as its users call it), frames already in memory.
 * The methods alternate within each repetition (the order changes every repetition) so that
 * a loaded machine slows them alike; prints medians and ranges of wall time, the thread
 * CPU time of the single-threaded runs (both decoders then run on the calling thread; CPU
 * time excludes the time other processes take), per-repetition speed ratios and peak RSS.
 * Each repetition also times the bandwidth limit on the same thread (every frame read once,
 * a result-sized block written once) and prints the decode's share of it. Output maps are
 * allocated before the timed runs on every side (OpenCV's three maps, impasto's result
 * through imp_sl_decode_reuse, the limit's block): the same job, without page faults.
 * impasto runs twice on one thread: every map, and coords_only (coordinates, flags,
 * confidence, σ: what triangulation reads, and more than OpenCV's users get), each against
 * the limit for the bytes it writes (26 and 14 bytes a pixel: the bytes read and written a
 * pixel are printed map by map, from the result's own element sizes). The machine's memory
 * bandwidth swings (a VM whose host takes it away at times): besides the median ratio the
 * bench prints the ratio in the repetition where the limit ran fastest, and the median over
 * the repetitions whose limit ran within 25 % of its best.
 * Usage: bench-decode [repeats] [data dir] [--impasto-only | --checksum]; without a data dir
 * the captures are looked for under $IMPASTO_SHARED_DIR (else the build's shared directory).
 * --checksum prints an FNV-1a 64 of every result map of each capture (1 and all threads)
 * and exits: two builds decode bit-identically when their lines are equal. Each line holds
 * two hashes: "exact", the maps a narrow encoding never touches (coordinates, flags, direct,
 * global, modulation) and the counts; "narrow", confidence and σ as their 16-bit encodings
 * (imp_sl_conf16, imp_sl_sigma16 of the float values for a build whose maps are float). Then
 * one line a capture for coords_only: the hash of its maps and counts, equal to the full
 * decode's; then capture 0 with non-default thresholds (print_param_checksums). */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "cv-graycode.h"
#include "numerics.h"
#include "structured-light.h"

#define NFRAMES 42
#define NCAP 5
#define MAX_REPS 64
#define NOMINAL_GBS 21.0        /* this VM's memory bandwidth, GB/s, as the issue gives it */

static double clock_s(clockid_t id) {
        struct timespec ts;
        clock_gettime(id, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double peak_rss_mib(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return ru.ru_maxrss / 1024.0;       /* KiB on Linux */
}

/* Median, min and max of v[0..n) (sorts a copy). */
static void stats(const double *v, int n, double *med, double *lo, double *hi) {
        double t[MAX_REPS];
        memcpy(t, v, n * sizeof *t);
        qsort(t, n, sizeof *t, imp_cmp_double);
        *med = imp_median_sorted(t, (size_t) n);
        *lo = t[0];
        *hi = t[n - 1];
}

static struct imp_image *img[NCAP][NFRAMES];
static struct imp_pattern *seq;
static struct imp_sl_result *kept[3];  /* impasto's maps: 1 thread, all threads, coords only */

/* All captures once into *r (imp_sl_decode_reuse: the maps are allocated once, before the
 * timed runs, as OpenCV's three output maps are); *ret_cpu: thread CPU time. Returns wall
 * time, < 0 on error. */
static double run_impasto(const struct imp_sl_params *p, struct imp_sl_result **r, size_t *ret_valid,
                          double *ret_cpu) {
        double t0 = clock_s(CLOCK_MONOTONIC), c0 = clock_s(CLOCK_THREAD_CPUTIME_ID);
        size_t valid = 0;
        for (int c = 0; c < NCAP; c++) {
                struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img[c], NFRAMES };
                struct imp_error err = { 0 };
                if (imp_sl_decode_reuse(&fr, p, r, &err) < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        return -1;
                }
                valid += (*r)->n_valid_xy;
        }
        *ret_cpu = clock_s(CLOCK_THREAD_CPUTIME_ID) - c0;
        *ret_valid = valid;
        return clock_s(CLOCK_MONOTONIC) - t0;
}

static uint64_t fnv(uint64_t h, const void *p, size_t n) {
        const uint8_t *b = p;
        for (size_t i = 0; i < n; i++)
                h = (h ^ b[i]) * 0x100000001b3ull;
        return h;
}

/* FNV-1a of the maps that coords_only keeps, and of the counts. */
static uint64_t coords_hash(const struct imp_sl_result *r) {
        size_t n = (size_t) r->width * r->height;
        uint64_t h = 0xcbf29ce484222325ull;
        h = fnv(h, r->proj_x, n * sizeof *r->proj_x);
        h = fnv(h, r->proj_y, n * sizeof *r->proj_y);
        h = fnv(h, r->confidence, n * sizeof *r->confidence);
        h = fnv(h, r->sigma_px, n * sizeof *r->sigma_px);
        h = fnv(h, r->flags, n * sizeof(uint16_t));
        size_t cnt[] = { r->n_valid_x, r->n_valid_y, r->n_valid_xy, r->n_shadow, r->n_saturated,
                         r->n_weak, r->n_disagree };
        return fnv(h, cnt, sizeof cnt);
}

/* One line a capture: coords_only's hash next to the full decode's over the same maps. */
static int print_coords_checksums(const struct imp_sl_params *p1) {
        struct imp_sl_params pc = *p1;
        pc.coords_only = true;
        int rc = 0;
        for (int c = 0; c < NCAP && !rc; c++) {
                struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img[c], NFRAMES };
                struct imp_sl_result *rf = NULL, *ro = NULL;
                struct imp_error err = { 0 };
                if (imp_sl_decode(&fr, p1, &rf, &err) < 0 || imp_sl_decode(&fr, &pc, &ro, &err) < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        rc = 1;
                } else {
                        uint64_t hf = coords_hash(rf), ho = coords_hash(ro);
                        printf("capture %d, coordinates only: %016llx (%s the full decode's)\n", c,
                               (unsigned long long) ho, ho == hf && !ro->direct ? "same as" : "NOT");
                        rc = ho != hf || ro->direct;
                }
                imp_sl_result_free(rf);
                imp_sl_result_free(ro);
        }
        return rc;
}

/* FNV-1a of the maps of r that no narrow encoding touches (those it has) and of its counts. */
static uint64_t exact_hash(const struct imp_sl_result *r) {
        size_t n = (size_t) r->width * r->height;
        uint64_t h = 0xcbf29ce484222325ull;
        const float *maps[] = { r->proj_x, r->proj_y, r->direct, r->global, r->modulation };
        for (size_t m = 0; m < sizeof maps / sizeof *maps; m++)
                if (maps[m])
                        h = fnv(h, maps[m], n * sizeof(float));
        h = fnv(h, r->flags, n * sizeof(uint16_t));
        size_t cnt[] = { r->n_valid_x, r->n_valid_y, r->n_valid_xy, r->n_shadow, r->n_saturated,
                         r->n_weak, r->n_disagree };
        return fnv(h, cnt, sizeof cnt);
}

/* FNV-1a of the narrow maps: confidence, then σ, as stored (imp_sl_conf16, imp_sl_sigma16). */
static uint64_t narrow_hash(const struct imp_sl_result *r) {
        size_t n = (size_t) r->width * r->height;
        uint64_t h = 0xcbf29ce484222325ull;
        h = fnv(h, r->confidence, n * sizeof *r->confidence);
        return fnv(h, r->sigma_px, n * sizeof *r->sigma_px);
}

/* Both, in one field of a checksum line. */
static void print_hashes(const struct imp_sl_result *r) {
        printf("exact %016llx narrow %016llx", (unsigned long long) exact_hash(r),
               (unsigned long long) narrow_hash(r));
}

/* Capture 0 decoded with thresholds other than the defaults, one line each: the byte-lane
 * kernels fold some of them into their per-pixel thresholds (saturation below 255 or at 0,
 * a contrast threshold no byte reaches, sign-only bits, a black level, a non-integer shadow
 * threshold, min_direct 0), so two builds must print the same lines for these too. */
static int print_param_checksums(const struct imp_sl_params *p1) {
        static const struct { const char *what; double sat, minc, black, shadow, mind; bool robust; } v[] = {
                { "saturation 200", 200, 5, 0, 40, 5, true },
                { "saturation 1 (every sample clipped)", 1, 5, 0, 40, 5, true },
                { "min_bit_contrast 300 (no bit decided)", 0, 300, 0, 40, 5, true },
                { "sign only, contrast 12.5", 0, 12.5, 0, 40, 5, false },
                { "black level 0.1, shadow 30.5, min_direct 0", 0, 5, 0.1, 30.5, 0, true },
        };
        struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img[0], NFRAMES };
        for (size_t i = 0; i < sizeof v / sizeof *v; i++) {
                struct imp_sl_params p = *p1;
                p.saturation = v[i].sat;
                p.min_bit_contrast = v[i].minc;
                p.black_level = v[i].black;
                p.shadow_threshold = v[i].shadow;
                p.min_direct = v[i].mind;
                p.robust = v[i].robust;
                struct imp_sl_result *r = NULL;
                struct imp_error err = { 0 };
                if (imp_sl_decode(&fr, &p, &r, &err) < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        return 1;
                }
                printf("capture 0, %s: ", v[i].what);
                print_hashes(r);
                printf(" (%zu valid, %zu weak, %zu saturated)\n", r->n_valid_xy, r->n_weak, r->n_saturated);
                imp_sl_result_free(r);
        }
        return 0;
}

/* One line per capture and thread count: the hash of every map and of the counts. The 1-thread
 * decode gets a new result each time, the all-threads decode reuses one result across the
 * captures (imp_sl_decode_reuse): equal lines also say that reuse leaves nothing stale. */
static int print_checksums(const struct imp_sl_params *p1, const struct imp_sl_params *pn) {
        struct imp_sl_result *reused = NULL;
        for (int c = 0; c < NCAP; c++)
                for (int t = 0; t < 2; t++) {
                        struct imp_sl_frames fr = { seq, (const struct imp_image *const *) img[c], NFRAMES };
                        struct imp_sl_result *r = t ? reused : NULL;
                        struct imp_error err = { 0 };
                        if (imp_sl_decode_reuse(&fr, t ? pn : p1, &r, &err) < 0) {
                                fprintf(stderr, "%s\n", err.msg);
                                return 1;
                        }
                        printf("capture %d, %s: ", c, t ? "all threads" : "1 thread");
                        print_hashes(r);
                        printf(" (%zu valid)\n", r->n_valid_xy);
                        if (t)
                                reused = r;
                        else
                                imp_sl_result_free(r);
                }
        imp_sl_result_free(reused);
        return print_coords_checksums(p1) || print_param_checksums(p1);
}

/* Bytes a pixel of r's maps, from their element sizes (the maps it has). */
static size_t result_px_bytes(const struct imp_sl_result *r) {
        return sizeof *r->proj_x + sizeof *r->proj_y + sizeof *r->confidence + sizeof *r->sigma_px +
               sizeof *r->flags + (r->direct ? sizeof *r->direct : 0) + (r->global ? sizeof *r->global : 0) +
               (r->modulation ? sizeof *r->modulation : 0);
}

/* The memory-bandwidth limit of a decode: one read pass over every frame of each capture
 * (the bytes the decoder must read) and one write pass over a result-sized block (px_bytes a
 * pixel, as imp_sl_decode_reuse fills them), same thread. The block is allocated once, as the
 * decoder's reused result is (2 MiB aligned, THP hint), by the first call: the largest. */
static double run_bandwidth(size_t px_bytes, double *ret_cpu, size_t *ret_bytes) {
        static char *blk;
        static size_t cap;
        size_t out = (size_t) img[0][0]->width * img[0][0]->height * px_bytes;
        if (!blk) {
                size_t round = (out + (2u << 20) - 1) & ~(size_t) ((2u << 20) - 1);
                blk = aligned_alloc(2u << 20, round);
                if (!blk)
                        return -1;
                (void) madvise(blk, round, MADV_HUGEPAGE);
                memset(blk, 1, out);
                cap = out;
        }
        if (out > cap)
                return -1;
        double t0 = clock_s(CLOCK_MONOTONIC), c0 = clock_s(CLOCK_THREAD_CPUTIME_ID);
        size_t bytes = 0;
        uint64_t acc = 0;
        for (int c = 0; c < NCAP; c++) {
                for (int i = 0; i < NFRAMES; i++) {
                        const struct imp_image *im = img[c][i];
                        for (int y = 0; y < im->height; y++) {
                                const uint8_t *row = imp_image_row(im, y);
                                uint64_t s = 0, v;
                                int x = 0;
                                for (; x + 8 <= im->width; x += 8) {
                                        memcpy(&v, row + x, 8);
                                        s ^= v;
                                }
                                for (; x < im->width; x++)
                                        s ^= row[x];
                                acc += s;
                        }
                        bytes += (size_t) im->width * im->height;
                }
                memset(blk, (int) (acc & 1), out);
                acc += (uint8_t) blk[out / 2];
                bytes += out;
        }
        *ret_cpu = clock_s(CLOCK_THREAD_CPUTIME_ID) - c0;
        *ret_bytes = bytes + (acc == 42);     /* keeps acc alive */
        return clock_s(CLOCK_MONOTONIC) - t0;
}

static double run_opencv(int32_t *cx, int32_t *cy, uint8_t *cv, size_t *ret_valid, double *ret_cpu) {
        double t0 = clock_s(CLOCK_MONOTONIC), c0 = clock_s(CLOCK_THREAD_CPUTIME_ID);
        size_t valid = 0;
        for (int c = 0; c < NCAP; c++) {
                size_t nv = 0;
                struct imp_error err = { 0 };
                if (imp_cv_graycode_decode(1024, 768, (const struct imp_image *const *) img[c], 40,
                                           img[c][40], img[c][41], 40, 5, cx, cy, cv, &nv, &err) < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        return -1;
                }
                valid += nv;
        }
        *ret_cpu = clock_s(CLOCK_THREAD_CPUTIME_ID) - c0;
        *ret_valid = valid;
        return clock_s(CLOCK_MONOTONIC) - t0;
}

/* The result maps of the impasto runs (p[i] into kept[i]) and the limit's block allocated
 * (and faulted in) before the timed runs, as OpenCV's maps are. */
static int warm_up(const struct imp_sl_params *p) {
        size_t valid, bytes;
        double cpu;
        for (int i = 0; i < 3; i++)
                if (run_impasto(&p[i], &kept[i], &valid, &cpu) < 0)
                        return -1;
        return run_bandwidth(result_px_bytes(kept[0]), &cpu, &bytes) < 0 ? -1 : 0;
}

/* The real captures, every frame of every capture, into img[][]. */
static int load_images(const char *dir) {
        for (int c = 0; c < NCAP; c++)
                for (int i = 0; i < NFRAMES; i++) {
                        char path[1024];
                        struct imp_error err = { 0 };
                        snprintf(path, sizeof path, "%s/capture_%d/graycode_%02d.png", dir, c, i);
                        if (imp_png_read(path, &img[c][i], &err) < 0) {
                                fprintf(stderr, "%s\n", err.msg);
                                return -1;
                        }
                }
        return 0;
}

static void free_images(void) {
        for (int i = 0; i < 3; i++)
                imp_sl_result_free(kept[i]);
        for (int c = 0; c < NCAP; c++)
                for (int i = 0; i < NFRAMES; i++)
                        imp_image_free(img[c][i]);
}

/* Per-repetition times (wall t*, thread CPU u*) of the methods, the limits, and ratios. */
struct timings {
        double t1[MAX_REPS], tn[MAX_REPS], to[MAX_REPS], tc[MAX_REPS];
        double u1[MAX_REPS], uo[MAX_REPS], uc[MAX_REPS], un;
        double ub[MAX_REPS], ubo[MAX_REPS];
        double bb1[MAX_REPS], bbo[MAX_REPS];   /* the limit run right before and after the 1-thread
                                                  decodes (every map, coords_only): the slower */
        size_t valid_imp, valid_cv, bw_bytes, bwo_bytes;
        double rss_imp;
};

/* The 1-thread decode p into *r between two runs of the limit (every map): *ret_bracket the
 * slower of the two, the memory's speed around the decode (it swings within seconds). */
static double run_bracketed(const struct imp_sl_params *p, struct imp_sl_result **r, size_t *ret_valid,
                            double *ret_cpu, double *ret_bracket) {
        double pre, post;
        size_t bytes;
        (void) run_bandwidth(result_px_bytes(kept[0]), &pre, &bytes);
        double t = run_impasto(p, r, ret_valid, ret_cpu);
        (void) run_bandwidth(result_px_bytes(kept[0]), &post, &bytes);
        *ret_bracket = pre > post ? pre : post;
        return t;
}

/* The repetitions: the four methods, then the two bandwidth limits. OpenCV comes last in
 * even repetitions (after coords_only) and first in odd ones (before the 1-thread decode):
 * a run next to OpenCV's came out slower, so the two 1-thread impasto runs take turns. p: 1
 * thread, all threads, 1 thread coords_only. The 1-thread runs are bracketed by the limit
 * (run_bracketed). */
static int run_all(const struct imp_sl_params *p, int repeats, bool only_imp, struct timings *T) {
        size_t n = (size_t) img[0][0]->width * img[0][0]->height;
        int32_t *cx = malloc(n * sizeof *cx), *cy = malloc(n * sizeof *cy);
        uint8_t *cv = malloc(n);
        int rc = !cx || !cy || !cv || warm_up(p) < 0;
        for (int rep = 0; rep < repeats && !rc; rep++) {
                for (int step = 0; step < 4 && !rc; step++) {
                        int which = rep % 2 ? (step + 3) % 4 : step;
                        double t;
                        if (which == 0)
                                t = T->t1[rep] = run_bracketed(&p[0], &kept[0], &T->valid_imp, &T->u1[rep], &T->bb1[rep]);
                        else if (which == 1)
                                t = T->tn[rep] = run_impasto(&p[1], &kept[1], &T->valid_imp, &T->un);
                        else if (which == 2)
                                t = T->to[rep] = run_bracketed(&p[2], &kept[2], &T->valid_imp, &T->uo[rep], &T->bbo[rep]);
                        else if (!only_imp)
                                t = T->tc[rep] = run_opencv(cx, cy, cv, &T->valid_cv, &T->uc[rep]);
                        else
                                t = T->tc[rep] = T->uc[rep] = 1;
                        rc = t < 0;
                        if (which < 3)
                                T->rss_imp = peak_rss_mib();
                }
                (void) run_bandwidth(result_px_bytes(kept[0]), &T->ub[rep], &T->bw_bytes);
                (void) run_bandwidth(result_px_bytes(kept[2]), &T->ubo[rep], &T->bwo_bytes);
        }
        free(cx);
        free(cy);
        free(cv);
        return rc;
}

/* Median [min – max] over the repetitions of f(i) = num[i] / den[i] (scaled). */
static void ratio_stats(const double *num, const double *den, int n, double scale, double *m,
                        double *lo, double *hi) {
        double r[MAX_REPS];
        for (int i = 0; i < n; i++)
                r[i] = scale * num[i] / den[i];
        stats(r, n, m, lo, hi);
}

/* The bytes a pixel the decode must move, map by map: every frame read once (u8), every map
 * written once (the result's element sizes; the decoder streams rows to a result this large
 * with non-temporal stores, which need not read the lines first). */
static void print_map_bytes(void) {
        const struct imp_sl_result *r = kept[0], *o = kept[2];
        printf("  bytes a pixel: read %d (%d u8 frames, each once); written: proj_x %zu, proj_y %zu, "
               "confidence %zu, sigma %zu, flags %zu, direct %zu, global %zu, modulation %zu = %zu "
               "(coords_only %zu); moved %zu (coords_only %zu)\n",
               NFRAMES, NFRAMES, sizeof *r->proj_x, sizeof *r->proj_y, sizeof *r->confidence, sizeof *r->sigma_px,
               sizeof *r->flags, r->direct ? sizeof *r->direct : 0, r->global ? sizeof *r->global : 0,
               r->modulation ? sizeof *r->modulation : 0, result_px_bytes(r), result_px_bytes(o),
               NFRAMES + result_px_bytes(r), NFRAMES + result_px_bytes(o));
}

/* The ratios where the memory ran at its best: the machine's bandwidth swings (the host takes
 * it away at times), and a decode that waits on memory slows with it while OpenCV, which waits
 * on instructions, hardly does. For each 1-thread decode, the repetition whose bracketing
 * limit (run_bracketed) ran fastest, and the median over the repetitions whose bracket took at
 * most 1.25× that best time. */
static void ratio_at_best(const double *bb, const double *u, const double *uc, int repeats, double *at_best,
                          double *med, int *ret_n, int *ret_best) {
        int best = 0, n = 0;
        for (int i = 1; i < repeats; i++)
                best = bb[i] < bb[best] ? i : best;
        double r[MAX_REPS], lo, hi;
        for (int i = 0; i < repeats; i++)
                if (bb[i] <= 1.25 * bb[best])
                        r[n++] = uc[i] / u[i];
        stats(r, n, med, &lo, &hi);
        *at_best = uc[best] / u[best];
        *ret_n = n;
        *ret_best = best;
}

static void print_ratio_at_best(const struct timings *T, int repeats) {
        double a1, m1, ao, mo;
        int n1, no, b1, bo;
        ratio_at_best(T->bb1, T->u1, T->uc, repeats, &a1, &m1, &n1, &b1);
        ratio_at_best(T->bbo, T->uo, T->uc, repeats, &ao, &mo, &no, &bo);
        const double gb = (double) T->bw_bytes / 1e9;
        printf("  where the memory ran fastest (the limit right before and after the decode): OpenCV/impasto CPU "
               "every map %.1fx (repetition %d, limit %.1f GB/s, decode %.1f GB/s), median %.1fx over the %d "
               "repetitions within 1.25x of it; coords_only %.1fx (repetition %d, limit %.1f GB/s), median "
               "%.1fx over %d\n", a1, b1, gb / T->bb1[b1], gb / T->u1[b1], m1, n1, ao, bo, gb / T->bbo[bo], mo, no);
}

/* The bytes the 1-thread decode with every map moves (the limit's bytes: every frame read
 * once, the result written once) at its median and best speed, against the limit's own rate
 * (median and best) and the machine's nominal bandwidth. */
static void print_bytes_moved(const struct timings *T, int repeats) {
        const double px = (double) img[0][0]->width * img[0][0]->height * NCAP;
        double m, lo, hi, bm, blo, bhi;
        stats(T->u1, repeats, &m, &lo, &hi);
        stats(T->ub, repeats, &bm, &blo, &bhi);
        const double gb = (double) T->bw_bytes / 1e9;
        printf("  bytes moved: %.0f B a pixel (%d frames read + the maps written); impasto 1 thread "
               "%.1f GB/s median, %.1f GB/s best = %.0f %% / %.0f %% of the limit's own median / best "
               "(%.1f / %.1f GB/s), %.0f %% / %.0f %% of %.0f GB/s\n",
               T->bw_bytes / px, NFRAMES, gb / m, gb / lo, 100 * bm / m, 100 * blo / lo, gb / bm, gb / blo,
               100 * gb / m / NOMINAL_GBS, 100 * gb / lo / NOMINAL_GBS, NOMINAL_GBS);
}

static void print_results(const struct timings *T, int repeats, bool only_imp, int max_threads) {
        int w = img[0][0]->width, h = img[0][0]->height;
        double mpix = (double) w * h * NCAP / 1e6, m, lo, hi;
        printf("structured-light decode, %d captures × %dx%d × %d frames (u8), %d repetitions, "
               "methods alternating; median [min – max]\n", NCAP, w, h, NFRAMES, repeats);
        stats(T->t1, repeats, &m, &lo, &hi);
        printf("  impasto, 1 thread  wall %7.3f s [%.3f – %.3f]  %6.1f Mpix/s  (%zu pixels decoded)\n",
               m, lo, hi, mpix / m, T->valid_imp);
        stats(T->u1, repeats, &m, &lo, &hi);
        printf("                      CPU %7.3f s [%.3f – %.3f]  %6.1f Mpix/s\n", m, lo, hi, mpix / m);
        stats(T->uo, repeats, &m, &lo, &hi);
        printf("  impasto, 1 thread, coords_only  CPU %7.3f s [%.3f – %.3f]  %6.1f Mpix/s\n", m, lo,
               hi, mpix / m);
        stats(T->tn, repeats, &m, &lo, &hi);
        printf("  impasto, %d threads wall %7.3f s [%.3f – %.3f]  %6.1f Mpix/s\n", max_threads, m,
               lo, hi, mpix / m);
        if (!only_imp) {
                stats(T->tc, repeats, &m, &lo, &hi);
                printf("  OpenCV getProjPixel wall %7.3f s [%.3f – %.3f]  %6.1f Mpix/s  (%zu pixels decoded)\n",
                       m, lo, hi, mpix / m, T->valid_cv);
                stats(T->uc, repeats, &m, &lo, &hi);
                printf("                      CPU %7.3f s [%.3f – %.3f]  %6.1f Mpix/s\n", m, lo, hi,
                       mpix / m);
                ratio_stats(T->tc, T->t1, repeats, 1, &m, &lo, &hi);
                printf("  speed ratio OpenCV/impasto per repetition: 1 thread wall %.1fx [%.1f – %.1f]",
                       m, lo, hi);
                ratio_stats(T->uc, T->u1, repeats, 1, &m, &lo, &hi);
                printf(", CPU %.1fx [%.1f – %.1f]", m, lo, hi);
                ratio_stats(T->uc, T->uo, repeats, 1, &m, &lo, &hi);
                printf(", coords_only CPU %.1fx [%.1f – %.1f]", m, lo, hi);
                ratio_stats(T->tc, T->tn, repeats, 1, &m, &lo, &hi);
                printf("; %d threads wall %.1fx [%.1f – %.1f]\n", max_threads, m, lo, hi);
        }
        stats(T->ub, repeats, &m, &lo, &hi);
        printf("  bandwidth limit (read every frame once, write the result maps once, 1 thread): "
               "CPU %.3f s [%.3f – %.3f], %.1f GB/s, %.1f Mpix/s\n", m, lo, hi, T->bw_bytes / m / 1e9,
               mpix / m);
        ratio_stats(T->ub, T->u1, repeats, 100, &m, &lo, &hi);
        printf("  impasto 1 thread at %.0f %% [%.0f – %.0f] of that limit (CPU time ratio per repetition)\n",
               m, lo, hi);
        print_map_bytes();
        print_bytes_moved(T, repeats);
        if (!only_imp)
                print_ratio_at_best(T, repeats);
        stats(T->ubo, repeats, &m, &lo, &hi);
        printf("  coords_only limit (its %zu B/px written): CPU %.3f s [%.3f – %.3f], %.1f GB/s; ",
               result_px_bytes(kept[2]), m, lo, hi, T->bwo_bytes / m / 1e9);
        ratio_stats(T->ubo, T->uo, repeats, 100, &m, &lo, &hi);
        printf("coords_only at %.0f %% [%.0f – %.0f] of it\n", m, lo, hi);
        printf("  peak RSS: %.1f MiB after impasto, %.1f MiB at the end (frames: %.1f MiB)\n",
               T->rss_imp, peak_rss_mib(), (double) w * h * NFRAMES * NCAP / (1 << 20));
}

int main(int argc, char **argv) {
        bool only_imp = argc > 1 && !strcmp(argv[argc - 1], "--impasto-only");
        bool checksum = argc > 1 && !strcmp(argv[argc - 1], "--checksum");
        if (only_imp || checksum)
                argc--;
        int repeats = argc > 1 ? atoi(argv[1]) : 5;
        const char *dir = argc > 2 ? argv[2] : getenv("IMPASTO_SHARED_DIR") ? getenv("IMPASTO_SHARED_DIR") : IMPASTO_SHARED_DIR;
        char dbuf[512];
        if (argc <= 2) {
                snprintf(dbuf, sizeof dbuf, "%s/data/procam-graycode/sample_data", dir);
                dir = dbuf;
        }
        repeats = repeats < 1 ? 1 : repeats > MAX_REPS ? MAX_REPS : repeats;
        if (load_images(dir) < 0)
                return 1;
        fprintf(stderr, "loaded %d captures of %d frames, %dx%d; peak RSS %.1f MiB\n", NCAP,
                NFRAMES, img[0][0]->width, img[0][0]->height, peak_rss_mib());

        int nseq = 0;
        if (imp_sl_sequence(1024, 768, 0, NULL, 0, &seq, &nseq) < 0 || nseq != NFRAMES)
                return 1;
        struct imp_sl_params p[3];      /* 1 thread, all threads, 1 thread coords_only */
        imp_sl_params_default(&p[0], IMP_PIX_U8);
        p[0].proj_width = 1024;
        p[0].proj_height = 768;
        p[0].threads = 1;
        p[1] = p[2] = p[0];
        int max_threads = 1;
#ifdef _OPENMP
        max_threads = omp_get_max_threads();
#endif
        p[1].threads = max_threads;
        p[2].coords_only = true;
        int rc;
        if (checksum) {
                rc = print_checksums(&p[0], &p[1]);
        } else {
                static struct timings T;
                rc = run_all(p, repeats, only_imp, &T);
                if (!rc)
                        print_results(&T, repeats, only_imp, max_threads);
        }
        free(seq);
        free_images();
        return rc;
}
