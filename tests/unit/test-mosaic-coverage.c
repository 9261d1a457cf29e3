/* The mosaic covers the painting's whole extent when the tile plan's outer fields pass it
 * (tiles.h edge_margin_mm), and says why a texel is not covered (mosaic.h, docs/mosaic.md
 * "Coverage"). Synthetic tiles (24 × 16 mm painting, 12 × 8 mm fields at 0.1 mm, 20 %
 * overlap) whose copies, like the rendered ones, stop half a texel inside their field, placed
 * at their true poses (stage errors of 0.3 mm σ and 0.05° σ): so what is measured is the
 * plan's and the blend's coverage, not the registration. */
#include <jansson.h>
#include <stdlib.h>
#include <string.h>
#include "image.h"
#include "json-util.h"
#include "mosaic-edit.h"
#include "mosaic.h"
#include "quality.h"
#include "test.h"

/* Blends DIR with every tile at its true pose into OUT. */
static void run(const char *dir, const char *out, struct imp_mosaic_figures *f) {
        struct imp_painting p;
        struct imp_error err = { 0 };
        struct imp_mosaic_options o;
        imp_mosaic_options_default(&o);
        o.out_tile_px = 64;
        o.prior_only = true;
        memset(f, 0, sizeof *f);
        int r = imp_painting_load(dir, &p, &err);
        CHECK_MSG(r == 0, "load: %s", err.msg);
        CHECK(p.has_truth);
        for (size_t k = 0; r == 0 && k < p.n_tiles; k++) {
                struct imp_mosaic_tile *t = &p.tiles[k];
                t->pose[0] = t->truth[0] - t->nominal_mm[0], t->pose[1] = t->truth[1] - t->nominal_mm[1];
                t->pose[2] = t->truth[2];
        }
        if (r == 0) {
                r = imp_mosaic_write(&p, &o, out, NULL, f, &err);
                CHECK_MSG(r == 0, "write: %s", err.msg);
        }
        const size_t *u = f->uncovered;
        fprintf(stderr, "%s: %zu tiles, %zu × %zu texels, %zu covered; uncovered edge %zu (to %.3f mm), gap %zu, "
                "copy edge %zu, hole %zu\n", dir, p.n_tiles, f->out_nx, f->out_ny, f->texels_covered,
                u[IMP_MOSAIC_UNCOVERED_EDGE], f->edge_depth_mm, u[IMP_MOSAIC_UNCOVERED_GAP],
                u[IMP_MOSAIC_UNCOVERED_COPY_EDGE], u[IMP_MOSAIC_UNCOVERED_HOLE]);
        imp_painting_done(&p);
}

static size_t uncovered(const struct imp_mosaic_figures *f) {
        size_t n = 0;
        for (int q = 0; q < IMP_MOSAIC_UNCOVERED_N; q++)
                n += f->uncovered[q];
        return n;
}

/* OUT/mosaic.json's coverage object holds the figures. */
static void check_json(const char *out, const struct imp_mosaic_figures *f) {
        char path[700];
        snprintf(path, sizeof path, "%s/mosaic.json", out);
        json_t *j = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_json_load(path, &j, &err));
        json_t *c = json_object_get(j, "coverage"), *u = json_object_get(c, "uncovered");
        CHECK_INT_EQ(json_integer_value(json_object_get(c, "texels")), f->out_nx * f->out_ny);
        CHECK_INT_EQ(json_integer_value(json_object_get(c, "covered")), f->texels_covered);
        CHECK_INT_EQ(json_integer_value(json_object_get(u, "edge")), f->uncovered[IMP_MOSAIC_UNCOVERED_EDGE]);
        CHECK_INT_EQ(json_integer_value(json_object_get(u, "hole")), f->uncovered[IMP_MOSAIC_UNCOVERED_HOLE]);
        json_decref(j);
}

/* Marks every texel of a copy's flags channel normal_uncertain (a flag that does not change
 * the blend's weights). */
static void mark_flags(struct imp_image *img, int c) {
        for (int j = 0; j < img->height; j++)
                for (int i = 0; i < img->width; i++)
                        imp_image_f32(img, i, j)[c] = (float) IMP_TEXEL_NORMAL_UNCERTAIN;
}

/* Texels of OUT/tiles/000-000/FILE (the painting's corner, which only tile 0 sees) whose
 * flags channel has bit. */
static size_t corner_flagged(const char *out, const char *file, unsigned bit) {
        char path[700];
        snprintf(path, sizeof path, "%s/tiles/000-000/%s", out, file);
        struct imp_image *img = NULL;
        char **names = NULL;
        struct imp_error err = { 0 };
        CHECK_OK(imp_exr_read(path, &img, &names, &err));
        if (!img)
                return 0;
        int c = imp_image_channel_index(names, "flags");
        CHECK_GE(c, 0);
        size_t n = 0;
        for (int j = 0; c >= 0 && j < 8; j++)
                for (int i = 0; i < 8; i++)
                        n += ((unsigned) lrintf(imp_image_f32(img, i, j)[c]) & bit) != 0;
        imp_strv_free(names);
        imp_image_free(img);
        return n;
}

/* A 20 × 20-texel hole in tile 0's mask where only tile 0 sees the painting (painting x 1.5–3.5,
 * y 0.5–2.5 mm with the 1 mm margin). */
#define HOLE_PX 20
static void hole_mask(struct imp_image *img, int c) {
        for (int j = 15; j < 15 + HOLE_PX; j++)
                for (int i = 25; i < 25 + HOLE_PX; i++)
                        imp_image_f32(img, i, j)[c] = 0;
}

int main(void) {
        struct imp_mosaic_synth s;
        imp_mosaic_synth_default(&s);
        s.extent_mm[0] = 24, s.extent_mm[1] = 16, s.pitch_mm = 0.1;
        s.sigma_mm = 0.3, s.seed = 3;
        const char *tmp = test_tmpdir();
        char plain[512], margin[512], out[512];
        snprintf(plain, sizeof plain, "%s/plain", tmp);
        snprintf(margin, sizeof margin, "%s/margin", tmp);
        snprintf(out, sizeof out, "%s/out", tmp);
        struct imp_error err = { 0 };
        CHECK_OK(imp_mosaic_synth_write(&s, plain, &err));
        s.edge_margin_mm = 1;
        CHECK_OK(imp_mosaic_synth_write(&s, margin, &err));

        /* Fields that end at the extent's edges: the tiles that landed inward leave a strip of
           the border uncovered (a few texels deep at 0.3 mm σ), all of it counted as such;
           edge_depth_mm is the farthest one's distance from the border (0: the border row). */
        struct imp_mosaic_figures f0, f1, f2;
        run(plain, out, &f0);
        CHECK_GE(f0.uncovered[IMP_MOSAIC_UNCOVERED_EDGE], 20);
        CHECK_INT_EQ(uncovered(&f0), f0.uncovered[IMP_MOSAIC_UNCOVERED_EDGE]);
        CHECK_INT_EQ(f0.texels_covered + uncovered(&f0), f0.out_nx * f0.out_ny);
        CHECK(f0.edge_depth_mm >= 0.05 && f0.edge_depth_mm <= 1.2);
        check_json(out, &f0);

        /* With a 1 mm margin (3 × 3 tiles still, spaced wider): every texel of the extent covered. */
        run(margin, out, &f1);
        CHECK_INT_EQ(f1.texels_covered, f1.out_nx * f1.out_ny);
        CHECK_INT_EQ(uncovered(&f1), 0);
        CHECK_INT_EQ(f1.texels_doubled, 0);
        check_json(out, &f1);

        /* A copy's texel flags (heightfield.exr) reach the mosaic's texel flags, not its fit flags. */
        CHECK_INT_EQ(corner_flagged(out, "heightfield.exr", IMP_TEXEL_NORMAL_UNCERTAIN), 0);
        edit_tile0(margin, "flags", mark_flags);
        struct imp_mosaic_figures ff;
        run(margin, out, &ff);
        CHECK_INT_EQ(corner_flagged(out, "heightfield.exr", IMP_TEXEL_NORMAL_UNCERTAIN), 64);
        CHECK_INT_EQ(corner_flagged(out, "fit-flags.exr", IMP_TEXEL_NORMAL_UNCERTAIN), 0);

        /* A hole in a copy where no other copy sees: counted as a hole, nothing else. */
        edit_tile0(margin, "mask", hole_mask);
        run(margin, out, &f2);
        CHECK_GE(f2.uncovered[IMP_MOSAIC_UNCOVERED_HOLE], HOLE_PX * HOLE_PX * 8 / 10);
        CHECK_LE(f2.uncovered[IMP_MOSAIC_UNCOVERED_HOLE], HOLE_PX * HOLE_PX * 12 / 10);
        CHECK_INT_EQ(uncovered(&f2), f2.uncovered[IMP_MOSAIC_UNCOVERED_HOLE]);
        CHECK_INT_EQ(f2.texels_covered + uncovered(&f2), f2.out_nx * f2.out_ny);
        check_json(out, &f2);
        if (!test_failures_) {
                char cmd[600];
                snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmp);
                CHECK_INT_EQ(system(cmd), 0);
        }
        return TEST_DONE();
}
