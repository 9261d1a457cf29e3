/* `impasto export --to lp` on the capture set and copy test-appearance-demo leaves behind
 * (CTest fixture), read back without impasto's readers (jansson, libpng, libtiff):
 *  - lights.lp: the rig's light count, unit directions; their pairwise angles and their
 *    elevations over the canvas agree with the rig's light positions seen from the canvas
 *    centre, with the same handedness (within 0.03: the frame's origin is the canvas point at the image centre, a
 *    few mm from the canvas centre, the lights ~500 mm away);
 *  - lights.dome: Relight's fields, directions identical to the .lp's, positions as far
 *    from the origin as the lights are from the canvas (within 20 mm);
 *  - images: 16-bit PNGs of the camera's size; light 0's equals its raw frame at exposure
 *    index 0 with the black level removed and the sensor's range stretched (within 1 DN). */
#include <png.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <tiffio.h>
#include "json-util.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define SMALL   IMPASTO_BINARY_DIR "/tests/appearance-small"

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static void norm3(double v[3]) {
        double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int a = 0; a < 3; a++)
                v[a] /= n;
}

/* A 16-bit RGB PNG through libpng's simplified API (linear: no conversion). */
static uint16_t *read_png16(const char *path, int *w, int *h) {
        png_image img = { .version = PNG_IMAGE_VERSION };
        if (!png_image_begin_read_from_file(&img, path))
                return NULL;
        img.format = PNG_FORMAT_LINEAR_RGB;
        uint16_t *buf = malloc(PNG_IMAGE_SIZE(img));
        if (!buf || !png_image_finish_read(&img, NULL, buf, 0, NULL)) {
                free(buf);
                return NULL;
        }
        *w = (int) img.width, *h = (int) img.height;
        return buf;
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        if (stat(SMALL "/set/manifest.jsonl", &st) < 0)
                TEST_SKIP("%s missing: run test-appearance-demo first (CTest fixture)", SMALL);
        const char *tmp = test_tmpdir();
        char cmd[4096], path[1024];
        /* a copy of the set: opening a capture set may repair a torn manifest */
        snprintf(cmd, sizeof cmd, "cp -r %s/set %s/set", SMALL, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(cmd, sizeof cmd, "%s export %s/copy --to lp --capture %s/set --exposure-index 0 --out %s/lp", IMPASTO,
                 SMALL, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);

        struct imp_error err = {};
        _cleanup_json_ json_t *rig = NULL, *copy = NULL, *dome = NULL;
        snprintf(path, sizeof path, "%s/set/rig.json", tmp);
        CHECK_OK(imp_json_load(path, &rig, &err));
        CHECK_OK(imp_json_load(SMALL "/copy/copy.json", &copy, &err));
        snprintf(path, sizeof path, "%s/lp/lights.dome", tmp);
        CHECK_OK(imp_json_load(path, &dome, &err));
        if (!rig || !copy || !dome)
                return TEST_DONE();
        json_t *lights = json_object_get(rig, "lights");
        size_t n = json_array_size(lights);
        CHECK_INT_GE(n, 8);
        /* canvas centre and normal in the world */
        double M[16], pitch = json_real_value(json_object_get(copy, "pitch_mm"));
        for (int i = 0; i < 16; i++)
                M[i] = json_number_value(json_array_get(json_object_get(copy, "canvas_to_world"), (size_t) i));
        double cu = 0.5 * (json_integer_value(json_object_get(copy, "nx")) - 1) * pitch;
        double cv = 0.5 * (json_integer_value(json_object_get(copy, "ny")) - 1) * pitch;
        double centre[3], nrm[3] = { M[2], M[6], M[10] };
        for (int a = 0; a < 3; a++)
                centre[a] = M[4 * a] * cu + M[4 * a + 1] * cv + M[4 * a + 3];
        double (*w)[3] = calloc(n, sizeof *w), (*u)[3] = calloc(n, sizeof *u), *dist = calloc(n, sizeof *dist);
        for (size_t l = 0; l < n; l++) {
                json_t *pos = json_object_get(json_array_get(lights, l), "pos_mm");
                for (int a = 0; a < 3; a++)
                        w[l][a] = json_number_value(json_array_get(pos, (size_t) a)) - centre[a];
                dist[l] = sqrt(w[l][0] * w[l][0] + w[l][1] * w[l][1] + w[l][2] * w[l][2]);
                norm3(w[l]);
        }
        /* lights.lp */
        snprintf(path, sizeof path, "%s/lp/lights.lp", tmp);
        FILE *f = fopen(path, "r");
        CHECK(f != NULL);
        size_t count = 0, bad_unit = 0, bad_elev = 0, bad_angle = 0, bad_dome = 0, bad_dist = 0;
        char file0[256] = "";
        if (f) {
                CHECK(fscanf(f, "%zu", &count) == 1);
                CHECK_INT_EQ(count, n);
                for (size_t l = 0; l < n && l < count; l++) {
                        char name[256];
                        CHECK(fscanf(f, "%255s %lf %lf %lf", name, &u[l][0], &u[l][1], &u[l][2]) == 4);
                        if (l == 0)
                                snprintf(file0, sizeof file0, "%s", name);
                        bad_unit += fabs(sqrt(u[l][0] * u[l][0] + u[l][1] * u[l][1] + u[l][2] * u[l][2]) - 1) > 1e-6;
                        double elev = fabs(w[l][0] * nrm[0] + w[l][1] * nrm[1] + w[l][2] * nrm[2]);
                        bad_elev += fabs(u[l][2] - elev) > 0.03;
                }
                fclose(f);
        }
        for (size_t a = 0; a < n; a++)
                for (size_t b = a + 1; b < n; b++) {
                        double du = u[a][0] * u[b][0] + u[a][1] * u[b][1] + u[a][2] * u[b][2];
                        double dw = w[a][0] * w[b][0] + w[a][1] * w[b][1] + w[a][2] * w[b][2];
                        bad_angle += fabs(du - dw) > 0.03;
                }
        /* handedness: a mirrored frame keeps every angle but flips this sign */
        size_t flipped = 0;
        for (size_t a = 0; a + 2 < n; a++) {
                double *p = u[a], *q = u[a + 1], *r = u[a + 2], *P = w[a], *Q = w[a + 1], *R = w[a + 2];
                double du = p[0] * (q[1] * r[2] - q[2] * r[1]) - p[1] * (q[0] * r[2] - q[2] * r[0]) + p[2] * (q[0] * r[1] - q[1] * r[0]);
                double dw = P[0] * (Q[1] * R[2] - Q[2] * R[1]) - P[1] * (Q[0] * R[2] - Q[2] * R[0]) + P[2] * (Q[0] * R[1] - Q[1] * R[0]);
                flipped += fabs(dw) > 0.05 && du * dw < 0;
        }
        CHECK_INT_EQ(flipped, 0);
        CHECK_INT_EQ(bad_unit, 0);
        CHECK_INT_EQ(bad_elev, 0);
        CHECK_INT_EQ(bad_angle, 0);
        /* lights.dome */
        CHECK_STR_EQ(json_string_value(json_object_get(dome, "lightConfiguration")), "lights3d");
        json_t *dd = json_object_get(dome, "directions"), *pp = json_object_get(dome, "positions3d");
        CHECK_INT_EQ(json_array_size(dd), n);
        CHECK_INT_EQ(json_array_size(pp), n);
        CHECK_INT_EQ(json_array_size(json_object_get(dome, "ledAdjust")), n);
        for (size_t l = 0; l < n && l < json_array_size(dd) && l < json_array_size(pp); l++) {
                json_t *d = json_array_get(dd, l), *p = json_array_get(pp, l);
                bad_dome += fabs(json_number_value(json_object_get(d, "x")) - u[l][0]) > 1e-6 ||
                            fabs(json_number_value(json_object_get(d, "y")) - u[l][1]) > 1e-6 ||
                            fabs(json_number_value(json_object_get(d, "z")) - u[l][2]) > 1e-6;
                double px = json_number_value(json_object_get(p, "x")), py = json_number_value(json_object_get(p, "y")),
                       pz = json_number_value(json_object_get(p, "z"));
                bad_dist += fabs(sqrt(px * px + py * py + pz * pz) - dist[l]) > 20;
        }
        CHECK_INT_EQ(bad_dome, 0);
        CHECK_INT_EQ(bad_dist, 0);
        /* light 0's image against its raw frame (exposure index 0), read with libtiff */
        json_t *cam = json_array_get(json_object_get(rig, "cameras"), 0), *sensor = json_object_get(cam, "sensor");
        int bits = (int) json_integer_value(json_object_get(sensor, "bits"));
        double black = json_number_value(json_object_get(sensor, "black_level_dn"));
        int id0 = (int) json_integer_value(json_object_get(json_array_get(lights, 0), "id"));
        snprintf(path, sizeof path, "%s/set/manifest.jsonl", tmp);
        char frame[512] = "";
        f = fopen(path, "r");
        char line[4096];
        while (f && fgets(line, sizeof line, f)) {
                json_t *r = json_loads(line, 0, NULL);
                if (r && !strcmp(json_string_value(json_object_get(r, "step")) ?: "", "dome") &&
                    json_integer_value(json_object_get(r, "light")) == id0 &&
                    json_integer_value(json_object_get(r, "exposure_index")) == 0 && !frame[0])
                        snprintf(frame, sizeof frame, "%s/set/%s", tmp, json_string_value(json_object_get(r, "file")));
                json_decref(r);
        }
        if (f)
                fclose(f);
        CHECK(frame[0] != 0);
        int pw = 0, ph = 0;
        snprintf(path, sizeof path, "%s/lp/%s", tmp, file0);
        uint16_t *png = read_png16(path, &pw, &ph);
        CHECK_MSG(png != NULL, "%s: not a 16-bit PNG libpng reads", path);
        TIFF *t = frame[0] ? TIFFOpen(frame, "r") : NULL;
        CHECK(t != NULL);
        if (png && t) {
                uint32_t tw = 0, th = 0;
                uint16_t spp = 0;
                TIFFGetField(t, TIFFTAG_IMAGEWIDTH, &tw);
                TIFFGetField(t, TIFFTAG_IMAGELENGTH, &th);
                TIFFGetField(t, TIFFTAG_SAMPLESPERPIXEL, &spp);
                CHECK_INT_EQ(spp, 3);   /* the simulated camera is RGB */
                CHECK_INT_EQ(pw, tw);
                CHECK_INT_EQ(ph, th);
                uint16_t *row = malloc(TIFFScanlineSize(t));
                size_t bad_px = 0, lit = 0;
                double scale = 65535.0 / (((1 << bits) - 1) - black);
                for (uint32_t y = 0; row && spp == 3 && y < th && (int) y < ph; y++) {
                        CHECK(TIFFReadScanline(t, row, y, 0) >= 0);
                        for (uint32_t x = 0; x < 3 * tw && (int) x < 3 * pw; x++) {
                                double want = fmin(fmax((row[x] - black) * scale, 0), 65535);
                                uint16_t got = png[(size_t) y * 3 * pw + x];
                                bad_px += fabs(got - want) > 1.0;
                                lit += got > 1000;
                        }
                }
                CHECK_INT_EQ(bad_px, 0);
                CHECK_INT_GE(lit, (size_t) 3 * pw * ph / 10);
                free(row);
        }
        if (t)
                TIFFClose(t);
        free(png);
        free(w);
        free(u);
        free(dist);
        /* without --capture: a usage error that says so */
        snprintf(cmd, sizeof cmd, "%s export %s/copy --to lp --out %s/lp2 2> %s/err.txt; test $? -eq 2 && grep -q -- --capture %s/err.txt",
                 IMPASTO, SMALL, tmp, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        return TEST_DONE();
}
