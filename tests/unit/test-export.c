/* `impasto export` on the synthetic copy of copy-synth.h, each file read back by a reader
 * that shares no code with the writer: libtiff for the heightmap, assimp (what MeshLab and
 * most 3D tools use) for PLY and glTF. Checks values, not only that files exist:
 *  - height.tif: 40×30 float32, resolution tags giving the pitch (relative 1e-6), every
 *    texel's height exact to float precision (1e-6 mm), NaN off the mask;
 *  - mesh.ply / mesh.glb: within the triangle budget, at the smallest sub-grid step that
 *    fits; every vertex on a texel with the copy's height within that texel's σ (in fact
 *    1e-5 mm), a unit normal agreeing with the copy's to 1e-3, the albedo colour within
 *    one 8-bit step (PLY); glTF in metres with both textures embedded as PNG;
 *  - openlime: the Ward refit's reported error agrees with the residual recomputed here
 *    from its ks and α (within 0.02), a sharper lobe refits to a higher gloss; the deepzoom
 *    tiles read back by libvips hold the kd map (sRGB ρd within one 8-bit step), the
 *    gloss map rises with the lobe exponent, the error map is finite on the mask;
 *  - a missing copy exits 3 naming it; an unknown format exits 2. */
#include <assimp/cimport.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <tiffio.h>
#include "copy-synth.h"
#include "export.h"
#include "json-util.h"
#include "test.h"
#ifdef IMPASTO_HAVE_VIPS
#include <vips/vips.h>
#endif

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define BUDGET 500

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static double srgb(double v) {
        v = v < 0 ? 0 : v > 1 ? 1 : v;
        return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
}

static void check_tiff(const char *path) {
        TIFF *t = TIFFOpen(path, "r");
        CHECK(t != NULL);
        if (!t)
                return;
        uint32_t w = 0, h = 0;
        uint16_t bps = 0, fmt = 0, spp = 0, unit = 0;
        float xr = 0, yr = 0;
        TIFFGetField(t, TIFFTAG_IMAGEWIDTH, &w);
        TIFFGetField(t, TIFFTAG_IMAGELENGTH, &h);
        TIFFGetField(t, TIFFTAG_BITSPERSAMPLE, &bps);
        TIFFGetField(t, TIFFTAG_SAMPLEFORMAT, &fmt);
        TIFFGetField(t, TIFFTAG_SAMPLESPERPIXEL, &spp);
        TIFFGetField(t, TIFFTAG_RESOLUTIONUNIT, &unit);
        TIFFGetField(t, TIFFTAG_XRESOLUTION, &xr);
        TIFFGetField(t, TIFFTAG_YRESOLUTION, &yr);
        CHECK_INT_EQ(w, COPY_SYNTH_NX);
        CHECK_INT_EQ(h, COPY_SYNTH_NY);
        CHECK_INT_EQ(bps, 32);
        CHECK_INT_EQ(fmt, SAMPLEFORMAT_IEEEFP);
        CHECK_INT_EQ(spp, 1);
        CHECK_INT_EQ(unit, RESUNIT_CENTIMETER);
        CHECK_NEAR(10.0 / xr, COPY_SYNTH_PITCH, COPY_SYNTH_PITCH * 1e-6);   /* mm per pixel */
        CHECK_NEAR(10.0 / yr, COPY_SYNTH_PITCH, COPY_SYNTH_PITCH * 1e-6);
        float row[COPY_SYNTH_NX];
        size_t bad = 0, nan_in = 0;
        for (uint32_t j = 0; j < h && w == COPY_SYNTH_NX; j++) {
                CHECK(TIFFReadScanline(t, row, j, 0) >= 0);
                for (int i = 0; i < COPY_SYNTH_NX; i++) {
                        if (!copy_synth_in(i, (int) j))
                                bad += !isnan(row[i]);
                        else if (isnan(row[i]))
                                nan_in++;
                        else
                                bad += fabs(row[i] - copy_synth_height(i, (int) j)) > 1e-6;
                }
        }
        CHECK_INT_EQ(bad, 0);
        CHECK_INT_EQ(nan_in, 0);
        TIFFClose(t);
}

/* Every vertex: on a texel, the copy's height within σ, the copy's normal; returns the
 * grid step (the smallest spacing between distinct vertex x). */
static int check_vertices(const struct aiMesh *m, double scale, bool colours) {
        size_t bad_pos = 0, bad_h = 0, bad_n = 0, bad_c = 0;
        for (unsigned v = 0; v < m->mNumVertices; v++) {
                double x = m->mVertices[v].x * scale, y = m->mVertices[v].y * scale, z = m->mVertices[v].z * scale;
                double fi = x / COPY_SYNTH_PITCH, fj = y / COPY_SYNTH_PITCH;
                int i = (int) lround(fi), j = (int) lround(fj);
                if (fabs(fi - i) > 1e-3 || fabs(fj - j) > 1e-3 || !copy_synth_in(i, j)) {
                        bad_pos++;
                        continue;
                }
                bad_h += !(fabs(z - copy_synth_height(i, j)) <= fmin(copy_synth_sigma(i, j), 1e-5));
                double gx = (copy_synth_height(i + 1, j) - copy_synth_height(i - 1, j)) / (2 * COPY_SYNTH_PITCH);
                double gy = (copy_synth_height(i, j + 1) - copy_synth_height(i, j - 1)) / (2 * COPY_SYNTH_PITCH);
                double nn = sqrt(1 + gx * gx + gy * gy);
                const struct aiVector3D *N = &m->mNormals[v];
                bad_n += fabs(N->x + gx / nn) > 1e-3 || fabs(N->y + gy / nn) > 1e-3 || fabs(N->z - 1 / nn) > 1e-3;
                if (colours && m->mColors[0])
                        for (int q = 0; q < 3; q++) {
                                double want = srgb(copy_synth_rho_d(i, j, q));
                                double got = q == 0 ? m->mColors[0][v].r : q == 1 ? m->mColors[0][v].g : m->mColors[0][v].b;
                                bad_c += fabs(got - want) > 1.0 / 255 + 1e-6;
                        }
        }
        CHECK_INT_EQ(bad_pos, 0);
        CHECK_INT_EQ(bad_h, 0);
        CHECK_INT_EQ(bad_n, 0);
        CHECK_INT_EQ(bad_c, 0);
        if (colours)
                CHECK(m->mColors[0] != NULL);
        /* the step: the smallest positive x among vertices beyond texel 1 */
        double xmin = INFINITY, x2 = INFINITY;
        for (unsigned v = 0; v < m->mNumVertices; v++)
                xmin = fmin(xmin, m->mVertices[v].x * scale);
        for (unsigned v = 0; v < m->mNumVertices; v++) {
                double x = m->mVertices[v].x * scale;
                if (x > xmin + 1e-6)
                        x2 = fmin(x2, x);
        }
        return (int) lround((x2 - xmin) / COPY_SYNTH_PITCH);
}

static void check_mesh(const char *path, double scale, bool colours) {
        const struct aiScene *s = aiImportFile(path, 0);
        CHECK_MSG(s != NULL, "assimp cannot read %s: %s", path, aiGetErrorString());
        if (!s)
                return;
        CHECK_INT_EQ(s->mNumMeshes, 1);
        const struct aiMesh *m = s->mMeshes[0];
        CHECK(m->mNormals != NULL);
        CHECK_INT_GE(m->mNumFaces, 100);
        CHECK_LE(m->mNumFaces, BUDGET);
        for (unsigned f = 0; f < m->mNumFaces; f++)
                if (m->mFaces[f].mNumIndices != 3)
                        CHECK_INT_EQ(m->mFaces[f].mNumIndices, 3);
        /* 38×28 texels on the mask: step 1 gives 2·37·27 = 1998 triangles, step 2 gives 2·18·13
         * = 468 <= 500 (vertices on texels 1, 3, …, 37, 38 and 1, 3, …, 27, 28) */
        if (m->mNormals) {
                int step = check_vertices(m, scale, colours);
                CHECK_INT_EQ(step, 2);
        }
        if (!colours) {   /* glTF: both textures embedded as PNG */
                CHECK_INT_EQ(s->mNumTextures, 2);
                for (unsigned t = 0; t < s->mNumTextures; t++) {
                        const struct aiTexture *x = s->mTextures[t];
                        CHECK(x->mHeight == 0 && x->mWidth > 8 && !memcmp(x->pcData, "\x89PNG", 4));
                }
                const struct aiMaterial *mat = s->mMaterials[m->mMaterialIndex];
                CHECK_INT_EQ(aiGetMaterialTextureCount(mat, aiTextureType_NORMALS), 1);
                CHECK_INT_GE(aiGetMaterialTextureCount(mat, aiTextureType_DIFFUSE) +
                             aiGetMaterialTextureCount(mat, aiTextureType_BASE_COLOR), 1);
        }
        aiReleaseImport(s);
}

/* The refit's claimed error against the residual of its own ks, α (Ward written here). */
static void check_ward(void) {
        double prev_gloss = -1;
        for (double k = 5; k <= 80; k *= 2) {
                struct imp_lafortune b = { .rho_d = { 0.5, 0.5, 0.5 }, .rho_s = { 0.3, 0.2, 0.1 }, .cx = -1, .cy = -1,
                                           .cz = 1, .k = (float) k };
                struct imp_ward_fit w;
                imp_ward_refit(&b, &w);
                double num = 0, den = 0, a = imp_ward_alpha(w.gloss);
                for (int t = 0; t <= 85; t++) {
                        double th = t * M_PI / 180, c = cos(th), wt = sin(th) + 1e-3, h = tan(th / 2);
                        double ward = w.ks[0] * exp(-h * h / (a * a)) / (4 * M_PI * a * a * sqrt(c)) * c;
                        double laf = b.rho_s[0] * pow(c, k) / M_PI * c;
                        num += wt * (ward - laf) * (ward - laf);
                        den += wt * laf * laf;
                }
                CHECK_NEAR(sqrt(num / den), w.rel_error, 0.02);
                CHECK_LE(w.rel_error, 0.5);
                CHECK_NEAR(w.ks[1] / w.ks[0], 0.2 / 0.3, 1e-5);   /* ρs only scales ks */
                CHECK_GE(w.gloss, prev_gloss + 1e-6);             /* sharper lobe, glossier */
                prev_gloss = w.gloss;
        }
}

#ifdef IMPASTO_HAVE_VIPS
/* Pixel (x, y) band b of a tile, through libvips. */
static int tile_px(VipsImage *im, int x, int y, int b) {
        double *v = NULL;
        int n = 0;
        if (vips_getpoint(im, &v, &n, x, y, NULL) || b >= n) {
                g_free(v);
                return -1;
        }
        int r = (int) v[b];
        g_free(v);
        return r;
}

static void check_openlime(const char *copy, const char *out) {
        char cmd[2048], path[1024];
        snprintf(cmd, sizeof cmd, "%s export %s --to openlime --out %s/ol", IMPASTO, copy, out);
        CHECK_INT_EQ(run(cmd), 0);
        struct imp_error err = {};
        _cleanup_json_ json_t *j = NULL;
        snprintf(path, sizeof path, "%s/ol/openlime.json", out);
        CHECK_OK(imp_json_load(path, &j, &err));
        CHECK_STR_EQ(json_string_value(json_object_get(json_object_get(j, "channels"), "gloss")), "gloss.dzi");
        CHECK_INT_EQ(json_integer_value(json_object_get(j, "width")), COPY_SYNTH_NX);
        if (VIPS_INIT("test-export"))
                return;
        /* 40 texels wide: the full-resolution level is 6 (2^6 >= 40), one 256-pixel tile */
        snprintf(path, sizeof path, "%s/ol/kd_files/6/0_0.png", out);
        VipsImage *kd = vips_image_new_from_file(path, NULL);
        snprintf(path, sizeof path, "%s/ol/gloss_files/6/0_0.png", out);
        VipsImage *gl = vips_image_new_from_file(path, NULL);
        CHECK_MSG(kd && gl, "libvips cannot read the level-6 tiles: %s", vips_error_buffer());
        if (kd && gl) {
                CHECK_INT_EQ(vips_image_get_width(kd), COPY_SYNTH_NX);
                CHECK_INT_EQ(vips_image_get_height(kd), COPY_SYNTH_NY);
                size_t bad = 0;
                for (int y = 1; y < COPY_SYNTH_NY - 1; y++)
                        for (int x = 1; x < COPY_SYNTH_NX - 1; x++)
                                for (int c = 0; c < 3; c++)
                                        bad += abs(tile_px(kd, x, y, c) - (int) lround(255 * srgb(copy_synth_rho_d(x, y, c)))) > 1;
                CHECK_INT_EQ(bad, 0);
                CHECK_GE(tile_px(gl, 30, 15, 0), tile_px(gl, 5, 15, 0) + 1);   /* k 40 vs 15 */
        }
        if (kd)
                g_object_unref(kd);
        if (gl)
                g_object_unref(gl);
        snprintf(path, sizeof path, "%s/ol/refit-error.tif", out);
        TIFF *t = TIFFOpen(path, "r");
        CHECK(t != NULL);
        size_t bad_e = 0;
        float row[COPY_SYNTH_NX];
        for (int y = 0; t && y < COPY_SYNTH_NY; y++) {
                CHECK(TIFFReadScanline(t, row, (uint32_t) y, 0) >= 0);
                for (int x = 0; x < COPY_SYNTH_NX; x++)
                        bad_e += copy_synth_in(x, y) ? !(row[x] >= 0 && row[x] <= 0.5) : !isnan(row[x]);
        }
        CHECK_INT_EQ(bad_e, 0);
        if (t)
                TIFFClose(t);
}
#endif

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char copy[512], out[512], cmd[2048], path[1024];
        snprintf(copy, sizeof copy, "%s/copy", tmp);
        snprintf(out, sizeof out, "%s/out", tmp);
        struct imp_error err = {};
        CHECK_OK(copy_synth_write(copy, &err));

        snprintf(cmd, sizeof cmd, "%s export %s --to tiff-height --out %s", IMPASTO, copy, out);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(path, sizeof path, "%s/height.tif", out);
        check_tiff(path);

        snprintf(cmd, sizeof cmd, "%s export %s --to ply --out %s --triangles %d", IMPASTO, copy, out, BUDGET);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(path, sizeof path, "%s/mesh.ply", out);
        check_mesh(path, 1.0, true);

        snprintf(cmd, sizeof cmd, "%s export %s --to glb --out %s --triangles %d", IMPASTO, copy, out, BUDGET);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(path, sizeof path, "%s/mesh.glb", out);
        check_mesh(path, 1000.0, false);   /* glTF is in metres */

        check_ward();
#ifdef IMPASTO_HAVE_VIPS
        check_openlime(copy, out);
#else
        fprintf(stderr, "openlime: not checked (built without libvips)\n");
#endif

        snprintf(cmd, sizeof cmd, "%s export %s/missing --to ply --out %s 2> %s/err.txt", IMPASTO, tmp, out, tmp);
        CHECK_INT_EQ(run(cmd), 3);
        snprintf(cmd, sizeof cmd, "grep -q 'missing' %s/err.txt", tmp);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(cmd, sizeof cmd, "%s export %s --to obj --out %s 2> /dev/null", IMPASTO, copy, out);
        CHECK_INT_EQ(run(cmd), 2);
        return TEST_DONE();
}
