/* `impasto report [--since TIME] [--json]`: the morning report (the `report` command of
 * proto/PROTOCOL.md): the sessions of the night with their frames and faults, the processing
 * jobs, the copies with their quality verdicts, and what needs the operator, each with the
 * command to act on it. TIME is UTC YYYY-MM-DDTHH:MM:SSZ, a date YYYY-MM-DD (its midnight,
 * UTC), or a span back from now: 30m, 12h, 2d (default 24h). */
#define _GNU_SOURCE 1
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "client.h"
#include "commands.h"
#include "log.h"
#include "numparse.h"

static void usage(FILE *f) {
        fprintf(f, "usage: impasto report [--since TIME] [--json] [--socket PATH]\n"
                   "TIME: YYYY-MM-DDTHH:MM:SSZ (UTC), YYYY-MM-DD (midnight UTC), or back from now: 30m, 12h, 2d\n"
                   "(default 24h)\n");
}

/* TIME as the daemon wants it (UTC, seconds): 0, or -EINVAL (logged). */
static int parse_since(const char *text, char out[static 32]) {
        size_t n = strlen(text);
        struct tm tm = { 0 };
        time_t t;
        char *end;
        if (n == 20 && strptime(text, "%Y-%m-%dT%H:%M:%SZ", &tm) == text + 20)
                t = timegm(&tm);
        else if (n == 10 && strptime(text, "%Y-%m-%d", &tm) == text + 10)
                t = timegm(&tm);
        else if (n >= 2 && strchr("mhd", text[n - 1]) && (strtol(text, &end, 10), end == text + n - 1) &&
                 text[0] >= '0' && text[0] <= '9') {
                char num[24];
                snprintf(num, sizeof num, "%.*s", (int) (n - 1), text);
                long v;
                if (imp_parse_long("--since", num, 0, 100000, &v) < 0)
                        return -EINVAL;
                t = time(NULL) - v * (text[n - 1] == 'm' ? 60 : text[n - 1] == 'h' ? 3600 : 86400);
        } else {
                log_error("--since: expected YYYY-MM-DDTHH:MM:SSZ, YYYY-MM-DD or a span such as 12h, got \"%s\"", text);
                return -EINVAL;
        }
        gmtime_r(&t, &tm);
        strftime(out, 32, "%Y-%m-%dT%H:%M:%SZ", &tm);
        return 0;
}

static void human_sessions(const json_t *r) {
        const json_t *list = json_object_get(r, "sessions"), *s, *f;
        size_t i, k;
        json_array_foreach(list, i, s) {
                printf("  %-40s %-10s %lld/%lld frames%s\n", imp_client_str(s, "session"), imp_client_str(s, "state"),
                       imp_client_int(s, "frames"), imp_client_int(s, "frames_total"),
                       json_is_true(json_object_get(s, "interrupted")) ? " (interrupted)" : "");
                json_array_foreach(json_object_get(s, "faults"), k, f)
                        printf("    %s fault%s%s: %s: %s\n", imp_client_str(f, "time"),
                               *imp_client_str(f, "device") ? " on " : "", imp_client_str(f, "device"),
                               imp_client_str(f, "code"), imp_client_str(f, "message"));
                if (*imp_client_str(s, "action"))
                        printf("    -> %s\n", imp_client_str(s, "action"));
        }
}

static void human_jobs(const json_t *r) {
        const json_t *list = json_object_get(r, "jobs"), *j;
        size_t i;
        json_array_foreach(list, i, j) {
                const json_t *e = json_object_get(j, "error");
                printf("  %-40s %-8s%s%s\n", imp_client_str(j, "job"), imp_client_str(j, "state"),
                       json_is_object(e) ? " " : "", json_is_object(e) ? imp_client_str(e, "message") : "");
                if (*imp_client_str(j, "action"))
                        printf("    -> %s\n", imp_client_str(j, "action"));
        }
        json_array_foreach(json_object_get(r, "copies"), i, j)
                printf("  copy %s: verdict %s (job %s)\n", imp_client_str(j, "copy"),
                       *imp_client_str(j, "verdict") ? imp_client_str(j, "verdict") : "none",
                       imp_client_str(j, "job"));
}

static void human(const json_t *r) {
        const json_t *t = json_object_get(r, "totals");
        printf("report %s .. %s\n", imp_client_str(r, "since"), imp_client_str(r, "until"));
        printf("sessions %lld, frames %lld, faults %lld; jobs %lld done, %lld failed, %lld pending; copies %lld\n",
               imp_client_int(t, "sessions"), imp_client_int(t, "frames"), imp_client_int(t, "faults"),
               imp_client_int(t, "jobs_done"), imp_client_int(t, "jobs_failed"), imp_client_int(t, "jobs_pending"),
               imp_client_int(t, "copies"));
        printf("sessions:\n");
        human_sessions(r);
        printf("jobs and copies:\n");
        human_jobs(r);
        const json_t *h = json_object_get(r, "hooks");
        if (*imp_client_str(h, "hook"))
                printf("hook %s: %lld run, %lld failed, %lld dropped\n", imp_client_str(h, "hook"),
                       imp_client_int(h, "run"), imp_client_int(h, "failed"), imp_client_int(h, "dropped"));
        imp_client_print_attention(json_object_get(r, "attention"));
}

static int run(int argc, char **argv) {
        struct imp_client_opts o = {};
        const char *since = "24h";
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' }, { "socket", required_argument, NULL, 'S' },
                { "since", required_argument, NULL, 's' }, { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 's': since = optarg; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        if (optind < argc) {
                log_error("report: unexpected argument \"%s\"", argv[optind]);
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        char t[32];
        if (parse_since(since, t) < 0)
                return IMP_EXIT_USAGE;
        return imp_client_simple(&o, "report", json_pack("{s:s}", "since", t), human);
}

const struct imp_command imp_cmd_report = {
        .name = "report",
        .summary = "the night's sessions, faults, jobs and copies, with what needs doing",
        .run = run,
};
