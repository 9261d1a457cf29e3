/* The job file of the processing queue (docs/jobs.md), shared by impastod (which writes new
 * jobs and follows them) and impasto-worker (which claims and runs them): its members, the
 * state names, the file names of one job (<id>.json, <id>.json.running, <id>.lock), the claim
 * lock and the RFC 3339 time stamps. Library code: nothing here logs. */
#pragma once
#include <limits.h>
#include <stdbool.h>
#include <stddef.h>
#include <jansson.h>
#include "error.h"

#define IMP_JOB_ID_MAX 128
#define IMP_JOB_DEFAULT_MAX_ATTEMPTS 3
#define IMP_JOB_MAX_ATTEMPTS_LIMIT 100

enum imp_job_state { IMP_JOB_QUEUED, IMP_JOB_RUNNING, IMP_JOB_DONE, IMP_JOB_FAILED, _IMP_JOB_STATE_MAX };
const char *imp_job_state_name(enum imp_job_state s);
/* -EINVAL for NULL or an unknown name. */
int imp_job_state_from_name(const char *s);

/* How strictly imp_job_parse() reads a file. */
enum imp_job_parse_mode {
        /* the worker's: every required member present and in range (docs/jobs.md) */
        IMP_JOB_STRICT,
        /* the daemon's: a state and a capture set suffice; impastod's old format ("set"
         * instead of "capture", no "copy", an error object) is accepted with `legacy` set */
        IMP_JOB_LENIENT,
};

/* One job file, read. Strings are "" when absent or null. */
struct imp_job {
        json_t *doc;                            /* the whole file: unknown members are kept */
        char id[IMP_JOB_ID_MAX + 1];
        char capture[PATH_MAX], copy[PATH_MAX]; /* as written (may be relative to the queue) */
        char session[128];
        enum imp_job_state state;
        int attempts, max_attempts;             /* max_attempts 0 when absent (lenient mode) */
        char queued[32], started[32], ended[32];
        char error[1024];
        char stage[64];
        double progress;                        /* clamped to 0..1 */
        json_t *worker_args;                    /* borrowed from doc: a string, or NULL */
        bool legacy;
};
/* Takes doc (a reference); `path` names the file in messages. On failure doc is released and
 * *j cleared; -EINVAL (strict) or -EBADMSG (lenient) with err naming the member. */
int imp_job_parse(json_t *doc, const char *path, enum imp_job_parse_mode mode, struct imp_job *j,
                  struct imp_error *err);
/* imp_json_load + imp_job_parse. */
int imp_job_read(const char *path, enum imp_job_parse_mode mode, struct imp_job *j, struct imp_error *err);
void imp_job_done(struct imp_job *j);

/* The files of job `id` in queue directory `dir`. -ENAMETOOLONG when one does not fit. */
enum imp_job_file { IMP_JOB_FILE_QUEUE, IMP_JOB_FILE_CLAIM, IMP_JOB_FILE_LOCK };
int imp_job_path(const char *dir, const char *id, enum imp_job_file which, char *buf, size_t size);
/* true for 1 to IMP_JOB_ID_MAX bytes of [A-Za-z0-9._-] not starting with '.'. */
bool imp_job_id_valid(const char *id);

/* The claim lock: flock(LOCK_EX|LOCK_NB) on the lock file, checked not to have been unlinked
 * by a holder finishing meanwhile (then the new file is taken). -EBUSY when another process
 * holds it. imp_job_unlock() unlinks the file and closes fd. */
int imp_job_lock(const char *lock_path, int *ret_fd);
void imp_job_unlock(const char *lock_path, int fd);

/* UTC now as "YYYY-MM-DDTHH:MM:SSZ". */
void imp_rfc3339_now(char buf[static 32]);
