/* The studies of `impasto-bench` (run as `impasto bench NAME …`): each bench/<study>.c
 * registers itself with IMP_BENCH_STUDY() and is listed once in bench/CMakeLists.txt
 * (IMPASTO_BENCH_STUDIES). The registrations gather in one linker section, as systemd
 * gathers its tests, so bench-main.c needs no list of its own. */
#pragma once
#include <stdbool.h>

struct imp_bench_study {
        const char *name;             /* `impasto bench NAME` */
        const char *summary;          /* one line for `impasto bench --help`; NULL: an internal step */
        int (*run)(int argc, char **argv);   /* argv[0] is NAME; returns the exit code */
        bool hugepages;               /* measures processing: malloc in huge pages, as the
                                       * processing programs run (hugepages.h) */
};

#define IMP_BENCH_STUDY(id, ...)                                                                  \
        static const struct imp_bench_study imp_bench_study_##id = { __VA_ARGS__ };                \
        static const struct imp_bench_study *const imp_bench_study_ptr_##id                         \
                __attribute__((section("imp_bench_studies"), used, aligned(sizeof(void *)))) =     \
                &imp_bench_study_##id
