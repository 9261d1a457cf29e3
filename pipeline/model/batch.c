/* The batch directory of a cluster engine and the copy's result manifest (batch.h). */
#include <errno.h>
#include <fcntl.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "batch.h"
#include "job.h"
#include "json-util.h"

static int resolve(const char *dir, const char *p, char *out, size_t size) {
        int n = p[0] == '/' ? snprintf(out, size, "%s", p) : snprintf(out, size, "%s/%s", dir, p);
        return n < 0 || (size_t) n >= size ? -ENAMETOOLONG : 0;
}

static int parse_task(const struct imp_batch *b, const char *path, size_t i, const json_t *t,
                      struct imp_batch_task *out, struct imp_error *err) {
        const char *capture = json_string_value(json_object_get(t, "capture"));
        const char *copy = json_string_value(json_object_get(t, "copy"));
        if (!json_is_object(t) || !capture || !capture[0] || !copy || !copy[0])
                return imp_error_set(err, -EINVAL, "%s: tasks[%zu]: expected an object with strings \"capture\" "
                                     "and \"copy\"", path, i);
        if (resolve(b->dir, capture, out->capture, sizeof out->capture) < 0 ||
            resolve(b->dir, copy, out->copy, sizeof out->copy) < 0)
                return imp_error_set(err, -ENAMETOOLONG, "%s: tasks[%zu]: path too long", path, i);
        return 0;
}

int imp_batch_load(const char *dir, struct imp_batch *b, struct imp_error *err) {
        *b = (struct imp_batch) {};
        char path[PATH_MAX + 32];
        snprintf(b->dir, sizeof b->dir, "%s", dir);
        snprintf(path, sizeof path, "%s/batch.json", dir);
        int r = imp_json_load(path, &b->doc, err);
        if (r < 0)
                return r;
        const char *id = json_string_value(json_object_get(b->doc, "id"));
        const json_t *tasks = json_object_get(b->doc, "tasks");
        const json_t *args = json_object_get(b->doc, "worker_args");
        if (!json_is_object(b->doc) || !id || !imp_job_id_valid(id))
                r = imp_error_set(err, -EINVAL, "%s: id: expected a token of 1-128 [A-Za-z0-9._-]", path);
        else if (!json_is_array(tasks) || json_array_size(tasks) == 0 || json_array_size(tasks) > IMP_BATCH_MAX_TASKS)
                r = imp_error_set(err, -EINVAL, "%s: tasks: expected an array of 1 to %d tasks", path,
                                  IMP_BATCH_MAX_TASKS);
        else if (args && !json_is_string(args) && !json_is_null(args))
                r = imp_error_set(err, -EINVAL, "%s: worker_args: expected a string or null, got %s", path,
                                  imp_json_type_name(args));
        if (r < 0) {
                imp_batch_done(b);
                return r;
        }
        snprintf(b->id, sizeof b->id, "%s", id);
        b->worker_args = json_string_value(args);
        b->n_tasks = json_array_size(tasks);
        b->tasks = calloc(b->n_tasks, sizeof *b->tasks);
        if (!b->tasks) {
                imp_batch_done(b);
                return imp_error_set(err, -ENOMEM, "out of memory");
        }
        for (size_t i = 0; i < b->n_tasks; i++)
                if ((r = parse_task(b, path, i, json_array_get(tasks, i), &b->tasks[i], err)) < 0) {
                        imp_batch_done(b);
                        return r;
                }
        return 0;
}

int imp_batch_save(const struct imp_batch *b, struct imp_error *err) {
        char path[PATH_MAX + 32];
        snprintf(path, sizeof path, "%s/batch.json", b->dir);
        return imp_json_save_atomic(path, b->doc, err);
}

void imp_batch_done(struct imp_batch *b) {
        json_decref(b->doc);
        free(b->tasks);
        *b = (struct imp_batch) {};
}

int imp_batch_task_file(const struct imp_batch *b, size_t i, char *buf, size_t size) {
        int n = snprintf(buf, size, "%s/tasks/%zu.json", b->dir, i);
        return n < 0 || (size_t) n >= size ? -ENAMETOOLONG : 0;
}

bool imp_result_done(const char *copy, const char *fingerprint) {
        char path[PATH_MAX + 32];
        snprintf(path, sizeof path, "%s/" IMP_RESULT_FILE, copy);
        json_t *doc = NULL;
        struct imp_error e = {};
        if (imp_json_load(path, &doc, &e) < 0)
                return false;
        const char *state = json_string_value(json_object_get(doc, "state"));
        const char *fp = json_string_value(json_object_get(doc, "fingerprint"));
        bool done = state && !strcmp(state, "done") && (!fingerprint || (fp && !strcmp(fp, fingerprint)));
        json_decref(doc);
        return done;
}

const char *imp_batch_task_state(const struct imp_batch *b, size_t i, char *error, size_t error_size) {
        error[0] = 0;
        if (imp_result_done(b->tasks[i].copy, NULL))
                return "done";
        char path[PATH_MAX + 32];
        json_t *doc = NULL;
        struct imp_error e = {};
        if (imp_batch_task_file(b, i, path, sizeof path) < 0 || imp_json_load(path, &doc, &e) < 0)
                return "queued";
        const char *state = json_string_value(json_object_get(doc, "state"));
        const char *msg = json_string_value(json_object_get(doc, "error"));
        const char *ret = state && !strcmp(state, "running") ? "running" : state && !strcmp(state, "failed") ? "failed"
                          : "queued";
        if (msg)
                snprintf(error, error_size, "%s", msg);
        json_decref(doc);
        return ret;
}

static void fnv1a(uint64_t *h, const void *data, size_t n) {
        const unsigned char *p = data;
        for (size_t i = 0; i < n; i++) {
                *h ^= p[i];
                *h *= 0x100000001b3ULL;
        }
}

int imp_result_fingerprint(const char *capture, const char *worker_args, char out[static 32],
                           struct imp_error *err) {
        char path[PATH_MAX + 32];
        snprintf(path, sizeof path, "%s/manifest.jsonl", capture);
        int fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0)
                return imp_error_set(err, negative_errno(), "%s: cannot open: %m", path);
        uint64_t h = 0xcbf29ce484222325ULL;
        char buf[65536];
        ssize_t k;
        while ((k = read(fd, buf, sizeof buf)) > 0)
                fnv1a(&h, buf, (size_t) k);
        int r = k < 0 ? negative_errno() : 0;
        close(fd);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot read: %s", path, strerror(-r));
        fnv1a(&h, "", 1);
        if (worker_args)
                fnv1a(&h, worker_args, strlen(worker_args));
        snprintf(out, 32, "fnv1a64:%016llx", (unsigned long long) h);
        return 0;
}
