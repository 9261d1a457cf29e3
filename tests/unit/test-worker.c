/* impasto-worker on a queue directory: a tiny rendered capture set (tests/data/worker-tiny.cfg)
 * queued as a job comes out as a digital copy with the job done; a job naming a missing
 * capture set ends failed at once with its error kept; a transient failure is retried up to
 * max_attempts; a claim left by a dead worker is recovered; malformed and finished job
 * files are left alone. */
#include <stdio.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define WORKER IMPASTO_BINARY_DIR "/cli/impasto-worker"

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static bool exists(const char *dir, const char *name) {
        char p[1024];
        struct stat st;
        snprintf(p, sizeof p, "%s/%s", dir, name);
        return stat(p, &st) == 0;
}

static void write_job(const char *jobs, const char *file, const char *text) {
        char p[1024];
        snprintf(p, sizeof p, "%s/%s", jobs, file);
        FILE *f = fopen(p, "w");
        if (!f) {
                perror(p);
                exit(2);
        }
        fputs(text, f);
        fclose(f);
}

static json_t *read_job(const char *jobs, const char *id) {
        char p[1024];
        snprintf(p, sizeof p, "%s/%s.json", jobs, id);
        struct imp_error err = {};
        json_t *j = NULL;
        if (imp_json_load(p, &j, &err) < 0)
                fprintf(stderr, "%s\n", err.msg);
        return j;
}

static const char *str(const json_t *j, const char *key) {
        return json_string_value(json_object_get(j, key));
}

static long long num(const json_t *j, const char *key) {
        return json_integer_value(json_object_get(j, key));
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0 || stat(WORKER, &st) < 0)
                TEST_SKIP("%s or %s not built", IMPASTO, WORKER);
        const char *tmp = test_tmpdir();
        char jobs[512], copy[512], cmd[2048];
        snprintf(jobs, sizeof jobs, "%s/jobs", tmp);
        snprintf(copy, sizeof copy, "%s/copy", tmp);
        CHECK_OK(imp_mkdir_p(jobs, 0755));
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s/tests/data/worker-tiny.cfg --plan %s/tests/data/worker-tiny-plan.cfg "
                 "--out %s/capture --quiet --threads 2", IMPASTO, IMPASTO_SOURCE_DIR, IMPASTO_SOURCE_DIR, tmp);
        CHECK_INT_EQ(run(cmd), 0);

        /* nothing queued */
        snprintf(cmd, sizeof cmd, "%s --queue %s --once", WORKER, jobs);
        CHECK_INT_EQ(run(cmd), 0);

        /* the good job; paths relative to the queue directory */
        write_job(jobs, "good.json", "{\"id\":\"good\",\"capture\":\"../capture\",\"copy\":\"../copy\","
                  "\"state\":\"queued\",\"attempts\":0,\"max_attempts\":3,\"error\":null,\"session\":\"s1\"}\n");
        CHECK_INT_EQ(run(cmd), 0);
        json_t *j = read_job(jobs, "good");
        CHECK_STR_EQ(str(j, "state"), "done");
        CHECK_INT_EQ(num(j, "attempts"), 1);
        CHECK(json_is_null(json_object_get(j, "error")));
        CHECK_STR_EQ(str(j, "session"), "s1");                 /* unknown members are kept */
        json_decref(j);
        CHECK(exists(copy, "heightfield.exr"));
        CHECK(exists(copy, "copy.json"));
        CHECK(!exists(jobs, "good.json.running"));
        CHECK(!exists(jobs, "good.lock"));
        CHECK_INT_EQ(run(cmd), 0);                             /* done jobs are not run again */

        /* a job as impastod writes it (daemon/jobs.c): absolute paths, its own members, and
         * worker_args; progress and stage come back in the file */
        char text[4096];
        snprintf(text, sizeof text, "{\"id\":\"20250301-101500-s2\",\"capture\":\"%s/capture\",\"copy\":\"%s/copy-d\","
                 "\"state\":\"queued\",\"attempts\":0,\"max_attempts\":3,\"error\":null,\"session\":\"20250301-101500-s2\","
                 "\"queued\":\"2025-03-01T10:15:00Z\",\"started\":null,\"ended\":null,\"progress\":0.0,\"stage\":null,"
                 "\"worker_args\":\"--holdout 2 --cell=10\"}\n", tmp, tmp);
        write_job(jobs, "20250301-101500-s2.json", text);
        CHECK_INT_EQ(run(cmd), 0);
        j = read_job(jobs, "20250301-101500-s2");
        CHECK_STR_EQ(str(j, "state"), "done");
        CHECK_NEAR(json_number_value(json_object_get(j, "progress")), 1.0, 1e-9);
        CHECK_STR_EQ(str(j, "stage"), "boxes");                 /* the last stage it reported */
        CHECK(str(j, "started") && str(j, "ended"));
        CHECK_STR_EQ(str(j, "queued"), "2025-03-01T10:15:00Z");
        json_decref(j);
        char cj_path[1024];
        snprintf(cj_path, sizeof cj_path, "%s/copy-d/copy.json", tmp);
        json_t *cj = NULL;
        struct imp_error cerr = {};
        CHECK_MSG(imp_json_load(cj_path, &cj, &cerr) == 0, "%s", cerr.msg);
        json_t *stages = json_object_get(cj, "stages");
        CHECK_INT_EQ(json_integer_value(json_object_get(json_object_get(json_object_get(stages, "btf"), "validation"),
                                                         "lights")), 1);   /* --holdout 2 of lights [0, 2] */
        CHECK_INT_EQ(json_integer_value(json_object_get(json_object_get(stages, "boxes"), "cell_px")), 10);
        json_decref(cj);

        /* worker_args the worker does not know: the job fails at once, saying which */
        write_job(jobs, "badargs.json", "{\"id\":\"badargs\",\"capture\":\"../capture\",\"copy\":\"../copy5\","
                  "\"state\":\"queued\",\"attempts\":0,\"max_attempts\":3,\"error\":null,\"worker_args\":\"--holdout x\"}\n");
        CHECK_INT_EQ(run(cmd), 1);
        j = read_job(jobs, "badargs");
        CHECK_STR_EQ(str(j, "state"), "failed");
        CHECK_STR_CONTAINS(str(j, "error"), "--holdout");
        json_decref(j);

        /* a missing capture set: failed at the first attempt, the error kept */
        write_job(jobs, "missing.json", "{\"id\":\"missing\",\"capture\":\"no-such-set\",\"copy\":\"../copy2\","
                  "\"state\":\"queued\",\"attempts\":0,\"max_attempts\":3,\"error\":null}\n");
        CHECK_INT_EQ(run(cmd), 1);
        j = read_job(jobs, "missing");
        CHECK_STR_EQ(str(j, "state"), "failed");
        CHECK_INT_EQ(num(j, "attempts"), 1);
        CHECK_STR_CONTAINS(str(j, "error"), "no-such-set");
        json_decref(j);
        CHECK_INT_EQ(run(cmd), 0);

        /* a transient failure (the copy cannot be created): retried, bounded by max_attempts */
        write_job(jobs, "retry.json", "{\"id\":\"retry\",\"capture\":\"../capture\",\"copy\":\"/dev/null/copy\","
                  "\"state\":\"queued\",\"attempts\":0,\"max_attempts\":2,\"error\":null}\n");
        CHECK_INT_EQ(run(cmd), 1);
        j = read_job(jobs, "retry");
        CHECK_STR_EQ(str(j, "state"), "queued");
        CHECK_INT_EQ(num(j, "attempts"), 1);
        CHECK_STR_CONTAINS(str(j, "error"), "/dev/null/copy");
        json_decref(j);
        CHECK_INT_EQ(run(cmd), 1);
        j = read_job(jobs, "retry");
        CHECK_STR_EQ(str(j, "state"), "failed");
        CHECK_INT_EQ(num(j, "attempts"), 2);
        CHECK_STR_CONTAINS(str(j, "error"), "/dev/null/copy");
        json_decref(j);

        /* a claim whose worker died: queued again, its attempt counted, then processed */
        write_job(jobs, "stale.json.running", "{\"id\":\"stale\",\"capture\":\"../capture\",\"copy\":\"../copy3\","
                  "\"state\":\"running\",\"attempts\":1,\"max_attempts\":3,\"error\":null}\n");
        CHECK_INT_EQ(run(cmd), 0);
        j = read_job(jobs, "stale");
        CHECK_STR_EQ(str(j, "state"), "done");
        CHECK_INT_EQ(num(j, "attempts"), 2);
        json_decref(j);
        CHECK(!exists(jobs, "stale.json.running"));

        /* malformed files are left alone in queue mode and refused as JOB_FILE */
        write_job(jobs, "bad.json", "{\"id\":\"bad\",\"state\":\"queued\"}\n");
        CHECK_INT_EQ(run(cmd), 0);
        CHECK(exists(jobs, "bad.json"));
        snprintf(cmd, sizeof cmd, "%s %s/bad.json", WORKER, jobs);
        CHECK_INT_EQ(run(cmd), 3);
        snprintf(cmd, sizeof cmd, "%s %s/good.json", WORKER, jobs);   /* done: not queued */
        CHECK_INT_EQ(run(cmd), 3);
        snprintf(cmd, sizeof cmd, "%s --once", WORKER);
        CHECK_INT_EQ(run(cmd), 2);
        snprintf(cmd, sizeof cmd, "%s --queue %s/absent --once", WORKER, tmp);
        CHECK_INT_EQ(run(cmd), 4);

        /* JOB_FILE mode on a fresh job */
        write_job(jobs, "single.json", "{\"id\":\"single\",\"capture\":\"../capture\",\"copy\":\"../copy4\","
                  "\"state\":\"queued\",\"attempts\":0,\"max_attempts\":1,\"error\":null}\n");
        snprintf(cmd, sizeof cmd, "%s %s/single.json", WORKER, jobs);
        CHECK_INT_EQ(run(cmd), 0);
        j = read_job(jobs, "single");
        CHECK_STR_EQ(str(j, "state"), "done");
        json_decref(j);
        return TEST_DONE();
}
