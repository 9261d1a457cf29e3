/* impasto-bench: the studies behind `impasto bench NAME …` (bench-study.h). Kept out of
 * the `impasto` binary: the shipped client carries no study code and execs this program,
 * which sits beside it; a study execs that `impasto` for the steps it measures. */
#include <stdio.h>
#include <string.h>
#include "bench-study.h"
#include "exit-codes.h"
#include "hugepages.h"
#include "log.h"

extern const struct imp_bench_study *const __start_imp_bench_studies[] __attribute__((weak));
extern const struct imp_bench_study *const __stop_imp_bench_studies[] __attribute__((weak));

static void usage(FILE *f) {
        fprintf(f, "usage: impasto bench STUDY [ARGS…]\n\nstudies:\n");
        for (const struct imp_bench_study *const *s = __start_imp_bench_studies; s < __stop_imp_bench_studies; s++)
                if ((*s)->summary)
                        fprintf(f, "  %-12s %s\n", (*s)->name, (*s)->summary);
}

int main(int argc, char **argv) {
        imp_log_set_ident("impasto bench");
        if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
                usage(argc < 2 ? stderr : stdout);
                return argc < 2 ? IMP_EXIT_USAGE : IMP_EXIT_OK;
        }
        for (const struct imp_bench_study *const *s = __start_imp_bench_studies; s < __stop_imp_bench_studies; s++)
                if (!strcmp((*s)->name, argv[1])) {
                        if ((*s)->hugepages)
                                imp_hugepages_reexec(argv);
                        return (*s)->run(argc - 1, argv + 1);
                }
        fprintf(stderr, "impasto bench: unknown study '%s'\n", argv[1]);
        usage(stderr);
        return IMP_EXIT_USAGE;
}
