/* The impasto control protocol (proto/PROTOCOL.md): one JSON object per line over a local
 * UNIX stream socket. This is the one codec both impastod and its clients use: a bounded line
 * splitter, request parsing and validation against the command table, reply/event builders,
 * and the client-side parser of daemon messages. Library code: nothing here logs. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <jansson.h>
#include "exit-codes.h"   /* IMP_EXIT_*: the client exit codes */
#include "macro.h"

#define IMP_PROTO_VERSION      1                /* "protocol" in the banner; bumped on breaking changes */
#define IMP_PROTO_REQUEST_MAX  (64 * 1024)      /* bytes of one request line, without its '\n' */
#define IMP_PROTO_MESSAGE_MAX  (1024 * 1024)    /* bytes of one reply or event line, without '\n' */
#define IMP_PROTO_DEPTH_MAX    32               /* nesting of arrays and objects in a request */
#define IMP_PROTO_ID_MAX       128              /* bytes of a string request id */
#define IMP_PROTO_OPERATOR_GROUP "impasto-operators"

enum imp_proto_role {
        IMP_PROTO_ROLE_OBSERVER,                /* read-only commands and events */
        IMP_PROTO_ROLE_OPERATOR,                /* everything */
};

/* Error codes of the "error" object; the symbolic names are the wire format. */
enum imp_proto_errcode {
        IMP_PROTO_E_NONE = 0,
        /* request-level: sent by the codec */
        IMP_PROTO_E_TOO_LONG,                   /* "too_long" */
        IMP_PROTO_E_BAD_JSON,                   /* "bad_json" */
        IMP_PROTO_E_BAD_REQUEST,                /* "bad_request" */
        IMP_PROTO_E_UNKNOWN_COMMAND,            /* "unknown_command" */
        IMP_PROTO_E_BAD_ARGUMENT,               /* "bad_argument" */
        IMP_PROTO_E_PERMISSION_DENIED,          /* "permission_denied" */
        /* command-level: sent by the daemon when a valid command fails */
        IMP_PROTO_E_NOT_FOUND,                  /* "not_found": no such session, job or plan file */
        IMP_PROTO_E_BAD_STATE,                  /* "bad_state": not allowed in the current state */
        IMP_PROTO_E_BUSY,                       /* "busy": rig or resource in use */
        IMP_PROTO_E_INVALID_PLAN,               /* "invalid_plan": the scan plan does not validate */
        IMP_PROTO_E_DEVICE,                     /* "device_error": hardware failed or timed out */
        IMP_PROTO_E_IO,                         /* "io_error": storage failed */
        IMP_PROTO_E_SHUTTING_DOWN,              /* "shutting_down": daemon is stopping */
        IMP_PROTO_E_INTERNAL,                   /* "internal": a bug or out of memory */
        IMP_PROTO_E_UNKNOWN,                    /* client side only: a code this client does not know */
        _IMP_PROTO_E_MAX,
};

/* The error object of a failed reply. `id` is the request's id when it could be read
 * (owned; NULL otherwise); release it with imp_proto_error_done(). */
struct imp_proto_error {
        enum imp_proto_errcode code;
        int sys_errno;                          /* positive errno, 0 when none applies */
        char field[128];                        /* "args.plan"; "" when no field is at fault */
        char message[512];
        json_t *id;
};
void imp_proto_error_done(struct imp_proto_error *e);
#define _cleanup_proto_error_ _cleanup_(imp_proto_error_done)

/* Fill e (any previous id is kept); field may be NULL. Returns -sys_errno, or -EINVAL when
 * sys_errno is 0, so that `return imp_proto_error_set(...)` works. */
int imp_proto_error_set(struct imp_proto_error *e, enum imp_proto_errcode code, int sys_errno,
                        const char *field, const char *fmt, ...) _printf_(5, 6);
const char *imp_proto_error_code_name(enum imp_proto_errcode code);
/* IMP_PROTO_E_UNKNOWN for a name this version does not know. */
enum imp_proto_errcode imp_proto_error_code_from_name(const char *name);

/* The exit code a client uses when the daemon answers with this error. */
int imp_proto_exit_status(enum imp_proto_errcode code);

const char *imp_proto_role_name(enum imp_proto_role role);

/* ---- Commands: one constant row per command in protocol.c. ---- */

enum imp_proto_cmd {
        IMP_PROTO_CMD_STATUS,
        IMP_PROTO_CMD_RIG,
        IMP_PROTO_CMD_DEVICES,
        IMP_PROTO_CMD_PLAN_VALIDATE,
        IMP_PROTO_CMD_PLAN_ESTIMATE,
        IMP_PROTO_CMD_SESSION_START,
        IMP_PROTO_CMD_SESSION_PAUSE,
        IMP_PROTO_CMD_SESSION_RESUME,
        IMP_PROTO_CMD_SESSION_ABORT,
        IMP_PROTO_CMD_SESSION_LIST,
        IMP_PROTO_CMD_SESSION_SHOW,
        IMP_PROTO_CMD_CALIBRATE,
        IMP_PROTO_CMD_JOBS_LIST,
        IMP_PROTO_CMD_JOBS_SHOW,
        IMP_PROTO_CMD_JOBS_RETRY,
        IMP_PROTO_CMD_SUBSCRIBE,
        IMP_PROTO_CMD_UNSUBSCRIBE,
        IMP_PROTO_CMD_CALIBRATION_LIST,
        IMP_PROTO_CMD_CALIBRATION_SHOW,
        IMP_PROTO_CMD_QUEUE_ADD,
        IMP_PROTO_CMD_QUEUE_LIST,
        IMP_PROTO_CMD_QUEUE_MOVE,
        IMP_PROTO_CMD_QUEUE_CANCEL,
        IMP_PROTO_CMD_REPORT,
        _IMP_PROTO_CMD_MAX,
};

enum imp_proto_type {
        IMP_PROTO_T_STRING,                     /* min..max: length in bytes */
        IMP_PROTO_T_INTEGER,                    /* min..max: value */
        IMP_PROTO_T_BOOLEAN,
        IMP_PROTO_T_OBJECT,                     /* opaque to the codec; the command checks it */
        IMP_PROTO_T_STRING_ARRAY,               /* min..max: element count; choices apply to elements */
};

/* Argument flags. */
#define IMP_PROTO_F_REQUIRED 0x1
#define IMP_PROTO_F_TOKEN    0x2                /* string of [A-Za-z0-9._-], not starting with '.' */

struct imp_proto_field {
        const char *name;
        enum imp_proto_type type;
        unsigned flags;
        long long min, max;
        const char *const *choices;             /* NULL-terminated allowed strings, or NULL */
        const char *what;                       /* "path of a scan plan on the daemon's host" */
};

struct imp_proto_command {
        const char *name;                       /* "session.start" */
        enum imp_proto_cmd cmd;
        bool operator_only;
        const struct imp_proto_field *fields;   /* terminated by a row with name == NULL */
        const char *summary;
};

/* The table, in wire order; *ret_n rows. */
const struct imp_proto_command *imp_proto_commands(size_t *ret_n);
/* NULL when unknown. */
const struct imp_proto_command *imp_proto_command_find(const char *name);

/* ---- Events ---- */

/* Event types, NULL-terminated: progress, frame, device, fault, done, job, calibration. */
extern const char *const imp_proto_event_types[];
bool imp_proto_event_type_valid(const char *type);

/* ---- Line splitter ---- */

/* An incremental splitter of a byte stream into '\n'-terminated lines of at most `max`
 * bytes (without the '\n'). Empty lines are skipped. After feeding, call next() until it
 * returns 0: memory is then bounded by max plus one feed. */
struct imp_linebuf;
/* Caller frees with imp_linebuf_free(). */
int imp_linebuf_new(size_t max, struct imp_linebuf **ret);
void imp_linebuf_free(struct imp_linebuf *lb);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_linebuf *, imp_linebuf_free);
#define _cleanup_linebuf_ _cleanup_(imp_linebuf_freep)
/* Append bytes; 0 or -ENOMEM. Bytes of an oversized line already reported are dropped. */
int imp_linebuf_feed(struct imp_linebuf *lb, const void *data, size_t n);
/* 1 and a line (NUL-terminated in place, without '\n'; valid until the next call on lb),
 * 0 when a complete line is not there yet, -E2BIG once for a line longer than max: its
 * bytes are skipped up to and including the next '\n' and the stream continues. */
int imp_linebuf_next(struct imp_linebuf *lb, char **ret_line, size_t *ret_len);
/* Bytes held that do not yet form a line (e.g. to report a truncated last line at EOF). */
size_t imp_linebuf_pending(const struct imp_linebuf *lb);

/* ---- Server side ---- */

struct imp_proto_request {
        json_t *id;                             /* owned: an integer or a string */
        const struct imp_proto_command *command;
        json_t *args;                           /* owned: an object, empty when absent */
};
void imp_proto_request_done(struct imp_proto_request *req);
#define _cleanup_proto_request_ _cleanup_(imp_proto_request_done)

/* Parse and validate one request line (without its '\n') for a peer in `role`. On success
 * fills *ret and returns 0. On failure *ret is untouched, *ret_err names the code, field and
 * reason (and ret_err->id holds the id when it was readable), and the return is -E2BIG
 * (too_long), -EBADMSG (bad_json), -EINVAL (bad_request, bad_argument), -EOPNOTSUPP
 * (unknown_command), -EPERM (permission_denied) or -ENOMEM (internal). *ret_err must be
 * zero-initialised or hold an earlier result (its id is released); it may be NULL. */
int imp_proto_parse_request(const char *line, size_t len, enum imp_proto_role role,
                            struct imp_proto_request *ret, struct imp_proto_error *ret_err);

/* Builders: each returns a new reference, or NULL when out of memory. Stolen arguments are
 * released even on failure. */
json_t *imp_proto_banner(enum imp_proto_role role);
/* result is stolen; NULL stands for {}. */
json_t *imp_proto_reply_ok(const json_t *id, json_t *result);
/* {"id","ok":false,"error":{"code","errno","message","field"?}}; "field" is left out when
 * e->field is empty. id NULL: e->id, or null when the request's id was unreadable. */
json_t *imp_proto_reply_error(const json_t *id, const struct imp_proto_error *e);
/* fields (stolen, may be NULL) are merged after "event" and "seq"; NULL for an unknown type. */
json_t *imp_proto_event(const char *type, unsigned long long seq, json_t *fields);
/* Compact, '\n'-terminated, no other newline. Caller frees with free(); NULL on ENOMEM. */
char *imp_proto_dump_line(const json_t *msg);

/* ---- Client side ---- */

enum imp_proto_msg_kind {
        IMP_PROTO_MSG_BANNER,
        IMP_PROTO_MSG_REPLY,
        IMP_PROTO_MSG_EVENT,
};

/* A message from the daemon. Pointers borrow from root. */
struct imp_proto_message {
        enum imp_proto_msg_kind kind;
        json_t *root;                           /* owned: the whole message */
        /* banner */
        const char *version;                    /* "0.1.0" */
        long long protocol;
        enum imp_proto_role role;
        /* reply */
        const json_t *id;
        bool ok;
        const json_t *result;                   /* ok: the result object */
        struct imp_proto_error error;           /* !ok: decoded error (error.id stays NULL) */
        /* event */
        const char *event;                      /* may be a type this client does not know */
        unsigned long long seq;
        const json_t *session;                  /* NULL when the event has none */
};
void imp_proto_message_done(struct imp_proto_message *m);
#define _cleanup_proto_message_ _cleanup_(imp_proto_message_done)

/* Parse one line from the daemon (same zero-initialisation rule for *ret_err). 0 and *ret filled; -EBADMSG with *ret_err (code bad_json
 * or bad_request, naming the field) when the line is not a well-formed banner, reply or
 * event; -E2BIG past IMP_PROTO_MESSAGE_MAX; -ENOMEM. *ret is untouched on failure. */
int imp_proto_parse_reply(const char *line, size_t len, struct imp_proto_message *ret,
                          struct imp_proto_error *ret_err);
