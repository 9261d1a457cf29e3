/* Hostile painting.json given to `impasto mosaic` (imp_painting_load) and to `impasto process`
 * of a tile (imp_painting_tile_detect reads ../../painting.json): each refused at once with
 * -EBADMSG naming the file and the field, nothing read outside the painting's directory,
 * memory bounded (a 65 MiB document is refused before it is parsed), a FIFO in place of the
 * file refused without blocking (the alarm fails the test if a read hangs). */
#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>
#include "json-util.h"
#include "mosaic.h"
#include "process-painting.h"
#include "test.h"

#define HDR "{\"format\": \"impasto-painting\", \"extent_mm\": [30, 20], \"fov_mm\": [12, 8], \"origin_mm\": [0, 0], "
#define TILE(idx, copy) "{\"index\": " #idx ", \"center_mm\": [6, 4], \"readback_mm\": [6, 4, 0], \"copy\": \"" copy "\"}"

static void put(const char *path, const char *text) {
        struct imp_error e = { 0 };
        CHECK_OK(imp_file_write_atomic(path, text, strlen(text), &e));
}

/* A copy.json the mosaic takes: 4 × 4 texels at 1 mm, the canvas on the painting plane. */
static void put_copy(const char *dir) {
        char p[700];
        CHECK_OK(imp_mkdir_p(dir, 0755));
        snprintf(p, sizeof p, "%s/copy.json", dir);
        put(p, "{\"nx\": 4, \"ny\": 4, \"pitch_mm\": 1.0, \"canvas_to_world\": [1,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]}");
}

static void check_mosaic(const char *tmp) {
        char dir[600], path[700], out[700];
        snprintf(dir, sizeof dir, "%s/m", tmp);
        snprintf(out, sizeof out, "%s/outside", tmp);
        snprintf(path, sizeof path, "%s/copies/0000", dir);
        put_copy(path);
        snprintf(path, sizeof path, "%s/copies/0001", dir);
        put_copy(path);
        put_copy(out);  /* what a "../outside" would read */
        snprintf(path, sizeof path, "%s/painting.json", dir);
        put(path, HDR "\"tiles\": [" TILE(0, "copies/0000") ", " TILE(1, "copies/0001") "]}");
        struct imp_painting p;
        struct imp_error err = { 0 };
        CHECK_MSG(imp_painting_load(dir, &p, &err) == 0, "the good painting: %s", err.msg);
        imp_painting_done(&p);
        static const char *const cases[][2] = {
                { HDR "\"tiles\": [" TILE(0, "../outside") "]}", "tiles[0].copy: \"../outside\" leaves the painting's directory" },
                { HDR "\"tiles\": [" TILE(0, "copies/../../outside") "]}", "tiles[0].copy: \"copies/../../outside\" leaves" },
                { HDR "\"tiles\": [" TILE(0, "copies/0000") ", " TILE(0, "copies/0001") "]}", "tiles[1].index: 0: another tile has it already" },
                { HDR "\"tiles\": [" TILE(0, "copies/0000") ", " TILE(99, "copies/0001") "]}", "tiles[1].index: expected 0..1, got 99" },
                { "{\"format\": \"impasto-painting\", \"extent_mm\": [1e300, 1e300], \"fov_mm\": [12, 8], \"origin_mm\": [0, 0], "
                  "\"tiles\": [" TILE(0, "copies/0000") "]}", "extent_mm[0]: expected a size in (0, 100000] mm" },
                { HDR "\"tiles\": [" TILE(0, "copies/0000") "], \"cols\": 1, \"rows\": 1, \"x\": [" TILE(1, "a") "]}", NULL },
        };
        for (size_t i = 0; i < ARRAY_SIZE(cases); i++) {
                put(path, cases[i][0]);
                int r = imp_painting_load(dir, &p, &err);
                if (!cases[i][1])
                        CHECK_MSG(r == 0, "case %zu: %s", i, err.msg);     /* unknown keys are fine */
                else {
                        CHECK_MSG(r == -EBADMSG, "case %zu: returned %d (%s)", i, r, err.msg);
                        CHECK_MSG(strstr(err.msg, cases[i][1]) && strstr(err.msg, "painting.json"), "case %zu: %s", i,
                                  err.msg);
                }
                imp_painting_done(&p);
        }
        /* 65 MiB of whitespace around a good document: refused by its size */
        int fd = open(path, O_WRONLY | O_TRUNC | O_CLOEXEC);
        CHECK(fd >= 0);
        static char spaces[1 << 20];
        memset(spaces, ' ', sizeof spaces);
        for (int k = 0; k < 65 && fd >= 0; k++)
                CHECK(write(fd, spaces, sizeof spaces) == (ssize_t) sizeof spaces);
        const char *good = HDR "\"tiles\": [" TILE(0, "copies/0000") "]}";
        CHECK(fd >= 0 && write(fd, good, strlen(good)) == (ssize_t) strlen(good));
        if (fd >= 0)
                close(fd);
        CHECK_ERR(imp_painting_load(dir, &p, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "expected a regular file of at most 64 MiB");
        imp_painting_done(&p);
        /* a FIFO: refused, not waited on */
        CHECK(unlink(path) == 0 && mkfifo(path, 0600) == 0);
        CHECK_ERR(imp_painting_load(dir, &p, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "a special file");
        imp_painting_done(&p);
}

/* A capture set as tile 0 of a painting: P/tiles/0000, P/painting.json. */
static void check_process(const char *tmp) {
        char pdir[600], set[700], path[700];
        snprintf(pdir, sizeof pdir, "%s/p", tmp);
        snprintf(set, sizeof set, "%s/tiles/0000", pdir);
        snprintf(path, sizeof path, "%s/tiles", pdir);
        CHECK_OK(imp_mkdir_p(path, 0755));
        struct imp_rig rig = { .n_cameras = 1 };
        snprintf(rig.cameras[0].name, sizeof rig.cameras[0].name, "cam0");
        struct imp_pinhole *m = &rig.cameras[0].model;
        *m = (struct imp_pinhole){ .width = 64, .height = 48, .fx = 80, .fy = 80, .cx = 32, .cy = 24 };
        imp_pinhole_look_at(m, (double[]){ 0, 0, 500 }, (double[]){ 0, 0, 0 }, (double[]){ 1, 0, 0 });
        struct imp_error err = { 0 };
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        CHECK_OK(imp_captureset_create(set, &rig, NULL, &cs, &err));
        if (!cs)
                return;
        snprintf(path, sizeof path, "%s/painting.json", pdir);
#define PTILE(idx) "{\"index\": " #idx ", \"center_mm\": [6, 4], \"readback_mm\": [6, 4, 0], \"capture\": \"tiles/0000\"}"
        put(path, HDR "\"tiles\": [" PTILE(0) "]}");
        struct imp_painting_tile t;
        CHECK_OK(imp_painting_tile_detect(cs, &t, &err));
        CHECK(t.is_tile && t.index == 0);
        static const char *const cases[][2] = {
                { HDR "\"tiles\": [" PTILE(4000000000) "]}", "tiles[0].index: expected 0..0, got 4000000000" },
                { HDR "\"pitch_mm\": 1e-300, \"tiles\": [" PTILE(0) "]}", "pitch_mm: expected a number in [0.001, 1000], got 1e-300" },
                { HDR "\"tiles\": 5}", "tiles: expected an array of 1..100000 tiles, got an integer" },
                { HDR "\"tiles\": [" PTILE(0) ", " PTILE(1) "], \"cols\": 1, \"rows\": 1}", "more than cols × rows = 1 × 1" },
        };
        for (size_t i = 0; i < ARRAY_SIZE(cases); i++) {
                put(path, cases[i][0]);
                int r = imp_painting_tile_detect(cs, &t, &err);
                CHECK_MSG(r < 0, "case %zu: accepted (index %d, pitch %g)", i, t.index, t.pitch_mm);
                CHECK_MSG(strstr(err.msg, "painting.json") && (!cases[i][1] || strstr(err.msg, cases[i][1])),
                          "case %zu: %s", i, err.msg);
        }
        CHECK(unlink(path) == 0 && mkfifo(path, 0600) == 0);
        CHECK(imp_painting_tile_detect(cs, &t, &err) < 0);
        CHECK_STR_CONTAINS(err.msg, "a special file");
        imp_rig_free(&rig);
}

int main(void) {
        alarm((unsigned) (60 * test_timeout_scale()));        /* a read that blocks fails the test */
        const char *tmp = test_tmpdir();
        check_mosaic(tmp);
        check_process(tmp);
        return TEST_DONE();
}
