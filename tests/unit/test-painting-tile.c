/* A painting's tile is processed as one (pipeline/process-painting.h, docs/painting.md): on
 * painting-small, rendered, tile 1 (whose 0.5 mm ridge the frame search took for a frame
 * edge, cropping a third of the tile) is processed by impasto-worker without options: the
 * copy covers its whole field, at the painting's pitch (1.02 × the 0.2 mm footprint), and
 * copy.json says where the pitch came from; --frame-search brings the crop back (what the
 * old code did), --pitch wins over the painting's, and the worker takes --frame-search. */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define WORKER IMPASTO_BINARY_DIR "/cli/impasto-worker"
#define FIELD_W_MM 40.0               /* config/scenes/painting-small.cfg: 200 × 150 px at 0.2 mm */
#define FIELD_H_MM 30.0

static json_t *load_copy(const char *dir) {
        char path[1024];
        snprintf(path, sizeof path, "%s/copy.json", dir);
        struct imp_error err = {};
        json_t *j = NULL;
        if (imp_json_load(path, &j, &err) < 0)
                fprintf(stderr, "%s\n", err.msg);
        return j;
}

static double num(const json_t *j, const char *a, const char *b, const char *c) {
        const json_t *v = json_object_get(j, a);
        v = b ? json_object_get(v, b) : v;
        v = c ? json_object_get(v, c) : v;
        return json_is_number(v) ? json_number_value(v) : -1;
}

static const json_t *tile_of(const json_t *copy) {
        return json_object_get(json_object_get(copy, "provenance"), "painting_tile");
}

/* Runs a one-job queue through impasto-worker: the tile into COPY with worker_args. */
static int worker(const char *tmp, const char *copy, const char *args) {
        char path[1024];
        snprintf(path, sizeof path, "%s/jobs-%s", tmp, copy);
        if (mkdir(path, 0755) < 0)
                return -1;
        snprintf(path, sizeof path, "%s/jobs-%s/j.json", tmp, copy);
        FILE *f = fopen(path, "w");
        if (!f)
                return -1;
        fprintf(f, "{\"id\":\"j\",\"capture\":\"../scan/tiles/0001\",\"copy\":\"../%s\",\"state\":\"queued\","
                   "\"worker_args\":\"%s\"}\n", copy, args);
        fclose(f);
        return test_sh("%s %s > /dev/null", WORKER, path);
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0 || stat(WORKER, &st) < 0)
                TEST_SKIP("%s or %s not built", IMPASTO, WORKER);
        char tmp[] = "/tmp/impasto-test-painting-tile.XXXXXX";
        CHECK(mkdtemp(tmp) != NULL);
        CHECK_INT_EQ(test_sh("%s sim render --scene %s/config/scenes/painting-small.cfg --plan %s/config/plans/painting-small.cfg "
                        "--out %s/scan --quiet > /dev/null", IMPASTO, IMPASTO_SOURCE_DIR, IMPASTO_SOURCE_DIR, tmp), 0);
        char dir[1024];

        /* The worker, no pitch, no frame option: the whole field at the painting's pitch. */
        CHECK_INT_EQ(worker(tmp, "whole", "--no-btf"), 0);
        snprintf(dir, sizeof dir, "%s/whole", tmp);
        _cleanup_json_ json_t *whole = load_copy(dir);
        CHECK(whole != NULL);
        double pitch = num(whole, "pitch_mm", NULL, NULL), nx = num(whole, "nx", NULL, NULL),
               ny = num(whole, "ny", NULL, NULL), mask = num(whole, "stages", "heightfield", "mask_texels");
        fprintf(stderr, "whole field: %.0f x %.0f texels at %.4f mm, %.0f in the mask\n", nx, ny, pitch, mask);
        CHECK_NEAR(pitch, 0.204, 1e-9);
        CHECK_GE(nx * pitch, 0.97 * FIELD_W_MM);
        CHECK_GE(ny * pitch, 0.97 * FIELD_H_MM);
        CHECK_GE(mask, 0.97 * nx * ny);
        const json_t *t = tile_of(whole);
        CHECK(json_is_true(json_object_get(t, "is_tile")));
        CHECK(json_is_false(json_object_get(t, "frame_search")));
        CHECK_INT_EQ(json_integer_value(json_object_get(t, "index")), 1);
        const char *src = json_string_value(json_object_get(t, "pitch_source"));
        CHECK(src && strstr(src, "footprint"));
        CHECK_NEAR(num(t, "pitch_mm", NULL, NULL), 0.204, 1e-9);

        /* --frame-search: the ridge's cliff is taken for a frame and the tile cropped. */
        CHECK_INT_EQ(test_sh("%s process %s/scan/tiles/0001 --out %s/framed --quiet --no-btf --frame-search > /dev/null", IMPASTO,
                        tmp, tmp), 0);
        snprintf(dir, sizeof dir, "%s/framed", tmp);
        _cleanup_json_ json_t *framed = load_copy(dir);
        CHECK(framed != NULL);
        double mask_f = num(framed, "stages", "heightfield", "mask_texels");
        fprintf(stderr, "with the frame search: %.0f texels in the mask\n", mask_f);
        CHECK_LE(mask_f, 0.8 * mask);
        CHECK(json_is_true(json_object_get(tile_of(framed), "frame_search")));

        /* --pitch wins, and says so. */
        CHECK_INT_EQ(test_sh("%s process %s/scan/tiles/0001 --out %s/pitched --quiet --no-btf --pitch 0.25 > /dev/null", IMPASTO,
                        tmp, tmp), 0);
        snprintf(dir, sizeof dir, "%s/pitched", tmp);
        _cleanup_json_ json_t *pitched = load_copy(dir);
        CHECK(pitched != NULL);
        CHECK_NEAR(num(pitched, "pitch_mm", NULL, NULL), 0.25, 1e-12);
        CHECK_STR_EQ(json_string_value(json_object_get(tile_of(pitched), "pitch_source")), "--pitch");

        /* The worker takes --frame-search too, and refuses a value given to it. */
        CHECK_INT_EQ(worker(tmp, "wframed", "--no-btf --frame-search"), 0);
        snprintf(dir, sizeof dir, "%s/wframed", tmp);
        _cleanup_json_ json_t *wframed = load_copy(dir);
        CHECK(wframed != NULL);
        CHECK(json_is_true(json_object_get(tile_of(wframed), "frame_search")));
        CHECK(worker(tmp, "wbad", "--no-frame-search=1") != 0);

        test_sh("rm -rf %s", tmp);
        return TEST_DONE();
}
