/* `impasto bench accuracy [--quick] [--out DIR] [--repo DIR] [--keep-sets]`:
 * what accuracy costs in time. Each study scene is rendered once with the richest plan;
 * every configuration's capture set is then derived by taking the frames its plan names
 * (2×2 binned for the binning knob), processed by its own `impasto process` process (fork
 * and exec of the `impasto` beside impasto-bench with the configuration's knobs as flags:
 * wall, CPU and peak RSS of that process alone) and compared with the truth in a forked child. The outputs are
 * written by bench/accuracy-report.c.
 *
 * Processing used to run in a forked child of this process (until 2026-11-22). That cost the
 * same as the exec (docs/accuracy-vs-time.md "Method changes"), but a forked child carries
 * the parent's state, and its wait4 peak RSS starts at the parent's resident memory; an
 * exec'd one is a command line anyone can rerun. Nothing that runs OpenMP is forked without
 * an exec now: the simulator's effect costs run as `impasto-bench sim-effects` too. */
#define _GNU_SOURCE   /* nftw() */
#include <errno.h>
#include <ftw.h>
#include <getopt.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <fcntl.h>
#include <limits.h>
#include <time.h>
#include <unistd.h>
#include "accuracy.h"
#include "bench-study.h"
#include "exit-codes.h"
#include "build-kind.h"
#include "captureset.h"
#include "compare-appearance.h"
#include "compare.h"
#include "json-util.h"
#include "log.h"
#include "plan.h"
#include "process.h"
#include "render.h"
#include "scene.h"
#include "sibling.h"

#define SL_EXP_ALL   0x7u
#define DOME_EXP_ALL 0x7u
#define EXP_SHORT    0x1u
#define EXP_MID      0x2u
#define EXP_LONG     0x4u

/* The baseline: both axes with inverses, 4-step phase at 16 px, the middle exposure, half
 * the dome, default processing. Every other configuration changes what its name says. */
#define BASE .axes = 2, .inverse = true, .phase_steps = 4, .phase_periods = 1, .sl_exposures = EXP_MID, \
        .lights = 24, .dome_exposures = EXP_MID, .btf = true, .btf_robust_passes = -1

/* Designated initializers after BASE override its fields on purpose. */
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Woverride-init"
static const struct acc_config configs[] = {
        { "base", "baseline: Gray+phase 4x1, inverses, 1 exposure, 24 lights", BASE, .quick = true, .hard = true },
        /* capture: structured light */
        { "gray", "Gray code only (no phase frames)", BASE, .phase_steps = 0, .quick = true, .hard = true },
        { "p3", "phase 3 steps", BASE, .phase_steps = 3, .hard = true },
        { "p6", "phase 6 steps", BASE, .phase_steps = 6 },
        { "p12", "phase 12 steps", BASE, .phase_steps = 12, .quick = true, .hard = true },
        { "p4x2", "phase 4 steps at 16 and 64 px", BASE, .phase_periods = 2 },
        { "noinv", "no inverse Gray planes (white/black threshold)", BASE, .inverse = false, .hard = true },
        { "xonly", "column code only (no row code)", BASE, .axes = 1 },
        /* capture: exposures */
        { "sl-e1", "structured light: short exposure only (noisy)", BASE, .sl_exposures = EXP_SHORT, .hard = true },
        { "sl-e3", "structured light: long exposure only", BASE, .sl_exposures = EXP_LONG, .hard = true },
        { "sl-2x", "structured light: 2 exposures per stack", BASE, .sl_exposures = EXP_MID | EXP_LONG, .quick = true,
          .hard = true },
        { "sl-3x", "structured light: 3 exposures per stack", BASE, .sl_exposures = SL_EXP_ALL },
        /* capture: dome */
        { "L12", "12 dome lights", BASE, .lights = 12, .quick = true, .hard = true },
        { "L48", "48 dome lights", BASE, .lights = 48, .hard = true },
        { "dome-e1", "dome: short exposure only (noisy)", BASE, .dome_exposures = EXP_SHORT },
        { "dome-2x", "dome: 2 exposures per light", BASE, .dome_exposures = EXP_MID | EXP_LONG, .hard = true },
        { "geom", "no dome sweep (geometry only)", BASE, .lights = 0, .btf = false },
        /* capture: camera */
        { "bin2", "2x2 binned frames", BASE, .bin2 = true, .hard = true },
        /* processing */
        { "dec-gray", "decoding: Gray only on the baseline set", BASE, .gray_decode = true },
        { "t1", "processing: 1 thread", BASE, .threads = 1, .quick = true },
        { "t2", "processing: 2 threads", BASE, .threads = 2 },
        { "fit-fast", "BTF fit: 8 iterations, no robust pass", BASE, .btf_max_iter = 8, .btf_robust_passes = 0,
          .hard = true },
        { "fit-slow", "BTF fit: 60 iterations, 4 robust passes", BASE, .btf_max_iter = 60, .btf_robust_passes = 4 },
        { "noshadow", "BTF: shadow test off", BASE, .no_shadow_test = true, .hard = true },
        { "n10", "relief boxes n = 10", BASE, .cell_px = 10 },
        { "n40", "relief boxes n = 40", BASE, .cell_px = 40 },
        /* combinations at the ends of the range */
        { "cheap", "Gray only, 12 lights, 1 exposure", BASE, .phase_steps = 0, .lights = 12, .quick = true,
          .hard = true },
        { "lean", "column code only, no inverses, phase 4x1, 12 lights", BASE, .axes = 1, .inverse = false,
          .lights = 12, .quick = true, .hard = true },
        /* below lean: the cheapest plans that still fuse phase heights with dome normals */
        { "lean3", "column code only, no inverses, phase 3x1, 12 lights", BASE, .axes = 1, .inverse = false,
          .phase_steps = 3, .lights = 12, .quick = true, .hard = true },
        { "lean8", "column code only, no inverses, phase 3x1, 8 lights", BASE, .axes = 1, .inverse = false,
          .phase_steps = 3, .lights = 8, .quick = true, .hard = true },
        { "mid", "phase 4x2, 2 SL exposures, 24 lights", BASE, .phase_periods = 2, .sl_exposures = EXP_MID | EXP_LONG,
          .hard = true },
        { "rich", "phase 12x2, 3 SL exposures, 48 lights x 2 exposures", BASE, .phase_steps = 12, .phase_periods = 2,
          .sl_exposures = SL_EXP_ALL, .lights = 48, .dome_exposures = EXP_MID | EXP_LONG, .quick = true, .hard = true },
};

/* The rich plan every configuration is a subset of (12 steps hold 3, 4 and 6). */
static const struct acc_config rich_plan = { "render", "", .axes = 2, .inverse = true, .phase_steps = 12,
        .phase_periods = 2, .sl_exposures = SL_EXP_ALL, .lights = 48, .dome_exposures = DOME_EXP_ALL };

#pragma GCC diagnostic pop

static const double sl_exposures_us[3] = { 3000.0, 10000.0, 30000.0 };
static const double dome_exposures_us[3] = { 4000.0, 12000.0, 36000.0 };

/* snprintf for paths: a path longer than the buffer is cut (and reported by the open). */
static void pathf(char *buf, size_t size, const char *fmt, ...) _printf_(3, 4);
static void pathf(char *buf, size_t size, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(buf, size, fmt, ap);
        va_end(ap);
}

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* ---- children ------------------------------------------------------------------------ */

struct child_cost {
        double wall_s, cpu_s;
        long maxrss_kib;
        int status;                   /* exit code, or 128 + signal */
};

/* Runs fn(arg) in a forked child; the child's exit code is fn's return. Cost from wait4(),
 * so it is that child's alone; but a child that does not exec carries this process's
 * memory (its peak RSS starts at ours) and state, so anything whose cost is reported goes
 * through an exec (exec_impasto, exec_self). The parent never starts an OpenMP thread pool. */
static int run_forked(int (*fn)(void *), void *arg, const char *log_path, struct child_cost *ret) {
        fflush(NULL);
        double t0 = now_s();
        pid_t pid = fork();
        if (pid < 0)
                return -errno;
        if (pid == 0) {
                if (log_path) {
                        int fd = open(log_path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
                        if (fd >= 0) {
                                dup2(fd, STDOUT_FILENO);
                                dup2(fd, STDERR_FILENO);
                        }
                }
                int rc = fn(arg);
                fflush(NULL);
                _exit(rc);
        }
        int status;
        struct rusage ru;
        if (wait4(pid, &status, 0, &ru) < 0)
                return -errno;
        ret->wall_s = now_s() - t0;
        ret->cpu_s = ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 + ru.ru_stime.tv_sec + ru.ru_stime.tv_usec * 1e-6;
        ret->maxrss_kib = ru.ru_maxrss;
        ret->status = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
        return 0;
}

/* `impasto …` (the client beside impasto-bench) with argv; argv[0] is replaced. */
static int exec_impasto(void *arg) {
        char **argv = arg, path[PATH_MAX];
        int r = imp_sibling_path("impasto", path, sizeof path);
        if (r < 0) {
                fprintf(stderr, "impasto beside impasto-bench: %s\n", strerror(-r));
                return 127;
        }
        argv[0] = path;
        execv(path, argv);
        fprintf(stderr, "exec %s: %s\n", path, strerror(errno));
        return 127;
}

/* impasto-bench itself with argv (a step of a study run in its own process). */
static int exec_self(void *arg) {
        char **argv = arg;
        execv("/proc/self/exe", argv);
        fprintf(stderr, "exec /proc/self/exe: %s\n", strerror(errno));
        return 127;
}

/* The 1-minute load average (-1 when unknown): the machine is shared, so every measured
 * figure is reported with it. */
static double load1(void) {
        double l[1];
        return getloadavg(l, 1) == 1 ? l[0] : -1;
}

/* `impasto process` flags for a configuration's processing knobs (the defaults give none). */
static void process_flags(const struct acc_config *c, char *buf, size_t size) {
        snprintf(buf, size, "%s%s%s", c->btf ? "" : " --no-btf", c->gray_decode ? " --gray-only" : "",
                 c->no_shadow_test ? " --no-shadow-test" : "");
        size_t n = strlen(buf);
        if (c->cell_px > 0)
                n += (size_t) snprintf(buf + n, n < size ? size - n : 0, " --cell %d", c->cell_px);
        if (c->threads > 0)
                n += (size_t) snprintf(buf + n, n < size ? size - n : 0, " --threads %d", c->threads);
        if (c->btf_max_iter > 0)
                n += (size_t) snprintf(buf + n, n < size ? size - n : 0, " --btf-iterations %d", c->btf_max_iter);
        if (c->btf_robust_passes >= 0)
                snprintf(buf + n, n < size ? size - n : 0, " --btf-robust-passes %d", c->btf_robust_passes);
}

struct compare_job {
        const char *copy, *truth, *out;
        bool appearance;
};

static int compare_child(void *arg) {
        struct compare_job *j = arg;
        struct imp_error err = {};
        struct imp_compare_result res;
        int r = imp_compare_dirs(j->copy, j->truth, &res, &err);
        if (r < 0) {
                fprintf(stderr, "compare %s: %s\n", j->copy, err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        _cleanup_json_ json_t *o = imp_compare_result_to_json(&res);
        if (j->appearance) {
                struct imp_compare_appearance app;
                r = imp_compare_appearance(j->copy, j->truth, &app, &err);
                if (r < 0) {
                        fprintf(stderr, "compare appearance %s: %s\n", j->copy, err.msg[0] ? err.msg : strerror(-r));
                        return 1;
                }
                json_object_set_new(o, "nan_count", json_integer((json_int_t) (res.nan_count + app.nan_count)));
                imp_compare_appearance_to_json(&app, o);
        }
        return imp_json_save_atomic(j->out, o, &err) < 0 ? 1 : 0;
}

/* ---- files ---------------------------------------------------------------------------- */

static long long tree_bytes;
static int add_size(const char *path, const struct stat *sb, int type, struct FTW *ftw) {
        (void) path, (void) ftw;
        if (type == FTW_F)
                tree_bytes += sb->st_size;
        return 0;
}

static long long dir_bytes(const char *dir) {
        tree_bytes = 0;
        nftw(dir, add_size, 16, FTW_PHYS);
        return tree_bytes;
}

static int remove_one(const char *path, const struct stat *sb, int type, struct FTW *ftw) {
        (void) sb, (void) type, (void) ftw;
        return remove(path) < 0 && errno != ENOENT ? -1 : 0;
}

static void remove_tree(const char *dir) {
        nftw(dir, remove_one, 16, FTW_DEPTH | FTW_PHYS);
}

static int write_text(const char *path, const char *text) {
        struct imp_error err = {};
        int r = imp_file_write_atomic(path, text, strlen(text), &err);
        if (r < 0)
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
        return r;
}

/* ---- plans and derived capture sets ---------------------------------------------------- */

static void append(char **buf, size_t *len, size_t *cap, const char *fmt, ...) _printf_(4, 5);
static void append(char **buf, size_t *len, size_t *cap, const char *fmt, ...) {
        va_list ap;
        for (;;) {
                va_start(ap, fmt);
                int n = vsnprintf(*buf ? *buf + *len : NULL, *buf ? *cap - *len : 0, fmt, ap);
                va_end(ap);
                if (n < 0)
                        return;
                if (*buf && *len + (size_t) n < *cap) {
                        *len += (size_t) n;
                        return;
                }
                size_t want = (*cap ? *cap : 256) * 2 + (size_t) n;
                char *b = realloc(*buf, want);
                if (!b)
                        return;
                *buf = b;
                *cap = want;
        }
}

static void exposures(char **b, size_t *len, size_t *cap, unsigned mask, const double *us) {
        append(b, len, cap, "exposures_us = [");
        const char *sep = "";
        for (int i = 0; i < 3; i++)
                if (mask & (1u << i)) {
                        append(b, len, cap, "%s%.1f", sep, us[i]);
                        sep = ", ";
                }
        append(b, len, cap, "];");
}

char *acc_plan_text(const struct acc_config *c, const struct acc_study *st, const int *light_ids,
                    int n_rig_lights) {
        char *b = NULL;
        size_t len = 0, cap = 0;
        append(&b, &len, &cap, "structured_light = {\n  inverse = %s;\n  axes = [%s];\n",
               c->inverse ? "true" : "false", c->axes == 1 ? "\"x\"" : "\"x\", \"y\"");
        if (c->phase_steps > 0)
                append(&b, &len, &cap, "  phase = { periods_px = [%s]; steps = %d; };\n",
                       c->phase_periods > 1 ? "16.0, 64.0" : "16.0", c->phase_steps);
        append(&b, &len, &cap, "  white = true;\n  black = true;\n  ");
        exposures(&b, &len, &cap, c->sl_exposures, st->sl_exposures_us);
        append(&b, &len, &cap, "\n};\n");
        if (c->lights > 0) {
                append(&b, &len, &cap, "dome = {\n  lights = ");
                if (c->lights >= n_rig_lights)
                        append(&b, &len, &cap, "\"all\";\n");
                else {
                        /* An even spread: every (n_rig / lights)-th light, so each ring keeps
                         * its share of the subset. */
                        int stride = IMP_MAX(1, n_rig_lights / c->lights);
                        append(&b, &len, &cap, "[");
                        for (int i = 0, k = 0; i < n_rig_lights && k < c->lights; i += stride, k++)
                                append(&b, &len, &cap, "%s%d", k ? ", " : "", light_ids[i]);
                        append(&b, &len, &cap, "];\n");
                }
                append(&b, &len, &cap, "  ");
                exposures(&b, &len, &cap, c->dome_exposures, st->dome_exposures_us);
                append(&b, &len, &cap, "\n};\n");
        }
        return b;
}

/* The same projected image and light: phase steps compare as fractions of a period, so the
 * 4-step frames are found among the 12-step ones. */
static bool same_frame(const struct imp_frame_record *want, const struct imp_frame_record *have) {
        if (strcmp(want->step, have->step) || strcmp(want->camera, have->camera) || want->tile != have->tile ||
            want->light != have->light || fabs(want->exposure_us - have->exposure_us) > 1e-3 ||
            want->pattern.kind != have->pattern.kind)
                return false;
        const struct imp_pattern *p = &want->pattern, *q = &have->pattern;
        switch (p->kind) {
        case IMP_PAT_GRAY:
                return p->axis == q->axis && p->bit == q->bit && p->nbits == q->nbits && p->inverse == q->inverse;
        case IMP_PAT_PHASE:
                return p->axis == q->axis && fabs(p->period_px - q->period_px) < 1e-9 &&
                       (long) p->step * q->steps == (long) q->step * p->steps;
        default:
                return true;
        }
}

/* The camera after 2×2 binning: pixel centres sit at integer pinhole coordinates, so the
 * binned pixel U covers u = 2U, 2U+1 and its centre is u = 2U + 0.5. Frames are the mean
 * of the four values, so one binned DN stands for 4 × the electrons and the read noise of
 * four reads. The readout time is kept (a conservative rig model). */
static void bin_rig(struct imp_rig *rig) {
        for (int i = 0; i < rig->n_cameras; i++) {
                struct imp_pinhole *m = &rig->cameras[i].model;
                struct imp_sensor *s = &rig->cameras[i].sensor;
                m->width /= 2;
                m->height /= 2;
                m->fx /= 2;
                m->fy /= 2;
                m->cx = (m->cx - 0.5) / 2;
                m->cy = (m->cy - 0.5) / 2;
                s->gain_e_per_dn *= 4;
                s->read_noise_e *= 2;
                s->full_well_e *= 4;
                s->quantum_scale *= 4;
                s->dark_current_e_per_s *= 4;
        }
}

static int bin_frame(const struct imp_image *in, struct imp_image **ret) {
        struct imp_image *o;
        int r = imp_image_new(in->width / 2, in->height / 2, in->channels, IMP_PIX_U16, &o);
        if (r < 0)
                return r;
        for (int y = 0; y < o->height; y++)
                for (int x = 0; x < o->width; x++)
                        for (int c = 0; c < in->channels; c++) {
                                unsigned s = imp_image_u16(in, 2 * x, 2 * y)[c] + imp_image_u16(in, 2 * x + 1, 2 * y)[c] +
                                             imp_image_u16(in, 2 * x, 2 * y + 1)[c] +
                                             imp_image_u16(in, 2 * x + 1, 2 * y + 1)[c];
                                imp_image_u16(o, x, y)[c] = (uint16_t) ((s + 2) / 4);
                        }
        *ret = o;
        return 0;
}

/* Writes the capture set the plan would have captured, from the rich set's frames. */
static int derive_set(const struct imp_captureset *rich, const struct imp_plan *plan, const char *plan_path,
                      bool bin2, const char *dir, struct imp_error *err) {
        struct imp_rig rig = {};
        int r = imp_rig_copy(imp_captureset_rig(rich), &rig);
        if (r < 0)
                return imp_error_set(err, r, "out of memory");
        if (bin2)
                bin_rig(&rig);
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        r = imp_captureset_create(dir, &rig, plan_path, &cs, err);
        imp_rig_free(&rig);
        if (r < 0)
                return r;
        size_t n_rich = imp_captureset_count(rich);
        for (size_t i = 0; i < imp_plan_count(plan); i++) {
                struct imp_frame_record rec = *imp_plan_frame(plan, i);
                size_t k = 0;
                while (k < n_rich && !same_frame(&rec, imp_captureset_record(rich, k)))
                        k++;
                if (k == n_rich)
                        return imp_error_set(err, -ENOENT, "%s: frame %zu is not in the rich set %s", plan_path, i,
                                             imp_captureset_dir(rich));
                const struct imp_frame_record *src = imp_captureset_record(rich, k);
                rec.t_light_on_ns = src->t_light_on_ns;
                rec.t_trigger_ns = src->t_trigger_ns;
                rec.t_frame_ns = src->t_frame_ns;
                _cleanup_image_ struct imp_image *img = NULL, *binned = NULL;
                r = imp_captureset_load_frame(rich, k, &img, err);
                if (r < 0)
                        return r;
                if (bin2 && (r = bin_frame(img, &binned)) < 0)
                        return imp_error_set(err, r, "out of memory");
                r = imp_captureset_add_frame(cs, &rec, binned ? binned : img, err);
                if (r < 0)
                        return r;
        }
        return 0;
}

static bool switches(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        const struct imp_pattern *p = &a->pattern, *q = &b->pattern;
        return a->light != b->light || p->kind != q->kind || p->axis != q->axis || p->bit != q->bit ||
               p->inverse != q->inverse || p->period_px != q->period_px || p->step != q->step || p->steps != q->steps;
}

/* The switch settle the simulator's clock left in the rich set: the smallest gap between
 * one frame's end and the next frame's light-on. */
static double switch_gap_ns(const struct imp_captureset *rich) {
        double gap = HUGE_VAL;
        for (size_t i = 0; i < imp_captureset_count(rich); i++) {
                const struct imp_frame_record *r = imp_captureset_record(rich, i);
                double g = i ? (double) (r->t_light_on_ns - imp_captureset_record(rich, i - 1)->t_frame_ns)
                             : (double) r->t_light_on_ns;
                if (g > 0 && g < gap)
                        gap = g;
        }
        return isfinite(gap) ? gap : 0;
}

/* Capture time from a set's manifest, as the simulated rig would take it: each frame costs
 * what the simulator's clock charged it (light-on to frame end: settle, exposure,
 * readout), each light or pattern switch the simulator's switch gap. Independent of
 * imp_plan_estimate_s: it reads timestamps, not the rig model. */
static double manifest_capture_s(const struct imp_captureset *cs, double gap_ns) {
        double ns = 0;
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *r = imp_captureset_record(cs, i);
                ns += (double) (r->t_frame_ns - r->t_light_on_ns);
                if (i == 0 || switches(imp_captureset_record(cs, i - 1), r))
                        ns += gap_ns;
        }
        return ns * 1e-9;
}

/* ---- the sweep ----------------------------------------------------------------------- */

static void capture_key(const struct acc_config *c, char *buf, size_t size) {
        snprintf(buf, size, "a%d-i%d-p%dx%d-e%x-l%d-d%x%s", c->axes, c->inverse, c->phase_steps,
                 c->phase_steps ? c->phase_periods : 0, c->sl_exposures, c->lights, c->lights ? c->dome_exposures : 0,
                 c->bin2 ? "-bin2" : "");
}

static double num(const json_t *o, const char *key) {
        json_t *v = json_object_get(o, key);
        return json_is_number(v) ? json_number_value(v) : -1;
}

static int render_rich(struct acc_study *st, int si, const char *scene_path, const char *plan_path,
                       const char *dir) {
        char path[4096];
        pathf(path, sizeof path, "%s/manifest.jsonl", dir);
        if (access(path, F_OK) == 0) {
                _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
                struct imp_error err = {};
                pathf(path, sizeof path, "%s/truth/truth.json", dir);
                if (imp_captureset_open(dir, &cs, &err) >= 0 && access(path, F_OK) == 0 &&
                    imp_captureset_count(cs) == st->render_frames[si]) {
                        log_info("bench accuracy: reusing the rendered set %s", dir);
                        return 0;
                }
                remove_tree(dir);
        }
        pathf(path, sizeof path, "%s.log", dir);
        char *argv[] = { "impasto", "sim", "render", "--scene", (char *) scene_path, "--plan", (char *) plan_path,
                         "--out", (char *) dir, "--quiet", NULL };
        struct child_cost cost = { .status = -1 };
        fprintf(stderr, "bench accuracy: rendering %s (%zu frames)…\n", scene_path, st->render_frames[si]);
        int r = run_forked(exec_impasto, argv, path, &cost);
        if (r < 0 || cost.status != 0)
                return log_error("bench accuracy: impasto sim render failed (exit %d), see %s", cost.status, path),
                       -EIO;
        st->render_wall_s[si] = cost.wall_s;
        st->render_cpu_s[si] = cost.cpu_s;
        return 0;
}

/* Processes and compares one configuration on a derived set. */
static void measure(struct acc_study *st, struct acc_result *res, const char *set, const char *truth) {
        const struct acc_config *c = res->cfg;
        char copy[4096], cmp[4096], log_path[4096];
        pathf(copy, sizeof copy, "%s/copies/%s/%s", st->out_dir, res->scene, c->name);
        pathf(cmp, sizeof cmp, "%s/copies/%s/%s.compare.json", st->out_dir, res->scene, c->name);
        pathf(log_path, sizeof log_path, "%s/copies/%s/%s.log", st->out_dir, res->scene, c->name);
        remove_tree(copy);
        /* Its own process: `impasto process SET --out COPY --quiet FLAGS`, exec'd. */
        pathf(res->set_dir, sizeof res->set_dir, "%s", set);
        process_flags(c, res->process_flags, sizeof res->process_flags);
        char flags[sizeof res->process_flags];
        snprintf(flags, sizeof flags, "%s", res->process_flags);
        char *argv[24] = { "impasto", "process", (char *) set, "--out", copy, "--quiet" };
        int n = 6;
        char *save = NULL;
        for (char *w = strtok_r(flags, " ", &save); w && n < (int) ARRAY_SIZE(argv) - 1; w = strtok_r(NULL, " ", &save))
                argv[n++] = w;
        struct child_cost cost = { .status = -1 };
        res->load_before = load1();
        if (run_forked(exec_impasto, argv, log_path, &cost) < 0 || cost.status != 0) {
                log_error("bench accuracy: %s/%s: processing failed (exit %d), see %s", res->scene, c->name,
                          cost.status, log_path);
                return;
        }
        res->load_after = load1();
        res->wall_s = cost.wall_s;
        res->cpu_s = cost.cpu_s;
        res->peak_rss_kib = cost.maxrss_kib;
        res->copy_bytes = dir_bytes(copy);
        struct compare_job cj = { copy, truth, cmp, c->btf && c->lights > 0 };
        struct child_cost ccost = { .status = -1 };
        pathf(log_path, sizeof log_path, "%s/copies/%s/%s.compare.log", st->out_dir, res->scene, c->name);
        if (run_forked(compare_child, &cj, log_path, &ccost) < 0 || ccost.status != 0) {
                log_error("bench accuracy: %s/%s: compare failed, see %s", res->scene, c->name, log_path);
                return;
        }
        struct imp_error err = {};
        _cleanup_json_ json_t *j = NULL;
        if (imp_json_load(cmp, &j, &err) < 0) {
                log_error("%s", err.msg);
                return;
        }
        res->height_rmse_um = num(j, "height_rmse_um");
        res->normal_err_deg = num(j, "normal_err_deg_mean");
        res->mask_iou = num(j, "mask_iou");
        res->nan_count = (long long) num(j, "nan_count");
        res->rho_d_err = num(j, "rho_d_rel_err_median");
        res->lobe_k_err = num(j, "lobe_k_rel_err_median");
        res->rerender_rmse = num(j, "rerender_rmse");
        res->ok = true;
}

static int sweep_scene(struct acc_study *st, int si, const char *scene_path, bool keep_sets) {
        char dir[4096], rich_dir[4096], plan_path[4096];
        const char *scene = st->scenes[si];
        pathf(dir, sizeof dir, "%s/plans/%s", st->out_dir, scene);
        int r = imp_mkdir_p(dir, 0755);
        if (r >= 0) {
                pathf(dir, sizeof dir, "%s/copies/%s", st->out_dir, scene);
                r = imp_mkdir_p(dir, 0755);
        }
        if (r >= 0) {
                pathf(dir, sizeof dir, "%s/sets/%s", st->out_dir, scene);
                r = imp_mkdir_p(dir, 0755);
        }
        if (r < 0)
                return log_error_errno(r, "bench accuracy: %s: %m", dir);

        /* The rich plan, expanded against the scene's rig (light ids come from the rig). */
        struct imp_error err = {};
        _cleanup_(imp_scene_freep) struct imp_scene *sc = NULL;
        if ((r = imp_scene_load(scene_path, &sc, &err)) < 0)
                return log_error("%s", err.msg), r;
        const struct imp_rig *rig = imp_scene_rig(sc);
        _cleanup_free_ int *ids = calloc(IMP_MAX(rig->n_lights, 1), sizeof *ids);
        if (!ids)
                return log_error("out of memory"), -ENOMEM;
        for (int i = 0; i < rig->n_lights; i++)
                ids[i] = rig->lights[i].id;
        _cleanup_free_ char *rich_text = acc_plan_text(&rich_plan, st, ids, rig->n_lights);
        pathf(plan_path, sizeof plan_path, "%s/plans/%s/render.cfg", st->out_dir, scene);
        if (!rich_text || write_text(plan_path, rich_text) < 0)
                return -EIO;
        {
                _cleanup_(imp_plan_freep) struct imp_plan *p = NULL;
                if ((r = imp_plan_load(plan_path, rig, &p, &err)) < 0)
                        return log_error("%s", err.msg), r;
                st->render_frames[si] = imp_plan_count(p);
        }
        pathf(rich_dir, sizeof rich_dir, "%s/sets/%s/rich", st->out_dir, scene);
        if ((r = render_rich(st, si, scene_path, plan_path, rich_dir)) < 0)
                return r;
        _cleanup_(imp_captureset_closep) struct imp_captureset *rich = NULL;
        if ((r = imp_captureset_open(rich_dir, &rich, &err)) < 0)
                return log_error("%s", err.msg), r;
        double gap_ns = switch_gap_ns(rich);
        char truth[4096];
        pathf(truth, sizeof truth, "%s/truth", rich_dir);

        /* Configurations grouped by capture: one derived set each. */
        size_t n_cfg = ARRAY_SIZE(configs);
        _cleanup_free_ bool *done = calloc(n_cfg, sizeof *done);
        if (!done)
                return log_error("out of memory"), -ENOMEM;
        for (size_t i = 0; i < n_cfg; i++) {
                const struct acc_config *c = &configs[i];
                if (done[i] || (st->quick && !c->quick) || (si > 0 && !c->hard))
                        continue;
                char key[128];
                capture_key(c, key, sizeof key);
                pathf(plan_path, sizeof plan_path, "%s/plans/%s/%s.cfg", st->out_dir, scene, c->name);
                _cleanup_free_ char *text = acc_plan_text(c, st, ids, rig->n_lights);
                if (!text || write_text(plan_path, text) < 0)
                        return -EIO;
                _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
                if ((r = imp_plan_load(plan_path, rig, &plan, &err)) < 0)
                        return log_error("%s", err.msg), r;
                char set[4096];
                pathf(set, sizeof set, "%s/sets/%s/%s", st->out_dir, scene, key);
                remove_tree(set);
                double t0 = now_s();
                if ((r = derive_set(rich, plan, plan_path, c->bin2, set, &err)) < 0)
                        return log_error("bench accuracy: %s", err.msg), r;
                double sim_s = 0;
                {
                        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
                        if ((r = imp_captureset_open(set, &cs, &err)) < 0)
                                return log_error("%s", err.msg), r;
                        sim_s = manifest_capture_s(cs, gap_ns);
                }
                fprintf(stderr, "bench accuracy: %s: set %s (%zu frames) derived in %.1f s\n", scene, key,
                        imp_plan_count(plan), now_s() - t0);
                for (size_t k = i; k < n_cfg; k++) {
                        const struct acc_config *d = &configs[k];
                        char key2[128];
                        capture_key(d, key2, sizeof key2);
                        if (done[k] || strcmp(key, key2) || (st->quick && !d->quick) || (si > 0 && !d->hard))
                                continue;
                        done[k] = true;
                        struct acc_result *res = &st->results[st->n_results++];
                        *res = (struct acc_result) { .cfg = d, .scene = scene, .frames = imp_plan_count(plan),
                                                     .capture_s = imp_plan_estimate_s(plan, rig),
                                                     .sim_capture_s = sim_s, .rho_d_err = -1, .lobe_k_err = -1,
                                                     .rerender_rmse = -1 };
                        /* Each configuration names its own plan file (same text within a set). */
                        pathf(res->plan_path, sizeof res->plan_path, "%s/plans/%s/%s.cfg", st->out_dir, scene,
                                 d->name);
                        if (k != i)
                                write_text(res->plan_path, text);
                        measure(st, res, set, truth);
                        fprintf(stderr, "bench accuracy: %s/%-9s capture %6.2f s  processing %6.2f s (cpu %6.2f s, "
                                "peak RSS %4.0f MiB, load %.2f→%.2f)  height rmse %7.2f um\n", scene, d->name,
                                res->capture_s, res->wall_s, res->cpu_s, res->peak_rss_kib / 1024.0, res->load_before,
                                res->load_after, res->height_rmse_um);
                }
                if (!keep_sets)
                        remove_tree(set);
        }
        return 0;
}

/* The simulator's cost per effect on a study scene (bench/bench-sim-effects.c's
 * measurement: `direct` alone, then each other effect alone on top of it; four frames),
 * as `impasto-bench sim-effects SCENE OUT_JSON` (not in the usage: the study's own step,
 * exec'd so that the renderer's OpenMP threads start in a fresh process). */
static int cmd_sim_effects(const char *scene_path, const char *out) {
        struct imp_error err = {};
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        if (imp_scene_load(scene_path, &scene, &err) < 0)
                return fprintf(stderr, "%s\n", err.msg), 1;
        const struct imp_rig *rig = imp_scene_rig(scene);
        struct imp_frame_record frames[4] = {
                { .seq = 0, .step = "dome", .light = rig->n_lights > 3 ? rig->lights[3].id : -1, .exposure_us = 10000 },
                { .seq = 1, .step = "structured-light", .light = -1, .exposure_us = 10000,
                  .pattern = { .kind = IMP_PAT_GRAY, .bit = 5, .nbits = 8 } },
                { .seq = 2, .step = "dome", .light = rig->n_lights > 20 ? rig->lights[20].id : -1, .exposure_us = 10000 },
                { .seq = 3, .step = "structured-light", .light = -1, .exposure_us = 10000,
                  .pattern = { .kind = IMP_PAT_PHASE, .period_px = 16, .step = 1, .steps = 4 } },
        };
        for (int f = 0; f < 4; f++)
                snprintf(frames[f].camera, sizeof frames[f].camera, "%s", rig->cameras[0].name);
        json_t *arr = json_array();
        for (int fx = -1; fx < IMP_FX_COUNT; fx++) {
                if (fx == IMP_FX_DIRECT || (fx == IMP_FX_PROJECTOR && !rig->has_projector) || fx == IMP_FX_DROPPED_FRAME)
                        continue;
                for (int i = 0; i < IMP_FX_COUNT; i++)
                        imp_scene_set_effect(scene, i, i == IMP_FX_DIRECT || i == fx);
                _cleanup_(imp_render_freep) struct imp_render *r = NULL;
                double t1 = now_s();
                if (imp_render_new(scene, &r, &err) < 0)
                        return fprintf(stderr, "%s\n", err.msg), 1;
                double tv = now_s() - t1;
                t1 = now_s();
                int n = 0;
                for (int f = 0; f < 4; f++) {
                        _cleanup_image_ struct imp_image *img = NULL;
                        if (imp_render_frame(r, &frames[f], &img, &err) == 0)
                                n++;
                }
                double ms = n ? (now_s() - t1) * 1e3 / n : 0;
                const struct imp_sim_counters *c = imp_render_counters(r);
                json_array_append_new(arr, json_pack("{s:s,s:f,s:f,s:I,s:I,s:I,s:I,s:I,s:I}",
                        "effect", fx < 0 ? "direct" : imp_sim_effect_name(fx), "view_s", tv, "ms_per_frame", ms,
                        "shading_evals", (json_int_t) c->shading_evals, "shadow_rays", (json_int_t) c->shadow_rays,
                        "shadow_steps", (json_int_t) c->shadow_steps, "random_draws", (json_int_t) c->random_draws,
                        "projector_lookups", (json_int_t) c->projector_lookups,
                        "distortion_evals", (json_int_t) c->distortion_evals));
        }
        int r = imp_json_save_atomic(out, arr, &err);
        json_decref(arr);
        return r < 0 ? 1 : 0;
}

static void measure_effects(struct acc_study *st, const char *scene_path) {
        char out[4096], log_path[4096];
        pathf(out, sizeof out, "%s/sim-effects.json", st->out_dir);
        pathf(log_path, sizeof log_path, "%s/sim-effects.log", st->out_dir);
        char *argv[] = { "impasto-bench", "sim-effects", (char *) scene_path, out, NULL };
        struct child_cost cost = { .status = -1 };
        if (run_forked(exec_self, argv, log_path, &cost) < 0 || cost.status != 0) {
                log_warning("bench accuracy: the simulator's effect costs could not be measured, see %s, ignoring",
                            log_path);
                return;
        }
        struct imp_error err = {};
        _cleanup_json_ json_t *arr = NULL;
        if (imp_json_load(out, &arr, &err) < 0)
                return;
        size_t i;
        json_t *e;
        json_array_foreach(arr, i, e) {
                if (st->n_effects >= (int) ARRAY_SIZE(st->effects))
                        break;
                struct acc_effect_cost *c = &st->effects[st->n_effects++];
                json_t *name = json_object_get(e, "effect");
                snprintf(c->effect, sizeof c->effect, "%s", json_is_string(name) ? json_string_value(name) : "?");
                c->view_s = num(e, "view_s");
                c->ms_per_frame = num(e, "ms_per_frame");
                c->shading_evals = (unsigned long long) num(e, "shading_evals");
                c->shadow_rays = (unsigned long long) num(e, "shadow_rays");
                c->shadow_steps = (unsigned long long) num(e, "shadow_steps");
                c->random_draws = (unsigned long long) num(e, "random_draws");
                c->projector_lookups = (unsigned long long) num(e, "projector_lookups");
                c->distortion_evals = (unsigned long long) num(e, "distortion_evals");
        }
        st->effects_scene = "study-demo";
}

static void usage(FILE *f) {
        fprintf(f, "usage: impasto bench accuracy [--quick] [--out DIR] [--repo DIR] [--scenes DIR] [--keep-sets]\n"
                   "  --out DIR     results, plots, presets and the report (default out/accuracy)\n"
                   "  --repo DIR    also write DIR/docs/accuracy-vs-time.md, DIR/docs/accuracy/*.svg and\n"
                   "                DIR/config/plans/{draft,standard,archival}.cfg + presets.json\n"
                   "                (default without --quick: the current directory when it holds config/plans)\n"
                   "  --scenes DIR  where study-demo.cfg and study-glossy.cfg are (default config/scenes of\n"
                   "                the source tree)\n"
                   "  --quick       the demo-like scene and %d configurations only\n"
                   "usage: impasto bench hard [--out DIR] [--repo DIR] [--only hard-NAME]...\n"
                   "                the hard-case suite (config/scenes/hard-*.cfg) into DIR/docs/hard-cases.md\n",
                (int) ({ int n = 0; for (size_t i = 0; i < ARRAY_SIZE(configs); i++) n += configs[i].quick; n; }));
}

static int cmd_accuracy(int argc, char **argv) {
        struct acc_study st = { .out_dir = "out/accuracy" };
        const char *scenes_dir = IMPASTO_SOURCE_DIR "/config/scenes";
        bool keep_sets = false, repo_given = false;
        static const struct option opts[] = {
                { "quick", no_argument, NULL, 'q' },     { "out", required_argument, NULL, 'o' },
                { "repo", required_argument, NULL, 'r' }, { "scenes", required_argument, NULL, 's' },
                { "keep-sets", no_argument, NULL, 'k' }, { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'q': st.quick = true; break;
                case 'o': st.out_dir = optarg; break;
                case 'r': st.repo_dir = optarg; repo_given = true; break;
                case 's': scenes_dir = optarg; break;
                case 'k': keep_sets = true; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return 2;
                }
        if (optind != argc) {
                usage(stderr);
                return 2;
        }
        if (!repo_given && !st.quick && access("config/plans", F_OK) == 0 && access("docs", F_OK) == 0)
                st.repo_dir = ".";
        /* The study's costs are the pipeline's only in an optimized build (an ASan build costs
         * ~9x the CPU and ~7x the memory on the study sets; docs/accuracy-vs-time.md). */
        if (imp_build_is_slow()) {
                if (repo_given)
                        return log_error("bench accuracy: this impasto is an %s build, whose processing costs are "
                                         "several times the pipeline's: not writing %s/docs from it (use an "
                                         "optimized build)", imp_build_kind(), st.repo_dir), 2;
                log_warning("bench accuracy: this impasto is an %s build: processing costs are several times the "
                            "pipeline's%s", imp_build_kind(), st.repo_dir ? "; docs/ and config/plans/ are left "
                            "alone" : "");
                st.repo_dir = NULL;
        }
        memcpy(st.sl_exposures_us, sl_exposures_us, sizeof sl_exposures_us);
        memcpy(st.dome_exposures_us, dome_exposures_us, sizeof dome_exposures_us);
        st.scenes[0] = "study-demo";
        st.scenes[1] = "study-glossy";
        st.n_scenes = st.quick ? 1 : 2;
        int r = imp_mkdir_p(st.out_dir, 0755);
        if (r < 0)
                return log_error_errno(r, "bench accuracy: %s: %m", st.out_dir), 1;
        _cleanup_free_ struct acc_result *results = calloc(2 * ARRAY_SIZE(configs), sizeof *results);
        if (!results)
                return log_error("out of memory"), 1;
        st.results = results;
        st.load_start = load1();
        double t0 = now_s();
        char path[4096];
        for (int si = 0; si < st.n_scenes; si++) {
                pathf(path, sizeof path, "%s/%s.cfg", scenes_dir, st.scenes[si]);
                if (sweep_scene(&st, si, path, keep_sets) < 0)
                        return 1;
        }
        if (!st.quick) {
                pathf(path, sizeof path, "%s/%s.cfg", scenes_dir, st.scenes[0]);
                measure_effects(&st, path);
        }
        st.total_wall_s = now_s() - t0;
        st.load_end = load1();
        acc_analyse(&st);
        if (acc_write_outputs(&st) < 0)
                return 1;
        size_t failed = 0;
        for (size_t i = 0; i < st.n_results; i++)
                failed += !st.results[i].ok;
        printf("bench accuracy: %zu configurations (%zu failed) in %.0f s; results in %s/\n", st.n_results, failed,
               st.total_wall_s, st.out_dir);
        return failed ? 1 : 0;
}

static int run_sim_effects(int argc, char **argv) {
        if (argc != 3)
                return fprintf(stderr, "usage: impasto-bench sim-effects SCENE OUT_JSON\n"), IMP_EXIT_USAGE;
        return cmd_sim_effects(argv[1], argv[2]);
}

IMP_BENCH_STUDY(accuracy, .name = "accuracy",
                .summary = "accuracy versus capture and processing time on the simulated rig", .run = cmd_accuracy);
/* the sweep's own step, run in a child: the simulator's cost per effect */
IMP_BENCH_STUDY(sim_effects, .name = "sim-effects", .summary = NULL, .run = run_sim_effects);
