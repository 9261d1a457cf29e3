/* Capture sets on disk (docs/capture-set.md): one directory per session, frames as 16-bit
 * TIFF with their metadata, an append-only JSON-lines manifest, rig.json, the scan plan.
 * Written crash-safely — frame to FILE.tmp, fsync, rename, fsync dir, then the manifest
 * line, fsynced — so that a crash at any instant leaves a set that reopens and resumes.
 * The simulator and the daemon write through this module; workers read through it. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "image.h"
#include "rig.h"
#include "pattern.h"

struct imp_frame_record {
        long long seq;                /* 0-based position in the plan */
        char step[24];                /* "structured-light", "dome", "dark", "flat" */
        char camera[32];
        int tile;                     /* gantry position, 0 without gantry */
        struct imp_pattern pattern;   /* kind NONE when the projector is dark */
        int light;                    /* dome light id, -1 for none */
        int exposure_index;           /* position in the exposure stack */
        double exposure_us;
        double gain_db;
        long long t_light_on_ns, t_trigger_ns, t_frame_ns;
        char file[64];                /* relative to the set, "frames/000012.tiff" */
        uint32_t crc32;               /* of the frame file's bytes */
        /* Whole-painting scans (docs/painting.md): where the gantry was told to go and where
         * it read back for this frame, machine mm (x, y, z); "stage" in the record. */
        bool has_stage;
        double stage_commanded_mm[3], stage_readback_mm[3];
};

struct imp_captureset;   /* opaque */

/* Creates DIR (must not exist or be empty) with set.json, rig.json and a copy of the
 * plan file (plan_path may be NULL). Caller closes with imp_captureset_close(). */
int imp_captureset_create(const char *dir, const struct imp_rig *rig, const char *plan_path,
                          struct imp_captureset **ret, struct imp_error *err);
/* The same with the plan's bytes given (plan_text NULL: no plan.cfg): a caller that has
 * read and checked the plan already (impastod) keeps exactly what it checked. */
int imp_captureset_create_with_plan(const char *dir, const struct imp_rig *rig, const char *plan_text,
                                    size_t plan_size, struct imp_captureset **ret, struct imp_error *err);
/* Opens an existing set for reading (and appending, when no other process holds the
 * writer's lock). Never changes anything on disk. A torn or unreadable last manifest line
 * is an error (-EBADMSG, pointing at imp_captureset_repair) unless another process is
 * writing the set (then the view ends before it); frame files no line lists and .tmp files
 * are not part of the set and are ignored (add_frame refuses to overwrite them). A damaged
 * line, a line whose `file` is not the frame of its line number, a missing or resized frame
 * is an error naming the file, line and field. */
int imp_captureset_open(const char *dir, struct imp_captureset **ret, struct imp_error *err);
/* The folder inside a set where repair moves what it cannot account for. */
#define IMP_CAPTURESET_QUARANTINE "quarantine"
/* The explicit repair of what a crash can leave: a torn or unreadable last manifest line
 * (its bytes saved as quarantine/manifest-tail.jsonl, the manifest cut back to its last good
 * line), frame files no line lists and *.tmp files (moved into quarantine/). Nothing is
 * deleted. Refuses (-EBUSY) while another process writes the set, and refuses without
 * moving anything when the damage is not a crash's (a bad line in the middle, a listed
 * frame missing or resized). *ret_report: a JSON array of {"path","reason","moved_to"} (no
 * moved_to when dry_run, which changes nothing). Returns the number of items, or < 0. */
int imp_captureset_repair(const char *dir, bool dry_run, json_t **ret_report, struct imp_error *err);
void imp_captureset_close(struct imp_captureset *cs);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_captureset *, imp_captureset_close);

/* Appends a frame: rec->file and rec->crc32 are filled in here. */
int imp_captureset_add_frame(struct imp_captureset *cs, struct imp_frame_record *rec,
                             const struct imp_image *frame, struct imp_error *err);

size_t imp_captureset_count(const struct imp_captureset *cs);
const struct imp_frame_record *imp_captureset_record(const struct imp_captureset *cs, size_t i);
const struct imp_rig *imp_captureset_rig(const struct imp_captureset *cs);
const char *imp_captureset_dir(const struct imp_captureset *cs);
/* Loads frame i (u16, raw digital numbers), verifying its checksum. */
int imp_captureset_load_frame(const struct imp_captureset *cs, size_t i, struct imp_image **ret,
                              struct imp_error *err);
/* The same, decoded into *io when it already has the frame's layout (no pages allocated or
 * zeroed; imp_tiff_read_reuse), else into a new image replacing it (*io may be NULL): for
 * a loop over frames that keeps one buffer. On failure *io is unspecified content or NULL. */
int imp_captureset_load_frame_reuse(const struct imp_captureset *cs, size_t i, struct imp_image **io,
                                    struct imp_error *err);

/* The set against its own plan (plan.cfg, expanded against its rig; read as text, no
 * @include): 0 when every planned frame is recorded (or the set has no plan); 1 when some
 * are missing, with err saying which ("SET: incomplete: 11 of the plan's 54 frames are
 * missing (dome: 11 of 12 frames (lights 1, 2, …))") and *ret_missing =
 * {"frames_planned","frames_present","frames_missing","steps":{STEP:{"planned","missing",
 * "lights":[…]}}}; < 0 when the plan cannot be read or a record is not the plan's frame of
 * its seq (-EBADMSG naming the manifest line and field). Reads only. */
int imp_captureset_check_complete(const struct imp_captureset *cs, json_t **ret_missing, struct imp_error *err);

/* The set's own plan.cfg, expanded against its rig (read as text, no @include); *ret NULL
 * when the set has no plan. Caller frees with imp_plan_free(). Reads only. */
struct imp_plan;
int imp_captureset_load_plan(const struct imp_captureset *cs, struct imp_plan **ret, struct imp_error *err);

json_t *imp_frame_record_to_json(const struct imp_frame_record *rec);
int imp_frame_record_from_json(const json_t *j, const char *what, struct imp_frame_record *ret,
                               struct imp_error *err);
