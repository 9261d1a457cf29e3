/* Pairs are registered on the tiles' heights, not on a normal map that disagrees with them:
 * synthetic tiles (4 × 4 of 12 × 8 mm at 50 µm, 20 % overlap, stage σ 50 µm / 0.05°) whose
 * normal maps are too small by s = 2·10⁻³ about the field centre, as a rendered copy's
 * photometric normals are by ~2·10⁻⁴ (docs/mosaic.md). Every pair then sees its tiles
 * stand too close (s × the 9.6 / 6.4 mm between tile centres: 19 / 13 µm); registered on
 * the normals too the mosaic comes out too small, on heights (the default) it does not. */
#include <stdlib.h>
#include <string.h>
#include "mosaic-fit.h"

static void run(const char *dir, unsigned channels, struct mosaic_fit *ret) {
        struct imp_mosaic_options o;
        imp_mosaic_options_default(&o);
        if (channels)
                o.reg_channels = channels;
        mosaic_fit_run(dir, &o, ret);
        fprintf(stderr, "channels %u: pairs %zu/%zu, vertical pairs %.2f µm short, registration %.2f µm (abs %.2f)\n",
                o.reg_channels, ret->ok, ret->n, ret->dy_short_um, ret->reg.rms_um, ret->reg.abs_rms_um);
}

int main(void) {
        struct imp_mosaic_synth synth;
        imp_mosaic_synth_default(&synth);
        synth.normal_scale = 2e-3;
        const char *tmp = test_tmpdir();
        char dir[512];
        snprintf(dir, sizeof dir, "%s/painting", tmp);
        struct imp_error err = { 0 };
        CHECK_OK(imp_mosaic_synth_write(&synth, dir, &err));

        struct mosaic_fit both, dflt;
        run(dir, IMP_MOSAIC_REG_HEIGHT | IMP_MOSAIC_REG_NORMALS, &both);
        run(dir, 0, &dflt);
        /* The contracted normals bite when used: pairs short by several µm, registration off. */
        CHECK_GE(both.dy_short_um, 4);
        CHECK_GE(both.reg.rms_um, 3);
        /* The default registers on heights: pairs within 1 µm, registration within 1.5 µm
           (0.56 µm on this painting before the normals were ever used). */
        CHECK_INT_EQ(dflt.ok, dflt.n);
        CHECK_LE(fabs(dflt.dy_short_um), 1);
        CHECK_LE(dflt.reg.rms_um, 1.5);
        if (!test_failures_) {
                char cmd[600];
                snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
                CHECK_INT_EQ(system(cmd), 0);
        }
        return TEST_DONE();
}
