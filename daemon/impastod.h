/* impastod internals shared by its modules: the daemon object (one event loop, its clients,
 * sessions and jobs), the rig config with its open devices, and the calls between modules.
 * Only the daemon includes this; nothing below daemon/ knows about sessions. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include <sys/types.h>
#include <limits.h>
#include <jansson.h>
#include <systemd/sd-event.h>
#include "camera.h"
#include "captureset.h"
#include "dome.h"
#include "error.h"
#include "job.h"
#include "slurm.h"
#include "plan.h"
#include "protocol.h"
#include "rig.h"
#include "projector.h"
#include "stage.h"

#define DAEMON_MAX_CAMERAS 4
#define DAEMON_DEVICE_TIMEOUT_MS 3000
#define DAEMON_OUT_SOFT_MAX (1024 * 1024)        /* progress/frame dropped, requests not read, beyond (PROTOCOL §6) */
#define DAEMON_OUT_HARD_MAX (4 * 1024 * 1024)    /* default --client-queue-max: connection closed beyond */

/* The connection limits of docs/security.md, with their defaults (impastod options). */
#define DAEMON_MAX_CLIENTS 32                   /* --max-clients */
#define DAEMON_ATTEMPTS_MAX 10000               /* --retries; a calibration's max_attempts; a job file's, read back
                                                   (--job-attempts: IMP_JOB_MAX_ATTEMPTS_LIMIT, the worker's) */
#define DAEMON_MAX_CLIENTS_PER_UID 8            /* --max-clients-per-uid: an observer uid's connections */
#define DAEMON_RESERVED_SLOTS 4                 /* --reserved-slots: of max-clients, for operators only */
#define DAEMON_IDLE_TIMEOUT_S 300               /* --idle-timeout-s: no request, no event subscription */
#define DAEMON_REQUEST_TIMEOUT_S 10             /* --request-timeout-s: a request line left unfinished */
#define DAEMON_DEVICE_PROBE_INTERVAL_S 10       /* --device-probe-interval-s: one `devices` probe per */

/* ---- rig config (rigcfg.c) ---------------------------------------------------------- */

enum dev_state { DEV_ABSENT, DEV_OK, DEV_BUSY, DEV_FAULT };
const char *dev_state_name(enum dev_state s);

struct dev_camera {
        char name[32], backend[32], address[128];
        struct imp_camera *cam;
        bool started;
        enum imp_pixel_format format;
        enum dev_state state;
        char detail[256];
        /* The exposure and gain last written to this camera, so that a frame with the same
         * settings skips two GenICam round trips. Cleared (valid = false) whenever the camera
         * may have lost them: a reopen, a failed step, a pause or a fault (session.c). */
        bool applied_valid;
        double applied_exposure_us, applied_gain_db;
        bool gain_unsupported;          /* the camera said -EOPNOTSUPP: not asked again */
        /* Streamed runs (session.c): false from `stream = false;` in the rig config, or once
         * the camera could not free-run (no TriggerMode, no frame free running). */
        bool stream;
        /* The serial the camera had when first opened: a reopen (after a fault) that finds
         * another camera at the address is refused, so that a set never mixes two cameras'
         * frames. Kept for the daemon's lifetime (restart impastod after swapping cameras). */
        char serial[64];
};

struct dev_dome {
        bool configured;
        char name[32], backend[32], address[128];
        struct imp_dome *dome;
        enum dev_state state;
        char detail[256];
};

struct dev_projector {
        bool configured;
        char name[32], backend[32], address[128];
        struct imp_projector *proj;
        enum dev_state state;
        char detail[256];
};

/* The gantry of whole-painting scans (docs/painting.md): `stage = { backend; address; }`. */
struct dev_stage {
        bool configured;
        char name[32], backend[32], address[128];
        struct imp_stage *stage;
        enum dev_state state;
        char detail[256];
        double sigma_mm, sigma_deg;     /* repeatability (default 0.05 mm, 0.05°): painting.json's prior */
        unsigned settle_timeout_ms;     /* a move not settled by then is stopped (TILE_SETTLE_TIMEOUT_MS) */
};

struct rigcfg {
        char name[64];
        char path[PATH_MAX];
        char calibration[PATH_MAX];     /* absolute path of rig.json */
        json_t *config;                 /* the config as JSON, for the `rig` command */
        int n_cameras;
        struct dev_camera cameras[DAEMON_MAX_CAMERAS];
        struct dev_dome dome;
        struct dev_projector projector;
        struct dev_stage stage;
        int32_t tile_pitch_um;          /* gantry step per tile on dome axis 0 (0: no gantry) */
        unsigned timeout_ms;            /* device open timeout (--device-timeout-ms) */
};

int rigcfg_load(const char *path, struct rigcfg **ret, struct imp_error *err);
void rigcfg_free(struct rigcfg *rc);
/* Open every configured device that is not open yet; 0 when all are usable, else the first
 * failure (device states and details say which). */
int rigcfg_open_devices(struct rigcfg *rc, const struct imp_rig *rig, struct imp_error *err);
/* Best effort: lights off, projector dark, cameras stopped. */
void rigcfg_safe_state(struct rigcfg *rc);
void rigcfg_close_devices(struct rigcfg *rc);
struct dev_camera *rigcfg_camera(struct rigcfg *rc, const char *name);
void rigcfg_drop_camera(struct dev_camera *cam);
json_t *rigcfg_devices_json(struct rigcfg *rc);
/* `devices` off the event loop: rigcfg_open_devices() in a thread on the rig config, while the
 * loop does not touch the devices (the rig must be free: no active session, and session.start,
 * session.resume and calibrate are refused as busy until it ends). `done` runs on the loop
 * with the devices' states. Rate-limited by the caller. -EBUSY when one is running. */
struct daemon;
typedef void (*device_probe_done_fn)(struct daemon *d, json_t *devices);
int device_probe_start(struct daemon *d, device_probe_done_fn done);
/* The devices as last known, without touching them (safe while a probe runs). */
json_t *device_probe_snapshot(struct daemon *d);
/* Waits for a running probe (shutdown). */
void device_probe_wait(struct daemon *d);

/* ---- sessions (session.c, store.c) ---------------------------------------------------- */

enum session_state {
        SESSION_IDLE,
        SESSION_PREPARING,
        SESSION_CAPTURING,              /* "running" on the wire */
        SESSION_PAUSED,
        SESSION_ABORTED,
        SESSION_FAILED,
        SESSION_COMPLETED,
        _SESSION_STATE_MAX,
};
const char *session_state_name(enum session_state s);
int session_state_from_name(const char *s);
static inline bool session_state_final(enum session_state s) {
        return s == SESSION_ABORTED || s == SESSION_FAILED || s == SESSION_COMPLETED;
}

struct daemon;
struct store_writer;

struct session {
        struct session *next;
        struct daemon *d;
        char id[128];
        char name[65];
        char plan_path[PATH_MAX];
        char dir[PATH_MAX];
        char started[32], ended[32];
        enum session_state state;
        bool interrupted;               /* found running after a restart */
        char damaged[512];              /* non-empty: session.json was unreadable (why); the
                                           session is rebuilt from its set's manifest and plan
                                           on resume, which writes session.json anew */
        char rebuilt[2048];             /* non-empty: what a resume rebuilt and why (session.json
                                           or a painting's painting.json was damaged), kept in
                                           session.json and shown by session.show */
        struct imp_rig rig;             /* from the set's rig.json once open */
        bool have_rig;
        struct imp_plan *plan;
        struct imp_captureset *cs;
        /* n_frames: durable frames (in the manifest); n_captured: frames grabbed, i.e. the
         * stored ones plus those the store writer still holds (the next plan index). */
        size_t n_frames, n_captured, frames_total;
        struct store_writer *writer;    /* owns cs while frames are queued (store.c) */
        long long bytes;
        double estimate_s;
        json_t *faults;                 /* array of fault objects */
        /* capture loop */
        sd_event_source *step_source;
        int phase;                      /* 0: set devices up, 1: expose and store */
        int attempt;
        bool pause_requested;
        uint64_t t_light_on_ns;
        uint64_t run_started_us;        /* monotonic, at (re)start of capturing, for ETA */
        size_t run_started_frames;
        int current_tile;
        int shown_pattern;              /* index into patterns[], -1 dark */
        /* A streamed run (session.c): frames of one state taken from the free-running camera. */
        struct dev_camera *stream_cam;  /* free-running now; NULL while triggered */
        size_t stream_end;              /* plan index one past the run */
        uint64_t stream_t0_ns;          /* CLOCK_REALTIME when it was switched to free running */
        uint64_t stream_last_id;        /* camera's id of the last frame taken in the run, 0 none */
        unsigned stream_bad;            /* incomplete frames in a row */
        struct {
                size_t runs, frames;    /* runs started, frames stored from them */
                size_t lost;            /* frames the stream lost (id gaps): later ones took their seq */
                size_t stale;           /* frames received before the switch, discarded */
                size_t stops;           /* runs cut short by a full store queue */
        } streamed;
        struct imp_pattern *patterns;   /* distinct patterns of the plan (projector upload) */
        unsigned n_patterns;
        /* A whole painting (session-painting.c, docs/painting.md): the plan's frames are one
         * tile's, frames_total is tiles × tile_frames, n_frames and n_captured count over the
         * painting, cs is the current tile's set (SESSION/tiles/NNNN). */
        const struct imp_tile_plan *tiles;      /* the plan's painting group; NULL: one field */
        size_t tile_frames;                     /* frames per tile (= frames_total without tiles) */
        json_t *painting;                       /* SESSION/painting.json */
        int cs_tile;                            /* the tile of cs, -1 none */
        bool at_tile;                           /* the stage stands at cs_tile, read back */
        double stage_cmd_mm[3], stage_rb_mm[3]; /* commanded and read back for cs_tile */
        /* A stage operation in progress, polled by the step timer (the loop never waits on
         * the gantry): homing before the scan, or the move to cs_tile. */
        enum { STAGE_OP_NONE, STAGE_OP_HOMING, STAGE_OP_MOVING } stage_op;
        uint64_t stage_deadline_us;             /* imp_stage_deadline_us() of the operation */
};

/* store.c: session.json and the state directory. */
int store_init(const char *state_dir, struct imp_error *err);
int store_session_save(const struct session *s, struct imp_error *err);
/* Loads every sessions/<id>/session.json into d's list (oldest first in the file system
 * order, the list is sorted newest first). */
int store_sessions_load(struct daemon *d);
int store_free_bytes(const char *path, uint64_t *ret);
uint64_t store_frame_bytes(const struct imp_rig *rig, const char *camera);
#define rfc3339_now imp_rfc3339_now      /* pipeline/model/job.h */

/* The store writer: one thread per capturing session that appends frames to the set in
 * the order queued, each through imp_captureset_add_frame() (TIFF to a temporary name,
 * fsync, rename, directory fsync, manifest line, fsync), while the event loop triggers the
 * next frame. The queue is bounded (STORE_QUEUE_MAX_FRAMES, STORE_QUEUE_MAX_BYTES): the
 * session does not capture while it is full. Results come back on the event loop, in
 * order, through `done`; after a failure the writer drops what it still held (those
 * frames were never in the manifest: capture resumes at the failed one). A SIGKILL loses
 * only queued frames, which the manifest does not list, so a restart captures them again. */
#define STORE_QUEUE_MAX_FRAMES 24
#define STORE_QUEUE_MAX_BYTES (96ULL * 1024 * 1024)
typedef void (*store_done_fn)(void *userdata, const struct imp_frame_record *rec, long long pixel_bytes,
                              int r, const char *msg);
int store_writer_new(sd_event *event, struct imp_captureset *cs, store_done_fn done, void *userdata,
                     struct store_writer **ret);
/* Queues a frame; takes img in every case. -EIO once a write failed, until the flush that
 * delivers the failure. The bound is the caller's to respect (store_writer_full). */
int store_writer_push(struct store_writer *w, const struct imp_frame_record *rec, struct imp_image *img);
bool store_writer_full(const struct store_writer *w);
/* An image the writer has stored and kept for reuse (a frame's pages already faulted in),
 * or NULL: a 1-channel u16 image of width × height, the caller's from then on. */
struct imp_image *store_writer_spare_image(struct store_writer *w, int width, int height);
/* Waits until every queued frame is stored (or dropped after a failure) and delivers the
 * results before returning; then accepts frames again. */
void store_writer_flush(struct store_writer *w);
/* Flushes, stops the thread; cs stays open (the caller's). NULL is fine. Called from a
 * `done` callback, the writer goes once that delivery returns. */
void store_writer_free(struct store_writer *w);

/* session-painting.c: sessions of a plan with a painting group, tile by tile on the gantry. */
bool painting_session_dir(const char *dir);
int painting_start(struct session *s, const char *plan_text, struct imp_proto_error *perr);
int painting_prepare_stage(struct session *s, struct imp_proto_error *perr);
/* Before frame s->n_captured: enters its tile when needed (the last tile's frames all
 * durable first: 0 = wait for the writer) and checks the stage; 1 = capture the frame;
 * PAINTING_POLL = the stage is homing or moving: step again in PAINTING_POLL_US;
 * PAINTING_MOVE_STARTED = as PAINTING_POLL, a move to the tile was just sent (announce it).
 * Negative: msg says what and where, *device the device ("stage") or NULL (storage). */
#define PAINTING_POLL 2
#define PAINTING_MOVE_STARTED 3
#define PAINTING_POLL_US (IMP_STAGE_POLL_INTERVAL_MS * 1000u)
int painting_step(struct session *s, store_done_fn done, const char **device, char *msg, size_t size);
/* Pausing, ending or shutting down: a homing or move in progress is soft-stopped (the
 * session moves to its tile again when it resumes). */
void painting_stop_stage(struct session *s);
/* After frame s->n_captured was grabbed: the stage still stood at its tile (else the frame
 * is dropped and taken again after the resume). Negative with msg as painting_step. */
int painting_check_frame(struct session *s, char *msg, size_t size);
void painting_stamp(const struct session *s, struct imp_frame_record *rec);
/* A completed session: its last tile done and queued. */
void painting_finish(struct session *s);
int painting_reopen(struct session *s, struct imp_proto_error *perr);
/* {"tiles","tiles_done","tile","tile_frames","tile_frames_done","tile_eta_s"} and, while the
 * stage works, "stage": "homing" or "moving to tile N (x, y) mm"; NULL without tiles. */
json_t *painting_progress_json(const struct session *s, double eta_s);

/* session.c */
int session_start(struct daemon *d, const char *plan_path, const char *name, struct session **ret,
                  struct imp_proto_error *perr);
int session_pause(struct session *s, struct imp_proto_error *perr);
int session_resume(struct session *s, struct imp_proto_error *perr);
int session_abort(struct session *s, struct imp_proto_error *perr);
void session_free(struct session *s);
struct session *session_find(struct daemon *d, const char *id);
json_t *session_summary_json(const struct session *s);
json_t *session_show_json(const struct session *s);
/* A painting's progress and ETA, by tile and whole (painting_progress_json + "eta_s"), or NULL. */
json_t *session_painting_json(const struct session *s);
/* Load a plan against the daemon's rig for validate/estimate. */
int plan_check(struct daemon *d, const char *path, struct imp_plan **ret, struct imp_proto_error *perr);
/* On shutdown: stop stepping, leave devices safe, flush. The state file keeps "running" so
 * that the next start finds the session interrupted. */
void session_shutdown(struct session *s);

/* ---- jobs (jobs.c) --------------------------------------------------------------------- */


/* The daemon's view of STATE/jobs/<id>.json (docs/jobs.md). The file is the truth: the
 * daemon writes it only while no worker holds the job (enqueue, retry, an attempt that no
 * worker accounted for) and otherwise re-reads what the worker wrote. */
struct job {
        struct job *next;
        struct daemon *d;
        char id[128];
        char session[128];
        char set_dir[PATH_MAX];         /* "capture" */
        char output[PATH_MAX];          /* "copy" */
        enum imp_job_state state;
        int attempts, max_attempts;
        char queued[32], started[32], ended[32];
        char error[1024];
        char stage[64];                 /* the worker's current processing stage, "" before */
        double progress;                /* 0..1 over the whole job */
        char verdict[16];               /* the copy's quality.verdict once done ("" when it has none) */
        json_t *worker_args;            /* as written into the file (string or null) */
        pid_t pid;                      /* our worker child, 0 when none */
        off_t log_start;                /* where this attempt's output starts in STATE/jobs/<id>.log */
        int spawn_attempts;             /* attempts in the file when the child was started */
        bool claim_seen;                /* the child was seen to claim the job (it accounts for it) */
        sd_event_source *child_source;
        /* what the last `job` event said, so that re-reads only announce changes */
        enum imp_job_state ev_state;
        int ev_attempts;
        double ev_progress;
        char ev_stage[64];
        bool ev_sent;
        char slurm_batch[PATH_MAX];     /* scheduler slurm: its batch directory, "" before (sched-slurm.c) */
        int slurm_task;
};

/* fork + execv(argv[0]) with the signal mask cleared, standard output and error on fd_out
 * and fd_err when >= 0; cb runs when it exits. *ret_pid and *ret_source set on success. */
int daemon_spawn(struct daemon *d, const char *const *argv, int fd_out, int fd_err, sd_event_child_handler_t cb,
                 void *userdata, pid_t *ret_pid, sd_event_source **ret_source);
int jobs_load(struct daemon *d);
int jobs_enqueue(struct daemon *d, const struct session *s);
/* A job of any capture set (a painting's tile): id, set and output given. -EEXIST when queued. */
int jobs_enqueue_set(struct daemon *d, const char *session, const char *id, const char *set_dir, const char *output);
int jobs_retry(struct daemon *d, struct job *j, struct imp_proto_error *perr);
struct job *jobs_find(struct daemon *d, const char *id);
json_t *job_json(const struct job *j, bool full);
/* Spawn mode: start the worker on the oldest queued job when none is running. */
void jobs_kick(struct daemon *d);
/* Watch STATE/jobs (inotify, and a slow timer for claims whose worker died). */
int jobs_watch(struct daemon *d);
void jobs_free_all(struct daemon *d);
/* Writes the job's file and sends the `job` event when something changed (sched-slurm.c). */
void jobs_save_announce(struct daemon *d, struct job *j);

/* ---- calibrations (calibration.c) ------------------------------------------------------ */

/* A calibration run by the daemon (docs/daemon.md, "Calibrations"): a capture session of the
 * routine's plan, then the offline routine on the set as a durable job of the daemon's own
 * (STATE/calibrations/<version>/calibration.json), then a new calibration version. */
/* A client's credentials, from the kernel at connect() (SO_PEERCRED, SO_PEERGROUPS): never
 * from /proc/<pid>, whose pid may be another process's by the time it is read (or 0 for a
 * peer in another PID namespace). */
#define DAEMON_PEER_GROUPS_MAX 256
struct daemon_peer {
        uid_t uid;
        gid_t gid;
        pid_t pid;                      /* for logs only; 0 from another PID namespace */
        int n_groups;                   /* supplementary groups; -1 when unknown (fail closed) */
        gid_t groups[DAEMON_PEER_GROUPS_MAX];
};
bool daemon_peer_in_group(const struct daemon_peer *p, gid_t gid);

enum calib_state { CALIB_CAPTURING, CALIB_QUEUED, CALIB_RUNNING, CALIB_DONE, CALIB_FAILED };

struct calibration {
        struct calibration *next;
        struct daemon *d;
        int version;
        char id[16];                    /* the version as a token */
        char routine[16];
        char session[128];
        char set_dir[PATH_MAX];
        char dir[PATH_MAX];             /* STATE/calibrations/<version> */
        char plan[PATH_MAX];
        json_t *args;                   /* routine parameters as given */
        enum calib_state state;
        int attempts, max_attempts;
        int based_on;                   /* the version current when it started (0: the rig config's) */
        char created[32], started[32], ended[32];
        char error[1024];
        json_t *figures;                /* flattened scalars of the routine's report, once done */
        pid_t pid;
        sd_event_source *child_source;
};

/* Loads STATE/calibrations and makes the current version (if any) the daemon's rig. */
int calibrations_load(struct daemon *d);
void calibrations_free_all(struct daemon *d);
int calibration_start(struct daemon *d, const char *routine, const json_t *args, const char *plan,
                      const char *name, const struct daemon_peer *peer, struct calibration **ret,
                      struct imp_proto_error *perr);
struct calibration *calibration_find(struct daemon *d, const char *id);
json_t *calibration_json(const struct calibration *c, bool full);
/* The calibration in force as {"version","file","date","routine"}; never NULL. */
json_t *calibration_current_json(struct daemon *d);
/* A session of a calibration: its set is calibrated, not processed. */
bool calibrations_own_session(struct daemon *d, const char *session);
/* From the session's `done` event: a completed capture queues its routine. */
void calibrations_session_ended(struct daemon *d, const char *session, const char *state);
/* Writes <set>/calibration.json naming the calibration version the set was captured with. */
int calibration_reference_set(struct daemon *d, const char *set_dir, struct imp_error *err);

/* ---- plan paths from clients (planpath.c) ------------------------------------------------ */

#define DAEMON_MAX_PLAN_DIRS 8
#define DAEMON_PLAN_MAX_BYTES (1024 * 1024)

/* A plan path named by a client, confined: it must resolve (symlinks followed) to a regular
 * file of at most DAEMON_PLAN_MAX_BYTES below one of the --plan-dir directories when any is
 * configured, and be readable by the peer itself (its uid and groups against the file's mode
 * and the search rights of its directories), so that the daemon never reads for a client what
 * the client could not. The resolved path in ret; not_found naming `field` otherwise. */
int plan_path_resolve(struct daemon *d, const struct daemon_peer *peer, const char *path, const char *field,
                      char ret[static PATH_MAX], struct imp_proto_error *perr);
/* Reads a (resolved) plan file through one descriptor: no symlink on the way, never blocking
 * (O_NONBLOCK: a FIFO or a device is refused, not waited on), a regular file of at most
 * DAEMON_PLAN_MAX_BYTES, text without NUL. *ret_text is malloc'd and NUL-terminated. */
int plan_read(const char *path, char **ret_text, struct imp_proto_error *perr);
/* plan_read + imp_plan_load_string against the daemon's rig: a plan may not @include, and its
 * expansion is capped (IMP_PLAN_MAX_FRAMES/BYTES) before anything is allocated. The text in
 * *ret_text when not NULL (the bytes the capture set keeps as plan.cfg). */
int plan_load_text(struct daemon *d, const char *path, struct imp_plan **ret, char **ret_text,
                   struct imp_proto_error *perr);
/* A plan file by name (e.g. "photon-transfer.cfg") from the first plan directory that has it. */
int plan_path_builtin(struct daemon *d, const char *name, char ret[static PATH_MAX]);

/* ---- server (server.c) ----------------------------------------------------------------- */

struct client;

int server_start(struct daemon *d);
void server_stop(struct daemon *d);
/* The command table agrees with the protocol's (every command handled, the same role);
 * false, logged, when not: the daemon then refuses to start. */
bool server_commands_check(void);
/* Event to every subscribed client; fields stolen. */
void server_broadcast(struct daemon *d, const char *type, json_t *fields);

/* ---- the daemon (main.c) ----------------------------------------------------------------- */

struct daemon {
        sd_event *event;
        const char *socket_path;
        const char *state_dir;
        const char *rig_config;
        const char *worker_cmd;
        const char *worker_args;        /* --worker-args, copied into each job (NULL: none) */
        bool spawn_workers;             /* false: impasto-worker@ services take the queue */
        bool operators_all;
        bool auto_resume;
        unsigned max_clients;
        unsigned max_clients_per_uid;   /* observers' connections per uid */
        unsigned reserved_slots;        /* of max_clients, for operators */
        unsigned idle_timeout_s;        /* 0: none */
        unsigned request_timeout_s;     /* 0: none */
        uint64_t client_queue_max;      /* queued reply/event bytes before a client is closed */
        unsigned device_probe_interval_s;
        unsigned retries;               /* attempts per capture step */
        unsigned job_attempts;
        uint64_t min_free_bytes;
        unsigned device_timeout_ms;     /* 0: the default */
        uint64_t started_us;

        struct rigcfg *rigcfg;
        struct imp_rig rig;
        bool have_rig;

        int listen_fd;
        sd_event_source *listen_source;
        struct client *clients;
        unsigned n_clients;
        sd_event_source *client_timer;  /* idle and request timeouts */
        int lock_fd;                    /* flock on STATE/impastod.lock: one daemon per state */
        int socket_lock_fd;             /* flock on SOCKET.lock when the socket is ours to create */
        uint64_t socket_ino;            /* the socket file we bound (unlinked at exit only if still it) */
        struct device_probe *probe;     /* a `devices` probe off the loop (rigcfg.c), or NULL */
        uint64_t probe_last_us;         /* monotonic start of the last probe */

        struct session *sessions;       /* newest first */
        struct session *active;         /* holds the rig: preparing, capturing or paused */
        struct job *jobs;               /* newest first */
        sd_event_source *job_timer;     /* spawn mode: the next start or retry */
        sd_event_source *job_watch;     /* inotify on STATE/jobs */
        struct imp_slurm_config *slurm; /* --scheduler-config; NULL or !enabled: local workers */
        sd_event_source *slurm_poll;
        sd_event_source *job_poll;      /* periodic re-read of jobs claimed by other workers */
        const char *plan_dirs[DAEMON_MAX_PLAN_DIRS];    /* --plan-dir */
        unsigned n_plan_dirs;
        const char *calibrate_cmd;      /* run as CMD calibrate ROUTINE --set SET … (calibration.c) */
        struct calibration *calibrations;       /* newest first */
        int calib_version;              /* the calibration in force; 0: the rig config's rig.json */
        sd_event_source *calib_timer;   /* the next calibration attempt */
        struct night *night;            /* impastod.conf, scan queue, hook (night.h) */
        bool stopping;
};

void daemon_notify_status(struct daemon *d);
