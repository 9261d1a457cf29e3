/* One human-editable config format (libconfig: comments, nesting, lists) for rig configs,
 * scan plans and scenes. Every getter checks type and range and, on failure, fills
 * struct imp_error with "FILE:LINE: FIELD: expected …, got …" and returns -EINVAL
 * (-ENOENT for a missing required field). Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <libconfig.h>
#include "error.h"

struct imp_conf;   /* a loaded file; opaque */

/* Caller frees with imp_conf_free(). Syntax errors give "FILE:LINE: <libconfig text>". */
int imp_conf_load(const char *path, struct imp_conf **ret, struct imp_error *err);
int imp_conf_load_string(const char *text, const char *name, struct imp_conf **ret,
                         struct imp_error *err);
void imp_conf_free(struct imp_conf *c);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_conf *, imp_conf_free);
const char *imp_conf_path(const struct imp_conf *c);
config_setting_t *imp_conf_root(const struct imp_conf *c);

/* Levenshtein distance of two names (99 when either is longer than 63 bytes), to suggest
 * the intended name for a typo: unknown config fields, unknown commands. */
int imp_edit_distance(const char *a, const char *b);

/* Paths are libconfig paths relative to `s` ("camera.fx", "lights.[3].pos_mm").
 * `s` NULL means the root. Optional getters leave *ret untouched when absent and
 * return 0; required ones return -ENOENT with a message. */
int imp_conf_get_double(const struct imp_conf *c, const config_setting_t *s, const char *path,
                        bool required, double min, double max, double *ret, struct imp_error *err);
int imp_conf_get_int(const struct imp_conf *c, const config_setting_t *s, const char *path,
                     bool required, long long min, long long max, long long *ret,
                     struct imp_error *err);
int imp_conf_get_bool(const struct imp_conf *c, const config_setting_t *s, const char *path,
                      bool required, bool *ret, struct imp_error *err);
/* The returned string belongs to the conf. */
int imp_conf_get_string(const struct imp_conf *c, const config_setting_t *s, const char *path,
                        bool required, const char **ret, struct imp_error *err);
/* One of `choices` (NULL-terminated); *ret is its index. */
int imp_conf_get_enum(const struct imp_conf *c, const config_setting_t *s, const char *path,
                      bool required, const char *const *choices, int *ret, struct imp_error *err);
/* A numeric array of exactly n numbers (n < 0: any length up to max_n, count in *ret_n). */
int imp_conf_get_doubles(const struct imp_conf *c, const config_setting_t *s, const char *path,
                         bool required, int n, double *ret, int max_n, int *ret_n,
                         struct imp_error *err);
/* A group or list member; NULL with -ENOENT/-EINVAL message when missing or wrong kind. */
int imp_conf_get_group(const struct imp_conf *c, const config_setting_t *s, const char *path,
                       bool required, config_setting_t **ret, struct imp_error *err);
int imp_conf_get_list(const struct imp_conf *c, const config_setting_t *s, const char *path,
                      bool required, config_setting_t **ret, struct imp_error *err);
/* "camera.fx" style full path of a setting, for messages; static buffer per thread. */
const char *imp_conf_setting_path(const config_setting_t *s);
/* Fails with "FILE:LINE: GROUP: unknown field NAME (expected one of: …)" if `s` has a
 * member not in `known` (NULL-terminated) — catches typos in hand-written files. */
int imp_conf_check_known(const struct imp_conf *c, const config_setting_t *s,
                         const char *const *known, struct imp_error *err);
