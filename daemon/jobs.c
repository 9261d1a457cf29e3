/* The durable job queue: a completed session becomes jobs/<id>.json (queued → running →
 * done | failed, attempts, error), and the worker (`WORKER process SET --out COPY`) runs as
 * a child of the daemon, one job at a time, retried a bounded number of times. A job found
 * running after a restart is queued again: the worker writes its output from scratch. */
#include <dirent.h>
#include <signal.h>
#include <string.h>
#include <sys/wait.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"

#define JOB_RETRY_DELAY_US 500000ULL

static const char *const job_state_names[] = { "queued", "running", "done", "failed" };

const char *job_state_name(enum job_state s) {
        return job_state_names[s];
}

static int job_state_from_name(const char *s) {
        for (size_t i = 0; i < ARRAY_SIZE(job_state_names); i++)
                if (!strcmp(s, job_state_names[i]))
                        return (int) i;
        return -EINVAL;
}

struct job *jobs_find(struct daemon *d, const char *id) {
        for (struct job *j = d->jobs; j; j = j->next)
                if (!strcmp(j->id, id))
                        return j;
        return NULL;
}

json_t *job_json(const struct job *j, bool full) {
        double progress = j->state == JOB_DONE ? 1.0 : 0.0;
        if (!full)
                return json_pack("{s:s, s:s, s:s, s:s, s:f, s:i}", "job", j->id, "session", j->session, "state",
                                 job_state_name(j->state), "queued", j->queued, "progress", progress, "attempts",
                                 j->attempts);
        json_t *err = NULL;
        if (j->error[0])
                err = json_pack("{s:s, s:i, s:s}", "code", "internal", "errno", 0, "message", j->error);
        return json_pack("{s:s, s:s, s:s, s:s, s:s?, s:s?, s:s?, s:o?, s:i, s:s, s:f}", "job", j->id, "session",
                         j->session, "state", job_state_name(j->state), "queued", j->queued, "started",
                         j->started[0] ? j->started : NULL, "ended", j->ended[0] ? j->ended : NULL, "output",
                         j->state == JOB_DONE ? j->output : NULL, "error", err, "attempts", j->attempts, "set",
                         j->set_dir, "progress", progress);
}

static void job_save(struct daemon *d, struct job *j) {
        char p[PATH_MAX + 200];
        snprintf(p, sizeof p, "%s/jobs/%s.json", d->state_dir, j->id);
        _cleanup_json_ json_t *o = job_json(j, true);
        struct imp_error e = { 0 };
        int r = o ? imp_json_save_atomic(p, o, &e) : -ENOMEM;
        if (r < 0)
                log_error_errno(r, "job %s: saving %s: %s", j->id, p, e.msg);
}

static void job_event(struct daemon *d, struct job *j) {
        server_broadcast(d, "job", json_pack("{s:s, s:s, s:s, s:f, s:s?}", "job", j->id, "session", j->session,
                                             "state", job_state_name(j->state), "progress",
                                             j->state == JOB_DONE ? 1.0 : 0.0, "output",
                                             j->state == JOB_DONE ? j->output : NULL));
}

static int job_exited(sd_event_source *src, const siginfo_t *si, void *userdata);

static int job_spawn(struct daemon *d, struct job *j) {
        pid_t pid = fork();
        if (pid < 0)
                return negative_errno();
        if (pid == 0) {
                sigset_t all;
                sigemptyset(&all);
                sigprocmask(SIG_SETMASK, &all, NULL);
                execl(d->worker_cmd, d->worker_cmd, "process", j->set_dir, "--out", j->output, (char *) NULL);
                _exit(127);
        }
        j->pid = pid;
        int r = sd_event_add_child(d->event, &j->child_source, pid, WEXITED, job_exited, j);
        if (r < 0) {
                kill(pid, SIGKILL);
                (void) waitpid(pid, NULL, 0);
                j->pid = 0;
                return r;
        }
        return 0;
}

void jobs_kick(struct daemon *d) {
        if (d->stopping)
                return;
        struct job *next = NULL;
        for (struct job *j = d->jobs; j; j = j->next) {
                if (j->state == JOB_RUNNING)
                        return;
                if (j->state == JOB_QUEUED)
                        next = j;       /* the list is newest first: the last one is the oldest */
        }
        if (!next)
                return;
        next->state = JOB_RUNNING;
        next->attempts++;
        rfc3339_now(next->started);
        next->ended[0] = 0;
        int r = job_spawn(d, next);
        if (r < 0) {
                snprintf(next->error, sizeof next->error, "starting %s: %s", d->worker_cmd, strerror(-r));
                next->state = JOB_FAILED;
                rfc3339_now(next->ended);
        }
        job_save(d, next);
        job_event(d, next);
        log_info("job %s: %s (attempt %d)", next->id, job_state_name(next->state), next->attempts);
        if (next->state == JOB_FAILED)
                jobs_kick(d);
}

static int retry_timer(sd_event_source *src, uint64_t usec, void *userdata) {
        jobs_kick(userdata);
        return 0;
}

static int job_exited(sd_event_source *src, const siginfo_t *si, void *userdata) {
        struct job *j = userdata;
        struct daemon *d = j->d;
        j->child_source = sd_event_source_disable_unref(j->child_source);
        j->pid = 0;
        rfc3339_now(j->ended);
        if (si->si_code == CLD_EXITED && si->si_status == 0) {
                j->state = JOB_DONE;
                j->error[0] = 0;
        } else {
                snprintf(j->error, sizeof j->error, "%.200s process %.200s: %s %d (attempt %d of %u)", d->worker_cmd,
                         j->set_dir, si->si_code == CLD_EXITED ? "exit status" : "killed by signal",
                         si->si_status, j->attempts, d->job_attempts);
                j->state = (unsigned) j->attempts < d->job_attempts ? JOB_QUEUED : JOB_FAILED;
        }
        job_save(d, j);
        job_event(d, j);
        if (j->state == JOB_DONE)
                log_info("job %s: done, output %s", j->id, j->output);
        else
                log_warning("job %s: %s%s", j->id, j->error, j->state == JOB_QUEUED ? ", retrying" : "");
        if (j->state == JOB_QUEUED) {
                sd_event_source_disable_unref(d->job_timer);
                d->job_timer = NULL;
                (void) sd_event_add_time_relative(d->event, &d->job_timer, CLOCK_MONOTONIC,
                                                  JOB_RETRY_DELAY_US * (uint64_t) j->attempts, 0, retry_timer, d);
        } else
                jobs_kick(d);
        return 0;
}

static struct job *job_new(struct daemon *d, const char *id) {
        struct job *j = calloc(1, sizeof *j);
        if (!j)
                return NULL;
        j->d = d;
        snprintf(j->id, sizeof j->id, "%s", id);
        return j;
}

int jobs_enqueue(struct daemon *d, const struct session *s) {
        if (jobs_find(d, s->id))
                return -EEXIST;
        struct job *j = job_new(d, s->id);
        if (!j)
                return -ENOMEM;
        snprintf(j->session, sizeof j->session, "%s", s->id);
        snprintf(j->set_dir, sizeof j->set_dir, "%s", s->dir);
        snprintf(j->output, sizeof j->output, "%s/outputs/%s", d->state_dir, s->id);
        rfc3339_now(j->queued);
        j->state = JOB_QUEUED;
        j->next = d->jobs;
        d->jobs = j;
        job_save(d, j);
        job_event(d, j);
        jobs_kick(d);
        return 0;
}

int jobs_retry(struct daemon *d, struct job *j, struct imp_proto_error *perr) {
        if (j->state != JOB_FAILED)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_STATE, EINVAL, "args.job", "job %s is %s, not failed",
                                           j->id, job_state_name(j->state));
        j->state = JOB_QUEUED;
        j->attempts = 0;
        j->ended[0] = 0;
        job_save(d, j);
        job_event(d, j);
        /* Started from the loop, after the reply that says "queued". */
        sd_event_source_disable_unref(d->job_timer);
        d->job_timer = NULL;
        (void) sd_event_add_time_relative(d->event, &d->job_timer, CLOCK_MONOTONIC, 0, 0, retry_timer, d);
        return 0;
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
        while ((de = readdir(dir))) {
                size_t l = strlen(de->d_name);
                if (de->d_name[0] == '.' || l < 6 || strcmp(de->d_name + l - 5, ".json"))
                        continue;
                char **nn = realloc(names, (n + 1) * sizeof *names);
                if (!nn)
                        break;
                names = nn;
                names[n++] = strndup(de->d_name, l - 5);
        }
        closedir(dir);
        qsort(names, n, sizeof *names, cmp_names);
        for (size_t i = 0; i < n; i++) {
                char p[PATH_MAX + 300];
                snprintf(p, sizeof p, "%s/%s.json", dirp, names[i] ? names[i] : "");
                _cleanup_json_ json_t *o = NULL;
                struct imp_error e = { 0 };
                const char *session = "", *state = "", *set = "", *queued = "", *started = NULL, *ended = NULL,
                           *output = NULL;
                long long attempts = 0;
                struct job *j = names[i] ? job_new(d, names[i]) : NULL;
                free(names[i]);
                if (!j)
                        continue;
                int st;
                if (imp_json_load(p, &o, &e) < 0 || imp_json_get_string(o, "session", true, &session, p, &e) < 0 ||
                    imp_json_get_string(o, "state", true, &state, p, &e) < 0 ||
                    imp_json_get_string(o, "set", true, &set, p, &e) < 0 ||
                    imp_json_get_string(o, "queued", false, &queued, p, &e) < 0 ||
                    imp_json_get_string(o, "started", false, &started, p, &e) < 0 ||
                    imp_json_get_string(o, "ended", false, &ended, p, &e) < 0 ||
                    imp_json_get_string(o, "output", false, &output, p, &e) < 0 ||
                    imp_json_get_int(o, "attempts", false, &attempts, p, &e) < 0 ||
                    (st = job_state_from_name(state)) < 0) {
                        log_warning("%s: %s, ignoring", p, e.msg[0] ? e.msg : "bad state");
                        free(j);
                        continue;
                }
                snprintf(j->session, sizeof j->session, "%s", session);
                snprintf(j->set_dir, sizeof j->set_dir, "%s", set);
                snprintf(j->queued, sizeof j->queued, "%s", queued);
                snprintf(j->started, sizeof j->started, "%s", started ? started : "");
                snprintf(j->ended, sizeof j->ended, "%s", ended ? ended : "");
                snprintf(j->output, sizeof j->output, "%s/outputs/%s", d->state_dir, j->id);
                json_t *err = json_object_get(o, "error");
                const char *msg = NULL;
                if (json_is_object(err) && imp_json_get_string(err, "message", false, &msg, p, &e) == 0 && msg)
                        snprintf(j->error, sizeof j->error, "%s", msg);
                j->attempts = (int) attempts;
                j->state = (enum job_state) st;
                if (j->state == JOB_RUNNING)
                        j->state = JOB_QUEUED;  /* the daemon stopped under it */
                j->next = d->jobs;
                d->jobs = j;
        }
        free(names);
        return 0;
}

void jobs_free_all(struct daemon *d) {
        sd_event_source_disable_unref(d->job_timer);
        d->job_timer = NULL;
        while (d->jobs) {
                struct job *j = d->jobs;
                d->jobs = j->next;
                if (j->pid > 0) {
                        /* The worker is left to finish; the job is queued again on restart. */
                        sd_event_source_disable_unref(j->child_source);
                }
                free(j);
        }
}
