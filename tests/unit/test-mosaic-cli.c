/* `impasto mosaic` as an operator runs it (cli/cmd-mosaic.c) on a synthetic painting with
 * truth: the registered run prints a registration error ≤ 10 µm and a seam step ≤ 2 µm, the
 * --prior-only run prints the stage prior's (both above), and both exit 0. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "mosaic.h"
#include "test.h"

/* Runs the command; its stdout in buf; the registration error and the seam step parsed. */
static int run(const char *cmd, char *buf, size_t n, double *ret_reg, double *ret_seam) {
        FILE *f = popen(cmd, "r");
        if (!f)
                return -1;
        size_t got = fread(buf, 1, n - 1, f);
        buf[got] = 0;
        int st = pclose(f);
        const char *r = strstr(buf, "truth: registration "), *s = strstr(buf, "seam step: ");
        *ret_reg = r ? atof(r + strlen("truth: registration ")) : NAN;
        *ret_seam = s ? atof(s + strlen("seam step: ")) : NAN;
        return st;
}

int main(void) {
        const char *tmp = test_tmpdir();
        char dir[512], cmd[2048];
        static char out[65536];
        snprintf(dir, sizeof dir, "%s/painting", tmp);
        struct imp_mosaic_synth s;
        imp_mosaic_synth_default(&s);
        s.extent_mm[0] = 30, s.extent_mm[1] = 20;
        s.truth_exr = true;
        struct imp_error err = { 0 };
        int r = imp_mosaic_synth_write(&s, dir, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        double reg, seam;
        snprintf(cmd, sizeof cmd, "%s/cli/impasto mosaic '%s' --out '%s/out' --tile-px 128", IMPASTO_BINARY_DIR, dir, tmp);
        CHECK_INT_EQ(run(cmd, out, sizeof out, &reg, &seam), 0);
        fprintf(stderr, "%s", out);
        CHECK_LE(reg, 10);
        CHECK_LE(seam, 2);
        CHECK_STR_CONTAINS(out, "adjustment: ");
        CHECK_STR_CONTAINS(out, "truth: height RMSE ");
        snprintf(cmd, sizeof cmd, "%s/cli/impasto mosaic '%s' --out '%s/prior' --prior-only --tile-px 128", IMPASTO_BINARY_DIR,
                 dir, tmp);
        CHECK_INT_EQ(run(cmd, out, sizeof out, &reg, &seam), 0);
        fprintf(stderr, "%s", out);
        CHECK_GE(reg, 20);
        CHECK_GE(seam, 2);
        CHECK(!strstr(out, "adjustment: "));
        if (!test_failures_) {
                snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
                CHECK_INT_EQ(system(cmd), 0);
        }
        return TEST_DONE();
}
