/* `impasto bench STUDY …`: runs impasto-bench, installed beside impasto, where the studies
 * live (bench/bench-main.c); the shipped client carries no study code. */
#include <errno.h>
#include <limits.h>
#include <string.h>
#include <unistd.h>
#include "commands.h"
#include "exit-codes.h"
#include "log.h"
#include "sibling.h"

#define BENCH_PROGRAM "impasto-bench"

static int run(int argc, char **argv) {
        char path[PATH_MAX];
        int r = imp_sibling_path(BENCH_PROGRAM, path, sizeof path);
        if (r < 0)
                return log_error_errno(r, "impasto bench: cannot find %s: %m", BENCH_PROGRAM), IMP_EXIT_FAILURE;
        argv[0] = path;
        execv(path, argv);
        log_error("impasto bench: %s: %s (the studies are a separate program, built with the benches)", path,
                  strerror(errno));
        return IMP_EXIT_FAILURE;
}

const struct imp_command imp_cmd_bench = {
        .name = "bench",
        .summary = "studies on the simulated rig: accuracy versus capture and processing time",
        .run = run,
};
