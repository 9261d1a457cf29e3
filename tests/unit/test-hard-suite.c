/* The hard-case suite's promises (docs/hard-cases.md, docs/copy-quality.md), end to end
 * through the `impasto` binary on config/scenes/hard-NAME.cfg with config/plans/hard.cfg:
 *
 *   test-hard-suite [--no-btf] [--plan PLAN] [--all] NAME...   (PLAN: config/plans/PLAN.cfg, default hard)
 *
 * Per scene: `sim render`; a scene named invalid-* must be refused by the loader with a
 * FILE:LINE message. Otherwise `process` must exit 0 (a copy), 6 (unusable: copy.json
 * says "unusable" with a reason) or 3 (a capture set that cannot be processed: an error
 * naming the capture set on stderr), the last two with no heightfield.exr, and nothing
 * else; a copy is
 * compared with its truth and must have: no NaN/Inf in any EXR channel; its canvas normal
 * within PLACEMENT_MAX_DEG of the truth's; at most FRAME_MAX of its canvas texels on the
 * truth frame; at most BEYOND_MAX of the unflagged texels beyond 3σ in height and in
 * normal angle (both measured: a copy without σ_n fails); no unflagged normal more than
 * 10° off; the heights of the texels without a height flag within 3σ_h (at most BEYOND_MAX
 * beyond), whatever their normal flags. A scene listed as NAME! must be refused (exit 6), as
 * NAME!WORD with WORD in the reason; as NAME@IOU it must give a copy whose canvas mask
 * covers the canvas the rig can measure with at least that IoU (mask_iou_observable: high
 * impasto cut into pockets lost most of its canvas). With --all, every
 * config/scenes/hard-*.cfg must be among the names (a new scene joins the suite). */
#include <dirent.h>
#include <fcntl.h>
#include <stdbool.h>
#include <spawn.h>
#include <unistd.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <jansson.h>
#include "test.h"

extern char **environ;

#define PLACEMENT_MAX_DEG 2.0         /* canvas normal vs the truth's: "placement right" */
#define FRAME_MAX         0.01        /* frame texels claimed as canvas */
#define BEYOND_MAX        0.01        /* unflagged texels beyond 3σ (height, normal) */
#define EXIT_UNUSABLE     6           /* cli/cmd-process.c IMP_EXIT_PROCESS_UNUSABLE */
#define EXIT_INVALID      3           /* cli/cmd-process.c IMP_EXIT_PROCESS_INVALID */

static int run(char *const argv[], const char *out_path, const char *err_path) {
        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        if (out_path)
                posix_spawn_file_actions_addopen(&fa, 1, out_path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        if (err_path)
                posix_spawn_file_actions_addopen(&fa, 2, err_path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        pid_t pid;
        int r = posix_spawn(&pid, argv[0], &fa, NULL, argv, environ);
        posix_spawn_file_actions_destroy(&fa);
        if (r != 0)
                return -1;
        int st;
        if (waitpid(pid, &st, 0) < 0)
                return -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
}

static char *slurp(const char *path) {
        FILE *f = fopen(path, "re");
        if (!f)
                return strdup("");
        char *buf = calloc(1, 65536);
        size_t n = fread(buf, 1, 65535, f);
        buf[n] = 0;
        fclose(f);
        return buf;
}

/* The loader names the file and the line: ".../hard-NAME.cfg:LINE:". */
static void check_refused_at_load(const char *name, const char *err_path) {
        char *e = slurp(err_path), pat[256];
        snprintf(pat, sizeof pat, "hard-%s.cfg:", name);
        const char *p = strstr(e, pat);
        CHECK_MSG(p && p[strlen(pat)] >= '1' && p[strlen(pat)] <= '9', "%s: no FILE:LINE in: %s", name, e);
        fprintf(stderr, "%s: refused at load: %s", name, e);
        free(e);
}

/* Exit 3: the capture set is refused before any stage; stderr names it. */
static void check_invalid_set(const char *name, const char *cap, const char *copy, const char *err_path) {
        char *e = slurp(err_path), path[4500];
        CHECK_MSG(strstr(e, cap) && strstr(e, "error"), "%s: exit 3 without an error naming %s: %s", name, cap, e);
        fprintf(stderr, "%s: refused: %s", name, e);
        free(e);
        snprintf(path, sizeof path, "%s/heightfield.exr", copy);
        struct stat st;
        CHECK_MSG(stat(path, &st) != 0, "%s: a refused set has a heightfield", name);
}

/* COPY/copy.json, NULL (and a failed check) when it cannot be read. */
static json_t *load_copy_json(const char *name, const char *copy) {
        char path[4500];
        snprintf(path, sizeof path, "%s/copy.json", copy);
        json_error_t je;
        json_t *j = json_load_file(path, 0, &je);
        CHECK_MSG(j != NULL, "%s: %s: %s", name, path, je.text);
        return j;
}

static void check_unusable(const char *name, const char *copy, const char *must_say) {
        char path[4500];
        json_t *j = load_copy_json(name, copy);
        json_t *q = json_object_get(j, "quality");
        const char *v = json_string_value(json_object_get(q, "verdict"));
        const char *why = json_string_value(json_array_get(json_object_get(q, "reasons"), 0));
        CHECK_MSG(v && !strcmp(v, "unusable"), "%s: verdict %s", name, v ? v : "(none)");
        CHECK_MSG(why && *why, "%s: unusable without a reason", name);
        CHECK_MSG(!*must_say || (why && strstr(why, must_say)), "%s: the refusal \"%s\" does not say \"%s\"", name,
                  why ? why : "", must_say);
        fprintf(stderr, "%s: refused: %s\n", name, why ? why : "");
        snprintf(path, sizeof path, "%s/heightfield.exr", copy);
        struct stat st;
        CHECK_MSG(stat(path, &st) != 0, "%s: a refused copy has a heightfield", name);
        json_decref(j);
}

static void check_copy(const char *name, const char *cmp_path, double min_iou) {
        json_error_t je;
        json_t *c = json_load_file(cmp_path, 0, &je);
        CHECK_MSG(c != NULL, "%s: %s: %s", name, cmp_path, je.text);
        if (!c)
                return;
#define NUM(k) json_number_value(json_object_get(c, k))
        long long nan = json_integer_value(json_object_get(c, "nan_count")) +
                        json_integer_value(json_object_get(c, "appearance_nan_count"));
        long long over = json_integer_value(json_object_get(c, "unflagged_normal_over_10deg"));
        fprintf(stderr, "%s: placement %.2f°, frame %.4f, beyond 3σ h %.4f n %.4f, max n %.1f° (%lld > 10°), "
                "flagged %.3f, NaN %lld\n", name, NUM("placement_deg"), NUM("frame_texel_fraction"),
                NUM("beyond_3sigma_height"), NUM("beyond_3sigma_normal"), NUM("unflagged_normal_err_deg_max"), over,
                NUM("flagged_fraction"), nan);
        CHECK_INT_EQ(nan, 0);
        fprintf(stderr, "%s: canvas mask IoU %.4f (%.4f over the canvas the rig can measure)\n", name,
                NUM("mask_iou"), NUM("mask_iou_observable"));
        CHECK_MSG(!(min_iou > 0) || NUM("mask_iou_observable") >= min_iou, "%s: canvas mask IoU %.4f over the "
                  "measurable canvas, at least %.2f expected", name, NUM("mask_iou_observable"), min_iou);
        CHECK_MSG(NUM("placement_deg") >= 0 && NUM("placement_deg") <= PLACEMENT_MAX_DEG, "%s: placement %.2f°",
                  name, NUM("placement_deg"));
        CHECK_MSG(NUM("frame_texel_fraction") <= FRAME_MAX, "%s: frame as canvas %.4f", name,
                  NUM("frame_texel_fraction"));
        CHECK_MSG(NUM("beyond_3sigma_height") <= BEYOND_MAX, "%s: beyond 3σ height %.4f", name,
                  NUM("beyond_3sigma_height"));
        /* Over the unflagged texels: numbers when there are any, null (not a 0 that reads as
         * perfect) when every texel carries a flag. */
        bool any_unflagged = json_integer_value(json_object_get(c, "n_unflagged")) > 0;
        CHECK_MSG(any_unflagged ? json_is_number(json_object_get(c, "beyond_3sigma_height")) &&
                                          json_is_number(json_object_get(c, "beyond_3sigma_normal"))
                                : json_is_null(json_object_get(c, "beyond_3sigma_height")) &&
                                          json_is_null(json_object_get(c, "beyond_3sigma_normal")),
                  "%s: σ figures %s with %s unflagged texels", name, any_unflagged ? "not measured" : "not null",
                  any_unflagged ? "some" : "no");
        CHECK_MSG(NUM("beyond_3sigma_normal") >= 0 && NUM("beyond_3sigma_normal") <= BEYOND_MAX,
                  "%s: beyond 3σ normal %.4f", name, NUM("beyond_3sigma_normal"));
        CHECK_MSG(over == 0, "%s: %lld unflagged normals more than 10° off", name, over);
        /* A normal's flag does not excuse its height: over the measured texels without a
         * height flag (saturated, filled, frame_adjacent, phase_rejected) the heights lie
         * within 3σ_h too; on a copy whose every texel is normal_uncertain this is all the
         * suite can hold it to. */
        long long nh = json_integer_value(json_object_get(c, "n_height_promised"));
        fprintf(stderr, "%s: heights promised on %lld texels, beyond 3σ %.4f\n", name, nh,
                NUM("beyond_3sigma_height_promised"));
        CHECK_MSG(nh > 0 ? json_is_number(json_object_get(c, "beyond_3sigma_height_promised"))
                         : json_is_null(json_object_get(c, "beyond_3sigma_height_promised")),
                  "%s: beyond_3sigma_height_promised not measured", name);
        CHECK_MSG(NUM("beyond_3sigma_height_promised") <= BEYOND_MAX, "%s: beyond 3σ height (promised) %.4f", name,
                  NUM("beyond_3sigma_height_promised"));
#undef NUM
        json_decref(c);
}

/* One of the verdict's reasons (quality.reasons) contains word. */
static bool reason_says(json_t *q, const char *word) {
        json_t *r;
        size_t i;
        json_array_foreach(json_object_get(q, "reasons"), i, r)
                if (json_string_value(r) && strstr(json_string_value(r), word))
                        return true;
        return false;
}

/* Flags that say why, not what followed (the photometric normal not kept: normal_uncertain,
 * photometric_rejected, fit_failed); frame_adjacent says where. */
static const char *const cause_flags[] = { "saturated", "dark", "shadowed", "interreflection", "filled",
                                           "few_samples", "phase_rejected" };
#define CAUSE_NAMED_MIN 0.9   /* a cause on this fraction of the texels must be in the reason */

/* A copy with more than 25 % of its texels flagged is degraded, and the reason names the flag
 * most of them carry (so that the verdict says what to change, not only "flagged"), or the
 * cause flag behind it when one covers nearly every texel (the advice for the consequence
 * sent the operator to the lens or the paint when a deep frame hid the lights). */
static void check_verdict(const char *name, const char *copy) {
        char path[4500];
        snprintf(path, sizeof path, "%s/copy.json", copy);
        json_error_t je;
        json_t *j = json_load_file(path, 0, &je);
        CHECK_MSG(j != NULL, "%s: %s: %s", name, path, je.text);
        json_t *q = json_object_get(j, "quality"), *flags = json_object_get(q, "flags");
        const char *v = json_string_value(json_object_get(q, "verdict")), *top = NULL, *k;
        double best = -1;
        json_t *val;
        json_object_foreach(flags, k, val)
                if (json_number_value(val) > best) {
                        best = json_number_value(val);
                        top = k;
                }
        if (json_number_value(json_object_get(q, "flagged_fraction")) > 0.25) {
                const char *why = json_string_value(json_array_get(json_object_get(q, "reasons"), 0));
                CHECK_MSG(v && strcmp(v, "ok"), "%s: %.0f %% flagged, verdict %s", name,
                          100 * json_number_value(json_object_get(q, "flagged_fraction")), v ? v : "(none)");
                CHECK_MSG(why && top && strstr(why, top) && strchr(why, '('), "%s: the reason \"%s\" does not name %s "
                          "and what would lift it", name, why ? why : "", top ? top : "?");
                const char *cause = NULL;
                for (size_t i = 0; i < sizeof cause_flags / sizeof *cause_flags; i++)
                        if (json_number_value(json_object_get(flags, cause_flags[i])) >= CAUSE_NAMED_MIN &&
                            (!cause || (why && !strstr(why, cause))))
                                cause = cause_flags[i];
                CHECK_MSG(!cause || (why && strstr(why, cause)), "%s: %s covers %.0f %% of the texels but the reason "
                          "\"%s\" does not name it", name, cause ? cause : "",
                          100 * json_number_value(json_object_get(flags, cause ? cause : "")), why ? why : "");
        }
        /* A canvas with holes over more than a quarter of its outline (high impasto): the
         * verdict says so. */
        json_t *hfj = json_object_get(json_object_get(j, "stages"), "heightfield");
        double outline = (double) json_integer_value(json_object_get(hfj, "outline_texels"));
        double mask = (double) json_integer_value(json_object_get(hfj, "mask_texels"));
        if (outline > 0 && mask < 0.75 * outline)
                CHECK_MSG(reason_says(q, "within its outline") && v && strcmp(v, "ok"), "%s: %.0f %% of the canvas's "
                          "outline has no texel, verdict %s without a reason saying so", name,
                          100 * (1 - mask / outline), v ? v : "(none)");
        /* The appearance fitted on few texels (stages.btf): the verdict says so. */
        json_t *btf = json_object_get(json_object_get(j, "stages"), "btf");
        /* Fewer than 8 lights: no photometric normal anywhere, and the texels say why. */
        double lights = json_number_value(json_object_get(btf, "lights"));
        if (btf && lights > 0 && lights < 8)
                CHECK_MSG(json_number_value(json_object_get(flags, "few_samples")) >= 0.99, "%s: %.0f lights, but "
                          "few_samples on %.0f %% of the texels", name, lights,
                          100 * json_number_value(json_object_get(flags, "few_samples")));
        double texels = (double) json_integer_value(json_object_get(q, "texels"));
        if (btf && texels > 0 && json_number_value(json_object_get(btf, "few_samples")) > 0.25 * texels)
                CHECK_MSG(reason_says(q, "appearance") && v && strcmp(v, "ok"), "%s: the BTF lacked samples on %.0f %% "
                          "of the texels, verdict %s without a reason naming the appearance", name,
                          100 * json_number_value(json_object_get(btf, "few_samples")) / texels, v ? v : "(none)");
        json_decref(j);
}

/* --all: every config/scenes/hard-NAME.cfg is among argv (NAME, NAME! or NAME@IOU). */
static void check_all_listed(int argc, char **argv) {
        char dir[4096];
        snprintf(dir, sizeof dir, "%s/config/scenes", IMPASTO_SOURCE_DIR);
        DIR *d = opendir(dir);
        CHECK_MSG(d != NULL, "%s: cannot list", dir);
        struct dirent *de;
        while (d && (de = readdir(d))) {
                size_t len = strlen(de->d_name);
                if (strncmp(de->d_name, "hard-", 5) || len < 10 || strcmp(de->d_name + len - 4, ".cfg"))
                        continue;
                bool listed = false;
                for (int a = 1; a < argc && !listed; a++) {
                        size_t n = strcspn(argv[a], "!@");
                        listed = n == len - 9 && !strncmp(argv[a], de->d_name + 5, n);
                }
                CHECK_MSG(listed, "%s is not in the suite's list (tests/hard.cmake)", de->d_name);
        }
        if (d)
                closedir(d);
}

int main(int argc, char **argv) {
        const char *tmp = test_tmpdir();
        char bin[4096], plan[4096];
        snprintf(bin, sizeof bin, "%s/cli/impasto", IMPASTO_BINARY_DIR);
        snprintf(plan, sizeof plan, "%s/config/plans/hard.cfg", IMPASTO_SOURCE_DIR);
        if (access(bin, X_OK) != 0)
                TEST_SKIP("%s not built", bin);
        bool btf = true;
        for (int a = 1; a < argc; a++) {
                if (!strcmp(argv[a], "--all")) {
                        check_all_listed(argc, argv);
                        continue;
                }
                if (!strcmp(argv[a], "--no-btf")) {
                        btf = false;
                        continue;
                }
                if (!strcmp(argv[a], "--plan") && a + 1 < argc) {
                        snprintf(plan, sizeof plan, "%s/config/plans/%s.cfg", IMPASTO_SOURCE_DIR, argv[++a]);
                        continue;
                }
                char name[128], scene[4400], cap[4400], copy[4400], truth[4500], cmp[4400], err_path[4400];
                snprintf(name, sizeof name, "%s", argv[a]);
                char *at = strchr(name, '@');
                double min_iou = at ? atof(at + 1) : 0;
                if (at)
                        *at = 0;
                char *bang = strchr(name, '!');
                bool must_refuse = bang != NULL;
                const char *must_say = "";
                if (bang) {
                        *bang = 0;
                        must_say = bang + 1;
                }
                snprintf(scene, sizeof scene, "%s/config/scenes/hard-%s.cfg", IMPASTO_SOURCE_DIR, name);
                snprintf(cap, sizeof cap, "%s/%s/capture", tmp, name);
                snprintf(copy, sizeof copy, "%s/%s/copy", tmp, name);
                snprintf(truth, sizeof truth, "%s/truth", cap);
                snprintf(cmp, sizeof cmp, "%s/%s.json", tmp, name);
                snprintf(err_path, sizeof err_path, "%s/%s.err", tmp, name);
                char *render[] = { bin, "sim", "render", "--scene", scene, "--plan", plan, "--out", cap, NULL };
                int rc = run(render, "/dev/null", err_path);
                if (!strncmp(name, "invalid-", 8)) {
                        CHECK_MSG(rc != 0, "%s: the loader accepted an invalid scene", name);
                        check_refused_at_load(name, err_path);
                        continue;
                }
                CHECK_MSG(rc == 0, "%s: render exited %d", name, rc);
                char *process[] = { bin, "process", cap, "--out", copy, "--quiet", btf ? NULL : "--no-btf", NULL };
                rc = run(process, "/dev/null", err_path);
                CHECK_MSG(rc == 0 || rc == EXIT_UNUSABLE || rc == EXIT_INVALID, "%s: process exited %d", name, rc);
                if (must_refuse)
                        CHECK_MSG(rc == EXIT_UNUSABLE, "%s: expected a refusal, process exited %d", name, rc);
                if (min_iou > 0)   /* a refusal of a canvas the rig can measure is no answer */
                        CHECK_MSG(rc == 0, "%s: process exited %d, a copy with mask IoU >= %.2f expected", name, rc,
                                  min_iou);
                if (rc == EXIT_UNUSABLE) {
                        check_unusable(name, copy, must_say);
                        continue;
                }
                if (rc == EXIT_INVALID) {
                        check_invalid_set(name, cap, copy, err_path);
                        continue;
                }
                if (rc != 0)
                        continue;
                char *compare[] = { bin, "compare", copy, "--truth", truth, "--json", NULL };
                rc = run(compare, cmp, err_path);
                CHECK_MSG(rc == 0, "%s: compare exited %d", name, rc);
                if (rc == 0)
                        check_copy(name, cmp, min_iou);
                check_verdict(name, copy);
        }
        return TEST_DONE();
}
