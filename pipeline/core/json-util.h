/* JSON through jansson: typed getters that fill struct imp_error with the field at fault,
 * and safe file I/O (write to temporary name, fsync, rename). Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <jansson.h>
#include "error.h"

/* jansson >= 2.11 defines json_decrefp (and json_auto_t) itself under GCC. */
#ifndef json_auto_t
DEFINE_TRIVIAL_CLEANUP_FUNC(json_t *, json_decref);
#endif
#define _cleanup_json_ _cleanup_(json_decrefp)

/* `what` names the document in messages ("manifest.jsonl:17", "rig.json"): the message is
 * "WHAT: KEY: expected …". A `what` ending in '.' or ' ' is a path prefix and the key is appended
 * directly ("rig.json: cameras[0].sensor." + "bits" → "rig.json: cameras[0].sensor.bits: …").
 * Optional getters leave *ret untouched when the key is absent or null, and return 0;
 * required ones return -ENOENT. A wrong type is -EINVAL. Doubles accept integers. */
int imp_json_get_double(const json_t *obj, const char *key, bool required, double *ret,
                        const char *what, struct imp_error *err);
int imp_json_get_int(const json_t *obj, const char *key, bool required, long long *ret,
                     const char *what, struct imp_error *err);
int imp_json_get_string(const json_t *obj, const char *key, bool required, const char **ret,
                        const char *what, struct imp_error *err);
int imp_json_get_doubles(const json_t *obj, const char *key, bool required, int n, double *ret,
                         const char *what, struct imp_error *err);
/* "an object", "an array", "a string", …: v's type for messages ("expected …, got %s"). */
const char *imp_json_type_name(const json_t *v);
/* A figure that is never negative, as JSON: null when it is not available (a negative
 * sentinel such as -1, or not finite), the number otherwise. A new reference. */
json_t *imp_json_figure(double v);
/* Makes s valid UTF-8 in place, as json_string() wants it: every byte that is not part of a
 * whole, valid character (a string cut by snprintf mid-character, a program's raw output)
 * becomes '?'. Returns the number of bytes replaced. */
size_t imp_utf8_sanitize(char *s);
/* Load a whole file; parse errors name file:line:column. */
int imp_json_load(const char *path, json_t **ret, struct imp_error *err);
/* Crash-safe: writes PATH.tmp, fsyncs it, renames over PATH, fsyncs the directory. */
int imp_json_save_atomic(const char *path, const json_t *j, struct imp_error *err);
/* Write bytes crash-safely in the same way (used for frames and other files). */
int imp_file_write_atomic(const char *path, const void *data, size_t size, struct imp_error *err);
/* write(2) until all of data is written, retrying on EINTR; negative errno. */
int imp_write_all(int fd, const void *data, size_t size);
/* mkdir -p */
int imp_mkdir_p(const char *path, int mode);
/* fsync an existing file by path (e.g. one written by another library). */
int imp_fsync_path(const char *path);
/* fsync the directory that holds `path`, so that a rename or create in it is durable. */
int imp_fsync_parent_dir(const char *path);
