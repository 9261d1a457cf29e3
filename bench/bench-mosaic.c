/* `impasto bench mosaic [--pitch MM] [--cache-mib N] [--only K]`: the mosaic of synthetic paintings of three
 * sizes up to 600 × 400 mm (docs/mosaic.md): per size the tiles, the time of registration +
 * adjustment + blending and writing per tile (linear growth means a flat per-tile time) and
 * the peak RSS of the process that did it (each size runs in its own child, so its peak is
 * its own). The synthetic tiles are written first, in another child, and not timed. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "bench-study.h"
#include "exit-codes.h"
#include "log.h"
#include "mosaic.h"

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

struct bench_result {
        size_t tiles, pairs_ok, loads, resident;
        double register_s, write_s, reg_um, seam_um;
};

/* In the child: register, adjust, write; the figures go back through a pipe. */
static size_t cache_bytes = (size_t) 1 << 30;

static int mosaic_child(const char *dir, const char *out, int fd) {
        struct imp_painting p;
        struct imp_error err = { 0 };
        struct imp_mosaic_options o;
        imp_mosaic_options_default(&o);
        o.cache_bytes = cache_bytes;
        struct bench_result b = { 0 };
        struct imp_mosaic_pair *pairs = NULL;
        struct imp_mosaic_adjust_stats st;
        struct imp_mosaic_figures f;
        struct imp_mosaic_reg_error re;
        size_t n = 0, ns;
        double t0 = now_s();
        if (imp_painting_load(dir, &p, &err) < 0 || imp_mosaic_register(&p, &o, &pairs, &n, &err) < 0 ||
            imp_mosaic_adjust(&p, pairs, n, &st, &err) < 0) {
                log_error("%s", err.msg);
                return 1;
        }
        for (size_t i = 0; i < n; i++)
                b.pairs_ok += pairs[i].ok;
        free(pairs);
        b.register_s = now_s() - t0;
        t0 = now_s();
        if (imp_mosaic_write(&p, &o, out, NULL, &f, &err) < 0) {
                log_error("%s", err.msg);
                return 1;
        }
        b.write_s = now_s() - t0;
        b.tiles = p.n_tiles, b.loads = f.input_loads, b.resident = f.max_resident;
        b.reg_um = imp_mosaic_registration_error(&p, &re) == 0 ? re.rms_um : NAN;
        b.seam_um = imp_mosaic_seam_step(&p, &o, &b.seam_um, &ns, &err) == 0 ? b.seam_um : NAN;
        imp_painting_done(&p);
        return write(fd, &b, sizeof b) == (ssize_t) sizeof b ? 0 : 1;
}

/* Runs fn in a child; its exit status and peak RSS (KiB). */
static int in_child(int (*fn)(const void *, int), const void *arg, int fd, long *ret_rss_kib) {
        pid_t pid = fork();
        if (pid < 0)
                return -errno;
        if (pid == 0)
                _exit(fn(arg, fd));
        int status;
        struct rusage ru;
        if (wait4(pid, &status, 0, &ru) < 0)
                return -errno;
        *ret_rss_kib = ru.ru_maxrss;
        return WIFEXITED(status) && WEXITSTATUS(status) == 0 ? 0 : -EIO;
}

struct size_arg {
        struct imp_mosaic_synth s;
        char dir[512], out[600];
};

static int synth_fn(const void *a, int fd) {
        const struct size_arg *x = a;
        struct imp_error err = { 0 };
        if (imp_mosaic_synth_write(&x->s, x->dir, &err) < 0) {
                log_error("%s", err.msg);
                return 1;
        }
        return 0;
}

static int mosaic_fn(const void *a, int fd) {
        const struct size_arg *x = a;
        return mosaic_child(x->dir, x->out, fd);
}

/* What the summary needs of each size. */
struct size_figures {
        bool done;
        double s_per_tile, rss_mib;
};

static int one_size(struct size_arg *x, const char *tmp, int k, struct size_figures *ret) {
        snprintf(x->dir, sizeof x->dir, "%s/painting-%d", tmp, k);
        snprintf(x->out, sizeof x->out, "%s/mosaic-%d", tmp, k);
        long rss_synth, rss;
        double t0 = now_s();
        if (in_child(synth_fn, x, -1, &rss_synth) < 0)
                return log_error("synthetic painting %d failed", k), 1;
        double synth_s = now_s() - t0;
        int pfd[2];
        if (pipe(pfd) < 0)
                return 1;
        int r = in_child(mosaic_fn, x, pfd[1], &rss);
        close(pfd[1]);
        struct bench_result b;
        bool got = read(pfd[0], &b, sizeof b) == (ssize_t) sizeof b;
        close(pfd[0]);
        if (r < 0 || !got)
                return log_error("mosaic %d failed", k), 1;
        double total = b.register_s + b.write_s;
        printf("%6.0f × %-4.0f mm %5zu tiles %4zu pairs | synth %6.1f s | register+adjust %7.2f s, blend+write %7.2f s, "
               "%6.3f s/tile | peak RSS %7.1f MiB | reads %zu, held ≤ %zu | reg %.2f µm, seam %.2f µm\n",
               x->s.extent_mm[0], x->s.extent_mm[1], b.tiles, b.pairs_ok, synth_s, b.register_s, b.write_s,
               total / b.tiles, rss / 1024.0, b.loads, b.resident, b.reg_um, b.seam_um);
        fflush(stdout);
        *ret = (struct size_figures) { true, total / b.tiles, rss / 1024.0 };
        char cmd[1400];
        snprintf(cmd, sizeof cmd, "rm -rf '%s' '%s'", x->dir, x->out);
        return system(cmd) == 0 ? 0 : 1;
}

/* The figures: peak RSS of the largest painting against 4 GiB, and linear time:
 * the time per tile of the largest painting over the smallest's (1 is linear, a quadratic
 * step would give ~19 from 9 to 169 tiles; below 1 the fixed costs spread over more tiles,
 * or the shared machine was less loaded). */
static void summary(const struct size_figures f[3]) {
        double rss = 0, first = 0, last = 0;
        int n = 0;
        for (int k = 0; k < 3; k++)
                if (f[k].done) {
                        rss = fmax(rss, f[k].rss_mib), n++;
                        if (!(first > 0))
                                first = f[k].s_per_tile;
                        last = f[k].s_per_tile;
                }
        printf("summary: peak RSS %.1f MiB (%s 4 GiB)", rss, rss <= 4096 ? "within" : "OVER");
        if (n >= 2)
                printf("; time per tile, largest painting over smallest: %.2f (%s)", last / first,
                       last / first <= 1.5 ? "linear or better" : "grows faster than linear");
        printf("\n");
}

static int run(int argc, char **argv) {
        double pitch = 0.05;
        int only = -1;
        for (int i = 1; i < argc; i++) {
                char *end;
                if (!strcmp(argv[i], "--cache-mib") && i + 1 < argc) {
                        long v = strtol(argv[++i], &end, 10);
                        if (*end || v < 16 || v > (1L << 20))
                                return log_error("--cache-mib: expected 16..1048576, got '%s'", argv[i]), IMP_EXIT_USAGE;
                        cache_bytes = (size_t) v << 20;
                        continue;
                }
                if (!strcmp(argv[i], "--only") && i + 1 < argc) {
                        long v = strtol(argv[++i], &end, 10);
                        if (*end || v < 0 || v > 2)
                                return log_error("--only: expected 0, 1 or 2 (the size), got '%s'", argv[i]), IMP_EXIT_USAGE;
                        only = (int) v;
                        continue;
                }
                if (!strcmp(argv[i], "--pitch") && i + 1 < argc) {
                        pitch = strtod(argv[++i], &end);
                        if (*end || !(pitch >= 0.01 && pitch <= 1))
                                return log_error("--pitch: expected 0.01..1 mm, got '%s'", argv[i]), IMP_EXIT_USAGE;
                } else {
                        fprintf(stderr, "usage: impasto bench mosaic [--pitch MM] [--cache-mib N] [--only 0|1|2]\n");
                        return !strcmp(argv[i], "--help") ? IMP_EXIT_OK : IMP_EXIT_USAGE;
                }
        }
        char tmp[256];
        const char *t = getenv("TMPDIR");
        snprintf(tmp, sizeof tmp, "%s/impasto-bench-mosaic-XXXXXX", t ? t : "/tmp");
        if (!mkdtemp(tmp))
                return log_error("mkdtemp: %s", strerror(errno)), IMP_EXIT_FAILURE;
        static const double sizes[3][2] = { { 150, 100 }, { 300, 200 }, { 600, 400 } };
        printf("mosaic bench: tiles of 60 × 40 mm at %.3f mm, 20%% overlap, stage σ 50 µm / 0.05°, cache %zu MiB\n", pitch,
               cache_bytes >> 20);
        int r = 0;
        struct size_figures f[3] = { 0 };
        for (int k = 0; k < 3 && r == 0; k++) {
                if (only >= 0 && k != only)
                        continue;
                struct size_arg x;
                imp_mosaic_synth_default(&x.s);
                x.s.extent_mm[0] = sizes[k][0], x.s.extent_mm[1] = sizes[k][1];
                x.s.fov_mm[0] = 60, x.s.fov_mm[1] = 40, x.s.pitch_mm = pitch;
                r = one_size(&x, tmp, k, &f[k]);
        }
        rmdir(tmp);
        if (r == 0)
                summary(f);
        return r ? IMP_EXIT_FAILURE : IMP_EXIT_OK;
}

IMP_BENCH_STUDY(mosaic, .name = "mosaic", .summary = "mosaic of synthetic paintings up to 600 × 400 mm: time per tile, peak RSS",
                .run = run);
