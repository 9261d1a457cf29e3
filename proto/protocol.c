/* The control protocol codec: the command table (one row per command with its role and
 * argument schema), request parsing and validation, reply and event builders, and the
 * client-side parser. PROTOCOL.md is the specification; keep the two in step. */
#include <errno.h>
#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "json-util.h"
#include "protocol.h"
#include "version.h"   /* IMPASTO_VERSION_STRING only */

/* ---- Errors ---- */

static const char *const error_names[_IMP_PROTO_E_MAX] = {
        [IMP_PROTO_E_NONE] = "none",
        [IMP_PROTO_E_TOO_LONG] = "too_long",
        [IMP_PROTO_E_BAD_JSON] = "bad_json",
        [IMP_PROTO_E_BAD_REQUEST] = "bad_request",
        [IMP_PROTO_E_UNKNOWN_COMMAND] = "unknown_command",
        [IMP_PROTO_E_BAD_ARGUMENT] = "bad_argument",
        [IMP_PROTO_E_PERMISSION_DENIED] = "permission_denied",
        [IMP_PROTO_E_NOT_FOUND] = "not_found",
        [IMP_PROTO_E_BAD_STATE] = "bad_state",
        [IMP_PROTO_E_BUSY] = "busy",
        [IMP_PROTO_E_INVALID_PLAN] = "invalid_plan",
        [IMP_PROTO_E_DEVICE] = "device_error",
        [IMP_PROTO_E_IO] = "io_error",
        [IMP_PROTO_E_SHUTTING_DOWN] = "shutting_down",
        [IMP_PROTO_E_INTERNAL] = "internal",
        [IMP_PROTO_E_UNKNOWN] = "unknown",
};

const char *imp_proto_error_code_name(enum imp_proto_errcode code) {
        if ((unsigned) code >= _IMP_PROTO_E_MAX)
                return "unknown";
        return error_names[code];
}

enum imp_proto_errcode imp_proto_error_code_from_name(const char *name) {
        if (!name)
                return IMP_PROTO_E_UNKNOWN;
        for (unsigned i = IMP_PROTO_E_TOO_LONG; i < IMP_PROTO_E_UNKNOWN; i++)
                if (!strcmp(error_names[i], name))
                        return (enum imp_proto_errcode) i;
        return IMP_PROTO_E_UNKNOWN;
}

int imp_proto_exit_status(enum imp_proto_errcode code) {
        switch (code) {
        case IMP_PROTO_E_NONE:
                return IMP_EXIT_OK;
        case IMP_PROTO_E_BAD_ARGUMENT:
        case IMP_PROTO_E_INVALID_PLAN:
        case IMP_PROTO_E_NOT_FOUND:
        case IMP_PROTO_E_TOO_LONG:
                return IMP_EXIT_BAD_INPUT;
        case IMP_PROTO_E_PERMISSION_DENIED:
                return IMP_EXIT_PERMISSION;
        default:
                return IMP_EXIT_FAILURE;
        }
}

void imp_proto_error_done(struct imp_proto_error *e) {
        if (!e)
                return;
        json_decref(e->id);
        e->id = NULL;
}

static int verror_set(struct imp_proto_error *e, enum imp_proto_errcode code, int sys_errno,
                      const char *field, const char *fmt, va_list ap) {
        if (e) {
                e->code = code;
                e->sys_errno = sys_errno > 0 ? sys_errno : 0;
                snprintf(e->field, sizeof e->field, "%s", field ? field : "");
                vsnprintf(e->message, sizeof e->message, fmt, ap);
        }
        return sys_errno > 0 ? -sys_errno : -EINVAL;
}

int imp_proto_error_set(struct imp_proto_error *e, enum imp_proto_errcode code, int sys_errno,
                        const char *field, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        int r = verror_set(e, code, sys_errno, field, fmt, ap);
        va_end(ap);
        return r;
}

const char *imp_proto_role_name(enum imp_proto_role role) {
        return role == IMP_PROTO_ROLE_OPERATOR ? "operator" : "observer";
}

/* ---- The command table ---- */

static const char *const calibrate_routines[] = { "camera", "procam", "lights", "radiometric", "projector-gamma",
                                                  NULL };
const char *const imp_proto_event_types[] = { "progress", "frame", "device", "fault", "done", "job", "calibration",
                                               NULL };

#define STR(n, fl, lo, hi, w) { .name = n, .type = IMP_PROTO_T_STRING, .flags = fl, .min = lo, .max = hi, .what = w }
#define PLAN  STR("plan", IMP_PROTO_F_REQUIRED, 1, PATH_MAX - 1, "path of a scan plan on the daemon's host")
#define SESSION STR("session", IMP_PROTO_F_REQUIRED | IMP_PROTO_F_TOKEN, 1, 128, "session id")
#define JOB   STR("job", IMP_PROTO_F_REQUIRED | IMP_PROTO_F_TOKEN, 1, 128, "job id")
#define LIMIT { .name = "limit", .type = IMP_PROTO_T_INTEGER, .min = 1, .max = 1000, .what = "most entries to list" }
#define END   { .name = NULL }

static const struct imp_proto_field no_args[] = { END };
static const struct imp_proto_field plan_args[] = { PLAN, END };
static const struct imp_proto_field estimate_args[] = {
        PLAN,
        { .name = "painting", .type = IMP_PROTO_T_OBJECT, .what = "whole-painting estimate options" },
        END,
};
static const struct imp_proto_field session_args[] = { SESSION, END };
static const struct imp_proto_field job_args[] = { JOB, END };
static const struct imp_proto_field list_args[] = { LIMIT, END };
static const struct imp_proto_field start_args[] = {
        PLAN,
        STR("name", IMP_PROTO_F_TOKEN, 1, 64, "session name"),
        END,
};
static const struct imp_proto_field calibrate_args[] = {
        { .name = "routine", .type = IMP_PROTO_T_STRING, .flags = IMP_PROTO_F_REQUIRED,
          .min = 1, .max = 32, .choices = calibrate_routines, .what = "calibration routine" },
        { .name = "args", .type = IMP_PROTO_T_OBJECT, .what = "routine parameters" },
        STR("plan", 0, 1, PATH_MAX - 1, "path of a scan plan on the daemon's host"),
        STR("name", IMP_PROTO_F_TOKEN, 1, 64, "session name"),
        END,
};
static const struct imp_proto_field calibration_args[] = {
        STR("calibration", IMP_PROTO_F_REQUIRED | IMP_PROTO_F_TOKEN, 1, 128, "calibration version"),
        END,
};
#define QUEUE_ID STR("id", IMP_PROTO_F_REQUIRED | IMP_PROTO_F_TOKEN, 1, 16, "queue entry id")
static const struct imp_proto_field queue_id_args[] = { QUEUE_ID, END };
static const struct imp_proto_field queue_move_args[] = {
        QUEUE_ID,
        { .name = "position", .type = IMP_PROTO_T_INTEGER, .min = 1, .max = 256,
          .what = "new position in the queue, 1 first (default 1)" },
        END,
};
static const struct imp_proto_field report_args[] = {
        STR("since", IMP_PROTO_F_REQUIRED, 1, 32, "UTC time as YYYY-MM-DDTHH:MM:SSZ"),
        END,
};
static const struct imp_proto_field subscribe_args[] = {
        { .name = "events", .type = IMP_PROTO_T_STRING_ARRAY, .min = 1, .max = 16,
          .choices = imp_proto_event_types, .what = "event types" },
        END,
};

static const struct imp_proto_command commands[] = {
#define C(n, id, op, f, s) { .name = n, .cmd = IMP_PROTO_CMD_##id, .operator_only = op, .fields = f, .summary = s }
        C("status",         STATUS,         false, no_args,        "daemon, rig and active session at a glance"),
        C("rig",            RIG,            false, no_args,        "the loaded rig configuration and its calibration"),
        C("devices",        DEVICES,        false, no_args,        "each device with its state"),
        C("plan.validate",  PLAN_VALIDATE,  false, plan_args,      "check a scan plan against the rig"),
        C("plan.estimate",  PLAN_ESTIMATE,  false, estimate_args,      "frames, bytes and time a plan will take"),
        C("session.start",  SESSION_START,  true,  start_args,     "start a capture session from a plan"),
        C("session.pause",  SESSION_PAUSE,  true,  session_args,   "pause a running session after the current frame"),
        C("session.resume", SESSION_RESUME, true,  session_args,   "resume a paused or interrupted session"),
        C("session.abort",  SESSION_ABORT,  true,  session_args,   "stop a session; what was captured is kept"),
        C("session.list",   SESSION_LIST,   false, list_args,      "sessions, newest first"),
        C("session.show",   SESSION_SHOW,   false, session_args,   "one session in detail"),
        C("calibrate",      CALIBRATE,      true,  calibrate_args, "run a calibration routine"),
        C("jobs.list",      JOBS_LIST,      false, list_args,      "processing jobs, newest first"),
        C("jobs.show",      JOBS_SHOW,      false, job_args,       "one job in detail"),
        C("jobs.retry",     JOBS_RETRY,     true,  job_args,       "queue a failed job again"),
        C("subscribe",      SUBSCRIBE,      false, subscribe_args, "stream events on this connection"),
        C("unsubscribe",    UNSUBSCRIBE,    false, no_args,        "stop streaming events"),
        C("calibration.list", CALIBRATION_LIST, false, list_args,  "stored calibrations, newest first"),
        C("calibration.show", CALIBRATION_SHOW, false, calibration_args, "one calibration with its figures"),
        C("queue.add",      QUEUE_ADD,      true,  start_args,     "queue a plan: it starts as its own session when the rig is free"),
        C("queue.list",     QUEUE_LIST,     false, no_args,        "the scan queue in order"),
        C("queue.move",     QUEUE_MOVE,     true,  queue_move_args, "move a queue entry to another position"),
        C("queue.cancel",   QUEUE_CANCEL,   true,  queue_id_args,  "remove an entry from the scan queue"),
        C("report",         REPORT,         false, report_args,    "sessions, faults, jobs and copies since a time"),
#undef C
};
_Static_assert(ARRAY_SIZE(commands) == _IMP_PROTO_CMD_MAX, "one row per command");

const struct imp_proto_command *imp_proto_commands(size_t *ret_n) {
        if (ret_n)
                *ret_n = ARRAY_SIZE(commands);
        return commands;
}

const struct imp_proto_command *imp_proto_command_find(const char *name) {
        if (!name)
                return NULL;
        for (size_t i = 0; i < ARRAY_SIZE(commands); i++)
                if (!strcmp(commands[i].name, name))
                        return &commands[i];
        return NULL;
}

static bool in_list(const char *const *list, const char *s) {
        for (; *list; list++)
                if (!strcmp(*list, s))
                        return true;
        return false;
}

bool imp_proto_event_type_valid(const char *type) {
        return type && in_list(imp_proto_event_types, type);
}

/* ---- Request parsing ---- */

/* "one of a, b, c" */
static void format_choices(char *buf, size_t size, const char *const *choices) {
        size_t n = (size_t) snprintf(buf, size, "one of");
        for (size_t i = 0; choices[i] && n < size; i++)
                n += (size_t) snprintf(buf + n, size - n, "%s %s", i ? "," : "", choices[i]);
}

static bool is_token(const char *s) {
        if (s[0] == '.')
                return false;
        for (; *s; s++)
                if (!(('a' <= *s && *s <= 'z') || ('A' <= *s && *s <= 'Z') ||
                      ('0' <= *s && *s <= '9') || *s == '.' || *s == '_' || *s == '-'))
                        return false;
        return true;
}

/* A member name from the peer may hold anything: keep a printable ASCII prefix for "field". */
static void printable(char *dst, size_t size, const char *src) {
        size_t i = 0;
        for (; src[i] && i < size - 1; i++)
                dst[i] = (src[i] >= 0x20 && src[i] < 0x7f) ? src[i] : '?';
        dst[i] = 0;
}

static int bad_arg(struct imp_proto_error *e, const char *field, const char *fmt, ...) _printf_(3, 4);
static int bad_arg(struct imp_proto_error *e, const char *field, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        int r = verror_set(e, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field, fmt, ap);
        va_end(ap);
        return r;
}

static int check_string(const struct imp_proto_field *f, const json_t *v, const char *path,
                        struct imp_proto_error *e) {
        char choices[256];
        if (f->choices)
                format_choices(choices, sizeof choices, f->choices);
        if (!json_is_string(v)) {
                if (f->choices)
                        return bad_arg(e, path, "expected a string, %s (%s), got %s", choices, f->what,
                                       imp_json_type_name(v));
                return bad_arg(e, path, "expected a string (%s), got %s", f->what, imp_json_type_name(v));
        }
        const char *s = json_string_value(v);
        size_t n = json_string_length(v);
        if (f->choices) {
                if (!in_list(f->choices, s))
                        return bad_arg(e, path, "expected %s (%s)", choices, f->what);
                return 0;
        }
        if ((long long) n < f->min || (long long) n > f->max)
                return bad_arg(e, path, "expected a string of %lld to %lld bytes (%s), got %zu bytes",
                               f->min, f->max, f->what, n);
        if (strlen(s) != n)
                return bad_arg(e, path, "expected a string without NUL characters (%s)", f->what);
        if ((f->flags & IMP_PROTO_F_TOKEN) && !is_token(s))
                return bad_arg(e, path, "expected a %s of letters, digits, '.', '_' and '-', "
                               "not starting with '.'", f->what);
        return 0;
}

static int check_value(const struct imp_proto_field *f, const json_t *v, const char *path,
                       struct imp_proto_error *e) {
        switch (f->type) {
        case IMP_PROTO_T_STRING:
                return check_string(f, v, path, e);
        case IMP_PROTO_T_INTEGER:
                if (!json_is_integer(v) || json_integer_value(v) < f->min || json_integer_value(v) > f->max)
                        return bad_arg(e, path, "expected an integer from %lld to %lld (%s)%s%s",
                                       f->min, f->max, f->what, json_is_integer(v) ? "" : ", got ",
                                       json_is_integer(v) ? "" : imp_json_type_name(v));
                return 0;
        case IMP_PROTO_T_BOOLEAN:
                if (!json_is_boolean(v))
                        return bad_arg(e, path, "expected true or false (%s), got %s", f->what,
                                       imp_json_type_name(v));
                return 0;
        case IMP_PROTO_T_OBJECT:
                if (!json_is_object(v))
                        return bad_arg(e, path, "expected an object (%s), got %s", f->what,
                                       imp_json_type_name(v));
                return 0;
        case IMP_PROTO_T_STRING_ARRAY: {
                size_t n = json_array_size(v);
                if (!json_is_array(v) || (long long) n < f->min || (long long) n > f->max)
                        return bad_arg(e, path, "expected an array of %lld to %lld strings (%s)%s%s",
                                       f->min, f->max, f->what, json_is_array(v) ? "" : ", got ",
                                       json_is_array(v) ? "" : imp_json_type_name(v));
                struct imp_proto_field elem = *f;
                elem.type = IMP_PROTO_T_STRING;
                elem.min = 1;
                elem.max = 64;
                for (size_t i = 0; i < n; i++) {
                        char p[sizeof e->field];
                        snprintf(p, sizeof p, "%s[%zu]", path, i);
                        int r = check_value(&elem, json_array_get(v, i), p, e);
                        if (r < 0)
                                return r;
                }
                return 0;
        }
        }
        return bad_arg(e, path, "unsupported argument type");
}

static const char *type_noun(const struct imp_proto_field *f) {
        switch (f->type) {
        case IMP_PROTO_T_STRING: return "a string";
        case IMP_PROTO_T_INTEGER: return "an integer";
        case IMP_PROTO_T_BOOLEAN: return "true or false";
        case IMP_PROTO_T_OBJECT: return "an object";
        default: return "an array of strings";
        }
}

static int check_args(const struct imp_proto_command *c, const json_t *args, struct imp_proto_error *e) {
        char path[sizeof e->field];
        for (const struct imp_proto_field *f = c->fields; f->name; f++) {
                snprintf(path, sizeof path, "args.%s", f->name);
                const json_t *v = json_object_get(args, f->name);
                if (!v || json_is_null(v)) {
                        if (f->flags & IMP_PROTO_F_REQUIRED)
                                return bad_arg(e, path, "missing; expected %s (%s)", type_noun(f), f->what);
                        continue;
                }
                int r = check_value(f, v, path, e);
                if (r < 0)
                        return r;
        }
        const char *key;
        const json_t *v;
        json_object_foreach((json_t *) args, key, v) {
                const struct imp_proto_field *f = c->fields;
                while (f->name && strcmp(f->name, key))
                        f++;
                if (!f->name) {
                        char safe[64];
                        printable(safe, sizeof safe, key);
                        snprintf(path, sizeof path, "args.%s", safe);
                        return bad_arg(e, path, "unknown argument of %s", c->name);
                }
        }
        return 0;
}

/* Characters from 1 (UTF-8 continuation bytes do not count), as jansson reports columns. */
static int column_of(const char *line, size_t pos) {
        int col = 0;
        for (size_t i = 0; i <= pos; i++)
                if (((unsigned char) line[i] & 0xC0) != 0x80)
                        col++;
        return col;
}

/* Before parsing: no NUL bytes, and nesting within IMP_PROTO_DEPTH_MAX, so that hostile
 * input is turned away before the recursive parser sees it. */
static int prescan(const char *line, size_t len, struct imp_proto_error *e) {
        int depth = 0;
        bool in_string = false, escaped = false;
        for (size_t i = 0; i < len; i++) {
                char ch = line[i];
                if (ch == '\0')
                        return imp_proto_error_set(e, IMP_PROTO_E_BAD_JSON, EBADMSG, NULL,
                                                   "invalid JSON at column %d: NUL byte", column_of(line, i));
                if (in_string) {
                        if (escaped)
                                escaped = false;
                        else if (ch == '\\')
                                escaped = true;
                        else if (ch == '"')
                                in_string = false;
                } else if (ch == '"') {
                        in_string = true;
                } else if (ch == '[' || ch == '{') {
                        if (++depth > IMP_PROTO_DEPTH_MAX)
                                return imp_proto_error_set(e, IMP_PROTO_E_BAD_JSON, EBADMSG, NULL,
                                                           "invalid JSON at column %d: nested deeper than %d levels",
                                                           column_of(line, i), IMP_PROTO_DEPTH_MAX);
                } else if (ch == ']' || ch == '}') {
                        depth--;
                }
        }
        return 0;
}

/* Parse one line into *ret (an object unless allow_any); codes for the peer's direction. */
static int load_line(const char *line, size_t len, size_t max, json_t **ret, struct imp_proto_error *e) {
        if (len > max)
                return imp_proto_error_set(e, IMP_PROTO_E_TOO_LONG, E2BIG, NULL,
                                           "line of %zu bytes exceeds the limit of %zu bytes", len, max);
        int r = prescan(line, len, e);
        if (r < 0)
                return r;
        json_error_t je;
        json_t *j = json_loadb(line, len, JSON_DECODE_ANY | JSON_REJECT_DUPLICATES, &je);
        if (!j) {
                if (json_error_code(&je) == json_error_out_of_memory)
                        return imp_proto_error_set(e, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_JSON, EBADMSG, NULL,
                                           "invalid JSON at column %d: %s", je.column, je.text);
        }
        if (!json_is_object(j)) {
                r = imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, NULL,
                                        "expected a JSON object, got %s", imp_json_type_name(j));
                json_decref(j);
                return r;
        }
        *ret = j;
        return 0;
}

static int check_id(const json_t *id, struct imp_proto_error *e) {
        if (!id)
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, "id",
                                           "missing; expected an integer or a string");
        if (json_is_integer(id))
                return 0;
        if (!json_is_string(id))
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, "id",
                                           "expected an integer or a string, got %s", imp_json_type_name(id));
        size_t n = json_string_length(id);
        if (n < 1 || n > IMP_PROTO_ID_MAX || strlen(json_string_value(id)) != n)
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, "id",
                                           "expected a string of 1 to %d bytes without NUL", IMP_PROTO_ID_MAX);
        return 0;
}

/* Everything after the id: cmd, args, members, role, argument schema. */
static int check_request(json_t *root, enum imp_proto_role role, const struct imp_proto_command **ret_cmd,
                         struct imp_proto_error *e) {
        json_t *cmd = json_object_get(root, "cmd");
        if (!cmd)
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, "cmd", "missing; expected a command name");
        if (!json_is_string(cmd))
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, "cmd",
                                           "expected a string (a command name), got %s", imp_json_type_name(cmd));

        json_t *args = json_object_get(root, "args");
        if (args && !json_is_null(args) && !json_is_object(args))
                return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, "args",
                                           "expected an object, got %s", imp_json_type_name(args));
        const char *key;
        json_t *v;
        json_object_foreach(root, key, v)
                if (strcmp(key, "id") && strcmp(key, "cmd") && strcmp(key, "args")) {
                        char name[64];
                        printable(name, sizeof name, key);
                        return imp_proto_error_set(e, IMP_PROTO_E_BAD_REQUEST, EINVAL, name,
                                                   "unknown member; a request has only \"id\", \"cmd\" and \"args\"");
                }

        const struct imp_proto_command *c = imp_proto_command_find(json_string_value(cmd));
        if (!c || strlen(json_string_value(cmd)) != json_string_length(cmd))
                return imp_proto_error_set(e, IMP_PROTO_E_UNKNOWN_COMMAND, EOPNOTSUPP, "cmd",
                                           "unknown command; see PROTOCOL.md for the list");
        if (c->operator_only && role != IMP_PROTO_ROLE_OPERATOR)
                return imp_proto_error_set(e, IMP_PROTO_E_PERMISSION_DENIED, EPERM, "cmd",
                                           "%s needs the operator role (root or group %s)", c->name,
                                           IMP_PROTO_OPERATOR_GROUP);
        /* absent or null args: check_args sees NULL, which has no members */
        int r = check_args(c, json_is_object(args) ? args : NULL, e);
        if (r < 0)
                return r;
        *ret_cmd = c;
        return 0;
}

int imp_proto_parse_request(const char *line, size_t len, enum imp_proto_role role,
                            struct imp_proto_request *ret, struct imp_proto_error *ret_err) {
        _cleanup_proto_error_ struct imp_proto_error scratch = {};
        struct imp_proto_error *e = ret_err ? ret_err : &scratch;
        imp_proto_error_done(e);
        *e = (struct imp_proto_error) {};
        if (!line || !ret)
                return imp_proto_error_set(e, IMP_PROTO_E_INTERNAL, EINVAL, NULL, "invalid call");

        _cleanup_json_ json_t *root = NULL;
        int r = load_line(line, len, IMP_PROTO_REQUEST_MAX, &root, e);
        if (r < 0)
                return r;
        json_t *id = json_object_get(root, "id");
        r = check_id(id, e);
        if (r < 0)
                return r;
        const struct imp_proto_command *c = NULL;
        r = check_request(root, role, &c, e);
        if (r < 0) {
                e->id = json_incref(id);
                return r;
        }
        json_t *args = json_object_get(root, "args");
        json_t *a = json_is_object(args) ? json_incref(args) : json_object();
        if (!a)
                return imp_proto_error_set(e, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
        *ret = (struct imp_proto_request) {
                .id = json_incref(id),
                .command = c,
                .args = a,
        };
        return 0;
}

void imp_proto_request_done(struct imp_proto_request *req) {
        if (!req)
                return;
        json_decref(req->id);
        json_decref(req->args);
        req->id = req->args = NULL;
        req->command = NULL;
}

/* ---- Builders ---- */

json_t *imp_proto_banner(enum imp_proto_role role) {
        return json_pack("{s:s, s:i, s:s}", "impasto", IMPASTO_VERSION_STRING, "protocol", IMP_PROTO_VERSION,
                         "role", imp_proto_role_name(role));
}

static json_t *id_or_null(const json_t *id) {
        return id ? json_incref((json_t *) id) : json_null();
}

json_t *imp_proto_reply_ok(const json_t *id, json_t *result) {
        if (!result)
                result = json_object();
        if (!result)
                return NULL;
        /* "o" steals even when packing fails */
        return json_pack("{s:o, s:b, s:o}", "id", id_or_null(id), "ok", 1, "result", result);
}

/* A JSON string of s; bytes that do not form valid UTF-8 (a message cut mid-character, a
 * parser message quoting raw input) become '?'. */
static json_t *safe_string(const char *s) {
        json_t *j = json_string(s);
        if (j)
                return j;
        char buf[1024];
        size_t i = 0;
        for (; s[i] && i < sizeof buf - 1; i++)
                buf[i] = (unsigned char) s[i] < 0x80 ? s[i] : '?';
        buf[i] = 0;
        return json_string(buf);
}

json_t *imp_proto_reply_error(const json_t *id, const struct imp_proto_error *e) {
        if (!e)
                return NULL;
        json_t *err = json_pack("{s:s, s:i, s:o}", "code", imp_proto_error_code_name(e->code),
                                "errno", e->sys_errno > 0 ? e->sys_errno : 0,
                                "message", safe_string(e->message));
        if (err && e->field[0] && json_object_set_new(err, "field", safe_string(e->field)) < 0) {
                json_decref(err);
                return NULL;
        }
        if (!err)
                return NULL;
        return json_pack("{s:o, s:b, s:o}", "id", id_or_null(id ? id : e->id), "ok", 0, "error", err);
}

json_t *imp_proto_event(const char *type, unsigned long long seq, json_t *fields) {
        _cleanup_json_ json_t *f = fields;
        if (!imp_proto_event_type_valid(type) || (f && !json_is_object(f)) || seq > (unsigned long long) LLONG_MAX)
                return NULL;
        _cleanup_json_ json_t *ev = json_pack("{s:s, s:I}", "event", type, "seq", (json_int_t) seq);
        if (!ev || (f && json_object_update_missing(ev, f) < 0))
                return NULL;
        return TAKE_PTR(ev);
}

char *imp_proto_dump_line(const json_t *msg) {
        if (!msg)
                return NULL;
        _cleanup_free_ char *s = json_dumps(msg, JSON_COMPACT | JSON_ENCODE_ANY);
        if (!s)
                return NULL;
        size_t n = strlen(s);
        char *line = realloc(s, n + 2);
        if (!line)
                return NULL;
        s = NULL;
        line[n] = '\n';
        line[n + 1] = '\0';
        return line;
}

/* ---- Client side ---- */

static int bad_msg(struct imp_proto_error *e, const char *field, const char *fmt, ...) _printf_(3, 4);
static int bad_msg(struct imp_proto_error *e, const char *field, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        verror_set(e, IMP_PROTO_E_BAD_REQUEST, EBADMSG, field, fmt, ap);
        va_end(ap);
        return -EBADMSG;
}

static int decode_error(const json_t *err, struct imp_proto_error *out, struct imp_proto_error *e) {
        const json_t *code = json_object_get(err, "code"), *no = json_object_get(err, "errno"),
                     *msg = json_object_get(err, "message"), *field = json_object_get(err, "field");
        if (!json_is_object(err))
                return bad_msg(e, "error", "expected an object");
        if (!json_is_string(code))
                return bad_msg(e, "error.code", "expected a string");
        if (!json_is_integer(no) || json_integer_value(no) < 0 || json_integer_value(no) > INT_MAX)
                return bad_msg(e, "error.errno", "expected an integer >= 0");
        if (!json_is_string(msg))
                return bad_msg(e, "error.message", "expected a string");
        if (field && !json_is_string(field))
                return bad_msg(e, "error.field", "expected a string");
        *out = (struct imp_proto_error) {
                .code = imp_proto_error_code_from_name(json_string_value(code)),
                .sys_errno = (int) json_integer_value(no),
        };
        snprintf(out->message, sizeof out->message, "%s", json_string_value(msg));
        if (field)
                snprintf(out->field, sizeof out->field, "%s", json_string_value(field));
        return 0;
}

static int decode_message(json_t *root, struct imp_proto_message *m, struct imp_proto_error *e) {
        const json_t *v;
        if ((v = json_object_get(root, "event"))) {
                const json_t *seq = json_object_get(root, "seq");
                if (!json_is_string(v))
                        return bad_msg(e, "event", "expected a string");
                if (!json_is_integer(seq) || json_integer_value(seq) < 0)
                        return bad_msg(e, "seq", "expected an integer >= 0");
                m->kind = IMP_PROTO_MSG_EVENT;
                m->event = json_string_value(v);
                m->seq = (unsigned long long) json_integer_value(seq);
                m->session = json_object_get(root, "session");
                return 0;
        }
        if ((v = json_object_get(root, "ok"))) {
                const json_t *id = json_object_get(root, "id");
                if (!json_is_boolean(v))
                        return bad_msg(e, "ok", "expected true or false");
                if (!id || !(json_is_integer(id) || json_is_string(id) || json_is_null(id)))
                        return bad_msg(e, "id", "expected an integer, a string or null");
                m->kind = IMP_PROTO_MSG_REPLY;
                m->id = id;
                m->ok = json_is_true(v);
                if (m->ok) {
                        m->result = json_object_get(root, "result");
                        if (!json_is_object(m->result))
                                return bad_msg(e, "result", "expected an object");
                        return 0;
                }
                return decode_error(json_object_get(root, "error"), &m->error, e);
        }
        if ((v = json_object_get(root, "impasto"))) {
                const json_t *proto = json_object_get(root, "protocol"), *role = json_object_get(root, "role");
                if (!json_is_string(v))
                        return bad_msg(e, "impasto", "expected a version string");
                if (!json_is_integer(proto))
                        return bad_msg(e, "protocol", "expected an integer");
                if (!json_is_string(role) || (strcmp(json_string_value(role), "observer") &&
                                              strcmp(json_string_value(role), "operator")))
                        return bad_msg(e, "role", "expected \"observer\" or \"operator\"");
                m->kind = IMP_PROTO_MSG_BANNER;
                m->version = json_string_value(v);
                m->protocol = json_integer_value(proto);
                m->role = strcmp(json_string_value(role), "operator") ? IMP_PROTO_ROLE_OBSERVER
                                                                       : IMP_PROTO_ROLE_OPERATOR;
                return 0;
        }
        return bad_msg(e, NULL, "not a banner, reply or event");
}

int imp_proto_parse_reply(const char *line, size_t len, struct imp_proto_message *ret,
                          struct imp_proto_error *ret_err) {
        struct imp_proto_error scratch = {};
        struct imp_proto_error *e = ret_err ? ret_err : &scratch;
        imp_proto_error_done(e);
        *e = (struct imp_proto_error) {};
        if (!line || !ret)
                return imp_proto_error_set(e, IMP_PROTO_E_INTERNAL, EINVAL, NULL, "invalid call");
        _cleanup_json_ json_t *root = NULL;
        int r = load_line(line, len, IMP_PROTO_MESSAGE_MAX, &root, e);
        if (r < 0)
                return r == -EINVAL ? -EBADMSG : r;
        struct imp_proto_message m = {};
        r = decode_message(root, &m, e);
        if (r < 0)
                return r;
        m.root = TAKE_PTR(root);
        *ret = m;
        return 0;
}

void imp_proto_message_done(struct imp_proto_message *m) {
        if (!m)
                return;
        json_decref(m->root);
        *m = (struct imp_proto_message) {};
}
