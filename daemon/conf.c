/* impastod.conf: the daemon's own config file (docs/daemon.md, "Config file"), read before
 * the command line, whose options override it. One group `impastod = { … }` in the config
 * format of the rig config (libconfig); an unknown field, a wrong type or a value out of
 * range stops the start with FILE:LINE: FIELD and what was expected. The top-level group
 * `slurm = { … }` next to it holds the Slurm settings of impastod.scheduler = "slurm" (the
 * group of a --scheduler-config file, read by the same reader: sched-slurm.c). */
#include <string.h>
#include <unistd.h>
#include "conf.h"
#include "impastod.h"
#include "log.h"
#include "night.h"
#include "sched-slurm.h"

static const char *night_conf_path(int argc, char **argv, const char *def, bool *required) {
        *required = false;
        for (int i = 1; i < argc; i++) {
                if (!strcmp(argv[i], "--"))
                        break;
                if (!strcmp(argv[i], "--config") && i + 1 < argc) {
                        *required = true;
                        return argv[i + 1];
                }
                if (!strncmp(argv[i], "--config=", 9)) {
                        *required = true;
                        return argv[i] + 9;
                }
        }
        return def;
}

static const char *keep(struct night *n, const char *s) {
        if (!s || n->n_owned == ARRAY_SIZE(n->owned))
                return NULL;
        char *c = strdup(s);
        if (c)
                n->owned[n->n_owned++] = c;
        return c;
}

static int conf_paths(struct daemon *d, struct imp_conf *c, config_setting_t *g, struct imp_error *err) {
        struct night *n = d->night;
        static const struct { const char *key; size_t off; } paths[] = {
                { "rig", offsetof(struct daemon, rig_config) },
                { "state_dir", offsetof(struct daemon, state_dir) },
                { "socket", offsetof(struct daemon, socket_path) },
                { "worker", offsetof(struct daemon, worker_cmd) },
                { "calibrate_cmd", offsetof(struct daemon, calibrate_cmd) },
        };
        int r;
        for (size_t i = 0; i < ARRAY_SIZE(paths); i++) {
                const char *v = NULL;
                if ((r = imp_conf_get_string(c, g, paths[i].key, false, &v, err)) < 0)
                        return r;
                if (!v)
                        continue;
                if (v[0] != '/') {
                        config_setting_t *s = config_setting_get_member(g, paths[i].key);
                        return imp_error_set(err, -EINVAL, "%s:%d: impastod.%s: expected an absolute path, got \"%s\"",
                                             imp_conf_path(c), s ? config_setting_source_line(s) : 0, paths[i].key, v);
                }
                *(const char **) ((char *) d + paths[i].off) = keep(n, v);
        }
        config_setting_t *list = NULL;
        if ((r = imp_conf_get_list(c, g, "plan_dirs", false, &list, err)) < 0)
                return r;
        for (int i = 0; list && i < config_setting_length(list); i++) {
                config_setting_t *e = config_setting_get_elem(list, (unsigned) i);
                const char *v = config_setting_get_string(e);
                if (!v || v[0] != '/' || d->n_plan_dirs == DAEMON_MAX_PLAN_DIRS)
                        return imp_error_set(err, -EINVAL, "%s:%d: impastod.plan_dirs[%d]: expected %s",
                                             imp_conf_path(c), config_setting_source_line(e), i,
                                             d->n_plan_dirs == DAEMON_MAX_PLAN_DIRS ? "at most 8 directories" :
                                             "an absolute path (a string)");
                d->plan_dirs[d->n_plan_dirs++] = keep(n, v);
        }
        return 0;
}

static int conf_apply(struct daemon *d, struct imp_conf *c, struct imp_error *err) {
        struct night *n = d->night;
        config_setting_t *g;
        int r;
        if ((r = imp_conf_get_group(c, NULL, "impastod", true, &g, err)) < 0)
                return r;
        static const char *const known[] = { "rig", "state_dir", "socket", "worker", "worker_args", "calibrate_cmd",
                                             "plan_dirs", "resume", "hook", "hook_timeout_s", "disk_low_mib",
                                             "min_free_mib", "job_attempts", "retries", "spawn_workers",
                                             "scheduler", NULL };
        config_setting_t *nested = config_setting_get_member(g, "slurm");
        if (nested)
                return imp_error_set(err, -EINVAL, "%s:%d: impastod.slurm: the slurm = { … } group goes at the top "
                                     "level of the file, next to impastod = { … }", imp_conf_path(c),
                                     config_setting_source_line(nested));
        if ((r = imp_conf_check_known(c, g, known, err)) < 0 || (r = conf_paths(d, c, g, err)) < 0)
                return r;
        static const char *const policies[] = { "manual", "interrupted", NULL };
        static const char *const schedulers[] = { "local", "slurm", NULL };
        int policy = d->auto_resume ? RESUME_INTERRUPTED : RESUME_MANUAL, sched = 0;
        long long timeout = n->hook_timeout_s, low = (long long) (n->disk_low_bytes >> 20),
                  minfree = (long long) (d->min_free_bytes >> 20), attempts = d->job_attempts, retries = d->retries;
        const char *hook = NULL, *wargs = NULL;
        if ((r = imp_conf_get_enum(c, g, "resume", false, policies, &policy, err)) < 0 ||
            (r = imp_conf_get_enum(c, g, "scheduler", false, schedulers, &sched, err)) < 0 ||
            (r = imp_conf_get_string(c, g, "hook", false, &hook, err)) < 0 ||
            (r = imp_conf_get_string(c, g, "worker_args", false, &wargs, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "hook_timeout_s", false, 1, 3600, &timeout, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "disk_low_mib", false, 0, 1LL << 40, &low, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "min_free_mib", false, 0, 1LL << 40, &minfree, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "job_attempts", false, 1, IMP_JOB_MAX_ATTEMPTS_LIMIT, &attempts, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "retries", false, 1, 10000, &retries, err)) < 0 ||
            (r = imp_conf_get_bool(c, g, "spawn_workers", false, &d->spawn_workers, err)) < 0)
                return r;
        if (hook && hook[0] && hook[0] != '/') {
                config_setting_t *s = config_setting_get_member(g, "hook");
                return imp_error_set(err, -EINVAL, "%s:%d: impastod.hook: expected the absolute path of an "
                                     "executable (run as HOOK EVENT, the event as JSON on its standard input), got \"%s\"",
                                     imp_conf_path(c), s ? config_setting_source_line(s) : 0, hook);
        }
        d->auto_resume = policy == RESUME_INTERRUPTED;
        free(n->hook);
        n->hook = hook && hook[0] ? strdup(hook) : NULL;
        free(n->scheduler);
        n->scheduler = strdup(schedulers[sched]);
        n->hook_timeout_s = (unsigned) timeout;
        n->disk_low_bytes = (uint64_t) low << 20;
        d->min_free_bytes = (uint64_t) minfree << 20;
        d->job_attempts = (unsigned) attempts;
        d->retries = (unsigned) retries;
        if (wargs && wargs[0])
                d->worker_args = keep(n, wargs);
        return 0;
}

int night_conf_load(struct daemon *d, int argc, char **argv, const char *def) {
        bool required;
        const char *path = night_conf_path(argc, argv, def, &required);
        struct night *n = d->night = calloc(1, sizeof *d->night);
        if (!n)
                return log_error_errno(-ENOMEM, "out of memory");
        n->hook_timeout_s = NIGHT_HOOK_TIMEOUT_S;
        n->disk_low_bytes = NIGHT_DISK_LOW_DEFAULT;
        if (!path)
                return 0;
        if (!required && access(path, F_OK) < 0 && errno == ENOENT) {
                log_debug("config %s: not there, using the defaults and the command line", path);
                return 0;
        }
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        struct imp_error err = { 0 };
        int r = imp_conf_load(path, &c, &err);
        if (r >= 0)
                r = conf_apply(d, c, &err);
        if (r < 0) {
                log_error("config: %s", err.msg);
                return r;
        }
        snprintf(n->conf_path, sizeof n->conf_path, "%s", path);
        config_setting_t *slurm = NULL;
        bool want = n->scheduler && !strcmp(n->scheduler, "slurm");
        if ((want || (imp_conf_get_group(c, NULL, "slurm", false, &slurm, &err) >= 0 && slurm)) &&
            (r = sched_slurm_configure_conf(d, path, want)) < 0)
                return r;
        return 0;
}

void night_free(struct daemon *d) {
        struct night *n = d->night;
        if (!n)
                return;
        queue_free(d);
        night_hooks_free(d);
        for (unsigned i = 0; i < n->n_owned; i++)
                free(n->owned[i]);
        free(n->hook);
        free(n->scheduler);
        free(n);
        d->night = NULL;
}

#define NIGHT_TICK_US (5 * 1000000ULL)

/* The queue is also looked at every few seconds: what frees the rig is not always an event
 * (an interrupted session aborted, a calibration made current, a probe finished). */
static int night_tick(sd_event_source *src, uint64_t usec, void *userdata) {
        struct daemon *d = userdata;
        queue_kick(d);
        (void) sd_event_source_set_time_relative(src, NIGHT_TICK_US);
        return 0;
}

void night_start(struct daemon *d) {
        struct night *n = d->night;
        if (n->conf_path[0])
                log_info("config %s: resume %s, hook %s, disk low below %llu MiB, scheduler %s", n->conf_path,
                         d->auto_resume ? "interrupted" : "manual", n->hook ? n->hook : "none",
                         (unsigned long long) (n->disk_low_bytes >> 20), n->scheduler ? n->scheduler : "local");
        night_seed_jobs(d);
        night_record_interrupted(d);
        (void) queue_load(d);
        sd_event_source *tick = NULL;
        if (sd_event_add_time_relative(d->event, &tick, CLOCK_MONOTONIC, NIGHT_TICK_US, 0, night_tick, d) >= 0) {
                (void) sd_event_source_set_enabled(tick, SD_EVENT_ON);
                (void) sd_event_source_set_floating(tick, true);
                sd_event_source_unref(tick);
        }
        queue_kick(d);
}
