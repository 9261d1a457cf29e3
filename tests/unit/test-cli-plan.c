/* `impasto plan validate|estimate` offline: the demo plan against the demo scene's rig (as
 * rig.json, the way a capture set or a calibration carries it) gives the library's frame
 * count and capture-time estimate; a broken plan exits 3 naming file:line: field; a
 * missing rig is a usage error; --daemon without a daemon exits 4. */
#include <stdio.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "json-util.h"
#include "plan.h"
#include "rig.h"
#include "scene.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define DEMO_PLAN IMPASTO_SOURCE_DIR "/config/plans/demo.cfg"
#define DEMO_SCENE IMPASTO_SOURCE_DIR "/config/scenes/demo.cfg"

/* Runs cmd with stdout+stderr into *ret_out (caller frees); returns the exit code. */
static int run(const char *cmd, char **ret_out) {
        char full[4096];
        snprintf(full, sizeof full, "%s 2>&1", cmd);
        fprintf(stderr, "$ %s\n", cmd);
        FILE *p = popen(full, "r");
        if (!p)
                return -1;
        char *buf = calloc(1, 65536);
        size_t n = buf ? fread(buf, 1, 65535, p) : 0;
        int st = pclose(p);
        fprintf(stderr, "%.*s", (int) n, buf ? buf : "");
        *ret_out = buf;
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char rig_path[512], cmd[2048], broken[512];
        struct imp_error err = {};

        /* the rig as a file, and the library's own answer to compare with */
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        CHECK_OK(imp_scene_load(DEMO_SCENE, &scene, &err));
        if (!scene)
                return TEST_DONE();
        const struct imp_rig *rig = imp_scene_rig(scene);
        snprintf(rig_path, sizeof rig_path, "%s/rig.json", tmp);
        CHECK_OK(imp_rig_save(rig_path, rig, &err));
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        CHECK_OK(imp_plan_load(DEMO_PLAN, rig, &plan, &err));
        if (!plan)
                return TEST_DONE();
        size_t frames = imp_plan_count(plan);
        double estimate_s = imp_plan_estimate_s(plan, rig);

        /* validate, human and JSON */
        _cleanup_free_ char *o1 = NULL, *o2 = NULL, *o3 = NULL, *o4 = NULL, *o5 = NULL, *o6 = NULL, *o7 = NULL;
        snprintf(cmd, sizeof cmd, "%s plan validate %s --rig %s", IMPASTO, DEMO_PLAN, rig_path);
        CHECK_INT_EQ(run(cmd, &o1), 0);
        CHECK_STR_CONTAINS(o1, "plan is valid");
        snprintf(cmd, sizeof cmd, "%s plan validate %s --rig %s --json", IMPASTO, DEMO_PLAN, rig_path);
        CHECK_INT_EQ(run(cmd, &o2), 0);
        _cleanup_json_ json_t *v = json_loads(o2 ? o2 : "", 0, NULL);
        CHECK(json_is_true(json_object_get(v, "valid")));
        CHECK_INT_EQ(json_integer_value(json_object_get(v, "frames")), frames);
        CHECK_INT_GE(json_integer_value(json_object_get(v, "steps")), 1);

        /* estimate: frames, bytes (16-bit frames of the one camera), capture time */
        snprintf(cmd, sizeof cmd, "%s plan estimate %s --rig %s --json", IMPASTO, DEMO_PLAN, rig_path);
        CHECK_INT_EQ(run(cmd, &o3), 0);
        _cleanup_json_ json_t *e = json_loads(o3 ? o3 : "", 0, NULL);
        CHECK_INT_EQ(json_integer_value(json_object_get(e, "frames")), frames);
        CHECK_INT_EQ(json_integer_value(json_object_get(e, "bytes")),
                     (long long) frames * rig->cameras[0].model.width * rig->cameras[0].model.height * 2);
        CHECK_NEAR(json_number_value(json_object_get(e, "duration_s")), estimate_s, 1e-6 * estimate_s);
        snprintf(cmd, sizeof cmd, "%s plan estimate %s --scene %s", IMPASTO, DEMO_PLAN, DEMO_SCENE);
        CHECK_INT_EQ(run(cmd, &o4), 0);
        CHECK_STR_CONTAINS(o4, "capture time");

        /* a broken plan: exit 3, file:line: field */
        snprintf(broken, sizeof broken, "%s/broken.cfg", tmp);
        FILE *f = fopen(broken, "w");
        CHECK(f != NULL);
        if (f) {
                fputs("# broken on purpose\ncameras = [\"cam0\"];\ndome = { lights = \"some\"; exposures_us = [10000.0]; };\n", f);
                fclose(f);
        }
        snprintf(cmd, sizeof cmd, "%s plan validate %s --rig %s", IMPASTO, broken, rig_path);
        CHECK_INT_EQ(run(cmd, &o5), 3);
        CHECK_STR_CONTAINS(o5, "broken.cfg:3: dome.lights");

        /* usage: no rig named; a missing rig file is bad input */
        snprintf(cmd, sizeof cmd, "%s plan validate %s", IMPASTO, DEMO_PLAN);
        CHECK_INT_EQ(run(cmd, &o6), 2);
        CHECK_STR_CONTAINS(o6, "--rig");
        snprintf(cmd, sizeof cmd, "%s plan estimate %s --rig %s/absent.json", IMPASTO, DEMO_PLAN, tmp);
        CHECK_INT_EQ(run(cmd, &o7), 3);

        /* --daemon without a daemon: unreachable */
        _cleanup_free_ char *o8 = NULL;
        snprintf(cmd, sizeof cmd, "IMPASTO_SOCKET=%s/none.sock %s plan validate %s --daemon", tmp, IMPASTO, DEMO_PLAN);
        CHECK_INT_EQ(run(cmd, &o8), 4);
        CHECK_STR_CONTAINS(o8, "none.sock");
        return TEST_DONE();
}
