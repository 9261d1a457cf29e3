/* `impasto jobs … --slurm` (cmd-jobs-slurm.c), reached from cmd-jobs.c. */
#pragma once
#include <stdbool.h>

/* true when the words ask for the Slurm batches (`submit`, or --slurm). */
bool imp_jobs_slurm_wanted(int argc, char **argv);
int imp_jobs_slurm_run(int argc, char **argv);
