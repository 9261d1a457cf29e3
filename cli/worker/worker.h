/* impasto-worker's modes, shared between its files: the queue (worker.c) and the one-job
 * modes an engine schedules (oneshot.c: --capture, --batch). */
#pragma once
#include <stddef.h>
#include "error.h"
#include "process.h"

#define WORKER_EXIT_DONE 0
#define WORKER_EXIT_JOB_FAILED 1
#define WORKER_EXIT_USAGE 2
#define WORKER_EXIT_BAD_JOB 3
#define WORKER_EXIT_QUEUE 4

/* worker_args (docs/jobs.md) into o; -EINVAL with msg naming the option. */
int worker_parse_args(const char *args, struct imp_process_options *o, char *msg, size_t size);

/* impasto-worker --capture SET --copy DIR [--args ARGS]: one job, idempotent. */
int worker_run_capture(const char *capture, const char *copy, const char *args);
/* impasto-worker --batch DIR --task N: task N of DIR/batch.json. */
int worker_run_batch_task(const char *dir, long task);
/* impasto-worker --batch DIR --finish: the step after every task (finish.c): checks every
 * copy, runs `impasto mosaic` when the batch's captures are the tiles of a painting, writes
 * DIR/result.json. */
int worker_run_batch_finish(const char *dir);

/* oneshot.c, for finish.c: rm -rf PATH (0 when it is gone); DIR.partial → DIR, fsynced and
 * swapped atomically when DIR exists (negative errno with err set). */
int worker_remove_tree(const char *path);
int worker_publish(const char *partial, const char *dir, struct imp_error *err);
