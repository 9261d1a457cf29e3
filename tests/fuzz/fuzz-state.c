/* Target 6: what impastod reads back from its own state directory at start and after a crash
 * (docs/fuzzing.md). The first byte picks the reader, the rest is a set of files in parts
 * (fuzz_split), written under a fresh STATE:
 *   0  a job (daemon/jobs.c, jobs_load): parts "queue" (jobs/J.json), "claim"
 *      (jobs/J.json.running), "copy" (the copy.json whose verdict a done job shows)
 *   1  the scan queue (daemon/queue.c, queue_load): the whole input after byte 0 is queue.json
 *   2  a session (daemon/store.c, store_sessions_load): parts are files of sessions/S/
 *      (session.json, set.json, manifest.jsonl, plan.cfg, rig.json, painting.json,
 *      tiles/NNNN/manifest.jsonl, …); a part "@" holds another name for the folder S
 *   3  a Slurm batch as the daemon polls it (daemon/sched-slurm.c: imp_batch_load,
 *      imp_slurm_status): parts are files of the batch directory (batch.json, tasks/N.json,
 *      result.json, a task's copy k0/result.json, …) and "squeue", "sacct": what those
 *      commands print (stand-ins on PATH)
 *   4  a calibration (daemon/calibration.c, calibrations_load): parts are files of
 *      calibrations/1/ (calibration.json, rig.json, …) and "current" (calibrations/current)
 * Checked beyond "no crash, no leak, no UB": a refusal says why; what is loaded answers the
 * protocol (its JSON can be built: a field cut inside a UTF-8 character cannot); counters
 * hold sane values; a file that was refused is unchanged, and queue.json, when damaged, is
 * kept byte for byte under another name before anything is written over it. */
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "fuzz.h"
#include "impastod.h"
#include "job.h"
#include "json-util.h"
#include "night.h"
#include "slurm.h"

/* The one symbol of daemon/main.c the other daemon sources use; never reached from the
 * readers. */
void daemon_notify_status(struct daemon *d) {
        (void) d;
}

/* ---- files ---------------------------------------------------------------------------------- */

struct snap {
        char path[4608];
        uint8_t *data;
        size_t size;
};

#define SNAP_MAX 64

/* dir/name with its folders (at most 3 levels: fuzz_clear_scratch removes 8 under the
 * scratch directory); false for a name that would leave dir. */
static bool write_under(const char *dir, const char *name, const void *data, size_t size) {
        size_t slashes = 0;
        for (const char *c = name; *c; c++)
                slashes += *c == '/';
        if (!name[0] || name[0] == '/' || strstr(name, "..") || slashes > 3 || strlen(dir) + strlen(name) > 4000)
                return false;
        char p[4608];
        snprintf(p, sizeof p, "%.4000s/%.500s", dir, name);
        for (char *s = p + strlen(dir) + 1; (s = strchr(s, '/')); s++) {
                *s = 0;
                if (mkdir(p, 0700) < 0 && errno != EEXIST) {
                        *s = '/';
                        return false;
                }
                *s = '/';
        }
        FILE *f = fopen(p, "wb");
        if (!f)
                return false;
        bool ok = (!size || fwrite(data, 1, size, f) == size);
        return fclose(f) == 0 && ok;
}

/* Every regular file under dir (three levels), for "a reader never modifies what it reads". */
static void snap_tree(const char *dir, int depth, struct snap *s, size_t *n) {
        DIR *d = opendir(dir);
        struct dirent *de;
        while (d && (de = readdir(d)) && *n < SNAP_MAX) {
                if (!strcmp(de->d_name, ".") || !strcmp(de->d_name, ".."))
                        continue;
                char p[4608];
                snprintf(p, sizeof p, "%.4000s/%.500s", dir, de->d_name);
                struct stat st;
                if (lstat(p, &st) < 0)
                        continue;
                if (S_ISDIR(st.st_mode) && depth < 4)
                        snap_tree(p, depth + 1, s, n);
                else if (S_ISREG(st.st_mode)) {
                        snprintf(s[*n].path, sizeof s[*n].path, "%s", p);
                        s[*n].data = fuzz_read_file(p, &s[*n].size);
                        (*n)++;
                }
        }
        if (d)
                closedir(d);
}

static bool snap_same(const struct snap *s) {
        size_t n = 0;
        uint8_t *now = fuzz_read_file(s->path, &n);
        bool same = now && n == s->size && (!n || !memcmp(now, s->data, n));
        free(now);
        return same;
}

static void snap_free(struct snap *s, size_t n) {
        for (size_t i = 0; i < n; i++)
                free(s[i].data);
}

/* A fresh STATE with jobs/ and sessions/ (the daemon's store_init makes them). */
static const char *fresh_state(void) {
        fuzz_clear_scratch();
        static char state[4608];
        snprintf(state, sizeof state, "%s/state", fuzz_scratch_dir());
        struct imp_error err = {};
        FUZZ_CHECK(store_init(state, &err) == 0, "store_init: %s", err.msg);
        /* a relative path in a file (a job's copy) is read from here */
        FUZZ_CHECK(chdir(state) == 0, "chdir %s", state);
        return state;
}

static struct daemon *daemon_new(const char *state) {
        struct daemon *d = calloc(1, sizeof *d);
        d->state_dir = state;
        d->job_attempts = 3;
        d->spawn_workers = true;
        char *argv[] = { "impastod", NULL };
        FUZZ_CHECK(night_conf_load(d, 1, argv, NULL) == 0 && d->night, "night_conf_load without a file");
        return d;
}

/* `status`'s attention list and `report` (daemon/report.c) over what was loaded: every paused
 * session and every failed job has its item, and the report can be built. */
static void check_report(struct daemon *d) {
        size_t paused = 0, failed = 0, items[2] = { 0 };
        for (const struct session *s = d->sessions; s; s = s->next)
                paused += s->state == SESSION_PAUSED;
        for (const struct job *j = d->jobs; j; j = j->next)
                failed += j->state == IMP_JOB_FAILED;
        json_t *a = night_attention_json(d), *it;
        FUZZ_CHECK(a, "the attention list cannot be built");
        size_t i;
        json_array_foreach(json_object_get(a, "items"), i, it) {
                const char *kind = json_string_value(json_object_get(it, "kind"));
                items[0] += kind && !strncmp(kind, "session_", 8);
                items[1] += kind && !strcmp(kind, "job_failed");
        }
        FUZZ_CHECK(items[0] == paused && items[1] == failed, "attention: %zu of %zu paused sessions, %zu of %zu "
                   "failed jobs", items[0], paused, items[1], failed);
        json_decref(a);
        struct imp_proto_error e = {};
        json_t *r = night_report_json(d, "1970-01-01T00:00:00Z", &e);
        FUZZ_CHECK(r, "the report cannot be built: %s", e.message);
        json_decref(r);
}

static void daemon_del(struct daemon *d) {
        while (d->sessions) {
                struct session *s = d->sessions;
                d->sessions = s->next;
                session_free(s);
        }
        jobs_free_all(d);
        queue_free(d);
        night_free(d);
        free(d);
}

/* ---- 0: a job ------------------------------------------------------------------------------- */

static void check_job(const struct job *j) {
        FUZZ_CHECK(j->state < _IMP_JOB_STATE_MAX, "job %s: state %d", j->id, (int) j->state);
        FUZZ_CHECK(j->attempts >= 0, "job %s: %d attempts accepted", j->id, j->attempts);
        FUZZ_CHECK(j->max_attempts >= 1 && j->max_attempts <= DAEMON_ATTEMPTS_MAX,
                   "job %s: max_attempts %d accepted", j->id, j->max_attempts);
        FUZZ_CHECK(isfinite(j->progress) && j->progress >= 0 && j->progress <= 1, "job %s: progress %g", j->id,
                   j->progress);
        json_t *a = job_json(j, false), *b = job_json(j, true);
        FUZZ_CHECK(a && b, "job %s: its %s JSON cannot be built (a `jobs` reply, a `job` event)", j->id,
                   a ? "full" : "short");
        json_decref(a);
        json_decref(b);
}

static void fuzz_job(const uint8_t *data, size_t size) {
        const char *state = fresh_state();
        struct fuzz_part parts[8];
        size_t n = fuzz_split(data, size, parts, 8);
        char jobs[4608];
        snprintf(jobs, sizeof jobs, "%s/jobs", state);
        for (size_t i = 0; i < n; i++) {
                const char *name = !strcmp(parts[i].name, "claim") ? "J.json.running" :
                                   !strcmp(parts[i].name, "copy") ? "../out/copy.json" : "J.json";
                if (!strcmp(name, "../out/copy.json"))
                        (void) write_under(state, "out/copy.json", parts[i].data, parts[i].size);
                else
                        (void) write_under(jobs, name, parts[i].data, parts[i].size);
        }
        struct snap before[SNAP_MAX];
        size_t n_before = 0;
        snap_tree(state, 0, before, &n_before);
        struct daemon *d = daemon_new(state);
        FUZZ_CHECK(jobs_load(d) == 0, "jobs_load failed on an existing jobs/");
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "job: %s\n", d->jobs ? imp_job_state_name(d->jobs->state) : "refused");
        if (!d->jobs)   /* refused: every file as it was */
                for (size_t i = 0; i < n_before; i++)
                        FUZZ_CHECK(snap_same(&before[i]), "%s changed although the job was refused", before[i].path);
        for (const struct job *j = d->jobs; j; j = j->next)
                check_job(j);
        check_report(d);
        snap_free(before, n_before);
        daemon_del(d);
}

/* ---- 1: the scan queue ---------------------------------------------------------------------- */

/* The original bytes of a damaged queue.json, under queue.json.damaged-*. */
static bool kept_aside(const char *state, const uint8_t *data, size_t size) {
        DIR *dir = opendir(state);
        struct dirent *de;
        bool found = false;
        while (dir && !found && (de = readdir(dir)))
                if (!strncmp(de->d_name, "queue.json.damaged-", 19)) {
                        char p[4608];
                        size_t n = 0;
                        snprintf(p, sizeof p, "%s/%s", state, de->d_name);
                        uint8_t *b = fuzz_read_file(p, &n);
                        found = b && n == size && (!n || !memcmp(b, data, n));
                        free(b);
                }
        if (dir)
                closedir(dir);
        return found;
}

static void fuzz_queue(const uint8_t *data, size_t size) {
        const char *state = fresh_state();
        FUZZ_CHECK(write_under(state, "queue.json", data, size), "writing queue.json");
        struct snap q = {};
        snprintf(q.path, sizeof q.path, "%s/queue.json", state);
        q.data = fuzz_read_file(q.path, &q.size);
        struct daemon *d = daemon_new(state);
        int r = queue_load(d);
        struct night *nt = d->night;
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "queue: %d, %u entries%s%s\n", r, nt->n_queue, nt->queue_damaged[0] ? "; " : "",
                        nt->queue_damaged);
        if (r == 0)
                FUZZ_CHECK(snap_same(&q), "queue.json changed although it was read whole");
        else {
                FUZZ_CHECK(r == -EBADMSG, "queue_load: %d", r);
                FUZZ_CHECK(nt->queue_broken || kept_aside(state, data, size),
                           "a damaged queue.json was neither kept aside byte for byte nor left alone");
                FUZZ_CHECK(nt->queue_broken || nt->queue_damaged[0], "a damaged queue.json without a reason");
        }
        FUZZ_CHECK(nt->n_queue <= NIGHT_QUEUE_MAX, "%u entries queued", nt->n_queue);
        json_t *l = queue_list_json(d), *e, *f;
        size_t i, k;
        json_array_foreach(json_object_get(l, "queue"), i, e) {
                const char *id = json_string_value(json_object_get(e, "id"));
                unsigned num;
                char end;
                /* the id the next `queue add` takes is no entry's */
                FUZZ_CHECK(!id || sscanf(id, "q%u%c", &num, &end) != 1 || num < nt->queue_next_id || num >= 1000000000,
                           "entry %s while the next id is q%u", id, nt->queue_next_id);
                json_array_foreach(json_object_get(l, "queue"), k, f)
                        FUZZ_CHECK(k == i || !json_equal(json_object_get(e, "id"), json_object_get(f, "id")),
                                   "two entries with the id %s", id);
        }
        FUZZ_CHECK(l && json_array_size(json_object_get(l, "queue")) == nt->n_queue,
                   "the queue's listing shows %zu of its %u entries", json_array_size(json_object_get(l, "queue")),
                   nt->n_queue);
        json_decref(l);
        free(q.data);
        daemon_del(d);
}

/* ---- 2: a session --------------------------------------------------------------------------- */

static void check_session(const struct session *s) {
        FUZZ_CHECK(session_state_name(s->state) != NULL, "session %s: state %d", s->id, (int) s->state);
        const char *folder = strrchr(s->dir, '/');
        FUZZ_CHECK(folder && !strcmp(folder + 1, s->id), "session %s is in the folder %s", s->id, s->dir);
        json_t *a = session_summary_json(s), *b = session_show_json(s);
        FUZZ_CHECK(a && b, "session %s: its %s JSON cannot be built (`sessions`, `session.show`)", s->id,
                   a ? "show" : "summary");
        json_decref(a);
        json_decref(b);
}

static void fuzz_session(const uint8_t *data, size_t size) {
        const char *state = fresh_state();
        struct fuzz_part parts[16];
        size_t n = fuzz_split(data, size, parts, 16);
        /* a part "@" names the session's folder (any bytes but '/' and NUL), else "S" */
        char dir[4608], sname[256] = "S";
        for (size_t i = 0; i < n; i++)
                if (!strcmp(parts[i].name, "@") && parts[i].size > 0 && parts[i].size < sizeof sname &&
                    !memchr(parts[i].data, '/', parts[i].size) && !memchr(parts[i].data, 0, parts[i].size) &&
                    parts[i].data[0] != '.')
                        snprintf(sname, sizeof sname, "%.*s", (int) parts[i].size, parts[i].data);
        snprintf(dir, sizeof dir, "%s/sessions/%s", state, sname);
        FUZZ_CHECK(mkdir(dir, 0700) == 0, "mkdir %s", dir);
        for (size_t i = 0; i < n; i++)
                if (strcmp(parts[i].name, "@"))
                        (void) write_under(dir, parts[i].name[0] ? parts[i].name : "session.json", parts[i].data,
                                           parts[i].size);
        struct snap before[SNAP_MAX];
        size_t n_before = 0;
        snap_tree(state, 0, before, &n_before);
        struct daemon *d = daemon_new(state);
        int loaded = store_sessions_load(d);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "session: %d loaded%s%s\n", loaded, d->sessions && d->sessions->damaged[0] ?
                        ", damaged: " : "", d->sessions ? d->sessions->damaged : "");
        FUZZ_CHECK(loaded >= 0 && loaded <= 1, "store_sessions_load: %d", loaded);
        for (size_t i = 0; i < n_before; i++)
                FUZZ_CHECK(snap_same(&before[i]), "%s changed by reading the sessions", before[i].path);
        for (const struct session *s = d->sessions; s; s = s->next)
                check_session(s);
        check_report(d);
        snap_free(before, n_before);
        daemon_del(d);
}

/* ---- 3: a Slurm batch ---------------------------------------------------------------------- */

static void check_task(const struct imp_slurm_task *t, const char *what) {
        static const char *const states[] = { "queued", "running", "done", "failed" };
        bool known = false;
        for (size_t i = 0; i < 4; i++)
                known |= !strcmp(t->state, states[i]);
        FUZZ_CHECK(known, "%s: state \"%s\"", what, t->state);
        FUZZ_CHECK(strcmp(t->state, "failed") || t->error[0], "%s failed without a reason", what);
}

/* A line of squeue's "A|I|STATE" (sacct false) or sacct's "A_I|A_I|STATE" (true) about
 * array job a's task i. */
static bool slurm_lists(const char *out, long a, size_t i, bool sacct) {
        char want[64];
        if (sacct)
                snprintf(want, sizeof want, "%ld_%zu|%ld_%zu|", a, i, a, i);
        else
                snprintf(want, sizeof want, "%ld|%zu|", a, i);
        size_t w = strlen(want);
        for (const char *l = out; l && *l; l = strchr(l, '\n') ? strchr(l, '\n') + 1 : NULL) {
                /* a state follows, one the parser keeps (no '|', space or CR first) */
                if (!strncmp(l, want, w) && strcspn(l, "\n") > w && !strchr("| \r", l[w]))
                        return true;
        }
        return false;
}

/* The array job of task i's last submission (batch.json "submissions"), 0 when none. */
static long array_of_task(const json_t *doc, size_t i) {
        const json_t *sub, *ix;
        size_t k, m;
        long a = 0;
        json_array_foreach(json_object_get(doc, "submissions"), k, sub)
                json_array_foreach(json_object_get(sub, "tasks"), m, ix)
                        if (json_is_integer(ix) && json_integer_value(ix) == (json_int_t) i)
                                a = (long) json_integer_value(json_object_get(sub, "array"));
        return a;
}

static void write_tool(const char *bin, const char *name) {
        char p[4608];
        snprintf(p, sizeof p, "%s/%s", bin, name);
        FILE *f = fopen(p, "w");
        FUZZ_CHECK(f, "writing %s", p);
        fprintf(f, "#!/bin/sh\nexec cat \"$0.out\" 2>/dev/null\n");
        fclose(f);
        FUZZ_CHECK(chmod(p, 0700) == 0, "chmod %s", p);
        snprintf(p, sizeof p, "%s/%s.out", bin, name);
        if (access(p, F_OK) < 0)
                (void) write_under(bin, strrchr(p, '/') + 1, "", 0);
}

static void fuzz_slurm(const uint8_t *data, size_t size) {
        const char *state = fresh_state();
        struct fuzz_part parts[16];
        size_t n = fuzz_split(data, size, parts, 16);
        char dir[4608], bin[4608];
        snprintf(dir, sizeof dir, "%s/batches/B", state);
        snprintf(bin, sizeof bin, "%s/bin", state);
        FUZZ_CHECK(imp_mkdir_p(dir, 0700) == 0 && imp_mkdir_p(bin, 0700) == 0, "mkdir %s", dir);
        char *out[2] = { calloc(1, 1), calloc(1, 1) };
        for (size_t i = 0; i < n; i++) {
                int tool = !strcmp(parts[i].name, "squeue") ? 0 : !strcmp(parts[i].name, "sacct") ? 1 : -1;
                if (tool < 0) {
                        (void) write_under(dir, parts[i].name[0] ? parts[i].name : "batch.json", parts[i].data,
                                           parts[i].size);
                        continue;
                }
                char name[80];
                snprintf(name, sizeof name, "%s.out", tool ? "sacct" : "squeue");
                (void) write_under(bin, name, parts[i].data, parts[i].size);
                free(out[tool]);
                out[tool] = strndup((const char *) parts[i].data, parts[i].size);
        }
        write_tool(bin, "squeue");
        write_tool(bin, "sacct");
        static char path0[4096];
        if (!path0[0])
                snprintf(path0, sizeof path0, "%s", getenv("PATH") ? getenv("PATH") : "/usr/bin:/bin");
        char path[8800];
        snprintf(path, sizeof path, "%s:%s", bin, path0);
        setenv("PATH", path, 1);
        struct snap before[SNAP_MAX];
        size_t n_before = 0;
        snap_tree(dir, 0, before, &n_before);
        struct imp_batch b;
        struct imp_error err = {};
        int r = imp_batch_load(dir, &b, &err);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "slurm: batch %d %s\n", r, err.msg);
        if (r < 0)
                FUZZ_CHECK(err.msg[0], "batch.json refused (%d) without a message", r);
        struct imp_slurm_status st = {};
        if (r == 0 && (r = imp_slurm_status(&b, &st, &err)) == 0) {
                FUZZ_CHECK(st.n_tasks == b.n_tasks, "%zu tasks of %zu", st.n_tasks, b.n_tasks);
                for (size_t i = 0; i < st.n_tasks; i++) {
                        long a = array_of_task(b.doc, i);
                        char what[64];
                        snprintf(what, sizeof what, "task %zu", i);
                        check_task(&st.tasks[i], what);
                        if (getenv("FUZZ_VERBOSE"))
                                fprintf(stderr, "slurm: task %zu: %s (%s) %s\n", i, st.tasks[i].state,
                                        st.tasks[i].slurm_state, st.tasks[i].error);
                        /* Slurm said something about it: never "no longer listed" */
                        FUZZ_CHECK(!a || !strstr(st.tasks[i].error, "gone from Slurm") ||
                                   !(slurm_lists(out[0], a, i, false) || slurm_lists(out[1], a, i, true)),
                                   "task %zu: \"%s\" although Slurm lists %ld_%zu", i, st.tasks[i].error, a, i);
                }
                check_task(&st.finish, "the finish step");
                imp_slurm_status_done(&st);
        }
        if (r == 0)
                imp_batch_done(&b);
        for (size_t i = 0; i < n_before; i++)
                FUZZ_CHECK(snap_same(&before[i]), "%s changed by reading the batch", before[i].path);
        snap_free(before, n_before);
        free(out[0]);
        free(out[1]);
}

/* ---- 4: a calibration ------------------------------------------------------------------------ */

static void fuzz_calibration(const uint8_t *data, size_t size) {
        const char *state = fresh_state();
        struct fuzz_part parts[8];
        size_t n = fuzz_split(data, size, parts, 8);
        char dir[4608], top[4608];
        snprintf(top, sizeof top, "%s/calibrations", state);
        snprintf(dir, sizeof dir, "%.4500s/1", top);
        FUZZ_CHECK(imp_mkdir_p(dir, 0700) == 0, "mkdir %s", dir);
        for (size_t i = 0; i < n; i++)
                (void) write_under(!strcmp(parts[i].name, "current") ? top : dir,
                                   parts[i].name[0] ? parts[i].name : "calibration.json", parts[i].data, parts[i].size);
        struct snap before[SNAP_MAX];
        size_t n_before = 0;
        snap_tree(state, 0, before, &n_before);
        struct daemon *d = daemon_new(state);
        d->stopping = true;             /* nothing is started: only what is read */
        d->rigcfg = calloc(1, sizeof *d->rigcfg);       /* impastod has one before this (no devices) */
        snprintf(d->rigcfg->calibration, sizeof d->rigcfg->calibration, "%s/rig.json", state);
        (void) calibrations_load(d);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "calibration: %s\n", d->calibrations ? "loaded" : "refused");
        if (!d->calibrations)
                for (size_t i = 0; i < n_before; i++)
                        FUZZ_CHECK(snap_same(&before[i]), "%s changed although the calibration was refused",
                                   before[i].path);
        for (const struct calibration *c = d->calibrations; c; c = c->next) {
                FUZZ_CHECK(c->attempts >= 0 && c->max_attempts >= 1 && c->max_attempts <= DAEMON_ATTEMPTS_MAX,
                           "calibration %s: attempts %d of %d accepted", c->id, c->attempts, c->max_attempts);
                json_t *a = calibration_json(c, false), *b = calibration_json(c, true);
                FUZZ_CHECK(a && b, "calibration %s: its JSON cannot be built", c->id);
                FUZZ_CHECK(c->state != CALIB_FAILED || !c->error[0] || json_is_object(json_object_get(b, "error")),
                           "calibration %s failed, and its JSON lost why", c->id);
                json_decref(a);
                json_decref(b);
        }
        snap_free(before, n_before);
        calibrations_free_all(d);
        if (d->have_rig)
                imp_rig_free(&d->rig);
        rigcfg_free(d->rigcfg);
        daemon_del(d);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
        if (size < 1)
                return 0;
        static char cwd[4096];
        if (!cwd[0])
                FUZZ_CHECK(getcwd(cwd, sizeof cwd), "getcwd");
        switch (data[0] % 5) {
        case 0:
                fuzz_job(data + 1, size - 1);
                break;
        case 1:
                fuzz_queue(data + 1, size - 1);
                break;
        case 2:
                fuzz_session(data + 1, size - 1);
                break;
        case 3:
                fuzz_slurm(data + 1, size - 1);
                break;
        default:
                fuzz_calibration(data + 1, size - 1);
                break;
        }
        FUZZ_CHECK(chdir(cwd) == 0, "chdir %s", cwd);
        return 0;
}
