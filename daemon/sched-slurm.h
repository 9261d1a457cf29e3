/* impastod's Slurm scheduler (sched-slurm.c, docs/scale-out.md): jobs.c hands queued jobs to
 * it instead of spawning impasto-worker when `scheduler = "slurm"` is configured. */
#pragma once
#include <stdbool.h>
#include <jansson.h>
#include "slurm.h"

struct daemon;
struct job;
struct imp_proto_error;

/* --scheduler-config FILE (pipeline/model/slurm.h's format). */
int sched_slurm_configure(struct daemon *d, const char *path);
/* impastod.conf's top-level slurm group, enabled when slurm (impastod.scheduler = "slurm"). */
int sched_slurm_configure_conf(struct daemon *d, const char *path, bool slurm);
bool sched_slurm_active(const struct daemon *d);
/* The job file's "slurm" member into j (jobs.c's reader). */
void sched_slurm_read(struct job *j, const json_t *doc);
/* Submits the queued jobs that have no batch yet, as one batch. */
void sched_slurm_kick(struct daemon *d);
/* Starts the timer that reads the batches' state back. */
int sched_slurm_watch(struct daemon *d);
int sched_slurm_retry(struct daemon *d, struct job *j, struct imp_proto_error *perr);
void sched_slurm_free(struct daemon *d);
