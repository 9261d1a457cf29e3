/* `impasto export` on the synthetic copy of copy-synth.h, each file read back by a reader
 * that shares no code with the writer: libtiff for the heightmap, assimp (what MeshLab and
 * most 3D tools use) for PLY and glTF. Checks values, not only that files exist:
 *  - height.tif: 40×30 float32, resolution tags giving the pitch (relative 1e-6), every
 *    texel's height exact to float precision (1e-6 mm), NaN off the mask;
 *  - mesh.ply / mesh.glb: within the triangle budget, at the smallest sub-grid step that
 *    fits; every vertex on a texel with the copy's height within that texel's σ (in fact
 *    1e-5 mm), a unit normal agreeing with the copy's to 1e-3, the albedo colour within
 *    one 8-bit step (PLY); glTF in metres with both textures embedded as PNG;
 *  - a missing copy exits 3 naming it; an unknown format exits 2. */
#include <assimp/cimport.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <tiffio.h>
#include "copy-synth.h"
#include "test.h"

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

        snprintf(cmd, sizeof cmd, "%s export %s/missing --to ply --out %s 2> %s/err.txt", IMPASTO, tmp, out, tmp);
        CHECK_INT_EQ(run(cmd), 3);
        snprintf(cmd, sizeof cmd, "grep -q 'missing' %s/err.txt", tmp);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(cmd, sizeof cmd, "%s export %s --to obj --out %s 2> /dev/null", IMPASTO, copy, out);
        CHECK_INT_EQ(run(cmd), 2);
        return TEST_DONE();
}
