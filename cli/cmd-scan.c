/* `impasto scan`: capture sessions on the daemon (session.* of proto/PROTOCOL.md).
 *   scan start PLAN [--name N] [--follow | --wait]   start; --follow draws progress until done
 *   scan pause|resume|abort SESSION   resume --follow: then follow it
 *   scan follow SESSION               follow a running (or paused) session until it ends
 *   scan list [--limit N]
 *   scan show SESSION
 * --follow subscribes before starting, so no event of the new session is missed; on a
 * terminal it draws a bar (frames done/total, rate, dropped events, ETA), otherwise it
 * prints a plain progress line at most once a second; with --json it prints the events as
 * they came, one per line. Exit 0 when the session completed, 1 when it failed or was
 * aborted. */
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "client.h"
#include "commands.h"
#include "help.h"
#include "log.h"

#define BAR_WIDTH 30
#define PLAIN_INTERVAL_S 1.0

static void usage(FILE *f) {
        fprintf(f, "usage: impasto scan start PLAN [--name NAME] [--follow | --wait] [--json] [--socket PATH]\n"
                   "       impasto scan pause|resume|abort SESSION [--json] [--socket PATH]\n"
                   "       impasto scan resume SESSION --follow [--json] [--socket PATH]\n"
                   "       impasto scan follow SESSION [--json] [--socket PATH]\n"
                   "Ctrl-C while following detaches: the scan goes on in impastod (exit 130).\n"
                   "       impasto scan list [--limit N] [--json] [--socket PATH]\n"
                   "       impasto scan show SESSION [--json] [--socket PATH]\n");
}

struct follow {
        bool json, tty, quiet;
        char session[160];
        unsigned long long last_seq, dropped;
        long long frames, frames_total, faults;
        long long tile, tiles;          /* a painting's: the tile being captured, of tiles (0: none) */
        char stage[200];                /* a painting's stage operation under way ("" when none) */
        double eta_s, t0, rate_t, rate_frames, rate, last_plain;
        char state[32];
        bool done, drawn;
        char done_state[32];
};

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void draw(struct follow *f, bool final) {
        if (f->quiet || f->json)
                return;
        char eta[32];
        imp_client_fmt_duration(f->eta_s, eta, sizeof eta);
        double frac = f->frames_total > 0 ? (double) f->frames / f->frames_total : 0;
        if (f->tty) {
                int fill = (int) (BAR_WIDTH * IMP_CLAMP(frac, 0, 1));
                fprintf(stderr, "\r[%.*s%*s] %lld/%lld frames  %.1f fr/s  dropped %llu  ETA %s %-10s", fill,
                        "##############################", BAR_WIDTH - fill, "", f->frames, f->frames_total,
                        f->rate, f->dropped, eta, f->state);
                f->drawn = true;
                if (final)
                        fputc('\n', stderr);
                fflush(stderr);
                return;
        }
        double t = now_s();
        if (!final && t - f->last_plain < PLAIN_INTERVAL_S)
                return;
        f->last_plain = t;
        char tile[64] = "";
        if (f->tiles > 0)
                snprintf(tile, sizeof tile, ", tile %lld of %lld", f->tile + 1, f->tiles);
        printf("progress %s: %lld/%lld frames (%.0f%%)%s, %.1f frames/s, dropped %llu, ETA %s, %s\n", f->session,
               f->frames, f->frames_total, 100 * frac, tile, f->rate, f->dropped, eta, f->state);
        fflush(stdout);
}

/* Forget the bar before printing a line of another kind. */
static void clear_bar(struct follow *f) {
        if (f->tty && f->drawn) {
                fputc('\n', stderr);
                f->drawn = false;
        }
}

/* A painting's stage move or homing: one line when it starts (the bar or the progress lines
 * stand still meanwhile, and a move can take a minute). */
static void follow_stage(struct follow *f, const char *stage) {
        if (!strcmp(stage, f->stage))
                return;
        snprintf(f->stage, sizeof f->stage, "%s", stage);
        if (!stage[0] || f->json || f->quiet)
                return;
        clear_bar(f);
        printf("session %s: %s\n", f->session, stage);
        fflush(stdout);
}

static void on_event(void *userdata, const struct imp_proto_message *m) {
        struct follow *f = userdata;
        imp_client_count_gap(&f->last_seq, &f->dropped, m->seq);
        const char *session = json_string_value(m->session);
        /* Only one session holds the rig; before the start reply names it, take the first. */
        if (session && f->session[0] && strcmp(session, f->session))
                return;
        if (session && !f->session[0])
                snprintf(f->session, sizeof f->session, "%s", session);
        if (f->json) {
                _cleanup_free_ char *s = json_dumps(m->root, JSON_COMPACT | JSON_PRESERVE_ORDER);
                if (s)
                        puts(s);
                fflush(stdout);
        }
        const json_t *e = m->root;
        if (!strcmp(m->event, "progress")) {
                f->frames = imp_client_int(e, "frames");
                f->frames_total = imp_client_int(e, "frames_total");
                f->eta_s = imp_client_num(e, "eta_s");
                f->tile = imp_client_int(json_object_get(e, "painting"), "tile");
                f->tiles = imp_client_int(json_object_get(e, "painting"), "tiles");
                snprintf(f->state, sizeof f->state, "%s", imp_client_str(e, "state"));
                follow_stage(f, imp_client_str(json_object_get(e, "painting"), "stage"));
                double t = now_s();
                if (f->rate_t == 0) {
                        f->rate_t = t;
                        f->rate_frames = (double) f->frames;
                } else if (t - f->rate_t >= 0.5) {
                        double r = (f->frames - f->rate_frames) / (t - f->rate_t);
                        f->rate = f->rate > 0 ? 0.7 * f->rate + 0.3 * r : r;   /* smoothed */
                        f->rate_t = t;
                        f->rate_frames = (double) f->frames;
                }
                draw(f, false);
                /* paused by a fault: nothing more comes until someone resumes it */
                if (!strcmp(f->state, "paused") && f->faults > 0) {
                        f->done = true;
                        snprintf(f->done_state, sizeof f->done_state, "paused");
                        if (!f->json)
                                printf("session %s paused after a fault; continue with: impasto scan resume %s "
                                       "--follow\n", f->session, f->session);
                }
        } else if (!strcmp(m->event, "fault")) {
                f->faults++;
                if (!f->json) {
                        clear_bar(f);
                        log_warning("fault%s%s: %s: %s%s", *imp_client_str(e, "device") ? " on " : "",
                                    imp_client_str(e, "device"), imp_client_str(e, "code"),
                                    imp_client_str(e, "message"),
                                    json_is_true(json_object_get(e, "fatal")) ? " (the session stopped)" : "");
                }
        } else if (!strcmp(m->event, "done")) {
                f->done = true;
                snprintf(f->done_state, sizeof f->done_state, "%s", imp_client_str(e, "state"));
                if (json_is_integer(json_object_get(e, "frames")))
                        f->frames = imp_client_int(e, "frames");
                snprintf(f->state, sizeof f->state, "%s", f->done_state);
                draw(f, true);
                if (!f->json && !f->quiet)
                        printf("session %s %s: %lld frames in %s\n", f->session, f->done_state, f->frames,
                               imp_client_str(e, "path"));
        }
        /* frame, device, job and unknown event types: nothing to draw */
}

/* Ctrl-C while following: the scan is impastod's and goes on; say so and how to come back
 * (prepared before, written from the handler with write(2), which is async-signal-safe). */
static char detach_msg[512];

static void on_interrupt(int sig) {
        (void) !write(STDERR_FILENO, detach_msg, strlen(detach_msg));
        _exit(130);
}

static void detach_on_interrupt(const char *session) {
        snprintf(detach_msg, sizeof detach_msg,
                 "\nimpasto: detached from session %s; the scan goes on in impastod.\n"
                 "Follow it again with: impasto scan follow %s (impasto status shows it too)\n", session, session);
        struct sigaction sa = { .sa_handler = on_interrupt };
        sigemptyset(&sa.sa_mask);
        (void) sigaction(SIGINT, &sa, NULL);
        (void) sigaction(SIGTERM, &sa, NULL);
}

/* Subscribes to the session events (progress, fault, done) and notes the sequence number to
 * follow from; 0, or the exit code after saying why. */
static int subscribe_session_events(struct imp_client *c, struct follow *f) {
        _cleanup_proto_message_ struct imp_proto_message sub = {};
        struct imp_error err = {};
        json_t *args = json_pack("{s:[s,s,s]}", "events", "progress", "fault", "done");
        int r = imp_client_call(c, "subscribe", args, NULL, NULL, &sub, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!sub.ok)
                return imp_client_report_error("subscribe", &sub);
        f->last_seq = (unsigned long long) imp_client_int(sub.result, "seq");
        return 0;
}

static int follow_session(struct imp_client *c, struct follow *f) {
        struct imp_error err = {};
        detach_on_interrupt(f->session);
        while (!f->done) {
                _cleanup_proto_message_ struct imp_proto_message m = {};
                int r = imp_client_next_event(c, -1, &m, &err);
                if (r < 0) {
                        clear_bar(f);
                        log_error("%s", err.msg);
                        return imp_client_exit_for_errno(r);
                }
                if (r > 0)
                        on_event(f, &m);
        }
        return !strcmp(f->done_state, "completed") ? IMP_EXIT_OK : IMP_EXIT_FAILURE;
}

static int scan_start(const struct imp_client_opts *o, const char *plan, const char *name, bool follow,
                      bool wait) {
        /* The daemon opens the plan itself: hand it an absolute path when we can. */
        char abs[PATH_MAX];
        if (realpath(plan, abs))
                plan = abs;
        _cleanup_client_ struct imp_client *c = NULL;
        int rc = imp_client_connect_or_log(o, &c);
        if (rc)
                return rc;
        struct follow f = { .json = o->json, .tty = isatty(STDERR_FILENO), .quiet = wait && !follow,
                            .eta_s = NAN, .t0 = now_s() };
        struct imp_error err = {};
        if ((follow || wait) && (rc = subscribe_session_events(c, &f)))
                return rc;
        json_t *args = json_pack("{s:s}", "plan", plan);
        if (args && name)
                json_object_set_new(args, "name", json_string(name));
        _cleanup_proto_message_ struct imp_proto_message reply = {};
        int r = imp_client_call(c, "session.start", args, follow || wait ? on_event : NULL, &f, &reply, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!reply.ok)
                return imp_client_report_error("session.start", &reply);
        snprintf(f.session, sizeof f.session, "%s", imp_client_str(reply.result, "session"));
        if (o->json) {
                _cleanup_free_ char *s = json_dumps(reply.result, JSON_COMPACT | JSON_PRESERVE_ORDER);
                if (s)
                        puts(s);
                fflush(stdout);
        } else
                printf("session %s started, capturing into %s\n", f.session, imp_client_str(reply.result, "path"));
        if (!follow && !wait)
                return IMP_EXIT_OK;
        return follow_session(c, &f);
}

/* scan follow ID, scan resume ID --follow: subscribed before the state is read (or the
 * resume sent), so no event in between is missed. */
static int scan_follow(const struct imp_client_opts *o, const char *session, bool resume) {
        _cleanup_client_ struct imp_client *c = NULL;
        int rc = imp_client_connect_or_log(o, &c);
        if (rc)
                return rc;
        struct follow f = { .json = o->json, .tty = isatty(STDERR_FILENO), .eta_s = NAN, .t0 = now_s() };
        snprintf(f.session, sizeof f.session, "%s", session);
        struct imp_error err = {};
        _cleanup_proto_message_ struct imp_proto_message reply = {};
        if ((rc = subscribe_session_events(c, &f)))
                return rc;
        const char *cmd = resume ? "session.resume" : "session.show";
        int r = imp_client_call(c, cmd, json_pack("{s:s}", "session", session), on_event, &f, &reply, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                return imp_client_exit_for_errno(r);
        }
        if (!reply.ok)
                return imp_client_report_error(cmd, &reply);
        const char *state = imp_client_str(reply.result, "state");
        if (!f.frames)
                f.frames = imp_client_int(reply.result, "frames");
        if (!f.frames_total)
                f.frames_total = imp_client_int(reply.result, "steps");
        snprintf(f.state, sizeof f.state, "%s", state);
        if (!f.done && (!strcmp(state, "completed") || !strcmp(state, "aborted") || !strcmp(state, "failed"))) {
                if (!o->json)
                        printf("session %s %s: %lld frames in %s\n", session, state, f.frames,
                               imp_client_str(reply.result, "path"));
                return !strcmp(state, "completed") ? IMP_EXIT_OK : IMP_EXIT_FAILURE;
        }
        if (!o->json && !f.done)
                printf("session %s: %s%s, following (Ctrl-C detaches; the scan goes on)\n", session,
                       resume ? "resumed, " : "", state);
        if (!o->json && !strcmp(state, "paused") && !resume)
                printf("session %s is paused: impasto scan resume %s --follow continues it\n", session, session);
        fflush(stdout);
        return follow_session(c, &f);
}

static void human_state(const json_t *r) {
        printf("session %s: %s", imp_client_str(r, "session"), imp_client_str(r, "state"));
        if (json_object_get(r, "step"))
                printf(" at step %lld", imp_client_int(r, "step"));
        if (json_object_get(r, "frames"))
                printf(", %lld frames kept", imp_client_int(r, "frames"));
        putchar('\n');
}

static void human_list(const json_t *r) {
        const json_t *list = json_object_get(r, "sessions"), *s;
        size_t i;
        if (!json_array_size(list)) {
                printf("no sessions\n");
                return;
        }
        printf("%-40s %-20s %-10s %-20s %s\n", "SESSION", "NAME", "STATE", "STARTED", "FRAMES");
        json_array_foreach(list, i, s)
                printf("%-40s %-20s %-10s %-20s %lld\n", imp_client_str(s, "session"), imp_client_str(s, "name"),
                       imp_client_str(s, "state"), imp_client_str(s, "started"), imp_client_int(s, "frames"));
}

static void human_show(const json_t *r) {
        printf("session  %s\nname     %s\nstate    %s\nplan     %s\npath     %s\nstarted  %s\n",
               imp_client_str(r, "session"), imp_client_str(r, "name"), imp_client_str(r, "state"),
               imp_client_str(r, "plan"), imp_client_str(r, "path"), imp_client_str(r, "started"));
        if (*imp_client_str(r, "ended"))
                printf("ended    %s\n", imp_client_str(r, "ended"));
        printf("step     %lld of %lld\nframes   %lld\n", imp_client_int(r, "step"), imp_client_int(r, "steps"),
               imp_client_int(r, "frames"));
        imp_client_print_painting(json_object_get(r, "painting"));
        /* a session whose session.json was damaged, and what a resume rebuilt (docs/painting.md) */
        if (*imp_client_str(r, "damaged"))
                printf("damaged  %s\n", imp_client_str(r, "damaged"));
        if (*imp_client_str(r, "rebuilt"))
                printf("rebuilt  %s\n", imp_client_str(r, "rebuilt"));
        const json_t *faults = json_object_get(r, "faults"), *e;
        size_t i;
        json_array_foreach(faults, i, e)
                printf("fault    %s%s%s: %s\n", imp_client_str(e, "device"), *imp_client_str(e, "device") ? ": " : "",
                       imp_client_str(e, "code"), imp_client_str(e, "message"));
}

/* Says what was wrong with the words after `impasto scan`. */
static int bad_args(const char *verb, int n) {
        static const char *const verbs[] = { "start", "follow", "pause", "resume", "abort", "list", "show" };
        bool known = false;
        for (size_t i = 0; i < ARRAY_SIZE(verbs); i++)
                known = known || !strcmp(verb, verbs[i]);
        if (!verb[0])
                fprintf(stderr, "impasto scan: expected an action (one of: start, follow, pause, resume, abort, list, "
                        "show)\n");
        else if (!known)
                return imp_cli_unknown_action("scan", verb, verbs, ARRAY_SIZE(verbs));
        else if (!strcmp(verb, "list"))
                fprintf(stderr, "impasto scan list: takes no arguments besides --limit N, got %d\n", n - 1);
        else
                fprintf(stderr, "impasto scan %s: expected one %s, got %d words\n", verb,
                        strcmp(verb, "start") ? "SESSION id" : "PLAN", n - 1);
        fprintf(stderr, "Run 'impasto help scan' for the usage.\n");
        return IMP_EXIT_USAGE;
}

static int run(int argc, char **argv) {
        struct imp_client_opts o = {};
        const char *name = NULL;
        bool follow = false, wait = false;
        long limit = 0;
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' },       { "socket", required_argument, NULL, 'S' },
                { "name", required_argument, NULL, 'N' }, { "follow", no_argument, NULL, 'f' },
                { "wait", no_argument, NULL, 'w' },       { "limit", required_argument, NULL, 'n' },
                { "help", no_argument, NULL, 'h' },       {} };
        int c;
        while ((c = getopt_long(argc, argv, "fh", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'N': name = optarg; break;
                case 'f': follow = true; break;
                case 'w': wait = true; break;
                case 'n':
                        if (imp_client_parse_limit(optarg, &limit))
                                return IMP_EXIT_USAGE;
                        break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        int n = argc - optind;
        const char *verb = n > 0 ? argv[optind] : "";
        bool start = !strcmp(verb, "start");
        if (!strcmp(verb, "resume") && follow && !name && !wait && n == 2)
                return scan_follow(&o, argv[optind + 1], true);
        if (!strcmp(verb, "follow") && n == 2 && !name && !wait && !limit)
                return scan_follow(&o, argv[optind + 1], false);
        if ((name || follow || wait) && !start) {
                log_error("--name and --wait go with scan start, --follow with scan start and scan resume");
                return IMP_EXIT_USAGE;
        }
        if (limit && strcmp(verb, "list")) {
                log_error("--limit goes with scan list");
                return IMP_EXIT_USAGE;
        }
        if (start && n == 2)
                return scan_start(&o, argv[optind + 1], name, follow, wait);
        if (!strcmp(verb, "list") && n == 1) {
                json_t *args = limit ? json_pack("{s:I}", "limit", (json_int_t) limit) : NULL;
                return imp_client_simple(&o, "session.list", args, human_list);
        }
        static const char *const verbs[][2] = {
                { "pause", "session.pause" }, { "resume", "session.resume" },
                { "abort", "session.abort" }, { "show", "session.show" } };
        for (size_t i = 0; n == 2 && i < ARRAY_SIZE(verbs); i++)
                if (!strcmp(verb, verbs[i][0]))
                        return imp_client_simple(&o, verbs[i][1], json_pack("{s:s}", "session", argv[optind + 1]),
                                                 strcmp(verb, "show") ? human_state : human_show);
        return bad_args(verb, n);
}

const struct imp_command imp_cmd_scan = {
        .name = "scan",
        .summary = "capture sessions: start, follow, pause, resume, abort, list, show",
        .run = run,
};
