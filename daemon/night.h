/* The unattended night (docs/daemon.md, "The night"): the daemon's config file
 * (impastod.conf, conf.c), the scan queue (queue.c), the notification hook and the session
 * logs (hooks.c), and what `status` and `report` say about it (report.c). */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include <jansson.h>
#include <systemd/sd-event.h>
#include "protocol.h"

struct daemon;
struct session;
struct hook_run;
struct queue_entry;

#define NIGHT_DISK_LOW_DEFAULT (10ULL << 30)    /* disk_low_mib default: 10 GiB */
#define NIGHT_HOOK_TIMEOUT_S 30
#define NIGHT_HOOKS_RUNNING_MAX 4               /* hooks at a time; more wait */
#define NIGHT_HOOKS_PENDING_MAX 256             /* waiting beyond this: the oldest is dropped, logged */
#define NIGHT_QUEUE_MAX 256                     /* entries in the scan queue */
#define NIGHT_ATTENTION_MAX 20                  /* items `status` lists (the count says how many more) */

enum resume_policy { RESUME_MANUAL, RESUME_INTERRUPTED };

/* The daemon's state for all of the above; d->night. */
struct night {
        char conf_path[4096];           /* the config file read, "" when none */
        char *hook;                     /* the hook command (an executable, run as HOOK EVENT), NULL: none */
        unsigned hook_timeout_s;
        uint64_t disk_low_bytes;        /* `status` warns below this much free space on the store */
        char *scheduler;                /* "local" (the slurm = { … } group is the Slurm backend's) */
        char *owned[16];                /* strings from the config file the daemon points at */
        unsigned n_owned;
        /* hooks.c */
        struct hook_run *hooks;         /* running */
        unsigned n_hooks;
        json_t *hooks_pending;          /* array of [event, json] waiting for a slot */
        unsigned long long hooks_run, hooks_failed, hooks_dropped;
        json_t *job_ends;               /* job id -> "STATE ENDED" last announced */
        /* queue.c */
        struct queue_entry *queue;      /* in order */
        unsigned n_queue;
        unsigned queue_next_id;
        sd_event_source *queue_defer;
        bool queue_broken;              /* queue.json unreadable and not moved aside: no change, no start */
        char queue_damaged[1024];       /* what was wrong with the queue.json moved aside at start */
};

/* conf.c: makes d->night and reads the config file (--config PATH or --config=PATH in
 * argv, else def, which may be absent: then nothing is set) into d before the command line,
 * whose options override it. Errors (logged) name FILE:LINE: FIELD. */
int night_conf_load(struct daemon *d, int argc, char **argv, const char *def);
void night_free(struct daemon *d);
/* After sessions and jobs are loaded: interruptions recorded, the queue loaded and kicked. */
void night_start(struct daemon *d);

/* hooks.c: every event the daemon broadcasts passes here: faults, a session's end and a
 * job's end go into the session's session.log (timestamped) and the journal, and to the
 * hook. Never blocks: the hook runs as a child with a timeout, reaped by the loop. */
void night_event(struct daemon *d, const char *type, const json_t *fields);
/* A line with a timestamp in STATE/sessions/ID/session.log (and the journal). */
void night_session_log(struct daemon *d, const char *session, const char *fmt, ...)
        __attribute__((format(printf, 3, 4)));
/* At start: a session found running was interrupted: recorded in its faults and log. */
void night_record_interrupted(struct daemon *d);
void night_hooks_free(struct daemon *d);
/* At start, after the jobs are loaded: the ends already there are not announced again. */
void night_seed_jobs(struct daemon *d);

/* queue.c: STATE/queue.json, written crash-safely at every change. */
int queue_load(struct daemon *d);
/* Starts the next queued plan when the rig is free (deferred to the loop). */
void queue_kick(struct daemon *d);
struct daemon_peer;
json_t *queue_add(struct daemon *d, const struct daemon_peer *peer, const char *plan, const char *name,
                  struct imp_proto_error *e);
json_t *queue_list_json(struct daemon *d);
json_t *queue_move(struct daemon *d, const char *id, int pos, struct imp_proto_error *e);
json_t *queue_cancel(struct daemon *d, const char *id, struct imp_proto_error *e);
void queue_free(struct daemon *d);
/* Entries that could not start, as `status` attention items. */
void queue_attention(struct daemon *d, json_t *list);

/* report.c */
/* What needs the operator, each with the command to act on it: failed jobs, paused or
 * interrupted sessions, low disk, queue entries that could not start. */
json_t *night_attention_json(struct daemon *d);
/* The `report` command: sessions, frames, faults, jobs and copies since an RFC 3339 time. */
json_t *night_report_json(struct daemon *d, const char *since, struct imp_proto_error *e);
