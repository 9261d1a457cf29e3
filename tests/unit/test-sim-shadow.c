/* Cast shadows: a step of height h lit from elevation e casts a shadow of length
 * h / tan(e) beyond the step's top edge, within one camera pixel (0.05 mm here); with
 * `shadows` not listed there is no shadow and no shadow ray. */
#include <stdio.h>
#include "render.h"
#include "scene.h"
#include "test.h"

#define PITCH_MM 0.05
#define STEP_AT_MM 10.0
#define STEP_H_MM 0.5
#define LIGHT_DIST_MM 20000.0   /* far enough that the elevation varies < 1e-4 rad over the shadow */

#define SCENE_FMT \
        "scene = { name = \"step\"; seed = 1; effects = [\"direct\"%s]; };\n" \
        "painting = { width_mm = 20.0; height_mm = 10.0; pitch_mm = 0.05;\n" \
        "  layers = ( { type = \"step\"; at_mm = 10.0; axis = \"x\"; amplitude_mm = 0.5; } );\n" \
        "  regions = ( { shape = \"all\"; rho_d = [0.9, 0.9, 0.9]; } ); };\n" \
        "rig = { cameras = ( { name = \"cam0\"; width = 400; height = 200; fx = 6000.0;\n" \
        "    pos_mm = [10.0, 5.0, 300.0]; look_at_mm = [10.0, 5.0, 0.0]; } );\n" \
        "  dome = { profile_exp = 0.0; lights = ( { pos_mm = [%.6f, 5.0, %.6f]; intensity = %.6f; } ); }; };\n"

/* Shadow end along the centre row: world x just past the last dark pixel after the step. */
static double shadow_end(bool shadows, double elev_deg, uint64_t *ret_rays) {
        double e = elev_deg * M_PI / 180;
        char text[2048];
        snprintf(text, sizeof text, SCENE_FMT, shadows ? ", \"shadows\"" : "", STEP_AT_MM - LIGHT_DIST_MM * cos(e),
                 LIGHT_DIST_MM * sin(e), (LIGHT_DIST_MM / 1000) * (LIGHT_DIST_MM / 1000));
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        _cleanup_(imp_render_freep) struct imp_render *r = NULL;
        _cleanup_image_ struct imp_image *rad = NULL;
        CHECK_OK(imp_scene_load_string(text, "step.cfg", &scene, &err));
        if (!scene) {
                fprintf(stderr, "%s\n", err.msg);
                return NAN;
        }
        CHECK_OK(imp_render_new(scene, &r, &err));
        struct imp_frame_record rec = { .step = "dome", .camera = "cam0", .light = 0, .exposure_us = 10000 };
        CHECK_OK(imp_render_radiance(r, &rec, &rad, &err));
        *ret_rays = imp_render_counters(r)->shadow_rays;
        int y = 100;
        double lit_v = 0.9 * sin(e), end = NAN;
        bool in_shadow = false;
        for (int x = 0; x < rad->width; x++) {
                double p[3];
                if (imp_render_view_point(r, 0, x, y, p, NULL) < 0 || p[0] <= STEP_AT_MM)
                        continue;
                double v = imp_image_get(rad, x, y, 0);
                if (v < 0.5 * lit_v) {
                        in_shadow = true;
                        continue;
                }
                if (p[0] > STEP_AT_MM + 2 * PITCH_MM)   /* beyond the step's tilted normals */
                        CHECK_NEAR(v, lit_v, 0.005 * lit_v);   /* lit ground: E cos θ ρd */
                if (in_shadow || isnan(end)) {
                        double pp[3];
                        /* boundary between the last dark pixel and this lit one */
                        if (in_shadow && imp_render_view_point(r, 0, x - 1, y, pp, NULL) == 0)
                                end = 0.5 * (pp[0] + p[0]);
                        else
                                end = p[0];
                }
                break;
        }
        return end;
}

int main(void) {
        const double top_edge_mm = STEP_AT_MM - PITCH_MM;   /* last raised sample: the bilinear top edge */
        const double elevs[] = { 20, 30, 45, 60 };
        for (size_t i = 0; i < ARRAY_SIZE(elevs); i++) {
                uint64_t rays = 0;
                double end = shadow_end(true, elevs[i], &rays);
                double expect = top_edge_mm + STEP_H_MM / tan(elevs[i] * M_PI / 180);
                fprintf(stderr, "elevation %.0f°: shadow ends at %.4f mm, expected %.4f mm (%.2f px)\n", elevs[i], end,
                        expect, (end - expect) / PITCH_MM);
                CHECK_NEAR(end, expect, PITCH_MM);   /* one pixel */
                CHECK(rays > 0);
        }
        uint64_t rays = 1;
        double end = shadow_end(false, 30, &rays);
        CHECK_LE(end, STEP_AT_MM + PITCH_MM);   /* first pixel past the step is lit */
        CHECK_INT_EQ(rays, 0);
        return TEST_DONE();
}
