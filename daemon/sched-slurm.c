/* impastod's Slurm scheduler (docs/scale-out.md): with `scheduler = "slurm"` (impastod.conf's
 * impastod.scheduler, or the file of --scheduler-config), queued jobs are not run here but submitted together as one batch
 * (pipeline/model/slurm.h: a job array of impasto-worker --batch tasks and the finish step
 * after them). Each job's file records its batch and task ("slurm": {"batch", "task"}); a
 * timer reads the batches' state back (their files, squeue, sacct) into the jobs, which are
 * then shown and announced like local ones. A failed task is resubmitted while the job has
 * attempts left; an operator's retry resubmits it once more. The Slurm commands run
 * synchronously on the loop (well under a second each on a healthy controller). */
#include <string.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "sched-slurm.h"

#define SLURM_POLL_US 10000000ULL       /* squeue at most every 10 s */

bool sched_slurm_active(const struct daemon *d) {
        return d->slurm && d->slurm->enabled;
}

static struct imp_slurm_config slurm_config;

static void configured(const struct imp_slurm_config *c) {
        if (c->enabled)
                log_info("scheduler slurm: batches in %s/batches, partition %s, account %s, %d CPUs and %s per task",
                         c->shared_dir, c->partition[0] ? c->partition : "(default)",
                         c->account[0] ? c->account : "(default)", c->cpus_per_task, c->mem[0] ? c->mem : "(default) memory");
}

/* impastod.conf: impastod.scheduler = "slurm" takes its settings from the top-level
 * slurm = { … } group of the same file (the group a --scheduler-config file holds, read by
 * the same reader); --scheduler-config, read after it, overrides both. */
int sched_slurm_configure_conf(struct daemon *d, const char *path, bool slurm) {
        struct imp_slurm_config *c = &slurm_config;
        imp_slurm_config_default(c, "");    /* "": --worker-cmd, whatever its place on the command line */
        struct imp_error err = {};
        int r = imp_slurm_config_load(path, c, &err);
        if (r < 0)
                return log_error("config: %s", err.msg), r;
        c->enabled = slurm;
        if (slurm && !c->shared_dir[0])
                return log_error("config: %s: slurm.shared_dir: required with impastod.scheduler = \"slurm\" (a "
                                 "top-level slurm = { shared_dir = \"DIR\"; … } group next to impastod = { … }, DIR "
                                 "mounted at the same path on every node; or --scheduler-config FILE)", path),
                       -EINVAL;
        d->slurm = c;
        configured(c);
        return 0;
}

int sched_slurm_configure(struct daemon *d, const char *path) {
        struct imp_slurm_config *c = &slurm_config;
        imp_slurm_config_default(c, "");    /* "": --worker-cmd, whatever its place on the command line */
        struct imp_error err = {};
        int r = imp_slurm_config_load(path, c, &err);
        if (r < 0)
                return log_error("--scheduler-config: %s", err.msg), r;
        d->slurm = c;
        configured(c);
        return 0;
}

void sched_slurm_read(struct job *j, const json_t *doc) {
        const json_t *s = json_object_get(doc, "slurm");
        const char *batch = json_string_value(json_object_get(s, "batch"));
        snprintf(j->slurm_batch, sizeof j->slurm_batch, "%s", batch ? batch : "");
        j->slurm_task = (int) json_integer_value(json_object_get(s, "task"));
}

/* Adds "slurm": {"batch", "task"} to the job's file (job_write keeps members it does not own). */
static void record(struct job *j) {
        char p[PATH_MAX + 200], dir[PATH_MAX + 8];
        snprintf(dir, sizeof dir, "%s/jobs", j->d->state_dir);
        (void) imp_job_path(dir, j->id, IMP_JOB_FILE_QUEUE, p, sizeof p);
        struct imp_error e = {};
        _cleanup_json_ json_t *doc = NULL;
        if (imp_json_load(p, &doc, &e) < 0 ||
            json_object_set_new(doc, "slurm", json_pack("{s:s, s:i}", "batch", j->slurm_batch, "task", j->slurm_task)) < 0 ||
            imp_json_save_atomic(p, doc, &e) < 0)
                log_error("job %s: recording its Slurm batch in %s: %s", j->id, p, e.msg[0] ? e.msg : "out of memory");
}

static void dirname_of(const char *p, char *out, size_t size) {
        const char *slash = strrchr(p, '/');
        snprintf(out, size, "%.*s", slash ? (int) (slash - p) : 1, slash ? p : ".");
}

/* Every queued job without a batch, submitted as one batch. */
void sched_slurm_kick(struct daemon *d) {
        size_t n = 0;
        for (struct job *j = d->jobs; j; j = j->next)
                n += j->state == IMP_JOB_QUEUED && !j->slurm_batch[0];
        if (n == 0)
                return;
        if (!d->slurm->worker[0])
                snprintf(d->slurm->worker, sizeof d->slurm->worker, "%s", d->worker_cmd);
        struct job **js = calloc(n, sizeof *js);
        const char **captures = calloc(n, sizeof *captures);
        if (!js || !captures) {
                free(js), free(captures);
                return;
        }
        size_t k = 0;
        for (struct job *j = d->jobs; j; j = j->next)
                if (j->state == IMP_JOB_QUEUED && !j->slurm_batch[0]) {
                        js[n - 1 - k] = j;       /* the list is newest first: oldest first in the array */
                        k++;
                }
        for (size_t i = 0; i < n; i++)
                captures[i] = js[i]->set_dir;
        char id[IMP_JOB_ID_MAX + 1], copies[PATH_MAX];
        snprintf(id, sizeof id, "%.100s-%zu", js[0]->id, n);
        dirname_of(js[0]->output, copies, sizeof copies);
        const char *args = json_string_value(js[0]->worker_args);
        struct imp_batch b = {};
        struct imp_error err = {};
        int r = imp_slurm_batch_create(d->slurm, id, captures, n, copies, args, &b, &err);
        if (r == 0)
                r = imp_slurm_submit(d->slurm, &b, NULL, 0, &err);
        for (size_t i = 0; i < n; i++) {
                struct job *j = js[i];
                if (r < 0) {
                        j->attempts++;
                        snprintf(j->error, sizeof j->error, "submitting to Slurm: %.900s", err.msg);
                        j->state = j->attempts >= j->max_attempts ? IMP_JOB_FAILED : IMP_JOB_QUEUED;
                        jobs_save_announce(d, j);
                        continue;
                }
                snprintf(j->slurm_batch, sizeof j->slurm_batch, "%s", b.dir);
                j->slurm_task = (int) i;
                j->attempts++;
                rfc3339_now(j->started);
                jobs_save_announce(d, j);
                record(j);
        }
        if (r < 0)
                log_error("Slurm: %s", err.msg);
        else
                log_info("Slurm: %zu jobs submitted as batch %s", n, b.dir);
        imp_batch_done(&b);
        free(js);
        free(captures);
}

/* One job from its task's state; a failed task with attempts left is resubmitted. */
static void apply(struct daemon *d, struct job *j, struct imp_batch *b, const struct imp_slurm_task *t) {
        enum imp_job_state s = !strcmp(t->state, "done") ? IMP_JOB_DONE : !strcmp(t->state, "running") ? IMP_JOB_RUNNING
                               : !strcmp(t->state, "queued") ? IMP_JOB_QUEUED : IMP_JOB_FAILED;
        if (s == IMP_JOB_FAILED && j->attempts < j->max_attempts) {
                size_t task = (size_t) j->slurm_task;
                struct imp_error err = {};
                log_warning("job %s: Slurm task %s failed (%s); resubmitting, attempt %d of %d", j->id, t->job, t->error,
                            j->attempts + 1, j->max_attempts);
                if (imp_slurm_submit(d->slurm, b, &task, 1, &err) == 0) {
                        j->attempts++;
                        s = IMP_JOB_QUEUED;
                } else
                        log_error("job %s: resubmitting: %s", j->id, err.msg);
        }
        if (s == j->state && (s != IMP_JOB_FAILED || !strcmp(j->error, t->error)))
                return;
        j->state = s;
        j->progress = s == IMP_JOB_DONE ? 1.0 : j->progress;
        if (s == IMP_JOB_DONE)
                j->error[0] = 0;
        else if (t->error[0])
                snprintf(j->error, sizeof j->error, "Slurm task %s: %.900s", t->job, t->error);
        if (s == IMP_JOB_DONE || s == IMP_JOB_FAILED)
                rfc3339_now(j->ended);
        jobs_save_announce(d, j);
}

static void refresh(struct daemon *d) {
        for (struct job *j = d->jobs; j; j = j->next) {
                if (!j->slurm_batch[0] || j->state == IMP_JOB_DONE || j->state == IMP_JOB_FAILED)
                        continue;
                struct imp_batch b;
                struct imp_slurm_status s;
                struct imp_error err = {};
                if (imp_batch_load(j->slurm_batch, &b, &err) < 0) {
                        log_warning("job %s: %s, ignoring", j->id, err.msg);
                        continue;
                }
                if (imp_slurm_status(&b, &s, &err) == 0) {
                        /* every job of this batch from one squeue */
                        for (struct job *o = d->jobs; o; o = o->next)
                                if (!strcmp(o->slurm_batch, b.dir) && o->slurm_task >= 0 &&
                                    (size_t) o->slurm_task < s.n_tasks && o->state != IMP_JOB_DONE &&
                                    o->state != IMP_JOB_FAILED)
                                        apply(d, o, &b, &s.tasks[o->slurm_task]);
                        imp_slurm_status_done(&s);
                }
                imp_batch_done(&b);
        }
}

static int on_timer(sd_event_source *src, uint64_t usec, void *userdata) {
        struct daemon *d = userdata;
        refresh(d);
        sched_slurm_kick(d);
        (void) sd_event_source_set_time_relative(src, SLURM_POLL_US);
        (void) sd_event_source_set_enabled(src, SD_EVENT_ONESHOT);
        return 0;
}

int sched_slurm_watch(struct daemon *d) {
        if (!sched_slurm_active(d))
                return 0;
        return sd_event_add_time_relative(d->event, &d->slurm_poll, CLOCK_MONOTONIC, SLURM_POLL_US / 5, 0, on_timer, d);
}

int sched_slurm_retry(struct daemon *d, struct job *j, struct imp_proto_error *perr) {
        if (!j->slurm_batch[0]) {
                j->state = IMP_JOB_QUEUED;      /* never submitted: the next kick takes it */
                j->attempts = 0;
                jobs_save_announce(d, j);
                sched_slurm_kick(d);
                return 0;
        }
        struct imp_batch b;
        struct imp_error err = {};
        size_t task = (size_t) j->slurm_task;
        int r = imp_batch_load(j->slurm_batch, &b, &err);
        if (r == 0)
                r = imp_slurm_submit(d->slurm, &b, &task, 1, &err);
        imp_batch_done(&b);
        if (r < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, "args.job", "job %s: resubmitting to Slurm: %s",
                                           j->id, err.msg);
        j->state = IMP_JOB_QUEUED;
        j->attempts = 1;
        j->ended[0] = 0;
        j->progress = 0;
        jobs_save_announce(d, j);
        return 0;
}

void sched_slurm_free(struct daemon *d) {
        d->slurm_poll = sd_event_source_disable_unref(d->slurm_poll);
}
