/* impasto bench tile [CAPTURE] [--threads N] [--out DIR] [--repeat N]: one tile processed
 * as `impasto process` processes it (imp_process_capture, default options: no held-out
 * validation unless asked for), against the hardware time of capturing it (the plan's
 * estimate, imp_plan_estimate_s, as `impasto plan estimate` prints it). Prints the
 * processing wall and CPU time, each stage's seconds from copy.json, the capture estimate,
 * their ratio (goal ≤ 1: processing keeps pace with capture), the load average and peak RSS
 * (docs/processing-speed.md). CAPTURE defaults to the demo's (out/demo/capture of the
 * source tree, made by scripts/demo; or `impasto sim render --scene config/scenes/demo.cfg
 * --plan config/plans/demo.cfg --out DIR`). */
#include <getopt.h>
#include <jansson.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>
#include "bench-study.h"
#include "captureset.h"
#include "exit-codes.h"
#include "plan.h"
#include "process.h"

static double tile_now(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double tile_cpu(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return ru.ru_utime.tv_sec + 1e-6 * ru.ru_utime.tv_usec + ru.ru_stime.tv_sec + 1e-6 * ru.ru_stime.tv_usec;
}

/* CPU time of the thread that called imp_process_capture() (read from whichever thread
 * reports progress): what a stage leaves on one core. With OMP_WAIT_POLICY=passive its
 * waits at the parallel regions' ends cost none, so on free cores a stage's wall time is
 * about this, whatever else a shared machine runs. */
static clockid_t main_clock;

static double tile_main_cpu(void) {
        struct timespec ts;
        if (clock_gettime(main_clock, &ts) < 0)
                return 0;
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

/* The capture estimate of the set's own plan (plan.cfg against its rig.json). */
static int capture_estimate(const char *capture, double *ret_s) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        struct imp_error err = {};
        char path[4096];
        snprintf(path, sizeof path, "%s/plan.cfg", capture);
        if (imp_captureset_open(capture, &cs, &err) < 0 ||
            imp_plan_load(path, imp_captureset_rig(cs), &plan, &err) < 0) {
                fprintf(stderr, "impasto bench tile: %s\n", err.msg);
                return -1;
        }
        *ret_s = imp_plan_estimate_s(plan, imp_captureset_rig(cs));
        return 0;
}

/* Wall and CPU time between progress callbacks, gathered per stage: the interval that ends
 * at a stage's last callback is that stage's; one that ends at a stage's first (done 0) is
 * what ran before it. CPU time (the process's, all threads) is what a loaded machine does
 * not inflate much; wall time is what the goal counts. */
#define MAX_SEG 32
struct seg { char name[48]; double wall, cpu, main; };
struct timing { struct seg s[MAX_SEG]; int n; double wall, cpu, main; };

static void on_progress(void *userdata, const char *stage, size_t done, size_t total) {
        struct timing *t = userdata;
        double w = tile_now(), c = tile_cpu(), mc = tile_main_cpu();
        char name[48];
        if (!strcmp(stage, "height fusion") && done == 0)
                snprintf(name, sizeof name, "photometric normals");
        else if (done == 0)
                snprintf(name, sizeof name, "(before %s)", stage);
        else
                snprintf(name, sizeof name, "%s", stage);
        if (!strcmp(stage, "photometric normals") && done == total)
                snprintf(name, sizeof name, "(photometric stage, rest)");
        int i = 0;
        while (i < t->n && strcmp(t->s[i].name, name))
                i++;
        if (i == t->n && t->n < MAX_SEG)
                snprintf(t->s[t->n++].name, sizeof name, "%s", name);
        if (i < t->n) {
                t->s[i].wall += w - t->wall;
                t->s[i].cpu += c - t->cpu;
                t->s[i].main += mc - t->main;
        }
        t->wall = w;
        t->cpu = c;
        t->main = mc;
}

static const struct seg *find_seg(const struct timing *t, const char *name) {
        for (int i = 0; i < t->n; i++)
                if (!strcmp(t->s[i].name, name))
                        return &t->s[i];
        return NULL;
}

/* The photometric normals (without the height fusion, which has its own report) against the
 * BTF fit, both measured in this run: goal ≤ 1. CPU time is the figure a loaded machine
 * inflates least. */
static void print_photometric_vs_fit(const struct timing *t) {
        const struct seg *pn = find_seg(t, "photometric normals"), *fit = find_seg(t, "btf fit");
        if (!pn || !fit || !(fit->cpu > 0) || !(fit->wall > 0)) {
                printf("  photometric / fit: (a stage did not run)\n");
                return;
        }
        printf("  photometric / fit: %.2f CPU (%.2f s / %.2f s), %.2f wall (goal ≤ 1.0)\n", pn->cpu / fit->cpu,
               pn->cpu, fit->cpu, pn->wall / fit->wall);
}

static double stage_s(json_t *stages, const char *stage, const char *key) {
        json_t *v = json_object_get(json_object_get(stages, stage), key);
        return json_is_number(v) ? json_number_value(v) : -1;
}

/* Each stage's seconds from OUT/copy.json (-1: the stage did not run). */
static void print_stages(const char *out) {
        char path[4096];
        snprintf(path, sizeof path, "%s/copy.json", out);
        json_t *copy = json_load_file(path, 0, NULL);
        json_t *st = json_object_get(copy, "stages");
        static const struct { const char *stage, *key, *label; } rows[] = {
                { "hdr", "seconds", "HDR merge, structured-light frames" },
                { "structured_light", "seconds", "structured-light decode" },
                { "triangulation", "seconds", "triangulation" },
                { "heightfield", "seconds", "heightfield" },
                { "btf", "seconds_hdr", "HDR merge, dome frames" },
                { "photometric", "seconds", "photometric normals (incl. fusion)" },
                { "fusion", "seconds", "  of which height fusion" },
                { "btf", "seconds_fit", "BTF samples + fit + fill" },
                { "boxes", "seconds", "relief boxes" },
        };
        for (size_t i = 0; i < sizeof rows / sizeof rows[0]; i++) {
                double s = stage_s(st, rows[i].stage, rows[i].key);
                if (s >= 0)
                        printf("    %-38s %7.2f s\n", rows[i].label, s);
                else
                        printf("    %-38s     (not run)\n", rows[i].label);
        }
        json_t *v = json_object_get(json_object_get(st, "btf"), "validation");
        if (v)
                printf("    %-38s %7.2f s\n", "held-out validation", json_number_value(json_object_get(v, "seconds")));
        json_decref(copy);
}

static int tile_run(int argc, char **argv) {
        static const struct option longopts[] = {
                { "threads", required_argument, NULL, 't' }, { "out", required_argument, NULL, 'o' },
                { "holdout", required_argument, NULL, 'H' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int threads = 2, holdout = 0, c;
        const char *out = NULL;
        while ((c = getopt_long(argc, argv, "h", longopts, NULL)) >= 0)
                switch (c) {
                case 't': threads = atoi(optarg); break;
                case 'o': out = optarg; break;
                case 'H': holdout = atoi(optarg); break;
                case 'h':
                        printf("usage: impasto bench tile [CAPTURE] [--threads N (2)] [--out DIR] [--holdout N (0)]\n");
                        return IMP_EXIT_OK;
                default:
                        return IMP_EXIT_USAGE;
                }
        const char *capture = optind < argc ? argv[optind] : IMPASTO_SOURCE_DIR "/out/demo/capture";
        char outbuf[64];
        if (!out) {
                snprintf(outbuf, sizeof outbuf, "/tmp/impasto-bench-tile-%d", (int) getpid());
                out = outbuf;
        }
        double est;
        if (capture_estimate(capture, &est) < 0) {
                fprintf(stderr, "impasto bench tile: no capture set at %s (run scripts/demo, or pass one)\n", capture);
                return IMP_EXIT_BAD_INPUT;
        }
        struct imp_process_options o;
        imp_process_options_default(&o);
        o.threads = threads;
        o.holdout_every = holdout;
        struct imp_error err = {};
        double load0[3] = { 0 }, load1[3] = { 0 };
        getloadavg(load0, 3);
        static struct timing tm;
        o.progress = on_progress;
        o.userdata = &tm;
        if (pthread_getcpuclockid(pthread_self(), &main_clock) != 0)
                main_clock = CLOCK_THREAD_CPUTIME_ID;
        double t0 = tile_now(), c0 = tile_cpu(), m0 = tile_main_cpu();
        tm.wall = t0;
        tm.cpu = c0;
        tm.main = m0;
        int r = imp_process_capture(capture, out, &o, &err);
        double t = tile_now() - t0, cpu = tile_cpu() - c0;
        getloadavg(load1, 3);
        o.progress = NULL;
        if (r < 0) {
                fprintf(stderr, "impasto bench tile: %s\n", err.msg);
                return IMP_EXIT_FAILURE;
        }
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        /* libgomp reads the wait policy when it loads: spinning threads cost CPU time on a
         * loaded machine, so the figures say which policy they were taken with */
        const char *wait = getenv("OMP_WAIT_POLICY");
        const char *tun = getenv("GLIBC_TUNABLES");
        printf("tile: %s → %s, %d threads, held-out validation %s, OMP_WAIT_POLICY %s, GLIBC_TUNABLES %s\n", capture,
               out, threads, holdout > 0 ? "on" : "off", wait && *wait ? wait : "unset (spin, then sleep)",
               tun && *tun ? tun : "unset");
        printf("  stages (copy.json seconds, wall):\n");
        print_stages(out);
        printf("  between progress reports (wall / CPU of all threads / CPU of the main thread):\n");
        for (int i = 0; i < tm.n; i++)
                printf("    %-38s %7.2f s  %7.2f s CPU  %6.2f s main\n", tm.s[i].name, tm.s[i].wall, tm.s[i].cpu,
                       tm.s[i].main);
        printf("    %-38s %7.2f s  %7.2f s CPU  %6.2f s main\n", "(after the last report: outputs)", t0 + t - tm.wall,
               c0 + cpu - tm.cpu, tile_main_cpu() - tm.main);
        print_photometric_vs_fit(&tm);
        printf("  processing      %7.2f s wall, %.2f s CPU (load average %.1f before, %.1f after)\n", t, cpu,
               load0[0], load1[0]);
        printf("  capture (plan)  %7.2f s (imp_plan_estimate_s)\n", est);
        printf("  ratio processing / capture: %.2f (goal ≤ 1.0); CPU-bound estimate on %d free cores: %.2f\n",
               t / est, threads, cpu / threads / est);
        printf("  peak RSS: %.0f MB\n", ru.ru_maxrss / 1024.0);
        return IMP_EXIT_OK;
}

IMP_BENCH_STUDY(tile, .name = "tile",
                .summary = "one tile processed against its capture estimate (docs/processing-speed.md)",
                .run = tile_run, .hugepages = true);
