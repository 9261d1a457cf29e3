/* Issue #9 acceptance through the `impasto` binary: `impasto bench accuracy --quick` runs
 * the reduced sweep on the demo-like study scene, and its results.json must show that the
 * archival preset is at least twice as accurate in height RMSE as draft, that draft
 * captures at least three times faster, and that `impasto plan estimate` of each preset
 * file (the rig model over the plan) is within 10 % of the simulated capture time of the
 * preset's capture set (the simulator's clock, replayed from the set's manifest). The last
 * check is repeated without the bench's arithmetic: the rich rendering's own manifest end
 * time against `plan estimate` of the rendered plan. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define WORK    IMPASTO_BINARY_DIR "/tests/accuracy-quick"
#define SCENE   IMPASTO_SOURCE_DIR "/config/scenes/study-demo.cfg"
#define CAPTURE_TOLERANCE 0.10   /* plan estimate vs simulated capture time, relative */

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static double num(const json_t *j, const char *key) {
        json_t *v = json_object_get(j, key);
        CHECK_MSG(json_is_number(v), "\"%s\" missing", key);
        return json_is_number(v) ? json_number_value(v) : NAN;
}

/* `impasto plan estimate PLAN --scene study-demo --json` → duration_s (and the object). */
static double estimate(const char *plan, const char *name, json_t **ret) {
        char cmd[16384], out[4096];
        snprintf(out, sizeof out, WORK "/%s.estimate.json", name);
        snprintf(cmd, sizeof cmd, "%s plan estimate %s --scene %s --json > %s", IMPASTO, plan, SCENE, out);
        CHECK_INT_EQ(run(cmd), 0);
        struct imp_error err = {};
        json_t *j = NULL;
        CHECK_OK(imp_json_load(out, &j, &err));
        if (!j)
                return NAN;
        *ret = j;
        return num(j, "duration_s");
}

/* The simulator's clock at the end of a set: t_frame_ns of its last manifest record. */
static double manifest_end_s(const char *set) {
        char path[4096], line[8192], last[8192] = "";
        snprintf(path, sizeof path, "%s/manifest.jsonl", set);
        FILE *f = fopen(path, "re");
        CHECK_MSG(f, "%s: cannot open", path);
        if (!f)
                return NAN;
        while (fgets(line, sizeof line, f))
                if (line[0] == '{')
                        memcpy(last, line, sizeof last);
        fclose(f);
        json_error_t e;
        _cleanup_json_ json_t *j = json_loads(last, 0, &e);
        return j ? num(j, "t_frame_ns") * 1e-9 : NAN;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        CHECK_INT_EQ(run("rm -rf " WORK " && mkdir -p " WORK), 0);
        CHECK_INT_EQ(run(IMPASTO " bench accuracy --quick --out " WORK), 0);

        struct imp_error err = {};
        _cleanup_json_ json_t *res = NULL;
        CHECK_OK(imp_json_load(WORK "/results.json", &res, &err));
        if (!res) {
                fprintf(stderr, "%s\n", err.msg);
                return TEST_DONE();
        }
        json_t *configs = json_object_get(res, "configurations"), *c;
        CHECK_INT_GE(json_array_size(configs), 6);
        size_t i;
        json_array_foreach(configs, i, c) {
                CHECK_MSG(json_is_true(json_object_get(c, "ok")), "configuration %s failed",
                          json_string_value(json_object_get(c, "config")));
                CHECK_INT_EQ(num(c, "nan_count"), 0);
        }

        json_t *presets = json_object_get(res, "presets");
        json_t *draft = json_object_get(presets, "draft"), *archival = json_object_get(presets, "archival");
        CHECK_MSG(draft && archival, "results.json: presets.draft and presets.archival expected");
        if (!draft || !archival)
                return TEST_DONE();
        CHECK_STR_EQ(json_string_value(json_object_get(draft, "scene")), "study-demo");
        CHECK_STR_EQ(json_string_value(json_object_get(archival, "scene")), "study-demo");
        double h_draft = num(draft, "height_rmse_um"), h_arch = num(archival, "height_rmse_um");
        double t_draft = num(draft, "capture_s"), t_arch = num(archival, "capture_s");
        fprintf(stderr, "draft: %.2f um in %.2f s; archival: %.2f um in %.2f s\n", h_draft, t_draft, h_arch, t_arch);
        CHECK_GE(h_draft, 2 * h_arch);
        CHECK_GE(t_arch, 3 * t_draft);

        const char *key;
        json_t *p;
        json_object_foreach(presets, key, p) {
                char plan[4096];
                snprintf(plan, sizeof plan, WORK "/presets/%s.cfg", key);
                _cleanup_json_ json_t *est = NULL;
                double t_plan = estimate(plan, key, &est), t_sim = num(p, "sim_capture_s");
                fprintf(stderr, "%s: plan estimate %.3f s, simulated %.3f s\n", key, t_plan, t_sim);
                CHECK_NEAR(t_plan, t_sim, CAPTURE_TOLERANCE * t_sim);
                /* plan estimate reads the measured figures from presets.json beside the plan */
                json_t *acc = est ? json_object_get(est, "expected_accuracy") : NULL;
                CHECK_MSG(acc, "%s: plan estimate printed no expected accuracy", key);
                if (acc)
                        CHECK_NEAR(num(acc, "height_rmse_um"), num(p, "height_rmse_um"), 1e-9);
        }

        _cleanup_json_ json_t *rich = NULL;
        double t_plan = estimate(WORK "/plans/study-demo/render.cfg", "render", &rich);
        double t_clock = manifest_end_s(WORK "/sets/study-demo/rich");
        fprintf(stderr, "rich rendering: plan estimate %.3f s, simulator clock %.3f s\n", t_plan, t_clock);
        CHECK_NEAR(t_plan, t_clock, CAPTURE_TOLERANCE * t_clock);
        return TEST_DONE();
}
