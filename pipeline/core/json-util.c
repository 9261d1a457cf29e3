/* JSON helpers over jansson: typed getters whose messages name the document and the key,
 * and crash-safe file writing (PATH.tmp, fsync, rename, fsync the directory) used by
 * capture sets and every result file. Library code: no logging. */
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <fcntl.h>
#include <libgen.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "json-util.h"

const char *imp_json_type_name(const json_t *v) {
        switch (json_typeof(v)) {
        case JSON_OBJECT: return "an object";
        case JSON_ARRAY: return "an array";
        case JSON_STRING: return "a string";
        case JSON_INTEGER: return "an integer";
        case JSON_REAL: return "a number";
        case JSON_TRUE:
        case JSON_FALSE: return "a boolean";
        case JSON_NULL: return "null";
        default: return "something else";
        }
}

static const char *sep(const char *what) {
        size_t n = strlen(what);
        return n && (what[n - 1] == '.' || what[n - 1] == ' ') ? "" : ": ";
}

/* 1 found, 0 absent and optional, <0 absent and required. */
static int member(const json_t *obj, const char *key, bool required, const char *what,
                  json_t **ret, struct imp_error *err) {
        if (!json_is_object(obj))
                return imp_error_set(err, -EINVAL, "%s: expected an object, got %s", what,
                                     obj ? imp_json_type_name(obj) : "nothing");
        json_t *v = json_object_get(obj, key);
        if (v && !(json_is_null(v) && !required)) {
                *ret = v;
                return 1;
        }
        if (!required)
                return 0;
        return imp_error_set(err, -ENOENT, "%s%s%s: missing (required)", what, sep(what), key);
}

static int wrong(const char *what, const char *key, const char *want, const json_t *v,
                 struct imp_error *err) {
        return imp_error_set(err, -EINVAL, "%s%s%s: expected %s, got %s", what, sep(what), key,
                             want, imp_json_type_name(v));
}

int imp_json_get_double(const json_t *obj, const char *key, bool required, double *ret,
                        const char *what, struct imp_error *err) {
        json_t *v = NULL;
        int r = member(obj, key, required, what, &v, err);
        if (r <= 0)
                return r;
        if (!json_is_number(v))
                return wrong(what, key, "a number", v, err);
        *ret = json_number_value(v);
        return 0;
}

int imp_json_get_int(const json_t *obj, const char *key, bool required, long long *ret,
                     const char *what, struct imp_error *err) {
        json_t *v = NULL;
        int r = member(obj, key, required, what, &v, err);
        if (r <= 0)
                return r;
        if (!json_is_integer(v))
                return wrong(what, key, "an integer", v, err);
        *ret = json_integer_value(v);
        return 0;
}

int imp_json_get_string(const json_t *obj, const char *key, bool required, const char **ret,
                        const char *what, struct imp_error *err) {
        json_t *v = NULL;
        int r = member(obj, key, required, what, &v, err);
        if (r <= 0)
                return r;
        if (!json_is_string(v))
                return wrong(what, key, "a string", v, err);
        *ret = json_string_value(v);
        return 0;
}

int imp_json_get_doubles(const json_t *obj, const char *key, bool required, int n, double *ret,
                         const char *what, struct imp_error *err) {
        json_t *v = NULL;
        int r = member(obj, key, required, what, &v, err);
        if (r <= 0)
                return r;
        if (!json_is_array(v))
                return imp_error_set(err, -EINVAL, "%s%s%s: expected an array of %d numbers, got %s",
                                     what, sep(what), key, n, imp_json_type_name(v));
        if ((int) json_array_size(v) != n)
                return imp_error_set(err, -EINVAL, "%s%s%s: expected %d numbers, got %zu", what,
                                     sep(what), key, n, json_array_size(v));
        for (int i = 0; i < n; i++)
                if (!json_is_number(json_array_get(v, (size_t) i)))
                        return imp_error_set(err, -EINVAL, "%s%s%s[%d]: expected a number, got %s",
                                             what, sep(what), key, i,
                                             imp_json_type_name(json_array_get(v, (size_t) i)));
        for (int i = 0; i < n; i++)
                ret[i] = json_number_value(json_array_get(v, (size_t) i));
        return 0;
}

int imp_json_load(const char *path, json_t **ret, struct imp_error *err) {
        FILE *f = fopen(path, "re");
        if (!f) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: %s", path, strerror(-r));
        }
        json_error_t je;
        json_t *j = json_loadf(f, JSON_REJECT_DUPLICATES, &je);
        fclose(f);
        if (!j)
                return imp_error_set(err, -EINVAL, "%s:%d:%d: %s", path, je.line, je.column, je.text);
        *ret = j;
        return 0;
}

int imp_json_save_atomic(const char *path, const json_t *j, struct imp_error *err) {
        _cleanup_free_ char *text = json_dumps(j, JSON_INDENT(2) | JSON_REAL_PRECISION(17));
        if (!text)
                return imp_error_set(err, -ENOMEM, "%s: cannot encode JSON", path);
        size_t n = strlen(text);
        _cleanup_free_ char *buf = malloc(n + 2);
        if (!buf)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        memcpy(buf, text, n);
        buf[n] = '\n';
        return imp_file_write_atomic(path, buf, n + 1, err);
}

int imp_write_all(int fd, const void *data, size_t size) {
        const char *p = data;
        while (size > 0) {
                ssize_t k = write(fd, p, size);
                if (k < 0) {
                        if (errno == EINTR)
                                continue;
                        return negative_errno();
                }
                p += k;
                size -= (size_t) k;
        }
        return 0;
}

int imp_fsync_path(const char *path) {
        _cleanup_close_ int fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0)
                return negative_errno();
        return fsync(fd) < 0 ? negative_errno() : 0;
}

int imp_fsync_parent_dir(const char *path) {
        _cleanup_free_ char *copy = strdup(path);
        if (!copy)
                return -ENOMEM;
        _cleanup_close_ int fd = open(dirname(copy), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
        if (fd < 0)
                return negative_errno();
        return fsync(fd) < 0 ? negative_errno() : 0;
}

int imp_file_write_atomic(const char *path, const void *data, size_t size, struct imp_error *err) {
        _cleanup_free_ char *tmp = NULL;
        if (asprintf(&tmp, "%s.tmp", path) < 0)
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        if (fd < 0) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: %s", tmp, strerror(-r));
        }
        const char *step = "write";
        int r = imp_write_all(fd, data, size);
        if (r == 0 && fsync(fd) < 0) {
                step = "fsync";
                r = negative_errno();
        }
        if (close(fd) < 0 && r == 0) {
                step = "close";
                r = negative_errno();
        }
        if (r == 0 && rename(tmp, path) < 0) {
                step = "rename";
                r = negative_errno();
        }
        if (r < 0) {
                unlink(tmp);
                return imp_error_set(err, r, "%s: %s: %s", tmp, step, strerror(-r));
        }
        r = imp_fsync_parent_dir(path);
        if (r < 0)
                return imp_error_set(err, r, "%s: fsync of directory: %s", path, strerror(-r));
        return 0;
}

int imp_mkdir_p(const char *path, int mode) {
        _cleanup_free_ char *p = strdup(path);
        if (!p)
                return -ENOMEM;
        size_t n = strlen(p);
        while (n > 1 && p[n - 1] == '/')
                p[--n] = 0;
        for (char *s = p + 1;; s++) {
                bool last = *s == 0;
                if (*s != '/' && !last)
                        continue;
                char c = *s;
                *s = 0;
                if (mkdir(p, (mode_t) mode) < 0) {
                        int e = errno;
                        struct stat st;
                        if (e != EEXIST)
                                return -e;
                        if (stat(p, &st) < 0)
                                return negative_errno();
                        if (!S_ISDIR(st.st_mode))
                                return -ENOTDIR;
                }
                *s = c;
                if (last)
                        break;
        }
        return 0;
}

json_t *imp_json_figure(double v) {
        return v >= 0 && isfinite(v) ? json_real(v) : json_null();
}

/* The length of the valid UTF-8 character at s (RFC 3629: no overlong form, no surrogate,
 * at most U+10FFFF), 0 when there is none. */
static size_t utf8_char_len(const unsigned char *s) {
        unsigned c = s[0];
        size_t n = c < 0x80 ? 1 : (c & 0xe0) == 0xc0 ? 2 : (c & 0xf0) == 0xe0 ? 3 : (c & 0xf8) == 0xf0 ? 4 : 0;
        if (n <= 1)
                return n;
        unsigned cp = c & (0x7f >> n);
        for (size_t i = 1; i < n; i++) {
                if ((s[i] & 0xc0) != 0x80)
                        return 0;
                cp = (cp << 6) | (s[i] & 0x3f);
        }
        static const unsigned min[5] = { 0, 0, 0x80, 0x800, 0x10000 };
        if (cp < min[n] || cp > 0x10ffff || (cp >= 0xd800 && cp <= 0xdfff))
                return 0;
        return n;
}

size_t imp_utf8_sanitize(char *s) {
        size_t replaced = 0;
        while (*s) {
                size_t n = utf8_char_len((const unsigned char *) s);
                if (n == 0) {
                        *s++ = '?';
                        replaced++;
                } else
                        s += n;
        }
        return replaced;
}
