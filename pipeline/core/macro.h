/* Small helpers every impasto module uses: cleanup attributes with explicit hand-off
 * (after systemd's _cleanup_ / TAKE_PTR), array sizes, clamping. */
#pragma once
#include <errno.h>
#include <stdlib.h>
#include <stdio.h>
#include <unistd.h>

#define _cleanup_(f) __attribute__((cleanup(f)))
#define _unused_ __attribute__((unused))
#define _printf_(a, b) __attribute__((format(printf, a, b)))
#define _warn_unused_ __attribute__((warn_unused_result))

#define ARRAY_SIZE(a) (sizeof(a) / sizeof((a)[0]))
#define IMP_MIN(a, b) ((a) < (b) ? (a) : (b))
#define IMP_MAX(a, b) ((a) > (b) ? (a) : (b))
#define IMP_CLAMP(x, lo, hi) ((x) < (lo) ? (lo) : (x) > (hi) ? (hi) : (x))

/* Hand ownership out of a cleanup variable: the variable becomes NULL. */
#define TAKE_PTR(p) ({ typeof(p) _p = (p); (p) = NULL; _p; })
#define TAKE_FD(fd) ({ int _fd = (fd); (fd) = -1; _fd; })

static inline void freep(void *p) { free(*(void **)p); }
#define _cleanup_free_ _cleanup_(freep)

static inline void closep(int *fd) { if (*fd >= 0) { int e = errno; close(*fd); errno = e; } }
#define _cleanup_close_ _cleanup_(closep)

static inline void fclosep(FILE **f) { if (*f) fclose(*f); }
#define _cleanup_fclose_ _cleanup_(fclosep)

/* Declare a cleanup helper for a destructor that accepts NULL:
 * DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_image *, imp_image_free) gives imp_image_freep. */
#define DEFINE_TRIVIAL_CLEANUP_FUNC(type, func) \
        static inline void func##p(type *p) { if (*p) func(*p); }

/* Convert the errno of a failed syscall into a negative return value. */
static inline int negative_errno(void) { return errno > 0 ? -errno : -EIO; }
