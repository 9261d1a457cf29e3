/* impasto-worker: turns queued capture sets into digital copies. A job is a JSON file
 * (docs/jobs.md) naming a capture set and a copy directory; the worker claims it atomically
 * (a flock on <id>.lock, then rename <id>.json -> <id>.json.running), runs
 * imp_process_capture(), and renames it back with state done or failed (or queued again
 * while attempts remain after a transient error), the error message kept.
 *
 *   impasto-worker JOB_FILE                    process that one job
 *   impasto-worker --queue DIR [--once]        process the DIR/<id>.json jobs (--once: one)
 *
 * While it runs, the worker writes its stage and overall progress into the claimed file
 * (atomically, on every new stage and at most once a second), which impastod re-reads to
 * send `job` events. The job's worker_args ("--holdout 8 --no-btf") set processing options.
 * It also records worker_build ("optimized", "AddressSanitizer", "unoptimized (-O0)"), and
 * warns when it is not an optimized build: such a build processes several times slower.
 *
 * The one-job modes an engine such as Slurm schedules (--capture, --batch) are in oneshot.c.
 *
 * Exit codes: 0 the job is done (or, with --once, nothing was queued; without --once, the
 * worker was stopped by SIGTERM/SIGINT), 1 the job failed or was put back for a retry,
 * 2 usage, 3 the job file is malformed, not queued, or claimed by another worker,
 * 4 the queue directory cannot be read. */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include "build-kind.h"
#include "hugepages.h"
#include "job.h"
#include "json-util.h"
#include "log.h"
#include "process.h"
#include "worker.h"

#define EXIT_DONE WORKER_EXIT_DONE
#define EXIT_JOB_FAILED WORKER_EXIT_JOB_FAILED
#define EXIT_USAGE WORKER_EXIT_USAGE
#define EXIT_BAD_JOB WORKER_EXIT_BAD_JOB
#define EXIT_QUEUE WORKER_EXIT_QUEUE

#define POLL_INTERVAL_S 2.0
#define PROGRESS_INTERVAL_S 1.0

static volatile sig_atomic_t stop_requested;

static void on_signal(int sig) {
        stop_requested = 1;
}

/* One claimed or inspected job: the file (pipeline/model/job.h) and where it lives. */
struct job {
        struct imp_job f;
        char path[PATH_MAX];          /* DIR/<id>.json */
        char running[PATH_MAX];       /* DIR/<id>.json.running while claimed */
        char lock[PATH_MAX];          /* DIR/<id>.lock */
        char capture[PATH_MAX], copy[PATH_MAX];   /* resolved against DIR */
        int lock_fd;
};

static void job_done(struct job *j) {
        imp_job_done(&j->f);
        if (j->lock_fd >= 0) {
                imp_job_unlock(j->lock, j->lock_fd);
                j->lock_fd = -1;
        }
}

static int resolve(const char *dir, const char *p, char *out, size_t size) {
        int n = p[0] == '/' ? snprintf(out, size, "%s", p) : snprintf(out, size, "%s/%s", dir, p);
        return n < 0 || (size_t) n >= size ? -ENAMETOOLONG : 0;
}

/* Reads and checks a job file; `path` is DIR/<id>.json. State is checked by the caller. */
static int job_read(const char *path, const char *read_from, struct job *j, struct imp_error *err) {
        *j = (struct job) { .lock_fd = -1 };
        snprintf(j->path, sizeof j->path, "%s", path);
        const char *slash = strrchr(path, '/');
        char dir[PATH_MAX];
        snprintf(dir, sizeof dir, "%.*s", slash ? (int) (slash - path) : 1, slash ? path : ".");
        if (slash == path)
                snprintf(dir, sizeof dir, "/");
        json_t *doc = NULL;
        int r = imp_json_load(read_from, &doc, err);
        if (r < 0)
                return r;
        if ((r = imp_job_parse(doc, path, IMP_JOB_STRICT, &j->f, err)) < 0)
                return r;
        int n1 = snprintf(j->running, sizeof j->running, "%s.running", path);
        if (resolve(dir, j->f.capture, j->capture, sizeof j->capture) < 0 ||
            resolve(dir, j->f.copy, j->copy, sizeof j->copy) < 0 || n1 < 0 || (size_t) n1 >= sizeof j->running ||
            imp_job_path(dir, j->f.id, IMP_JOB_FILE_LOCK, j->lock, sizeof j->lock) < 0)
                return imp_error_set(err, -ENAMETOOLONG, "%s: a path of the job is too long", path);
        return 0;
}

static const char *job_state(const struct job *j) {
        return json_string_value(json_object_get(j->f.doc, "state"));
}

/* The claim lock (pipeline/model/job.h), held while the job is claimed; -EBUSY when another
 * worker has it. */
static int job_lock(struct job *j) {
        return imp_job_lock(j->lock, &j->lock_fd);
}

static int job_write(struct job *j, const char *where, struct imp_error *err) {
        return imp_json_save_atomic(where, j->f.doc, err);
}

static int set_state(struct job *j, const char *state, const char *error) {
        char now[32];
        imp_rfc3339_now(now);
        bool running = !strcmp(state, "running");
        if (json_object_set_new(j->f.doc, running ? "started" : "ended", json_string(now)) < 0 ||
            (running && json_object_set_new(j->f.doc, "ended", json_null()) < 0) ||
            (running && json_object_set_new(j->f.doc, "progress", json_real(0)) < 0) ||
            (running && json_object_set_new(j->f.doc, "stage", json_null()) < 0) ||
            (!strcmp(state, "done") && json_object_set_new(j->f.doc, "progress", json_real(1)) < 0) ||
            json_object_set_new(j->f.doc, "state", json_string(state)) < 0 ||
            json_object_set_new(j->f.doc, "attempts", json_integer(j->f.attempts)) < 0 ||
            json_object_set_new(j->f.doc, "max_attempts", json_integer(j->f.max_attempts)) < 0 ||
            json_object_set_new(j->f.doc, "error", error ? json_string(error) : json_null()) < 0)
                return -ENOMEM;
        return 0;
}

/* Puts the claimed file back under its queue name; the state written first. */
static int job_release(struct job *j, struct imp_error *err) {
        int r = job_write(j, j->running, err);
        if (r < 0)
                return r;
        if (rename(j->running, j->path) < 0)
                return imp_error_set(err, negative_errno(), "%s: cannot rename to %s: %m", j->running, j->path);
        imp_fsync_parent_dir(j->path);
        return 0;
}

/* Claims a queued job: lock, re-read under the lock, rename to .running, count the attempt.
 * -EBUSY when another worker has it, -EALREADY when it is not queued. */
static int job_claim(const char *path, struct job *j, struct imp_error *err) {
        int r = job_read(path, path, j, err);
        if (r < 0)
                return r;
        if (strcmp(job_state(j) ?: "", "queued")) {
                imp_error_set(err, -EALREADY, "%s: job %s is %s, not queued", path, j->f.id, job_state(j) ?: "?");
                return -EALREADY;
        }
        r = job_lock(j);
        if (r < 0)
                return imp_error_set(err, r, "%s: %s", path,
                                     r == -EBUSY ? "claimed by another worker" : strerror(-r));
        /* Another worker may have finished it between our read and the lock. */
        imp_job_done(&j->f);
        int lock_fd = TAKE_FD(j->lock_fd);
        r = job_read(path, path, j, err);
        j->lock_fd = lock_fd;
        if (r < 0)
                return r == -ENOENT ? imp_error_set(err, -EBUSY, "%s: claimed by another worker", path) : r;
        if (strcmp(job_state(j) ?: "", "queued"))
                return imp_error_set(err, -EALREADY, "%s: job %s is %s, not queued", path, j->f.id,
                                     job_state(j) ?: "?");
        if (rename(path, j->running) < 0)
                return imp_error_set(err, negative_errno(), "%s: cannot claim: %m", path);
        j->f.attempts++;
        if ((r = set_state(j, "running", json_string_value(json_object_get(j->f.doc, "error")))) < 0)
                return imp_error_set(err, r, "out of memory");
        if ((r = job_write(j, j->running, err)) < 0) {
                rename(j->running, path);
                return r;
        }
        return 0;
}

/* Errors that another attempt will not fix: the capture set itself is wrong or missing. */
static bool permanent(int r) {
        return r == -EINVAL || r == -EBADMSG || r == -ENOENT;
}

struct progress_state {
        struct job *job;
        char stage[64];
        double last;
        double fraction;              /* of the whole job, never decreasing */
};

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void on_progress(void *userdata, const char *stage, size_t done, size_t total) {
        struct progress_state *p = userdata;
        double t = now_s();
        bool new_stage = strcmp(p->stage, stage) != 0;
        if (!new_stage && done != total && t - p->last < PROGRESS_INTERVAL_S)
                return;
        snprintf(p->stage, sizeof p->stage, "%s", stage);
        p->last = t;
        p->fraction = imp_process_fraction(p->fraction, stage, done, total);
        printf("job %s: %s %zu/%zu\n", p->job->f.id, stage, done, total);
        fflush(stdout);
        /* Progress is advice: a failed write does not stop the job. */
        struct imp_error err = {};
        if (json_object_set_new(p->job->f.doc, "stage", json_string(stage)) < 0 ||
            json_object_set_new(p->job->f.doc, "progress", json_real(p->fraction)) < 0 ||
            job_write(p->job, p->job->running, &err) < 0)
                log_warning("job %s: writing progress: %s, ignoring", p->job->f.id,
                            err.msg[0] ? err.msg : "out of memory");
}

/* worker_args (docs/jobs.md): whitespace-separated options of `impasto process`, --opt VALUE
 * or --opt=VALUE. */
int worker_parse_args(const char *args, struct imp_process_options *o, char *msg, size_t size) {
        char buf[1024];
        if (snprintf(buf, sizeof buf, "%s", args) >= (int) sizeof buf) {
                snprintf(msg, size, "worker_args: longer than %zu bytes", sizeof buf - 1);
                return -EINVAL;
        }
        char *save = NULL;
        for (char *w = strtok_r(buf, " \t\n", &save); w; w = strtok_r(NULL, " \t\n", &save)) {
                char *eq = strchr(w, '=');
                if (eq)
                        *eq = 0;
                if (!strcmp(w, "--no-btf") && !eq) {
                        o->btf = false;
                        continue;
                }
                if ((!strcmp(w, "--frame-search") || !strcmp(w, "--no-frame-search")) && !eq) {
                        o->frame_search = w[2] == 'n' ? IMP_FRAME_SEARCH_OFF : IMP_FRAME_SEARCH_ON;
                        continue;
                }
                bool known = !strcmp(w, "--holdout") || !strcmp(w, "--pitch") || !strcmp(w, "--cell") ||
                             !strcmp(w, "--delta");
                if (!known) {
                        snprintf(msg, size, "worker_args: unknown option \"%s\" (known: --holdout N, --pitch MM, "
                                 "--cell N, --delta FRACTION, --no-btf, --frame-search, --no-frame-search)", w);
                        return -EINVAL;
                }
                const char *v = eq ? eq + 1 : strtok_r(NULL, " \t\n", &save);
                char *end = NULL;
                double x = v ? strtod(v, &end) : 0;
                bool integer = strcmp(w, "--pitch") && strcmp(w, "--delta");
                if (!v || end == v || *end || !isfinite(x) || x < 0 || (integer && (x != floor(x) || x > 1000))) {
                        snprintf(msg, size, "worker_args: %s expects %s, got \"%s\"", w,
                                 integer ? "an integer 0..1000" : "a number >= 0", v ? v : "");
                        return -EINVAL;
                }
                if (!strcmp(w, "--holdout"))
                        o->holdout_every = (int) x;
                else if (!strcmp(w, "--cell")) {
                        if (x > 0)   /* 0: the default */
                                o->boxes.cell_px = (int) x;
                } else if (!strcmp(w, "--pitch"))
                        o->heightfield.pitch_mm = x;
                else if (x > 0)
                        o->boxes.delta_frac = x;
        }
        return 0;
}

/* Runs a claimed job to its next state and releases it. Returns the exit code. */
static int job_run(struct job *j) {
        printf("job %s: attempt %d of %d: %s -> %s\n", j->f.id, j->f.attempts, j->f.max_attempts, j->capture, j->copy);
        fflush(stdout);
        struct imp_process_options o;
        imp_process_options_default(&o);
        struct progress_state ps = { .job = j };
        o.progress = on_progress;
        o.userdata = &ps;
        struct imp_error err = {};
        const char *args = json_string_value(json_object_get(j->f.doc, "worker_args"));
        int r = args ? worker_parse_args(args, &o, err.msg, sizeof err.msg) : 0;
        if (r == 0 && args && args[0])
                printf("job %s: worker_args %s\n", j->f.id, args);
        /* The job file says which build processed it; a sanitizer or -O0 build is said aloud,
         * since its processing time is not the pipeline's (pipeline/core/build-kind.h). */
        json_object_set_new(j->f.doc, "worker_build", json_string(imp_build_kind()));
        if (imp_build_is_slow())
                log_warning("job %s: this impasto-worker is an %s build: processing takes several times longer "
                            "(and more memory) than with an optimized build", j->f.id, imp_build_kind());
        if (r == 0)
                r = imp_process_capture(j->capture, j->copy, &o, &err);
        const char *state = "done";
        char msg[sizeof err.msg];
        msg[0] = 0;
        if (r < 0) {
                snprintf(msg, sizeof msg, "%s", err.msg[0] ? err.msg : strerror(-r));
                state = permanent(r) || j->f.attempts >= j->f.max_attempts ? "failed" : "queued";
        }
        if (set_state(j, state, r < 0 ? msg : NULL) < 0)
                return log_error("out of memory"), EXIT_JOB_FAILED;
        struct imp_error werr = {};
        int w = job_release(j, &werr);
        if (w < 0)
                log_error("job %s: %s", j->f.id, werr.msg);
        if (r < 0) {
                log_error("job %s: %s", j->f.id, msg);
                printf("job %s: %s after attempt %d of %d\n", j->f.id, state, j->f.attempts, j->f.max_attempts);
        } else
                printf("job %s: done, digital copy in %s\n", j->f.id, j->copy);
        fflush(stdout);
        return r < 0 || w < 0 ? EXIT_JOB_FAILED : EXIT_DONE;
}

static bool ends_with(const char *s, const char *suffix) {
        size_t n = strlen(s), m = strlen(suffix);
        return n >= m && !strcmp(s + n - m, suffix);
}

/* A .running file whose lock nobody holds was left by a worker that died: queue it again
 * (its attempt counted) or fail it when the attempts are used up. */
static void recover_stale(const char *dir, const char *name) {
        char running[PATH_MAX], path[PATH_MAX];
        snprintf(running, sizeof running, "%s/%s", dir, name);
        snprintf(path, sizeof path, "%s/%.*s", dir, (int) (strlen(name) - strlen(".running")), name);
        _cleanup_(job_done) struct job j = { .lock_fd = -1 };
        struct imp_error err = {};
        if (job_read(path, running, &j, &err) < 0) {
                log_warning("%s: %s, ignoring", running, err.msg);
                return;
        }
        if (job_lock(&j) < 0)
                return;   /* its worker is alive */
        if (access(running, F_OK) < 0)
                return;   /* it finished meanwhile */
        bool exhausted = j.f.attempts >= j.f.max_attempts;
        char msg[256];
        snprintf(msg, sizeof msg, "the worker stopped during attempt %d", j.f.attempts);
        if (set_state(&j, exhausted ? "failed" : "queued", msg) < 0 || job_release(&j, &err) < 0)
                log_warning("%s: cannot recover: %s, ignoring", running, err.msg);
        else
                log_notice("job %s: %s; %s", j.f.id, msg, exhausted ? "failed" : "queued again");
}

/* Recovers every stale claim in DIR before the queue is scanned, so that a recovered job
 * can run in the same pass. */
static int recover_all(const char *dir) {
        DIR *d = opendir(dir);
        if (!d)
                return negative_errno();
        char **stale = NULL;
        size_t n_stale = 0;
        struct dirent *de;
        while ((de = readdir(d)))
                if (de->d_name[0] != '.' && ends_with(de->d_name, ".json.running")) {
                        char **s = realloc(stale, (n_stale + 1) * sizeof *s);
                        if (!s)
                                break;
                        stale = s;
                        if ((stale[n_stale] = strdup(de->d_name)))
                                n_stale++;
                }
        closedir(d);
        for (size_t i = 0; i < n_stale; i++) {
                recover_stale(dir, stale[i]);
                free(stale[i]);
        }
        free(stale);
        return 0;
}

/* One pass over DIR: recover stale claims, then run the oldest queued job. 1 when a job
 * ran (*ret_exit set), 0 when none was queued, negative errno when DIR cannot be read. */
static int queue_pass(const char *dir, int *ret_exit) {
        int r = recover_all(dir);
        if (r < 0)
                return r;
        DIR *d = opendir(dir);
        if (!d)
                return negative_errno();
        char best[PATH_MAX] = "";
        struct timespec best_t = {};
        struct dirent *de;
        while ((de = readdir(d))) {
                if (de->d_name[0] == '.' || !ends_with(de->d_name, ".json"))
                        continue;
                char path[PATH_MAX];
                struct stat st;
                if (snprintf(path, sizeof path, "%s/%s", dir, de->d_name) >= (int) sizeof path ||
                    stat(path, &st) < 0 || !S_ISREG(st.st_mode))
                        continue;
                /* oldest first, by modification time */
                if (!best[0] || st.st_mtim.tv_sec < best_t.tv_sec ||
                    (st.st_mtim.tv_sec == best_t.tv_sec && st.st_mtim.tv_nsec < best_t.tv_nsec)) {
                        struct job j = { .lock_fd = -1 };
                        struct imp_error err = {};
                        int k = job_read(path, path, &j, &err);
                        bool queued = k >= 0 && !strcmp(job_state(&j) ?: "", "queued");
                        if (k < 0 && k != -ENOENT)
                                log_warning("%s, ignoring", err.msg);
                        job_done(&j);
                        if (!queued)
                                continue;
                        snprintf(best, sizeof best, "%s", path);
                        best_t = st.st_mtim;
                }
        }
        closedir(d);
        if (!best[0])
                return 0;
        _cleanup_(job_done) struct job j = { .lock_fd = -1 };
        struct imp_error err = {};
        r = job_claim(best, &j, &err);
        if (r == -EBUSY || r == -EALREADY || r == -ENOENT) {
                log_debug("%s", err.msg);
                return queue_pass(dir, ret_exit);   /* lost the race: look again */
        }
        if (r < 0) {
                log_warning("%s, ignoring", err.msg);
                return 0;
        }
        *ret_exit = job_run(&j);
        return 1;
}

static int run_queue(const char *dir, bool once) {
        for (;;) {
                int code = EXIT_DONE;
                int r = queue_pass(dir, &code);
                if (r < 0) {
                        log_error_errno(r, "queue %s: %m", dir);
                        return EXIT_QUEUE;
                }
                if (once)
                        return r ? code : EXIT_DONE;
                if (stop_requested)
                        return EXIT_DONE;
                if (r == 0) {
                        struct timespec ts = { (time_t) POLL_INTERVAL_S, 0 };
                        nanosleep(&ts, NULL);   /* a signal cuts it short */
                        if (stop_requested)
                                return EXIT_DONE;
                }
        }
}

static int run_file(const char *path) {
        _cleanup_(job_done) struct job j = { .lock_fd = -1 };
        struct imp_error err = {};
        int r = job_claim(path, &j, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return EXIT_BAD_JOB;
        }
        return job_run(&j);
}

static void usage(FILE *f) {
        fprintf(f, "usage: impasto-worker JOB_FILE\n"
                   "       impasto-worker --queue DIR [--once]\n"
                   "       impasto-worker --capture SET --copy DIR [--args \"WORKER_ARGS\"]\n"
                   "       impasto-worker --batch DIR [--task N | --finish]\n"
                   "exit codes: 0 done (or nothing queued), 1 the job failed or awaits a retry, 2 usage,\n"
                   "            3 bad or unclaimable job file, 4 queue directory unreadable\n");
}

/* The options of every mode; main() checks which combination was given. */
struct worker_cmdline {
        const char *queue, *capture, *copy, *args, *batch, *task;
        bool once, finish;
};

static int parse_cmdline(int argc, char **argv, struct worker_cmdline *c) {
        static const struct option opts[] = {
                { "queue", required_argument, NULL, 'q' }, { "once", no_argument, NULL, '1' },
                { "capture", required_argument, NULL, 'c' }, { "copy", required_argument, NULL, 'o' },
                { "args", required_argument, NULL, 'a' }, { "batch", required_argument, NULL, 'b' },
                { "task", required_argument, NULL, 't' }, { "finish", no_argument, NULL, 'f' },
                { "help", no_argument, NULL, 'h' }, {} };
        int k;
        while ((k = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (k) {
                case 'q': c->queue = optarg; break;
                case '1': c->once = true; break;
                case 'c': c->capture = optarg; break;
                case 'o': c->copy = optarg; break;
                case 'a': c->args = optarg; break;
                case 'b': c->batch = optarg; break;
                case 't': c->task = optarg; break;
                case 'f': c->finish = true; break;
                case 'h': usage(stdout); return 1;
                default: usage(stderr); return -EINVAL;
                }
        int modes = !!c->queue + !!c->capture + !!c->batch;
        bool ok = modes == 0 ? optind + 1 == argc && !c->once && !c->copy && !c->args && !c->task && !c->finish
                : optind == argc && modes == 1 &&
                  (c->queue ? !c->copy && !c->args && !c->task && !c->finish
                   : c->capture ? c->copy && !c->once && !c->task && !c->finish
                   : !c->once && !c->copy && !c->args && !(c->task && c->finish));
        if (!ok) {
                usage(stderr);
                return -EINVAL;
        }
        return 0;
}

/* --task N, or the array index Slurm gives the task. */
static int batch_task(const struct worker_cmdline *c) {
        const char *t = c->task ?: getenv("SLURM_ARRAY_TASK_ID");
        char *end = NULL;
        long n = t ? strtol(t, &end, 10) : -1;
        if (!t || end == t || *end || n < 0) {
                log_error("--batch: expected --task N (an integer >= 0) or $SLURM_ARRAY_TASK_ID, got \"%s\"",
                          t ? t : "");
                return EXIT_USAGE;
        }
        return worker_run_batch_task(c->batch, n);
}

int main(int argc, char **argv) {
        imp_log_set_ident("impasto-worker");
        imp_hugepages_reexec(argv);
        struct worker_cmdline c = {};
        int r = parse_cmdline(argc, argv, &c);
        if (r != 0)
                return r > 0 ? 0 : EXIT_USAGE;
        /* One-job modes die on SIGTERM (scancel): their next attempt starts clean. */
        if (c.capture)
                return worker_run_capture(c.capture, c.copy, c.args);
        if (c.batch)
                return c.finish ? worker_run_batch_finish(c.batch) : batch_task(&c);
        struct sigaction sa = { .sa_handler = on_signal };
        sigaction(SIGTERM, &sa, NULL);
        sigaction(SIGINT, &sa, NULL);
        return c.queue ? run_queue(c.queue, c.once) : run_file(argv[optind]);
}
