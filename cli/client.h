/* The client side of the control protocol (proto/PROTOCOL.md) for the `impasto` commands
 * that talk to impastod: connect, read and check the banner, send requests with ids, read
 * replies and events through the one codec in proto/protocol.h, and map what happened to
 * the client's exit codes (0 ok, 1 failure, 2 usage, 3 bad input, 4 daemon unreachable,
 * 5 permission denied). */
#pragma once
#include <stdbool.h>
#include <jansson.h>
#include "error.h"
#include "protocol.h"

#define IMP_CLIENT_DEFAULT_SOCKET "/run/impasto/control.sock"
#define IMP_CLIENT_REPLY_TIMEOUT_MS 30000      /* a reply later than this: daemon unreachable */

struct imp_client;   /* opaque: one connection */

/* The socket to use: `arg` (from --socket) when set, else $IMPASTO_SOCKET when set and
 * non-empty, else IMP_CLIENT_DEFAULT_SOCKET. */
const char *imp_client_socket_path(const char *arg);

/* Connects, reads the banner and checks its protocol version. Caller frees with
 * imp_client_free(). Negative errno with err->msg on failure: connection errors as they
 * came (-ENOENT, -ECONNREFUSED, -EACCES, …), -ECONNRESET when the daemon closed before the
 * banner, -ETIMEDOUT, -EPROTO for an unknown protocol version, -EBADMSG for a malformed
 * banner. */
int imp_client_open(const char *path, struct imp_client **ret, struct imp_error *err);
void imp_client_free(struct imp_client *c);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_client *, imp_client_free);
#define _cleanup_client_ _cleanup_(imp_client_freep)

/* The banner's role and release. */
enum imp_proto_role imp_client_role(const struct imp_client *c);
const char *imp_client_daemon_version(const struct imp_client *c);

/* Called for every event read while waiting; the message is released after the call. */
typedef void (*imp_client_event_fn)(void *userdata, const struct imp_proto_message *event);

/* Sends {"id":N,"cmd":cmd,"args":args} (args stolen, NULL for none) and reads until the
 * reply with that id arrives; events read meanwhile go to on_event (may be NULL). 0 and
 * *ret filled with the reply, whether ok or not (release with imp_proto_message_done());
 * negative errno with err->msg when the exchange itself failed (see imp_client_open()). */
int imp_client_call(struct imp_client *c, const char *cmd, json_t *args, imp_client_event_fn on_event,
                    void *userdata, struct imp_proto_message *ret, struct imp_error *err);

/* Reads the next message that is an event, waiting at most timeout_ms (-1: forever).
 * 1 and *ret filled, 0 on timeout, negative errno (-ECONNRESET at EOF) with err->msg.
 * Replies read meanwhile (none expected) are dropped. */
int imp_client_next_event(struct imp_client *c, int timeout_ms, struct imp_proto_message *ret,
                          struct imp_error *err);

/* Exit code for a failed exchange (a negative errno from the calls above): 4 for anything
 * that means the daemon could not be reached or went away, 1 otherwise. */
int imp_client_exit_for_errno(int r);

/* ---- helpers shared by the cmd-*.c files ---- */

/* Options every daemon command takes. */
struct imp_client_opts {
        const char *socket;           /* --socket PATH */
        bool json;                    /* --json: print the result object as it came */
};

/* Connects (logging why not) and returns an exit code: 0 and *ret on success. */
int imp_client_connect_or_log(const struct imp_client_opts *o, struct imp_client **ret);

/* Logs a failed reply ("CODE: message (field)") and returns its exit code. */
int imp_client_report_error(const char *cmd, const struct imp_proto_message *reply);

/* One request, one reply: connects, calls cmd with args (stolen), and on success prints
 * the result with --json as JSON, otherwise through `human` (when NULL: as indented JSON).
 * Returns the exit code. */
int imp_client_simple(const struct imp_client_opts *o, const char *cmd, json_t *args,
                      void (*human)(const json_t *result));

/* The whole of a command that takes no arguments but --json and --socket PATH: parses
 * argv, prints "usage: impasto CMD [--json] [--socket PATH]" on --help or misuse, and
 * runs imp_client_simple(). Returns the exit code. */
int imp_client_main_simple(int argc, char **argv, const char *cmd, void (*human)(const json_t *result));

/* Result members for human output: "" / 0 / NAN when absent or of another type. */
const char *imp_client_str(const json_t *obj, const char *key);
long long imp_client_int(const json_t *obj, const char *key);
double imp_client_num(const json_t *obj, const char *key);
/* "1.2 GB"-style byte counts and "1 h 02 min"-style durations into buf. */
const char *imp_client_fmt_bytes(double bytes, char *buf, size_t size);
const char *imp_client_fmt_duration(double s, char *buf, size_t size);

/* Subscribes c to the event types given (a JSON array of strings, stolen) and returns an
 * exit code; *ret_seq gets the connection's last event sequence number (events before the
 * subscription are not counted as dropped). */
int imp_client_subscribe(struct imp_client *c, json_t *events, unsigned long long *ret_seq);

/* --limit N of the list commands: 0 and *ret, or IMP_EXIT_USAGE (logged). */
int imp_client_parse_limit(const char *arg, long *ret);

/* A list result as a table: one column per entry (a string or integer member of each row;
 * width 0: the last, unpadded column), a header line first; `empty` when there are no rows. */
struct imp_client_column {
        const char *title, *key;
        int width;
};
void imp_client_print_table(const json_t *rows, const struct imp_client_column *cols, size_t n_cols,
                            const char *empty);

/* Following events: counts in *dropped the events lost between *last_seq and seq (the
 * daemon drops events for a subscriber that reads too slowly), then remembers seq. */
void imp_client_count_gap(unsigned long long *last_seq, unsigned long long *dropped, unsigned long long seq);

/* The `attention` object of status and report (cmd-status.c): each item that needs the
 * operator with the command that acts on it, or "nothing needs attention". */
void imp_client_print_attention(const json_t *att);
/* A painting session's progress by tile ("painting" of status, session.show): one line. */
void imp_client_print_painting(const json_t *p);
