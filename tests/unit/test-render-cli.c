/* `impasto render` on the copy test-appearance-demo leaves behind (CTest fixture): PNG and
 * EXR of the requested size, finite values, something of the copy in view; bad arguments
 * exit 2 with a message naming the argument; a missing copy exits 3. */
#include <stdio.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "image.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define COPY    IMPASTO_BINARY_DIR "/tests/appearance-small/copy"

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static char *slurp(const char *path) {
        FILE *f = fopen(path, "r");
        if (!f)
                return NULL;
        char *buf = calloc(1, 1 << 14);
        size_t n = fread(buf, 1, (1 << 14) - 1, f);
        buf[n] = 0;
        fclose(f);
        return buf;
}

/* Runs `impasto render COPY ARGS 2> err.txt`, expects exit 2 and NAME in the message. */
static void bad(const char *tmp, const char *args, const char *name) {
        char cmd[2048], path[512];
        snprintf(path, sizeof path, "%s/err.txt", tmp);
        snprintf(cmd, sizeof cmd, "%s render %s %s 2> %s", IMPASTO, COPY, args, path);
        CHECK_INT_EQ(run(cmd), 2);
        _cleanup_free_ char *msg = slurp(path);
        CHECK(msg != NULL);
        if (msg)
                CHECK_STR_CONTAINS(msg, name);
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        if (stat(COPY "/rho_d.exr", &st) < 0)
                TEST_SKIP("%s missing: run test-appearance-demo first (CTest fixture)", COPY);
        const char *tmp = test_tmpdir();
        char cmd[2048], png[512], exr[512];
        snprintf(png, sizeof png, "%s/view.png", tmp);
        snprintf(exr, sizeof exr, "%s/view.exr", tmp);
        struct imp_error err = {};

        /* oblique view from the camera's side, light from the upper right */
        snprintf(cmd, sizeof cmd, "%s render %s --view 5.6,-100,200 --light 100,50,300 --out %s --size 160x120 --fov 5",
                 IMPASTO, COPY, png);
        CHECK_INT_EQ(run(cmd), 0);
        _cleanup_image_ struct imp_image *img = NULL;
        CHECK_OK(imp_png_read(png, &img, &err));
        if (img) {
                CHECK_INT_EQ(img->width, 160);
                CHECK_INT_EQ(img->height, 120);
                CHECK_INT_EQ(img->channels, 3);
                size_t lit = 0;
                for (int y = 0; y < img->height; y++)
                        for (int x = 0; x < img->width; x++)
                                lit += imp_image_get(img, x, y, 1) > 0;
                CHECK_GE(lit, img->width * img->height / 10);   /* the canvas fills the middle */
        }

        /* EXR, relief everywhere, shadows on, explicit target: linear and finite */
        snprintf(cmd, sizeof cmd, "%s render %s --view 6,4,150,6,4,0 --light -50,4,100 --out %s --size 48x32 "
                 "--fov 4 --mode relief --shadows", IMPASTO, COPY, exr);
        CHECK_INT_EQ(run(cmd), 0);
        _cleanup_image_ struct imp_image *lin = NULL;
        CHECK_OK(imp_exr_read(exr, &lin, NULL, &err));
        if (lin) {
                CHECK_INT_EQ(lin->width, 48);
                CHECK_INT_EQ(lin->height, 32);
                size_t nonfinite = 0, hit = 0;
                for (int y = 0; y < lin->height; y++)
                        for (int x = 0; x < lin->width; x++)
                                for (int c = 0; c < lin->channels; c++) {
                                        double v = imp_image_get(lin, x, y, c);
                                        nonfinite += !isfinite(v);
                                        hit += v > 0;
                                }
                CHECK_INT_EQ(nonfinite, 0);
                CHECK_GE(hit, 1);
        }

        bad(tmp, "--view 1,2 --light 1,2,3 --out x.png", "--view");
        bad(tmp, "--view 1,2,3 --light 1,2,x --out x.png", "--light");
        bad(tmp, "--view 1,2,3 --light 1,2,3 --out x.jpg", "--out");
        bad(tmp, "--view 1,2,3 --light 1,2,3 --out x.png --size 0x5", "--size");
        bad(tmp, "--view 1,2,3 --light 1,2,3 --out x.png --size 10", "--size");
        bad(tmp, "--view 1,2,3 --light 1,2,3 --out x.png --fov 200", "--fov");
        bad(tmp, "--view 1,2,3 --light 1,2,3 --out x.png --mode glossy", "--mode");
        bad(tmp, "--view 1,2,3 --out x.png", "--light");
        bad(tmp, "--light 1,2,3 --out x.png", "--view");
        bad(tmp, "--view 1,2,3 --light 1,2,3", "--out");

        snprintf(cmd, sizeof cmd, "%s render %s/nothing --view 1,2,3 --light 1,2,3 --out %s 2>/dev/null", IMPASTO,
                 tmp, png);
        CHECK_INT_EQ(run(cmd), 3);
        return TEST_DONE();
}
