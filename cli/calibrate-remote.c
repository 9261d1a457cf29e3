/* `impasto calibrate start|list|show`: calibrations run by impastod (the `calibrate`,
 * `calibration.list` and `calibration.show` commands of proto/PROTOCOL.md), dispatched from
 * cli/cmd-calibrate.c. The daemon captures the routine's plan as a session, runs the offline
 * routine on the set and keeps the result as a new calibration version.
 *   calibrate start ROUTINE [--plan FILE] [--name NAME] [--arg KEY[=VALUE]]... [--follow] [--json]
 *   calibrate list [--limit N] [--json]
 *   calibrate show VERSION [--json]
 * --follow prints the capture's progress and the calibration's states until it is done
 * (exit 0) or failed (exit 1); with --json the events as they came, one per line. */
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "calibrate-remote.h"
#include "client.h"
#include "json-util.h"
#include "log.h"

#define PROGRESS_INTERVAL_S 1.0

static void usage(FILE *f) {
        fprintf(f, "usage: impasto calibrate start camera|procam|lights|radiometric|projector-gamma [--plan FILE]\n"
                   "                        [--name NAME] [--arg KEY[=VALUE]]... [--follow] [--json] [--socket PATH]\n"
                   "       impasto calibrate list [--limit N] [--json] [--socket PATH]\n"
                   "       impasto calibrate show VERSION [--json] [--socket PATH]\n"
                   "  on the daemon: captures the routine's plan (default: its plan from the daemon's plan\n"
                   "  directories), runs the routine on the set and stores a new calibration version.\n"
                   "  --arg: a routine parameter (radiometric: camera, roi; projector-gamma: camera;\n"
                   "         lights: sphere_radius or spheres, sphere_cut, hemispheres, sessions,\n"
                   "         plane_z_mm, camera, white, dome;\n"
                   "         camera/procam: board, square, projector, sessions, reference, ...); VALUE is\n"
                   "         read as JSON when it parses (3, [1,2], [\"ID@20\"]), else as a string; KEY\n"
                   "         alone is KEY=true (hemispheres)\n"
                   "  e.g.   calibrate start lights --arg sphere_radius=10 --arg sphere_cut=7\n"
                   "         --arg 'sessions=[\"ID1@20\",\"ID2@40\"]' --arg 'dome=[30,20,0,500]'\n");
}

struct follow {
        bool json;
        char calibration[32], session[160];
        unsigned long long last_seq, dropped;
        double last_print;
        bool finished;
        int exit_code;
};

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + (double) ts.tv_nsec * 1e-9;
}

static void print_figures(const json_t *figures) {
        const char *k;
        json_t *v;
        json_object_foreach((json_t *) figures, k, v) {
                if (json_is_number(v))
                        printf("  %-32s %.6g\n", k, json_number_value(v));
                else if (json_is_string(v))
                        printf("  %-32s %s\n", k, json_string_value(v));
                else if (json_is_boolean(v))
                        printf("  %-32s %s\n", k, json_is_true(v) ? "true" : "false");
        }
}

static void on_calibration(struct follow *f, const json_t *e) {
        if (*f->calibration && strcmp(imp_client_str(e, "calibration"), f->calibration))
                return;
        const char *st = imp_client_str(e, "state");
        if (!f->json)
                printf("calibration %s (%s): %s%s%s\n", imp_client_str(e, "calibration"), imp_client_str(e, "routine"),
                       st, !strcmp(st, "done") ? ", stored in " : "", !strcmp(st, "done") ? imp_client_str(e, "path") : "");
        if (!strcmp(st, "done")) {
                if (!f->json)
                        print_figures(json_object_get(e, "figures"));
                f->finished = true;
                f->exit_code = IMP_EXIT_OK;
        } else if (!strcmp(st, "failed")) {
                const json_t *err = json_object_get(e, "error");
                log_error("calibration %s failed: %s", imp_client_str(e, "calibration"), imp_client_str(err, "message"));
                f->finished = true;
                f->exit_code = IMP_EXIT_FAILURE;
        }
}

static void on_event(void *userdata, const struct imp_proto_message *m) {
        struct follow *f = userdata;
        imp_client_count_gap(&f->last_seq, &f->dropped, m->seq);
        const json_t *e = m->root;
        const char *session = json_string_value(m->session);
        bool ours = !strcmp(m->event, "calibration") ? !*f->calibration ||
                                                       !strcmp(imp_client_str(e, "calibration"), f->calibration)
                                                     : session && (!*f->session || !strcmp(session, f->session));
        if (!ours)
                return;
        if (f->json) {
                _cleanup_free_ char *s = json_dumps(e, JSON_COMPACT | JSON_PRESERVE_ORDER);
                if (s)
                        puts(s);
                fflush(stdout);
        }
        if (!strcmp(m->event, "calibration"))
                on_calibration(f, e);
        else if (!strcmp(m->event, "progress") && !f->json) {
                double t = now_s();
                long long frames = imp_client_int(e, "frames"), total = imp_client_int(e, "frames_total");
                if (t - f->last_print >= PROGRESS_INTERVAL_S || frames == total) {
                        f->last_print = t;
                        printf("capture %s: %lld/%lld frames, ETA %.0f s, %s\n", imp_client_str(e, "session"), frames,
                               total, imp_client_num(e, "eta_s"), imp_client_str(e, "state"));
                }
        } else if (!strcmp(m->event, "fault") && !f->json)
                log_warning("fault%s%s: %s", *imp_client_str(e, "device") ? " on " : "", imp_client_str(e, "device"),
                            imp_client_str(e, "message"));
        else if (!strcmp(m->event, "done") && strcmp(imp_client_str(e, "state"), "completed")) {
                log_error("the capture session %s ended %s", session, imp_client_str(e, "state"));
                f->finished = true;
                f->exit_code = IMP_EXIT_FAILURE;
        }
        fflush(stdout);
}

/* KEY=VALUE → args[KEY]: JSON when VALUE parses as JSON, else the string; KEY alone → true. */
static int add_arg(json_t *args, const char *kv) {
        const char *eq = strchr(kv, '=');
        if (!eq && kv[0] && strlen(kv) < 64)
                return json_object_set_new(args, kv, json_true()) < 0 ? -ENOMEM : 0;
        if (!eq || eq == kv || !eq[1]) {
                log_error("--arg: expected KEY=VALUE, got '%s'", kv);
                return -EINVAL;
        }
        char key[64];
        snprintf(key, sizeof key, "%.*s", (int) IMP_MIN((size_t) (eq - kv), sizeof key - 1), kv);
        json_t *v = json_loads(eq + 1, JSON_DECODE_ANY | JSON_REJECT_DUPLICATES, NULL);
        if (!v || json_is_object(v) || json_is_null(v)) {
                json_decref(v);
                v = json_string(eq + 1);
        }
        return json_object_set_new(args, key, v) < 0 ? -ENOMEM : 0;
}

static int start(const struct imp_client_opts *o, const char *routine, const char *plan, const char *name,
                 json_t *rargs, bool follow) {
        _cleanup_json_ json_t *ra = rargs;
        char abs[PATH_MAX];
        if (plan && realpath(plan, abs))
                plan = abs;     /* the daemon opens it: an absolute path */
        _cleanup_client_ struct imp_client *c = NULL;
        int rc = imp_client_connect_or_log(o, &c);
        if (rc)
                return rc;
        struct follow f = { .json = o->json, .exit_code = IMP_EXIT_FAILURE };
        if (follow && (rc = imp_client_subscribe(c, json_pack("[s,s,s,s]", "progress", "fault", "done",
                                                              "calibration"), &f.last_seq)))
                return rc;
        json_t *args = json_pack("{s:s, s:O}", "routine", routine, "args", ra);
        if (args && plan)
                json_object_set_new(args, "plan", json_string(plan));
        if (args && name)
                json_object_set_new(args, "name", json_string(name));
        struct imp_error err = {};
        _cleanup_proto_message_ struct imp_proto_message reply = {};
        int r = imp_client_call(c, "calibrate", args, follow ? on_event : NULL, &f, &reply, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!reply.ok)
                return imp_client_report_error("calibrate", &reply);
        snprintf(f.calibration, sizeof f.calibration, "%s", imp_client_str(reply.result, "calibration"));
        snprintf(f.session, sizeof f.session, "%s", imp_client_str(reply.result, "session"));
        if (o->json) {
                _cleanup_free_ char *s = json_dumps(reply.result, JSON_COMPACT | JSON_PRESERVE_ORDER);
                if (s)
                        puts(s);
        } else
                printf("calibration %s (%s): capturing session %s with %s\n", f.calibration, routine, f.session,
                       imp_client_str(reply.result, "plan"));
        fflush(stdout);
        while (follow && !f.finished) {
                _cleanup_proto_message_ struct imp_proto_message m = {};
                r = imp_client_next_event(c, -1, &m, &err);
                if (r < 0) {
                        log_error("%s", err.msg);
                        return imp_client_exit_for_errno(r);
                }
                if (r > 0)
                        on_event(&f, &m);
        }
        return follow ? f.exit_code : IMP_EXIT_OK;
}

static void human_list(const json_t *r) {
        static const struct imp_client_column cols[] = {
                { "VERSION", "calibration", 8 }, { "ROUTINE", "routine", 12 }, { "STATE", "state", 10 },
                { "CREATED", "created", 22 }, { "SESSION", "session", 0 } };
        const json_t *cur = json_object_get(r, "current");
        printf("in force: version %lld (%s)\n", imp_client_int(cur, "version"), imp_client_str(cur, "file"));
        imp_client_print_table(json_object_get(r, "calibrations"), cols, ARRAY_SIZE(cols),
                               "no calibrations run by the daemon");
}

static void human_show(const json_t *r) {
        printf("calibration %s%s\nroutine     %s\nstate       %s\nsession     %s\ncapture     %s\nplan        %s\n"
               "created     %s\nattempts    %lld of %lld\n", imp_client_str(r, "calibration"),
               json_is_true(json_object_get(r, "current")) ? " (in force)" : "", imp_client_str(r, "routine"),
               imp_client_str(r, "state"), imp_client_str(r, "session"), imp_client_str(r, "capture"),
               imp_client_str(r, "plan"), imp_client_str(r, "created"), imp_client_int(r, "attempts"),
               imp_client_int(r, "max_attempts"));
        if (*imp_client_str(r, "rig"))
                printf("rig         %s\nreport      %s\n", imp_client_str(r, "rig"), imp_client_str(r, "report"));
        const json_t *e = json_object_get(r, "error");
        if (json_is_object(e))
                printf("error       %s\n", imp_client_str(e, "message"));
        if (json_is_object(json_object_get(r, "figures"))) {
                printf("figures\n");
                print_figures(json_object_get(r, "figures"));
        }
}

int imp_calibrate_remote_main(int argc, char **argv) {
        struct imp_client_opts o = {};
        const char *plan = NULL, *name = NULL;
        bool follow = false;
        long limit = 0;
        _cleanup_json_ json_t *rargs = json_object();
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' },       { "socket", required_argument, NULL, 'S' },
                { "plan", required_argument, NULL, 'p' }, { "name", required_argument, NULL, 'N' },
                { "arg", required_argument, NULL, 'a' },  { "follow", no_argument, NULL, 'f' },
                { "limit", required_argument, NULL, 'n' }, { "help", no_argument, NULL, 'h' }, {} };
        int ch;
        optind = 1;
        while ((ch = getopt_long(argc, argv, "fh", opts, NULL)) >= 0)
                switch (ch) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'p': plan = optarg; break;
                case 'N': name = optarg; break;
                case 'f': follow = true; break;
                case 'a':
                        if (add_arg(rargs, optarg) < 0)
                                return IMP_EXIT_USAGE;
                        break;
                case 'n':
                        if (imp_client_parse_limit(optarg, &limit))
                                return IMP_EXIT_USAGE;
                        break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        /* argv[0] is the verb (start, list, show) */
        const char *verb = argv[0];
        int n = argc - optind;
        bool is_start = !strcmp(verb, "start");
        if (!is_start && (plan || name || follow || json_object_size(rargs))) {
                log_error("--plan, --name, --arg and --follow go with calibrate start");
                return IMP_EXIT_USAGE;
        }
        if (is_start && n == 1)
                return start(&o, argv[optind], plan, name, TAKE_PTR(rargs), follow);
        if (!strcmp(verb, "list") && n == 0)
                return imp_client_simple(&o, "calibration.list",
                                         limit ? json_pack("{s:I}", "limit", (json_int_t) limit) : NULL, human_list);
        if (!strcmp(verb, "show") && n == 1 && !limit)
                return imp_client_simple(&o, "calibration.show", json_pack("{s:s}", "calibration", argv[optind]),
                                         human_show);
        usage(stderr);
        return IMP_EXIT_USAGE;
}
