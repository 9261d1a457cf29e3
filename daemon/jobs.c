/* The durable job queue (docs/jobs.md): a completed session becomes STATE/jobs/<id>.json in
 * the one format impasto-worker reads. By default the daemon runs `WORKER JOBFILE` as a
 * child, one job at a time; with --no-spawn-workers impasto-worker@ services claim the jobs.
 * Either way the worker owns the file while it holds the claim (stage, progress, final state,
 * error); the daemon re-reads it (inotify, the child's exit, a slow timer), announces changes
 * as `job` events, accounts for attempts no worker accounted for (a worker that could not
 * start, or died) and retries a bounded number of times. */
#include <dirent.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <string.h>
#include <sys/file.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "sched-slurm.h"

#define JOB_RETRY_DELAY_US 500000ULL    /* before attempt n+1 after a failed one: n × this */
#define JOB_POLL_US 2000000ULL          /* re-read of claims held by workers we did not start */
#define JOB_LOG_ECHO_MAX 16384          /* the tail of an attempt's output echoed to our log */

struct job *jobs_find(struct daemon *d, const char *id) {
        for (struct job *j = d->jobs; j; j = j->next)
                if (!strcmp(j->id, id))
                        return j;
        return NULL;
}

static json_t *job_error_json(const struct job *j) {
        if (!j->error[0] || j->state == IMP_JOB_DONE)
                return NULL;
        return json_pack("{s:s, s:i, s:s}", "code", "internal", "errno", 0, "message", j->error);
}

/* The copy's quality verdict (copy.json "quality": {"verdict": "ok"|"degraded"|"unusable"}),
 * read once the job is done; "" when the copy has none (or a value not one of these). */
static void job_read_verdict(struct job *j) {
        j->verdict[0] = 0;
        if (j->state != IMP_JOB_DONE || !j->output[0])
                return;
        char p[PATH_MAX + 16];
        snprintf(p, sizeof p, "%s/copy.json", j->output);
        struct imp_error e = { 0 };
        _cleanup_json_ json_t *doc = NULL;
        if (imp_json_load(p, &doc, &e) < 0)
                return;
        const char *v = json_string_value(json_object_get(json_object_get(doc, "quality"), "verdict"));
        if (v && (!strcmp(v, "ok") || !strcmp(v, "degraded") || !strcmp(v, "unusable")))
                snprintf(j->verdict, sizeof j->verdict, "%s", v);
        else if (v)
                log_warning("%s: quality.verdict \"%.32s\" is not ok, degraded or unusable, ignoring", p, v);
}

/* STATE/jobs/<id>.log: what our worker children printed, attempt after attempt. */
static void job_log_path(const struct job *j, char *buf, size_t size) {
        snprintf(buf, size, "%.3000s/jobs/%s.log", j->d->state_dir, j->id);
}

/* The attempt under way for a running job whose worker has not counted it yet (the spawn's),
 * else the attempts counted: what "attempt N of M" shows. */
static int job_attempt_now(const struct job *j) {
        return j->attempts + (j->state == IMP_JOB_RUNNING && j->pid > 0 && j->attempts == j->spawn_attempts);
}

json_t *job_json(const struct job *j, bool full) {
        const char *stage = j->stage[0] ? j->stage : NULL, *verdict = j->verdict[0] ? j->verdict : NULL;
        if (!full)
                return json_pack("{s:s, s:s, s:s, s:s, s:f, s:s?, s:i, s:s*}", "job", j->id, "session", j->session,
                                 "state", imp_job_state_name(j->state), "queued", j->queued, "progress", j->progress,
                                 "stage", stage, "attempts", j->attempts, "verdict", verdict);
        char logp[PATH_MAX + 200];
        struct stat st;
        job_log_path(j, logp, sizeof logp);
        const char *log = lstat(logp, &st) == 0 && S_ISREG(st.st_mode) ? logp : NULL;
        return json_pack("{s:s, s:s, s:s, s:s, s:s?, s:s?, s:s?, s:o?, s:i, s:i, s:i, s:s, s:f, s:s?, s:O?, s:s*, s:s*}",
                         "job", j->id, "session", j->session, "state", imp_job_state_name(j->state), "queued",
                         j->queued, "started", j->started[0] ? j->started : NULL, "ended", j->ended[0] ? j->ended : NULL,
                         "output", j->state == IMP_JOB_DONE ? j->output : NULL, "error", job_error_json(j),
                         "attempts", j->attempts, "attempt", job_attempt_now(j), "max_attempts", j->max_attempts, "set", j->set_dir, "progress",
                         j->progress, "stage", stage, "worker_args", j->worker_args, "verdict", verdict, "log", log);
}

/* ---- the file ----------------------------------------------------------------------------- */


static void job_path(const struct job *j, enum imp_job_file which, char *buf, size_t size) {
        char dir[PATH_MAX];
        snprintf(dir, sizeof dir, "%s/jobs", j->d->state_dir);
        (void) imp_job_path(dir, j->id, which, buf, size);
}

/* The members the daemon owns, in the worker's format (docs/jobs.md). */
static json_t *job_file_json(const struct job *j) {
        return json_pack("{s:s, s:s, s:s, s:s, s:i, s:i, s:s?, s:s, s:s, s:s?, s:s?, s:f, s:s?, s:O?}", "id", j->id,
                         "capture", j->set_dir, "copy", j->output, "state", imp_job_state_name(j->state), "attempts",
                         j->attempts, "max_attempts", j->max_attempts, "error", j->error[0] ? j->error : NULL,
                         "session", j->session, "queued", j->queued, "started", j->started[0] ? j->started : NULL,
                         "ended", j->ended[0] ? j->ended : NULL, "progress", j->progress, "stage",
                         j->stage[0] ? j->stage : NULL, "worker_args", j->worker_args);
}

/* Writes j into `which`, keeping members the daemon does not know (a worker's). */
static int job_write(struct job *j, enum imp_job_file which) {
        char p[PATH_MAX + 200];
        job_path(j, which, p, sizeof p);
        struct imp_error e = { 0 };
        _cleanup_json_ json_t *doc = NULL;
        if (imp_json_load(p, &doc, &e) < 0 || !json_is_object(doc)) {
                json_decref(doc);
                doc = json_object();
        }
        _cleanup_json_ json_t *mine = job_file_json(j);
        int r = doc && mine && json_object_update(doc, mine) == 0 ? imp_json_save_atomic(p, doc, &e) : -ENOMEM;
        if (r < 0)
                log_error_errno(r, "job %s: saving %s: %s", j->id, p, e.msg[0] ? e.msg : "out of memory");
        return r;
}

/* The strings a job shows, valid UTF-8 whatever a file or a worker's output held and wherever
 * a buffer cut them: job_json and job_file_json (json_pack) fail on anything else, and the
 * job would vanish from `jobs` and never be saved again. */
static void job_sanitize(struct job *j) {
        char *const s[] = { j->set_dir, j->output, j->session, j->queued, j->started, j->ended, j->stage, j->error };
        for (size_t i = 0; i < ARRAY_SIZE(s); i++)
                (void) imp_utf8_sanitize(s[i]);
}

/* The counters a hand-edited or damaged file may hold out of range: read as they are, -5
 * attempts or a max_attempts of 2^31 would retry a failing job without end, and a value past
 * an int would be cut to another number. (--job-attempts takes at most the worker's 100; a
 * file of an older daemon may hold up to 10000, read back here and refused by the worker.) */
static int job_check_counts(const json_t *doc, const char *p, struct imp_error *e) {
        static const struct {
                const char *key;
                long long min, max;
        } k[] = { { "attempts", 0, INT_MAX }, { "max_attempts", 1, DAEMON_ATTEMPTS_MAX } };
        for (size_t i = 0; i < ARRAY_SIZE(k); i++) {
                const json_t *v = json_object_get(doc, k[i].key);
                if (v && !json_is_null(v) &&
                    (!json_is_integer(v) || json_integer_value(v) < k[i].min || json_integer_value(v) > k[i].max))
                        return imp_error_set(e, -EBADMSG, "%s: %s: expected an integer from %lld to %lld", p, k[i].key,
                                             k[i].min, k[i].max);
        }
        const json_t *task = json_object_get(json_object_get(doc, "slurm"), "task");
        if (task && (!json_is_integer(task) || json_integer_value(task) < 0 ||
                     json_integer_value(task) >= IMP_BATCH_MAX_TASKS))
                return imp_error_set(e, -EBADMSG, "%s: slurm.task: expected an integer from 0 to %d", p,
                                     IMP_BATCH_MAX_TASKS - 1);
        return 0;
}

/* Reads the job's file (the queue name, else the claim) into j. *ret_which says which one;
 * *ret_legacy is set for a file in the daemon's old format (job/set/output), which the
 * caller rewrites. -ENOENT when neither exists, -EBADMSG when it is not a job. */
static int job_read(struct job *j, enum imp_job_file *ret_which, bool *ret_legacy) {
        char p[PATH_MAX + 200];
        _cleanup_(imp_job_done) struct imp_job f = { 0 };
        struct imp_error e = { 0 };
        enum imp_job_file which = IMP_JOB_FILE_QUEUE;
        int r = -ENOENT;
        /* The worker renames queue → claim → queue: try the claim in between. */
        for (int k = 0; k < 3 && r == -ENOENT; k++) {
                which = k == 1 ? IMP_JOB_FILE_CLAIM : IMP_JOB_FILE_QUEUE;
                job_path(j, which, p, sizeof p);
                r = imp_job_read(p, IMP_JOB_LENIENT, &f, &e);
        }
        if (r == 0)
                r = job_check_counts(f.doc, p, &e);
        if (r == -EBADMSG)
                log_warning("%s, ignoring", e.msg);
        if (r < 0)
                return r;
        bool legacy = f.legacy;
        snprintf(j->set_dir, sizeof j->set_dir, "%s", f.capture);
        if (legacy)
                snprintf(j->output, sizeof j->output, "%s/outputs/%s", j->d->state_dir, j->id);
        else if (f.copy[0])
                snprintf(j->output, sizeof j->output, "%s", f.copy);
        if (f.session[0])
                snprintf(j->session, sizeof j->session, "%s", f.session);
        if (f.queued[0])
                snprintf(j->queued, sizeof j->queued, "%s", f.queued);
        snprintf(j->started, sizeof j->started, "%s", f.started);
        snprintf(j->ended, sizeof j->ended, "%s", f.ended);
        snprintf(j->stage, sizeof j->stage, "%s", f.stage);
        snprintf(j->error, sizeof j->error, "%s", f.error);
        j->attempts = f.attempts;
        if (f.max_attempts >= 1)
                j->max_attempts = f.max_attempts;
        else if (j->max_attempts < 1)
                j->max_attempts = (int) j->d->job_attempts;
        j->progress = f.progress;
        json_decref(j->worker_args);
        j->worker_args = json_incref(f.worker_args);
        sched_slurm_read(j, f.doc);
        job_sanitize(j);
        j->state = f.state;
        /* A claim is running whatever its file says yet; a running job under the queue name
         * was left by the old daemon (it ran the worker itself): queued again. */
        if (which == IMP_JOB_FILE_CLAIM)
                j->state = IMP_JOB_RUNNING;
        else if (j->state == IMP_JOB_RUNNING && !j->slurm_batch[0]) {   /* (Slurm's are the daemon's) */
                j->state = IMP_JOB_QUEUED;
                legacy = true;
        }
        if (j->state != IMP_JOB_DONE)
                j->verdict[0] = 0;
        else if (!j->verdict[0])
                job_read_verdict(j);
        *ret_which = which;
        if (ret_legacy)
                *ret_legacy = legacy;
        return 0;
}

/* The claim lock of docs/jobs.md (pipeline/model/job.h). -EBUSY when a worker holds it. */
static int job_lock(const struct job *j, int *ret_fd) {
        char p[PATH_MAX + 200];
        job_path(j, IMP_JOB_FILE_LOCK, p, sizeof p);
        return imp_job_lock(p, ret_fd);
}

static void job_unlock(const struct job *j, int fd) {
        char p[PATH_MAX + 200];
        job_path(j, IMP_JOB_FILE_LOCK, p, sizeof p);
        imp_job_unlock(p, fd);
}

static void job_set_failed_attempt(struct job *j, const char *why) {
        snprintf(j->error, sizeof j->error, "%.1000s", why);
        (void) imp_utf8_sanitize(j->error);    /* a worker's output, cut anywhere */
        j->state = j->attempts >= j->max_attempts ? IMP_JOB_FAILED : IMP_JOB_QUEUED;
        rfc3339_now(j->ended);
}

/* An attempt that ended without the worker writing its outcome: a worker that could not
 * start or refused the file (the queue file untouched), counted here. */
static void job_account(struct job *j, const char *why) {
        int fd;
        if (job_lock(j, &fd) < 0)
                return;         /* a worker is claiming it: its outcome will be read */
        j->attempts++;
        job_set_failed_attempt(j, why);
        (void) job_write(j, IMP_JOB_FILE_QUEUE);
        job_unlock(j, fd);
}

/* A claim whose worker died (its lock free): back to the queue name, queued again with its
 * attempt counted, or failed when the attempts are used up. 1 when recovered, 0 when a worker
 * holds it, negative errno. */
static int job_recover(struct job *j, const char *why) {
        int fd, r = job_lock(j, &fd);
        if (r < 0)
                return r == -EBUSY ? 0 : r;
        char claim[PATH_MAX + 200], queue[PATH_MAX + 200];
        job_path(j, IMP_JOB_FILE_CLAIM, claim, sizeof claim);
        job_path(j, IMP_JOB_FILE_QUEUE, queue, sizeof queue);
        if (access(claim, F_OK) < 0) {
                job_unlock(j, fd);
                return 0;       /* released meanwhile */
        }
        job_set_failed_attempt(j, why);
        r = job_write(j, IMP_JOB_FILE_CLAIM);
        if (r >= 0 && rename(claim, queue) < 0)
                r = negative_errno();
        if (r >= 0)
                (void) imp_fsync_parent_dir(queue);
        job_unlock(j, fd);
        if (r < 0)
                return log_error_errno(r, "job %s: recovering %s: %m", j->id, claim);
        log_notice("job %s: %s; %s", j->id, why, imp_job_state_name(j->state));
        return 1;
}

/* ---- events and scheduling ---------------------------------------------------------------- */

static void job_announce(struct daemon *d, struct job *j) {
        if (j->ev_sent && j->ev_state == j->state && j->ev_attempts == j->attempts &&
            fabs(j->ev_progress - j->progress) < 1e-6 && !strcmp(j->ev_stage, j->stage))
                return;
        /* The claim counts the attempt our spawn already announced: one line per state. */
        if (!j->ev_sent || j->ev_state != j->state || (j->state != IMP_JOB_RUNNING && j->ev_attempts != j->attempts)) {
                if (j->state == IMP_JOB_DONE)
                        log_info("job %s: done, output %s", j->id, j->output);
                else if (j->state == IMP_JOB_FAILED || (j->state == IMP_JOB_QUEUED && j->error[0] && j->attempts > 0))
                        log_warning("job %s: %s after attempt %d of %d: %s", j->id, imp_job_state_name(j->state),
                                    j->attempts, j->max_attempts, j->error);
                else
                        log_info("job %s: %s (attempt %d of %d)", j->id, imp_job_state_name(j->state),
                                 job_attempt_now(j), j->max_attempts);
        }
        j->ev_sent = true;
        j->ev_state = j->state;
        j->ev_attempts = j->attempts;
        j->ev_progress = j->progress;
        snprintf(j->ev_stage, sizeof j->ev_stage, "%s", j->stage);
        server_broadcast(d, "job",
                         json_pack("{s:s, s:s, s:s, s:f, s:s?, s:i, s:i, s:i, s:s?, s:o?, s:s*}", "job", j->id,
                                   "session", j->session, "state", imp_job_state_name(j->state), "progress",
                                   j->progress, "stage", j->stage[0] ? j->stage : NULL, "attempts", j->attempts,
                                   "attempt", job_attempt_now(j), "max_attempts", j->max_attempts, "output", j->state == IMP_JOB_DONE ? j->output : NULL,
                                   "error", j->state == IMP_JOB_QUEUED || j->state == IMP_JOB_RUNNING ? NULL
                                   : job_error_json(j), "verdict", j->verdict[0] ? j->verdict : NULL));
}

void jobs_save_announce(struct daemon *d, struct job *j) {
        job_sanitize(j);        /* (Slurm's task errors come from the task's file) */
        (void) job_write(j, IMP_JOB_FILE_QUEUE);
        job_announce(d, j);
}

static int kick_timer(sd_event_source *src, uint64_t usec, void *userdata) {
        jobs_kick(userdata);
        return 0;
}

static void schedule_kick(struct daemon *d, uint64_t delay_us) {
        if (!d->spawn_workers || d->stopping)
                return;
        sd_event_source_disable_unref(d->job_timer);
        d->job_timer = NULL;
        (void) sd_event_add_time_relative(d->event, &d->job_timer, CLOCK_MONOTONIC, delay_us, 0, kick_timer, d);
}

static bool kick_pending(struct daemon *d) {
        int enabled = SD_EVENT_OFF;
        return d->job_timer && sd_event_source_get_enabled(d->job_timer, &enabled) >= 0 && enabled != SD_EVENT_OFF;
}

/* Re-reads the file of a job we are not running as a child and announces what changed. */
static void job_refresh(struct daemon *d, struct job *j) {
        enum imp_job_state before = j->state;
        enum imp_job_file which;
        int pid = j->pid;
        if (job_read(j, &which, NULL) < 0)
                return;
        if (pid > 0 && (which == IMP_JOB_FILE_CLAIM || j->attempts != j->spawn_attempts))
                j->claim_seen = true;
        if (pid > 0 && !j->claim_seen && j->state == IMP_JOB_QUEUED)
                j->state = IMP_JOB_RUNNING;         /* our child has not claimed it yet */
        if (pid == 0 && which == IMP_JOB_FILE_CLAIM) {
                char why[128];
                snprintf(why, sizeof why, "the worker stopped during attempt %d", j->attempts);
                (void) job_recover(j, why);
        }
        job_announce(d, j);
        if (pid == 0 && before == IMP_JOB_RUNNING && j->state != IMP_JOB_RUNNING && !kick_pending(d))
                schedule_kick(d, 0);
}

/* ---- spawn mode ------------------------------------------------------------------------- */

static int job_exited(sd_event_source *src, const siginfo_t *si, void *userdata);

/* Our environment with OMP_WAIT_POLICY=passive added, NULL when it is set (or without
 * memory): the children are pipeline runs (workers, calibration) on a machine they share,
 * where libgomp's default of spinning at every join before sleeping burnt most of a stage's
 * CPU time (docs/processing-speed.md). libgomp reads it when it loads, so it must come from
 * the parent; the array is built here because the child may only exec. */
extern char **environ;
static char **child_environ(void) {
        if (getenv("OMP_WAIT_POLICY"))
                return NULL;
        size_t n = 0;
        while (environ[n])
                n++;
        char **e = malloc((n + 2) * sizeof *e);
        if (!e)
                return NULL;
        memcpy(e, environ, n * sizeof *e);
        e[n] = (char *) "OMP_WAIT_POLICY=passive";
        e[n + 1] = NULL;
        return e;
}

int daemon_spawn(struct daemon *d, const char *const *argv, int fd_out, int fd_err, sd_event_child_handler_t cb,
                 void *userdata, pid_t *ret_pid, sd_event_source **ret_source) {
        _cleanup_free_ char **env = child_environ();
        pid_t pid = fork();
        if (pid < 0)
                return negative_errno();
        if (pid == 0) {
                sigset_t all;
                sigemptyset(&all);
                sigprocmask(SIG_SETMASK, &all, NULL);
                if ((fd_out >= 0 && dup2(fd_out, STDOUT_FILENO) < 0) || (fd_err >= 0 && dup2(fd_err, STDERR_FILENO) < 0))
                        _exit(127);
                execve(argv[0], (char *const *) argv, env ? env : environ);
                dprintf(STDERR_FILENO, "exec %s: %s\n", argv[0], strerror(errno));
                _exit(127);
        }
        int r = sd_event_add_child(d->event, ret_source, pid, WEXITED, cb, userdata);
        if (r < 0) {
                kill(pid, SIGKILL);
                (void) waitpid(pid, NULL, 0);
                return r;
        }
        *ret_pid = pid;
        return 0;
}

static int job_spawn(struct daemon *d, struct job *j) {
        char file[PATH_MAX + 200], logp[PATH_MAX + 200];
        job_path(j, IMP_JOB_FILE_QUEUE, file, sizeof file);
        job_log_path(j, logp, sizeof logp);
        const char *const argv[] = { d->worker_cmd, file, NULL };
        /* The worker's output goes to the job's log (echoed to ours when it exits), so that a
         * worker that dies without writing its error still leaves its last words with the job. */
        _cleanup_close_ int fd = open(logp, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC | O_NOFOLLOW, 0640);
        if (fd >= 0) {
                char now[32];
                rfc3339_now(now);
                dprintf(fd, "== %s: attempt %d, %s %s\n", now, j->attempts + 1, d->worker_cmd, file);
                j->log_start = lseek(fd, 0, SEEK_END);
        } else
                log_warning("job %s: %s: %s; the worker's output goes to ours", j->id, logp, strerror(errno));
        return daemon_spawn(d, argv, fd, fd, job_exited, j, &j->pid, &j->child_source);
}

/* Echoes what the attempt just ended printed (its last JOB_LOG_ECHO_MAX bytes) to our log and
 * leaves its last non-empty line in last[] ("" when it printed nothing). */
static void job_log_collect(const struct job *j, char *last, size_t size) {
        char logp[PATH_MAX + 200];
        last[0] = 0;
        job_log_path(j, logp, sizeof logp);
        _cleanup_close_ int fd = open(logp, O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
        struct stat st;
        if (fd < 0 || fstat(fd, &st) < 0 || st.st_size <= j->log_start)
                return;
        off_t from = IMP_MAX(j->log_start, st.st_size - JOB_LOG_ECHO_MAX);
        char *buf = malloc(JOB_LOG_ECHO_MAX + 1);
        ssize_t n = buf ? pread(fd, buf, (size_t) (st.st_size - from), from) : -1;
        if (n <= 0) {
                free(buf);
                return;
        }
        buf[n] = 0;
        for (char *line = buf, *nl; line && *line; line = nl) {
                if ((nl = strchr(line, '\n')))
                        *nl++ = 0;
                if (!line[strspn(line, " \t\r")])
                        continue;
                log_info("job %s: worker: %s", j->id, line);
                snprintf(last, size, "%s", line);
        }
        free(buf);
}

/* The daemon's account of an attempt that ended badly, with the worker's last words. */
static void job_why(const struct job *j, const char *what, const char *last, char *buf, size_t size) {
        char logp[PATH_MAX + 200];
        job_log_path(j, logp, sizeof logp);
        if (last[0])
                snprintf(buf, size, "%.400s; its last output: \"%.240s\" (all of it in %.300s)", what, last, logp);
        else
                snprintf(buf, size, "%.400s; it printed nothing", what);
}

void jobs_kick(struct daemon *d) {
        if (d->stopping || !d->spawn_workers)
                return;
        if (sched_slurm_active(d))
                { sched_slurm_kick(d); return; }
        struct job *next = NULL;
        for (struct job *j = d->jobs; j; j = j->next) {
                if (j->state == IMP_JOB_RUNNING || j->pid > 0)
                        return;
                if (j->state == IMP_JOB_QUEUED)
                        next = j;       /* the list is newest first: the last one is the oldest */
        }
        if (!next)
                return;
        next->spawn_attempts = next->attempts;
        next->claim_seen = false;
        int r = job_spawn(d, next);
        if (r < 0) {
                char why[PATH_MAX + 64];
                snprintf(why, sizeof why, "starting %s: %s", d->worker_cmd, strerror(-r));
                job_account(next, why);
                job_announce(d, next);
                if (next->state == IMP_JOB_QUEUED)
                        schedule_kick(d, JOB_RETRY_DELAY_US * (uint64_t) next->attempts);
                else
                        schedule_kick(d, 0);
                return;
        }
        next->state = IMP_JOB_RUNNING;
        job_announce(d, next);
}

static int job_exited(sd_event_source *src, const siginfo_t *si, void *userdata) {
        struct job *j = userdata;
        struct daemon *d = j->d;
        j->child_source = sd_event_source_disable_unref(j->child_source);
        j->pid = 0;
        char how[64];
        snprintf(how, sizeof how, "%s %d", si->si_code == CLD_EXITED ? "exit status" : "killed by signal",
                 si->si_status);
        char last[512], what[PATH_MAX + 256], why[sizeof j->error];
        job_log_collect(j, last, sizeof last);
        enum imp_job_file which;
        int r = job_read(j, &which, NULL);
        if (r < 0) {
                snprintf(what, sizeof what, "the job file is gone or unreadable after %.200s exited (%s)",
                         d->worker_cmd, how);
                job_why(j, what, last, j->error, sizeof j->error);
                j->state = IMP_JOB_FAILED;
        } else if (which == IMP_JOB_FILE_CLAIM) {
                snprintf(what, sizeof what, "%.200s stopped during attempt %d (%s)", d->worker_cmd, j->attempts, how);
                job_why(j, what, last, why, sizeof why);
                if (job_recover(j, why) <= 0)
                        j->state = IMP_JOB_RUNNING; /* another worker holds the claim */
        } else if (j->state == IMP_JOB_QUEUED && j->attempts == j->spawn_attempts && !j->claim_seen) {
                /* (once the claim was seen, a queued file is the worker's retry or an
                 * operator's jobs.retry that came before the child's exit) */
                snprintf(what, sizeof what, "%.200s %.300s/jobs/%s.json: %s without processing the job "
                         "(attempt %d of %d)", d->worker_cmd, d->state_dir, j->id, how, j->attempts + 1,
                         j->max_attempts);
                job_why(j, what, last, why, sizeof why);
                job_account(j, why);
        }
        job_announce(d, j);
        if (j->state == IMP_JOB_QUEUED)
                schedule_kick(d, JOB_RETRY_DELAY_US * (uint64_t) IMP_MAX(j->attempts, 1));
        else
                jobs_kick(d);
        return 0;
}

/* ---- the queue ------------------------------------------------------------------------------- */

static struct job *job_new(struct daemon *d, const char *id) {
        struct job *j = calloc(1, sizeof *j);
        if (!j)
                return NULL;
        j->d = d;
        j->max_attempts = (int) d->job_attempts;
        snprintf(j->id, sizeof j->id, "%s", id);
        return j;
}

static void job_free(struct job *j) {
        if (!j)
                return;
        sd_event_source_disable_unref(j->child_source);
        json_decref(j->worker_args);
        free(j);
}

static json_t *worker_args_json(const struct daemon *d) {
        return d->worker_args && d->worker_args[0] ? json_string(d->worker_args) : NULL;
}

int jobs_enqueue(struct daemon *d, const struct session *s) {
        if (calibrations_own_session(d, s->id))
                return 0;       /* its set is calibrated (calibration.c), not processed */
        char out[PATH_MAX];
        snprintf(out, sizeof out, "%.2000s/outputs/%s", d->state_dir, s->id);
        return jobs_enqueue_set(d, s->id, s->id, s->dir, out);
}

int jobs_enqueue_set(struct daemon *d, const char *session, const char *id, const char *set_dir, const char *output) {
        if (jobs_find(d, id))
                return -EEXIST;
        struct job *j = job_new(d, id);
        if (!j)
                return -ENOMEM;
        snprintf(j->session, sizeof j->session, "%s", session);
        snprintf(j->set_dir, sizeof j->set_dir, "%s", set_dir);
        snprintf(j->output, sizeof j->output, "%s", output);
        rfc3339_now(j->queued);
        j->worker_args = worker_args_json(d);
        j->state = IMP_JOB_QUEUED;
        j->next = d->jobs;
        d->jobs = j;
        int r = job_write(j, IMP_JOB_FILE_QUEUE);
        job_announce(d, j);
        jobs_kick(d);
        return r < 0 ? r : 0;
}

int jobs_retry(struct daemon *d, struct job *j, struct imp_proto_error *perr) {
        if (j->state != IMP_JOB_FAILED)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EINVAL, "args.job", "job %s is %s, not failed",
                                           j->id, imp_job_state_name(j->state));
        if (sched_slurm_active(d))
                return sched_slurm_retry(d, j, perr);
        /* No lock: workers claim only queued files, and the worker that failed this one may
         * still hold its lock for a moment after writing the outcome. */
        /* The error of the last attempt is kept until the job is done; the arguments are the
         * daemon's current --worker-args, so that a retry after a configuration fix uses it. */
        j->state = IMP_JOB_QUEUED;
        j->attempts = 0;
        j->ended[0] = 0;
        j->progress = 0;
        j->stage[0] = 0;
        json_decref(j->worker_args);
        j->worker_args = worker_args_json(d);
        int r = job_write(j, IMP_JOB_FILE_QUEUE);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, "args.job", "job %s: writing its file: %s", j->id,
                                           strerror(-r));
        job_announce(d, j);
        /* Started from the loop, after the reply that says "queued". */
        schedule_kick(d, 0);
        return 0;
}

/* One job from its file(s); a claim nobody holds is recovered, the old format rewritten. */
static struct job *job_load(struct daemon *d, const char *id) {
        struct job *j = job_new(d, id);
        if (!j)
                return NULL;
        enum imp_job_file which;
        bool legacy = false;
        if (job_read(j, &which, &legacy) < 0) {
                job_free(j);
                return NULL;
        }
        if (which == IMP_JOB_FILE_CLAIM) {
                char why[128];
                snprintf(why, sizeof why, "the worker stopped during attempt %d", j->attempts);
                (void) job_recover(j, why);
        } else if (legacy)
                (void) job_write(j, IMP_JOB_FILE_QUEUE);
        return j;
}

/* "<id>.json" or "<id>.json.running" → id; false for anything else (locks, .tmp). */
static bool job_id_of(const char *name, char id[static IMP_JOB_ID_MAX + 1]) {
        size_t l = strlen(name);
        size_t n = l > 13 && !strcmp(name + l - 13, ".json.running") ? l - 13 :
                   l > 5 && !strcmp(name + l - 5, ".json") ? l - 5 : 0;
        if (n == 0 || n > IMP_JOB_ID_MAX || name[0] == '.')
                return false;
        memcpy(id, name, n);
        id[n] = 0;
        return true;
}

static int cmp_names(const void *a, const void *b) {
        return strcmp(*(char *const *) a, *(char *const *) b);
}

int jobs_load(struct daemon *d) {
        char dirp[PATH_MAX];
        snprintf(dirp, sizeof dirp, "%s/jobs", d->state_dir);
        DIR *dir = opendir(dirp);
        if (!dir)
                return negative_errno();
        char **names = NULL;
        size_t n = 0;
        struct dirent *de;
        char id[IMP_JOB_ID_MAX + 1];
        while ((de = readdir(dir))) {
                if (!job_id_of(de->d_name, id))
                        continue;
                char **nn = realloc(names, (n + 1) * sizeof *names);
                if (!nn)
                        break;
                names = nn;
                if ((names[n] = strdup(id)))
                        n++;
        }
        closedir(dir);
        if (n)
                qsort(names, n, sizeof *names, cmp_names);
        for (size_t i = 0; i < n; i++) {
                struct job *j = i > 0 && !strcmp(names[i], names[i - 1]) ? NULL : job_load(d, names[i]);
                if (!j)
                        continue;
                j->next = d->jobs;      /* ids start with the time: the list ends newest first */
                d->jobs = j;
        }
        for (size_t i = 0; i < n; i++)
                free(names[i]);
        free(names);
        return 0;
}

/* ---- watching the queue ---------------------------------------------------------------------- */

static int on_jobs_dir(sd_event_source *src, const struct inotify_event *ev, void *userdata) {
        struct daemon *d = userdata;
        if (ev->mask & IN_Q_OVERFLOW) {
                for (struct job *j = d->jobs; j; j = j->next)
                        if (j->state == IMP_JOB_QUEUED || j->state == IMP_JOB_RUNNING)
                                job_refresh(d, j);
                return 0;
        }
        char id[IMP_JOB_ID_MAX + 1];
        if (ev->len == 0 || !job_id_of(ev->name, id))
                return 0;
        struct job *j = jobs_find(d, id);
        if (j) {
                job_refresh(d, j);
                return 0;
        }
        /* A job queued by someone else (an operator, another tool): ours to watch and run. */
        if (!(ev->mask & (IN_MOVED_TO | IN_CLOSE_WRITE)) || !(j = job_load(d, id)))
                return 0;
        j->next = d->jobs;
        d->jobs = j;
        job_announce(d, j);
        if (!kick_pending(d))
                schedule_kick(d, 0);
        return 0;
}

/* A worker we did not start may die holding a claim: no file changes then, only its lock
 * goes; re-read such jobs from time to time. */
static int on_poll(sd_event_source *src, uint64_t usec, void *userdata) {
        struct daemon *d = userdata;
        for (struct job *j = d->jobs; j; j = j->next)
                if (j->pid == 0 && (j->state == IMP_JOB_RUNNING || (!d->spawn_workers && j->state == IMP_JOB_QUEUED)))
                        job_refresh(d, j);
        (void) sd_event_source_set_time_relative(src, JOB_POLL_US);
        (void) sd_event_source_set_enabled(src, SD_EVENT_ONESHOT);
        return 0;
}

int jobs_watch(struct daemon *d) {
        char dirp[PATH_MAX];
        snprintf(dirp, sizeof dirp, "%s/jobs", d->state_dir);
        int r = sd_event_add_inotify(d->event, &d->job_watch, dirp,
                                     IN_MOVED_TO | IN_CLOSE_WRITE | IN_MOVED_FROM | IN_DELETE | IN_ONLYDIR,
                                     on_jobs_dir, d);
        if (r < 0)
                log_warning_errno(r, "watching %s: %m; job progress is read every %llu s, ignoring", dirp,
                                  JOB_POLL_US / 1000000ULL);
        int k = sd_event_add_time_relative(d->event, &d->job_poll, CLOCK_MONOTONIC, JOB_POLL_US, 0, on_poll, d);
        int s = sched_slurm_watch(d);
        return r < 0 ? r : k < 0 ? k : s;
}

void jobs_free_all(struct daemon *d) {
        d->job_timer = sd_event_source_disable_unref(d->job_timer);
        d->job_watch = sd_event_source_disable_unref(d->job_watch);
        d->job_poll = sd_event_source_disable_unref(d->job_poll);
        sched_slurm_free(d);
        while (d->jobs) {
                struct job *j = d->jobs;
                d->jobs = j->next;
                /* A running worker is left to finish: it holds the claim, and the next daemon
                 * finds the job running (or recovers the claim if the worker died). */
                job_free(j);
        }
}
