/* What the processing-cost measurements rest on (docs/accuracy-vs-time.md "Method changes",
 * docs/jobs.md worker_build): on a tiny rendered set (tests/data/worker-tiny.cfg),
 * `impasto process` honours the cost knobs that `impasto bench accuracy` now passes as
 * flags (--cell and --gray-only show in copy.json; --threads, --no-shadow-test,
 * --btf-iterations, --btf-robust-passes are accepted, their effect is not visible on a
 * set this small; bad values exit 2 before any work),
 * and impasto-worker records in the job file which build processed the job, the one this
 * test was compiled in. */
#include <stdarg.h>
#include <stdio.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "build-kind.h"
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define WORKER IMPASTO_BINARY_DIR "/cli/impasto-worker"

static json_t *load(const char *path) {
        struct imp_error err = {};
        json_t *j = NULL;
        if (imp_json_load(path, &j, &err) < 0)
                fprintf(stderr, "%s\n", err.msg);
        return j;
}

/* copy.json stages.STAGE.KEY as a number (-1 when absent). */
static double stage_num(const json_t *copy, const char *stage, const char *key) {
        json_t *v = json_object_get(json_object_get(json_object_get(copy, "stages"), stage), key);
        return json_is_number(v) ? json_number_value(v) : -1;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0 || stat(WORKER, &st) < 0)
                TEST_SKIP("%s or %s not built", IMPASTO, WORKER);
        char tmp[] = "/tmp/impasto-test-flags.XXXXXX";
        CHECK(mkdtemp(tmp) != NULL);
        char path[1024];
        CHECK_INT_EQ(test_sh("%s sim render --scene %s/tests/data/worker-tiny.cfg --plan %s/tests/data/worker-tiny-plan.cfg "
                        "--out %s/capture --quiet --threads 2", IMPASTO, IMPASTO_SOURCE_DIR, IMPASTO_SOURCE_DIR, tmp), 0);

        /* Bad values are usage errors, before the set is opened. */
        const char *bad[] = { "--threads -1", "--threads x", "--btf-iterations -1", "--btf-robust-passes -2",
                              "--btf-robust-passes 1001" };
        for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
                int rc = test_sh("%s process %s/no-such-set --out %s/bad --quiet %s 2>/dev/null", IMPASTO, tmp, tmp, bad[i]);
                CHECK_MSG(rc == 2, "%s: exit %d, expected 2 (usage)", bad[i], rc);
        }

        /* The defaults, then every cost knob at once. */
        CHECK_INT_EQ(test_sh("%s process %s/capture --out %s/default --quiet", IMPASTO, tmp, tmp), 0);
        CHECK_INT_EQ(test_sh("%s process %s/capture --out %s/knobs --quiet --threads 1 --gray-only --btf-iterations 3 "
                        "--btf-robust-passes 0 --no-shadow-test --cell 10", IMPASTO, tmp, tmp), 0);
        snprintf(path, sizeof path, "%s/default/copy.json", tmp);
        _cleanup_json_ json_t *def = load(path);
        snprintf(path, sizeof path, "%s/knobs/copy.json", tmp);
        _cleanup_json_ json_t *knobs = load(path);
        CHECK(def && knobs);
        if (def && knobs) {
                CHECK_NEAR(stage_num(def, "boxes", "cell_px"), 20, 0);
                CHECK_NEAR(stage_num(knobs, "boxes", "cell_px"), 10, 0);
                /* --gray-only: the phase frames' stacks are not merged (13 → 9 on this set) */
                fprintf(stderr, "HDR stacks: %.0f by default, %.0f with --gray-only\n", stage_num(def, "hdr", "stacks"),
                        stage_num(knobs, "hdr", "stacks"));
                CHECK_GE(stage_num(knobs, "hdr", "stacks"), 1);
                CHECK_LE(stage_num(knobs, "hdr", "stacks"), stage_num(def, "hdr", "stacks") - 1);
        }

        /* The worker names its build in the job file. */
        snprintf(path, sizeof path, "%s/jobs", tmp);
        CHECK_OK(mkdir(path, 0755));
        snprintf(path, sizeof path, "%s/jobs/j1.json", tmp);
        FILE *f = fopen(path, "w");
        CHECK(f != NULL);
        if (f) {
                fprintf(f, "{\"id\":\"j1\",\"capture\":\"../capture\",\"copy\":\"../copy-worker\",\"state\":\"queued\","
                           "\"worker_args\":\"--no-btf\"}\n");
                fclose(f);
        }
        CHECK_INT_EQ(test_sh("%s %s", WORKER, path), 0);
        _cleanup_json_ json_t *job = load(path);
        CHECK(job != NULL);
        if (job) {
                CHECK_STR_EQ(json_string_value(json_object_get(job, "state")), "done");
                CHECK_STR_EQ(json_string_value(json_object_get(job, "worker_build")), imp_build_kind());
        }
        fprintf(stderr, "this build: %s\n", imp_build_kind());

        test_sh("rm -rf %s", tmp);
        return TEST_DONE();
}
