/* The outputs of `impasto bench accuracy`: Pareto fronts and presets from the measured
 * configurations, results.csv / results.json, SVG plots written directly, the scan presets
 * (plan files with a measured header, presets.json for `impasto plan estimate`) and the
 * generated report docs/accuracy-vs-time.md. */
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/utsname.h>
#include <time.h>
#include <unistd.h>
#include <jansson.h>
#include "accuracy.h"
#include "build-kind.h"
#include "json-util.h"
#include "log.h"

#define HEIGHT_FACTOR_STANDARD 1.5   /* standard: within this factor of archival's height RMSE */
#define HEIGHT_FACTOR_DRAFT    3.0   /* draft: within this factor (a usable copy, not any copy) */

/* snprintf for paths: a path longer than the buffer is cut (and reported by the open). */
static void pathf(char *buf, size_t size, const char *fmt, ...) _printf_(3, 4);
static void pathf(char *buf, size_t size, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(buf, size, fmt, ap);
        va_end(ap);
}

static const char *const preset_names[3] = { "draft", "standard", "archival" };

/* ---- analysis ------------------------------------------------------------------------ */

static double proc_x(const struct acc_result *r) { return r->cpu_s; }
static double capt_x(const struct acc_result *r) { return r->capture_s; }

static bool dominated(const struct acc_result *r, const struct acc_result *all, size_t n,
                      double (*x)(const struct acc_result *), bool (*eligible)(const struct acc_result *)) {
        for (size_t i = 0; i < n; i++) {
                const struct acc_result *o = &all[i];
                if (o == r || !o->ok || strcmp(o->scene, r->scene) || (eligible && !eligible(o)))
                        continue;
                if (x(o) <= x(r) && o->height_rmse_um <= r->height_rmse_um &&
                    (x(o) < x(r) || o->height_rmse_um < r->height_rmse_um))
                        return true;
        }
        return false;
}

/* A preset is a plan: default processing, a dome sweep, no binning, no NaN. */
static bool preset_eligible(const struct acc_result *r) {
        const struct acc_config *c = r->cfg;
        return r->ok && c->btf && c->lights > 0 && !c->bin2 && !c->gray_decode && c->threads == 0 &&
               c->btf_max_iter == 0 && c->btf_robust_passes < 0 && !c->no_shadow_test && c->cell_px == 0 &&
               r->nan_count == 0;
}

void acc_analyse(struct acc_study *st) {
        for (size_t i = 0; i < st->n_results; i++) {
                struct acc_result *r = &st->results[i];
                r->front_capture = r->ok && !dominated(r, st->results, st->n_results, capt_x, NULL);
                r->front_processing = r->ok && !dominated(r, st->results, st->n_results, proc_x, NULL);
        }
        /* Presets on the first scene, from the front of the plan-only configurations. */
        struct acc_result *front[64];
        size_t nf = 0;
        for (size_t i = 0; i < st->n_results && nf < 64; i++) {
                struct acc_result *r = &st->results[i];
                if (!strcmp(r->scene, st->scenes[0]) && preset_eligible(r) &&
                    !dominated(r, st->results, st->n_results, capt_x, preset_eligible))
                        front[nf++] = r;
        }
        if (nf == 0)
                return;
        /* sort by capture time */
        for (size_t i = 1; i < nf; i++)
                for (size_t k = i; k > 0 && front[k]->capture_s < front[k - 1]->capture_s; k--) {
                        struct acc_result *t = front[k];
                        front[k] = front[k - 1];
                        front[k - 1] = t;
                }
        struct acc_result *draft = NULL, *archival = front[nf - 1], *standard = NULL;
        size_t di = 0;
        for (size_t i = 0; i < nf && !draft; i++)
                if (front[i]->height_rmse_um <= HEIGHT_FACTOR_DRAFT * archival->height_rmse_um)
                        draft = front[di = i];
        if (!draft || draft == archival)
                draft = front[di = 0];
        for (size_t i = di + 1; i + 1 < nf && !standard; i++)
                if (front[i]->height_rmse_um <= HEIGHT_FACTOR_STANDARD * archival->height_rmse_um)
                        standard = front[i];
        if (!standard && nf > di + 2)
                standard = front[(di + nf) / 2];
        draft->preset = "draft";
        if (standard)
                standard->preset = "standard";
        archival->preset = "archival";
}

static const struct acc_result *find_preset(const struct acc_study *st, const char *name) {
        for (size_t i = 0; i < st->n_results; i++)
                if (st->results[i].preset && !strcmp(st->results[i].preset, name))
                        return &st->results[i];
        return NULL;
}

static const struct acc_result *find(const struct acc_study *st, const char *scene, const char *config) {
        for (size_t i = 0; i < st->n_results; i++)
                if (!strcmp(st->results[i].scene, scene) && !strcmp(st->results[i].cfg->name, config))
                        return &st->results[i];
        return NULL;
}

/* ---- machine --------------------------------------------------------------------------- */

struct machine {
        const char *build;
        long nproc;
        char cpu[128];
        double mem_gib;
        char date[64], host[128];
};

static void machine_info(struct machine *m) {
        *m = (struct machine) { .build = imp_build_kind(), .nproc = sysconf(_SC_NPROCESSORS_ONLN) };
        snprintf(m->cpu, sizeof m->cpu, "unknown");
        char line[512];
        FILE *f = fopen("/proc/cpuinfo", "re");
        while (f && fgets(line, sizeof line, f))
                if (!strncmp(line, "model name", 10) && strchr(line, ':')) {
                        snprintf(m->cpu, sizeof m->cpu, "%.120s", strchr(line, ':') + 2);
                        m->cpu[strcspn(m->cpu, "\n")] = 0;
                        break;
                }
        if (f)
                fclose(f);
        f = fopen("/proc/meminfo", "re");
        long long kib;
        while (f && fgets(line, sizeof line, f))
                if (sscanf(line, "MemTotal: %lld kB", &kib) == 1)
                        m->mem_gib = kib / 1048576.0;
        if (f)
                fclose(f);
        time_t now = time(NULL);
        struct tm tm;
        gmtime_r(&now, &tm);
        strftime(m->date, sizeof m->date, "%Y-%m-%d %H:%M UTC", &tm);
        struct utsname u;
        if (uname(&u) == 0)
                snprintf(m->host, sizeof m->host, "%.30s %.60s %.30s", u.sysname, u.release, u.machine);
}

/* ---- results.csv / results.json -------------------------------------------------------- */

static json_t *result_json(const struct acc_result *r) {
        json_t *o = json_pack("{s:s,s:s,s:s,s:s,s:b,s:I,s:f,s:f,s:f,s:f,s:I,s:I,s:f,s:f,s:f,s:I,s:f,s:f,s:f,s:b,s:b}",
                "scene", r->scene, "config", r->cfg->name, "knob", r->cfg->knob, "plan", r->plan_path, "ok", r->ok,
                "frames", (json_int_t) r->frames, "capture_s", r->capture_s, "sim_capture_s", r->sim_capture_s,
                "processing_wall_s", r->wall_s, "processing_cpu_s", r->cpu_s, "peak_rss_kib", (json_int_t) r->peak_rss_kib,
                "copy_bytes", (json_int_t) r->copy_bytes, "height_rmse_um", r->height_rmse_um,
                "normal_err_deg_mean", r->normal_err_deg, "mask_iou", r->mask_iou, "nan_count", (json_int_t) r->nan_count,
                "rho_d_rel_err_median", r->rho_d_err, "lobe_k_rel_err_median", r->lobe_k_err,
                "rerender_rmse", r->rerender_rmse, "front_capture", r->front_capture,
                "front_processing", r->front_processing);
        if (o) {
                json_object_set_new(o, "preset", r->preset ? json_string(r->preset) : json_null());
                json_object_set_new(o, "process_flags", json_string(r->process_flags));
                json_object_set_new(o, "set", json_string(r->set_dir));
                json_object_set_new(o, "load_before", json_real(r->load_before));
                json_object_set_new(o, "load_after", json_real(r->load_after));
        }
        return o;
}

static json_t *preset_json(const struct acc_study *st, const struct acc_result *r, const char *out_plan) {
        json_t *o = json_pack("{s:s,s:s,s:s,s:I,s:f,s:f,s:f,s:f,s:f,s:f,s:f}", "config", r->cfg->name, "scene",
                r->scene, "plan", out_plan, "frames", (json_int_t) r->frames, "capture_s", r->capture_s,
                "sim_capture_s", r->sim_capture_s, "processing_cpu_s", r->cpu_s, "height_rmse_um", r->height_rmse_um,
                "normal_err_deg_mean", r->normal_err_deg, "rho_d_rel_err_median", r->rho_d_err,
                "lobe_k_rel_err_median", r->lobe_k_err);
        for (int si = 1; o && si < st->n_scenes; si++) {
                const struct acc_result *h = find(st, st->scenes[si], r->cfg->name);
                if (h && h->ok)
                        json_object_set_new(o, st->scenes[si], json_pack("{s:f,s:f,s:f,s:f}",
                                "height_rmse_um", h->height_rmse_um, "normal_err_deg_mean", h->normal_err_deg,
                                "rho_d_rel_err_median", h->rho_d_err, "lobe_k_rel_err_median", h->lobe_k_err));
        }
        return o;
}

static int write_csv(const struct acc_study *st, const char *path) {
        FILE *f = fopen(path, "we");
        if (!f)
                return log_error_errno(-errno, "%s: %m", path), -errno;
        fprintf(f, "scene,config,knob,frames,capture_s,sim_capture_s,processing_wall_s,processing_cpu_s,peak_rss_kib,"
                   "copy_bytes,height_rmse_um,normal_err_deg_mean,mask_iou,nan_count,rho_d_rel_err_median,"
                   "lobe_k_rel_err_median,rerender_rmse,front_capture,front_processing,preset,load_before,load_after,"
                   "process_flags\n");
        for (size_t i = 0; i < st->n_results; i++) {
                const struct acc_result *r = &st->results[i];
                fprintf(f, "%s,%s,\"%s\",%zu,%.4f,%.4f,%.3f,%.3f,%ld,%lld,%.3f,%.3f,%.4f,%lld,%.4f,%.4f,%.4f,%d,%d,%s,"
                           "%.2f,%.2f,\"%s\"\n",
                        r->scene, r->cfg->name, r->cfg->knob, r->frames, r->capture_s, r->sim_capture_s, r->wall_s,
                        r->cpu_s, r->peak_rss_kib, r->copy_bytes, r->height_rmse_um, r->normal_err_deg, r->mask_iou,
                        r->nan_count, r->rho_d_err, r->lobe_k_err, r->rerender_rmse, r->front_capture,
                        r->front_processing, r->preset ? r->preset : "", r->load_before, r->load_after,
                        r->process_flags + (r->process_flags[0] == ' '));
        }
        return fclose(f) == 0 ? 0 : -EIO;
}

/* ---- SVG ------------------------------------------------------------------------------- */

enum { SVG_W = 860, SVG_H = 540, SVG_L = 80, SVG_R = 30, SVG_T = 56, SVG_B = 64 };

struct axis {
        double lo, hi;                /* log10 range */
};

static void axis_fit(struct axis *a, double vmin, double vmax) {
        if (!(vmin > 0))
                vmin = 1e-3;
        if (!(vmax > vmin))
                vmax = vmin * 10;
        a->lo = log10(vmin) - 0.08 * (log10(vmax) - log10(vmin) + 0.2);
        a->hi = log10(vmax) + 0.08 * (log10(vmax) - log10(vmin) + 0.2);
}

static double map(const struct axis *a, double v, double p0, double p1) {
        return p0 + (log10(v) - a->lo) / (a->hi - a->lo) * (p1 - p0);
}

static void svg_ticks(FILE *f, const struct axis *a, bool horizontal) {
        static const int mant[] = { 1, 2, 5 };
        for (int e = (int) floor(a->lo) - 1; e <= (int) ceil(a->hi); e++)
                for (int m = 0; m < 3; m++) {
                        double v = mant[m] * pow(10, e);
                        if (log10(v) < a->lo || log10(v) > a->hi)
                                continue;
                        char label[32];
                        snprintf(label, sizeof label, "%g", v);
                        if (horizontal) {
                                double x = map(a, v, SVG_L, SVG_W - SVG_R);
                                fprintf(f, "<line x1=\"%.1f\" y1=\"%d\" x2=\"%.1f\" y2=\"%d\" stroke=\"#ddd\"/>\n"
                                           "<text x=\"%.1f\" y=\"%d\" text-anchor=\"middle\" font-size=\"12\">%s</text>\n",
                                        x, SVG_T, x, SVG_H - SVG_B, x, SVG_H - SVG_B + 16, label);
                        } else {
                                double y = map(a, v, SVG_H - SVG_B, SVG_T);
                                fprintf(f, "<line x1=\"%d\" y1=\"%.1f\" x2=\"%d\" y2=\"%.1f\" stroke=\"#ddd\"/>\n"
                                           "<text x=\"%d\" y=\"%.1f\" text-anchor=\"end\" font-size=\"12\">%s</text>\n",
                                        SVG_L, y, SVG_W - SVG_R, y, SVG_L - 6, y + 4, label);
                        }
                }
}

static int cmp_x;   /* 0: capture, 1: processing (qsort has no context argument) */
static int by_x(const void *a, const void *b) {
        const struct acc_result *p = *(const struct acc_result *const *) a, *q = *(const struct acc_result *const *) b;
        double x = cmp_x ? p->cpu_s : p->capture_s, y = cmp_x ? q->cpu_s : q->capture_s;
        return (x > y) - (x < y);
}

static int write_svg(const struct acc_study *st, const char *path, const char *scene, bool processing) {
        const struct acc_result *pts[128];
        size_t n = 0;
        double xmin = HUGE_VAL, xmax = 0, ymin = HUGE_VAL, ymax = 0;
        for (size_t i = 0; i < st->n_results && n < 128; i++) {
                const struct acc_result *r = &st->results[i];
                double x = processing ? r->cpu_s : r->capture_s;
                if (!r->ok || strcmp(r->scene, scene) || !(x > 0) || !(r->height_rmse_um > 0))
                        continue;
                pts[n++] = r;
                xmin = fmin(xmin, x), xmax = fmax(xmax, x);
                ymin = fmin(ymin, r->height_rmse_um), ymax = fmax(ymax, r->height_rmse_um);
        }
        FILE *f = fopen(path, "we");
        if (!f)
                return log_error_errno(-errno, "%s: %m", path), -errno;
        struct axis ax, ay;
        axis_fit(&ax, xmin, xmax);
        axis_fit(&ay, ymin, ymax);
        fprintf(f, "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%d\" height=\"%d\" viewBox=\"0 0 %d %d\" "
                   "font-family=\"sans-serif\">\n<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n",
                SVG_W, SVG_H, SVG_W, SVG_H);
        fprintf(f, "<text x=\"%d\" y=\"24\" font-size=\"16\" font-weight=\"bold\">%s: height RMSE versus %s</text>\n",
                SVG_L, scene, processing ? "processing CPU time" : "capture time on the rig");
        fprintf(f, "<text x=\"%d\" y=\"42\" font-size=\"11\" fill=\"#555\">each point is one configuration "
                   "(labels as in docs/accuracy-vs-time.md); red: Pareto front; ringed: scan preset</text>\n", SVG_L);
        svg_ticks(f, &ax, true);
        svg_ticks(f, &ay, false);
        fprintf(f, "<rect x=\"%d\" y=\"%d\" width=\"%d\" height=\"%d\" fill=\"none\" stroke=\"#333\"/>\n", SVG_L, SVG_T,
                SVG_W - SVG_L - SVG_R, SVG_H - SVG_T - SVG_B);
        fprintf(f, "<text x=\"%d\" y=\"%d\" text-anchor=\"middle\" font-size=\"13\">%s (log scale)</text>\n",
                (SVG_L + SVG_W - SVG_R) / 2, SVG_H - 18,
                processing ? "processing CPU time per copy [s]" : "capture time per tile, rig model [s]");
        fprintf(f, "<text transform=\"translate(20,%d) rotate(-90)\" text-anchor=\"middle\" font-size=\"13\">"
                   "height RMSE against truth [µm] (log scale)</text>\n", (SVG_T + SVG_H - SVG_B) / 2);
        /* the front as a staircase */
        const struct acc_result *front[128];
        size_t nf = 0;
        for (size_t i = 0; i < n; i++)
                if (processing ? pts[i]->front_processing : pts[i]->front_capture)
                        front[nf++] = pts[i];
        cmp_x = processing;
        qsort(front, nf, sizeof front[0], by_x);
        if (nf > 0) {
                fprintf(f, "<polyline fill=\"none\" stroke=\"#d62728\" stroke-width=\"1.5\" points=\"");
                for (size_t i = 0; i < nf; i++) {
                        double x = map(&ax, processing ? front[i]->cpu_s : front[i]->capture_s, SVG_L, SVG_W - SVG_R);
                        double y = map(&ay, front[i]->height_rmse_um, SVG_H - SVG_B, SVG_T);
                        if (i > 0)
                                fprintf(f, "%.1f,%.1f ", x, map(&ay, front[i - 1]->height_rmse_um, SVG_H - SVG_B, SVG_T));
                        fprintf(f, "%.1f,%.1f ", x, y);
                }
                fprintf(f, "\"/>\n");
        }
        double lab[128][2];
        size_t n_lab = 0;
        for (size_t i = 0; i < n; i++) {
                const struct acc_result *r = pts[i];
                bool on = processing ? r->front_processing : r->front_capture;
                double x = map(&ax, processing ? r->cpu_s : r->capture_s, SVG_L, SVG_W - SVG_R);
                double y = map(&ay, r->height_rmse_um, SVG_H - SVG_B, SVG_T);
                fprintf(f, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"4\" fill=\"%s\"><title>%s: %s</title></circle>\n", x, y,
                        on ? "#d62728" : "#4a78b0", r->cfg->name, r->cfg->knob);
                if (r->preset && !strcmp(r->scene, st->scenes[0]))
                        fprintf(f, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"8\" fill=\"none\" stroke=\"#222\"/>\n", x, y);
                /* Labels of coinciding points stack downwards; near the right edge they end at the point. */
                bool right = x > SVG_W - SVG_R - 130;
                double ly = y - 5;
                for (size_t k = 0; k < n_lab; k++)
                        if (fabs(lab[k][0] - x) < 40 && fabs(lab[k][1] - ly) < 10) {
                                ly = lab[k][1] + 11;
                                k = (size_t) -1;
                        }
                if (n_lab < 128) {
                        lab[n_lab][0] = x;
                        lab[n_lab++][1] = ly;
                }
                fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" font-size=\"10\"%s%s>%s%s%s%s</text>\n", right ? x - 6 : x + 6, ly,
                        right ? " text-anchor=\"end\"" : "", on ? " font-weight=\"bold\"" : " fill=\"#333\"", r->cfg->name,
                        r->preset && !strcmp(r->scene, st->scenes[0]) ? " [" : "",
                        r->preset && !strcmp(r->scene, st->scenes[0]) ? r->preset : "",
                        r->preset && !strcmp(r->scene, st->scenes[0]) ? "]" : "");
        }
        /* legend */
        int lx = SVG_W - SVG_R - 190, ly = SVG_T + 14;
        fprintf(f, "<rect x=\"%d\" y=\"%d\" width=\"182\" height=\"58\" fill=\"white\" stroke=\"#999\"/>\n"
                   "<circle cx=\"%d\" cy=\"%d\" r=\"4\" fill=\"#d62728\"/><text x=\"%d\" y=\"%d\" font-size=\"11\">Pareto front</text>\n"
                   "<circle cx=\"%d\" cy=\"%d\" r=\"4\" fill=\"#4a78b0\"/><text x=\"%d\" y=\"%d\" font-size=\"11\">dominated configuration</text>\n"
                   "<circle cx=\"%d\" cy=\"%d\" r=\"8\" fill=\"none\" stroke=\"#222\"/><text x=\"%d\" y=\"%d\" font-size=\"11\">scan preset</text>\n",
                lx, ly - 10, lx + 12, ly + 4, lx + 24, ly + 8, lx + 12, ly + 20, lx + 24, ly + 24, lx + 12, ly + 36,
                lx + 24, ly + 40);
        fprintf(f, "</svg>\n");
        return fclose(f) == 0 ? 0 : -EIO;
}

/* ---- presets ---------------------------------------------------------------------------- */

static char *read_all(const char *path) {
        FILE *f = fopen(path, "re");
        if (!f)
                return NULL;
        char *buf = NULL;
        size_t len = 0;
        FILE *m = open_memstream(&buf, &len);
        char chunk[4096];
        size_t k;
        while (m && (k = fread(chunk, 1, sizeof chunk, f)) > 0)
                fwrite(chunk, 1, k, m);
        fclose(f);
        if (m)
                fclose(m);
        return buf;
}

static int write_preset(const struct acc_study *st, const struct machine *mc, const struct acc_result *r,
                        const char *name, const char *path) {
        _cleanup_free_ char *plan = read_all(r->plan_path);
        if (!plan)
                return log_error_errno(-errno, "%s: %m", r->plan_path), -EIO;
        FILE *f = fopen(path, "we");
        if (!f)
                return log_error_errno(-errno, "%s: %m", path), -errno;
        fprintf(f, "# Scan preset \"%s\", generated by `impasto bench accuracy` on %s from the Pareto front of\n"
                   "# capture time versus height RMSE (docs/accuracy-vs-time.md; configuration \"%s\": %s).\n"
                   "# Expected on the study rig (config/scenes/%s.cfg: 400 x 300 camera, 10 ms readout, 2 ms settle):\n"
                   "#   capture time per tile %.1f s (%zu frames), processing %.1f s CPU;\n"
                   "#   accuracy on %s: height RMSE %.1f um, normal error %.2f deg, rho_d median rel. error %.3f",
                name, mc->date, r->cfg->name, r->cfg->knob, r->scene, r->capture_s, r->frames, r->cpu_s, r->scene,
                r->height_rmse_um, r->normal_err_deg, r->rho_d_err);
        for (int si = 1; si < st->n_scenes; si++) {
                const struct acc_result *h = find(st, st->scenes[si], r->cfg->name);
                if (h && h->ok)
                        fprintf(f, ";\n#   on %s: height RMSE %.1f um, normal error %.2f deg", h->scene,
                                h->height_rmse_um, h->normal_err_deg);
        }
        fprintf(f, ".\n# Light ids and exposures are the study rig's; `impasto plan estimate` prints the figures.\n%s",
                plan);
        return fclose(f) == 0 ? 0 : -EIO;
}

static int write_presets(const struct acc_study *st, const struct machine *mc, const char *dir) {
        int r = imp_mkdir_p(dir, 0755);
        if (r < 0)
                return log_error_errno(r, "%s: %m", dir);
        _cleanup_json_ json_t *pj = json_pack("{s:s,s:s}", "generated", mc->date, "by", "impasto bench accuracy");
        for (int i = 0; i < 3; i++) {
                const struct acc_result *p = find_preset(st, preset_names[i]);
                if (!p)
                        continue;
                char path[4096];
                pathf(path, sizeof path, "%s/%s.cfg", dir, preset_names[i]);
                if ((r = write_preset(st, mc, p, preset_names[i], path)) < 0)
                        return r;
                json_object_set_new(pj, preset_names[i], preset_json(st, p, path));
        }
        char path[4096];
        pathf(path, sizeof path, "%s/presets.json", dir);
        struct imp_error err = {};
        if ((r = imp_json_save_atomic(path, pj, &err)) < 0)
                log_error("%s", err.msg);
        return r;
}

/* ---- the report --------------------------------------------------------------------------- */

/* v with `decimals` decimals, or "–" when not measured (v < 0). */
static void fmt_opt(char *buf, size_t size, double v, int decimals) {
        if (v < 0)
                snprintf(buf, size, "–");
        else
                snprintf(buf, size, "%.*f", decimals, v);
}

static void report_table(FILE *f, const struct acc_study *st, const char *scene) {
        fprintf(f, "| config | what changes | frames | capture s | proc wall s | proc CPU s | peak RSS MiB | load | "
                   "copy MiB | height RMSE µm | normal ° | mask IoU | ρd err | k err | front |\n"
                   "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n");
        for (size_t i = 0; i < st->n_results; i++) {
                const struct acc_result *r = &st->results[i];
                if (strcmp(r->scene, scene))
                        continue;
                if (!r->ok) {
                        fprintf(f, "| %s | %s | %zu | %.2f | failed | | | | | | | | | | |\n", r->cfg->name, r->cfg->knob,
                                r->frames, r->capture_s);
                        continue;
                }
                char rd[32], k[32];
                fmt_opt(rd, sizeof rd, r->rho_d_err, 3);
                fmt_opt(k, sizeof k, r->lobe_k_err, 2);
                char front[64];
                snprintf(front, sizeof front, "%s%s%s%s%s", r->front_capture ? "**C**" : "",
                         r->front_capture && r->front_processing ? " " : "", r->front_processing ? "**P**" : "",
                         r->preset && !strcmp(scene, st->scenes[0]) ? " " : "",
                         r->preset && !strcmp(scene, st->scenes[0]) ? r->preset : "");
                fprintf(f, "| %s%s%s | %s | %zu | %.2f | %.2f | %.2f | %.0f | %.1f | %.2f | %.2f | %.2f | %.3f | %s | %s | "
                           "%s |\n",
                        r->front_capture || r->front_processing ? "**" : "", r->cfg->name,
                        r->front_capture || r->front_processing ? "**" : "", r->cfg->knob, r->frames, r->capture_s,
                        r->wall_s, r->cpu_s, r->peak_rss_kib / 1024.0, r->load_after, r->copy_bytes / 1048576.0,
                        r->height_rmse_um,
                        r->normal_err_deg, r->mask_iou, rd, k, front);
        }
        fputc('\n', f);
}

/* The processing costs the study published on 2026-11-22 04:23 UTC, measured with a binary
 * it did not record, most likely an ASan build (docs/accuracy-vs-time.md "Method changes"):
 * kept to set the new ones beside. */
static const struct {
        const char *scene, *config;
        double wall_s, cpu_s, rss_mib;
} asan_costs[] = {
        { "study-demo", "base", 6.20, 12.05, 327 },   { "study-demo", "t1", 11.73, 11.72, 325 },
        { "study-demo", "gray", 1.82, 3.48, 348 },    { "study-demo", "L48", 10.01, 19.55, 474 },
        { "study-demo", "rich", 12.59, 24.51, 511 },  { "study-glossy", "base", 5.09, 9.82, 465 },
        { "study-glossy", "rich", 10.84, 21.07, 529 },
};

static void report_method_changes(FILE *f, const struct acc_study *st) {
        fprintf(f, "## Method changes\n\n"
                   "**2026-11-22 — each configuration its own exec'd process; the build recorded.** The processing "
                   "costs published at 04:23 UTC (study-demo `base` 12.05 s CPU and 327 MiB, peaks of 325–529 MiB) "
                   "were suspected to come from running each configuration in a forked child (OpenMP after fork, "
                   "the parent's memory in the child's peak RSS). They do not: the bench's parent never starts "
                   "OpenMP and holds 23 MiB (7.5 MiB anonymous), and on the same derived sets the current code in "
                   "an optimized build costs the same forked or exec'd (`base` at load ≈ 1: 2.26 s CPU / 39 MiB "
                   "forked, 2.23 s / 45 MiB exec'd, the exec'd process counting its own start-up; `impasto "
                   "process` by hand 2.1 s / 45 MiB). What the 04:23 run measured was its binary, which it did not "
                   "record: its peaks are those of an AddressSanitizer build (the tree's `build/`, Debug + ASan, "
                   "which also ran the demo's 275.8 s worker: 338 MiB and 19.8 s CPU on `base`), its CPU times "
                   "between that and an optimized build. Since then each configuration runs as `impasto process` "
                   "with its knobs as flags, exec'd (a row is a command line to rerun), the Machine table names "
                   "the build, `impasto bench accuracy` refuses to write docs/ from a sanitizer or -O0 build, and "
                   "every row carries the load average.\n\n");
        double lo = HUGE_VAL, hi = -HUGE_VAL, cpu_lo = HUGE_VAL, cpu_hi = 0, rss_lo = HUGE_VAL, rss_hi = 0;
        for (size_t i = 0; i < st->n_results; i++)
                if (st->results[i].ok && st->results[i].load_after >= 0) {
                        lo = fmin(lo, st->results[i].load_after);
                        hi = fmax(hi, st->results[i].load_after);
                }
        for (size_t i = 0; i < ARRAY_SIZE(asan_costs); i++) {
                const struct acc_result *r = find(st, asan_costs[i].scene, asan_costs[i].config);
                if (!r || !r->ok || r->cpu_s <= 0 || r->peak_rss_kib <= 0)
                        continue;
                cpu_lo = fmin(cpu_lo, asan_costs[i].cpu_s / r->cpu_s);
                cpu_hi = fmax(cpu_hi, asan_costs[i].cpu_s / r->cpu_s);
                rss_lo = fmin(rss_lo, asan_costs[i].rss_mib * 1024.0 / (double) r->peak_rss_kib);
                rss_hi = fmax(rss_hi, asan_costs[i].rss_mib * 1024.0 / (double) r->peak_rss_kib);
        }
        if (lo <= hi && cpu_lo <= cpu_hi)
                fprintf(f, "The old and new costs side by side: the 04:23 figures were %.1f–%.1f× the CPU time and "
                           "%.1f–%.1f× the peak RSS of this run's (the old run's load was not recorded; this run's "
                           "1-minute load average ranged %.1f–%.1f on %ld CPUs, and wall times carry other jobs' "
                           "work):\n\n", cpu_lo, cpu_hi, rss_lo, rss_hi, lo, hi, sysconf(_SC_NPROCESSORS_ONLN));
        fprintf(f, "| scene | config | 04:23 run: wall s | CPU s | peak RSS MiB | this run: wall s | CPU s | "
                   "peak RSS MiB | load |\n|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
        for (size_t i = 0; i < ARRAY_SIZE(asan_costs); i++) {
                const struct acc_result *r = find(st, asan_costs[i].scene, asan_costs[i].config);
                if (!r || !r->ok)
                        continue;
                fprintf(f, "| %s | %s | %.2f | %.2f | %.0f | %.2f | %.2f | %.0f | %.1f |\n", r->scene, r->cfg->name,
                        asan_costs[i].wall_s, asan_costs[i].cpu_s, asan_costs[i].rss_mib, r->wall_s, r->cpu_s,
                        r->peak_rss_kib / 1024.0, r->load_after);
        }
        fputc('\n', f);
}

static void report_front(FILE *f, const struct acc_study *st, const char *scene, bool processing) {
        const struct acc_result *v[128];
        size_t n = 0;
        for (size_t i = 0; i < st->n_results && n < 128; i++) {
                const struct acc_result *r = &st->results[i];
                if (!strcmp(r->scene, scene) && (processing ? r->front_processing : r->front_capture))
                        v[n++] = r;
        }
        cmp_x = processing;
        qsort(v, n, sizeof v[0], by_x);
        fprintf(f, "- %s, %s: ", scene, processing ? "processing CPU time" : "capture time");
        for (size_t i = 0; i < n; i++)
                fprintf(f, "%s`%s` (%.2f s, %.1f µm)", i ? " → " : "", v[i]->cfg->name,
                        processing ? v[i]->cpu_s : v[i]->capture_s, v[i]->height_rmse_um);
        fputc('\n', f);
}

/* The presets' table: the figures of each preset on every scene. */
static void report_presets(FILE *f, const struct acc_study *st) {
        fprintf(f, "\n## Scan presets\n\n"
                   "Picked on %s from the capture-time front of the configurations a plan can express (default "
                   "processing, a dome sweep, no binning): **archival** = the most accurate, **draft** = the fastest "
                   "whose height RMSE is within %.0f× archival's, **standard** = the fastest after draft within "
                   "%.1f× archival's. Written to "
                   "`config/plans/{draft,standard,archival}.cfg` with the figures in their header and in "
                   "`config/plans/presets.json`, which `impasto plan estimate` reads.\n\n"
                   "| preset | config | frames | capture s | height RMSE µm | normal ° | ρd err |",
                st->scenes[0], HEIGHT_FACTOR_DRAFT, HEIGHT_FACTOR_STANDARD);
        for (int si = 1; si < st->n_scenes; si++)
                fprintf(f, " %s height µm |", st->scenes[si]);
        fprintf(f, "\n|---|---|---:|---:|---:|---:|---:|");
        for (int si = 1; si < st->n_scenes; si++)
                fprintf(f, "---:|");
        fputc('\n', f);
        for (int i = 0; i < 3; i++) {
                const struct acc_result *p = find_preset(st, preset_names[i]);
                if (!p)
                        continue;
                fprintf(f, "| %s | `%s` | %zu | %.2f | %.2f | %.2f | %.3f |", preset_names[i], p->cfg->name, p->frames,
                        p->capture_s, p->height_rmse_um, p->normal_err_deg, p->rho_d_err);
                for (int si = 1; si < st->n_scenes; si++) {
                        const struct acc_result *h = find(st, st->scenes[si], p->cfg->name);
                        fprintf(f, h && h->ok ? " %.2f |" : " – |", h ? h->height_rmse_um : 0);
                }
                fputc('\n', f);
        }
}

/* The simulator's cost: the rich renderings and the per-effect measurement. */
static void report_sim_cost(FILE *f, const struct acc_study *st) {
        fprintf(f, "\n## Simulator cost\n\n");
        for (int si = 0; si < st->n_scenes; si++)
                if (st->render_wall_s[si] > 0)
                        fprintf(f, "- rendering the rich set of %s: %zu frames in %.1f s wall, %.1f s CPU "
                                   "(%.1f ms CPU per frame)\n", st->scenes[si], st->render_frames[si],
                                st->render_wall_s[si], st->render_cpu_s[si],
                                1e3 * st->render_cpu_s[si] / (double) IMP_MAX(st->render_frames[si], 1));
        if (st->n_effects > 0) {
                fprintf(f, "\nPer effect on %s (bench/bench-sim-effects.c's measurement: `direct` alone, then each "
                           "effect alone on top of it; 4 frames: two dome lights, a Gray plane, a phase frame):\n\n"
                           "| effect | view maps s | ms/frame | shading evals | shadow rays | shadow steps | random draws "
                           "| projector lookups | distortion evals |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
                        st->effects_scene);
                for (int i = 0; i < st->n_effects; i++) {
                        const struct acc_effect_cost *e = &st->effects[i];
                        fprintf(f, "| %s | %.2f | %.1f | %llu | %llu | %llu | %llu | %llu | %llu |\n", e->effect, e->view_s,
                                e->ms_per_frame, e->shading_evals, e->shadow_rays, e->shadow_steps, e->random_draws,
                                e->projector_lookups, e->distortion_evals);
                }
        }
}

static int write_report(const struct acc_study *st, const struct machine *mc, const char *path, const char *img_dir) {
        FILE *f = fopen(path, "we");
        if (!f)
                return log_error_errno(-errno, "%s: %m", path), -errno;
        size_t ok = 0;
        for (size_t i = 0; i < st->n_results; i++)
                ok += st->results[i].ok;
        fprintf(f, "# Accuracy versus time\n\n"
                   "*Generated by `impasto bench accuracy%s` on %s — do not edit, rerun the command "
                   "(issue #9).* %zu configurations measured in %.0f s.\n\n",
                st->quick ? " --quick" : "", mc->date, ok, st->total_wall_s);
        fprintf(f, "## Machine\n\n| | |\n|---|---|\n| CPUs (nproc) | %ld |\n| CPU model | %s |\n| memory | %.1f GiB |\n"
                   "| system | %s |\n| build | %s |\n| date | %s |\n"
                   "| 1-minute load average | %.2f at the start, %.2f at the end |\n\n"
                   "The machine was shared with other jobs while this ran: wall times carry their load, CPU times "
                   "(user + system of the processing process) much less, so the processing front uses CPU time. "
                   "The **load** column is the 1-minute load average when the configuration's processing ended "
                   "(it includes the processing's own threads; on %ld CPUs, a load above %ld means it waited for "
                   "a CPU).\n\n",
                mc->nproc, mc->cpu, mc->mem_gib, mc->host, mc->build, mc->date, st->load_start, st->load_end, mc->nproc,
                mc->nproc);
        fprintf(f, "## Method\n\n"
                   "Each study scene (`config/scenes/study-*.cfg`) is rendered **once** by `impasto sim render` with "
                   "the richest plan (`out/accuracy/plans/SCENE/render.cfg`: Gray code on both axes with inverses, "
                   "12-step phase shifting at 16 and 64 projector pixels, white and black, at %.0f, %.0f and %.0f µs; "
                   "all 48 dome lights at %.0f, %.0f and %.0f µs). Every configuration is a scan plan "
                   "(`out/accuracy/plans/SCENE/CONFIG.cfg`); its capture set is derived by taking from the rich set "
                   "the frames the plan names (the 3-, 4- and 6-step phase frames are among the 12-step ones; a "
                   "dome subset is every 2nd or 4th light, so every ring keeps its share), and for `bin2` by "
                   "averaging 2×2 pixels with the camera model scaled to match. So a configuration costs "
                   "processing only.\n\n"
                   "- **capture s**: `imp_plan_estimate_s` of the plan on the study rig (Σ exposure + readout 10 ms "
                   "+ settle 2 ms, plus a settle per light or pattern switch). Independently, the simulator's own "
                   "clock (manifest timestamps) replayed over the derived set gives `sim_capture_s` in "
                   "results.json; the two agree within a settle.\n"
                   "- **proc wall / CPU s, peak RSS**: each configuration is processed by its own process, "
                   "`impasto process SET --out COPY --quiet` with the configuration's knobs as flags (`--threads`, "
                   "`--gray-only`, `--btf-iterations`, `--btf-robust-passes`, `--no-shadow-test`, `--cell`, "
                   "`--no-btf`; `process_flags` in results.json), fork and exec of `impasto`; wall from "
                   "the fork to `wait4`, CPU (user + system) and peak RSS from `wait4`'s rusage of that process "
                   "only.\n"
                   "- **copy MiB**: bytes of the copy directory (EXR textures, boxes, previews).\n"
                   "- **accuracy**: `imp_compare_dirs` + `imp_compare_appearance` against the simulator's truth: "
                   "height RMSE after the median offset, mean normal error, canvas-mask IoU, median relative ρd "
                   "error, median relative lobe-exponent error over unflagged glossy texels (– when none).\n"
                   "- **front**: **C** = non-dominated in (capture time, height RMSE), **P** = in (processing CPU "
                   "time, height RMSE), per scene.\n\n",
                st->sl_exposures_us[0], st->sl_exposures_us[1], st->sl_exposures_us[2], st->dome_exposures_us[0],
                st->dome_exposures_us[1], st->dome_exposures_us[2]);
        report_method_changes(f, st);
        for (int si = 0; si < st->n_scenes; si++) {
                fprintf(f, "## %s\n\n", st->scenes[si]);
                if (st->render_frames[si])
                        fprintf(f, "Rich rendering: %zu frames, %s.\n\n", st->render_frames[si],
                                st->render_wall_s[si] > 0 ? "see below" : "reused from an earlier run");
                report_table(f, st, st->scenes[si]);
                fprintf(f, "![height RMSE vs capture time, %s](%s/capture-%s.svg)\n\n", st->scenes[si], img_dir,
                        st->scenes[si]);
                fprintf(f, "![height RMSE vs processing time, %s](%s/processing-%s.svg)\n\n", st->scenes[si], img_dir,
                        st->scenes[si]);
        }
        fprintf(f, "## Pareto fronts\n\n");
        for (int si = 0; si < st->n_scenes; si++) {
                report_front(f, st, st->scenes[si], false);
                report_front(f, st, st->scenes[si], true);
        }
        report_presets(f, st);
        report_sim_cost(f, st);
        fprintf(f, "\n## Not measured here\n\n"
                   "- **Fewer Gray bits** (dropping LSB planes and letting the phase resolve the period): the "
                   "decoder (`imp_sl_decode`) rejects a code with fewer bits than the projector needs, so this "
                   "knob waits for a decoder change; the cheaper-Gray-code axis here is inverses on/off and one "
                   "axis only.\n"
                   "- **Held-out re-render RMSE**: the sweep fits every light (no `--holdout`), so that column "
                   "is absent; ρd and lobe errors against the truth stand in for it.\n"
                   "- **Binning's readout time**: the rig model keeps the full readout for binned frames.\n");
        return fclose(f) == 0 ? 0 : -EIO;
}

int acc_write_outputs(const struct acc_study *st) {
        struct machine mc;
        machine_info(&mc);
        char path[4096];
        int r;
        pathf(path, sizeof path, "%s/results.csv", st->out_dir);
        if ((r = write_csv(st, path)) < 0)
                return r;

        _cleanup_json_ json_t *j = json_pack("{s:{s:I,s:s,s:f,s:s,s:s,s:s,s:f,s:f},s:b,s:f,s:o,s:o,s:o,s:o}",
                "machine", "nproc", (json_int_t) mc.nproc, "cpu", mc.cpu, "memory_gib", mc.mem_gib, "system", mc.host,
                "date", mc.date, "build", mc.build, "load_start", st->load_start, "load_end", st->load_end,
                "quick", st->quick, "total_wall_s", st->total_wall_s, "scenes", json_array(),
                "configurations", json_array(), "presets", json_object(), "sim_effects", json_array());
        if (!j)
                return log_error("out of memory"), -ENOMEM;
        for (int si = 0; si < st->n_scenes; si++)
                json_array_append_new(json_object_get(j, "scenes"), json_pack("{s:s,s:I,s:f,s:f}", "name", st->scenes[si],
                        "render_frames", (json_int_t) st->render_frames[si], "render_wall_s", st->render_wall_s[si],
                        "render_cpu_s", st->render_cpu_s[si]));
        for (size_t i = 0; i < st->n_results; i++)
                json_array_append_new(json_object_get(j, "configurations"), result_json(&st->results[i]));
        char preset_dir[4096];
        pathf(preset_dir, sizeof preset_dir, "%s/presets", st->out_dir);
        for (int i = 0; i < 3; i++) {
                const struct acc_result *p = find_preset(st, preset_names[i]);
                if (!p)
                        continue;
                pathf(path, sizeof path, "%s/%s.cfg", preset_dir, preset_names[i]);
                json_object_set_new(json_object_get(j, "presets"), preset_names[i], preset_json(st, p, path));
        }
        for (int i = 0; i < st->n_effects; i++) {
                const struct acc_effect_cost *e = &st->effects[i];
                json_array_append_new(json_object_get(j, "sim_effects"), json_pack("{s:s,s:f,s:f,s:I,s:I,s:I,s:I,s:I}",
                        "effect", e->effect, "view_s", e->view_s, "ms_per_frame", e->ms_per_frame,
                        "shading_evals", (json_int_t) e->shading_evals, "shadow_rays", (json_int_t) e->shadow_rays,
                        "shadow_steps", (json_int_t) e->shadow_steps, "random_draws", (json_int_t) e->random_draws,
                        "projector_lookups", (json_int_t) e->projector_lookups));
        }
        struct imp_error err = {};
        pathf(path, sizeof path, "%s/results.json", st->out_dir);
        if ((r = imp_json_save_atomic(path, j, &err)) < 0)
                return log_error("%s", err.msg), r;
        if ((r = write_presets(st, &mc, preset_dir)) < 0)
                return r;

        char docs_img[4096];
        pathf(docs_img, sizeof docs_img, "%s/docs/accuracy", st->repo_dir ? st->repo_dir : ".");
        if (st->repo_dir && (r = imp_mkdir_p(docs_img, 0755)) < 0)
                return log_error_errno(r, "%s: %m", docs_img);
        for (int si = 0; si < st->n_scenes; si++)
                for (int p = 0; p < 2; p++) {
                        pathf(path, sizeof path, "%s/%s-%s.svg", st->out_dir, p ? "processing" : "capture",
                                 st->scenes[si]);
                        if ((r = write_svg(st, path, st->scenes[si], p)) < 0)
                                return r;
                        if (!st->repo_dir)
                                continue;
                        pathf(path, sizeof path, "%s/%s-%s.svg", docs_img, p ? "processing" : "capture",
                                 st->scenes[si]);
                        if ((r = write_svg(st, path, st->scenes[si], p)) < 0)
                                return r;
                }
        pathf(path, sizeof path, "%s/accuracy-vs-time.md", st->out_dir);
        if ((r = write_report(st, &mc, path, ".")) < 0)
                return r;
        if (!st->repo_dir)
                return 0;
        pathf(path, sizeof path, "%s/docs/accuracy-vs-time.md", st->repo_dir);
        if ((r = write_report(st, &mc, path, "accuracy")) < 0)
                return r;
        pathf(path, sizeof path, "%s/config/plans", st->repo_dir);
        return write_presets(st, &mc, path);
}
