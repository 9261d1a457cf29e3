/* impastod: the capture-rig daemon. One sd-event loop serves the control socket (socket
 * activation or --socket), steps the capture session, reaps the processing workers and
 * handles SIGTERM/SIGINT: lights off, projector dark, cameras stopped, state flushed,
 * exit 0. systemd is told READY, STATUS, WATCHDOG and STOPPING. */
#include <fcntl.h>
#include <getopt.h>
#include <signal.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <systemd/sd-daemon.h>
#include "impastod.h"
#include "log.h"
#include "night.h"
#include "sched-slurm.h"
#include "version.h"

#ifndef IMPASTO_DEFAULT_RIG     /* from the install prefix: cmake/install.cmake */
#define IMPASTO_DEFAULT_RIG "/etc/impasto/rig.cfg"
#define IMPASTO_DEFAULT_WORKER "/usr/bin/impasto-worker"
#define IMPASTO_DEFAULT_CLI "/usr/bin/impasto"
#define IMPASTO_DEFAULT_CONF "/etc/impasto/impastod.conf"
#endif

static void help(void) {
        printf("usage: impastod [--config FILE] [--rig CONFIG] [options]\n"
               "  --config FILE          impastod.conf, read first; options override it (default\n"
               "                         " IMPASTO_DEFAULT_CONF ", used when present)\n"
               "  --rig PATH             rig config (devices and calibration; default " IMPASTO_DEFAULT_RIG ")\n"
               "  --socket PATH          control socket when not socket-activated (default /run/impasto/control.sock)\n"
               "  --state-dir DIR        sessions and jobs (default /var/lib/impasto)\n"
               "  --worker-cmd PATH      processing worker, run as PATH JOBFILE (default " IMPASTO_DEFAULT_WORKER ")\n"
               "  --worker-args \"ARGS\"   processing options stored in each job for the worker:\n"
               "                         --holdout N, --pitch MM, --cell N, --delta FRACTION, --no-btf\n"
               "  --no-spawn-workers     leave the queue in STATE/jobs to impasto-worker@ services\n"
               "  --scheduler-config FILE  scheduler = \"slurm\" and its slurm = { … } group: jobs go to\n"
               "                         Slurm as job arrays (docs/scale-out.md); overrides impastod.conf's\n"
               "                         scheduler and slurm group; default: local workers\n"
               "  --resume               resume sessions interrupted by a stop or crash\n"
               "  --operators-all        every client is an operator (tests)\n"
               "  --max-clients N        connections at a time (default 32)\n"
               "  --max-clients-per-uid N  connections of one observer uid (default 8)\n"
               "  --reserved-slots N     of --max-clients, kept for operators and root (default 4)\n"
               "  --idle-timeout-s N     close a connection without requests or subscription after N s\n"
               "                         (default 300; 0 never)\n"
               "  --request-timeout-s N  close a connection whose request line stays unfinished N s\n"
               "                         (default 10; 0 never)\n"
               "  --client-queue-max N   bytes of replies and events queued for a client before it is\n"
               "                         closed (default 4194304)\n"
               "  --device-probe-interval-s N  an operator's `devices` reopens devices at most once per\n"
               "                         N s (default 10)\n"
               "  --retries N            attempts per capture step before pausing (default 3)\n"
               "  --job-attempts N       worker runs per job before it fails (1 to 100, default 3)\n"
               "  --device-timeout-ms N  timeout of a device connection (default 3000)\n"
               "  --min-free-bytes N     free space kept on the store; below it capture pauses (default 256 MiB)\n"
               "  --plan-dir DIR         plans named by clients must lie below DIR (repeatable; also where\n"
               "                         `calibrate` finds a routine's default plan)\n"
               "  --calibrate-cmd PATH   the offline calibration routines, run as PATH calibrate ROUTINE …\n"
               "                         (default " IMPASTO_DEFAULT_CLI ")\n"
               "  -v, --verbose          debug logging\n"
               "  --version              print the version and exit\n");
}

void daemon_notify_status(struct daemon *d) {
        struct session *s = d->active;
        if (s)
                sd_notifyf(false, "STATUS=session %s %s, frame %zu of %zu", s->id, session_state_name(s->state),
                           s->n_frames, s->frames_total);
        else
                sd_notify(false, "STATUS=idle");
}

static int on_signal(sd_event_source *src, const struct signalfd_siginfo *si, void *userdata) {
        struct daemon *d = userdata;
        log_info("signal %s: stopping", strsignal((int) si->ssi_signo));
        d->stopping = true;
        sd_notify(false, "STOPPING=1");
        return sd_event_exit(d->event, 0);
}

static int parse_u64(const char *s, uint64_t *ret) {
        char *end;
        errno = 0;
        unsigned long long v = strtoull(s, &end, 10);
        if (errno || end == s || *end || s[0] == '-')
                return -EINVAL;
        *ret = v;
        return 0;
}

/* The worker parses a job's worker_args (cli/worker/worker.c); a typo found here is found
 * before a capture, not after it. Same grammar: whitespace-separated, --opt VALUE or
 * --opt=VALUE. */
static int check_worker_args(const char *args) {
        static const struct { const char *name; bool value; } known[] = {
                { "--holdout", true }, { "--pitch", true }, { "--cell", true }, { "--delta", true },
                { "--no-btf", false },
        };
        _cleanup_free_ char *copy = strdup(args);
        if (!copy) {
                log_error("out of memory");
                return -ENOMEM;
        }
        char *save = NULL;
        for (char *w = strtok_r(copy, " \t\n", &save); w; w = strtok_r(NULL, " \t\n", &save)) {
                char *eq = strchr(w, '=');
                size_t n = eq ? (size_t) (eq - w) : strlen(w);
                size_t k;
                for (k = 0; k < ARRAY_SIZE(known); k++)
                        if (strlen(known[k].name) == n && !strncmp(w, known[k].name, n))
                                break;
                if (k == ARRAY_SIZE(known)) {
                        log_error("--worker-args: unknown worker option \"%s\" (known: --holdout N, --pitch MM, "
                                  "--cell N, --delta FRACTION, --no-btf)", w);
                        return -EINVAL;
                }
                const char *v = eq ? eq + 1 : known[k].value ? strtok_r(NULL, " \t\n", &save) : NULL;
                char *end = NULL;
                if (known[k].value && (!v || (strtod(v, &end), end == v || *end))) {
                        log_error("--worker-args: %s expects a number, got \"%s\"", known[k].name, v ? v : "");
                        return -EINVAL;
                }
                if (!known[k].value && eq) {
                        log_error("--worker-args: %s takes no value", known[k].name);
                        return -EINVAL;
                }
        }
        return 0;
}

enum { ARG_SOCKET = 256, ARG_STATE, ARG_WORKER, ARG_RESUME, ARG_OPS, ARG_MAXC, ARG_RETRIES, ARG_JOBS, ARG_MINFREE,
       ARG_RIG, ARG_DEVTIMEOUT, ARG_WORKER_ARGS, ARG_NO_SPAWN, ARG_PLAN_DIR, ARG_CALIB_CMD, ARG_PER_UID, ARG_RESERVED,
       ARG_IDLE, ARG_REQ_TIMEOUT, ARG_QUEUE_MAX, ARG_PROBE, ARG_CONFIG, ARG_SCHED };

/* The connection limits: integers 0 to 100000 (0: none, for the timeouts). */
static int parse_limit(int opt, const char *arg, struct daemon *d) {
        static const struct { int opt; const char *name; size_t off; unsigned min; } limits[] = {
                { ARG_PER_UID, "max-clients-per-uid", offsetof(struct daemon, max_clients_per_uid), 1 },
                { ARG_RESERVED, "reserved-slots", offsetof(struct daemon, reserved_slots), 0 },
                { ARG_IDLE, "idle-timeout-s", offsetof(struct daemon, idle_timeout_s), 0 },
                { ARG_REQ_TIMEOUT, "request-timeout-s", offsetof(struct daemon, request_timeout_s), 0 },
                { ARG_PROBE, "device-probe-interval-s", offsetof(struct daemon, device_probe_interval_s), 0 },
        };
        for (size_t i = 0; i < ARRAY_SIZE(limits); i++) {
                if (limits[i].opt != opt)
                        continue;
                uint64_t v;
                if (parse_u64(arg, &v) < 0 || v < limits[i].min || v > 100000) {
                        log_error("--%s: expected an integer from %u to 100000, got \"%s\"", limits[i].name,
                                  limits[i].min, arg);
                        return -EINVAL;
                }
                *(unsigned *) ((char *) d + limits[i].off) = (unsigned) v;
                return 0;
        }
        return -EINVAL;
}

static int parse_args(int argc, char **argv, struct daemon *d) {
        static const struct option opts[] = {
                { "rig", required_argument, NULL, ARG_RIG },
                { "socket", required_argument, NULL, ARG_SOCKET },
                { "state-dir", required_argument, NULL, ARG_STATE },
                { "worker-cmd", required_argument, NULL, ARG_WORKER },
                { "worker-args", required_argument, NULL, ARG_WORKER_ARGS },
                { "no-spawn-workers", no_argument, NULL, ARG_NO_SPAWN },
                { "scheduler-config", required_argument, NULL, ARG_SCHED },
                { "resume", no_argument, NULL, ARG_RESUME },
                { "operators-all", no_argument, NULL, ARG_OPS },
                { "max-clients", required_argument, NULL, ARG_MAXC },
                { "retries", required_argument, NULL, ARG_RETRIES },
                { "job-attempts", required_argument, NULL, ARG_JOBS },
                { "min-free-bytes", required_argument, NULL, ARG_MINFREE },
                { "device-timeout-ms", required_argument, NULL, ARG_DEVTIMEOUT },
                { "plan-dir", required_argument, NULL, ARG_PLAN_DIR },
                { "calibrate-cmd", required_argument, NULL, ARG_CALIB_CMD },
                { "max-clients-per-uid", required_argument, NULL, ARG_PER_UID },
                { "reserved-slots", required_argument, NULL, ARG_RESERVED },
                { "idle-timeout-s", required_argument, NULL, ARG_IDLE },
                { "request-timeout-s", required_argument, NULL, ARG_REQ_TIMEOUT },
                { "client-queue-max", required_argument, NULL, ARG_QUEUE_MAX },
                { "device-probe-interval-s", required_argument, NULL, ARG_PROBE },
                { "config", required_argument, NULL, ARG_CONFIG },      /* read before (conf.c) */
                { "verbose", no_argument, NULL, 'v' },
                { "help", no_argument, NULL, 'h' },
                { "version", no_argument, NULL, 'V' },
                {},
        };
        int c;
        uint64_t v, max;
        while ((c = getopt_long(argc, argv, "vh", opts, NULL)) >= 0) {
                switch (c) {
                case ARG_RIG: d->rig_config = optarg; break;
                case ARG_SOCKET: d->socket_path = optarg; break;
                case ARG_STATE: d->state_dir = optarg; break;
                case ARG_WORKER: d->worker_cmd = optarg; break;
                case ARG_WORKER_ARGS:
                        if (check_worker_args(optarg) < 0)
                                return -EINVAL;
                        d->worker_args = optarg;
                        break;
                case ARG_NO_SPAWN: d->spawn_workers = false; break;
                case ARG_SCHED:
                        if (sched_slurm_configure(d, optarg) < 0)
                                return -EINVAL;
                        break;
                case ARG_RESUME: d->auto_resume = true; break;
                case ARG_OPS: d->operators_all = true; break;
                case ARG_MAXC:
                case ARG_RETRIES:
                case ARG_JOBS:
                        /* a job's attempts are the worker's to count: it refuses more than its limit */
                        max = c == ARG_JOBS ? IMP_JOB_MAX_ATTEMPTS_LIMIT : DAEMON_ATTEMPTS_MAX;
                        if (parse_u64(optarg, &v) < 0 || v < 1 || v > max) {
                                log_error("--%s: expected an integer from 1 to %llu, got \"%s\"",
                                          c == ARG_MAXC ? "max-clients" : c == ARG_RETRIES ? "retries" : "job-attempts",
                                          (unsigned long long) max, optarg);
                                return -EINVAL;
                        }
                        *(c == ARG_MAXC ? &d->max_clients : c == ARG_RETRIES ? &d->retries : &d->job_attempts) =
                                (unsigned) v;
                        break;
                case ARG_MINFREE:
                        if (parse_u64(optarg, &d->min_free_bytes) < 0) {
                                log_error("--min-free-bytes: expected a byte count, got \"%s\"", optarg);
                                return -EINVAL;
                        }
                        break;
                case ARG_DEVTIMEOUT:
                        if (parse_u64(optarg, &v) < 0 || v < 10 || v > 600000) {
                                log_error("--device-timeout-ms: expected 10 to 600000, got \"%s\"", optarg);
                                return -EINVAL;
                        }
                        d->device_timeout_ms = (unsigned) v;
                        break;
                case ARG_PLAN_DIR:
                        if (d->n_plan_dirs == DAEMON_MAX_PLAN_DIRS || access(optarg, X_OK) < 0) {
                                log_error("--plan-dir %s: %s", optarg, d->n_plan_dirs == DAEMON_MAX_PLAN_DIRS ?
                                          "too many plan directories" : strerror(errno));
                                return -EINVAL;
                        }
                        d->plan_dirs[d->n_plan_dirs++] = optarg;
                        break;
                case ARG_CALIB_CMD: d->calibrate_cmd = optarg; break;
                case ARG_PER_UID:
                case ARG_RESERVED:
                case ARG_IDLE:
                case ARG_REQ_TIMEOUT:
                case ARG_PROBE:
                        if (parse_limit(c, optarg, d) < 0)
                                return -EINVAL;
                        break;
                case ARG_QUEUE_MAX:
                        if (parse_u64(optarg, &d->client_queue_max) < 0 || d->client_queue_max < 2 * IMP_PROTO_MESSAGE_MAX) {
                                log_error("--client-queue-max: expected a byte count of at least %d (two of the "
                                          "longest messages), got \"%s\"", 2 * IMP_PROTO_MESSAGE_MAX, optarg);
                                return -EINVAL;
                        }
                        break;
                case ARG_CONFIG: break;
                case 'v': imp_log_set_level(IMP_LOG_DEBUG); break;
                case 'h': help(); exit(0);
                case 'V': printf("impastod %s\n", imp_version()); exit(0);
                default: return -EINVAL;
                }
        }
        if (optind < argc) {
                log_error("unexpected argument \"%s\"", argv[optind]);
                return -EINVAL;
        }
        return 0;
}

/* One daemon per state directory and per socket: flock on STATE/impastod.lock (and on
 * SOCKET.lock when the daemon creates its socket), taken before the socket is touched, so a
 * second impastod exits saying who holds them and never unlinks the first one's socket. The
 * locks go with the process (even on SIGKILL). */
static int lock_one(const char *path, const char *what) {
        int fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0644);
        if (fd < 0)
                return log_error_errno(negative_errno(), "%s: cannot open the lock file %s: %m", what, path);
        if (flock(fd, LOCK_EX | LOCK_NB) < 0) {
                int r = negative_errno();
                char pid[32] = "";
                ssize_t n = pread(fd, pid, sizeof pid - 1, 0);
                pid[n > 0 ? n : 0] = 0;
                pid[strcspn(pid, "\n")] = 0;
                close(fd);
                if (r == -EWOULDBLOCK) {
                        log_error("%s is in use by another impastod%s%s%s (lock %s); refusing to start a second one",
                                  what, pid[0] ? " (pid " : "", pid, pid[0] ? ")" : "", path);
                        return -EBUSY;
                }
                return log_error_errno(r, "%s: locking %s: %m", what, path);
        }
        char text[32];
        int n = snprintf(text, sizeof text, "%d\n", (int) getpid());
        if (ftruncate(fd, 0) < 0 || pwrite(fd, text, (size_t) n, 0) != n)
                log_warning("%s: writing the pid into %s: %m, ignoring", what, path);
        return fd;
}

static int lock_instance(struct daemon *d, bool own_socket) {
        char p[PATH_MAX + 16];
        snprintf(p, sizeof p, "%s/impastod.lock", d->state_dir);
        char what[PATH_MAX + 32];
        snprintf(what, sizeof what, "the state directory %s", d->state_dir);
        int fd = lock_one(p, what);
        if (fd < 0)
                return fd;
        d->lock_fd = fd;
        if (!own_socket)
                return 0;
        snprintf(p, sizeof p, "%s.lock", d->socket_path);
        snprintf(what, sizeof what, "the socket %s", d->socket_path);
        fd = lock_one(p, what);
        if (fd < 0)
                return fd;
        d->socket_lock_fd = fd;
        return 0;
}

/* The socket file still the one this daemon bound (not replaced by someone else's). */
static bool socket_is_ours(const struct daemon *d) {
        struct stat st;
        return d->socket_ino != 0 && stat(d->socket_path, &st) == 0 && st.st_ino == d->socket_ino &&
               S_ISSOCK(st.st_mode);
}

#define AUTO_RESUME_ATTEMPTS 5
#define AUTO_RESUME_DELAY_US 300000ULL

/* A device may refuse the first connection after the daemon died holding it (a GigE camera
 * keeps the dead controller's privilege for a while): retry a few times from a timer. */
static int auto_resume(sd_event_source *src, uint64_t usec, void *userdata) {
        struct daemon *d = userdata;
        static unsigned attempt;
        if (d->probe) {         /* a `devices` probe holds the devices for a moment */
                (void) sd_event_add_time_relative(d->event, NULL, CLOCK_MONOTONIC, AUTO_RESUME_DELAY_US, 0,
                                                  auto_resume, d);
                return 0;
        }
        for (struct session *s = d->sessions; s; s = s->next) {
                if (!s->interrupted || s->state != SESSION_PAUSED)
                        continue;
                _cleanup_proto_error_ struct imp_proto_error e = { 0 };
                if (session_resume(s, &e) == 0)
                        break;
                if (e.code == IMP_PROTO_E_DEVICE && ++attempt < AUTO_RESUME_ATTEMPTS) {
                        log_warning("session %s: resuming: %s (attempt %u of %u), retrying", s->id, e.message,
                                    attempt, AUTO_RESUME_ATTEMPTS);
                        (void) sd_event_add_time_relative(d->event, NULL, CLOCK_MONOTONIC, AUTO_RESUME_DELAY_US, 0,
                                                          auto_resume, d);
                } else
                        log_error("session %s: resuming: %s", s->id, e.message);
                break;          /* one session holds the rig */
        }
        return 0;
}

static int defer_resume(sd_event_source *src, void *userdata) {
        return auto_resume(src, 0, userdata);
}

/* Shutdown: the rig safe first, then the state files and the clients. */
static void daemon_shutdown(struct daemon *d, bool activated) {
        sd_notify(false, "STOPPING=1");
        d->stopping = true;
        device_probe_wait(d);
        for (struct session *s = d->sessions; s; s = s->next)
                if (s == d->active || s->cs)
                        session_shutdown(s);
        rigcfg_safe_state(d->rigcfg);
        server_stop(d);
        if (!activated && d->listen_fd >= 0 && socket_is_ours(d))
                (void) unlink(d->socket_path);
        if (d->listen_fd >= 0)
                close(d->listen_fd);
        jobs_free_all(d);
        calibrations_free_all(d);
        night_free(d);
        while (d->sessions) {
                struct session *s = d->sessions;
                d->sessions = s->next;
                session_free(s);
        }
        rigcfg_free(d->rigcfg);
        if (d->have_rig)
                imp_rig_free(&d->rig);
        sd_event_unref(d->event);
        if (d->socket_lock_fd >= 0)
                close(d->socket_lock_fd);
        if (d->lock_fd >= 0)
                close(d->lock_fd);      /* (the lock files stay: unlinking them would race a new daemon) */
}

/* impastod.conf can name the scheduler, but its Slurm settings are read from the file of
 * --scheduler-config (top-level scheduler/slurm, docs/scale-out.md): never fall back to local
 * workers silently when Slurm was asked for. */
static bool scheduler_unconfigured(const struct daemon *d) {
        if (!d->night || !d->night->scheduler || strcmp(d->night->scheduler, "slurm") || (d->slurm && d->slurm->enabled))
                return false;
        log_error("%s: impastod.scheduler: \"slurm\" needs --scheduler-config FILE with the slurm = { … } "
                  "group (docs/scale-out.md); refusing to run the jobs locally instead",
                  d->night->conf_path[0] ? d->night->conf_path : "impastod.conf");
        return true;
}

int main(int argc, char **argv) {
        struct daemon d = {
                .socket_path = "/run/impasto/control.sock",
                .state_dir = "/var/lib/impasto",
                .rig_config = IMPASTO_DEFAULT_RIG,
                .worker_cmd = IMPASTO_DEFAULT_WORKER,
                .calibrate_cmd = IMPASTO_DEFAULT_CLI,
                .spawn_workers = true,
                .max_clients = DAEMON_MAX_CLIENTS,
                .max_clients_per_uid = DAEMON_MAX_CLIENTS_PER_UID,
                .reserved_slots = DAEMON_RESERVED_SLOTS,
                .idle_timeout_s = DAEMON_IDLE_TIMEOUT_S,
                .request_timeout_s = DAEMON_REQUEST_TIMEOUT_S,
                .client_queue_max = DAEMON_OUT_HARD_MAX,
                .device_probe_interval_s = DAEMON_DEVICE_PROBE_INTERVAL_S,
                .lock_fd = -1,
                .socket_lock_fd = -1,
                .retries = 3,
                .job_attempts = 3,
                .min_free_bytes = 256ull << 20,
                .listen_fd = -1,
        };
        imp_log_set_ident("impastod");
        /* impastod.conf first (conf.c), the command line overrides it */
        if (night_conf_load(&d, argc, argv, IMPASTO_DEFAULT_CONF) < 0 || parse_args(argc, argv, &d) < 0 ||
            (d.worker_args && check_worker_args(d.worker_args) < 0) || scheduler_unconfigured(&d)) {
                night_free(&d);
                sched_slurm_free(&d);
                return 2;
        }
        if (d.spawn_workers && access(d.worker_cmd, X_OK) < 0)
                log_warning("worker %s: %m: every processing job will fail; install it or pass --worker-cmd PATH "
                            "(--no-spawn-workers for impasto-worker@ services)", d.worker_cmd);

        /* Signals arrive through the loop; children and threads inherit the mask. */
        sigset_t mask;
        sigemptyset(&mask);
        sigaddset(&mask, SIGTERM);
        sigaddset(&mask, SIGINT);
        sigaddset(&mask, SIGCHLD);
        sigprocmask(SIG_BLOCK, &mask, NULL);
        signal(SIGPIPE, SIG_IGN);

        /* One daemon per state directory and socket, decided before anything is loaded or
         * the socket touched. */
        struct imp_error e = { 0 };
        int r;
        if ((r = store_init(d.state_dir, &e)) < 0) {
                log_error_errno(r, "state directory: %s", e.msg);
                return 1;
        }
        int n = sd_listen_fds(true);
        if (n > 1) {
                log_error("socket activation passed %d sockets, expected one", n);
                return 1;
        }
        if (n == 1) {
                if (sd_is_socket_unix(SD_LISTEN_FDS_START, SOCK_STREAM, 1, NULL, 0) <= 0) {
                        log_error("socket activation passed fd %d, which is not a listening UNIX stream socket",
                                  SD_LISTEN_FDS_START);
                        return 1;
                }
                d.listen_fd = SD_LISTEN_FDS_START;
        }
        if (!server_commands_check())
                return 1;
        if (lock_instance(&d, n != 1) < 0)
                return 1;
        r = rigcfg_load(d.rig_config, &d.rigcfg, &e);
        if (r < 0) {
                log_error_errno(r, "rig config: %s (--rig PATH names another one)", e.msg);
                return 1;
        }
        if (d.device_timeout_ms)
                d.rigcfg->timeout_ms = d.device_timeout_ms;
        r = imp_rig_load(d.rigcfg->calibration, &d.rig, &e);
        if (r < 0)
                log_warning_errno(r, "rig calibration: %s; sessions cannot start until it exists, ignoring", e.msg);
        else
                d.have_rig = true;
        if ((r = sd_event_default(&d.event)) < 0) {
                log_error_errno(r, "event loop: %m");
                return 1;
        }
        sd_event_now(d.event, CLOCK_MONOTONIC, &d.started_us);
        (void) sd_event_add_signal(d.event, NULL, SIGTERM, on_signal, &d);
        (void) sd_event_add_signal(d.event, NULL, SIGINT, on_signal, &d);
        (void) sd_event_set_watchdog(d.event, true);

        if ((r = server_start(&d)) < 0) {
                log_error_errno(r, "control socket %s: %m", d.socket_path);
                return 1;
        }
        int ns = store_sessions_load(&d);
        if ((r = calibrations_load(&d)) < 0)
                log_warning_errno(r, "%s/calibrations: %m; calibrations cannot be stored, ignoring", d.state_dir);
        (void) jobs_load(&d);
        (void) jobs_watch(&d);
        night_start(&d);        /* interruptions recorded, the scan queue loaded (queue.c) */
        if (d.spawn_workers)
                log_info("jobs: %s JOBFILE, one at a time%s%s", d.worker_cmd, d.worker_args ? ", worker_args " : "",
                         d.worker_args ? d.worker_args : "");
        else
                log_info("jobs: queued in %s/jobs for impasto-worker@ services", d.state_dir);
        log_info("impastod %s: rig %s, %d sessions in %s, socket %s", imp_version(), d.rigcfg->name,
                 IMP_MAX(ns, 0), d.state_dir, n == 1 ? "(activated)" : d.socket_path);
        if (d.auto_resume)
                (void) sd_event_add_defer(d.event, NULL, defer_resume, &d);
        jobs_kick(&d);
        sd_notify(false, "READY=1");
        daemon_notify_status(&d);

        r = sd_event_loop(d.event);
        if (r < 0)
                log_error_errno(r, "event loop: %m");

        daemon_shutdown(&d, n == 1);
        log_info("stopped");
        return r < 0 ? 1 : 0;
}
