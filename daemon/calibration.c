/* Calibrations run by the daemon: `calibrate` captures the frames a routine needs
 * as an ordinary session of the routine's plan, then runs the offline routine
 * (`impasto calibrate ROUTINE --set SET --json --out …`, the same code as from image folders)
 * on the completed set as a durable job of the daemon's own, and stores the result as a new
 * calibration version STATE/calibrations/<N>/ (rig.json, report.json, calibration.json) that
 * becomes the rig of every later session; each set names its version in calibration.json.
 * The job file is rewritten atomically at every state change, so a daemon killed at any
 * moment finds each calibration capturing, queued (run again), or finished. */
#define _GNU_SOURCE 1
#include <dirent.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdarg.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "impastod.h"
#include "json-util.h"
#include "log.h"

#define CALIB_RETRY_DELAY_US 500000ULL  /* before attempt n+1: n × this */
#define CALIB_FIGURES_MAX 64            /* scalars kept from a report */
#define CALIB_ARG_MAX 1024              /* bytes of one routine parameter */
#define IMP_CALIB_MAX_SETS 30           /* earlier sessions joining a calibration (board poses) */
#define IMP_CALIB_MAX_MM 1000.0         /* lengths and board heights, in mm (a dome is ~500 mm) */
#define EXIT_ROUTINE_USAGE 2            /* the routine's exit codes that another attempt cannot fix */
#define EXIT_ROUTINE_BAD_INPUT 3
#define EXIT_ROUTINE_UNDETERMINED 6     /* projector gamma outside the search's bounds */

static const char *const state_names[] = { "capturing", "queued", "running", "done", "failed" };

/* Routine parameters accepted in the `args` object, each passed to the offline routine as
 * one option. */
enum arg_kind {
        ARG_VALUE,                      /* a value, passed as it is (arg_text()) */
        ARG_MM,                         /* a length in mm, |v| <= IMP_CALIB_MAX_MM */
        ARG_MM_POSITIVE,                /* a length in mm, 0 < v <= IMP_CALIB_MAX_MM */
        ARG_FLAG,                       /* true: the option alone; false: nothing */
        ARG_SESSION,                    /* a completed session of this daemon: its set directory */
        ARG_MORE_SETS,                  /* completed sessions whose sets join the routine's own */
        ARG_MORE_SETS_AT,               /* the same as "ID@Z", Z the board height in mm: OPTION DIR@Z each */
};

struct routine_arg {
        const char *key, *option;       /* option NULL: ARG_MORE_SETS, the sets follow --sets SET */
        bool required;                  /* with alt: this one or alt */
        enum arg_kind kind;
        const char *alt;                /* never both; see required */
        const char *needs;              /* given only together with this one */
};

struct routine {
        const char *name;
        const char *tool;               /* impasto calibrate TOOL */
        const char *plan;               /* the default plan, looked up in the plan directories */
        const char *set_option;         /* "--set", "--sets" or "--projector-set" */
        const struct routine_arg *args;
};

static const struct routine_arg radiometric_args[] = {
        { "camera", "--camera", false }, { "roi", "--roi", false }, {},
};
static const struct routine_arg gamma_args[] = {
        { "camera", "--camera", false }, {},
};
/* The mirrors detected in each set (sphere_radius, with sphere_cut or hemispheres), or their
 * positions given (spheres, one set only). Sets at other board heights (sessions, "ID@Z")
 * add the vertical baseline the low rings need (docs/calibration-lights.md). */
static const struct routine_arg lights_args[] = {
        { "sphere_radius", "--sphere-radius", true, ARG_MM_POSITIVE, "spheres" },
        { "spheres", "--spheres", true, ARG_VALUE, "sphere_radius" },
        { "sphere_cut", "--sphere-cut", false, ARG_MM, "hemispheres", "sphere_radius" },
        { "hemispheres", "--hemispheres", false, ARG_FLAG, NULL, "sphere_radius" },
        { "sessions", "--set", false, ARG_MORE_SETS_AT, NULL, "sphere_radius" },
        { "plane_z_mm", "--plane-z", false, ARG_MM }, { "camera", "--camera", false },
        { "white", "--white", false }, { "dome", "--dome", false }, {},
};
static const struct routine_arg procam_args[] = {
        { "board", "--board", true }, { "square", "--square", true }, { "projector", "--projector", false },
        { "mm_per_unit", "--mm-per-unit", false }, { "black_threshold", "--black-threshold", false },
        { "white_threshold", "--white-threshold", false }, { "window", "--window", false },
        /* a board needs several poses: the sets of earlier sessions (one pose each) join this
         * capture's; the reference pose lies on the canvas and fixes the canvas frame */
        { "sessions", NULL, false, ARG_MORE_SETS }, { "reference", "--reference", false, ARG_SESSION },
        { "board_origin", "--board-origin", false }, {},
};

/* camera: the Gray-code target set calibrates the camera together with the projector. */
static const struct routine routines[] = {
        { "camera", "procam", "target.cfg", "--sets", procam_args },
        { "procam", "procam", "target.cfg", "--sets", procam_args },
        { "lights", "lights", "lights.cfg", "--set", lights_args },
        { "radiometric", "radiometric", "photon-transfer.cfg", "--set", radiometric_args },
        /* the projector's gamma and black level: a white board under phase shifts */
        { "projector-gamma", "radiometric", "projector-gamma.cfg", "--projector-set", gamma_args },
};

static const struct routine *routine_find(const char *name) {
        for (size_t i = 0; i < ARRAY_SIZE(routines); i++)
                if (name && !strcmp(routines[i].name, name))
                        return &routines[i];
        return NULL;
}

static const struct routine_arg *routine_arg_find(const struct routine *rt, const char *key) {
        for (const struct routine_arg *a = rt->args; a->key; a++)
                if (!strcmp(a->key, key))
                        return a;
        return NULL;
}

/* A parameter as the routine's command line wants it: a string as it is, a number, numbers
 * joined by ',' ([x, y, w, h]), lists of numbers joined by ';' ([[x, y, r], …]). */
static int arg_text(const json_t *v, char *buf, size_t size) {
        if (json_is_string(v)) {
                if (json_string_length(v) == 0 || json_string_length(v) >= size)
                        return -EINVAL;
                snprintf(buf, size, "%s", json_string_value(v));
                return 0;
        }
        if (json_is_number(v)) {
                snprintf(buf, size, "%.17g", json_number_value(v));
                return 0;
        }
        if (!json_is_array(v) || json_array_size(v) == 0)
                return -EINVAL;
        size_t i, n = 0;
        json_t *e;
        buf[0] = 0;
        json_array_foreach(v, i, e) {
                bool inner = json_is_array(e);
                char part[CALIB_ARG_MAX];
                if (inner) {
                        if (arg_text(e, part, sizeof part) < 0 || json_is_array(json_array_get(e, 0)))
                                return -EINVAL;
                } else if (json_is_number(e))
                        snprintf(part, sizeof part, "%.17g", json_number_value(e));
                else
                        return -EINVAL;
                int k = snprintf(buf + n, size - n, "%s%s", i ? (inner ? ";" : ",") : "", part);
                if (k < 0 || (size_t) k >= size - n)
                        return -EINVAL;
                n += (size_t) k;
        }
        return 0;
}

/* A session as a routine parameter: "ID", or for ARG_MORE_SETS_AT "ID@Z" (Z the board height
 * of its capture in mm; session ids are tokens, without '@'). The id goes to id; the set
 * of the completed session of this daemon to *ret_dir. -EINVAL: not of that shape; -ERANGE:
 * Z is not a height; -ENOENT: no completed session of that id. */
static int session_ref(struct daemon *d, const struct routine_arg *a, const json_t *v, char *id, size_t size,
                       const char **ret_dir, double *ret_z) {
        const char *s = json_string_value(v), *at = NULL;
        if (!s)
                return -EINVAL;
        double z = 0;
        if (a->kind == ARG_MORE_SETS_AT) {
                char *end;
                if (!(at = strrchr(s, '@')))
                        return -EINVAL;
                z = strtod(at + 1, &end);
                if (end == at + 1 || *end || !isfinite(z) || fabs(z) > IMP_CALIB_MAX_MM)
                        return -ERANGE;
        }
        size_t n = at ? (size_t) (at - s) : strlen(s);
        if (n == 0 || n >= size)
                return -EINVAL;
        memcpy(id, s, n);
        id[n] = 0;
        struct session *ses = session_find(d, id);
        if (!ses || ses->state != SESSION_COMPLETED)
                return -ENOENT;
        *ret_dir = ses->dir;
        *ret_z = z;
        return 0;
}

static int check_sessions(struct daemon *d, const struct routine_arg *a, const json_t *v, const char *field,
                          struct imp_proto_error *perr) {
        bool list = a->kind != ARG_SESSION, at = a->kind == ARG_MORE_SETS_AT;
        const char *shape = at ? "\"ID@Z\": a completed session of this daemon and the board height of its "
                                 "capture in mm" : "a session id";
        size_t i, n = list ? json_array_size(v) : 1;
        if (list && (!json_is_array(v) || n == 0 || n > IMP_CALIB_MAX_SETS))
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                           "expected a list of 1 to %d %s", IMP_CALIB_MAX_SETS,
                                           at ? "\"ID@Z\" strings (a completed session, its board height in mm)"
                                              : "session ids");
        char ids[IMP_CALIB_MAX_SETS][128];
        for (i = 0; i < n; i++) {
                const json_t *e = list ? json_array_get(v, i) : v;
                const char *dir, *s = json_is_string(e) ? json_string_value(e) : "(not a string)";
                double z;
                char ef[128];
                if (list)
                        snprintf(ef, sizeof ef, "%.100s[%zu]", field, i);
                else
                        snprintf(ef, sizeof ef, "%.100s", field);
                int r = session_ref(d, a, e, ids[i], sizeof ids[i], &dir, &z);
                if (r == -ERANGE)
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, ef,
                                                   "%.200s: the board height after '@' must be a number of mm from "
                                                   "%g to %g", s, -IMP_CALIB_MAX_MM, IMP_CALIB_MAX_MM);
                if (r == -EINVAL)
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, ef, "%.200s: expected %s",
                                                   s, shape);
                if (r < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, ef,
                                                   "%s is not a completed session of this daemon", ids[i]);
                for (size_t k = 0; k < i; k++)
                        if (!strcmp(ids[k], ids[i]))
                                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, ef,
                                                           "%s is listed twice", ids[i]);
        }
        return 0;
}

static int check_value(struct daemon *d, const struct routine_arg *a, const json_t *v, const char *field,
                       struct imp_proto_error *perr) {
        char text[CALIB_ARG_MAX];
        double x = json_number_value(v);
        switch (a->kind) {
        case ARG_MM:
        case ARG_MM_POSITIVE:
                if (!json_is_number(v) || !isfinite(x) || fabs(x) > IMP_CALIB_MAX_MM ||
                    (a->kind == ARG_MM_POSITIVE && !(x > 0)))
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                   "expected a number of mm %s %g", a->kind == ARG_MM ?
                                                   "from -1000 to" : "above 0, at most", IMP_CALIB_MAX_MM);
                return 0;
        case ARG_FLAG:
                if (!json_is_boolean(v))
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                   "expected true or false");
                return 0;
        case ARG_VALUE:
                if (arg_text(v, text, sizeof text) < 0)
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                   "expected a string, a number or a list of numbers (or of "
                                                   "lists of numbers), at most %d bytes", CALIB_ARG_MAX - 1);
                return 0;
        default:
                return check_sessions(d, a, v, field, perr);
        }
}

static bool arg_given(const json_t *args, const char *key) {
        const json_t *v = key ? json_object_get(args, key) : NULL;
        return v && !json_is_false(v);
}

/* Each parameter on its own, then the rules between them: required (this one or its alt),
 * never both of a pair, needs. */
static int check_args(struct daemon *d, const struct routine *rt, const json_t *args, struct imp_proto_error *perr) {
        const char *key;
        json_t *v;
        char field[96];
        json_object_foreach((json_t *) args, key, v) {
                snprintf(field, sizeof field, "args.args.%.60s", key);
                const struct routine_arg *a = routine_arg_find(rt, key);
                if (!a) {
                        char known[256] = "";
                        for (const struct routine_arg *k = rt->args; k->key; k++)
                                snprintf(known + strlen(known), sizeof known - strlen(known), "%s%s",
                                         k == rt->args ? "" : ", ", k->key);
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                   "unknown parameter of the %s routine (known: %s)", rt->name, known);
                }
                int r = check_value(d, a, v, field, perr);
                if (r < 0)
                        return r;
        }
        for (const struct routine_arg *a = rt->args; a->key; a++) {
                bool given = arg_given(args, a->key);
                snprintf(field, sizeof field, "args.args.%s", a->key);
                if (a->required && !given && !arg_given(args, a->alt))
                        return a->alt ? imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                            "missing; the %s routine needs %s or %s (%s or %s of "
                                                            "`impasto calibrate %s`)", rt->name, a->key, a->alt,
                                                            a->option, routine_arg_find(rt, a->alt)->option, rt->tool)
                                      : imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                            "missing; the %s routine needs it (%s of `impasto "
                                                            "calibrate %s`)", rt->name, a->option, rt->tool);
                if (given && arg_given(args, a->alt))
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                   "given together with %s: give one of the two", a->alt);
                if (given && a->needs && !arg_given(args, a->needs))
                        return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, field,
                                                   "only together with %s, which is not given", a->needs);
        }
        /* the board cuts the spheres between their bottom and their top */
        const json_t *cut = json_object_get(args, "sphere_cut"), *radius = json_object_get(args, "sphere_radius");
        if (cut && radius && !(fabs(json_number_value(cut)) < json_number_value(radius)))
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, "args.args.sphere_cut",
                                           "the board cuts the spheres this far above their centres: expected "
                                           "less than sphere_radius (%g mm) either way", json_number_value(radius));
        return 0;
}

/* ---- the job file --------------------------------------------------------------------------- */

static void calib_path(const struct calibration *c, const char *name, char *buf, size_t size) {
        snprintf(buf, size, "%s/%s", c->dir, name);
}

static json_t *calib_file_json(const struct calibration *c) {
        return json_pack("{s:i, s:s, s:s, s:s, s:s, s:s, s:O, s:i, s:i, s:i, s:s, s:s?, s:s?, s:s?, s:O?}", "version",
                         c->version, "routine", c->routine, "session", c->session, "capture", c->set_dir, "plan",
                         c->plan, "state", state_names[c->state], "args", c->args, "attempts", c->attempts,
                         "max_attempts", c->max_attempts, "based_on", c->based_on, "created", c->created, "started",
                         c->started[0] ? c->started : NULL, "ended", c->ended[0] ? c->ended : NULL, "error",
                         c->error[0] ? c->error : NULL, "figures", c->figures);
}

static int calib_save(struct calibration *c) {
        char p[PATH_MAX + 32];
        calib_path(c, "calibration.json", p, sizeof p);
        _cleanup_json_ json_t *j = calib_file_json(c);
        struct imp_error e = { 0 };
        int r = j ? imp_json_save_atomic(p, j, &e) : -ENOMEM;
        if (r < 0)
                log_error_errno(r, "calibration %s: %s", c->id, e.msg[0] ? e.msg : "out of memory");
        return r;
}

/* Cut to fit (maybe inside a character) and made valid UTF-8: calibration_json would fail. */
static void copy_str(const json_t *j, const char *key, char *buf, size_t size) {
        const char *s = json_string_value(json_object_get(j, key));
        snprintf(buf, size, "%s", s ? s : "");
        (void) imp_utf8_sanitize(buf);
}

static int calib_read(struct calibration *c) {
        char p[PATH_MAX + 32];
        calib_path(c, "calibration.json", p, sizeof p);
        _cleanup_json_ json_t *j = NULL;
        struct imp_error e = { 0 };
        int r = imp_json_load(p, &j, &e);
        if (r < 0) {
                log_warning_errno(r, "calibration %s: %s, ignoring", c->id, e.msg);
                return r;
        }
        const char *st = json_string_value(json_object_get(j, "state"));
        int state = -1;
        for (size_t i = 0; i < ARRAY_SIZE(state_names); i++)
                if (st && !strcmp(st, state_names[i]))
                        state = (int) i;
        if (state < 0 || !routine_find(json_string_value(json_object_get(j, "routine")))) {
                log_warning("calibration %s: %s: bad state or routine, ignoring", c->id, p);
                return -EBADMSG;
        }
        /* read as they were, -5 attempts or a max_attempts of 2^31 retried without end (the
         * bound: --job-attempts', which the daemon writes here) */
        json_t *na = json_object_get(j, "attempts"), *nm = json_object_get(j, "max_attempts");
        if ((na && (!json_is_integer(na) || json_integer_value(na) < 0 || json_integer_value(na) > INT_MAX)) ||
            (nm && (!json_is_integer(nm) || json_integer_value(nm) < 1 ||
                    json_integer_value(nm) > DAEMON_ATTEMPTS_MAX))) {
                log_warning("calibration %s: %s: attempts: expected an integer from 0, max_attempts one from 1 to %d, "
                            "ignoring", c->id, p, DAEMON_ATTEMPTS_MAX);
                return -EBADMSG;
        }
        c->state = (enum calib_state) state;
        copy_str(j, "routine", c->routine, sizeof c->routine);
        copy_str(j, "session", c->session, sizeof c->session);
        copy_str(j, "capture", c->set_dir, sizeof c->set_dir);
        copy_str(j, "plan", c->plan, sizeof c->plan);
        copy_str(j, "created", c->created, sizeof c->created);
        copy_str(j, "started", c->started, sizeof c->started);
        copy_str(j, "ended", c->ended, sizeof c->ended);
        copy_str(j, "error", c->error, sizeof c->error);
        c->attempts = (int) json_integer_value(json_object_get(j, "attempts"));
        c->max_attempts = IMP_MAX((int) json_integer_value(json_object_get(j, "max_attempts")), 1);
        c->based_on = (int) json_integer_value(json_object_get(j, "based_on"));
        json_t *a = json_object_get(j, "args");
        c->args = json_is_object(a) ? json_incref(a) : json_object();
        json_t *f = json_object_get(j, "figures");
        c->figures = json_is_object(f) ? json_incref(f) : NULL;
        return 0;
}

/* ---- events and views ------------------------------------------------------------------------ */

json_t *calibration_json(const struct calibration *c, bool full) {
        json_t *err = c->state == CALIB_FAILED && c->error[0] ?
                      json_pack("{s:s, s:i, s:s}", "code", "internal", "errno", 0, "message", c->error) : NULL;
        json_t *j = json_pack("{s:s, s:i, s:s, s:s, s:s, s:s, s:i, s:O?, s:o?}", "calibration", c->id, "version",
                              c->version, "routine", c->routine, "session", c->session, "state",
                              state_names[c->state], "created", c->created, "attempts", c->attempts, "figures",
                              c->figures, "error", err);
        if (j && full) {
                json_object_set_new(j, "path", json_string(c->dir));
                json_object_set_new(j, "capture", json_string(c->set_dir));
                json_object_set_new(j, "plan", json_string(c->plan));
                json_object_set(j, "args", c->args);
                json_object_set_new(j, "max_attempts", json_integer(c->max_attempts));
                json_object_set_new(j, "based_on", json_integer(c->based_on));
                json_object_set_new(j, "current", json_boolean(c->version == c->d->calib_version));
                json_object_set_new(j, "started", c->started[0] ? json_string(c->started) : json_null());
                json_object_set_new(j, "ended", c->ended[0] ? json_string(c->ended) : json_null());
                if (c->state == CALIB_DONE) {
                        char p[PATH_MAX + 32];
                        calib_path(c, "rig.json", p, sizeof p);
                        json_object_set_new(j, "rig", json_string(p));
                        calib_path(c, "report.json", p, sizeof p);
                        json_object_set_new(j, "report", json_string(p));
                }
        }
        return j;
}

static void announce(struct calibration *c) {
        json_t *ev = calibration_json(c, false);
        if (!ev)
                return;
        json_object_del(ev, "created");
        json_object_set_new(ev, "max_attempts", json_integer(c->max_attempts));
        json_object_set_new(ev, "progress", json_real(c->state == CALIB_DONE ? 1.0 : c->state == CALIB_RUNNING ? 0.5
                                                       : c->state == CALIB_QUEUED ? 0.4 : 0.0));
        if (c->state == CALIB_DONE)
                json_object_set_new(ev, "path", json_string(c->dir));
        server_broadcast(c->d, "calibration", ev);
}

struct calibration *calibration_find(struct daemon *d, const char *id) {
        for (struct calibration *c = d->calibrations; c; c = c->next)
                if (id && !strcmp(c->id, id))
                        return c;
        return NULL;
}

bool calibrations_own_session(struct daemon *d, const char *session) {
        for (struct calibration *c = d->calibrations; c; c = c->next)
                if (!strcmp(c->session, session))
                        return true;
        return false;
}

json_t *calibration_current_json(struct daemon *d) {
        struct calibration *c = NULL;
        if (d->calib_version > 0) {
                char id[16];
                snprintf(id, sizeof id, "%d", d->calib_version);
                c = calibration_find(d, id);
        }
        return json_pack("{s:i, s:s, s:s?, s:s?, s:s?}", "version", d->calib_version, "file", d->rigcfg->calibration,
                         "date", c ? c->ended : NULL, "routine", c ? c->routine : NULL, "calibration",
                         c ? c->id : NULL);
}

int calibration_reference_set(struct daemon *d, const char *set_dir, struct imp_error *err) {
        char p[PATH_MAX + 32];
        snprintf(p, sizeof p, "%s/calibration.json", set_dir);
        _cleanup_json_ json_t *j = calibration_current_json(d);
        if (!j)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return imp_json_save_atomic(p, j, err);
}

/* ---- the routine as a child ----------------------------------------------------------------- */

static int calib_exited(sd_event_source *src, const siginfo_t *si, void *userdata);
static void calib_kick(struct daemon *d);

static void fail(struct calibration *c, const char *fmt, ...) _printf_(2, 3);
static void fail(struct calibration *c, const char *fmt, ...) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(c->error, sizeof c->error, fmt, ap);
        va_end(ap);
        c->state = CALIB_FAILED;
        rfc3339_now(c->ended);
        log_error("calibration %s (%s): %s", c->id, c->routine, c->error);
        (void) calib_save(c);
        announce(c);
}

static int spawn(struct calibration *c) {
        struct daemon *d = c->d;
        const struct routine *rt = routine_find(c->routine);
        char out[PATH_MAX + 32], report[PATH_MAX + 32], logf[PATH_MAX + 32];
        calib_path(c, "rig.json.tmp", out, sizeof out);
        calib_path(c, "report.json.tmp", report, sizeof report);
        calib_path(c, "routine.log", logf, sizeof logf);
        /* argv before the fork: the child only execs */
        enum { MAX_ARGV = 128, MAX_OPTION_ARGV = 40 };  /* options after the sets: --json, --out, values */
        const char *argv[MAX_ARGV];
        static char values[16][CALIB_ARG_MAX], sets_at[IMP_CALIB_MAX_SETS][PATH_MAX + 32];
        int n = 0, nv = 0, ns = 0;
        argv[n++] = d->calibrate_cmd;
        argv[n++] = "calibrate";
        argv[n++] = rt->tool;
        argv[n++] = rt->set_option;
        argv[n++] = c->set_dir;
        const char *key;
        json_t *v;
        /* the sets of earlier sessions: after this capture's on --sets SET…, or OPTION DIR@Z each */
        json_object_foreach(c->args, key, v) {
                const struct routine_arg *a = routine_arg_find(rt, key);
                size_t i;
                json_t *e;
                if (!a || (a->kind != ARG_MORE_SETS && a->kind != ARG_MORE_SETS_AT))
                        continue;
                json_array_foreach(v, i, e) {
                        char id[128];
                        const char *dir;
                        double z;
                        if (session_ref(d, a, e, id, sizeof id, &dir, &z) < 0 || ns == IMP_CALIB_MAX_SETS ||
                            n + 2 > MAX_ARGV - MAX_OPTION_ARGV)
                                return -ENOENT;
                        if (a->kind == ARG_MORE_SETS) {
                                argv[n++] = dir;
                                continue;
                        }
                        snprintf(sets_at[ns], sizeof sets_at[ns], "%s@%.10g", dir, z);
                        argv[n++] = a->option;
                        argv[n++] = sets_at[ns++];
                }
        }
        argv[n++] = "--json";
        argv[n++] = "--out";
        argv[n++] = out;
        json_object_foreach(c->args, key, v) {
                const struct routine_arg *a = routine_arg_find(rt, key);
                if (a && (a->kind == ARG_MORE_SETS || a->kind == ARG_MORE_SETS_AT))
                        continue;
                if (!a || nv == (int) ARRAY_SIZE(values) || n + 3 > MAX_ARGV)
                        return -EINVAL;
                if (a->kind == ARG_FLAG) {
                        if (json_is_true(v))
                                argv[n++] = a->option;
                        continue;
                }
                char id[128];
                const char *set = NULL;
                double z;
                if (a->kind == ARG_SESSION ? session_ref(d, a, v, id, sizeof id, &set, &z) < 0
                                           : arg_text(v, values[nv], CALIB_ARG_MAX) < 0)
                        return -EINVAL;
                argv[n++] = a->option;
                argv[n++] = set ? set : values[nv++];
        }
        /* a board origin without a reference session: this capture is the pose on the canvas */
        if (json_object_get(c->args, "board_origin") && !json_object_get(c->args, "reference")) {
                argv[n++] = "--reference";
                argv[n++] = c->set_dir;
        }
        argv[n] = NULL;
        int fo = open(report, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0640);
        int fe = open(logf, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0640);
        if (fo < 0 || fe < 0) {
                int r = negative_errno();
                if (fo >= 0)
                        close(fo);
                if (fe >= 0)
                        close(fe);
                return r;
        }
        dprintf(fe, "---- attempt %d:", c->attempts);
        for (int i = 0; i < n; i++)
                dprintf(fe, " %s", argv[i]);
        dprintf(fe, "\n");
        int r = daemon_spawn(d, argv, fo, fe, calib_exited, c, &c->pid, &c->child_source);
        close(fo), close(fe);
        return r;
}

/* The last non-empty line the routine wrote to its log: its error message. */
static void last_log_line(const struct calibration *c, char *buf, size_t size) {
        char p[PATH_MAX + 32], line[512];
        calib_path(c, "routine.log", p, sizeof p);
        buf[0] = 0;
        _cleanup_fclose_ FILE *f = fopen(p, "re");
        while (f && fgets(line, sizeof line, f)) {
                line[strcspn(line, "\n")] = 0;
                if (line[0] && strncmp(line, "---- attempt", 12))
                        snprintf(buf, size, "%.500s", line);
        }
}

static bool is_scalar(const json_t *v) {
        return json_is_number(v) || json_is_string(v) || json_is_boolean(v);
}

/* An array of objects (one per light, per board view): per member, the largest number or
 * the count of true ("lights.located.true": 48, "lights.rms_mm.max": 1.9). */
static void array_figures(json_t *f, const char *k, const json_t *arr) {
        const json_t *first = json_array_get(arr, 0), *e;
        const char *m;
        json_t *mv;
        json_object_foreach((json_t *) first, m, mv) {
                char name[160];
                bool num = json_is_number(mv);
                if (!num && !json_is_boolean(mv))
                        continue;
                double max = -INFINITY;
                json_int_t n_true = 0;
                size_t i;
                json_array_foreach(arr, i, e) {
                        const json_t *x = json_object_get(e, m);
                        if (num && json_is_number(x))
                                max = fmax(max, json_number_value(x));
                        n_true += json_is_true(x);
                }
                snprintf(name, sizeof name, "%.70s.%.70s.%s", k, m, num ? "max" : "true");
                json_object_set_new(f, name, num ? json_real(max) : json_integer(n_true));
        }
}

/* The report's scalars, objects flattened one level ("camera.rms_px"), arrays as counts
 * (and arrays of objects summarized, array_figures()). */
static json_t *figures_of(const json_t *report) {
        json_t *f = json_object();
        const char *k, *k2;
        json_t *v, *v2;
        json_object_foreach((json_t *) report, k, v) {
                char name[160];
                if (json_object_size(f) >= CALIB_FIGURES_MAX)
                        break;
                if (is_scalar(v))
                        json_object_set(f, k, v);
                else if (json_is_array(v)) {
                        snprintf(name, sizeof name, "%.80s.count", k);
                        json_object_set_new(f, name, json_integer((json_int_t) json_array_size(v)));
                        if (json_is_object(json_array_get(v, 0)))
                                array_figures(f, k, v);
                } else if (json_is_object(v))
                        json_object_foreach(v, k2, v2)
                                if (is_scalar(v2)) {
                                        snprintf(name, sizeof name, "%.70s.%.70s", k, k2);
                                        json_object_set(f, name, v2);
                                }
        }
        return f;
}

static int make_current(struct daemon *d, struct calibration *c, struct imp_error *err) {
        char rigp[PATH_MAX + 32], cur[PATH_MAX + 64], text[32];
        calib_path(c, "rig.json", rigp, sizeof rigp);
        struct imp_rig rig;
        int r = imp_rig_load(rigp, &rig, err);
        if (r < 0)
                return r;
        snprintf(cur, sizeof cur, "%s/calibrations/current", d->state_dir);
        int k = snprintf(text, sizeof text, "%d\n", c->version);
        if ((r = imp_file_write_atomic(cur, text, (size_t) k, err)) < 0) {
                imp_rig_free(&rig);
                return r;
        }
        if (d->have_rig)
                imp_rig_free(&d->rig);
        d->rig = rig;
        d->have_rig = true;
        d->calib_version = c->version;
        snprintf(d->rigcfg->calibration, sizeof d->rigcfg->calibration, "%.4000s", rigp);
        return 0;
}

/* The routine succeeded: keep its result under the final names and put it in force. */
static void finish_done(struct calibration *c) {
        char tmp[PATH_MAX + 32], fin[PATH_MAX + 32];
        struct imp_error e = { 0 };
        _cleanup_json_ json_t *report = NULL;
        calib_path(c, "report.json.tmp", tmp, sizeof tmp);
        int r = imp_json_load(tmp, &report, &e);
        if (r < 0) {
                fail(c, "the routine's report: %s", e.msg);
                return;
        }
        calib_path(c, "report.json", fin, sizeof fin);
        if ((r = imp_json_save_atomic(fin, report, &e)) < 0) {
                fail(c, "%s", e.msg);
                return;
        }
        (void) unlink(tmp);
        calib_path(c, "rig.json.tmp", tmp, sizeof tmp);
        calib_path(c, "rig.json", fin, sizeof fin);
        if (rename(tmp, fin) < 0) {
                fail(c, "%s: %s", fin, strerror(errno));
                return;
        }
        json_decref(c->figures);
        c->figures = figures_of(report);
        if ((r = make_current(c->d, c, &e)) < 0) {
                fail(c, "putting the result in force: %s", e.msg);
                return;
        }
        c->state = CALIB_DONE;
        c->error[0] = 0;
        rfc3339_now(c->ended);
        (void) calib_save(c);
        log_info("calibration %s (%s): done, now the rig's calibration (%s)", c->id, c->routine, fin);
        announce(c);
}

static int retry_timer(sd_event_source *src, uint64_t usec, void *userdata) {
        calib_kick(userdata);
        return 0;
}

static void schedule(struct daemon *d, uint64_t delay_us) {
        if (d->stopping)
                return;
        d->calib_timer = sd_event_source_disable_unref(d->calib_timer);
        (void) sd_event_add_time_relative(d->event, &d->calib_timer, CLOCK_MONOTONIC, delay_us, 0, retry_timer, d);
}

/* A failed attempt: again while attempts remain, unless the routine said the input is wrong. */
static void attempt_failed(struct calibration *c, int exit_code, const char *why) {
        bool final = exit_code == EXIT_ROUTINE_USAGE || exit_code == EXIT_ROUTINE_BAD_INPUT ||
                     exit_code == EXIT_ROUTINE_UNDETERMINED || c->attempts >= c->max_attempts;
        if (final) {
                fail(c, "%.900s (attempt %d of %d)", why, c->attempts, c->max_attempts);
                return;
        }
        snprintf(c->error, sizeof c->error, "%.900s (attempt %d of %d)", why, c->attempts, c->max_attempts);
        log_warning("calibration %s (%s): %s, retrying", c->id, c->routine, c->error);
        c->state = CALIB_QUEUED;
        (void) calib_save(c);
        announce(c);
        schedule(c->d, CALIB_RETRY_DELAY_US * (uint64_t) c->attempts);
}

static int calib_exited(sd_event_source *src, const siginfo_t *si, void *userdata) {
        struct calibration *c = userdata;
        struct daemon *d = c->d;
        c->child_source = sd_event_source_disable_unref(c->child_source);
        c->pid = 0;
        if (si->si_code == CLD_EXITED && si->si_status == 0)
                finish_done(c);
        else {
                char last[512], why[1024];
                last_log_line(c, last, sizeof last);
                snprintf(why, sizeof why, "impasto calibrate %s: %s %d%s%s", routine_find(c->routine)->tool,
                         si->si_code == CLD_EXITED ? "exit status" : "killed by signal", si->si_status,
                         last[0] ? ": " : "", last);
                attempt_failed(c, si->si_code == CLD_EXITED ? si->si_status : -1, why);
        }
        calib_kick(d);
        return 0;
}

/* One routine at a time, oldest queued first. */
static void calib_kick(struct daemon *d) {
        if (d->stopping)
                return;
        struct calibration *next = NULL;
        for (struct calibration *c = d->calibrations; c; c = c->next) {
                if (c->state == CALIB_RUNNING)
                        return;
                if (c->state == CALIB_QUEUED)
                        next = c;
        }
        if (!next)
                return;
        next->attempts++;
        next->state = CALIB_RUNNING;
        rfc3339_now(next->started);
        (void) calib_save(next);
        int r = spawn(next);
        if (r < 0) {
                char why[PATH_MAX + 64];
                snprintf(why, sizeof why, "starting %s: %s", d->calibrate_cmd, strerror(-r));
                attempt_failed(next, -1, why);
                return;
        }
        log_info("calibration %s (%s): running the routine on %s (attempt %d of %d)", next->id, next->routine,
                 next->set_dir, next->attempts, next->max_attempts);
        announce(next);
}

void calibrations_session_ended(struct daemon *d, const char *session, const char *state) {
        for (struct calibration *c = d->calibrations; c; c = c->next) {
                if (c->state != CALIB_CAPTURING || strcmp(c->session, session))
                        continue;
                if (!strcmp(state, "completed")) {
                        c->state = CALIB_QUEUED;
                        (void) calib_save(c);
                        announce(c);
                        schedule(d, 0);         /* after the session's own events */
                } else
                        fail(c, "the capture session %s ended %s", session, state);
        }
}

/* ---- start ------------------------------------------------------------------------------------- */

static struct calibration *calib_new(struct daemon *d, int version) {
        struct calibration *c = calloc(1, sizeof *c);
        if (!c)
                return NULL;
        c->d = d;
        c->version = version;
        snprintf(c->id, sizeof c->id, "%d", version);
        snprintf(c->dir, sizeof c->dir, "%s/calibrations/%d", d->state_dir, version);
        c->max_attempts = (int) d->job_attempts;
        return c;
}

static void calib_free(struct calibration *c) {
        if (!c)
                return;
        sd_event_source_disable_unref(c->child_source);
        json_decref(c->args);
        json_decref(c->figures);
        free(c);
}

/* The directory of the next version, created (mkdir is the claim on the number). */
static int next_version(struct daemon *d, int *ret) {
        int v = 1;
        for (struct calibration *c = d->calibrations; c; c = c->next)
                v = IMP_MAX(v, c->version + 1);
        for (int tries = 0; tries < 1000; tries++, v++) {
                char p[PATH_MAX + 32];
                snprintf(p, sizeof p, "%s/calibrations/%d", d->state_dir, v);
                if (mkdir(p, 0750) == 0) {
                        *ret = v;
                        return 0;
                }
                if (errno != EEXIST)
                        return negative_errno();
        }
        return -EEXIST;
}

int calibration_start(struct daemon *d, const char *routine, const json_t *args, const char *plan,
                      const char *name, const struct daemon_peer *peer, struct calibration **ret,
                      struct imp_proto_error *perr) {
        const struct routine *rt = routine_find(routine);
        if (!rt)
                return imp_proto_error_set(perr, IMP_PROTO_E_BAD_ARGUMENT, EINVAL, "args.routine",
                                           "unknown calibration routine %s", routine ? routine : "");
        _cleanup_json_ json_t *a = json_is_object(args) ? json_incref((json_t *) args) : json_object();
        int r = check_args(d, rt, a, perr);
        if (r < 0)
                return r;
        if (d->stopping)
                return imp_proto_error_set(perr, IMP_PROTO_E_SHUTTING_DOWN, ESHUTDOWN, NULL, "the daemon is stopping");
        if (d->active)
                return imp_proto_error_set(perr, IMP_PROTO_E_BUSY, EBUSY, NULL, "session %s holds the rig (%s)",
                                           d->active->id, session_state_name(d->active->state));
        char planp[PATH_MAX];
        if (plan) {
                if ((r = plan_path_resolve(d, peer, plan, "args.plan", planp, perr)) < 0)
                        return r;
        } else if (plan_path_builtin(d, rt->plan, planp) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_NOT_FOUND, ENOENT, "args.plan",
                                           "no plan given, and no plan directory (--plan-dir) holds %s, the %s "
                                           "routine's plan", rt->plan, rt->name);
        int version;
        if ((r = next_version(d, &version)) < 0)
                return imp_proto_error_set(perr, IMP_PROTO_E_IO, -r, NULL, "%s/calibrations: %s", d->state_dir,
                                           strerror(-r));
        struct calibration *c = calib_new(d, version);
        if (!c)
                return imp_proto_error_set(perr, IMP_PROTO_E_INTERNAL, ENOMEM, NULL, "out of memory");
        char sname[65];
        snprintf(sname, sizeof sname, "%s", name ? name : "");
        if (!name)
                snprintf(sname, sizeof sname, "calibrate-%s", rt->name);
        struct session *s = NULL;
        if ((r = session_start(d, planp, sname, &s, perr)) < 0) {
                (void) rmdir(c->dir);
                calib_free(c);
                return r;
        }
        snprintf(c->routine, sizeof c->routine, "%s", rt->name);
        snprintf(c->session, sizeof c->session, "%s", s->id);
        snprintf(c->set_dir, sizeof c->set_dir, "%s", s->dir);
        snprintf(c->plan, sizeof c->plan, "%s", planp);
        c->args = TAKE_PTR(a);
        c->based_on = d->calib_version;
        c->state = CALIB_CAPTURING;
        rfc3339_now(c->created);
        c->next = d->calibrations;
        d->calibrations = c;
        (void) calib_save(c);
        log_info("calibration %s (%s): capturing %s with plan %s", c->id, c->routine, c->session, planp);
        announce(c);
        *ret = c;
        return 0;
}

/* ---- load ------------------------------------------------------------------------------------- */

static int cmp_int(const void *a, const void *b) {
        return (*(const int *) a > *(const int *) b) - (*(const int *) a < *(const int *) b);
}

/* After a restart: a routine that was running is run again (its attempt counted); a capture
 * whose session ended while we were away is settled from the session's state. */
static void recover(struct daemon *d, struct calibration *c) {
        if (c->state == CALIB_RUNNING) {
                char why[128];
                snprintf(why, sizeof why, "the daemon stopped during attempt %d", c->attempts);
                attempt_failed(c, -1, why);
                return;
        }
        if (c->state != CALIB_CAPTURING)
                return;
        struct session *s = session_find(d, c->session);
        if (!s)
                fail(c, "the capture session %s is gone", c->session);
        else if (session_state_final(s->state))
                calibrations_session_ended(d, c->session, session_state_name(s->state));
}

static void load_current(struct daemon *d) {
        char p[PATH_MAX + 64], text[32] = "";
        snprintf(p, sizeof p, "%s/calibrations/current", d->state_dir);
        _cleanup_fclose_ FILE *f = fopen(p, "re");
        if (!f || !fgets(text, sizeof text, f))
                return;
        struct calibration *c = calibration_find(d, (text[strcspn(text, "\n")] = 0, text));
        struct imp_error e = { 0 };
        if (!c || c->state != CALIB_DONE || make_current(d, c, &e) < 0)
                log_warning("%s names calibration %s, which is not a finished one%s%s; keeping %s", p, text,
                            e.msg[0] ? ": " : "", e.msg, d->rigcfg->calibration);
}

int calibrations_load(struct daemon *d) {
        char dirp[PATH_MAX + 32];
        snprintf(dirp, sizeof dirp, "%s/calibrations", d->state_dir);
        if (mkdir(dirp, 0750) < 0 && errno != EEXIST)
                return negative_errno();
        DIR *dir = opendir(dirp);
        if (!dir)
                return negative_errno();
        int *versions = NULL;
        size_t n = 0;
        struct dirent *de;
        while ((de = readdir(dir))) {
                char *end;
                long v = strtol(de->d_name, &end, 10);
                if (*end || end == de->d_name || v < 1 || v > 1000000000)
                        continue;
                int *nv = realloc(versions, (n + 1) * sizeof *nv);
                if (!nv)
                        break;
                versions = nv;
                versions[n++] = (int) v;
        }
        closedir(dir);
        if (n)
                qsort(versions, n, sizeof *versions, cmp_int);
        for (size_t i = 0; i < n; i++) {
                struct calibration *c = calib_new(d, versions[i]);
                if (!c)
                        break;
                if (calib_read(c) < 0) {
                        calib_free(c);
                        continue;
                }
                c->next = d->calibrations;      /* the list ends newest first */
                d->calibrations = c;
        }
        free(versions);
        load_current(d);
        for (struct calibration *c = d->calibrations; c; c = c->next)
                recover(d, c);
        calib_kick(d);
        return (int) n;
}

void calibrations_free_all(struct daemon *d) {
        d->calib_timer = sd_event_source_disable_unref(d->calib_timer);
        while (d->calibrations) {
                struct calibration *c = d->calibrations;
                d->calibrations = c->next;
                /* A routine still running is stopped: the next daemon runs it again, and two
                 * runs never write the same files. */
                if (c->pid > 0)
                        (void) kill(c->pid, SIGTERM);
                calib_free(c);
        }
}
