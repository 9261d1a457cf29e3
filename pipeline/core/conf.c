/* Config files through libconfig, with getters that check type and range and say
 * exactly which file, line and field is wrong: hand-written rig configs and scan plans
 * are read by people who need to fix them. Library code: no logging. */
#define _GNU_SOURCE
#include <errno.h>
#include <libgen.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "conf.h"

struct imp_conf {
        config_t cfg;
        char *name;          /* file path (or the name given for a string) */
};

static struct imp_conf *conf_new(const char *name) {
        struct imp_conf *c = calloc(1, sizeof *c);
        if (!c)
                return NULL;
        c->name = strdup(name ? name : "(string)");
        if (!c->name) {
                free(c);
                return NULL;
        }
        config_init(&c->cfg);
        return c;
}

void imp_conf_free(struct imp_conf *c) {
        if (!c)
                return;
        config_destroy(&c->cfg);
        free(c->name);
        free(c);
}

static int syntax_error(struct imp_conf *c, struct imp_error *err) {
        const char *file = config_error_file(&c->cfg);
        int r = imp_error_set(err, -EINVAL, "%s:%d: %s", file ? file : c->name,
                              config_error_line(&c->cfg),
                              config_error_text(&c->cfg) ? config_error_text(&c->cfg)
                                                         : "syntax error");
        imp_conf_free(c);
        return r;
}

int imp_conf_load(const char *path, struct imp_conf **ret, struct imp_error *err) {
        struct imp_conf *c = conf_new(path);
        if (!c)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        /* libconfig reports an unreadable file as a FILE_IO error without errno: look first. */
        FILE *f = fopen(path, "re");
        if (!f) {
                int r = negative_errno();
                imp_conf_free(c);
                return imp_error_set(err, r, "%s: %s", path, strerror(-r));
        }
        fclose(f);
        /* @include "x.cfg" is relative to the including file, not to the working directory. */
        char *copy = strdup(path);
        if (!copy) {
                imp_conf_free(c);
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        }
        config_set_include_dir(&c->cfg, dirname(copy));
        free(copy);
        if (config_read_file(&c->cfg, path) != CONFIG_TRUE) {
                if (config_error_type(&c->cfg) == CONFIG_ERR_FILE_IO) {
                        imp_conf_free(c);
                        return imp_error_set(err, -EIO, "%s: read error", path);
                }
                return syntax_error(c, err);
        }
        *ret = c;
        return 0;
}

int imp_conf_load_string(const char *text, const char *name, struct imp_conf **ret,
                         struct imp_error *err) {
        struct imp_conf *c = conf_new(name);
        if (!c)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", name ? name : "(string)");
        if (config_read_string(&c->cfg, text) != CONFIG_TRUE)
                return syntax_error(c, err);
        *ret = c;
        return 0;
}

const char *imp_conf_path(const struct imp_conf *c) { return c->name; }

config_setting_t *imp_conf_root(const struct imp_conf *c) { return config_root_setting(&c->cfg); }

/* ---- names and lines for messages ---- */

static void path_append(char *buf, size_t size, const config_setting_t *s) {
        if (!s || config_setting_is_root(s))
                return;
        path_append(buf, size, config_setting_parent(s));
        size_t n = strlen(buf);
        const char *sep = n ? "." : "";
        if (config_setting_name(s))
                snprintf(buf + n, size - n, "%s%s", sep, config_setting_name(s));
        else
                snprintf(buf + n, size - n, "%s[%d]", sep, config_setting_index(s));
}

const char *imp_conf_setting_path(const config_setting_t *s) {
        static __thread char buf[512];
        buf[0] = 0;
        path_append(buf, sizeof buf, s);
        return buf;
}

/* "FILE:LINE" of a setting; without a line (the root) just "FILE". */
static void where(const struct imp_conf *c, const config_setting_t *s, char *buf, size_t size) {
        const char *file = s ? config_setting_source_file(s) : NULL;
        if (!file)
                file = c->name;
        unsigned line = s ? config_setting_source_line(s) : 0;
        if (line > 0)
                snprintf(buf, size, "%s:%u", file, line);
        else
                snprintf(buf, size, "%s", file);
}

/* Field name of `path` below `s`, as written in messages. */
static void field_name(const config_setting_t *s, const char *path, char *buf, size_t size) {
        const char *base = imp_conf_setting_path(s);
        if (base[0] && path && path[0])
                snprintf(buf, size, "%s.%s", base, path);
        else
                snprintf(buf, size, "%s", base[0] ? base : (path ? path : ""));
}

static const char *type_name(const config_setting_t *s) {
        switch (config_setting_type(s)) {
        case CONFIG_TYPE_GROUP: return "a group";
        case CONFIG_TYPE_INT:
        case CONFIG_TYPE_INT64: return "an integer";
        case CONFIG_TYPE_FLOAT: return "a number";
        case CONFIG_TYPE_STRING: return "a string";
        case CONFIG_TYPE_BOOL: return "a boolean";
        case CONFIG_TYPE_ARRAY: return "an array";
        case CONFIG_TYPE_LIST: return "a list";
        default: return "nothing";
        }
}

static int fail_at(const struct imp_conf *c, const config_setting_t *at, int code,
                   struct imp_error *err, const char *fmt, ...) _printf_(5, 6);
static int fail_at(const struct imp_conf *c, const config_setting_t *at, int code,
                   struct imp_error *err, const char *fmt, ...) {
        char w[320], field[512], detail[512];
        where(c, at, w, sizeof w);
        snprintf(field, sizeof field, "%s", imp_conf_setting_path(at));
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(detail, sizeof detail, fmt, ap);
        va_end(ap);
        return imp_error_set(err, code, "%s: %s: %s", w, field[0] ? field : "(top level)", detail);
}

/* Walks "a.b.[3].c" (also "a.b[3]" and "a/b") from s; libconfig 1.5's own lookup does
 * not take list indices everywhere. NULL when absent. */
static config_setting_t *lookup(config_setting_t *s, const char *path) {
        char buf[512];
        if (!path || !path[0])
                return s;
        if (strlen(path) >= sizeof buf)
                return NULL;
        strcpy(buf, path);
        for (char *save = NULL, *tok = strtok_r(buf, "./:", &save); tok && s;
             tok = strtok_r(NULL, "./:", &save)) {
                char *br = strchr(tok, '[');
                if (br != tok) {
                        if (br)
                                *br = 0;
                        if (config_setting_type(s) != CONFIG_TYPE_GROUP)
                                return NULL;
                        s = config_setting_get_member(s, tok);
                        if (br)
                                *br = '[';
                }
                while (s && br) {
                        char *end;
                        long i = strtol(br + 1, &end, 10);
                        if (*end != ']' || i < 0 || !config_setting_is_aggregate(s))
                                return NULL;
                        s = config_setting_get_elem(s, (unsigned) i);
                        br = strchr(end, '[');
                }
        }
        return s;
}

/* Finds path below s (NULL: root). 1 found, 0 absent-optional, <0 absent-required. */
static int find(const struct imp_conf *c, const config_setting_t *s, const char *path,
                bool required, config_setting_t **ret, struct imp_error *err) {
        config_setting_t *base = s ? (config_setting_t *) s : imp_conf_root(c);
        config_setting_t *f = lookup(base, path);
        if (f) {
                *ret = f;
                return 1;
        }
        if (!required)
                return 0;
        /* The line of the deepest enclosing setting that exists: where to add the field. */
        char prefix[512], w[320], field[512];
        config_setting_t *at = base;
        snprintf(prefix, sizeof prefix, "%s", path);
        for (char *dot; (dot = strrchr(prefix, '.'));) {
                *dot = 0;
                config_setting_t *p = lookup(base, prefix);
                if (p) {
                        at = p;
                        break;
                }
        }
        where(c, at, w, sizeof w);
        field_name(base, path, field, sizeof field);
        return imp_error_set(err, -ENOENT, "%s: %s: missing (required)", w, field);
}

static bool is_int(const config_setting_t *s) {
        int t = config_setting_type(s);
        return t == CONFIG_TYPE_INT || t == CONFIG_TYPE_INT64;
}

static double number_of(const config_setting_t *s) {
        return is_int(s) ? (double) config_setting_get_int64(s) : config_setting_get_float(s);
}

static void describe_value(const config_setting_t *s, char *buf, size_t size) {
        if (is_int(s))
                snprintf(buf, size, "%lld", config_setting_get_int64(s));
        else if (config_setting_type(s) == CONFIG_TYPE_FLOAT)
                snprintf(buf, size, "%.10g", config_setting_get_float(s));
        else if (config_setting_type(s) == CONFIG_TYPE_STRING)
                snprintf(buf, size, "\"%.200s\"", config_setting_get_string(s));
        else
                snprintf(buf, size, "%s", type_name(s));
}

static void describe_range(double min, double max, char *buf, size_t size) {
        if (min <= -HUGE_VAL && max >= HUGE_VAL)
                snprintf(buf, size, "a number");
        else if (min <= -HUGE_VAL)
                snprintf(buf, size, "a number <= %.10g", max);
        else if (max >= HUGE_VAL)
                snprintf(buf, size, "a number >= %.10g", min);
        else
                snprintf(buf, size, "a number in [%.10g, %.10g]", min, max);
}

static int check_number(const struct imp_conf *c, const config_setting_t *f, double min,
                        double max, double *ret, struct imp_error *err) {
        char want[128], got[256];
        describe_range(min, max, want, sizeof want);
        if (!config_setting_is_number(f)) {
                describe_value(f, got, sizeof got);
                return fail_at(c, f, -EINVAL, err, "expected %s, got %s", want, got);
        }
        double v = number_of(f);
        if (!(v >= min && v <= max)) {
                describe_value(f, got, sizeof got);
                return fail_at(c, f, -EINVAL, err, "expected %s, got %s", want, got);
        }
        *ret = v;
        return 0;
}

int imp_conf_get_double(const struct imp_conf *c, const config_setting_t *s, const char *path,
                        bool required, double min, double max, double *ret,
                        struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        double v = 0;
        r = check_number(c, f, min, max, &v, err);
        if (r < 0)
                return r;
        *ret = v;
        return 0;
}

int imp_conf_get_int(const struct imp_conf *c, const config_setting_t *s, const char *path,
                     bool required, long long min, long long max, long long *ret,
                     struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        char got[256];
        if (!is_int(f)) {
                describe_value(f, got, sizeof got);
                return fail_at(c, f, -EINVAL, err, "expected an integer in [%lld, %lld], got %s",
                               min, max, got);
        }
        long long v = config_setting_get_int64(f);
        if (v < min || v > max)
                return fail_at(c, f, -EINVAL, err, "expected an integer in [%lld, %lld], got %lld",
                               min, max, v);
        *ret = v;
        return 0;
}

int imp_conf_get_bool(const struct imp_conf *c, const config_setting_t *s, const char *path,
                      bool required, bool *ret, struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        if (config_setting_type(f) != CONFIG_TYPE_BOOL) {
                char got[256];
                describe_value(f, got, sizeof got);
                return fail_at(c, f, -EINVAL, err, "expected true or false, got %s", got);
        }
        *ret = config_setting_get_bool(f);
        return 0;
}

int imp_conf_get_string(const struct imp_conf *c, const config_setting_t *s, const char *path,
                        bool required, const char **ret, struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        if (config_setting_type(f) != CONFIG_TYPE_STRING) {
                char got[256];
                describe_value(f, got, sizeof got);
                return fail_at(c, f, -EINVAL, err, "expected a string, got %s", got);
        }
        *ret = config_setting_get_string(f);
        return 0;
}

int imp_conf_get_enum(const struct imp_conf *c, const config_setting_t *s, const char *path,
                      bool required, const char *const *choices, int *ret,
                      struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        const char *v = config_setting_type(f) == CONFIG_TYPE_STRING ? config_setting_get_string(f)
                                                                      : NULL;
        for (int i = 0; v && choices[i]; i++)
                if (strcmp(v, choices[i]) == 0) {
                        *ret = i;
                        return 0;
                }
        char list[512] = "", got[256];
        for (int i = 0; choices[i]; i++) {
                size_t n = strlen(list);
                snprintf(list + n, sizeof list - n, "%s\"%s\"", i ? ", " : "", choices[i]);
        }
        describe_value(f, got, sizeof got);
        return fail_at(c, f, -EINVAL, err, "expected one of %s, got %s", list, got);
}

int imp_conf_get_doubles(const struct imp_conf *c, const config_setting_t *s, const char *path,
                         bool required, int n, double *ret, int max_n, int *ret_n,
                         struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        int t = config_setting_type(f);
        int len = (t == CONFIG_TYPE_ARRAY || t == CONFIG_TYPE_LIST) ? config_setting_length(f) : -1;
        if (n >= 0 && len != n) {
                if (len < 0)
                        return fail_at(c, f, -EINVAL, err, "expected an array of %d numbers, got %s",
                                       n, type_name(f));
                return fail_at(c, f, -EINVAL, err, "expected %d numbers, got %d", n, len);
        }
        if (n < 0 && (len < 0 || len > max_n)) {
                if (len < 0)
                        return fail_at(c, f, -EINVAL, err,
                                       "expected an array of up to %d numbers, got %s", max_n,
                                       type_name(f));
                return fail_at(c, f, -EINVAL, err, "expected at most %d numbers, got %d", max_n, len);
        }
        /* Check everything before writing: *ret stays untouched on failure. */
        for (int i = 0; i < len; i++) {
                config_setting_t *e = config_setting_get_elem(f, (unsigned) i);
                if (!config_setting_is_number(e)) {
                        char got[256];
                        describe_value(e, got, sizeof got);
                        return fail_at(c, e, -EINVAL, err, "expected a number, got %s", got);
                }
        }
        for (int i = 0; i < len; i++)
                ret[i] = number_of(config_setting_get_elem(f, (unsigned) i));
        if (ret_n)
                *ret_n = len;
        return 0;
}

static int get_kind(const struct imp_conf *c, const config_setting_t *s, const char *path,
                    bool required, bool list, config_setting_t **ret, struct imp_error *err) {
        config_setting_t *f = NULL;
        int r = find(c, s, path, required, &f, err);
        if (r <= 0)
                return r;
        int t = config_setting_type(f);
        bool ok = list ? (t == CONFIG_TYPE_LIST || t == CONFIG_TYPE_ARRAY) : t == CONFIG_TYPE_GROUP;
        if (!ok)
                return fail_at(c, f, -EINVAL, err, "expected %s, got %s",
                               list ? "a list ( … )" : "a group { … }", type_name(f));
        *ret = f;
        return 0;
}

int imp_conf_get_group(const struct imp_conf *c, const config_setting_t *s, const char *path,
                       bool required, config_setting_t **ret, struct imp_error *err) {
        return get_kind(c, s, path, required, false, ret, err);
}

int imp_conf_get_list(const struct imp_conf *c, const config_setting_t *s, const char *path,
                      bool required, config_setting_t **ret, struct imp_error *err) {
        return get_kind(c, s, path, required, true, ret, err);
}

int imp_edit_distance(const char *a, const char *b) {
        size_t la = strlen(a), lb = strlen(b);
        if (la > 63 || lb > 63)
                return 99;
        int d[64][64];
        for (size_t i = 0; i <= la; i++)
                d[i][0] = (int) i;
        for (size_t j = 0; j <= lb; j++)
                d[0][j] = (int) j;
        for (size_t i = 1; i <= la; i++)
                for (size_t j = 1; j <= lb; j++) {
                        int sub = d[i - 1][j - 1] + (a[i - 1] != b[j - 1]);
                        int del = d[i - 1][j] + 1, ins = d[i][j - 1] + 1;
                        d[i][j] = IMP_MIN(sub, IMP_MIN(del, ins));
                }
        return d[la][lb];
}

int imp_conf_check_known(const struct imp_conf *c, const config_setting_t *s,
                         const char *const *known, struct imp_error *err) {
        const config_setting_t *g = s ? s : imp_conf_root(c);
        if (config_setting_type(g) != CONFIG_TYPE_GROUP)
                return 0;
        int n = config_setting_length(g);
        for (int i = 0; i < n; i++) {
                config_setting_t *m = config_setting_get_elem(g, (unsigned) i);
                const char *name = config_setting_name(m);
                bool found = false;
                for (int k = 0; known[k] && !found; k++)
                        found = strcmp(name, known[k]) == 0;
                if (found)
                        continue;
                char w[320], group[512], list[512] = "", hint[128] = "";
                where(c, m, w, sizeof w);
                snprintf(group, sizeof group, "%s", imp_conf_setting_path(g));
                int best = 3;
                for (int k = 0; known[k]; k++) {
                        size_t len = strlen(list);
                        snprintf(list + len, sizeof list - len, "%s%s", k ? ", " : "", known[k]);
                        int d = imp_edit_distance(name, known[k]);
                        if (d < best) {
                                best = d;
                                snprintf(hint, sizeof hint, "; did you mean %s?", known[k]);
                        }
                }
                return imp_error_set(err, -EINVAL, "%s: %s: unknown field %s (expected one of: %s)%s",
                                     w, group[0] ? group : "(top level)", name, list, hint);
        }
        return 0;
}
