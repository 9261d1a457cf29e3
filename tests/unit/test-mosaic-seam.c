/* The seam step the output mosaic shows (imp_mosaic_figures.seam_out_*, docs/mosaic.md),
 * beside the copies' seam step before blending (imp_mosaic_seam_step). Synthetic tiles
 * (4 × 4 of 12 × 8 mm at 50 µm, 20 % overlap) placed at their true poses (stage σ 1 nm, the
 * true dz of truth/tile-poses.json given to each tile), then:
 *  - step-free: the output's seam step is ~0 (< 0.3 µm: measured 0.17 µm, the bands' means
 *    of 1 µm noise over ~800 texels are ~0.05 µm, the rest is the bilinear resampling of the
 *    relief, 0.14 µm about the tiles' middles too);
 *  - a known step: tiles on the black squares of a checkerboard raised by 4 µm, so every
 *    seam jumps by 4 µm: the figure measures 4 µm (± 0.2), the reference (no seam) stays
 *    ~0, and mosaic.json carries it;
 *  - noisy copies (6 µm of texel noise, step-free): the copies disagree (5×5-texel means
 *    ~√2·6/5 = 1.7 µm) but the blended copy shows no step (< 0.5 µm; measured 0.23 µm, its
 *    bands' means carry 6 µm/√800 = 0.2 µm of noise each): the two figures measure
 *    different things. */
#include <jansson.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "json-util.h"
#include "mosaic.h"
#include "test.h"

static struct imp_mosaic_synth synth;

static double truth_height(void *ctx, double x, double y) {
        return imp_mosaic_synth_height(ctx, x, y);
}

/* Each tile's true dz (truth/tile-poses.json), by tile index. */
static void true_dz(const char *dir, double *dz, size_t n) {
        char path[700];
        snprintf(path, sizeof path, "%s/truth/tile-poses.json", dir);
        json_t *j = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_json_load(path, &j, &err));
        json_t *t;
        size_t i;
        json_array_foreach(json_object_get(j, "tiles"), i, t) {
                long long k = json_integer_value(json_object_get(t, "index"));
                CHECK(k >= 0 && (size_t) k < n);
                if (k >= 0 && (size_t) k < n)
                        dz[k] = json_real_value(json_object_get(t, "dz_mm"));
        }
        json_decref(j);
}

struct seam {
        double before_um;             /* imp_mosaic_seam_step */
        struct imp_mosaic_figures f;
};

/* The mosaic with every tile at its true pose plus step_um on the checkerboard's black
 * squares. */
static void run(const char *dir, const char *out, double step_um, struct seam *ret) {
        struct imp_painting p;
        struct imp_error err = { 0 };
        struct imp_mosaic_options o;
        imp_mosaic_options_default(&o);
        o.out_tile_px = 256;
        CHECK_OK(imp_painting_load(dir, &p, &err));
        double dz[64] = { 0 };
        CHECK_LE(p.n_tiles, 64);
        true_dz(dir, dz, 64);
        for (size_t k = 0; k < p.n_tiles && p.tiles[k].index < 64; k++) {
                struct imp_mosaic_tile *t = &p.tiles[k];
                t->pose[3] = dz[t->index] + ((t->col + t->row) & 1 ? 1e-3 * step_um : 0);
        }
        size_t n;
        CHECK_OK(imp_mosaic_seam_step(&p, &o, &ret->before_um, &n, &err));
        struct imp_mosaic_truth tr = { truth_height, &synth };
        int r = imp_mosaic_write(&p, &o, out, &tr, &ret->f, &err);
        CHECK_MSG(r == 0, "write: %s", err.msg);
        fprintf(stderr, "step %.1f µm, noise %.1f µm: copies' seam step %.2f µm; output seam step %.3f µm (jump %.3f µm "
                        "over %zu segments, reference %.3f µm); height RMSE %.2f µm\n", step_um, synth.noise_um,
                ret->before_um, ret->f.seam_out_step_um, ret->f.seam_out_jump_um, ret->f.seam_out_n, ret->f.seam_out_ref_um,
                ret->f.height_rmse_um);
        imp_painting_done(&p);
}

static double json_truth(const char *out, const char *key) {
        char path[700];
        snprintf(path, sizeof path, "%s/mosaic.json", out);
        json_t *j = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_json_load(path, &j, &err));
        double v = json_number_value(json_object_get(json_object_get(j, "truth"), key));
        json_decref(j);
        return v;
}

int main(void) {
        imp_mosaic_synth_default(&synth);
        synth.sigma_mm = 1e-6, synth.sigma_deg = 1e-6;      /* painting.json wants σ > 0 */
        const char *tmp = test_tmpdir();
        char dir[512], noisy[512], out[512];
        snprintf(dir, sizeof dir, "%s/painting", tmp);
        snprintf(noisy, sizeof noisy, "%s/noisy", tmp);
        snprintf(out, sizeof out, "%s/out", tmp);
        struct imp_error err = { 0 };
        CHECK_OK(imp_mosaic_synth_write(&synth, dir, &err));

        struct seam flat, step, loud;
        run(dir, out, 0, &flat);
        CHECK_GE(flat.f.seam_out_n, 24);                /* 24 seams, 1–2 segments each (36) */
        CHECK_LE(flat.f.seam_out_step_um, 0.3);
        CHECK_LE(flat.f.seam_out_jump_um, 0.3);

        run(dir, out, 4, &step);
        CHECK_NEAR(step.f.seam_out_step_um, 4, 0.2);
        CHECK_NEAR(step.f.seam_out_jump_um, 4, 0.2);
        CHECK_LE(step.f.seam_out_ref_um, 0.3);          /* no seam about a tile's centre */
        CHECK_NEAR(json_truth(out, "seam_step_output_um"), step.f.seam_out_step_um, 1e-9);
        CHECK_GE(step.before_um, 3);                    /* the copies disagree by the step too */

        synth.noise_um = 6;
        CHECK_OK(imp_mosaic_synth_write(&synth, noisy, &err));
        run(noisy, out, 0, &loud);
        CHECK_GE(loud.before_um, 1.2);
        CHECK_LE(loud.f.seam_out_step_um, 0.5);
        if (!test_failures_) {
                char cmd[600];
                snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
                CHECK_INT_EQ(system(cmd), 0);
        }
        return TEST_DONE();
}
