/* `impasto sim render` end to end: the flat-white scene (with projector, shadows and noise
 * switched on) and the quick plan give a capture set that imp_captureset_open reads back
 * with the plan's frame count and the truth files; a bad scene exits 3 naming file:line. */
#include <stdio.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "captureset.h"
#include "image.h"
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define QUICK_FRAMES (2 + 8 + 4 + 3 + 1)   /* quick.cfg with a 256-pixel-wide projector */

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static char *slurp(const char *path) {
        FILE *f = fopen(path, "r");
        if (!f)
                return NULL;
        char *buf = calloc(1, 1 << 16);
        size_t n = fread(buf, 1, (1 << 16) - 1, f);
        buf[n] = 0;
        fclose(f);
        return buf;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char scene[512], cmd[2048], out[512], path[1024];

        /* flat-white with more effects on */
        _cleanup_free_ char *text = slurp(IMPASTO_SOURCE_DIR "/config/scenes/flat-white.cfg");
        CHECK(text != NULL);
        if (!text)
                return TEST_DONE();
        char *fx = strstr(text, "effects = [\"direct\"];");
        CHECK(fx != NULL);
        snprintf(scene, sizeof scene, "%s/scene.cfg", tmp);
        FILE *f = fopen(scene, "w");
        fwrite(text, 1, fx - text, f);
        fputs("effects = [\"direct\", \"shadows\", \"projector\", \"noise\", \"vignetting\"];", f);
        fputs(fx + strlen("effects = [\"direct\"];"), f);
        fclose(f);

        snprintf(out, sizeof out, "%s/set", tmp);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s --plan %s/config/plans/quick.cfg --out %s --seed 7 --threads 2",
                 IMPASTO, scene, IMPASTO_SOURCE_DIR, out);
        CHECK_INT_EQ(run(cmd), 0);

        struct imp_error err = { 0 };
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        CHECK_OK(imp_captureset_open(out, &cs, &err));
        if (!cs) {
                fprintf(stderr, "%s\n", err.msg);
                return TEST_DONE();
        }
        CHECK_INT_EQ(imp_captureset_count(cs), QUICK_FRAMES);
        CHECK_INT_EQ(imp_captureset_rig(cs)->n_lights, 8);
        _cleanup_image_ struct imp_image *white = NULL, *dark = NULL;
        CHECK_OK(imp_captureset_load_frame(cs, 0, &white, &err));
        CHECK_OK(imp_captureset_load_frame(cs, QUICK_FRAMES - 1, &dark, &err));
        if (white && dark) {
                CHECK_INT_EQ(white->width, 200);
                CHECK_INT_EQ(white->type, IMP_PIX_U16);
                CHECK_STR_EQ(imp_captureset_record(cs, QUICK_FRAMES - 1)->step, "dark");
                double c = imp_image_get(white, 100, 75, 0), d = imp_image_get(dark, 100, 75, 0);
                fprintf(stderr, "white centre %.0f DN, dark %.0f DN\n", c, d);
                CHECK_GE(c, d + 500);           /* the projector lights the canvas */
                CHECK_LE(fabs(d - 64), 20);     /* dark frame: black level + read noise */
        }
        const char *truth[] = { "truth.json", "heightfield.exr", "rho_d.exr", "rho_s.exr", "lobe.exr", "rig.json",
                                "correspondence-cam0.exr" };
        for (size_t i = 0; i < ARRAY_SIZE(truth); i++) {
                snprintf(path, sizeof path, "%s/truth/%s", out, truth[i]);
                CHECK_MSG(stat(path, &st) == 0, "%s missing", path);
        }
        _cleanup_json_ json_t *tj = NULL;
        snprintf(path, sizeof path, "%s/truth/truth.json", out);
        CHECK_OK(imp_json_load(path, &tj, &err));
        long long nx = 0;
        double pitch = 0;
        CHECK_OK(imp_json_get_int(tj, "nx", true, &nx, "truth.json", &err));
        CHECK_OK(imp_json_get_double(tj, "pitch_mm", true, &pitch, "truth.json", &err));
        CHECK_INT_EQ(nx, 201);
        CHECK_NEAR(pitch, 0.1, 1e-12);
        _cleanup_image_ struct imp_image *hf = NULL, *corr = NULL;
        char **names = NULL;
        snprintf(path, sizeof path, "%s/truth/heightfield.exr", out);
        CHECK_OK(imp_exr_read(path, &hf, &names, &err));
        if (hf && names) {
                CHECK_INT_EQ(hf->channels, 5);
                bool has_mask = false;
                for (int i = 0; names[i]; i++)
                        has_mask |= !strcmp(names[i], "mask");
                CHECK(has_mask);
        }
        imp_strv_free(names);
        snprintf(path, sizeof path, "%s/truth/correspondence-cam0.exr", out);
        CHECK_OK(imp_exr_read(path, &corr, NULL, &err));
        if (corr) {
                CHECK_INT_EQ(corr->width, 200);
                CHECK_INT_EQ(corr->channels, 4);
        }

        /* a bad scene: exit 3, message names file and line */
        snprintf(scene, sizeof scene, "%s/bad.cfg", tmp);
        f = fopen(scene, "w");
        fputs("scene = {\n  effects = [\"direct\", \"sparkle\"];\n};\n", f);
        fclose(f);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s --plan %s/config/plans/quick.cfg --out %s/set2 2> %s/err.txt",
                 IMPASTO, scene, IMPASTO_SOURCE_DIR, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 3);
        snprintf(path, sizeof path, "%s/err.txt", tmp);
        _cleanup_free_ char *msg = slurp(path);
        CHECK_STR_CONTAINS(msg, "bad.cfg:2: scene.effects.[1]: unknown effect \"sparkle\"");
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s > /dev/null 2>&1", IMPASTO, scene);
        CHECK_INT_EQ(run(cmd), 2);
        return TEST_DONE();
}
