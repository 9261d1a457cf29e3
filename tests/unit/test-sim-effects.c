/* "An effect not listed is not computed": with only `direct` listed, the counters of
 * shadow rays, grid vertices, random draws, projector lookups, distortion and defocus stay
 * exactly 0; listing each effect alone on top of `direct` makes its own counter nonzero
 * and leaves the others' at 0. Also: dropped frames, Bayer and colour output shapes. */
#include <stdio.h>
#include "render.h"
#include "scene.h"
#include "test.h"

static const char *scene_text =
        "scene = { name = \"fx\"; seed = 3; effects = [\"direct\"]; ambient = 0.05; dropped_frames = [1];\n"
        "  hot_pixels = { fraction = 0.01; e_per_s = 100000.0; };\n"
        "  indirect = { canvas_pitch_mm = 2.0; frame_pitch_mm = 3.0; paths_per_vertex = 4; max_bounces = 1; simplify = 4; }; };\n"
        "painting = { width_mm = 10.0; height_mm = 8.0; pitch_mm = 0.1; frame = { width_mm = 1.0; height_mm = 1.5; };\n"
        "  layers = ( { type = \"ridge\"; amplitude_mm = 0.5; start_mm = [2.0, 3.0]; end_mm = [8.0, 5.0]; } ); };\n"
        "rig = { cameras = ( { name = \"cam0\"; width = 120; height = 100; fx = 3000.0; k1 = -0.1;\n"
        "    pos_mm = [5.0, 4.0, 300.0]; look_at_mm = [5.0, 4.0, 0.0]; } );\n"
        "  projector = { width = 64; height = 48; fx = 800.0; pos_mm = [100.0, 4.0, 280.0]; look_at_mm = [5.0, 4.0, 0.0]; };\n"
        "  dome = { rings = ( { elevation_deg = 30.0; count = 4; } ); }; };\n";

static const struct imp_frame_record dome = { .seq = 0, .step = "dome", .camera = "cam0", .light = 2,
                                              .exposure_us = 10000 };
static const struct imp_frame_record sl = { .seq = 1, .step = "structured-light", .camera = "cam0", .light = -1,
                                            .exposure_us = 10000,
                                            .pattern = { .kind = IMP_PAT_GRAY, .bit = 2, .nbits = 6 } };

struct outcome {
        struct imp_sim_counters c;
        int sl_rc;              /* imp_render_frame on the SL frame (seq 1, listed as dropped) */
        int channels;
};

static struct outcome run(int fx, bool colour) {
        struct imp_error err = { 0 };
        struct outcome o = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        _cleanup_(imp_render_freep) struct imp_render *r = NULL;
        CHECK_OK(imp_scene_load_string(scene_text, "fx.cfg", &scene, &err));
        if (!scene) {
                fprintf(stderr, "%s\n", err.msg);
                exit(1);
        }
        if (fx >= 0)
                CHECK_OK(imp_scene_set_effect(scene, fx, true));
        CHECK_OK(imp_render_new(scene, &r, &err));
        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
        CHECK_OK(imp_render_frame(r, &dome, &a, &err));
        o.sl_rc = imp_render_frame(r, &sl, &b, &err);
        o.channels = a ? a->channels : 0;
        o.c = *imp_render_counters(r);
        (void) colour;
        return o;
}

#define C(o, field) ((o).c.field)

int main(void) {
        struct outcome base = run(-1, false);
        CHECK(C(base, shading_evals) > 0);
        CHECK_INT_EQ(C(base, shadow_rays), 0);
        CHECK_INT_EQ(C(base, shadow_steps), 0);
        CHECK_INT_EQ(C(base, grid_vertices), 0);
        CHECK_INT_EQ(C(base, indirect_paths), 0);
        CHECK_INT_EQ(C(base, indirect_lookups), 0);
        CHECK_INT_EQ(C(base, random_draws), 0);
        CHECK_INT_EQ(C(base, projector_lookups), 0);
        CHECK_INT_EQ(C(base, distortion_evals), 0);
        CHECK_INT_EQ(C(base, defocus_taps), 0);
        CHECK_INT_EQ(base.sl_rc, 0);            /* dropped_frames listed but the effect is not */
        CHECK_INT_EQ(base.channels, 1);

        struct outcome o = run(IMP_FX_SHADOWS, false);
        CHECK(C(o, shadow_rays) > 0 && C(o, shadow_steps) > 0);
        CHECK_INT_EQ(C(o, random_draws) + C(o, projector_lookups) + C(o, grid_vertices), 0);

        o = run(IMP_FX_PROJECTOR, false);
        CHECK(C(o, projector_lookups) > 0);
        CHECK_INT_EQ(C(o, shadow_rays) + C(o, random_draws) + C(o, grid_vertices) + C(o, defocus_taps), 0);

        o = run(IMP_FX_NOISE, false);
        CHECK(C(o, random_draws) > 0);
        CHECK_INT_EQ(C(o, shadow_rays) + C(o, projector_lookups) + C(o, grid_vertices), 0);

        o = run(IMP_FX_HOT_PIXELS, false);
        CHECK(C(o, random_draws) > 0);
        CHECK_INT_EQ(C(o, shadow_rays) + C(o, projector_lookups), 0);

        o = run(IMP_FX_DISTORTION, false);
        CHECK(C(o, distortion_evals) > 0);
        CHECK_INT_EQ(C(o, random_draws) + C(o, shadow_rays), 0);

        o = run(IMP_FX_DEFOCUS, false);
        CHECK(C(o, defocus_taps) > 0);
        CHECK_INT_EQ(C(o, random_draws) + C(o, shadow_rays) + C(o, projector_lookups), 0);

        o = run(IMP_FX_INDIRECT, false);
        CHECK(C(o, grid_vertices) > 0 && C(o, indirect_lookups) > 0);
        CHECK_INT_EQ(C(o, shadow_rays) + C(o, projector_lookups), 0);

        o = run(IMP_FX_DROPPED_FRAME, false);
        CHECK_ERR(o.sl_rc, -EAGAIN);

        o = run(IMP_FX_BAYER, false);
        CHECK_INT_EQ(o.channels, 1);
        CHECK_INT_EQ(C(o, random_draws), 0);

        /* ambient and vignetting have no counter of their own: check they change the image */
        struct imp_error err = { 0 };
        double centre[3];
        for (int fx = IMP_FX_AMBIENT; fx <= IMP_FX_VIGNETTING; fx += IMP_FX_VIGNETTING - IMP_FX_AMBIENT) {
                _cleanup_(imp_scene_freep) struct imp_scene *s0 = NULL, *s1 = NULL;
                _cleanup_(imp_render_freep) struct imp_render *r0 = NULL, *r1 = NULL;
                _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
                CHECK_OK(imp_scene_load_string(scene_text, "fx.cfg", &s0, &err));
                CHECK_OK(imp_scene_load_string(scene_text, "fx.cfg", &s1, &err));
                CHECK_OK(imp_scene_set_effect(s1, fx, true));
                CHECK_OK(imp_render_new(s0, &r0, &err));
                CHECK_OK(imp_render_new(s1, &r1, &err));
                CHECK_OK(imp_render_radiance(r0, &dome, &a, &err));
                CHECK_OK(imp_render_radiance(r1, &dome, &b, &err));
                double va = imp_image_get(a, 5, 5, 0), vb = imp_image_get(b, 5, 5, 0);
                fprintf(stderr, "%s: corner radiance %.5f -> %.5f\n", imp_sim_effect_name(fx), va, vb);
                CHECK(fx == IMP_FX_AMBIENT ? vb > va : vb < va);
                CHECK_OK(imp_render_view_point(r0, 0, 60, 50, centre, NULL));
        }
        return TEST_DONE();
}
