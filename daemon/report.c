/* What `status` says needs the operator (each item with the command that acts on it) and
 * the `report` command: the night's sessions, frames, faults, jobs and copies with their
 * quality verdicts, from the daemon's own state (session.json, the job files, copy.json). */
#include <string.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "night.h"

static void attention_add(json_t *list, unsigned *n_more, json_t *item) {
        if (json_array_size(list) < NIGHT_ATTENTION_MAX)
                json_array_append_new(list, item);
        else {
                (*n_more)++;
                json_decref(item);
        }
}

/* The newest fault's message of a session, or "". */
static const char *last_fault(const struct session *s) {
        size_t n = json_array_size(s->faults);
        const char *m = n ? json_string_value(json_object_get(json_array_get(s->faults, n - 1), "message")) : NULL;
        return m ? m : "";
}

static void attention_sessions(struct daemon *d, json_t *list, unsigned *more) {
        for (struct session *s = d->sessions; s; s = s->next) {
                if (s->state != SESSION_PAUSED)
                        continue;
                char msg[768], action[320];
                const char *kind = s->damaged[0] ? "session_damaged" : s->interrupted ? "session_interrupted" :
                                   "session_paused";
                if (s->damaged[0])
                        snprintf(msg, sizeof msg, "session %s: its session.json is damaged (%s); %zu frames in its set",
                                 s->id, s->damaged, s->n_frames);
                else if (s->interrupted)
                        snprintf(msg, sizeof msg, "session %s was interrupted at frame %zu of %zu (impastod stopped or "
                                 "died)", s->id, s->n_frames, s->frames_total);
                else
                        snprintf(msg, sizeof msg, "session %s is paused at frame %zu of %zu%s%.500s", s->id, s->n_frames,
                                 s->frames_total, *last_fault(s) ? ": " : "", last_fault(s));
                snprintf(action, sizeof action, "impasto scan resume %s --follow (or impasto scan abort %s)", s->id,
                         s->id);
                (void) imp_utf8_sanitize(msg);  /* a fault's message cut inside a character */
                attention_add(list, more, json_pack("{s:s, s:s, s:s, s:s}", "kind", kind, "id", s->id, "message", msg,
                                                    "action", action));
        }
}

static void attention_jobs(struct daemon *d, json_t *list, unsigned *more) {
        for (struct job *j = d->jobs; j; j = j->next) {
                if (j->state != IMP_JOB_FAILED)
                        continue;
                char msg[1400], action[320];
                snprintf(msg, sizeof msg, "job %s (session %s) failed after %d attempts%s%.1024s", j->id, j->session,
                         j->attempts, j->error[0] ? ": " : "", j->error);
                snprintf(action, sizeof action, "impasto jobs retry %.128s (impasto jobs show %.128s for the error)", j->id,
                         j->id);
                (void) imp_utf8_sanitize(msg);
                attention_add(list, more, json_pack("{s:s, s:s, s:s, s:s}", "kind", "job_failed", "id", j->id,
                                                    "message", msg, "action", action));
        }
}

static void attention_disk(struct daemon *d, json_t *list, unsigned *more) {
        uint64_t free_b = 0;
        int r = store_free_bytes(d->state_dir, &free_b);
        uint64_t low = d->night->disk_low_bytes;
        if (r < 0 || free_b >= IMP_MAX(low, d->min_free_bytes))
                return;
        char msg[PATH_MAX + 200], action[PATH_MAX + 200];
        snprintf(msg, sizeof msg, "%llu MiB free on %s, below the %llu MiB of disk_low_mib%s",
                 (unsigned long long) (free_b >> 20), d->state_dir, (unsigned long long) (low >> 20),
                 free_b < d->min_free_bytes ? "; capture pauses below --min-free-bytes" : "");
        snprintf(action, sizeof action, "free space: move finished copies (%s/outputs) and processed capture sets "
                 "(%s/sessions) elsewhere; impasto report --since 7d lists them", d->state_dir, d->state_dir);
        attention_add(list, more, json_pack("{s:s, s:s, s:s, s:I}", "kind", "disk_low", "message", msg, "action",
                                            action, "free_bytes", (json_int_t) free_b));
}

json_t *night_attention_json(struct daemon *d) {
        json_t *list = json_array();
        unsigned more = 0;
        if (!d->have_rig)
                attention_add(list, &more, json_pack("{s:s, s:s, s:s}", "kind", "rig_uncalibrated", "message",
                                                     "the rig has no calibration: sessions cannot start", "action",
                                                     "impasto calibrate start ROUTINE (docs/calibration.md)"));
        attention_sessions(d, list, &more);
        attention_jobs(d, list, &more);
        attention_disk(d, list, &more);
        if (d->night)
                queue_attention(d, list);
        return json_pack("{s:o, s:i}", "items", list, "more", (int) more);
}

/* ---- report ------------------------------------------------------------------------------ */

/* "YYYY-MM-DDTHH:MM:SSZ": the only form the daemon writes, so times compare as strings. */
static bool rfc3339_valid(const char *s) {
        static const char pat[] = "dddd-dd-ddTdd:dd:ddZ";
        if (!s || strlen(s) != sizeof pat - 1)
                return false;
        for (size_t i = 0; pat[i]; i++)
                if (pat[i] == 'd' ? (s[i] < '0' || s[i] > '9') : s[i] != pat[i])
                        return false;
        return true;
}

/* In the window: started or ended at or after since, or not ended yet. */
static bool in_window(const char *since, const char *started, const char *ended) {
        return !ended || !ended[0] || strcmp(ended, since) >= 0 || (started && strcmp(started, since) >= 0);
}

static json_t *report_sessions(struct daemon *d, const char *since, long long *frames, long long *faults) {
        json_t *a = json_array();
        for (struct session *s = d->sessions; s && json_array_size(a) < 1000; s = s->next) {
                if (!in_window(since, s->started, s->ended) || (s->damaged[0] && !s->started[0]))
                        continue;
                json_t *fl = json_array(), *f;
                size_t i;
                json_array_foreach(s->faults, i, f) {
                        const char *t = json_string_value(json_object_get(f, "time"));
                        if (!t || strcmp(t, since) >= 0)
                                json_array_append(fl, f);
                }
                *frames += (long long) s->n_frames;
                *faults += (long long) json_array_size(fl);
                json_t *e = json_pack("{s:s, s:s, s:s, s:s, s:s?, s:I, s:I, s:b, s:o}", "session", s->id, "name", s->name,
                                      "state", session_state_name(s->state), "started", s->started, "ended",
                                      s->ended[0] ? s->ended : NULL, "frames", (json_int_t) s->n_frames,
                                      "frames_total", (json_int_t) s->frames_total, "interrupted", s->interrupted,
                                      "faults", fl);
                if (s->state == SESSION_PAUSED) {
                        char action[320];
                        snprintf(action, sizeof action, "impasto scan resume %s --follow (or impasto scan abort %s)",
                                 s->id, s->id);
                        json_object_set_new(e, "action", json_string(action));
                }
                json_array_append_new(a, e);
        }
        return a;
}

static json_t *report_jobs(struct daemon *d, const char *since, json_t *copies, long long counts[3]) {
        json_t *a = json_array();
        for (struct job *j = d->jobs; j && json_array_size(a) < 1000; j = j->next) {
                if (!in_window(since, j->queued, j->ended))
                        continue;
                json_t *e = job_json(j, true);
                counts[0] += j->state == IMP_JOB_DONE;
                counts[1] += j->state == IMP_JOB_FAILED;
                counts[2] += j->state == IMP_JOB_QUEUED || j->state == IMP_JOB_RUNNING;
                if (j->state == IMP_JOB_FAILED) {
                        char action[200];
                        snprintf(action, sizeof action, "impasto jobs retry %s", j->id);
                        json_object_set_new(e, "action", json_string(action));
                }
                if (j->state == IMP_JOB_DONE)
                        json_array_append_new(copies, json_pack("{s:s, s:s, s:s, s:s?}", "job", j->id, "session",
                                                                j->session, "copy", j->output, "verdict",
                                                                j->verdict[0] ? j->verdict : NULL));
                json_array_append_new(a, e);
        }
        return a;
}

json_t *night_report_json(struct daemon *d, const char *since, struct imp_proto_error *e) {
        if (!rfc3339_valid(since))
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, "args.since",
                                           "expected a UTC time as YYYY-MM-DDTHH:MM:SSZ, got \"%.64s\"", since), NULL;
        long long frames = 0, faults = 0, jc[3] = { 0 };
        json_t *copies = json_array();
        json_t *sessions = report_sessions(d, since, &frames, &faults);
        json_t *jobs = report_jobs(d, since, copies, jc);
        char now[32];
        rfc3339_now(now);
        struct night *n = d->night;
        return json_pack("{s:s, s:s, s:{s:I, s:I, s:I, s:I, s:I, s:I, s:I}, s:o, s:o, s:o, s:o, s:o, s:{s:s?, s:I, s:I, s:I}}",
                         "since", since, "until", now, "totals", "sessions", (json_int_t) json_array_size(sessions),
                         "frames", (json_int_t) frames, "faults", (json_int_t) faults, "jobs_done", (json_int_t) jc[0],
                         "jobs_failed", (json_int_t) jc[1], "jobs_pending", (json_int_t) jc[2], "copies",
                         (json_int_t) json_array_size(copies), "sessions", sessions, "jobs", jobs, "copies", copies,
                         "attention", night_attention_json(d), "queue", queue_list_json(d), "hooks", "hook",
                         n->hook, "run", (json_int_t) n->hooks_run, "failed", (json_int_t) n->hooks_failed,
                         "dropped", (json_int_t) n->hooks_dropped);
}
