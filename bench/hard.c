/* `impasto bench hard [--out DIR] [--repo DIR] [--only NAME]…`: the hard-case suite. Every
 * config/scenes/hard-*.cfg is rendered with config/plans/hard.cfg, processed and compared
 * with its truth, each step by exec'ing this binary (`impasto sim render`, `impasto
 * process --quiet`, `impasto compare --json`), so every row is a command line anyone can
 * rerun; the table goes to REPO/docs/hard-cases.md (generated: edit this file, not that).
 * A scene the loader refuses (invalid parameters) is a row with the loader's message. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <math.h>
#include <spawn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "bench-study.h"
#include "hard.h"
#include "json-util.h"
#include "log.h"
#include "sibling.h"

extern char **environ;

#define HARD_MAX_SCENES 64

struct hard_row {
        char name[64];
        int render_rc, process_rc, compare_rc;
        char message[256];            /* the loader's or the process's first error line, or the
                                         verdict's first reason */
        char verdict[16];
        double seconds;
        json_t *cmp;                  /* compare --json, NULL when not compared */
        double flagged;               /* copy.json quality.flagged_fraction */
};

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Runs the impasto beside impasto-bench with argv (argv[0] ignored), stdout to out_path, stderr to err_path. */
static int run_self(char *const argv[], const char *out_path, const char *err_path) {
        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        posix_spawn_file_actions_addopen(&fa, 1, out_path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        posix_spawn_file_actions_addopen(&fa, 2, err_path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        pid_t pid;
        char exe[4096];
        int r = imp_sibling_path("impasto", exe, sizeof exe);
        if (r < 0) {
                posix_spawn_file_actions_destroy(&fa);
                return r;
        }
        r = posix_spawn(&pid, exe, &fa, NULL, argv, environ);
        posix_spawn_file_actions_destroy(&fa);
        if (r != 0)
                return -r;
        int st;
        if (waitpid(pid, &st, 0) < 0)
                return -errno;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

/* The first line of a file that says "error" (or the first line), into buf. */
static void first_error(const char *path, char *buf, size_t size) {
        FILE *f = fopen(path, "re");
        char line[512];
        buf[0] = 0;
        if (!f)
                return;
        while (fgets(line, sizeof line, f)) {
                line[strcspn(line, "\n")] = 0;
                if (!buf[0] || strstr(line, "error")) {
                        const char *p = strstr(line, "error: ");
                        size_t len = strnlen(p ? p + 7 : line, size - 1);
                        memcpy(buf, p ? p + 7 : line, len);
                        buf[len] = 0;
                        if (p)
                                break;
                }
        }
        fclose(f);
}

/* Removes every occurrence of "prefix/" from s (the table names paths relative to the
 * repository and the output directory). */
static void strip_prefix(char *s, const char *prefix) {
        char pat[1100];
        snprintf(pat, sizeof pat, "%s/", prefix);
        size_t n = strlen(pat);
        for (char *p; n > 1 && (p = strstr(s, pat));)
                memmove(p, p + n, strlen(p + n) + 1);
}

static void run_scene(const char *repo, const char *out, const char *name, struct hard_row *row) {
        char scene[1024], plan[1024], cap[1024], copy[1024], truth[1100], log_out[1024], log_err[1024];
        snprintf(row->name, sizeof row->name, "%s", name);
        snprintf(scene, sizeof scene, "%s/config/scenes/%s.cfg", repo, name);
        snprintf(plan, sizeof plan, "%s/config/plans/hard.cfg", repo);
        snprintf(cap, sizeof cap, "%s/%s/capture", out, name);
        snprintf(copy, sizeof copy, "%s/%s/copy", out, name);
        snprintf(truth, sizeof truth, "%s/truth", cap);
        snprintf(log_out, sizeof log_out, "%s/%s.out", out, name);
        snprintf(log_err, sizeof log_err, "%s/%s.err", out, name);
        double t0 = now_s();
        row->process_rc = row->compare_rc = -1;
        char *render[] = { "impasto", "sim", "render", "--scene", scene, "--plan", plan, "--out", cap, NULL };
        row->render_rc = run_self(render, log_out, log_err);
        if (row->render_rc != 0) {
                first_error(log_err, row->message, sizeof row->message);
                snprintf(row->verdict, sizeof row->verdict, "refused");
                row->seconds = now_s() - t0;
                strip_prefix(row->message, repo);
                return;
        }
        char *process[] = { "impasto", "process", cap, "--out", copy, "--quiet", "--force", NULL };
        row->process_rc = run_self(process, log_out, log_err);
        if (row->process_rc != 0)
                first_error(log_err, row->message, sizeof row->message);
        char path[1100];
        snprintf(path, sizeof path, "%s/copy.json", copy);
        _cleanup_json_ json_t *cj = NULL;
        if (imp_json_load(path, &cj, NULL) >= 0) {
                json_t *q = json_object_get(cj, "quality");
                snprintf(row->verdict, sizeof row->verdict, "%s",
                         json_string_value(json_object_get(q, "verdict")) ?: "?");
                row->flagged = json_number_value(json_object_get(q, "flagged_fraction"));
                const char *why = json_string_value(json_array_get(json_object_get(q, "reasons"), 0));
                if (row->process_rc == 0 && why)   /* a degraded copy: why (the flag behind it) */
                        snprintf(row->message, sizeof row->message, "%s", why);
        } else
                snprintf(row->verdict, sizeof row->verdict, "none");
        snprintf(path, sizeof path, "%s/%s.json", out, name);
        if (row->process_rc == 0) {
                char *compare[] = { "impasto", "compare", copy, "--truth", truth, "--json", NULL };
                row->compare_rc = run_self(compare, path, log_err);
                if (row->compare_rc == 0)
                        imp_json_load(path, &row->cmp, NULL);
        }
        row->seconds = now_s() - t0;
        strip_prefix(row->message, out);
        strip_prefix(row->message, repo);
}

static double num(const json_t *j, const char *key) {
        return json_number_value(json_object_get(j, key));
}

/* A compare figure as text, "–" when compare could not measure it (null or absent). */
static const char *fig(const json_t *j, const char *key, int prec, const char *unit, char *buf, size_t size) {
        const json_t *v = json_object_get(j, key);
        if (!json_is_number(v))
                return "–";
        snprintf(buf, size, "%.*f%s", prec, json_number_value(v), unit);
        return buf;
}

#define HARD_PLACEMENT_MAX_DEG 2.0    /* "placement right": copy normal within this of truth */

static int write_report(const char *repo, const struct hard_row *rows, size_t n, double total_s) {
        char path[1024];
        snprintf(path, sizeof path, "%s/docs/hard-cases.md", repo);
        FILE *f = fopen(path, "we");
        if (!f)
                return -errno;
        fprintf(f, "# Hard cases: right, honestly uncertain, or refused\n\n"
                   "Generated by `impasto bench hard` (bench/hard.c); do not edit. Each scene\n"
                   "`config/scenes/hard-*.cfg` is rendered with `config/plans/hard.cfg`, processed with\n"
                   "`impasto process --quiet` (every stage) and compared with its truth. The verdict rules\n"
                   "are in docs/copy-quality.md.\n\n"
                   "Columns: *placement* = angle between the copy's canvas normal and the truth's (right\n"
                   "when ≤ %.0f°); *frame* = fraction of the copy's canvas texels that lie on the truth frame;\n"
                   "*>3σ h* and *>3σ n* = fraction of the unflagged texels whose height error exceeds 3σ\n"
                   "(after the median offset) and whose normal error exceeds 3σ_n; *max n* = largest normal\n"
                   "error of an unflagged texel and *>10°* how many exceed 10°; *>3σ h prom.* = the same\n"
                   "height figure over the measured texels without a height flag (saturated, filled,\n"
                   "frame_adjacent, phase_rejected) whatever their normal flags; *flagged* = fraction of\n"
                   "the compared texels with a flag; *rc* = exit code of `impasto process` (6: unusable);\n"
                   "– where there is nothing to measure (no unflagged texel, or no copy); *note* = the\n"
                   "refusal, or the verdict's first reason.\n\n",
                HARD_PLACEMENT_MAX_DEG);
        fprintf(f, "| scene | rc | verdict | placement | frame | >3σ h | >3σ n | max n | >10° | >3σ h prom. | flagged | s "
                   "| note |\n|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
        for (size_t i = 0; i < n; i++) {
                const struct hard_row *r = &rows[i];
                fprintf(f, "| %s | %d | %s |", r->name + 5, r->render_rc ? r->render_rc : r->process_rc, r->verdict);
                if (r->cmp) {
                        double pl = num(r->cmp, "placement_deg");
                        bool none = json_integer_value(json_object_get(r->cmp, "n_unflagged")) == 0;
                        char b[5][32];
                        /* with every texel flagged there is no unflagged figure to give */
                        fprintf(f, " %.2f° (%s) | %.4f | %s | %s | %s | %s | %s | %.3f |", pl,
                                pl <= HARD_PLACEMENT_MAX_DEG ? "right" : "WRONG", num(r->cmp, "frame_texel_fraction"),
                                none ? "–" : fig(r->cmp, "beyond_3sigma_height", 4, "", b[0], sizeof b[0]),
                                none ? "–" : fig(r->cmp, "beyond_3sigma_normal", 4, "", b[1], sizeof b[1]),
                                none ? "–" : fig(r->cmp, "unflagged_normal_err_deg_max", 1, "°", b[2], sizeof b[2]),
                                none ? "–" : fig(r->cmp, "unflagged_normal_over_10deg", 0, "", b[3], sizeof b[3]),
                                fig(r->cmp, "beyond_3sigma_height_promised", 4, "", b[4], sizeof b[4]),
                                num(r->cmp, "flagged_fraction"));
                } else
                        fprintf(f, " – | – | – | – | – | – | – | – |");
                fprintf(f, " %.0f | %s |\n", r->seconds, r->message);
        }
        fprintf(f, "\n%zu scenes in %.0f s.\n", n, total_s);
        fclose(f);
        return 0;
}

static int cmp_names(const void *a, const void *b) {
        return strcmp(*(char *const *) a, *(char *const *) b);
}

int imp_bench_hard(int argc, char **argv) {
        const char *repo = IMPASTO_SOURCE_DIR, *out = "hard-cases";
        const char *only[HARD_MAX_SCENES];
        int n_only = 0, c;
        static const struct option longopts[] = {
                { "out", required_argument, NULL, 'o' }, { "repo", required_argument, NULL, 'r' },
                { "only", required_argument, NULL, 'n' }, { "help", no_argument, NULL, 'h' }, {}
        };
        while ((c = getopt_long(argc, argv, "h", longopts, NULL)) >= 0)
                switch (c) {
                case 'o': out = optarg; break;
                case 'r': repo = optarg; break;
                case 'n':
                        if (n_only < HARD_MAX_SCENES)
                                only[n_only++] = optarg;
                        break;
                case 'h':
                        printf("usage: impasto bench hard [--out DIR] [--repo DIR] [--only hard-NAME]...\n");
                        return 0;
                default: return 2;
                }
        char dir[1024];
        snprintf(dir, sizeof dir, "%s/config/scenes", repo);
        DIR *d = opendir(dir);
        if (!d) {
                log_error("%s: %m", dir);
                return 1;
        }
        char *names[HARD_MAX_SCENES];
        size_t n = 0;
        struct dirent *e;
        while ((e = readdir(d)) && n < HARD_MAX_SCENES) {
                size_t len = strlen(e->d_name);
                if (strncmp(e->d_name, "hard-", 5) || len < 5 || strcmp(e->d_name + len - 4, ".cfg"))
                        continue;
                bool want = n_only == 0;
                for (int k = 0; k < n_only && !want; k++)
                        want = !strncmp(only[k], e->d_name, len - 4) && strlen(only[k]) == len - 4;
                if (want)
                        names[n++] = strndup(e->d_name, len - 4);
        }
        closedir(d);
        qsort(names, n, sizeof *names, cmp_names);
        if (imp_mkdir_p(out, 0755) < 0) {
                log_error("%s: cannot create", out);
                return 1;
        }
        struct hard_row *rows = calloc(n ? n : 1, sizeof *rows);
        if (!rows)
                return 1;
        double t0 = now_s();
        for (size_t i = 0; i < n; i++) {
                run_scene(repo, out, names[i], &rows[i]);
                printf("%-28s render %d process %d verdict %-9s %5.0f s %s\n", names[i], rows[i].render_rc,
                       rows[i].process_rc, rows[i].verdict, rows[i].seconds, rows[i].message);
                fflush(stdout);
        }
        int r = n_only ? 0 : write_report(repo, rows, n, now_s() - t0);
        if (r < 0)
                log_error("docs/hard-cases.md: %s", strerror(-r));
        for (size_t i = 0; i < n; i++) {
                json_decref(rows[i].cmp);
                free(names[i]);
        }
        free(rows);
        return r < 0 ? 1 : 0;
}

IMP_BENCH_STUDY(hard, .name = "hard",
                .summary = "the hard-case suite: placement, flags, honest σ and verdicts (docs/hard-cases.md)",
                .run = imp_bench_hard);
