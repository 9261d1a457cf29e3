/* HDR merge benchmark: impasto's noise-model merge (imp_hdr_merge) vs OpenCV's
 * MergeDebevec on the same synthetic exposure stacks, for speed, noise against the known
 * radiance, and peak memory.
 *
 * Scene: radiance V(x, y) = 10^(−3 x/(w−1)) · texture, texture = 1 + 0.3 sin·sin (periods
 * 37 and 23 px): a horizontal gradient over 3 decades. Sensor: 12 bit, black 64 DN,
 * 2.5 e/DN, read noise 3 e, full well 10000 e, quantum_scale 8e6 e/s; exposures 1, 4,
 * 16 ms at 0 dB; Poisson shot noise (normal approximation above 30 e) + Gaussian read
 * noise, clipped at full well and at 4095 DN.
 *
 * OpenCV 4.6's MergeDebevec takes only 8-bit frames (CV_Assert(depth == CV_8U); checked
 * at run time below), so it gets the same stacks quantised to 8 bit, DN8 = round(DN12/16)
 * (≤ 255). impasto merges both the 12-bit frames and those 8-bit frames (as an 8-bit
 * sensor: black 4 DN, 40 e/DN) for a like-for-like comparison. MergeDebevec runs with
 * (a) the TRUE linear response of the 8-bit frames, (16 d − 64) · 2.5 / 8e6 (floored at half an
 * 8-bit step: OpenCV takes its log), (b) CalibrateDebevec's estimate from the frames,
 * (c) its default response (response = d, 0 → 1; the black level not removed), passed
 * explicitly because 4.6 corrupts the heap building it for 1-channel frames.
 *
 * Error: relative RMS of (V̂ − V)/V over the pixels whose expected signal in the shortest
 * exposure is below 90 % of the clip level, after a global least-squares scale fit
 * (minimising the same relative error) for OpenCV's results, whose units are arbitrary
 * except with the true response. impasto's results are not rescaled (scale shown).
 *
 * Accuracy and peak memory: each method once in its own forked child (peak RSS per method,
 * getrusage after resetting the high-water mark through /proc/self/clear_refs).
 * Speed: all methods in ONE forked child, side by side, with 1 and 2 threads
 * (omp_set_num_threads for impasto, cv::setNumThreads for OpenCV): one warm-up run each,
 * then `repetitions` rounds, each running every method once in a rotating order, so that a
 * load change on the shared machine hits all methods alike. Per method: median and range
 * of the wall time (CLOCK_MONOTONIC), median CPU time of the calling thread
 * (CLOCK_THREAD_CPUTIME_ID) and of the process (CLOCK_PROCESS_CPUTIME_ID: all threads,
 * including the worker pools' spin-waiting), and the median over rounds of the paired ratio
 * t_OpenCV,true / t_method (wall and process CPU). Twice: with glibc's default malloc, whose
 * freed large blocks go back to the kernel so every call faults its temporaries in again,
 * and with M_MMAP_THRESHOLD/M_TRIM_THRESHOLD raised so that they are reused (compute only).
 * Usage: bench-hdr [repetitions (default 7)] [side ...] (default 1024 2048). */
#include <errno.h>
#include <malloc.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "cv-hdr.h"
#include "hdr.h"
#include "image.h"
#include "numerics.h"

#define N_EXP 3
#define N_BINS 3
static const double exposure_us[N_EXP] = { 1000, 4000, 16000 };

static const struct imp_sensor sensor12 = {
        .bits = 12, .black_level_dn = 64, .gain_e_per_dn = 2.5, .read_noise_e = 3.0,
        .full_well_e = 10000, .quantum_scale = 8e6,
};
/* The same sensor read out at 8 bit: DN8 = round(DN12 / 16). */
static const struct imp_sensor sensor8 = {
        .bits = 8, .black_level_dn = 4, .gain_e_per_dn = 40, .read_noise_e = 3.0,
        .full_well_e = 10000, .quantum_scale = 8e6,
};

enum method { M_IMP12, M_IMP8, M_CV_TRUE, M_CV_CALIB, M_CV_DEFAULT, N_METHODS };
static const char *method_name[N_METHODS] = {
        "impasto imp_hdr_merge, 12-bit",
        "impasto imp_hdr_merge, 8-bit",
        "OpenCV MergeDebevec, true resp.",
        "OpenCV MergeDebevec, Calibrate",
        "OpenCV MergeDebevec, default",
};

struct stack {
        int w, h;
        float *truth;                               /* V */
        uint8_t *mask;                              /* evaluated pixels */
        struct imp_image *f12[N_EXP], *f8u16[N_EXP], *f8[N_EXP];
};

struct outcome {                                    /* child → parent through a pipe */
        int ok;
        char err[256];
        double ms_median, ms_min, calib_ms;
        double scale, rel_rms, rel_bias, bin_rms[N_BINS];
        long n_eval, n_bad;
        double peak_rss_mib, base_rss_mib;
        int cv_threads_default;
        char cv_framework[32];
};

static double clock_ms(clockid_t id) {
        struct timespec ts;
        clock_gettime(id, &ts);
        return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}
static double now_ms(void) { return clock_ms(CLOCK_MONOTONIC); }

/* xoshiro256** seeded by splitmix64. */
struct rng { uint64_t s[4]; };
static uint64_t splitmix(uint64_t *x) {
        uint64_t z = (*x += 0x9e3779b97f4a7c15ull);
        z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
        z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
        return z ^ (z >> 31);
}
static void rng_seed(struct rng *r, uint64_t seed) {
        for (int i = 0; i < 4; i++)
                r->s[i] = splitmix(&seed);
}
static inline uint64_t rotl(uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }
static inline uint64_t rng_next(struct rng *r) {
        uint64_t *s = r->s, res = rotl(s[1] * 5, 7) * 9, t = s[1] << 17;
        s[2] ^= s[0]; s[3] ^= s[1]; s[1] ^= s[2]; s[0] ^= s[3]; s[2] ^= t; s[3] = rotl(s[3], 45);
        return res;
}
static inline double rng_unit(struct rng *r) { return ((rng_next(r) >> 11) + 0.5) * 0x1.0p-53; }
static inline double rng_normal(struct rng *r) {
        return sqrt(-2.0 * log(rng_unit(r))) * cos(2.0 * M_PI * rng_unit(r));
}
static double rng_poisson(struct rng *r, double lambda) {
        if (lambda > 30)
                return fmax(0.0, round(lambda + sqrt(lambda) * rng_normal(r)));
        double L = exp(-lambda), p = 1.0;
        int k = -1;
        do {
                k++;
                p *= rng_unit(r);
        } while (p > L);
        return k;
}

static void stack_free(struct stack *st) {
        free(st->truth);
        free(st->mask);
        for (int i = 0; i < N_EXP; i++) {
                imp_image_free(st->f12[i]);
                imp_image_free(st->f8u16[i]);
                imp_image_free(st->f8[i]);
        }
}

static int stack_render(int w, int h, struct stack *st) {
        *st = (struct stack) { .w = w, .h = h };
        size_t np = (size_t) w * h;
        st->truth = malloc(np * sizeof(float));
        st->mask = malloc(np);
        if (!st->truth || !st->mask)
                return -ENOMEM;
        for (int i = 0; i < N_EXP; i++)
                if (imp_image_new(w, h, 1, IMP_PIX_U16, &st->f12[i]) < 0 ||
                    imp_image_new(w, h, 1, IMP_PIX_U16, &st->f8u16[i]) < 0 ||
                    imp_image_new(w, h, 1, IMP_PIX_U8, &st->f8[i]) < 0)
                        return -ENOMEM;
        const struct imp_sensor *s = &sensor12;
        double clip_e = fmin(s->full_well_e, ((1 << s->bits) - 1 - s->black_level_dn) * s->gain_e_per_dn);
        double t_min = exposure_us[0] * 1e-6;
        for (int y = 0; y < h; y++) {
                struct rng r;
                rng_seed(&r, 0x1234567ull + (uint64_t) y);
                for (int x = 0; x < w; x++) {
                        double tex = 1.0 + 0.3 * sin(2 * M_PI * x / 37.0) * sin(2 * M_PI * y / 23.0);
                        double V = pow(10.0, -3.0 * x / (w - 1)) * tex;
                        size_t k = (size_t) y * w + x;
                        st->truth[k] = (float) V;
                        st->mask[k] = V * s->quantum_scale * t_min < 0.9 * clip_e;
                        for (int i = 0; i < N_EXP; i++) {
                                double e = rng_poisson(&r, V * s->quantum_scale * exposure_us[i] * 1e-6);
                                e = fmin(e, s->full_well_e) + s->read_noise_e * rng_normal(&r);
                                double dn = round(e / s->gain_e_per_dn + s->black_level_dn);
                                dn = fmin(fmax(dn, 0.0), (1 << s->bits) - 1);
                                uint16_t d12 = (uint16_t) dn;
                                uint16_t d8 = (uint16_t) ((d12 + 8) >> 4);
                                if (d8 > 255)
                                        d8 = 255;
                                *imp_image_u16(st->f12[i], x, y) = d12;
                                *imp_image_u16(st->f8u16[i], x, y) = d8;
                                *imp_image_u8(st->f8[i], x, y) = (uint8_t) d8;
                        }
                }
        }
        return 0;
}

static void set_threads(int n) {
#ifdef _OPENMP
        omp_set_num_threads(n);
#endif
        imp_cv_hdr_threads_set(n);
}

static double rss_mib(void) {
        FILE *f = fopen("/proc/self/statm", "r");
        long pages = 0, res = 0;
        if (f) {
                if (fscanf(f, "%ld %ld", &pages, &res) != 2)
                        res = 0;
                fclose(f);
        }
        return res * (double) sysconf(_SC_PAGESIZE) / (1024.0 * 1024.0);
}

static void reset_hwm(void) {
        FILE *f = fopen("/proc/self/clear_refs", "w");
        if (f) {
                fputs("5", f);
                fclose(f);
        }
}

/* Error of est (f32, 1 channel) against the truth over the mask. */
static void evaluate(const struct stack *st, const struct imp_image *est, bool fit, struct outcome *o) {
        double s1 = 0, s2 = 0;
        long n = 0, bad = 0;
        for (int y = 0; y < st->h; y++)
                for (int x = 0; x < st->w; x++) {
                        size_t k = (size_t) y * st->w + x;
                        if (!st->mask[k])
                                continue;
                        double r = *imp_image_f32(est, x, y) / st->truth[k];
                        if (!isfinite(r)) {
                                bad++;
                                continue;
                        }
                        s1 += r;
                        s2 += r * r;
                        n++;
                }
        double scale = fit && s2 > 0 ? s1 / s2 : 1.0;
        double se = 0, sb = 0, bse[N_BINS] = { 0 };
        long bn[N_BINS] = { 0 };
        for (int y = 0; y < st->h; y++)
                for (int x = 0; x < st->w; x++) {
                        size_t k = (size_t) y * st->w + x;
                        if (!st->mask[k])
                                continue;
                        double r = *imp_image_f32(est, x, y) / st->truth[k];
                        if (!isfinite(r))
                                continue;
                        double d = scale * r - 1.0;
                        se += d * d;
                        sb += d;
                        /* decade of the gradient: x position */
                        int b = (int) (3.0 * x / st->w);
                        bse[b] += d * d;
                        bn[b]++;
                }
        o->scale = fit ? scale : (s2 > 0 ? s1 / s2 : 1.0);   /* impasto: the scale it would get */
        o->rel_rms = n ? sqrt(se / n) : NAN;
        o->rel_bias = n ? sb / n : NAN;
        for (int b = 0; b < N_BINS; b++)
                o->bin_rms[b] = bn[b] ? sqrt(bse[b] / bn[b]) : NAN;
        o->n_eval = n;
        o->n_bad = bad;
}

static void true_response8(float *lut) {
        const struct imp_sensor *s = &sensor12;
        for (int d = 0; d < IMP_CV_HDR_LUT; d++) {
                double dn12 = fmax(16.0 * d - s->black_level_dn, 8.0);
                lut[d] = (float) (dn12 * s->gain_e_per_dn / s->quantum_scale);
        }
}

/* Runs in the child. */
static void run_method(const struct stack *st, enum method m, int threads, int reps, struct outcome *o) {
        struct imp_error err = {};
        o->cv_threads_default = imp_cv_hdr_threads_get();
        snprintf(o->cv_framework, sizeof o->cv_framework, "%.31s", imp_cv_hdr_parallel_framework());
        set_threads(threads);
        reset_hwm();
        o->base_rss_mib = rss_mib();
        double times[64], exp_s[N_EXP];
        for (int i = 0; i < N_EXP; i++)
                exp_s[i] = exposure_us[i] * 1e-6;
        float lut[IMP_CV_HDR_LUT];
        const float *resp = NULL;
        if (m == M_CV_TRUE) {
                true_response8(lut);
                resp = lut;
        } else if (m == M_CV_DEFAULT) {
                /* OpenCV's own default, passed explicitly: 4.6 sets it up with
                 * response.at<Vec3f>(0) even for 1-channel frames and corrupts the heap
                 * (abort / SIGSEGV) when no response is given for grey input. */
                for (int d = 0; d < IMP_CV_HDR_LUT; d++)
                        lut[d] = (float) (d ? d : 1);
                resp = lut;
        } else if (m == M_CV_CALIB) {
                double t0 = now_ms();
                int r = imp_cv_hdr_calibrate_debevec((const struct imp_image *const *) st->f8, exp_s, N_EXP,
                                                     0, 0, false, lut, &err);
                o->calib_ms = now_ms() - t0;
                if (r < 0) {
                        snprintf(o->err, sizeof o->err, "%.255s", err.msg);
                        return;
                }
                resp = lut;
        }
        struct imp_image *cv_out = NULL;
        if (m >= M_CV_TRUE && imp_image_new(st->w, st->h, 1, IMP_PIX_F32, &cv_out) < 0) {
                snprintf(o->err, sizeof o->err, "out of memory");
                return;
        }
        struct imp_hdr_exposure ex[N_EXP];
        for (int i = 0; i < N_EXP; i++)
                ex[i] = (struct imp_hdr_exposure) {
                        .frame = m == M_IMP12 ? st->f12[i] : st->f8u16[i],
                        .exposure_us = exposure_us[i],
                };
        struct imp_hdr_result res = {};
        for (int rep = 0; rep <= reps; rep++) {            /* rep 0: warm-up, untimed */
                imp_hdr_result_done(&res);
                double t0 = now_ms();
                int r;
                if (m <= M_IMP8)
                        r = imp_hdr_merge(ex, N_EXP, m == M_IMP12 ? &sensor12 : &sensor8, NULL, &res);
                else
                        r = imp_cv_hdr_merge_debevec((const struct imp_image *const *) st->f8, exp_s, N_EXP,
                                                     resp, cv_out, &err);
                double t = now_ms() - t0;
                if (r < 0) {
                        snprintf(o->err, sizeof o->err, "%.255s", m <= M_IMP8 ? strerror(-r) : err.msg);
                        return;
                }
                if (rep > 0)
                        times[rep - 1] = t;
        }
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        o->peak_rss_mib = ru.ru_maxrss / 1024.0;
        qsort(times, reps, sizeof *times, imp_cmp_double);
        o->ms_median = times[reps / 2];
        o->ms_min = times[0];
        evaluate(st, m <= M_IMP8 ? res.value : cv_out, m >= M_CV_TRUE, o);
        imp_hdr_result_done(&res);
        imp_image_free(cv_out);
        o->ok = 1;
}

static int run_forked(const struct stack *st, enum method m, int threads, int reps, struct outcome *o) {
        int fd[2];
        *o = (struct outcome) {};
        if (pipe(fd) < 0)
                return -errno;
        fflush(stdout);
        pid_t pid = fork();
        if (pid < 0)
                return -errno;
        if (pid == 0) {
                close(fd[0]);
                struct outcome c = {};
                run_method(st, m, threads, reps, &c);
                ssize_t wr = write(fd[1], &c, sizeof c);
                _exit(wr == (ssize_t) sizeof c ? 0 : 1);
        }
        close(fd[1]);
        ssize_t rd = read(fd[0], o, sizeof *o);
        close(fd[0]);
        int status;
        waitpid(pid, &status, 0);
        if (rd != (ssize_t) sizeof *o) {
                snprintf(o->err, sizeof o->err, "child failed (status %d)", status);
                o->ok = 0;
        }
        return 0;
}

static bool read_full(int fd, void *buf, size_t len) {
        uint8_t *p = buf;
        while (len > 0) {
                ssize_t rd = read(fd, p, len);
                if (rd <= 0)
                        return false;
                p += rd;
                len -= (size_t) rd;
        }
        return true;
}

#define MAX_REPS 64
struct timing {                                     /* child → parent through a pipe */
        int ok;
        char err[256];
        double wall[N_METHODS][MAX_REPS], thr[N_METHODS][MAX_REPS], proc[N_METHODS][MAX_REPS];
};

/* Runs in the child: every method once per round, rotating the order. */
static void run_interleaved(const struct stack *st, int threads, int reps, bool warm_malloc, struct timing *t) {
        struct imp_error err = {};
        if (warm_malloc) {       /* freed blocks stay mapped: no page faults on re-allocation */
                mallopt(M_MMAP_THRESHOLD, 1 << 30);
                mallopt(M_TRIM_THRESHOLD, 1 << 30);
        }
        double exp_s[N_EXP];
        float lut[N_METHODS][IMP_CV_HDR_LUT];
        struct imp_hdr_exposure ex[N_METHODS][N_EXP];
        set_threads(threads);
        for (int i = 0; i < N_EXP; i++) {
                exp_s[i] = exposure_us[i] * 1e-6;
                ex[M_IMP12][i] = (struct imp_hdr_exposure) { .frame = st->f12[i], .exposure_us = exposure_us[i] };
                ex[M_IMP8][i] = (struct imp_hdr_exposure) { .frame = st->f8u16[i], .exposure_us = exposure_us[i] };
        }
        true_response8(lut[M_CV_TRUE]);
        for (int d = 0; d < IMP_CV_HDR_LUT; d++)      /* OpenCV's default, explicit (see run_method) */
                lut[M_CV_DEFAULT][d] = (float) (d ? d : 1);
        if (imp_cv_hdr_calibrate_debevec((const struct imp_image *const *) st->f8, exp_s, N_EXP, 0, 0, false,
                                         lut[M_CV_CALIB], &err) < 0) {
                snprintf(t->err, sizeof t->err, "CalibrateDebevec: %.200s", err.msg);
                return;
        }
        struct imp_image *cv_out = NULL;
        if (imp_image_new(st->w, st->h, 1, IMP_PIX_F32, &cv_out) < 0) {
                snprintf(t->err, sizeof t->err, "out of memory");
                return;
        }
        struct imp_hdr_result res = {};
        for (int round = -1; round < reps; round++)      /* round -1: warm-up, untimed */
                for (int k = 0; k < N_METHODS; k++) {
                        int m = (round < 0 ? k : round + k) % N_METHODS;
                        imp_hdr_result_done(&res);
                        double w0 = now_ms(), c0 = clock_ms(CLOCK_THREAD_CPUTIME_ID),
                               p0 = clock_ms(CLOCK_PROCESS_CPUTIME_ID);
                        int r = m <= M_IMP8 ?
                                imp_hdr_merge(ex[m], N_EXP, m == M_IMP12 ? &sensor12 : &sensor8, NULL, &res) :
                                imp_cv_hdr_merge_debevec((const struct imp_image *const *) st->f8, exp_s, N_EXP,
                                                         lut[m], cv_out, &err);
                        double w1 = now_ms(), c1 = clock_ms(CLOCK_THREAD_CPUTIME_ID),
                               p1 = clock_ms(CLOCK_PROCESS_CPUTIME_ID);
                        if (r < 0) {
                                snprintf(t->err, sizeof t->err, "%s: %.200s", method_name[m],
                                         m <= M_IMP8 ? strerror(-r) : err.msg);
                                goto out;
                        }
                        if (round >= 0) {
                                t->wall[m][round] = w1 - w0;
                                t->thr[m][round] = c1 - c0;
                                t->proc[m][round] = p1 - p0;
                        }
                }
        t->ok = 1;
out:
        imp_hdr_result_done(&res);
        imp_image_free(cv_out);
}

static void time_forked(const struct stack *st, int threads, int reps, bool warm_malloc, struct timing *t) {
        int fd[2];
        *t = (struct timing) {};
        if (pipe(fd) < 0) {
                snprintf(t->err, sizeof t->err, "pipe: %s", strerror(errno));
                return;
        }
        fflush(stdout);
        pid_t pid = fork();
        if (pid < 0) {
                snprintf(t->err, sizeof t->err, "fork: %s", strerror(errno));
                close(fd[0]);
                close(fd[1]);
                return;
        }
        if (pid == 0) {
                close(fd[0]);
                static struct timing c;
                run_interleaved(st, threads, reps, warm_malloc, &c);
                ssize_t wr = write(fd[1], &c, sizeof c);
                _exit(wr == (ssize_t) sizeof c ? 0 : 1);
        }
        close(fd[1]);
        bool got = read_full(fd[0], t, sizeof *t);
        close(fd[0]);
        int status;
        waitpid(pid, &status, 0);
        if (!got) {
                snprintf(t->err, sizeof t->err, "child failed (status %d)", status);
                t->ok = 0;
        }
}

static double median_of(const double *x, int n, double *ret_min, double *ret_max) {
        double tmp[MAX_REPS];
        memcpy(tmp, x, n * sizeof *x);
        qsort(tmp, n, sizeof *tmp, imp_cmp_double);
        if (ret_min)
                *ret_min = tmp[0];
        if (ret_max)
                *ret_max = tmp[n - 1];
        return imp_median_sorted(tmp, (size_t) n);
}

static void print_timing(const struct timing *t, int reps, double mpix) {
        printf("%-32s %8s %17s %8s %8s %7s %15s %9s\n", "method", "wall ms", "[min - max]", "thr CPU", "proc CPU",
               "Mpix/s", "speedup wall", "spd CPU");
        for (int m = 0; m < N_METHODS; m++) {
                double lo, hi, rw[MAX_REPS], rc[MAX_REPS], rlo, rhi;
                double wm = median_of(t->wall[m], reps, &lo, &hi);
                for (int k = 0; k < reps; k++) {
                        rw[k] = t->wall[M_CV_TRUE][k] / t->wall[m][k];
                        rc[k] = t->proc[M_CV_TRUE][k] / t->proc[m][k];
                }
                double sw = median_of(rw, reps, &rlo, &rhi);
                printf("%-32s %8.2f [%6.2f - %6.2f] %8.2f %8.2f %7.1f %5.2fx [%.2f-%.2f] %8.2fx\n", method_name[m], wm,
                       lo, hi, median_of(t->thr[m], reps, NULL, NULL), median_of(t->proc[m], reps, NULL, NULL),
                       mpix / (wm * 1e-3), sw, rlo, rhi, median_of(rc, reps, NULL, NULL));
        }
}

/* OpenCV 4.6 and 16-bit input: expect a refusal (run in a child: OpenCV prints nothing
 * but keep the parent free of OpenCV's thread pool before forking). */
static void probe_u16(const struct stack *st) {
        struct outcome o;
        int fd[2];
        if (pipe(fd) < 0)
                return;
        fflush(stdout);
        pid_t pid = fork();
        if (pid == 0) {
                close(fd[0]);
                struct outcome c = {};
                struct imp_error err = {};
                struct imp_image *out = NULL;
                double exp_s[N_EXP];
                for (int i = 0; i < N_EXP; i++)
                        exp_s[i] = exposure_us[i] * 1e-6;
                if (imp_image_new(st->w, st->h, 1, IMP_PIX_F32, &out) == 0) {
                        int r = imp_cv_hdr_merge_debevec((const struct imp_image *const *) st->f12, exp_s,
                                                         N_EXP, NULL, out, &err);
                        c.ok = r == 0;
                        snprintf(c.err, sizeof c.err, "%.255s", r == 0 ? "accepted" : err.msg);
                }
                imp_image_free(out);
                ssize_t wr = write(fd[1], &c, sizeof c);
                _exit(wr == (ssize_t) sizeof c ? 0 : 1);
        }
        close(fd[1]);
        ssize_t rd = read(fd[0], &o, sizeof o);
        close(fd[0]);
        waitpid(pid, NULL, 0);
        if (rd == (ssize_t) sizeof o) {
                char *nl = strchr(o.err, '\n');
                if (nl)
                        *nl = 0;
                printf("OpenCV MergeDebevec on the 12-bit (CV_16UC1) frames: %s\n", o.ok ? "accepted" : o.err);
        }
}

int main(int argc, char **argv) {
        int reps = argc > 1 ? atoi(argv[1]) : 7;
        if (reps < 1 || reps > MAX_REPS) {
                fprintf(stderr, "usage: bench-hdr [repetitions 1..64] [side ...]\n");
                return 2;
        }
        int sides[8] = { 1024, 2048 }, n_sides = 2;
        if (argc > 2) {
                n_sides = 0;
                for (int i = 2; i < argc && n_sides < 8; i++)
                        sides[n_sides++] = atoi(argv[i]);
        }
        printf("bench-hdr: 3 exposures (1, 4, 16 ms), 12-bit sensor (black 64 DN, 2.5 e/DN, read 3 e, "
               "full well 10000 e), radiance 1e-3..1.3; %d timed repetitions after 1 warm-up, median\n", reps);
        bool probed = false;
        for (int si = 0; si < n_sides; si++) {
                int side = sides[si];
                if (side < 16 || side > 8192)
                        continue;
                struct stack st;
                double t0 = now_ms();
                if (stack_render(side, side, &st) < 0) {
                        fprintf(stderr, "out of memory\n");
                        stack_free(&st);
                        return 1;
                }
                double mpix = (double) side * side / 1e6;
                long n_mask = 0;
                for (size_t k = 0; k < (size_t) side * side; k++)
                        n_mask += st.mask[k];
                printf("\n== %d x %d (%.2f Mpix), rendered in %.0f ms; evaluated pixels %ld (%.1f %%) ==\n",
                       side, side, mpix, now_ms() - t0, n_mask, 100.0 * n_mask / ((double) side * side));
                if (!probed) {
                        probe_u16(&st);
                        probed = true;
                }
                struct outcome o[N_METHODS];
                for (int m = 0; m < N_METHODS; m++)
                        run_forked(&st, m, 1, 1, &o[m]);
                if (si == 0)
                        printf("OpenCV parallel framework: %s, cv::getNumThreads() default %d\n",
                               o[M_CV_TRUE].cv_framework, o[M_CV_TRUE].cv_threads_default);
                printf("\n-- accuracy and memory (1 thread, one run after a warm-up, own child each) --\n");
                printf("%-32s %7s %8s %8s | rel RMS by decade (bright..dark) | %8s %8s\n",
                       "method", "scale", "relRMS", "relBias", "peakRSS", "+work");
                for (int m = 0; m < N_METHODS; m++) {
                        if (!o[m].ok) {
                                printf("%-32s failed: %s\n", method_name[m], o[m].err);
                                continue;
                        }
                        printf("%-32s %7.4f %8.5f %+8.5f | %8.5f %8.5f %8.5f | %6.0fMiB %5.0fMiB",
                               method_name[m], o[m].scale, o[m].rel_rms, o[m].rel_bias,
                               o[m].bin_rms[0], o[m].bin_rms[1], o[m].bin_rms[2],
                               o[m].peak_rss_mib, o[m].peak_rss_mib - o[m].base_rss_mib);
                        if (m == M_CV_CALIB)
                                printf("  (+ CalibrateDebevec %.1f ms)", o[m].calib_ms);
                        if (o[m].n_bad)
                                printf("  (%ld non-finite)", o[m].n_bad);
                        printf("\n");
                }
                for (int k = 0; k < 4; k++) {
                        static struct timing t;
                        int threads = 1 + (k & 1);
                        bool warm = k >= 2;
                        time_forked(&st, threads, reps, warm, &t);
                        printf("\n-- speed, %d thread%s, %s: %d interleaved rounds, ms --\n", threads,
                               threads > 1 ? "s" : "", warm ? "malloc keeps freed memory mapped" : "default malloc", reps);
                        if (!t.ok) {
                                printf("failed: %s\n", t.err);
                                continue;
                        }
                        print_timing(&t, reps, mpix);
                }
                stack_free(&st);
        }
        printf("\nspeedup: median over rounds of t(OpenCV MergeDebevec, true response) / t(method) in the same "
               "round (wall; 'spd CPU': process CPU time). thr CPU: CPU time of the calling thread; proc CPU: "
               "all threads of the process. 'malloc keeps freed memory mapped': M_MMAP_THRESHOLD and "
               "M_TRIM_THRESHOLD 1 GiB, so repeated calls reuse pages instead of faulting fresh ones in. scale: least-squares scale (applied to OpenCV rows only). +work: "
               "peak RSS minus the RSS at the start of the method's child (frames and scene inherited).\n");
        return 0;
}
