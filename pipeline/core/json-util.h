/* JSON through jansson: typed getters that fill struct imp_error with the field at fault,
 * and safe file I/O (write to temporary name, fsync, rename). Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <jansson.h>
#include "error.h"

DEFINE_TRIVIAL_CLEANUP_FUNC(json_t *, json_decref);
#define _cleanup_json_ _cleanup_(json_decrefp)

/* `what` names the document in messages ("manifest.jsonl:17", "rig.json"). */
int imp_json_get_double(const json_t *obj, const char *key, bool required, double *ret,
                        const char *what, struct imp_error *err);
int imp_json_get_int(const json_t *obj, const char *key, bool required, long long *ret,
                     const char *what, struct imp_error *err);
int imp_json_get_string(const json_t *obj, const char *key, bool required, const char **ret,
                        const char *what, struct imp_error *err);
int imp_json_get_doubles(const json_t *obj, const char *key, bool required, int n, double *ret,
                         const char *what, struct imp_error *err);
/* Load a whole file; parse errors name file:line:column. */
int imp_json_load(const char *path, json_t **ret, struct imp_error *err);
/* Crash-safe: writes PATH.tmp, fsyncs it, renames over PATH, fsyncs the directory. */
int imp_json_save_atomic(const char *path, const json_t *j, struct imp_error *err);
/* Write bytes crash-safely in the same way (used for frames and other files). */
int imp_file_write_atomic(const char *path, const void *data, size_t size, struct imp_error *err);
/* mkdir -p */
int imp_mkdir_p(const char *path, int mode);
