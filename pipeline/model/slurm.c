/* The Slurm engine for processing batches (slurm.h, docs/scale-out.md). */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "conf.h"
#include "job.h"
#include "json-util.h"
#include "slurm.h"

#define SLURM_CMD_TIMEOUT_MS 60000

void imp_slurm_config_default(struct imp_slurm_config *c, const char *worker_default) {
        *c = (struct imp_slurm_config) { .cpus_per_task = 2 };
        snprintf(c->mem, sizeof c->mem, "1G");
        snprintf(c->worker, sizeof c->worker, "%s", worker_default);
}

static int get_str(const struct imp_conf *f, const config_setting_t *g, const char *name, char *out, size_t size,
                   struct imp_error *err) {
        const char *v = NULL;
        int r = imp_conf_get_string(f, g, name, false, &v, err);
        if (r < 0 || !v)
                return r;
        if (strlen(v) >= size || strpbrk(v, "\n\"'`$\\"))
                return imp_error_set(err, -EINVAL, "%s:%d: slurm.%s: expected at most %zu bytes without quotes, "
                                     "backslashes, $ or newlines", imp_conf_path(f),
                                     config_setting_source_line(config_setting_get_member(g, name)), name, size - 1);
        snprintf(out, size, "%s", v);
        return 0;
}

static int load_group(const struct imp_conf *f, const config_setting_t *g, struct imp_slurm_config *c,
                      struct imp_error *err) {
        static const char *const known[] = { "partition", "account", "cpus_per_task", "mem", "time", "max_running",
                                             "shared_dir", "worker", NULL };
        long long cpus = c->cpus_per_task, k = c->max_running;
        int r;
        if ((r = imp_conf_check_known(f, g, known, err)) < 0 ||
            (r = get_str(f, g, "partition", c->partition, sizeof c->partition, err)) < 0 ||
            (r = get_str(f, g, "account", c->account, sizeof c->account, err)) < 0 ||
            (r = get_str(f, g, "mem", c->mem, sizeof c->mem, err)) < 0 ||
            (r = get_str(f, g, "time", c->time, sizeof c->time, err)) < 0 ||
            (r = get_str(f, g, "shared_dir", c->shared_dir, sizeof c->shared_dir, err)) < 0 ||
            (r = get_str(f, g, "worker", c->worker, sizeof c->worker, err)) < 0 ||
            (r = imp_conf_get_int(f, g, "cpus_per_task", false, 1, 1024, &cpus, err)) < 0 ||
            (r = imp_conf_get_int(f, g, "max_running", false, 0, 100000, &k, err)) < 0)
                return r;
        c->cpus_per_task = (int) cpus;
        c->max_running = (int) k;
        return 0;
}

int imp_slurm_config_load(const char *path, struct imp_slurm_config *c, struct imp_error *err) {
        _cleanup_(imp_conf_freep) struct imp_conf *f = NULL;
        int r = imp_conf_load(path, &f, err);
        if (r < 0)
                return r;
        static const char *const schedulers[] = { "local", "slurm", NULL };
        int which = 0;
        if ((r = imp_conf_get_enum(f, NULL, "scheduler", false, schedulers, &which, err)) < 0)
                return r;
        c->enabled = which == 1;
        config_setting_t *g = NULL;
        if ((r = imp_conf_get_group(f, NULL, "slurm", false, &g, err)) < 0)
                return r;
        if (g && (r = load_group(f, g, c, err)) < 0)
                return r;
        if (c->enabled && !c->shared_dir[0])
                return imp_error_set(err, -EINVAL, "%s: slurm.shared_dir: required with scheduler = \"slurm\" (a "
                                     "directory every node mounts at the same path)", path);
        return 0;
}

/* ---- running the Slurm commands ----------------------------------------------------------- */

/* Drains both pipes until they close; false on the timeout. */
static bool read_pipes(int fds[2], char *bufs[2], size_t sizes[2]) {
        size_t len[2] = { 0, 0 };
        int open_fds = 2;
        struct timespec t0, t;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        while (open_fds > 0) {
                struct pollfd p[2] = { { fds[0], POLLIN, 0 }, { fds[1], POLLIN, 0 } };
                clock_gettime(CLOCK_MONOTONIC, &t);
                long left = SLURM_CMD_TIMEOUT_MS - ((t.tv_sec - t0.tv_sec) * 1000 + (t.tv_nsec - t0.tv_nsec) / 1000000);
                if (left <= 0 || poll(p, 2, (int) left) == 0)
                        return false;
                for (int i = 0; i < 2; i++) {
                        if (fds[i] < 0 || !(p[i].revents & (POLLIN | POLLHUP | POLLERR)))
                                continue;
                        char tmp[4096];
                        ssize_t k = read(fds[i], tmp, sizeof tmp);
                        if (k <= 0) {
                                if (k < 0 && errno == EINTR)
                                        continue;
                                close(fds[i]);
                                fds[i] = -1;
                                open_fds--;
                                continue;
                        }
                        size_t room = sizes[i] - 1 - len[i];
                        size_t n = (size_t) k < room ? (size_t) k : room;
                        memcpy(bufs[i] + len[i], tmp, n);
                        len[i] += n;
                        bufs[i][len[i]] = 0;
                }
        }
        return true;
}

/* Runs argv (PATH search), its standard output into out. The exit status when it ran, else
 * a negative errno with err set; a failure's standard error goes into err. */
static int run_cmd(const char *const *argv, char *out, size_t out_size, struct imp_error *err) {
        int po[2], pe[2];
        if (pipe2(po, O_CLOEXEC) < 0)
                return imp_error_set(err, negative_errno(), "pipe: %m");
        if (pipe2(pe, O_CLOEXEC) < 0) {
                close(po[0]), close(po[1]);
                return imp_error_set(err, negative_errno(), "pipe: %m");
        }
        pid_t pid = fork();
        if (pid == 0) {
                dup2(po[1], STDOUT_FILENO);
                dup2(pe[1], STDERR_FILENO);
                execvp(argv[0], (char *const *) argv);
                dprintf(STDERR_FILENO, "cannot run %s: %s", argv[0], strerror(errno));
                _exit(127);
        }
        close(po[1]);
        close(pe[1]);
        if (pid < 0) {
                close(po[0]), close(pe[0]);
                return imp_error_set(err, negative_errno(), "fork: %m");
        }
        char errbuf[768] = "";
        out[0] = 0;
        int fds[2] = { po[0], pe[0] };
        char *bufs[2] = { out, errbuf };
        size_t sizes[2] = { out_size, sizeof errbuf };
        bool finished = read_pipes(fds, bufs, sizes);
        for (int i = 0; i < 2; i++)
                if (fds[i] >= 0)
                        close(fds[i]);
        if (!finished)
                kill(pid, SIGKILL);
        int st = 0;
        while (waitpid(pid, &st, 0) < 0 && errno == EINTR)
                ;
        errbuf[strcspn(errbuf, "\n")] = 0;
        if (!finished)
                return imp_error_set(err, -ETIMEDOUT, "%s: no answer within %d s", argv[0], SLURM_CMD_TIMEOUT_MS / 1000);
        int code = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
        if (code == 127)
                return imp_error_set(err, -ENOENT, "%s", errbuf[0] ? errbuf : "cannot run the Slurm command");
        if (code != 0)
                imp_error_set(err, -EIO, "%s exited with status %d: %s", argv[0], code, errbuf);
        return code;
}

/* ---- creating and submitting --------------------------------------------------------------- */

static int write_script(const struct imp_batch *b, const char *name, const char *worker, const char *mode,
                        struct imp_error *err) {
        char path[PATH_MAX + 32], text[3 * PATH_MAX + 512], abs[PATH_MAX];
        snprintf(path, sizeof path, "%s/%s", b->dir, name);
        /* the script runs in the batch directory: a relative worker path is made absolute */
        if (worker[0] != '/' && strchr(worker, '/') && realpath(worker, abs))
                worker = abs;
        if (strpbrk(worker, "'\n") || strpbrk(b->dir, "'\n"))
                return imp_error_set(err, -EINVAL, "%s: the worker path and the batch directory may not contain "
                                     "quotes or newlines (they go into a shell script)", path);
        int n = snprintf(text, sizeof text,
                         "#!/bin/sh\n"
                         "# impasto batch %s (docs/scale-out.md), written by impasto; submitted with sbatch.\n"
                         "export OMP_NUM_THREADS=\"${SLURM_CPUS_PER_TASK:-1}\"\n"
                         "export OMP_WAIT_POLICY=\"${OMP_WAIT_POLICY:-passive}\"\n"
                         "exec '%s' --batch '%s' %s\n", b->id, worker, b->dir, mode);
        if (n < 0 || (size_t) n >= sizeof text)
                return imp_error_set(err, -ENAMETOOLONG, "%s: paths too long", path);
        int r = imp_file_write_atomic(path, text, (size_t) n, err);
        if (r == 0 && chmod(path, 0755) < 0)
                r = imp_error_set(err, negative_errno(), "%s: chmod: %m", path);
        return r;
}

static const char *base_name(const char *p, char *buf, size_t size) {
        size_t n = strlen(p);
        while (n > 1 && p[n - 1] == '/')
                n--;
        size_t s = n;
        while (s > 0 && p[s - 1] != '/')
                s--;
        snprintf(buf, size, "%.*s", (int) (n - s), p + s);
        return buf;
}

static json_t *tasks_json(const char *const *captures, size_t n, const char *copies, struct imp_error *err) {
        json_t *tasks = json_array();
        for (size_t i = 0; tasks && i < n; i++) {
                char base[256], abs[PATH_MAX], copy[PATH_MAX + 256];
                base_name(captures[i], base, sizeof base);
                for (size_t k = 0; k < i; k++) {
                        char other[256];
                        if (!strcmp(base, base_name(captures[k], other, sizeof other))) {
                                json_decref(tasks);
                                imp_error_set(err, -EEXIST, "%s and %s: two capture sets named %s; their copies "
                                              "would share %s/%s", captures[k], captures[i], base, copies, base);
                                return NULL;
                        }
                }
                if (!realpath(captures[i], abs)) {
                        json_decref(tasks);
                        imp_error_set(err, negative_errno(), "%s: %m", captures[i]);
                        return NULL;
                }
                snprintf(copy, sizeof copy, "%s/%s", copies, base);
                json_array_append_new(tasks, json_pack("{s:s, s:s}", "capture", abs, "copy", copy));
        }
        return tasks;
}

int imp_slurm_batch_create(const struct imp_slurm_config *c, const char *id, const char *const *captures,
                           size_t n, const char *copies_dir, const char *worker_args, struct imp_batch *b,
                           struct imp_error *err) {
        char dir[PATH_MAX], copies[PATH_MAX], logs[PATH_MAX + 8], now[32];
        if (!imp_job_id_valid(id))
                return imp_error_set(err, -EINVAL, "batch id \"%s\": expected 1-128 [A-Za-z0-9._-]", id);
        if (n == 0 || n > IMP_BATCH_MAX_TASKS)
                return imp_error_set(err, -EINVAL, "expected 1 to %d capture sets, got %zu", IMP_BATCH_MAX_TASKS, n);
        int k1 = snprintf(dir, sizeof dir, "%s/batches/%s", c->shared_dir, id);
        int k2 = copies_dir && copies_dir[0] ? snprintf(copies, sizeof copies, "%s", copies_dir)
                 : snprintf(copies, sizeof copies, "%s/copies/%s", c->shared_dir, id);
        if (k1 < 0 || k2 < 0 || (size_t) k1 >= sizeof dir || (size_t) k2 >= sizeof copies)
                return imp_error_set(err, -ENAMETOOLONG, "%s: shared_dir too long", c->shared_dir);
        snprintf(logs, sizeof logs, "%s/logs", dir);
        int r = imp_mkdir_p(logs, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", logs, strerror(-r));
        if ((r = imp_mkdir_p(copies, 0755)) < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", copies, strerror(-r));
        json_t *tasks = tasks_json(captures, n, copies, err);
        if (!tasks)
                return err->code ? err->code : -ENOMEM;
        imp_rfc3339_now(now);
        *b = (struct imp_batch) { .doc = json_pack("{s:i, s:s, s:s, s:s?, s:o, s:s, s:[], s:b}", "format", 1, "id", id,
                                                   "created", now, "worker_args", worker_args, "tasks", tasks,
                                                   "engine", "slurm", "submissions", "cancelled", false) };
        snprintf(b->dir, sizeof b->dir, "%s", dir);
        if (!b->doc)
                return imp_error_set(err, -ENOMEM, "out of memory");
        if ((r = imp_batch_save(b, err)) < 0 || (r = write_script(b, "task.sbatch", c->worker, "--task \"$SLURM_ARRAY_TASK_ID\"", err)) < 0 ||
            (r = write_script(b, "finish.sbatch", c->worker, "--finish", err)) < 0)
                return r;
        imp_batch_done(b);
        return imp_batch_load(dir, b, err);
}

/* "0,3,5%K" or "0-N%K". */
static int array_spec(const struct imp_slurm_config *c, const size_t *tasks, size_t n, size_t total, char **ret) {
        size_t size = 32 + (tasks ? n * 8 : 0);
        char *s = malloc(size);
        if (!s)
                return -ENOMEM;
        size_t len = 0;
        if (!tasks)
                len = (size_t) snprintf(s, size, "0-%zu", total - 1);
        for (size_t i = 0; tasks && i < n; i++)
                len += (size_t) snprintf(s + len, size - len, "%s%zu", i ? "," : "", tasks[i]);
        if (c->max_running > 0)
                snprintf(s + len, size - len, "%%%d", c->max_running);
        *ret = s;
        return 0;
}

/* The options both submissions share; argv[*n] onwards. */
static void common_args(const struct imp_slurm_config *c, char opt[6][128], const char **argv, size_t *n) {
        int k = 0;
        if (c->partition[0])
                snprintf(opt[k], 128, "--partition=%s", c->partition), argv[(*n)++] = opt[k++];
        if (c->account[0])
                snprintf(opt[k], 128, "--account=%s", c->account), argv[(*n)++] = opt[k++];
        if (c->mem[0])
                snprintf(opt[k], 128, "--mem=%s", c->mem), argv[(*n)++] = opt[k++];
        if (c->time[0])
                snprintf(opt[k], 128, "--time=%s", c->time), argv[(*n)++] = opt[k++];
        snprintf(opt[k], 128, "--cpus-per-task=%d", c->cpus_per_task), argv[(*n)++] = opt[k++];
}

/* sbatch --parsable ARGS SCRIPT → the job id ("123", or "123;cluster"). */
static int sbatch(const struct imp_slurm_config *c, const struct imp_batch *b, const char *extra1, const char *extra2,
                  const char *name, const char *log, const char *script, long *ret_id, struct imp_error *err) {
        char opt[6][128], jn[192], out[PATH_MAX + 64], chdir_opt[PATH_MAX + 16], path[PATH_MAX + 32], buf[256];
        const char *argv[20] = { "sbatch", "--parsable", "--open-mode=append" };
        size_t n = 3;
        common_args(c, opt, argv, &n);
        snprintf(jn, sizeof jn, "--job-name=impasto-%s-%s", name, b->id);
        snprintf(out, sizeof out, "--output=%s/logs/%s", b->dir, log);
        snprintf(chdir_opt, sizeof chdir_opt, "--chdir=%s", b->dir);
        snprintf(path, sizeof path, "%s/%s", b->dir, script);
        argv[n++] = jn;
        argv[n++] = out;
        argv[n++] = chdir_opt;
        argv[n++] = extra1;
        if (extra2)
                argv[n++] = extra2;
        argv[n++] = path;
        argv[n] = NULL;
        int r = run_cmd(argv, buf, sizeof buf, err);
        if (r != 0)
                return r < 0 ? r : err->code;
        char *end = NULL;
        long id = strtol(buf, &end, 10);
        if (end == buf || id <= 0 || (*end && *end != ';' && *end != '\n'))
                return imp_error_set(err, -EBADMSG, "sbatch --parsable printed \"%.64s\", not a job id", buf);
        *ret_id = id;
        return 0;
}

static int submit_finish(const struct imp_slurm_config *c, const struct imp_batch *b, long array, long *ret_id,
                         struct imp_error *err) {
        char dep[64];
        snprintf(dep, sizeof dep, "--dependency=afterok:%ld", array);
        return sbatch(c, b, dep, "--kill-on-invalid-dep=yes", "finish", "finish.out", "finish.sbatch", ret_id, err);
}

int imp_slurm_submit(const struct imp_slurm_config *c, struct imp_batch *b, const size_t *tasks, size_t n,
                     struct imp_error *err) {
        _cleanup_free_ char *spec = NULL;
        if (array_spec(c, tasks, n, b->n_tasks, &spec) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        char arr[64 + strlen(spec)];
        snprintf(arr, sizeof arr, "--array=%s", spec);
        long array = 0, finish = 0;
        int r = sbatch(c, b, arr, NULL, "tile", "task-%a.out", "task.sbatch", &array, err);
        if (r < 0)
                return r;
        if ((r = submit_finish(c, b, array, &finish, err)) < 0) {
                char id[32];
                snprintf(id, sizeof id, "%ld", array);
                const char *argv[] = { "scancel", id, NULL };
                char out[64];
                struct imp_error e2 = {};
                (void) run_cmd(argv, out, sizeof out, &e2);
                return r;
        }
        json_t *list = json_array();
        for (size_t i = 0; list && i < (tasks ? n : b->n_tasks); i++)
                json_array_append_new(list, json_integer((json_int_t) (tasks ? tasks[i] : i)));
        char now[32];
        imp_rfc3339_now(now);
        json_t *sub = json_pack("{s:I, s:I, s:o, s:s}", "array", (json_int_t) array, "finish", (json_int_t) finish,
                                "tasks", list, "at", now);
        if (!sub || json_array_append_new(json_object_get(b->doc, "submissions"), sub) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return imp_batch_save(b, err);
}

/* ---- state, cancel, retry -------------------------------------------------------------------- */

/* One line of squeue/sacct: the array (or plain) job id, the array index (-1 for a plain
 * job), the state. */
struct slurm_line {
        long job;
        long index;
        char state[32];
};

/* Parses "JOB|INDEX|STATE" lines (INDEX "N/A" for a plain job); sacct's are
 * "JOB_INDEX|JOB_INDEX|STATE" ("JOB|JOB|STATE" for a plain job), whose second field is no index. */
static size_t parse_lines(char *text, struct slurm_line *out, size_t max, bool sacct) {
        size_t n = 0;
        char *save = NULL;
        for (char *l = strtok_r(text, "\n", &save); l && n < max; l = strtok_r(NULL, "\n", &save)) {
                char *end = NULL;
                long job = strtol(l, &end, 10), index = -1;
                if (end == l)
                        continue;
                if (*end == '_')
                        index = strtol(end + 1, &end, 10);
                if (*end != '|')
                        continue;
                char *p = end + 1;
                if (!sacct && *p != '|' && strncmp(p, "N/A", 3))
                        index = strtol(p, &end, 10);
                char *bar = strchr(p, '|');
                if (!bar)
                        continue;
                snprintf(out[n].state, sizeof out[n].state, "%.*s", (int) strcspn(bar + 1, " |\r"), bar + 1);
                out[n].job = job;
                out[n].index = index;
                n++;
        }
        return n;
}

/* What Slurm says about the batch's jobs: squeue (jobs it still remembers), then sacct
 * (where the cluster keeps accounting; fails harmlessly where it does not). */
static size_t slurm_lines(const struct imp_batch *b, struct slurm_line *out, size_t max) {
        char names[600], buf[1 << 16];
        snprintf(names, sizeof names, "--name=impasto-tile-%s,impasto-finish-%s", b->id, b->id);
        const char *sq[] = { "squeue", "-h", "-r", "-t", "all", "-o", "%F|%K|%T", names, NULL };
        struct imp_error e = {};
        size_t n = run_cmd(sq, buf, sizeof buf, &e) == 0 ? parse_lines(buf, out, max, false) : 0;
        const char *sa[] = { "sacct", "-n", "-P", "-X", "-o", "JobID,JobID,State", names, NULL };
        if (n < max && run_cmd(sa, buf, sizeof buf, &e) == 0) {
                struct slurm_line more[256];
                size_t m = parse_lines(buf, more, 256, true);
                for (size_t i = 0; i < m && n < max; i++) {
                        bool seen = false;
                        for (size_t k = 0; k < n && !seen; k++)
                                seen = out[k].job == more[i].job && out[k].index == more[i].index;
                        if (!seen)
                                out[n++] = more[i];
                }
        }
        return n;
}

static const char *slurm_state_of(const struct slurm_line *l, size_t n, long job, long index) {
        for (size_t i = 0; i < n; i++)
                if (l[i].job == job && l[i].index == index)
                        return l[i].state;
        return NULL;
}

static bool slurm_active(const char *s) {
        return !strcmp(s, "PENDING") || !strcmp(s, "RUNNING") || !strcmp(s, "CONFIGURING") ||
               !strcmp(s, "COMPLETING") || !strcmp(s, "REQUEUED") || !strcmp(s, "RESIZING") ||
               !strcmp(s, "SUSPENDED") || !strcmp(s, "REQUEUE_HOLD") || !strcmp(s, "REQUEUE_FED");
}

/* One task (or the finish step, file_state NULL) from the batch's files and Slurm's view. */
static void task_from(struct imp_slurm_task *t, const char *file_state, const char *file_error, const char *ss,
                      bool cancelled) {
        snprintf(t->slurm_state, sizeof t->slurm_state, "%s", ss ? ss : "");
        snprintf(t->error, sizeof t->error, "%s", file_error ? file_error : "");
        const char *st = "failed";
        if (file_state && !strcmp(file_state, "done"))
                st = "done";
        else if (ss && slurm_active(ss))
                st = !strcmp(ss, "PENDING") || !strcmp(ss, "REQUEUED") ? "queued" : "running";
        else if (!file_state && ss && !strcmp(ss, "COMPLETED"))
                st = "done";
        else if (t->error[0])
                ;       /* the worker said why */
        else if (file_state && !strcmp(file_state, "running"))
                snprintf(t->error, sizeof t->error, "the task stopped while running (Slurm: %s)",
                         ss ? ss : "no longer listed");
        else if (ss)
                snprintf(t->error, sizeof t->error, "Slurm: %s", ss);
        else
                snprintf(t->error, sizeof t->error, "%s", cancelled ? "cancelled"
                         : "gone from Slurm's queue without a result");
        snprintf(t->state, sizeof t->state, "%s", st);
}

int imp_slurm_status(const struct imp_batch *b, struct imp_slurm_status *s, struct imp_error *err) {
        *s = (struct imp_slurm_status) { .n_tasks = b->n_tasks, .tasks = calloc(b->n_tasks, sizeof *s->tasks) };
        if (!s->tasks)
                return imp_error_set(err, -ENOMEM, "out of memory");
        s->cancelled = json_is_true(json_object_get(b->doc, "cancelled"));
        struct slurm_line *lines = calloc(4 * b->n_tasks + 64, sizeof *lines);
        if (!lines)
                return imp_error_set(err, -ENOMEM, "out of memory");
        size_t n = slurm_lines(b, lines, 4 * b->n_tasks + 64);
        const json_t *subs = json_object_get(b->doc, "submissions"), *sub, *ix;
        long *array_of = calloc(b->n_tasks, sizeof *array_of);
        size_t k, m;
        json_array_foreach(subs, k, sub) json_array_foreach(json_object_get(sub, "tasks"), m, ix) {
                json_int_t i = json_integer_value(ix);
                if (array_of && i >= 0 && (size_t) i < b->n_tasks)
                        array_of[i] = (long) json_integer_value(json_object_get(sub, "array"));
        }
        for (size_t i = 0; i < b->n_tasks; i++) {
                char error[512];
                const char *fs = imp_batch_task_state(b, i, error, sizeof error);
                long a = array_of ? array_of[i] : 0;
                const char *ss = a ? slurm_state_of(lines, n, a, (long) i) : NULL;
                bool never_started = !strcmp(fs, "queued");
                task_from(&s->tasks[i], fs, error[0] ? error : NULL, ss, s->cancelled);
                if (never_started && !ss && !a)
                        snprintf(s->tasks[i].state, sizeof s->tasks[i].state, "queued");
                snprintf(s->tasks[i].job, sizeof s->tasks[i].job, "%ld_%zu", a, i);
        }
        long fin = (long) json_integer_value(json_object_get(json_array_get(subs, json_array_size(subs) - 1), "finish"));
        const char *ss = fin ? slurm_state_of(lines, n, fin, -1) : NULL;
        char result[PATH_MAX + 32];
        snprintf(result, sizeof result, "%s/" IMP_RESULT_FILE, b->dir);
        json_t *doc = NULL;
        struct imp_error e = {};
        bool have = imp_json_load(result, &doc, &e) == 0;
        const char *rstate = have ? json_string_value(json_object_get(doc, "state")) : NULL;
        bool finished = rstate && !strcmp(rstate, "done");
        /* the step ran and failed: a copy missing, or the mosaic (its error) */
        const char *merr = json_string_value(json_object_get(json_object_get(doc, "mosaic"), "error"));
        char why[sizeof s->finish.error];
        snprintf(why, sizeof why, "the mosaic failed: %s", merr ? merr : "");
        task_from(&s->finish, finished ? "done" : rstate ? "failed" : ss ? NULL : "queued",
                  rstate && !finished && merr ? why : NULL, ss, s->cancelled);
        json_decref(doc);
        snprintf(s->finish.job, sizeof s->finish.job, "%ld", fin);
        free(array_of);
        free(lines);
        return 0;
}

void imp_slurm_status_done(struct imp_slurm_status *s) {
        free(s->tasks);
        *s = (struct imp_slurm_status) {};
}

static void scancel_ids(const char *const *ids, size_t n) {
        const char *argv[n + 2];
        argv[0] = "scancel";
        for (size_t i = 0; i < n; i++)
                argv[i + 1] = ids[i];
        argv[n + 1] = NULL;
        char out[256];
        struct imp_error e = {};
        (void) run_cmd(argv, out, sizeof out, &e);   /* ids Slurm has forgotten: nothing to do */
}

int imp_slurm_cancel(struct imp_batch *b, struct imp_error *err) {
        const json_t *subs = json_object_get(b->doc, "submissions"), *sub;
        size_t n = json_array_size(subs), k;
        char (*ids)[32] = calloc(2 * n + 1, sizeof *ids);
        const char **p = calloc(2 * n + 1, sizeof *p);
        if (!ids || !p) {
                free(ids), free(p);
                return imp_error_set(err, -ENOMEM, "out of memory");
        }
        json_array_foreach(subs, k, sub) {
                snprintf(ids[2 * k], 32, "%lld", json_integer_value(json_object_get(sub, "finish")));
                snprintf(ids[2 * k + 1], 32, "%lld", json_integer_value(json_object_get(sub, "array")));
                p[2 * k] = ids[2 * k];
                p[2 * k + 1] = ids[2 * k + 1];
        }
        if (n)
                scancel_ids(p, 2 * n);
        free(ids);
        free(p);
        json_object_set_new(b->doc, "cancelled", json_true());
        return imp_batch_save(b, err);
}

int imp_slurm_retry(const struct imp_slurm_config *c, struct imp_batch *b, size_t *ret_n, struct imp_error *err) {
        struct imp_slurm_status s;
        int r = imp_slurm_status(b, &s, err);
        if (r < 0)
                return r;
        size_t *failed = calloc(b->n_tasks, sizeof *failed), n = 0;
        if (!failed) {
                imp_slurm_status_done(&s);
                return imp_error_set(err, -ENOMEM, "out of memory");
        }
        bool busy = false;
        for (size_t i = 0; i < s.n_tasks; i++) {
                if (!strcmp(s.tasks[i].state, "failed"))
                        failed[n++] = i;
                busy |= !strcmp(s.tasks[i].state, "queued") || !strcmp(s.tasks[i].state, "running");
        }
        /* the old finish step waits on tasks that failed: it never runs (or was killed) */
        char fin[48];
        snprintf(fin, sizeof fin, "%s", s.finish.job);
        imp_slurm_status_done(&s);
        *ret_n = n;
        if (n == 0) {
                free(failed);
                return 0;
        }
        if (busy) {
                free(failed);
                return imp_error_set(err, -EBUSY, "batch %s: tasks are still queued or running; retry once they end",
                                     b->id);
        }
        const char *ids[] = { fin };
        if (strcmp(fin, "0"))
                scancel_ids(ids, 1);
        json_object_set_new(b->doc, "cancelled", json_false());
        r = imp_slurm_submit(c, b, failed, n, err);
        free(failed);
        return r;
}
