/* What happens to the events the daemon broadcasts, besides the clients: faults, the end of
 * a session and the end of a job are written, with a timestamp, into the session's
 * session.log (the journal has them from the module that caused them), and handed to the
 * operator's hook (impastod.conf `hook`), run as `HOOK EVENT` with the event as one JSON
 * object on its standard input. A hook never holds the loop: it is a child in its own
 * process group, its input is written into a non-blocking pipe at once (events are far
 * smaller than a pipe's buffer), it is killed after hook_timeout_s, at most
 * NIGHT_HOOKS_RUNNING_MAX run at a time and the rest wait in a bounded list. */
#define _GNU_SOURCE 1
#include <fcntl.h>
#include <signal.h>
#include <stdarg.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "night.h"

struct hook_run {
        struct hook_run *next;
        struct daemon *d;
        pid_t pid;
        char event[32];
        sd_event_source *child, *timer;
        bool killed;
};

void night_session_log(struct daemon *d, const char *session, const char *fmt, ...) {
        if (!session || !session[0] || strchr(session, '/') || session[0] == '.')
                return;
        char line[2048], ts[32];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(line, sizeof line, fmt, ap);
        va_end(ap);
        rfc3339_now(ts);
        char p[PATH_MAX + 200];
        snprintf(p, sizeof p, "%s/sessions/%s/session.log", d->state_dir, session);
        int fd = open(p, O_WRONLY | O_APPEND | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0640);
        if (fd < 0) {
                log_warning("session %s: writing %s: %m, ignoring", session, p);
                return;
        }
        /* one write per line: lines of concurrent writers never interleave (O_APPEND) */
        char buf[2200];
        int n = snprintf(buf, sizeof buf, "%s %s\n", ts, line);
        if (write(fd, buf, (size_t) IMP_MIN(n, (int) sizeof buf - 1)) < 0)
                log_warning("session %s: writing %s: %m, ignoring", session, p);
        close(fd);
}

static const char *str(const json_t *o, const char *k) {
        const char *s = json_string_value(json_object_get(o, k));
        return s ? s : "";
}

static void hook_start_pending(struct daemon *d);

static void hook_free(struct hook_run *h) {
        struct night *n = h->d->night;
        for (struct hook_run **p = &n->hooks; *p; p = &(*p)->next)
                if (*p == h) {
                        *p = h->next;
                        n->n_hooks--;
                        break;
                }
        sd_event_source_disable_unref(h->child);
        sd_event_source_disable_unref(h->timer);
        free(h);
}

static int hook_exited(sd_event_source *src, const siginfo_t *si, void *userdata) {
        struct hook_run *h = userdata;
        struct daemon *d = h->d;
        struct night *n = d->night;
        if (h->killed || si->si_code != CLD_EXITED || si->si_status != 0) {
                n->hooks_failed++;
                if (h->killed)
                        log_warning("hook %s %s: killed after %u s", n->hook, h->event, n->hook_timeout_s);
                else if (si->si_code == CLD_EXITED)
                        log_warning("hook %s %s: exit status %d", n->hook, h->event, si->si_status);
                else
                        log_warning("hook %s %s: killed by signal %s", n->hook, h->event, strsignal(si->si_status));
        } else
                log_debug("hook %s %s: done", n->hook, h->event);
        hook_free(h);
        hook_start_pending(d);
        return 0;
}

static int hook_timeout(sd_event_source *src, uint64_t usec, void *userdata) {
        struct hook_run *h = userdata;
        h->killed = true;
        (void) kill(-h->pid, SIGKILL);          /* its process group: what it started too */
        return 0;
}

/* The child: its own process group (killed as one), the event on stdin, stdout to the
 * journal's stderr, nothing else of the daemon's. */
static void hook_exec(const char *hook, const char *event, int in) {
        sigset_t all;
        sigemptyset(&all);
        sigprocmask(SIG_SETMASK, &all, NULL);
        (void) setpgid(0, 0);
        if (dup2(in, STDIN_FILENO) < 0 || dup2(STDERR_FILENO, STDOUT_FILENO) < 0)
                _exit(127);
        execl(hook, hook, event, (char *) NULL);
        dprintf(STDERR_FILENO, "hook %s: %s\n", hook, strerror(errno));
        _exit(127);
}

static int hook_spawn(struct daemon *d, const char *event, const json_t *j) {
        struct night *n = d->night;
        _cleanup_free_ char *text = json_dumps(j, JSON_COMPACT | JSON_SORT_KEYS);
        if (!text)
                return -ENOMEM;
        int p[2];
        if (pipe2(p, O_CLOEXEC) < 0)
                return negative_errno();
        struct hook_run *h = calloc(1, sizeof *h);
        pid_t pid = h ? fork() : -1;
        if (pid == 0)
                hook_exec(n->hook, event, p[0]);
        int r = pid < 0 ? (h ? negative_errno() : -ENOMEM) : 0;
        close(p[0]);
        if (r < 0) {
                close(p[1]);
                free(h);
                return r;
        }
        (void) setpgid(pid, pid);       /* (both sides: no race with the timeout's kill) */
        h->d = d;
        h->pid = pid;
        snprintf(h->event, sizeof h->event, "%s", event);
        (void) fcntl(p[1], F_SETFL, O_NONBLOCK);
        size_t len = strlen(text);
        text[len] = '\n';
        ssize_t w = write(p[1], text, len + 1);
        if (w != (ssize_t) len + 1)
                log_warning("hook %s %s: %zd of %zu bytes of the event written (%s)", n->hook, event, w, len + 1,
                            w < 0 ? strerror(errno) : "the hook does not read");
        close(p[1]);
        if ((r = sd_event_add_child(d->event, &h->child, pid, WEXITED, hook_exited, h)) < 0 ||
            (r = sd_event_add_time_relative(d->event, &h->timer, CLOCK_MONOTONIC,
                                            (uint64_t) n->hook_timeout_s * 1000000ULL, 0, hook_timeout, h)) < 0) {
                (void) kill(-pid, SIGKILL);
                (void) waitpid(pid, NULL, 0);
                sd_event_source_disable_unref(h->child);
                free(h);
                return r;
        }
        h->next = n->hooks;
        n->hooks = h;
        n->n_hooks++;
        n->hooks_run++;
        return 0;
}

static void hook_start_pending(struct daemon *d) {
        struct night *n = d->night;
        while (!d->stopping && n->n_hooks < NIGHT_HOOKS_RUNNING_MAX && json_array_size(n->hooks_pending) > 0) {
                json_t *item = json_incref(json_array_get(n->hooks_pending, 0));
                json_array_remove(n->hooks_pending, 0);
                const char *event = json_string_value(json_array_get(item, 0));
                int r = hook_spawn(d, event, json_array_get(item, 1));
                if (r < 0) {
                        n->hooks_failed++;
                        log_warning("hook %s %s: %s", n->hook, event, strerror(-r));
                }
                json_decref(item);
        }
}

static void hook_queue(struct daemon *d, const char *event, json_t *j) {
        struct night *n = d->night;
        if (!n->hook) {
                json_decref(j);
                return;
        }
        if (!n->hooks_pending)
                n->hooks_pending = json_array();
        if (json_array_size(n->hooks_pending) >= NIGHT_HOOKS_PENDING_MAX) {
                n->hooks_dropped++;
                log_warning("hook %s: %d events waiting for it, dropping the oldest (%s)", n->hook,
                            NIGHT_HOOKS_PENDING_MAX, str(json_array_get(json_array_get(n->hooks_pending, 0), 1), "event"));
                json_array_remove(n->hooks_pending, 0);
        }
        json_array_append_new(n->hooks_pending, json_pack("[s,o]", event, j));
        hook_start_pending(d);
}

/* The event as the hook gets it: the broadcast's members plus "event" and "time". */
static json_t *hook_json(const char *type, const json_t *fields) {
        json_t *j = fields ? json_deep_copy(fields) : json_object();
        char ts[32];
        rfc3339_now(ts);
        json_object_set_new(j, "event", json_string(type));
        json_object_set_new(j, "time", json_string(ts));
        return j;
}

/* A job's end once per state and end time (events repeat for progress; a retried job may
 * end again): n->job_ends maps a job id to "STATE ENDED" last announced. */
static bool job_ended_now(struct daemon *d, const json_t *f) {
        struct night *n = d->night;
        const char *state = str(f, "state"), *id = str(f, "job");
        if (strcmp(state, "done") && strcmp(state, "failed"))
                return false;
        const char *ended = "";
        for (struct job *j = d->jobs; j; j = j->next)
                if (!strcmp(j->id, id))
                        ended = j->ended;
        char key[64];
        snprintf(key, sizeof key, "%s %s", state, ended);
        if (!strcmp(str(n->job_ends, id), key))
                return false;
        json_object_set_new(n->job_ends, id, json_string(key));
        return true;
}

void night_seed_jobs(struct daemon *d) {
        struct night *n = d->night;
        if (!n->job_ends)
                n->job_ends = json_object();
        for (struct job *j = d->jobs; j; j = j->next)
                if (j->state == IMP_JOB_DONE || j->state == IMP_JOB_FAILED) {
                        char key[64];
                        snprintf(key, sizeof key, "%s %s", imp_job_state_name(j->state), j->ended);
                        json_object_set_new(n->job_ends, j->id, json_string(key));
                }
}

void night_event(struct daemon *d, const char *type, const json_t *fields) {
        if (!d->night)
                return;
        const char *session = str(fields, "session");
        if (!strcmp(type, "fault")) {
                const char *dev = str(fields, "device");
                night_session_log(d, session, "fault%s%s: %s: %s%s (frame %lld)", dev[0] ? " on " : "", dev,
                                  str(fields, "code"), str(fields, "message"),
                                  json_is_true(json_object_get(fields, "fatal")) ? "; the session stopped" :
                                  "; the session is paused (impasto scan resume to continue)",
                                  (long long) json_integer_value(json_object_get(fields, "frame")));
        } else if (!strcmp(type, "done")) {
                night_session_log(d, session, "session %s: %lld frames", str(fields, "state"),
                                  (long long) json_integer_value(json_object_get(fields, "frames")));
        } else if (!strcmp(type, "job")) {
                if (!job_ended_now(d, fields))
                        return;
                const json_t *err = json_object_get(fields, "error");
                night_session_log(d, session, "job %s %s%s%s", str(fields, "job"), str(fields, "state"),
                                  json_is_object(err) ? ": " : "", json_is_object(err) ? str(err, "message") : "");
        } else
                return;
        hook_queue(d, type, hook_json(type, fields));
}

void night_record_interrupted(struct daemon *d) {
        for (struct session *s = d->sessions; s; s = s->next) {
                if (!s->interrupted || s->damaged[0])
                        continue;
                char ts[32], msg[512];
                rfc3339_now(ts);
                snprintf(msg, sizeof msg, "interrupted: impastod stopped or died while the session was running, "
                         "at frame %zu of %zu (found at start)", s->n_frames, s->frames_total);
                json_t *f = json_pack("{s:s, s:i, s:s, s:b, s:s, s:I, s:b}", "code", "interrupted", "errno", 0,
                                      "message", msg, "fatal", 0, "time", ts, "frame", (json_int_t) s->n_frames,
                                      "interrupted", 1);
                if (f && s->faults)
                        json_array_append_new(s->faults, f);
                else
                        json_decref(f);
                struct imp_error e = { 0 };
                if (store_session_save(s, &e) < 0)
                        log_warning("session %s: recording the interruption: %s", s->id, e.msg);
                log_warning("session %s: %s; %s", s->id, msg, d->auto_resume ? "resuming it" :
                            "resume it with: impasto scan resume ID (or resume = \"interrupted\" in impastod.conf)");
                night_session_log(d, s->id, "%s", msg);
                _cleanup_json_ json_t *ev = json_pack("{s:s, s:s, s:I, s:I}", "session", s->id, "message", msg,
                                                      "frames", (json_int_t) s->n_frames, "frames_total",
                                                      (json_int_t) s->frames_total);
                hook_queue(d, "interrupted", hook_json("interrupted", ev));
        }
}

void night_hooks_free(struct daemon *d) {
        struct night *n = d->night;
        /* At exit running hooks are left to finish on their own (their process group is
         * theirs); only the loop's sources go. */
        while (n->hooks)
                hook_free(n->hooks);
        json_decref(n->hooks_pending);
        n->hooks_pending = NULL;
        json_decref(n->job_ends);
        n->job_ends = NULL;
}
