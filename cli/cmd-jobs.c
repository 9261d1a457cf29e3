/* `impasto jobs [list] [--limit N]`, `impasto jobs show ID`, `impasto jobs retry ID`: the
 * processing queue (jobs.list, jobs.show, jobs.retry of proto/PROTOCOL.md). */
#include <getopt.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "client.h"
#include "cmd-jobs-slurm.h"
#include "commands.h"
#include "help.h"
#include "log.h"

static void usage(FILE *f) {
        fprintf(f, "usage: impasto jobs [list] [--limit N] [--json] [--socket PATH]\n"
                   "       impasto jobs show ID [--json] [--socket PATH]\n"
                   "       impasto jobs retry ID [--json] [--socket PATH]\n"
                   "       impasto jobs follow ID [--json] [--socket PATH]   one line per change until it ends\n"
                   "       impasto jobs submit --slurm [options] CAPTURE...   (docs/scale-out.md)\n"
                   "       impasto jobs list|show|cancel|retry --slurm BATCH\n"
                   "jobs follow exits 0 when the job is done, 1 when it failed; Ctrl-C detaches (the job goes\n"
                   "on in impastod) and exits 130.\n");
}

static void human_list(const json_t *r) {
        const json_t *list = json_object_get(r, "jobs"), *j;
        size_t i;
        if (!json_array_size(list)) {
                printf("no jobs\n");
                return;
        }
        printf("%-32s %-32s %-8s %-20s %-8s %s\n", "JOB", "SESSION", "STATE", "QUEUED", "PROGRESS", "VERDICT");
        json_array_foreach(list, i, j) {
                double p = imp_client_num(j, "progress");
                const char *v = imp_client_str(j, "verdict");
                printf("%-32s %-32s %-8s %-20s %7.0f%% %s\n", imp_client_str(j, "job"), imp_client_str(j, "session"),
                       imp_client_str(j, "state"), imp_client_str(j, "queued"), p == p ? 100 * p : 0, v[0] ? v : "-");
        }
}

static void human_show(const json_t *r) {
        printf("job      %s\nsession  %s\nstate    %s\nqueued   %s\n", imp_client_str(r, "job"),
               imp_client_str(r, "session"), imp_client_str(r, "state"), imp_client_str(r, "queued"));
        if (*imp_client_str(r, "started"))
                printf("started  %s\n", imp_client_str(r, "started"));
        if (*imp_client_str(r, "ended"))
                printf("ended    %s\n", imp_client_str(r, "ended"));
        if (*imp_client_str(r, "output"))
                printf("output   %s\n", imp_client_str(r, "output"));
        if (*imp_client_str(r, "verdict"))
                printf("verdict  %s\n", imp_client_str(r, "verdict"));
        const json_t *e = json_object_get(r, "error");
        if (json_is_object(e))
                printf("error    %s: %s\n", imp_client_str(e, "code"), imp_client_str(e, "message"));
        if (*imp_client_str(r, "log"))
                printf("log      %s\n", imp_client_str(r, "log"));
}

static void human_retry(const json_t *r) {
        printf("job %s: %s\n", imp_client_str(r, "job"), imp_client_str(r, "state"));
}

static char detach_msg[512];

static void on_interrupt(int sig) {
        (void) !write(STDERR_FILENO, detach_msg, strlen(detach_msg));
        _exit(130);
}

/* One line per change of the job (state, stage, progress, attempts); --json: the events. */
static void print_job_line(const json_t *e, bool json) {
        if (json) {
                _cleanup_free_ char *s = json_dumps(e, JSON_COMPACT | JSON_PRESERVE_ORDER);
                if (s)
                        puts(s);
        } else {
                double p = imp_client_num(e, "progress");
                const json_t *err = json_object_get(e, "error");
                printf("job %s: %s%s%s %.0f%% (attempt %lld of %lld)%s%s\n", imp_client_str(e, "job"),
                       imp_client_str(e, "state"), *imp_client_str(e, "stage") ? ", " : "", imp_client_str(e, "stage"),
                       p == p ? 100 * p : 0,
                       json_is_integer(json_object_get(e, "attempt")) ? imp_client_int(e, "attempt")
                                                                     : imp_client_int(e, "attempts"),
                       imp_client_int(e, "max_attempts"),
                       json_is_object(err) ? ": " : "", json_is_object(err) ? imp_client_str(err, "message") : "");
        }
        fflush(stdout);
}

static bool job_final(const json_t *e) {
        return !strcmp(imp_client_str(e, "state"), "done") || !strcmp(imp_client_str(e, "state"), "failed");
}

static int jobs_follow(const struct imp_client_opts *o, const char *id) {
        _cleanup_client_ struct imp_client *c = NULL;
        int rc = imp_client_connect_or_log(o, &c);
        if (rc)
                return rc;
        struct imp_error err = {};
        _cleanup_proto_message_ struct imp_proto_message sub = {}, show = {};
        int r = imp_client_call(c, "subscribe", json_pack("{s:[s]}", "events", "job"), NULL, NULL, &sub, &err);
        if (r >= 0 && sub.ok)
                r = imp_client_call(c, "jobs.show", json_pack("{s:s}", "job", id), NULL, NULL, &show, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!sub.ok || !show.ok)
                return imp_client_report_error(!sub.ok ? "subscribe" : "jobs.show", !sub.ok ? &sub : &show);
        print_job_line(show.result, o->json);
        bool failed = !strcmp(imp_client_str(show.result, "state"), "failed");
        if (job_final(show.result))
                return failed ? IMP_EXIT_FAILURE : IMP_EXIT_OK;
        snprintf(detach_msg, sizeof detach_msg, "\nimpasto: detached from job %s; it goes on in impastod.\n"
                 "Follow it again with: impasto jobs follow %s\n", id, id);
        struct sigaction sa = { .sa_handler = on_interrupt };
        sigemptyset(&sa.sa_mask);
        (void) sigaction(SIGINT, &sa, NULL);
        (void) sigaction(SIGTERM, &sa, NULL);
        for (;;) {
                _cleanup_proto_message_ struct imp_proto_message m = {};
                r = imp_client_next_event(c, -1, &m, &err);
                if (r < 0) {
                        log_error("%s", err.msg);
                        return imp_client_exit_for_errno(r);
                }
                if (r == 0 || strcmp(imp_client_str(m.root, "job"), id))
                        continue;
                print_job_line(m.root, o->json);
                if (job_final(m.root))
                        return !strcmp(imp_client_str(m.root, "state"), "done") ? IMP_EXIT_OK : IMP_EXIT_FAILURE;
        }
}

/* Says what was wrong with the words after `impasto jobs`. */
static int bad_args(const char *verb, int n, long limit) {
        static const char *const verbs[] = { "list", "show", "retry", "follow", "submit" };
        if (strcmp(verb, "list") && strcmp(verb, "show") && strcmp(verb, "retry") && strcmp(verb, "follow"))
                return imp_cli_unknown_action("jobs", verb, verbs, ARRAY_SIZE(verbs));
        if (!strcmp(verb, "list"))
                fprintf(stderr, "impasto jobs list: takes no arguments besides --limit N\n");
        else if (limit)
                fprintf(stderr, "impasto jobs %s: --limit applies to 'jobs list' only\n", verb);
        else
                fprintf(stderr, "impasto jobs %s: expected one JOB id, got %d\n", verb, n - 1);
        fprintf(stderr, "Run 'impasto help jobs' for the usage.\n");
        return IMP_EXIT_USAGE;
}

static int run(int argc, char **argv) {
        if (imp_jobs_slurm_wanted(argc, argv))
                return imp_jobs_slurm_run(argc, argv);
        struct imp_client_opts o = {};
        long limit = 0;
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' }, { "socket", required_argument, NULL, 'S' },
                { "limit", required_argument, NULL, 'n' }, { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'n':
                        if (imp_client_parse_limit(optarg, &limit))
                                return IMP_EXIT_USAGE;
                        break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        int n = argc - optind;
        const char *verb = n > 0 ? argv[optind] : "list";
        if (!strcmp(verb, "list") && n <= 1) {
                json_t *args = limit ? json_pack("{s:I}", "limit", (json_int_t) limit) : NULL;
                return imp_client_simple(&o, "jobs.list", args, human_list);
        }
        if (!strcmp(verb, "follow") && n == 2 && !limit)
                return jobs_follow(&o, argv[optind + 1]);
        if ((!strcmp(verb, "show") || !strcmp(verb, "retry")) && n == 2 && !limit) {
                json_t *args = json_pack("{s:s}", "job", argv[optind + 1]);
                if (!strcmp(verb, "show"))
                        return imp_client_simple(&o, "jobs.show", args, human_show);
                return imp_client_simple(&o, "jobs.retry", args, human_retry);
        }
        return bad_args(verb, n, limit);
}

const struct imp_command imp_cmd_jobs = {
        .name = "jobs",
        .summary = "the processing queue: list, show, follow and retry jobs",
        .run = run,
};
