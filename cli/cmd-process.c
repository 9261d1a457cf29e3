/* `impasto process CAPTURE_DIR --out COPY_DIR`: a capture set in, the digital copy out
 * (pipeline/process.c does the work), with a progress bar on a terminal and one line per
 * stage otherwise, both with the overall ETA. */
#define _GNU_SOURCE 1
#include <dirent.h>
#include <errno.h>
#include <ftw.h>
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "commands.h"
#include "exit-codes.h"
#include "json-util.h"
#include "log.h"
#include "macro.h"
#include "numparse.h"
#include "process.h"
#include "process-photometric.h"
#include "process-range.h"

/* Exit codes of `impasto process` (docs/copy-quality.md), those of every command (exit-codes.h). */
#define IMP_EXIT_PROCESS_FAILED   IMP_EXIT_FAILURE       /* I/O, memory, a stage failed */
#define IMP_EXIT_PROCESS_USAGE    IMP_EXIT_USAGE
#define IMP_EXIT_PROCESS_INVALID  IMP_EXIT_BAD_INPUT     /* the capture set cannot be processed */
#define IMP_EXIT_PROCESS_UNUSABLE IMP_EXIT_UNDETERMINED  /* processed, but the copy's verdict is "unusable" */

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

/* A copy without its BRDF maps although the BTF was asked for: the set had no dome sweep. */
static void say_if_no_btf(const char *out) {
        char path[PATH_MAX + 16];
        snprintf(path, sizeof path, "%s/rho_d.exr", out);
        if (access(path, F_OK) < 0)
                printf("no BTF possible: the capture set has no photometric (dome) frames; the copy holds the "
                       "geometry only (heights, boxes), no BRDF maps\n");
}

/* Progress of the whole run: the stage's place in it (imp_process_fraction) gives the ETA. */
struct progress {
        double t0, t_stage, fraction;
        char stage[64];
};

static double mono_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* "about 2 min 10 s left", or "" while too little is done to say. */
static void eta(const struct progress *p, double now, char *buf, size_t size) {
        double f = p->fraction, left = f > 0.02 && f < 1 ? (now - p->t0) * (1 - f) / f : -1;
        if (left < 0)
                snprintf(buf, size, "%s", f >= 1 ? "done" : "");
        else if (left >= 60)
                snprintf(buf, size, "about %d min %02d s left", (int) (left / 60), (int) left % 60);
        else
                snprintf(buf, size, "about %.0f s left", left);
}

/* A terminal: one bar redrawn in place, with the overall ETA. */
static void progress_bar(void *userdata, const char *stage, size_t done, size_t total) {
        struct progress *p = userdata;
        double now = mono_s();
        p->fraction = imp_process_fraction(p->fraction, stage, done, total);
        char left[64];
        eta(p, now, left, sizeof left);
        int width = 30, fill = total ? (int) (width * done / total) : width;
        fprintf(stderr, "\r%-18s [%.*s%*s] %zu/%zu  %-24s", stage, fill,
                "##############################", width - fill, "", done, total, left);
        if (done == total)
                fputc('\n', stderr);
        fflush(stderr);
}

/* A pipe or a file (a log, a job runner): one line per stage as it ends, with the time it
 * took, the run's elapsed time and the overall ETA; no carriage returns. */
static void progress_lines(void *userdata, const char *stage, size_t done, size_t total) {
        struct progress *p = userdata;
        double now = mono_s();
        if (strcmp(p->stage, stage)) {
                snprintf(p->stage, sizeof p->stage, "%s", stage);
                p->t_stage = now;
        }
        p->fraction = imp_process_fraction(p->fraction, stage, done, total);
        if (done != total)
                return;
        char left[64];
        eta(p, now, left, sizeof left);
        fprintf(stderr, "process: %s done in %.1f s (%.0f %% of the run, %.0f s elapsed%s%s)\n", stage,
                now - p->t_stage, 100 * p->fraction, now - p->t0, left[0] ? ", " : "", left);
        fflush(stderr);
        p->stage[0] = 0;
}

/* The absolute form of path, which need not exist yet: its deepest existing ancestor
 * resolved (symbolic links, ..), the rest appended. */
static int resolve_future(const char *path, char ret[PATH_MAX]) {
        char head[PATH_MAX], tail[PATH_MAX] = "";
        if (snprintf(head, sizeof head, "%s", path) >= (int) sizeof head)
                return -ENAMETOOLONG;
        for (;;) {
                if (realpath(head[0] ? head : ".", ret)) {
                        size_t n = strlen(ret);
                        return snprintf(ret + n, PATH_MAX - n, "%s", tail) >= (int) (PATH_MAX - n) ? -ENAMETOOLONG : 0;
                }
                if (errno != ENOENT)
                        return -errno;
                char *slash = strrchr(head, '/');
                char part[2 * PATH_MAX + 2];
                snprintf(part, sizeof part, "/%s%s", slash ? slash + 1 : head, tail);
                if (strlen(part) >= sizeof tail)
                        return -ENAMETOOLONG;
                memcpy(tail, part, sizeof tail);
                if (!slash)
                        head[0] = 0;
                else if (slash == head)
                        head[1] = 0;
                else
                        *slash = 0;
        }
}

DEFINE_TRIVIAL_CLEANUP_FUNC(DIR *, closedir)

/* true when dir exists and holds anything. */
static bool nonempty_dir(const char *dir) {
        _cleanup_(closedirp) DIR *d = opendir(dir);
        if (!d)
                return false;
        for (struct dirent *e; (e = readdir(d));)
                if (strcmp(e->d_name, ".") && strcmp(e->d_name, ".."))
                        return true;
        return false;
}

static int rm_entry(const char *path, const struct stat *st, int flag, struct FTW *ftw) {
        return remove(path) < 0 ? -1 : 0;
}

/* --force over an existing copy: the new copy is built beside it (OUT.partial-PID, same file
 * system) and swapped in when this run wrote one, so no file of the old copy survives in the
 * new one and a run that writes nothing leaves the old copy as it was. */
static int force_place(const char *out, char *work, size_t size) {
        size_t n = strlen(out);
        while (n > 1 && out[n - 1] == '/')
                n--;
        if (snprintf(work, size, "%.*s.partial-%d", (int) n, out, (int) getpid()) >= (int) size)
                return -ENAMETOOLONG;
        return 0;
}

static void force_swap(const char *out, const char *work) {
        char path[PATH_MAX + 48], old[PATH_MAX + 48];
        snprintf(path, sizeof path, "%s/copy.json", work);
        if (access(path, F_OK) < 0) {
                (void) nftw(work, rm_entry, 16, FTW_DEPTH | FTW_PHYS);
                log_notice("--out %s: left as it was (this run wrote no copy)", out);
                return;
        }
        snprintf(old, sizeof old, "%s", work);
        memcpy(strrchr(old, '.'), ".old-", 5);          /* OUT.old-PID */
        if (rename(out, old) < 0 || rename(work, out) < 0) {
                log_error("--out %s: replacing the old copy: %m; the new one is in %s", out, work);
                return;
        }
        if (nftw(old, rm_entry, 16, FTW_DEPTH | FTW_PHYS) < 0)
                log_warning("removing the old copy %s: %m", old);
}

/* A failed run: the message, copy.json's verdict when one was written, the exit code. */
static int exit_for_error(int r, const struct imp_error *err, const char *out) {
        log_error("%s", err->msg[0] ? err->msg : strerror(-r));
        if (r == -ENODATA && print_quality(out))
                return IMP_EXIT_PROCESS_UNUSABLE;
        if (r == -EINVAL || r == -EBADMSG || r == -ENODATA) {   /* an unusable copy.json says why */
                print_quality(out);
                return IMP_EXIT_PROCESS_INVALID;
        }
        if (r == -ENOENT || r == -ENOTDIR || r == -EPROTONOSUPPORT)   /* no set, or not one we read */
                return IMP_EXIT_PROCESS_INVALID;
        return IMP_EXIT_PROCESS_FAILED;
}

/* The places a copy may not go: into the raw capture set (a reader never modifies what it
 * reads), over an existing copy or other files without --force. Returns an exit code, 0 = go. */
static int check_places(const char *cap, const char *out, bool force) {
        char rcap[PATH_MAX], rout[PATH_MAX];
        if (!realpath(cap, rcap)) {
                log_error("%s: %m (expected a capture set directory)", cap);
                return IMP_EXIT_BAD_INPUT;
        }
        int r = resolve_future(out, rout);
        if (r < 0) {
                log_error("--out %s: %s", out, strerror(-r));
                return IMP_EXIT_USAGE;
        }
        size_t n = strlen(rcap);
        if (!strncmp(rout, rcap, n) && (rout[n] == 0 || rout[n] == '/')) {
                log_error("--out %s: lies inside the capture set %s, which is never written to; "
                          "choose a folder outside it", out, cap);
                return IMP_EXIT_USAGE;
        }
        if (!force && nonempty_dir(out)) {
                char path[PATH_MAX + 16];
                snprintf(path, sizeof path, "%s/copy.json", out);
                log_error("--out %s: %s; not overwritten (--force replaces it)", out,
                          access(path, F_OK) == 0 ? "holds a digital copy already" : "is not empty");
                return IMP_EXIT_USAGE;
        }
        return 0;
}

static void usage(FILE *f) {
        fprintf(f, "usage: impasto process CAPTURE_DIR --out COPY_DIR [--pitch MM] [--cell N]\n"
                   "                       [--delta FRACTION] [--no-btf] [--holdout N] [--quiet]\n"
                   "                       [--no-photometric-normals] [--threads N] [--gray-only]\n"
                   "                       [--btf-iterations N] [--btf-robust-passes N] [--no-shadow-test]\n"
                   "                       [--photometric-only | --range-only] [--allow-incomplete] [--force]\n"
                   "                       [--frame-search | --no-frame-search]\n"
                   "  COPY_DIR must lie outside CAPTURE_DIR and be new or empty; --force writes over\n"
                   "                an existing copy\n"
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
                   "  --pitch MM    the copy's grid pitch; without it (or 0) a painting's tile gets the\n"
                   "                painting's pitch (docs/painting.md), any other set its camera footprint\n"
                   "  --no-frame-search  the whole field is canvas (no frame looked for): the default for a\n"
                   "                painting's tile (its plan.cfg has a painting group, or ../../painting.json\n"
                   "                lists it); --frame-search looks for a frame even there\n"
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
        struct progress prog = { .t0 = mono_s() };
        o.progress = isatty(STDERR_FILENO) ? progress_bar : progress_lines;
        o.userdata = &prog;
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
                { "allow-incomplete", no_argument, NULL, 'A' }, { "force", no_argument, NULL, 'F' },
                { "frame-search", no_argument, NULL, 'f' }, { "no-frame-search", no_argument, NULL, 'W' },
                { "help", no_argument, NULL, 'h' }, {}
        };
        bool photometric_only = false, range_only = false, force = false;
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
                case 'f': o.frame_search = IMP_FRAME_SEARCH_ON; break;
                case 'W': o.frame_search = IMP_FRAME_SEARCH_OFF; break;
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
                case 'F': force = true; break;
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
        int e = check_places(argv[optind], out, force);
        if (e)
                return e;
        struct timespec t0, t1;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        struct imp_error err = {};
        struct imp_po_options po;
        imp_po_options_default(&po);
        po.btf = o.btf;
        po.threads = o.threads;
        char work[PATH_MAX + 32];
        const char *dest = out;
        if (force && nonempty_dir(out)) {
                if (force_place(out, work, sizeof work) < 0) {
                        log_error("--out %s: name too long", out);
                        return IMP_EXIT_PROCESS_USAGE;
                }
                dest = work;
        }
        int r = range_only ? imp_process_range(argv[optind], dest, &err)
                : photometric_only ? imp_process_photometric(argv[optind], dest, &po, &err)
                : imp_process_capture(argv[optind], dest, &o, &err);
        if (dest != out)
                force_swap(out, work);
        if (r < 0)
                return exit_for_error(r, &err, out);
        clock_gettime(CLOCK_MONOTONIC, &t1);
        printf("digital copy written to %s (%.1f s)\n", out,
               (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9);
        if (o.btf && !range_only)
                say_if_no_btf(out);
        return print_quality(out) ? IMP_EXIT_PROCESS_UNUSABLE : 0;
}

const struct imp_command imp_cmd_process = {
        .name = "process",
        .summary = "turn a capture set into a digital copy (heightfield, boxes, BTF)",
        .run = run,
        .hugepages = true,
};
