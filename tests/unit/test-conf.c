/* Config getters: a sample parses; every error kind names the file, the line and the
 * full field path (syntax, wrong type, out of range, missing, unknown field). */
#include <errno.h>
#include <math.h>
#include "conf.h"
#include "test.h"

static const char sample[] =
        "# a simulated rig\n"                                  /* 1 */
        "camera = {\n"                                         /* 2 */
        "  fx = 2400.5;   // pixels\n"                         /* 3 */
        "  width = 640;\n"                                     /* 4 */
        "  name = \"cam0\";\n"                                 /* 5 */
        "  bayer = false;\n"                                   /* 6 */
        "  sensor = {\n"                                       /* 7 */
        "    bits = 12;\n"                                     /* 8 */
        "    mode = \"mono\";\n"                               /* 9 */
        "  };\n"                                               /* 10 */
        "};\n"                                                 /* 11 */
        "lights = (\n"                                         /* 12 */
        "  { id = 0; pos_mm = [0.0, 0.0, 500.0]; },\n"         /* 13 */
        "  { id = 1; pos_mm = [100, 0, 500]; },\n"             /* 14 */
        "  { id = 2; pos_mm = (0.0, \"x\", 500.0); },\n"       /* 15 */
        "  { id = 3; pos_mm = [1.0, 2.0]; }\n"                 /* 16 */
        ");\n"                                                 /* 17 */
        "settle_us = 250;\n";                                  /* 18 */

static void test_sample(void) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        struct imp_error e = {};
        CHECK_OK(imp_conf_load_string(sample, "rig.cfg", &c, &e));
        if (!c)
                return;
        CHECK_STR_EQ(imp_conf_path(c), "rig.cfg");
        double fx = 0, settle = 0;
        long long w = 0, bits = 0;
        bool bayer = true;
        const char *name = NULL;
        int mode = -1;
        static const char *const modes[] = { "rgb", "mono", NULL };
        CHECK_OK(imp_conf_get_double(c, NULL, "camera.fx", true, 0, 1e6, &fx, &e));
        CHECK_NEAR(fx, 2400.5, 0);
        /* integers are accepted where a number is expected */
        CHECK_OK(imp_conf_get_double(c, NULL, "settle_us", true, 0, 1e6, &settle, &e));
        CHECK_NEAR(settle, 250, 0);
        CHECK_OK(imp_conf_get_int(c, NULL, "camera.width", true, 1, 100000, &w, &e));
        CHECK_INT_EQ(w, 640);
        CHECK_OK(imp_conf_get_bool(c, NULL, "camera.bayer", true, &bayer, &e));
        CHECK(!bayer);
        CHECK_OK(imp_conf_get_string(c, NULL, "camera.name", true, &name, &e));
        CHECK_STR_EQ(name, "cam0");
        config_setting_t *cam = NULL, *sensor = NULL, *lights = NULL;
        CHECK_OK(imp_conf_get_group(c, NULL, "camera", true, &cam, &e));
        CHECK_OK(imp_conf_get_group(c, cam, "sensor", true, &sensor, &e));
        CHECK_OK(imp_conf_get_int(c, sensor, "bits", true, 8, 16, &bits, &e));
        CHECK_INT_EQ(bits, 12);
        CHECK_OK(imp_conf_get_enum(c, sensor, "mode", true, modes, &mode, &e));
        CHECK_INT_EQ(mode, 1);
        CHECK_STR_EQ(imp_conf_setting_path(sensor), "camera.sensor");
        CHECK_OK(imp_conf_get_list(c, NULL, "lights", true, &lights, &e));
        CHECK_INT_EQ(config_setting_length(lights), 4);
        double pos[3] = {};
        CHECK_OK(imp_conf_get_doubles(c, NULL, "lights.[1].pos_mm", true, 3, pos, 0, NULL, &e));
        CHECK_NEAR(pos[0], 100, 0);
        CHECK_NEAR(pos[2], 500, 0);
        double any[8];
        int n = 0;
        CHECK_OK(imp_conf_get_doubles(c, config_setting_get_elem(lights, 3), "pos_mm", true, -1, any,
                                      8, &n, &e));
        CHECK_INT_EQ(n, 2);
        /* optional and absent: untouched, 0 */
        double untouched = 42;
        CHECK_ERR(imp_conf_get_double(c, NULL, "camera.fy", false, 0, 1e6, &untouched, &e), 0);
        CHECK_NEAR(untouched, 42, 0);
        static const char *const cam_known[] = { "fx", "width", "name", "bayer", "sensor", NULL };
        CHECK_OK(imp_conf_check_known(c, cam, cam_known, &e));
}

static void expect(int r, int code, const struct imp_error *e, const char *const *needles) {
        CHECK_ERR(r, code);
        CHECK_INT_EQ(e->code, code);
        for (int i = 0; needles[i]; i++)
                CHECK_STR_CONTAINS(e->msg, needles[i]);
}

static void test_errors(void) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        struct imp_error e = {};
        CHECK_OK(imp_conf_load_string(sample, "rig.cfg", &c, &e));
        if (!c)
                return;
        double d = 7;
        long long i = 7;
        bool b = true;
        const char *s = NULL;
        int mode = 9;

        /* wrong type */
        expect(imp_conf_get_double(c, NULL, "camera.name", true, 0, 1, &d, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:5: camera.name: expected a number", "got \"cam0\"", NULL });
        expect(imp_conf_get_int(c, NULL, "camera.fx", true, 0, 10000, &i, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:3: camera.fx: expected an integer", "2400.5", NULL });
        expect(imp_conf_get_bool(c, NULL, "camera.width", true, &b, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:4: camera.width: expected true or false", NULL });
        expect(imp_conf_get_string(c, NULL, "settle_us", true, &s, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:18: settle_us: expected a string", NULL });
        expect(imp_conf_get_group(c, NULL, "lights", true, NULL, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:12: lights: expected a group", "got a list", NULL });
        static const char *const modes[] = { "rgb", "bayer", NULL };
        expect(imp_conf_get_enum(c, NULL, "camera.sensor.mode", true, modes, &mode, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:9: camera.sensor.mode: expected one of \"rgb\", \"bayer\"",
                                 "got \"mono\"", NULL });
        double pos[3];
        expect(imp_conf_get_doubles(c, NULL, "lights.[2].pos_mm", true, 3, pos, 0, NULL, &e),
               -EINVAL, &e, (const char *[]){ "rig.cfg:15: lights.[2].pos_mm.[1]: expected a number",
                                             NULL });
        expect(imp_conf_get_doubles(c, NULL, "lights.[3].pos_mm", true, 3, pos, 0, NULL, &e),
               -EINVAL, &e, (const char *[]){ "rig.cfg:16: lights.[3].pos_mm: expected 3 numbers, got 2",
                                             NULL });
        /* out of range */
        expect(imp_conf_get_int(c, NULL, "camera.sensor.bits", true, 14, 16, &i, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:8: camera.sensor.bits: expected an integer in [14, 16], got 12",
                                 NULL });
        expect(imp_conf_get_double(c, NULL, "camera.fx", true, 0, 1000, &d, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:3: camera.fx: expected a number in [0, 1000], got 2400.5",
                                 NULL });
        expect(imp_conf_get_double(c, NULL, "settle_us", true, 300, HUGE_VAL, &d, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:18: settle_us: expected a number >= 300, got 250", NULL });
        /* missing required (the line is that of the enclosing group) */
        expect(imp_conf_get_double(c, NULL, "camera.fy", true, 0, 1e6, &d, &e), -ENOENT, &e,
               (const char *[]){ "rig.cfg:2: camera.fy: missing (required)", NULL });
        config_setting_t *sensor = NULL;
        CHECK_OK(imp_conf_get_group(c, NULL, "camera.sensor", true, &sensor, &e));
        expect(imp_conf_get_double(c, sensor, "gain", true, 0, 1e6, &d, &e), -ENOENT, &e,
               (const char *[]){ "rig.cfg:7: camera.sensor.gain: missing", NULL });
        expect(imp_conf_get_int(c, NULL, "lights.[7].id", true, 0, 9, &i, &e), -ENOENT, &e,
               (const char *[]){ "rig.cfg:12: lights.[7].id: missing", NULL });
        expect(imp_conf_get_int(c, NULL, "scene", true, 0, 9, &i, &e), -ENOENT, &e,
               (const char *[]){ "rig.cfg: scene: missing (required)", NULL });
        /* nothing was written on any failure */
        CHECK_NEAR(d, 7, 0);
        CHECK_INT_EQ(i, 7);
        CHECK(b);
        CHECK(s == NULL);
        CHECK_INT_EQ(mode, 9);
        /* unknown (misspelled) field */
        static const char *const sensor_known[] = { "bits", "mdoe", NULL };
        expect(imp_conf_check_known(c, sensor, sensor_known, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:9: camera.sensor: unknown field mode (expected one of: bits, mdoe)",
                                 "did you mean mdoe?", NULL });
        static const char *const top_known[] = { "camera", "lights", NULL };
        expect(imp_conf_check_known(c, NULL, top_known, &e), -EINVAL, &e,
               (const char *[]){ "rig.cfg:18: (top level): unknown field settle_us", NULL });
}

static void test_syntax(void) {
        struct imp_conf *c = NULL;
        struct imp_error e = {};
        expect(imp_conf_load_string("a = 1;\nb = {\n  c = 2;\n  d = ;\n};\n", "plan.cfg", &c, &e),
               -EINVAL, &e, (const char *[]){ "plan.cfg:4: ", "syntax error", NULL });
        CHECK(c == NULL);
        /* libconfig arrays hold one scalar type: [1, 2.5] is an error, worth a clear line */
        expect(imp_conf_load_string("\nv = [1, 2.5];\n", "plan.cfg", &c, &e), -EINVAL, &e,
               (const char *[]){ "plan.cfg:2: mismatched element type in array", NULL });
        imp_conf_free(c);
        c = NULL;

        /* from a file: the path and the line */
        char path[512];
        snprintf(path, sizeof path, "%s/bad.cfg", test_tmpdir());
        FILE *f = fopen(path, "w");
        CHECK(f != NULL);
        if (!f)
                return;
        fputs("# comment\nx = 1;\ny = [1, 2;\n", f);
        fclose(f);
        char want[600];
        snprintf(want, sizeof want, "%s:3: ", path);
        expect(imp_conf_load(path, &c, &e), -EINVAL, &e, (const char *[]){ want, NULL });
        CHECK(c == NULL);

        snprintf(path, sizeof path, "%s/good.cfg", test_tmpdir());
        f = fopen(path, "w");
        if (!f)
                return;
        fputs("// comment\nx = 1;   # another\n/* block */ y = [1.5, 2.0];\n", f);
        fclose(f);
        CHECK_OK(imp_conf_load(path, &c, &e));
        if (c) {
                double y[2] = {};
                CHECK_OK(imp_conf_get_doubles(c, NULL, "y", true, 2, y, 0, NULL, &e));
                CHECK_NEAR(y[1], 2, 0);
                long long x = 0;
                CHECK_OK(imp_conf_get_int(c, NULL, "x", true, 0, 1, &x, &e));
                snprintf(want, sizeof want, "%s:2: x: expected an integer in [2, 3]", path);
                expect(imp_conf_get_int(c, NULL, "x", true, 2, 3, &x, &e), -EINVAL, &e,
                       (const char *[]){ want, NULL });
                imp_conf_free(c);
                c = NULL;
        }
        /* @include is relative to the including file */
        snprintf(path, sizeof path, "%s/part.cfg", test_tmpdir());
        f = fopen(path, "w");
        if (!f)
                return;
        fputs("z = 3;\n", f);
        fclose(f);
        snprintf(path, sizeof path, "%s/main.cfg", test_tmpdir());
        f = fopen(path, "w");
        if (!f)
                return;
        fputs("@include \"part.cfg\"\nw = 1;\n", f);
        fclose(f);
        CHECK_OK(imp_conf_load(path, &c, &e));
        if (c) {
                long long z = 0;
                CHECK_OK(imp_conf_get_int(c, NULL, "z", true, 0, 9, &z, &e));
                CHECK_INT_EQ(z, 3);
                imp_conf_free(c);
                c = NULL;
        }
        snprintf(path, sizeof path, "%s/absent.cfg", test_tmpdir());
        expect(imp_conf_load(path, &c, &e), -ENOENT, &e, (const char *[]){ "absent.cfg", NULL });
        imp_conf_free(NULL);
}

int main(void) {
        test_sample();
        test_errors();
        test_syntax();
        return TEST_DONE();
}
