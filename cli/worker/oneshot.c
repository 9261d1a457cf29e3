/* impasto-worker's one-job modes, the unit a cluster engine schedules (docs/scale-out.md):
 *
 *   --capture SET --copy DIR [--args ARGS]   process SET into DIR, no queue, no daemon
 *   --batch DIR --task N                     task N of DIR/batch.json (N defaults to
 *                                            $SLURM_ARRAY_TASK_ID)
 *   --batch DIR --finish                     the step after every task (finish.c)
 *
 * Idempotent: a copy whose COPY/result.json says done for the same inputs (the fingerprint
 * of the set's manifest.jsonl and the options) is not processed again. A copy is built in
 * COPY.partial, which a new attempt deletes first, and moved to COPY only once every file
 * (result.json last) is written and fsynced: a killed attempt leaves no half-written copy
 * under COPY, and the next one starts from scratch. A lock on COPY.lock keeps two attempts
 * (a requeued task and its ghost) from building the same copy at once. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <ftw.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include "batch.h"
#include "build-kind.h"
#include "job.h"
#include "json-util.h"
#include "log.h"
#include "version.h"
#include "worker.h"

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int remove_entry(const char *path, const struct stat *st, int flag, struct FTW *ftw) {
        (void) st;
        (void) ftw;
        return (flag == FTW_DP ? rmdir(path) : unlink(path)) < 0 && errno != ENOENT ? -1 : 0;
}

/* rm -rf PATH; 0 when it is gone. */
int worker_remove_tree(const char *path) {
        struct stat st;
        if (lstat(path, &st) < 0)
                return errno == ENOENT ? 0 : negative_errno();
        return nftw(path, remove_entry, 16, FTW_DEPTH | FTW_PHYS) < 0 ? negative_errno() : 0;
}

static int fsync_entry(const char *path, const struct stat *st, int flag, struct FTW *ftw) {
        (void) st;
        (void) ftw;
        return flag == FTW_F || flag == FTW_DP ? (imp_fsync_path(path) < 0 ? -1 : 0) : 0;
}

/* Every file and directory below PATH on disk. */
static int fsync_tree(const char *path) {
        return nftw(path, fsync_entry, 16, FTW_DEPTH | FTW_PHYS) < 0 ? negative_errno() : 0;
}

/* ---- progress --------------------------------------------------------------------------- */

struct oneshot_progress {
        const char *name;
        char stage[64];
        double last, stage_delay_s;
};

static void on_progress(void *userdata, const char *stage, size_t done, size_t total) {
        struct oneshot_progress *p = userdata;
        double t = now_s();
        bool new_stage = strcmp(p->stage, stage) != 0;
        if (!new_stage && done != total && t - p->last < 1.0)
                return;
        snprintf(p->stage, sizeof p->stage, "%s", stage);
        p->last = t;
        printf("%s: %s %zu/%zu\n", p->name, stage, done, total);
        fflush(stdout);
        /* Tests only: hold each new stage so that a test can kill the job mid-run. */
        if (new_stage && p->stage_delay_s > 0) {
                struct timespec ts = { (time_t) p->stage_delay_s,
                                       (long) ((p->stage_delay_s - floor(p->stage_delay_s)) * 1e9) };
                nanosleep(&ts, NULL);
        }
}

/* Tests only: with IMPASTO_WORKER_TEST_HOLD=DIR a job that has processed its capture, before
 * its last step (the result manifest and publishing the copy), writes DIR/C.held with its pid
 * (C the copy directory's last name: copies/tile-2 → tile-2.held) and waits until
 * DIR/release exists (10 min at most), so that a test kills a job that is certainly running
 * and then lets the others finish. Always true (it only delays). */
static bool test_hold(const char *name, const char *copy) {
        const char *dir = getenv("IMPASTO_WORKER_TEST_HOLD");
        if (!dir || !*dir)
                return true;
        char held[PATH_MAX], tmp[PATH_MAX + 8], release[PATH_MAX];
        const char *base = strrchr(copy, '/');
        snprintf(held, sizeof held, "%s/%s.held", dir, base ? base + 1 : copy);
        snprintf(tmp, sizeof tmp, "%s.tmp", held);
        snprintf(release, sizeof release, "%s/release", dir);
        FILE *f = fopen(tmp, "w");
        bool ok = f && fprintf(f, "%d\n", (int) getpid()) > 0;
        ok = f && fclose(f) == 0 && ok && rename(tmp, held) == 0;
        if (!ok) {
                log_warning("%s: IMPASTO_WORKER_TEST_HOLD: cannot write %s: %m, not holding", name, held);
                return true;
        }
        printf("%s: held until %s exists (IMPASTO_WORKER_TEST_HOLD)\n", name, release);
        fflush(stdout);
        for (int i = 0; i < 12000 && access(release, F_OK) < 0; i++)
                nanosleep(&(struct timespec) { 0, 50000000 }, NULL);
        return true;
}

/* ---- the result manifest --------------------------------------------------------------- */

static json_t *files_json(const char *dir) {
        static const char *const names[] = { "heightfield.exr", "boxes.json", "rho_d.exr", "rho_s.exr", "lobe.exr",
                                              "fit-flags.exr", "copy.json" };
        json_t *a = json_array();
        for (size_t i = 0; a && i < ARRAY_SIZE(names); i++) {
                char p[PATH_MAX + 32];
                struct stat st;
                snprintf(p, sizeof p, "%s/%s", dir, names[i]);
                if (stat(p, &st) == 0)
                        json_array_append_new(a, json_pack("{s:s, s:I}", "name", names[i], "bytes",
                                                           (json_int_t) st.st_size));
        }
        return a;
}

static const char *copy_verdict(const char *dir, char *buf, size_t size) {
        char p[PATH_MAX + 32];
        snprintf(p, sizeof p, "%s/copy.json", dir);
        json_t *doc = NULL;
        struct imp_error e = {};
        buf[0] = 0;
        if (imp_json_load(p, &doc, &e) == 0) {
                const char *v = json_string_value(json_object_get(json_object_get(doc, "quality"), "verdict"));
                snprintf(buf, size, "%s", v ? v : "");
                json_decref(doc);
        }
        return buf[0] ? buf : NULL;
}

struct run_info {
        const char *capture, *copy, *args, *fingerprint;
        char started[32];
        double t0;
};

static int write_result(const struct run_info *ri, const char *dir, struct imp_error *err) {
        char ended[32], host[256] = "", verdict[32], path[PATH_MAX + 32];
        imp_rfc3339_now(ended);
        gethostname(host, sizeof host - 1);
        const char *job = getenv("SLURM_JOB_ID");
        _cleanup_json_ json_t *doc = json_pack(
                "{s:i, s:s, s:s, s:s, s:s, s:s?, s:s, s:s, s:s, s:s, s:s, s:f, s:s?, s:s?, s:o}", "format", 1, "state",
                "done", "capture", ri->capture, "copy", ri->copy, "fingerprint", ri->fingerprint, "worker_args",
                ri->args, "worker_build", imp_build_kind(), "version", imp_version(), "host", host, "started",
                ri->started, "ended", ended, "seconds", now_s() - ri->t0, "verdict",
                copy_verdict(dir, verdict, sizeof verdict), "slurm_job", job, "files", files_json(dir));
        if (!doc)
                return imp_error_set(err, -ENOMEM, "out of memory");
        snprintf(path, sizeof path, "%s/" IMP_RESULT_FILE, dir);
        return imp_json_save_atomic(path, doc, err);
}

/* COPY.partial → COPY: swapped atomically when COPY exists (an older or unfinished copy,
 * then deleted), renamed otherwise. */
int worker_publish(const char *partial, const char *copy, struct imp_error *err) {
        int r = fsync_tree(partial);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot sync: %s", partial, strerror(-r));
        if (renameat2(AT_FDCWD, partial, AT_FDCWD, copy, RENAME_EXCHANGE) == 0) {
                imp_fsync_parent_dir(copy);
                return worker_remove_tree(partial);    /* now the old copy */
        }
        if (errno != ENOENT) {
                /* a file system without RENAME_EXCHANGE: move the old copy aside first */
                char old[PATH_MAX + 16];
                snprintf(old, sizeof old, "%s.old", copy);
                if (worker_remove_tree(old) < 0 || rename(copy, old) < 0)
                        return imp_error_set(err, negative_errno(), "%s: cannot replace: %m", copy);
                (void) worker_remove_tree(old);
        }
        if (rename(partial, copy) < 0)
                return imp_error_set(err, negative_errno(), "%s: cannot rename to %s: %m", partial, copy);
        imp_fsync_parent_dir(copy);
        return 0;
}

/* Processes capture into copy unless it is done already. 0 done (now or before: *ran says
 * which), negative errno with err set. */
static int run_one(const char *name, const char *capture, const char *copy, const char *args, bool *ran,
                   struct imp_error *err) {
        *ran = false;
        struct imp_process_options o;
        imp_process_options_default(&o);
        char fp[32];
        int r = args ? worker_parse_args(args, &o, err->msg, sizeof err->msg) : 0;
        if (r < 0)
                return err->code = r;
        if ((r = imp_result_fingerprint(capture, args, fp, err)) < 0)
                return r;
        if (imp_result_done(copy, fp)) {
                printf("%s: %s is done already for these inputs (%s): nothing to do\n", name, copy, fp);
                return 0;
        }
        char lock[PATH_MAX + 16], partial[PATH_MAX + 16];
        snprintf(lock, sizeof lock, "%s.lock", copy);
        snprintf(partial, sizeof partial, "%s.partial", copy);
        char parent[PATH_MAX];
        snprintf(parent, sizeof parent, "%s", copy);
        char *slash = strrchr(parent, '/');
        if (slash && slash != parent && (*slash = 0, (r = imp_mkdir_p(parent, 0755)) < 0))
                return imp_error_set(err, r, "%s: cannot create: %s", parent, strerror(-r));
        int lock_fd = -1;
        if ((r = imp_job_lock(lock, &lock_fd)) < 0)
                return imp_error_set(err, r, "%s: %s", lock, r == -EBUSY ? "another worker is building this copy"
                                                                        : strerror(-r));
        struct run_info ri = { capture, copy, args, fp, "", now_s() };
        imp_rfc3339_now(ri.started);
        /* What a killed attempt left is never reused: from scratch. */
        if ((r = worker_remove_tree(partial)) < 0)
                imp_error_set(err, r, "%s: cannot remove the unfinished copy: %s", partial, strerror(-r));
        const char *delay = getenv("IMPASTO_WORKER_TEST_STAGE_DELAY_S");
        struct oneshot_progress ps = { .name = name, .stage_delay_s = delay ? atof(delay) : 0 };
        o.progress = on_progress;
        o.userdata = &ps;
        if (imp_build_is_slow())
                log_warning("%s: this impasto-worker is an %s build: processing takes several times longer",
                            name, imp_build_kind());
        printf("%s: %s -> %s\n", name, capture, copy);
        fflush(stdout);
        if (r == 0 && (r = imp_process_capture(capture, partial, &o, err)) == 0 && test_hold(name, copy) &&
            (r = write_result(&ri, partial, err)) == 0)
                r = worker_publish(partial, copy, err);
        imp_job_unlock(lock, lock_fd);
        *ran = r == 0;
        return r;
}

int worker_run_capture(const char *capture, const char *copy, const char *args) {
        struct imp_error err = {};
        bool ran;
        int r = run_one("job", capture, copy, args, &ran, &err);
        if (r < 0) {
                log_error("%s: %s", capture, err.msg[0] ? err.msg : strerror(-r));
                return r == -EBUSY ? WORKER_EXIT_BAD_JOB : WORKER_EXIT_JOB_FAILED;
        }
        if (ran)
                printf("job: done, digital copy in %s\n", copy);
        return WORKER_EXIT_DONE;
}

/* ---- batches ----------------------------------------------------------------------------- */

/* tasks/<i>.json: the task's last known state, for `impasto jobs status --slurm`. */
static void task_state(const struct imp_batch *b, size_t i, const char *state, const char *error) {
        char path[PATH_MAX + 32], dir[PATH_MAX + 16], now[32], host[256] = "";
        snprintf(dir, sizeof dir, "%s/tasks", b->dir);
        (void) imp_mkdir_p(dir, 0755);
        imp_rfc3339_now(now);
        gethostname(host, sizeof host - 1);
        struct imp_error e = {};
        json_t *old = NULL;
        long long attempts = 0;
        if (imp_batch_task_file(b, i, path, sizeof path) < 0)
                return;
        if (imp_json_load(path, &old, &e) == 0)
                attempts = json_integer_value(json_object_get(old, "attempts"));
        json_decref(old);
        if (!strcmp(state, "running"))
                attempts++;
        _cleanup_json_ json_t *doc = json_pack("{s:I, s:s, s:I, s:s, s:i, s:s, s:s?, s:s?}", "task", (json_int_t) i,
                                               "state", state, "attempts", (json_int_t) attempts, "host", host,
                                               "pid", (int) getpid(), "at", now, "error", error, "slurm_job",
                                               getenv("SLURM_JOB_ID"));
        if (!doc || imp_json_save_atomic(path, doc, &e) < 0)
                log_warning("%s: %s, ignoring", path, e.msg[0] ? e.msg : "out of memory");
}

int worker_run_batch_task(const char *dir, long task) {
        struct imp_batch b;
        struct imp_error err = {};
        if (imp_batch_load(dir, &b, &err) < 0) {
                log_error("%s", err.msg);
                return WORKER_EXIT_BAD_JOB;
        }
        if (task < 0 || (size_t) task >= b.n_tasks) {
                log_error("%s/batch.json: no task %ld (it has tasks 0 to %zu)", dir, task, b.n_tasks - 1);
                imp_batch_done(&b);
                return WORKER_EXIT_BAD_JOB;
        }
        char name[64];
        snprintf(name, sizeof name, "task %ld", task);
        task_state(&b, (size_t) task, "running", NULL);
        bool ran;
        int r = run_one(name, b.tasks[task].capture, b.tasks[task].copy, b.worker_args, &ran, &err);
        if (r < 0) {
                log_error("%s: %s", name, err.msg[0] ? err.msg : strerror(-r));
                task_state(&b, (size_t) task, "failed", err.msg[0] ? err.msg : strerror(-r));
        } else {
                task_state(&b, (size_t) task, "done", NULL);
                printf("%s: done, digital copy in %s\n", name, b.tasks[task].copy);
        }
        imp_batch_done(&b);
        return r < 0 ? WORKER_EXIT_JOB_FAILED : WORKER_EXIT_DONE;
}
