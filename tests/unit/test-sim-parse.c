/* Scene and plan files: errors name FILE:LINE: FIELD; the plan expands into the documented
 * frame order and count; the capture-time estimate follows its formula. */
#include <stdio.h>
#include "plan.h"
#include "scene.h"
#include "test.h"

static const char *good_scene =
        "scene = { name = \"p\"; effects = [\"direct\", \"projector\"]; };\n"                  /* 1 */
        "painting = { width_mm = 10.0; height_mm = 8.0; pitch_mm = 0.2; };\n"                   /* 2 */
        "rig = { cameras = ( { name = \"cam0\"; width = 40; height = 30; fx = 1000.0;\n"         /* 3 */
        "    pos_mm = [5.0, 4.0, 300.0]; look_at_mm = [5.0, 4.0, 0.0]; } );\n"                  /* 4 */
        "  projector = { width = 100; height = 60; fx = 800.0; pos_mm = [100.0, 4.0, 280.0]; look_at_mm = [5.0, 4.0, 0.0]; };\n"
        "  settle_us = 1000.0;\n"
        "  dome = { rings = ( { elevation_deg = 30.0; count = 6; } ); }; };\n";

static void expect_scene_error(const char *text, const char *needle) {
        struct imp_error err = { 0 };
        struct imp_scene *s = NULL;
        int r = imp_scene_load_string(text, "bad.cfg", &s, &err);
        CHECK(r < 0);
        CHECK(s == NULL);
        CHECK_STR_CONTAINS(err.msg, needle);
        imp_scene_free(s);
}

static void expect_plan_error(const struct imp_rig *rig, const char *text, const char *needle) {
        struct imp_error err = { 0 };
        struct imp_plan *p = NULL;
        int r = imp_plan_load_string(text, "plan.cfg", rig, &p, &err);
        CHECK(r < 0);
        CHECK_STR_CONTAINS(err.msg, needle);
        imp_plan_free(p);
}

int main(void) {
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        CHECK_OK(imp_scene_load_string(good_scene, "good.cfg", &scene, &err));
        if (!scene) {
                fprintf(stderr, "%s\n", err.msg);
                return 1;
        }
        const struct imp_rig *rig = imp_scene_rig(scene);
        CHECK_INT_EQ(rig->n_lights, 6);
        CHECK_INT_EQ(imp_scene_surface(scene)->nx, 51);

        /* scene errors */
        expect_scene_error("scene = { effects = [\"direct\",\n  \"glare\"]; };\npainting = { width_mm = 1.0; };",
                           "bad.cfg:2: scene.effects.[1]: unknown effect \"glare\"");
        expect_scene_error("scene = { effects = [\"direct\"]; };\npainting = { width_mm = 10.0; height_mm = 8.0; };\n",
                           "pitch_mm");
        expect_scene_error("scene = { effects = [\"direct\"]; };\npainting = { width_mm = 10.0;\n height_mm = 8.0; pitch_mm = -1.0; };\n",
                           "bad.cfg:3");
        expect_scene_error("scene = { effects = [\"direct\"]; colour = 1; };\n", "colour");
        expect_scene_error("scene = { effects = [\"direct\"]; };\npainting = { width_mm = 10.0; height_mm = 8.0; pitch_mm = 0.2;\n"
                           "  layers = ( { type = \"sculpture\"; } ); };\n", "bad.cfg:3");
        expect_scene_error("scene = { effects = [\"direct\"]; };\npainting = { width_mm = 10.0; height_mm = 8.0; pitch_mm = 0.2; };\n"
                           "rig = { cameras = ( { name = \"c\"; width = 40; height = 30; fx = 1000.0;\n"
                           "   pos_mm = [1.0, 2.0]; look_at_mm = [5.0, 4.0, 0.0]; } ); };\n", "pos_mm");
        expect_scene_error("scene = { effects = [\"projector\"]; };\npainting = { width_mm = 10.0; height_mm = 8.0; pitch_mm = 0.2; };\n"
                           "rig = { cameras = ( { name = \"c\"; width = 40; height = 30; fx = 1000.0;\n"
                           "   pos_mm = [1.0, 2.0, 300.0]; look_at_mm = [5.0, 4.0, 0.0]; } ); };\n", "projector");

        /* plan errors */
        expect_plan_error(rig, "structured_light = {\n  axes = [\"x\", \"z\"];\n  exposures_us = [1000.0]; };\n",
                          "plan.cfg:2: structured_light.axes.[1]");
        expect_plan_error(rig, "structured_light = { axes = [\"x\"]; };\n", "exposures_us");
        expect_plan_error(rig, "dome = { exposures_us = [1000.0];\n lights = [0, 99]; };\n", "plan.cfg:2: dome.lights.[1]");
        expect_plan_error(rig, "cameras = [\"cam9\"];\ndome = { exposures_us = [1000.0]; };\n", "cam9");
        expect_plan_error(rig, "dome = { exposures_us = [1000.0]; };\nstructured_light = { gray_bitz = 3; exposures_us = [1.0]; };\n",
                          "gray_bitz");
        expect_plan_error(rig, "dome = { lights = \"some\"; exposures_us = [1000.0]; };\n", "dome.lights");

        /* expansion */
        _cleanup_(imp_plan_freep) struct imp_plan *p = NULL;
        CHECK_OK(imp_plan_load_string("structured_light = { phase = { periods_px = [16.0]; steps = 4; };\n"
                                      "  exposures_us = [1000.0, 4000.0]; };\n"
                                      "dome = { lights = [1, 4]; exposures_us = [2000.0, 8000.0]; };\n"
                                      "dark = { count = 2; };\n", "plan.cfg", rig, &p, &err));
        if (!p) {
                fprintf(stderr, "%s\n", err.msg);
                return 1;
        }
        /* gray bits from projector 100 x 60: 7 and 6; per exposure: 2 + (7 + 6) * 2 + 2 * 4 = 36 */
        CHECK_INT_EQ(imp_plan_gray_bits(p, 0), 7);
        CHECK_INT_EQ(imp_plan_gray_bits(p, 1), 6);
        size_t n_sl = 2 * 36, n_dome = 2 * 2, n_dark = 4 * 2;
        CHECK_INT_EQ(imp_plan_count(p), n_sl + n_dome + n_dark);
        const struct imp_frame_record *f = imp_plan_frame(p, 0);
        CHECK_INT_EQ(f->pattern.kind, IMP_PAT_WHITE);
        CHECK_STR_EQ(f->step, "structured-light");
        CHECK_STR_EQ(f->camera, "cam0");
        CHECK_INT_EQ(imp_plan_frame(p, 1)->pattern.kind, IMP_PAT_BLACK);
        f = imp_plan_frame(p, 2);
        CHECK(f->pattern.kind == IMP_PAT_GRAY && f->pattern.bit == 0 && !f->pattern.inverse && f->pattern.nbits == 7);
        f = imp_plan_frame(p, 3);
        CHECK(f->pattern.kind == IMP_PAT_GRAY && f->pattern.bit == 0 && f->pattern.inverse);
        f = imp_plan_frame(p, 2 + 14);
        CHECK(f->pattern.kind == IMP_PAT_PHASE && f->pattern.axis == 0 && f->pattern.step == 0 && f->pattern.steps == 4);
        f = imp_plan_frame(p, 36);
        CHECK(f->exposure_index == 1 && f->exposure_us == 4000.0 && f->pattern.kind == IMP_PAT_WHITE);
        f = imp_plan_frame(p, n_sl);
        CHECK(!strcmp(f->step, "dome") && f->light == 1 && f->exposure_us == 2000.0 && f->pattern.kind == IMP_PAT_NONE);
        f = imp_plan_frame(p, n_sl + 1);
        CHECK(f->light == 1 && f->exposure_us == 8000.0);
        CHECK_INT_EQ(imp_plan_frame(p, n_sl + 2)->light, 4);
        f = imp_plan_frame(p, n_sl + n_dome);
        CHECK(!strcmp(f->step, "dark") && f->light == -1);
        for (size_t i = 0; i < imp_plan_count(p); i++)
                CHECK_INT_EQ(imp_plan_frame(p, i)->seq, i);
        CHECK(imp_plan_frame(p, imp_plan_count(p)) == NULL);

        /* fewer Gray bits than the projector needs: the coarsest planes of the full 7-bit code */
        {
                _cleanup_(imp_plan_freep) struct imp_plan *q = NULL;
                CHECK_OK(imp_plan_load_string("structured_light = { gray_bits = 4; phase = { periods_px = [16.0]; steps = 4; };\n"
                                              "  exposures_us = [1000.0]; };\n",
                                              "plan.cfg", rig, &q, &err));
                CHECK_INT_EQ(imp_plan_gray_bits(q, 0), 4);
                int seen = 0;
                for (size_t i = 0; q && i < imp_plan_count(q); i++) {
                        const struct imp_frame_record *g = imp_plan_frame(q, i);
                        if (g->pattern.kind == IMP_PAT_GRAY && g->pattern.axis == 0 && !g->pattern.inverse) {
                                CHECK_INT_EQ(g->pattern.nbits, 7);
                                CHECK(g->pattern.bit < 4);
                                seen++;
                        }
                }
                CHECK_INT_EQ(seen, 4);
        }

        /* estimate: Σ (exposure + readout + settle) + settle per light/pattern change */
        double expo = 0, changes = 0;
        for (size_t i = 0; i < imp_plan_count(p); i++) {
                const struct imp_frame_record *g = imp_plan_frame(p, i), *h = i ? imp_plan_frame(p, i - 1) : NULL;
                expo += g->exposure_us;
                if (h && (g->light != h->light || g->pattern.kind != h->pattern.kind || g->pattern.bit != h->pattern.bit ||
                          g->pattern.inverse != h->pattern.inverse || g->pattern.step != h->pattern.step ||
                          g->pattern.axis != h->pattern.axis))
                        changes++;
        }
        double readout = rig->cameras[0].sensor.readout_us, settle = rig->settle_us;
        double expect = (expo + imp_plan_count(p) * (readout + settle) + changes * settle) * 1e-6;
        CHECK_NEAR(imp_plan_estimate_s(p, rig), expect, 1e-9);

        /* the demo plan against the demo scene: 2 × (2 + 2 × 10 × 2 + 2 × 2 × 4) + 56 × 2 (56 dome lights: rings of 16, 16, 16, 8) */
        _cleanup_(imp_scene_freep) struct imp_scene *demo = NULL;
        _cleanup_(imp_plan_freep) struct imp_plan *dp = NULL;
        CHECK_OK(imp_scene_load(IMPASTO_SOURCE_DIR "/config/scenes/demo.cfg", &demo, &err));
        if (demo) {
                CHECK_OK(imp_plan_load(IMPASTO_SOURCE_DIR "/config/plans/demo.cfg", imp_scene_rig(demo), &dp, &err));
                CHECK_INT_EQ(dp ? imp_plan_count(dp) : 0, 2 * (2 + 2 * 10 * 2 + 2 * 2 * 4) + 56 * 2);
                CHECK_INT_EQ(imp_scene_rig(demo)->n_lights, 56);
                CHECK_LE(imp_scene_max_height_mm(demo), 5.0 + 1e-6);   /* the frame is the highest */
                _cleanup_(imp_scene_freep) struct imp_scene *fw = NULL;
                _cleanup_(imp_plan_freep) struct imp_plan *qp = NULL;
                CHECK_OK(imp_scene_load(IMPASTO_SOURCE_DIR "/config/scenes/flat-white.cfg", &fw, &err));
                CHECK_OK(imp_plan_load(IMPASTO_SOURCE_DIR "/config/plans/quick.cfg", imp_scene_rig(fw), &qp, &err));
                CHECK_INT_EQ(qp ? imp_plan_count(qp) : 0, 2 + 8 + 4 + 3 + 1);
        } else {
                fprintf(stderr, "%s\n", err.msg);
        }
        return TEST_DONE();
}
