/* `impasto mosaic` as an operator runs it (cli/cmd-mosaic.c) on a synthetic painting with
 * truth: the registered run prints a registration error ≤ 10 µm and a seam step ≤ 2 µm, the
 * --prior-only run prints the stage prior's (both above), and both exit 0. --register-on: on
 * tiles whose normal maps are 2·10⁻³ too small (as the rendered copies' are, less so:
 * docs/mosaic.md) registering on the normals is worse than on the heights (the default), so
 * the option reaches the registration; an unknown value is a usage error. */
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
        /* --register-on: a painting whose tiles' normal maps are contracted. */
        char dir2[600];
        snprintf(dir2, sizeof dir2, "%s/contracted", tmp);
        s.normal_scale = 2e-3;
        r = imp_mosaic_synth_write(&s, dir2, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        double reg_h, reg_n;
        snprintf(cmd, sizeof cmd, "%s/cli/impasto mosaic '%s' --out '%s/c-h' --tile-px 128", IMPASTO_BINARY_DIR, dir2, tmp);
        CHECK_INT_EQ(run(cmd, out, sizeof out, &reg_h, &seam), 0);
        snprintf(cmd, sizeof cmd, "%s/cli/impasto mosaic '%s' --out '%s/c-n' --tile-px 128 --register-on normals",
                 IMPASTO_BINARY_DIR, dir2, tmp);
        CHECK_INT_EQ(run(cmd, out, sizeof out, &reg_n, &seam), 0);
        fprintf(stderr, "contracted normal maps: registration %.2f µm on heights, %.2f µm on normals\n", reg_h, reg_n);
        CHECK_LE(reg_h, 5);
        CHECK_GE(reg_n, 2 * reg_h + 2);
        snprintf(cmd, sizeof cmd, "%s/cli/impasto mosaic '%s' --out '%s/c-x' --register-on albedo 2>&1", IMPASTO_BINARY_DIR,
                 dir2, tmp);
        CHECK_INT_EQ(run(cmd, out, sizeof out, &reg_n, &seam), 2 << 8);
        CHECK_STR_CONTAINS(out, "--register-on: expected heights, normals or both");
        if (!test_failures_) {
                snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
                CHECK_INT_EQ(system(cmd), 0);
        }
        return TEST_DONE();
}
