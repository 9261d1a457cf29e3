/* `impasto jobs submit --slurm CAPTURE...` and `impasto jobs list|show|cancel|retry --slurm
 * BATCH`: processing batches on a Slurm cluster without the daemon (docs/scale-out.md). The
 * engine is pipeline/model/slurm.h; this file parses arguments and prints. */
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include "cmd-jobs-slurm.h"
#include "exit-codes.h"
#include "job.h"
#include "json-util.h"
#include "log.h"
#include "sibling.h"
#include "slurm.h"

#define DEFAULT_CONFIG "/etc/impasto/scheduler.conf"

static void usage(FILE *f) {
        fprintf(f, "usage: impasto jobs submit --slurm [options] CAPTURE...\n"
                   "       impasto jobs list|show|cancel|retry --slurm BATCH [--config FILE] [--shared DIR] [--json]\n"
                   "options of submit (they override the config file's slurm group):\n"
                   "  --config FILE        scheduler config (default " DEFAULT_CONFIG " when it exists)\n"
                   "  --shared DIR         a directory every node mounts: batches and copies go there\n"
                   "  --partition P  --account A  --cpus N  --mem SIZE  --time LIMIT\n"
                   "  --max-running K      at most K tasks at once (the %%K of --array)\n"
                   "  --worker PATH        impasto-worker as the nodes see it\n"
                   "  --worker-args ARGS   processing options (docs/jobs.md worker_args)\n"
                   "  --out DIR            copies in DIR/<set name> (default SHARED/copies/BATCH)\n"
                   "  --name NAME          batch id suffix (default: batch)\n"
                   "BATCH is a batch directory or its id under SHARED/batches.\n");
}

bool imp_jobs_slurm_wanted(int argc, char **argv) {
        for (int i = 1; i < argc; i++)
                if (!strcmp(argv[i], "--slurm") || !strcmp(argv[i], "submit"))
                        return true;
        return false;
}

struct slurm_cli {
        struct imp_slurm_config c;
        const char *config, *out, *name, *worker_args;
        bool json;
        const char *shared, *partition, *account, *mem, *time, *worker;
        long cpus, max_running;
};

static int parse_count(const char *opt, const char *v, long min, long *ret) {
        char *end = NULL;
        long n = strtol(v, &end, 10);
        if (end == v || *end || n < min || n > 100000) {
                log_error("%s: expected an integer from %ld to 100000, got \"%s\"", opt, min, v);
                return -1;
        }
        *ret = n;
        return 0;
}

static int parse_opts(int argc, char **argv, struct slurm_cli *o) {
        enum { O_SLURM = 256, O_CONFIG, O_SHARED, O_PART, O_ACCT, O_CPUS, O_MEM, O_TIME, O_MAXR, O_WORKER, O_WARGS,
               O_OUT, O_NAME, O_JSON };
        static const struct option opts[] = {
                { "slurm", no_argument, NULL, O_SLURM }, { "config", required_argument, NULL, O_CONFIG },
                { "shared", required_argument, NULL, O_SHARED }, { "partition", required_argument, NULL, O_PART },
                { "account", required_argument, NULL, O_ACCT }, { "cpus", required_argument, NULL, O_CPUS },
                { "mem", required_argument, NULL, O_MEM }, { "time", required_argument, NULL, O_TIME },
                { "max-running", required_argument, NULL, O_MAXR }, { "worker", required_argument, NULL, O_WORKER },
                { "worker-args", required_argument, NULL, O_WARGS }, { "out", required_argument, NULL, O_OUT },
                { "name", required_argument, NULL, O_NAME }, { "json", no_argument, NULL, O_JSON },
                { "help", no_argument, NULL, 'h' }, {} };
        int c;
        o->cpus = o->max_running = -1;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case O_SLURM: break;
                case O_CONFIG: o->config = optarg; break;
                case O_SHARED: o->shared = optarg; break;
                case O_PART: o->partition = optarg; break;
                case O_ACCT: o->account = optarg; break;
                case O_MEM: o->mem = optarg; break;
                case O_TIME: o->time = optarg; break;
                case O_WORKER: o->worker = optarg; break;
                case O_WARGS: o->worker_args = optarg; break;
                case O_OUT: o->out = optarg; break;
                case O_NAME: o->name = optarg; break;
                case O_JSON: o->json = true; break;
                case O_CPUS:
                case O_MAXR:
                        if (parse_count(c == O_CPUS ? "--cpus" : "--max-running", optarg, c == O_CPUS ? 1 : 0,
                                        c == O_CPUS ? &o->cpus : &o->max_running) < 0)
                                return IMP_EXIT_USAGE;
                        break;
                case 'h': usage(stdout); return -1;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        return 0;
}

static void set_str(char *dst, size_t size, const char *v) {
        if (v)
                snprintf(dst, size, "%s", v);
}

/* The config file (explicit, or the default one when present), then the options. */
static int load_config(struct slurm_cli *o) {
        char worker[4096] = "impasto-worker";
        (void) imp_sibling_path("impasto-worker", worker, sizeof worker);
        imp_slurm_config_default(&o->c, worker);
        const char *path = o->config ?: access(DEFAULT_CONFIG, F_OK) == 0 ? DEFAULT_CONFIG : NULL;
        struct imp_error err = {};
        if (path && imp_slurm_config_load(path, &o->c, &err) < 0 && !(err.code == -EINVAL && !o->c.shared_dir[0] &&
                                                                       o->shared)) {
                log_error("%s", err.msg);
                return IMP_EXIT_BAD_INPUT;
        }
        set_str(o->c.shared_dir, sizeof o->c.shared_dir, o->shared);
        set_str(o->c.partition, sizeof o->c.partition, o->partition);
        set_str(o->c.account, sizeof o->c.account, o->account);
        set_str(o->c.mem, sizeof o->c.mem, o->mem);
        set_str(o->c.time, sizeof o->c.time, o->time);
        set_str(o->c.worker, sizeof o->c.worker, o->worker);
        if (o->cpus > 0)
                o->c.cpus_per_task = (int) o->cpus;
        if (o->max_running >= 0)
                o->c.max_running = (int) o->max_running;
        return 0;
}

static int submit(struct slurm_cli *o, int n, char **captures) {
        if (!o->c.shared_dir[0]) {
                log_error("impasto jobs submit --slurm: no shared directory: give --shared DIR or slurm.shared_dir "
                          "in %s", o->config ?: DEFAULT_CONFIG);
                return IMP_EXIT_USAGE;
        }
        char id[160], stamp[32];
        time_t now = time(NULL);
        strftime(stamp, sizeof stamp, "%Y%m%d-%H%M%S", gmtime(&now));
        snprintf(id, sizeof id, "%s-%s-%d", stamp, o->name ?: "batch", (int) getpid() % 100000);
        struct imp_batch b;
        struct imp_error err = {};
        if (imp_slurm_batch_create(&o->c, id, (const char *const *) captures, (size_t) n, o->out, o->worker_args, &b,
                                   &err) < 0) {
                log_error("%s", err.msg);
                return err.code == -ENOENT || err.code == -EEXIST ? IMP_EXIT_BAD_INPUT : IMP_EXIT_FAILURE;
        }
        int r = imp_slurm_submit(&o->c, &b, NULL, 0, &err);
        if (r < 0)
                log_error("batch %s: %s", b.dir, err.msg);
        else {
                const json_t *sub = json_array_get(json_object_get(b.doc, "submissions"), 0);
                printf("batch %s: %zu tasks, Slurm array job %lld, finish job %lld\n%s\n", b.id, b.n_tasks,
                       json_integer_value(json_object_get(sub, "array")),
                       json_integer_value(json_object_get(sub, "finish")), b.dir);
        }
        imp_batch_done(&b);
        return r < 0 ? IMP_EXIT_FAILURE : IMP_EXIT_OK;
}

static int open_batch(const struct slurm_cli *o, const char *arg, struct imp_batch *b) {
        char dir[8192];
        struct stat st;
        if (strchr(arg, '/') || stat(arg, &st) == 0 || !o->c.shared_dir[0])
                snprintf(dir, sizeof dir, "%s", arg);
        else
                snprintf(dir, sizeof dir, "%s/batches/%s", o->c.shared_dir, arg);
        struct imp_error err = {};
        if (imp_batch_load(dir, b, &err) < 0) {
                log_error("%s", err.msg);
                return IMP_EXIT_BAD_INPUT;
        }
        return 0;
}

static json_t *task_json(const struct imp_slurm_task *t, const char *name, const char *copy) {
        return json_pack("{s:s, s:s, s:s, s:s?, s:s?, s:s?}", "task", name, "state", t->state, "slurm_job", t->job,
                         "slurm_state", t->slurm_state[0] ? t->slurm_state : NULL, "copy", copy, "error",
                         t->error[0] ? t->error : NULL);
}

static int list(const struct slurm_cli *o, const struct imp_batch *b, bool full) {
        struct imp_slurm_status s;
        struct imp_error err = {};
        if (imp_slurm_status(b, &s, &err) < 0) {
                log_error("%s", err.msg);
                return IMP_EXIT_FAILURE;
        }
        _cleanup_json_ json_t *tasks = json_array();
        size_t failed = 0, done = 0;
        for (size_t i = 0; i < s.n_tasks; i++) {
                char name[32];
                snprintf(name, sizeof name, "%zu", i);
                json_array_append_new(tasks, task_json(&s.tasks[i], name, b->tasks[i].copy));
                failed += !strcmp(s.tasks[i].state, "failed");
                done += !strcmp(s.tasks[i].state, "done");
        }
        _cleanup_json_ json_t *doc = json_pack("{s:s, s:s, s:o, s:o, s:b}", "batch", b->id, "dir", b->dir, "tasks",
                                               json_incref(tasks), "finish", task_json(&s.finish, "finish", NULL),
                                               "cancelled", s.cancelled);
        if (o->json) {
                char *text = json_dumps(doc, JSON_INDENT(2));
                printf("%s\n", text ?: "{}");
                free(text);
        } else {
                printf("batch %s: %zu of %zu done, %zu failed%s\n", b->id, done, s.n_tasks, failed,
                       s.cancelled ? " (cancelled)" : "");
                printf("%-8s %-8s %-16s %-12s %s\n", "TASK", "STATE", "SLURM JOB", "SLURM STATE", full ? "COPY / ERROR" : "ERROR");
                for (size_t i = 0; i <= s.n_tasks; i++) {
                        const struct imp_slurm_task *t = i < s.n_tasks ? &s.tasks[i] : &s.finish;
                        char name[32];
                        snprintf(name, sizeof name, i < s.n_tasks ? "%zu" : "finish", i);
                        printf("%-8s %-8s %-16s %-12s %s%s%s\n", name, t->state, t->job, t->slurm_state[0] ? t->slurm_state : "-",
                               full && i < s.n_tasks ? b->tasks[i].copy : "", full && t->error[0] ? "  " : "", t->error);
                }
        }
        imp_slurm_status_done(&s);
        return failed ? IMP_EXIT_FAILURE : IMP_EXIT_OK;
}

static int batch_verb(struct slurm_cli *o, const char *verb, const char *arg) {
        struct imp_batch b;
        int r = open_batch(o, arg, &b);
        if (r)
                return r;
        struct imp_error err = {};
        if (!strcmp(verb, "list") || !strcmp(verb, "show"))
                r = list(o, &b, !strcmp(verb, "show"));
        else if (!strcmp(verb, "cancel")) {
                r = imp_slurm_cancel(&b, &err) < 0 ? IMP_EXIT_FAILURE : IMP_EXIT_OK;
                if (r)
                        log_error("%s", err.msg);
                else
                        printf("batch %s: cancelled\n", b.id);
        } else {
                size_t n = 0;
                r = imp_slurm_retry(&o->c, &b, &n, &err) < 0 ? IMP_EXIT_FAILURE : IMP_EXIT_OK;
                if (r)
                        log_error("%s", err.msg);
                else if (n == 0)
                        printf("batch %s: no failed task to retry\n", b.id);
                else
                        printf("batch %s: %zu failed tasks resubmitted, Slurm array job %lld\n", b.id, n,
                               json_integer_value(json_object_get(
                                       json_array_get(json_object_get(b.doc, "submissions"),
                                                      json_array_size(json_object_get(b.doc, "submissions")) - 1),
                                       "array")));
        }
        imp_batch_done(&b);
        return r;
}

int imp_jobs_slurm_run(int argc, char **argv) {
        struct slurm_cli o = {};
        int r = parse_opts(argc, argv, &o);
        if (r)
                return r < 0 ? IMP_EXIT_OK : r;
        int n = argc - optind;
        const char *verb = n > 0 ? argv[optind] : "";
        if ((r = load_config(&o)))
                return r;
        if (!strcmp(verb, "submit") && n >= 2)
                return submit(&o, n - 1, argv + optind + 1);
        static const char *const verbs[] = { "list", "show", "cancel", "retry" };
        for (size_t i = 0; i < ARRAY_SIZE(verbs); i++)
                if (!strcmp(verb, verbs[i]) && n == 2)
                        return batch_verb(&o, verb, argv[optind + 1]);
        usage(stderr);
        return IMP_EXIT_USAGE;
}
