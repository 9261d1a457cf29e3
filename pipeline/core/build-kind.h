/* What kind of build this code was compiled in, for the programs that time processing
 * (impasto-worker, `impasto bench accuracy`): an AddressSanitizer or -O0 build processes
 * several times slower and with several times the memory of an optimized one (the demo's
 * 275.8 s job of 2026-11-22 came from such a build: docs/jobs.md "Processing time"), so its
 * figures must not pass for the pipeline's cost. */
#pragma once
#include <stdbool.h>

#if defined(__SANITIZE_ADDRESS__)
#define IMP_BUILD_KIND_SLOW 1
#define IMP_BUILD_KIND "AddressSanitizer"
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define IMP_BUILD_KIND_SLOW 1
#define IMP_BUILD_KIND "AddressSanitizer"
#endif
#endif
#ifndef IMP_BUILD_KIND
#ifdef __OPTIMIZE__
#define IMP_BUILD_KIND_SLOW 0
#define IMP_BUILD_KIND "optimized"
#else
#define IMP_BUILD_KIND_SLOW 1
#define IMP_BUILD_KIND "unoptimized (-O0)"
#endif
#endif

/* "optimized", "AddressSanitizer" or "unoptimized (-O0)". */
static inline const char *imp_build_kind(void) {
        return IMP_BUILD_KIND;
}

/* True when timings and memory of this build do not stand for the pipeline's cost. */
static inline bool imp_build_is_slow(void) {
        return IMP_BUILD_KIND_SLOW;
}
