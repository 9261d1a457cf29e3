/* Logging for programs (daemon, cli, worker, tests) — not for library code.
 * Under systemd (JOURNAL_STREAM set) lines carry <N> priority prefixes that journald
 * understands; on a terminal they are plain "impasto: level: message". */
#pragma once
#include "macro.h"

enum imp_log_level { IMP_LOG_ERR = 3, IMP_LOG_WARNING = 4, IMP_LOG_NOTICE = 5,
                     IMP_LOG_INFO = 6, IMP_LOG_DEBUG = 7 };

void imp_log_set_level(enum imp_log_level max);
void imp_log_set_ident(const char *ident);
enum imp_log_level imp_log_get_level(void);
/* Logs and returns error (a negative errno), with %m expanded to strerror(-error). */
int imp_log_internal(enum imp_log_level level, int error, const char *file, int line,
                     const char *fmt, ...) _printf_(5, 6);

#define imp_log(level, ...) imp_log_internal(level, 0, __FILE__, __LINE__, __VA_ARGS__)
#define log_debug(...)   imp_log(IMP_LOG_DEBUG, __VA_ARGS__)
#define log_info(...)    imp_log(IMP_LOG_INFO, __VA_ARGS__)
#define log_notice(...)  imp_log(IMP_LOG_NOTICE, __VA_ARGS__)
#define log_warning(...) imp_log(IMP_LOG_WARNING, __VA_ARGS__)
#define log_error(...)   imp_log(IMP_LOG_ERR, __VA_ARGS__)
#define log_error_errno(r, ...)   imp_log_internal(IMP_LOG_ERR, (r), __FILE__, __LINE__, __VA_ARGS__)
#define log_warning_errno(r, ...) imp_log_internal(IMP_LOG_WARNING, (r), __FILE__, __LINE__, __VA_ARGS__)
#define log_debug_errno(r, ...)   imp_log_internal(IMP_LOG_DEBUG, (r), __FILE__, __LINE__, __VA_ARGS__)
