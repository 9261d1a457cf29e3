/* `impasto process CAPTURE_DIR --out COPY_DIR`: a capture set in, the digital copy out
 * (pipeline/process.c does the work), with a progress bar on a terminal. */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "commands.h"
#include "json-util.h"
#include "log.h"
#include "numparse.h"
#include "process.h"
#include "process-photometric.h"
#include "process-range.h"

/* Exit codes of `impasto process` (docs/copy-quality.md). */
#define IMP_EXIT_PROCESS_FAILED   1   /* I/O, memory, a stage failed */
#define IMP_EXIT_PROCESS_USAGE    2
#define IMP_EXIT_PROCESS_INVALID  3   /* the capture set cannot be processed */
#define IMP_EXIT_PROCESS_UNUSABLE 6   /* processed, but the copy's verdict is "unusable" */

/* Prints copy.json's quality verdict and reasons; returns true when it is "unusable". */
static bool print_quality(const char *out) {
        char path[4096];
        snprintf(path, sizeof path, "%s/copy.json", out);
        _cleanup_json_ json_t *j = NULL;
        if (imp_json_load(path, &j, NULL) < 0)
                return false;
        json_t *q = json_object_get(j, "quality");
        const char *v = json_string_value(json_object_get(q, "verdict"));
        if (!v)
                return false;
        printf("quality: %s (%.1f %% of the canvas texels flagged)\n", v,
               100 * json_number_value(json_object_get(q, "flagged_fraction")));
        size_t i;
        json_t *r;
        json_array_foreach(json_object_get(q, "reasons"), i, r)
                printf("  %s\n", json_string_value(r));
        return !strcmp(v, "unusable");
}

static void progress_bar(void *userdata, const char *stage, size_t done, size_t total) {
        int width = 30, fill = total ? (int) (width * done / total) : width;
        fprintf(stderr, "\r%-18s [%.*s%*s] %zu/%zu", stage, fill,
                "##############################", width - fill, "", done, total);
        if (done == total)
                fputc('\n', stderr);
        fflush(stderr);
}

static void usage(FILE *f) {
        fprintf(f, "usage: impasto process CAPTURE_DIR --out COPY_DIR [--pitch MM] [--cell N]\n"
                   "                       [--delta FRACTION] [--no-btf] [--holdout N] [--quiet]\n"
                   "                       [--no-photometric-normals] [--threads N] [--gray-only]\n"
                   "                       [--btf-iterations N] [--btf-robust-passes N] [--no-shadow-test]\n"
                   "                       [--photometric-only | --range-only]\n"
                   "  --photometric-only  dome frames alone (e.g. `impasto import photometric`): normals, albedo,\n"
                   "                BTF and integrated heights on the pixel grid (docs/import.md)\n"
                   "  --range-only  structured light alone (e.g. `impasto import sl`): range.exr on the\n"
                   "                camera grid (docs/import.md)\n"
                   "  --holdout N   leave every Nth dome light out of the fit and report the\n"
                   "                re-render error on those lights in copy.json\n"
                   "  --no-photometric-normals  keep the geometric (structured-light) normals\n"
                   "                instead of refining them from the dome sweep\n"
                   "  cost knobs (docs/accuracy-vs-time.md): --threads N OpenMP threads (0: all);\n"
                   "                --gray-only decodes the Gray code alone; --btf-iterations N LM\n"
                   "                iterations per pass (0: default); --btf-robust-passes N Huber\n"
                   "                reweightings (-1: default); --no-shadow-test keeps self-shadowed samples\n"
                   "  --allow-incomplete  process a set that lacks frames of its plan (refused\n"
                   "                otherwise); what is missing goes to copy.json provenance.incomplete\n");
}

/* An integer option from lo to 1000 (--holdout 0 = none, --threads 0 = all, ...). */
static int int_arg(const char *name, const char *arg, long lo, int *ret) {
        char *end;
        long v = strtol(arg, &end, 10);
        if (end == arg || *end || v < lo || v > 1000) {
                log_error("--%s: expected an integer %ld..1000, got '%s'", name, lo, arg);
                return -EINVAL;
        }
        *ret = (int) v;
        return 0;
}

static int run(int argc, char **argv) {
        struct imp_process_options o;
        imp_process_options_default(&o);
        const char *out = NULL;
        if (isatty(STDERR_FILENO))
                o.progress = progress_bar;
        static const struct option longopts[] = {
                { "out", required_argument, NULL, 'o' }, { "pitch", required_argument, NULL, 'p' },
                { "cell", required_argument, NULL, 'n' }, { "delta", required_argument, NULL, 'd' },
                { "no-btf", no_argument, NULL, 'B' },
                { "no-photometric-normals", no_argument, NULL, 'P' },
                { "holdout", required_argument, NULL, 'H' }, { "quiet", no_argument, NULL, 'q' },
                { "threads", required_argument, NULL, 't' }, { "gray-only", no_argument, NULL, 'G' },
                { "btf-iterations", required_argument, NULL, 'I' },
                { "btf-robust-passes", required_argument, NULL, 'R' },
                { "no-shadow-test", no_argument, NULL, 'S' },
                { "photometric-only", no_argument, NULL, 'O' }, { "range-only", no_argument, NULL, 'Z' },
                { "allow-incomplete", no_argument, NULL, 'A' },
                { "help", no_argument, NULL, 'h' }, {}
        };
        bool photometric_only = false, range_only = false;
        int c, n;
        while ((c = getopt_long(argc, argv, "o:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'o': out = optarg; break;
                case 'p':   /* 0: the camera footprint */
                        if (imp_parse_double("--pitch", optarg, 0, 1000, &o.heightfield.pitch_mm) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        break;
                case 'n':
                        if (int_arg("cell", optarg, 0, &n) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        if (n > 0)   /* 0: the default */
                                o.boxes.cell_px = n;
                        break;
                case 'd': {
                        double v;
                        if (imp_parse_double("--delta", optarg, 0, 1, &v) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        if (v > 0)   /* 0: the default */
                                o.boxes.delta_frac = v;
                        break;
                }
                case 'B': o.btf = false; break;
                case 'P': o.photometric_normals = false; break;
                case 'H':
                        if (int_arg("holdout", optarg, 0, &o.holdout_every) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        break;
                case 't':
                        if (int_arg("threads", optarg, 0, &o.threads) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        break;
                case 'I':
                        if (int_arg("btf-iterations", optarg, 0, &n) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        if (n > 0)   /* 0: the fit's default */
                                o.btf_fit.max_iter = n;
                        break;
                case 'R':
                        if (int_arg("btf-robust-passes", optarg, -1, &n) < 0)
                                return IMP_EXIT_PROCESS_USAGE;
                        if (n >= 0)   /* -1: the fit's default */
                                o.btf_fit.robust_passes = n;
                        break;
                case 'G': o.sl_gray_only = true; break;
                case 'S': o.btf_samples.march_step_texels = 0; break;   /* no ray: nothing blocked */
                case 'A': o.allow_incomplete = true; break;
                case 'q': o.progress = NULL; break;
                case 'O': photometric_only = true; break;
                case 'Z': range_only = true; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_PROCESS_USAGE;
                }
        if (optind + 1 != argc || !out) {
                usage(stderr);
                return IMP_EXIT_PROCESS_USAGE;
        }
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        struct imp_error err = {};
        struct imp_po_options po;
        imp_po_options_default(&po);
        po.btf = o.btf;
        po.threads = o.threads;
        int r = range_only ? imp_process_range(argv[optind], out, &err)
                : photometric_only ? imp_process_photometric(argv[optind], out, &po, &err)
                : imp_process_capture(argv[optind], out, &o, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                if (r == -ENODATA && print_quality(out))
                        return IMP_EXIT_PROCESS_UNUSABLE;
                if (r == -EINVAL || r == -EBADMSG || r == -ENODATA) {   /* an unusable copy.json says why */
                        print_quality(out);
                        return IMP_EXIT_PROCESS_INVALID;
                }
                return IMP_EXIT_PROCESS_FAILED;
        }
        clock_gettime(CLOCK_MONOTONIC, &t1);
        printf("digital copy written to %s (%.1f s)\n", out,
               (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9);
        return print_quality(out) ? IMP_EXIT_PROCESS_UNUSABLE : 0;
}

const struct imp_command imp_cmd_process = {
        .name = "process",
        .summary = "turn a capture set into a digital copy (heightfield, boxes, BTF)",
        .run = run,
};
