/* Scan plans: the dome group's `repeat` (N frames per light × exposure, consecutive), its
 * validation (FILE:LINE: dome.repeat: …), runs of one state (imp_plan_same_state,
 * imp_plan_run_length: repeats and dark frames, which impastod streams) and the capture-time
 * estimate counting every repeat. */
#include "plan.h"
#include "unit/test.h"

static void make_rig(struct imp_rig *rig) {
        *rig = (struct imp_rig) { .n_cameras = 1, .settle_us = 500 };
        struct imp_rig_camera *c = &rig->cameras[0];
        snprintf(c->name, sizeof c->name, "cam0");
        c->model = (struct imp_pinhole) { .width = 64, .height = 32, .fx = 100, .fy = 100, .cx = 32, .cy = 16,
                                          .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }, .t = { 0, 0, 500 } };
        c->sensor = (struct imp_sensor) { .bits = 16, .gain_e_per_dn = 1, .full_well_e = 60000, .quantum_scale = 1,
                                          .readout_us = 1000 };
        rig->n_lights = 3;
        rig->lights = calloc(3, sizeof *rig->lights);
        for (int i = 0; i < 3; i++)
                rig->lights[i] = (struct imp_rig_light) { .id = i, .pos_mm = { 100.0 * i, 0, 500 }, .intensity = 1,
                                                          .colour = { 1, 1, 1 }, .axis = { 0, 0, -1 } };
}

static struct imp_plan *load(const struct imp_rig *rig, const char *text, struct imp_error *e) {
        struct imp_plan *p = NULL;
        *e = (struct imp_error) { 0 };
        int r = imp_plan_load_string(text, "t.cfg", rig, &p, e);
        return r < 0 ? NULL : p;
}

/* A plan that must fail, naming the file, line 2 and the field. */
static void bad(const struct imp_rig *rig, const char *repeat) {
        char text[256];
        snprintf(text, sizeof text, "dome = { lights = [0];\n  repeat = %s;\n  exposures_us = [1000.0]; };\n", repeat);
        struct imp_error e;
        struct imp_plan *p = load(rig, text, &e);
        CHECK_MSG(p == NULL, "repeat = %s accepted", repeat);
        imp_plan_free(p);
        CHECK_MSG(strstr(e.msg, "t.cfg:2: dome.repeat: ") != NULL, "repeat = %s: message \"%s\"", repeat, e.msg);
}

int main(void) {
        struct imp_rig rig;
        make_rig(&rig);
        struct imp_error e;

        struct imp_plan *p = load(&rig, "dome = { lights = [0, 2]; exposures_us = [1000.0, 2000.0]; repeat = 3; };\n"
                                        "dark = { count = 2; };\n", &e);
        CHECK_MSG(p != NULL, "%s", e.msg);
        if (!p)
                return TEST_DONE();
        CHECK_INT_EQ(imp_plan_count(p), 2 * 2 * 3 + 2 * 2);
        static const int light[] = { 0, 2 };
        static const double exp_us[] = { 1000.0, 2000.0 };
        for (size_t i = 0; i < 12; i++) {
                const struct imp_frame_record *f = imp_plan_frame(p, i);
                CHECK_INT_EQ(f->seq, (long long) i);
                CHECK_STR_EQ(f->step, "dome");
                CHECK_INT_EQ(f->light, light[i / 6]);
                CHECK_INT_EQ(f->exposure_index, (int) (i / 3 % 2));
                CHECK_NEAR(f->exposure_us, exp_us[i / 3 % 2], 0);
                /* runs of 3, each starting where the state changes */
                CHECK_INT_EQ(imp_plan_run_length(p, i), 3 - i % 3);
                if (i > 0)
                        CHECK(imp_plan_same_state(f, imp_plan_frame(p, i - 1)) == (i % 3 != 0));
        }
        for (size_t i = 12; i < 16; i++) {
                const struct imp_frame_record *f = imp_plan_frame(p, i);
                CHECK_STR_EQ(f->step, "dark");
                CHECK_INT_EQ(f->light, -1);
                CHECK_NEAR(f->exposure_us, exp_us[(i - 12) / 2], 0);
                CHECK_INT_EQ(imp_plan_run_length(p, i), 2 - i % 2);
        }
        CHECK_INT_EQ(imp_plan_run_length(p, 16), 0);
        CHECK(!imp_plan_same_state(imp_plan_frame(p, 11), imp_plan_frame(p, 12)));   /* light off */
        imp_plan_free(p);

        /* estimate: every frame exposure + readout + settle, one more settle per light change */
        p = load(&rig, "dome = { lights = [0, 2]; exposures_us = [1000.0, 2000.0]; };\n", &e);
        CHECK_MSG(p != NULL, "%s", e.msg);
        double once = p ? imp_plan_estimate_s(p, &rig) : 0;
        CHECK_NEAR(once, 2 * (1000 + 1000 + 500 + 2000 + 1000 + 500) * 1e-6 + 500e-6, 1e-9);
        imp_plan_free(p);
        p = load(&rig, "dome = { lights = [0, 2]; exposures_us = [1000.0, 2000.0]; repeat = 3; };\n", &e);
        CHECK_MSG(p != NULL, "%s", e.msg);
        CHECK_NEAR(p ? imp_plan_estimate_s(p, &rig) : 0, 3 * 2 * (1000 + 1000 + 500 + 2000 + 1000 + 500) * 1e-6 + 500e-6,
                   1e-9);
        CHECK_INT_EQ(p ? imp_plan_count(p) : 0, 12);
        imp_plan_free(p);

        /* repeat = 1 is the plan without it */
        p = load(&rig, "dome = { lights = \"all\"; exposures_us = [1000.0]; repeat = 1; };\n", &e);
        CHECK_MSG(p != NULL, "%s", e.msg);
        CHECK_INT_EQ(p ? imp_plan_count(p) : 0, 3);
        CHECK_INT_EQ(p ? imp_plan_run_length(p, 0) : 0, 1);
        imp_plan_free(p);

        bad(&rig, "0");
        bad(&rig, "-2");
        bad(&rig, "10001");
        bad(&rig, "2.5");
        bad(&rig, "\"3\"");
        bad(&rig, "true");

        imp_rig_free(&rig);
        return TEST_DONE();
}
