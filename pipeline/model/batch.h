/* A batch of processing tasks for a cluster engine (docs/scale-out.md): one directory on
 * storage every node mounts, holding batch.json (the tasks: a capture set and the copy to
 * write, the worker options, the engine's job ids), tasks/<i>.json (each task's last known
 * state, written by impasto-worker) and logs/. Shared by `impasto jobs submit --slurm`,
 * impastod's Slurm scheduler and impasto-worker --batch. Library code: nothing here logs.
 *
 * batch.json: {"format":1, "id":TOKEN, "created":RFC3339, "worker_args":STRING|null,
 *   "tasks":[{"capture":PATH, "copy":PATH}, …], "engine":"slurm",
 *   "submissions":[{"array":JOBID, "finish":JOBID, "tasks":[INDEX, …], "at":RFC3339}, …],
 *   "cancelled":BOOL}
 * Relative paths are relative to the batch directory. */
#pragma once
#include <limits.h>
#include <stdbool.h>
#include <stddef.h>
#include <jansson.h>
#include "error.h"

#define IMP_BATCH_MAX_TASKS 100000

struct imp_batch_task {
        char capture[PATH_MAX], copy[PATH_MAX];   /* resolved against the batch directory */
};

struct imp_batch {
        json_t *doc;                    /* the whole batch.json: unknown members are kept */
        char dir[PATH_MAX];
        char id[129];
        size_t n_tasks;
        struct imp_batch_task *tasks;
        const char *worker_args;        /* borrowed from doc; NULL when none */
};

/* Reads DIR/batch.json. -EINVAL with err naming the member when it is malformed. */
int imp_batch_load(const char *dir, struct imp_batch *b, struct imp_error *err);
int imp_batch_save(const struct imp_batch *b, struct imp_error *err);
void imp_batch_done(struct imp_batch *b);

/* DIR/tasks/<i>.json, DIR/logs. -ENAMETOOLONG when it does not fit. */
int imp_batch_task_file(const struct imp_batch *b, size_t i, char *buf, size_t size);

/* A task's state as the batch knows it from its files alone: "done" when the copy's
 * result manifest says so, else the state in tasks/<i>.json ("running", "failed"), else
 * "queued". *error gets the task file's error ("" when none). */
const char *imp_batch_task_state(const struct imp_batch *b, size_t i, char *error, size_t error_size);

/* The result manifest of one finished copy: COPY/result.json (docs/scale-out.md). */
#define IMP_RESULT_FILE "result.json"
/* true when COPY/result.json says "done" (and, when fingerprint is not NULL, for these
 * inputs). */
bool imp_result_done(const char *copy, const char *fingerprint);
/* What a copy was made from: FNV-1a 64 of the capture set's manifest.jsonl and the worker
 * options, "fnv1a64:<16 hex>". A rerun with the same fingerprint is a no-op. */
int imp_result_fingerprint(const char *capture, const char *worker_args, char out[static 32],
                           struct imp_error *err);
