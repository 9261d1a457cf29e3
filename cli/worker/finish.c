/* impasto-worker --batch DIR --finish, the step Slurm runs after every task of a batch
 * (docs/scale-out.md): checks that every copy is done; when the batch's captures are the
 * tiles of a painting (PAINTING/painting.json lists each of them as a tile's "capture", the
 * layout of `impasto sim render` and of a painting session: PAINTING/tiles/NNNN), it writes
 * DIR/painting/painting.json pointing every tile at the batch's copy of it and runs
 * `impasto mosaic DIR/painting --out DIR/mosaic` (the program beside this one); then
 * DIR/result.json with the copies and what the mosaic step did. A batch that is not a
 * painting (one capture, or sets of no painting) records "nothing to mosaic". */
#define _GNU_SOURCE
#include <errno.h>
#include <libgen.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "batch.h"
#include "job.h"
#include "json-util.h"
#include "log.h"
#include "sibling.h"
#include "worker.h"

static double mono_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* PATH's directory, `levels` up, resolved (symlinks, ..): 0, or -ENOENT. */
static int dir_up(const char *path, int levels, char out[static PATH_MAX]) {
        char buf[PATH_MAX];
        if (!realpath(path, buf))
                return -ENOENT;
        for (int i = 0; i < levels; i++) {
                char *slash = strrchr(buf, '/');
                if (!slash || slash == buf)
                        return -ENOENT;
                *slash = 0;
        }
        snprintf(out, PATH_MAX, "%s", buf);
        return 0;
}

/* The painting the batch's first capture is a tile of: the directory one or two levels up
 * holding painting.json. -ENOENT when none. */
static int painting_dir(const struct imp_batch *b, char out[static PATH_MAX]) {
        for (int up = 2; up >= 1; up--) {
                char d[PATH_MAX], pj[PATH_MAX + 16];
                if (dir_up(b->tasks[0].capture, up, d) < 0)
                        continue;
                snprintf(pj, sizeof pj, "%s/painting.json", d);
                if (access(pj, R_OK) == 0) {
                        snprintf(out, PATH_MAX, "%s", d);
                        return 0;
                }
        }
        return -ENOENT;
}

/* Points every tile of doc (painting.json of pdir) at the batch's capture and copy of it.
 * 0; -ENOENT with why set when a tile is not in the batch (or has no capture). */
static int map_tiles(const struct imp_batch *b, const char *pdir, json_t *doc, char *why, size_t why_size) {
        json_t *tiles = json_object_get(doc, "tiles");
        if (!json_is_array(tiles) || json_array_size(tiles) < 2) {
                snprintf(why, why_size, "%s/painting.json has %s", pdir,
                         json_is_array(tiles) ? "fewer than two tiles" : "no \"tiles\" array");
                return -ENOENT;
        }
        /* the tasks' captures resolved once (a painting may have hundreds of tiles) */
        char (*rt)[PATH_MAX] = calloc(b->n_tasks, PATH_MAX);
        if (!rt) {
                snprintf(why, why_size, "out of memory");
                return -ENOMEM;
        }
        for (size_t k = 0; k < b->n_tasks; k++)
                if (!realpath(b->tasks[k].capture, rt[k]))
                        rt[k][0] = 0;
        size_t i, found = 0;
        json_t *t;
        json_array_foreach(tiles, i, t) {
                const char *cap = json_string_value(json_object_get(t, "capture"));
                char p[PATH_MAX + PATH_MAX], rp[PATH_MAX];
                if (!cap)
                        continue;
                if (cap[0] == '/')
                        snprintf(p, sizeof p, "%s", cap);
                else
                        snprintf(p, sizeof p, "%s/%s", pdir, cap);
                if (!realpath(p, rp))
                        continue;
                for (size_t k = 0; k < b->n_tasks; k++)
                        if (!strcmp(rt[k], rp)) {
                                json_object_set_new(t, "capture", json_string(rp));
                                json_object_set_new(t, "copy", json_string(b->tasks[k].copy));
                                found++;
                                break;
                        }
        }
        free(rt);
        if (found < json_array_size(tiles)) {
                snprintf(why, why_size, "the batch holds %zu of the %zu tiles of the painting %s", found,
                         json_array_size(tiles), pdir);
                return -ENOENT;
        }
        return 0;
}

/* DIR/painting/: painting.json with the batch's copies, and truth/ (a link to the
 * painting's, when it has one: `impasto mosaic` then scores the copy against it). */
static int write_painting(const struct imp_batch *b, const char *pdir, const json_t *doc, char out[static PATH_MAX + 16],
                          struct imp_error *err) {
        char path[PATH_MAX + 48], truth[PATH_MAX + 16];
        snprintf(out, PATH_MAX + 16, "%s/painting", b->dir);
        int r = worker_remove_tree(out);
        if (r < 0 || (r = imp_mkdir_p(out, 0755)) < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", out, strerror(-r));
        snprintf(truth, sizeof truth, "%s/truth", pdir);
        snprintf(path, sizeof path, "%s/truth", out);
        if (access(truth, F_OK) == 0 && symlink(truth, path) < 0)
                return imp_error_set(err, -errno, "%s: cannot link to %s: %m", path, truth);
        snprintf(path, sizeof path, "%s/painting.json", out);
        return imp_json_save_atomic(path, doc, err);
}

/* `impasto mosaic PAINTING --out OUT`, its output in this step's log. 0, or -EIO with err
 * saying how it ended. */
static int run_mosaic(const char *painting, const char *out, struct imp_error *err) {
        char prog[PATH_MAX];
        int r = imp_sibling_path("impasto", prog, sizeof prog);
        if (r < 0)
                return imp_error_set(err, r, "cannot find impasto beside impasto-worker: %s", strerror(-r));
        printf("finish: %s mosaic %s --out %s\n", prog, painting, out);
        fflush(stdout);
        fflush(stderr);
        pid_t pid = fork();
        if (pid < 0)
                return imp_error_set(err, -errno, "fork: %m");
        if (pid == 0) {
                execl(prog, "impasto", "mosaic", painting, "--out", out, (char *) NULL);
                fprintf(stderr, "%s: %m\n", prog);
                _exit(127);
        }
        int st;
        while (waitpid(pid, &st, 0) < 0)
                if (errno != EINTR)
                        return imp_error_set(err, -errno, "waitpid: %m");
        if (WIFEXITED(st) && WEXITSTATUS(st) == 0)
                return 0;
        if (WIFEXITED(st))
                return imp_error_set(err, -EIO, "impasto mosaic exited with status %d (its messages are in "
                                     "logs/finish.out)", WEXITSTATUS(st));
        return imp_error_set(err, -EIO, "impasto mosaic killed by signal %d", WTERMSIG(st));
}

/* The mosaic step: a JSON object for result.json ("state" done, failed or skipped). */
static json_t *mosaic_step(const struct imp_batch *b) {
        char pdir[PATH_MAX], why[PATH_MAX + 128], painting[PATH_MAX + 16], out[PATH_MAX + 16], partial[PATH_MAX + 32];
        if (b->n_tasks < 2)
                return json_pack("{s:s, s:s}", "state", "skipped", "reason", "nothing to mosaic: one capture");
        if (painting_dir(b, pdir) < 0)
                return json_pack("{s:s, s:s}", "state", "skipped", "reason",
                                 "nothing to mosaic: the captures are not the tiles of a painting (no "
                                 "painting.json above them)");
        struct imp_error err = {};
        _cleanup_json_ json_t *doc = NULL;
        char pj[PATH_MAX + 16];
        snprintf(pj, sizeof pj, "%s/painting.json", pdir);
        if (imp_json_load(pj, &doc, &err) < 0)
                return json_pack("{s:s, s:s, s:s}", "state", "failed", "painting", pdir, "error", err.msg);
        int m = map_tiles(b, pdir, doc, why, sizeof why);
        if (m == -ENOMEM)
                return json_pack("{s:s, s:s, s:s}", "state", "failed", "painting", pdir, "error", why);
        if (m < 0)
                return json_pack("{s:s, s:s, s:s+}", "state", "skipped", "painting", pdir, "reason",
                                 "nothing to mosaic: ", why);
        double t0 = mono_s();
        snprintf(out, sizeof out, "%s/mosaic", b->dir);
        snprintf(partial, sizeof partial, "%s.partial", out);
        int r = write_painting(b, pdir, doc, painting, &err);
        if (r == 0 && (r = worker_remove_tree(partial)) < 0)
                imp_error_set(&err, r, "%s: cannot remove: %s", partial, strerror(-r));
        if (r == 0 && (r = run_mosaic(painting, partial, &err)) == 0)
                r = worker_publish(partial, out, &err);
        if (r < 0)
                return json_pack("{s:s, s:s, s:s}", "state", "failed", "painting", pdir, "error", err.msg);
        return json_pack("{s:s, s:s, s:I, s:s, s:f}", "state", "done", "painting", pdir, "tiles",
                         (json_int_t) json_array_size(json_object_get(doc, "tiles")), "copy", out, "seconds",
                         mono_s() - t0);
}

int worker_run_batch_finish(const char *dir) {
        struct imp_batch b;
        struct imp_error err = {};
        if (imp_batch_load(dir, &b, &err) < 0) {
                log_error("%s", err.msg);
                return WORKER_EXIT_BAD_JOB;
        }
        _cleanup_json_ json_t *copies = json_array();
        size_t missing = 0;
        for (size_t i = 0; i < b.n_tasks; i++) {
                bool done = imp_result_done(b.tasks[i].copy, NULL);
                missing += !done;
                json_array_append_new(copies, json_pack("{s:s, s:b}", "copy", b.tasks[i].copy, "done", done));
        }
        json_t *mosaic = missing ? json_pack("{s:s, s:s}", "state", "skipped", "reason", "not run: copies missing")
                                 : mosaic_step(&b);
        const char *ms = json_string_value(json_object_get(mosaic, "state"));
        bool mosaic_failed = ms && !strcmp(ms, "failed");
        char now[32], path[PATH_MAX + 32];
        imp_rfc3339_now(now);
        snprintf(path, sizeof path, "%s/" IMP_RESULT_FILE, dir);
        _cleanup_json_ json_t *doc = json_pack("{s:i, s:s, s:s, s:s, s:O, s:o}", "format", 1, "batch", b.id, "state",
                                               missing || mosaic_failed ? "failed" : "done", "ended", now, "copies",
                                               copies, "mosaic", mosaic);
        int r = doc ? imp_json_save_atomic(path, doc, &err) : -ENOMEM;
        if (r < 0)
                log_error("%s: %s", path, err.msg[0] ? err.msg : "out of memory");
        else if (missing)
                log_error("batch %s: %zu of %zu copies are not done", b.id, missing, b.n_tasks);
        else if (mosaic_failed)
                log_error("batch %s: the mosaic failed: %s", b.id,
                          json_string_value(json_object_get(mosaic, "error")));
        else
                printf("batch %s: all %zu copies done; mosaic: %s; %s\n", b.id, b.n_tasks,
                       json_string_value(json_object_get(mosaic, ms && !strcmp(ms, "done") ? "copy" : "reason")),
                       path);
        imp_batch_done(&b);
        return r < 0 || missing || mosaic_failed ? WORKER_EXIT_JOB_FAILED : WORKER_EXIT_DONE;
}
