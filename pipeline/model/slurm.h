/* The Slurm engine for processing batches (docs/scale-out.md), shared by
 * `impasto jobs submit --slurm` and impastod's scheduler = "slurm": a batch (batch.h) is
 * submitted as one job array running `impasto-worker --batch DIR --task $SLURM_ARRAY_TASK_ID`
 * (`sbatch --parsable --array=LIST%K`), plus the step after it (`--dependency=afterok:ID`,
 * `impasto-worker --batch DIR --finish`). State comes back from the batch's files, squeue
 * and, where the cluster keeps accounting, sacct; cancel is scancel; retry resubmits the
 * tasks that are neither done nor queued nor running, with a new finish step.
 * Runs the Slurm commands synchronously (each takes well under a second on a healthy
 * controller). Library code: nothing here logs. */
#pragma once
#include <limits.h>
#include <stdbool.h>
#include <stddef.h>
#include "batch.h"
#include "error.h"

struct imp_slurm_config {
        bool enabled;                   /* scheduler = "slurm" */
        char partition[64];             /* "" : the cluster's default */
        char account[64];               /* "" : the user's default */
        int cpus_per_task;              /* default 2 */
        char mem[32];                   /* --mem per task, default "1G" ("" : the cluster's default) */
        char time[32];                  /* --time per task, "" : the partition's default */
        int max_running;                /* %K of --array, 0: no limit */
        char shared_dir[PATH_MAX];      /* batches in SHARED/batches, copies in SHARED/copies */
        char worker[PATH_MAX];          /* impasto-worker as the nodes see it */
};

/* Defaults; worker_default is the impasto-worker path to use when the file names none. */
void imp_slurm_config_default(struct imp_slurm_config *c, const char *worker_default);
/* Reads `scheduler = "local"|"slurm";` and the `slurm = { … }` group of a libconfig file
 * (the fields above; docs/scale-out.md). A missing file is -ENOENT; unknown fields and bad
 * values are -EINVAL naming FILE:LINE and the field. */
int imp_slurm_config_load(const char *path, struct imp_slurm_config *c, struct imp_error *err);

/* Creates SHARED/batches/<id>/ with batch.json (one task per capture set, copies in
 * copies_dir/<basename of the set>, copies_dir "" : SHARED/copies/<id>), the two job
 * scripts and logs/. -EEXIST when two sets share a basename. */
int imp_slurm_batch_create(const struct imp_slurm_config *c, const char *id, const char *const *captures,
                           size_t n, const char *copies_dir, const char *worker_args, struct imp_batch *b,
                           struct imp_error *err);
/* Submits tasks (NULL: all) as an array and its finish step; the submission is recorded in
 * batch.json. */
int imp_slurm_submit(const struct imp_slurm_config *c, struct imp_batch *b, const size_t *tasks, size_t n,
                     struct imp_error *err);

struct imp_slurm_task {
        char state[16];                 /* queued, running, done, failed (docs/jobs.md states) */
        char slurm_state[32];           /* as squeue/sacct said ("" when Slurm no longer knows) */
        char job[48];                   /* ARRAYID_INDEX of its last submission */
        char error[512];
};
struct imp_slurm_status {
        size_t n_tasks;
        struct imp_slurm_task *tasks;
        struct imp_slurm_task finish;   /* the step after the tasks */
        bool cancelled;
};
int imp_slurm_status(const struct imp_batch *b, struct imp_slurm_status *s, struct imp_error *err);
void imp_slurm_status_done(struct imp_slurm_status *s);
/* scancel of every job of the batch still queued or running. */
int imp_slurm_cancel(struct imp_batch *b, struct imp_error *err);
/* Resubmits the failed tasks (and a new finish step, the old one cancelled). *ret_n: how
 * many; 0 when none had failed. */
int imp_slurm_retry(const struct imp_slurm_config *c, struct imp_batch *b, size_t *ret_n, struct imp_error *err);
