/* glTF 2.0 binary of the mesh with albedo and normal-map textures (export.h). Layout: one
 * buffer (the GLB's BIN chunk) with views for positions, normals, texture coordinates,
 * indices and the two PNG images; one mesh, one material, metres as glTF wants. */
#include <errno.h>
#include <float.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "export.h"
#include "json-util.h"

struct bin {
        uint8_t *data;
        size_t size, cap;
};

/* Appends n bytes at a 4-byte boundary; returns the offset or -1. */
static long bin_add(struct bin *b, const void *p, size_t n) {
        size_t off = (b->size + 3) & ~(size_t) 3;
        if (off + n > b->cap) {
                size_t cap = IMP_MAX(2 * b->cap, off + n + 1024);
                uint8_t *d = realloc(b->data, cap);
                if (!d)
                        return -1;
                b->data = d, b->cap = cap;
        }
        memset(b->data + b->size, 0, off - b->size);
        memcpy(b->data + off, p, n);
        b->size = off + n;
        return (long) off;
}

static json_t *view_json(long off, size_t n, int target) {
        json_t *v = json_pack("{s:i, s:I, s:I}", "buffer", 0, "byteOffset", (json_int_t) off, "byteLength", (json_int_t) n);
        if (target)
                json_object_set_new(v, "target", json_integer(target));
        return v;
}

static json_t *document(const struct imp_mesh *m, const long off[6], const size_t len[6], size_t bin_size,
                        const float lo[3], const float hi[3]) {
        json_t *views = json_array();
        static const int targets[6] = { 34962, 34962, 34962, 34963, 0, 0 };
        for (int i = 0; i < 6; i++)
                json_array_append_new(views, view_json(off[i], len[i], targets[i]));
        json_int_t nv = (json_int_t) m->n_vertices;
        return json_pack(
                "{s:{s:s, s:s}, s:i, s:[{s:[i]}], s:[{s:i, s:s}], "
                "s:[{s:[{s:{s:i, s:i, s:i}, s:i, s:i, s:i}]}], "
                "s:[{s:s, s:{s:{s:i}, s:f, s:f}, s:{s:i}, s:b}], s:[{s:i, s:i}, {s:i, s:i}], "
                "s:[{s:i, s:s}, {s:i, s:s}], s:[{s:i, s:i, s:i, s:i}], "
                "s:[{s:i, s:i, s:I, s:s, s:[fff], s:[fff]}, {s:i, s:i, s:I, s:s}, {s:i, s:i, s:I, s:s}, "
                "{s:i, s:i, s:I, s:s}], s:o, s:[{s:I}]}",
                "asset", "version", "2.0", "generator", "impasto export",
                "scene", 0, "scenes", "nodes", 0, "nodes", "mesh", 0, "name", "painting",
                "meshes", "primitives", "attributes", "POSITION", 0, "NORMAL", 1, "TEXCOORD_0", 2, "indices", 3,
                "material", 0, "mode", 4,
                "materials", "name", "paint", "pbrMetallicRoughness", "baseColorTexture", "index", 0, "metallicFactor", 0.0,
                "roughnessFactor", 0.8, "normalTexture", "index", 1, "doubleSided", false,
                "textures", "source", 0, "sampler", 0, "source", 1, "sampler", 0,
                "images", "bufferView", 4, "mimeType", "image/png", "bufferView", 5, "mimeType", "image/png",
                "samplers", "magFilter", 9729, "minFilter", 9729, "wrapS", 33071, "wrapT", 33071,
                "accessors", "bufferView", 0, "componentType", 5126, "count", nv, "type", "VEC3",
                "min", (double) lo[0], (double) lo[1], (double) lo[2], "max", (double) hi[0], (double) hi[1], (double) hi[2],
                "bufferView", 1, "componentType", 5126, "count", nv, "type", "VEC3",
                "bufferView", 2, "componentType", 5126, "count", nv, "type", "VEC2",
                "bufferView", 3, "componentType", 5125, "count", (json_int_t) (3 * m->n_triangles), "type", "SCALAR",
                "bufferViews", views, "buffers", "byteLength", (json_int_t) bin_size);
}

static int write_glb(const char *path, const char *js, const struct bin *b, struct imp_error *err) {
        size_t jn = strlen(js), jpad = (jn + 3) & ~(size_t) 3, bpad = (b->size + 3) & ~(size_t) 3;
        uint32_t total = (uint32_t) (12 + 8 + jpad + 8 + bpad);
        uint32_t head[3] = { 0x46546C67u, 2, total }, jh[2] = { (uint32_t) jpad, 0x4E4F534Au },
                 bh[2] = { (uint32_t) bpad, 0x004E4942u };
        FILE *f = fopen(path, "wbe");
        if (!f)
                return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        fwrite(head, 4, 3, f);
        fwrite(jh, 4, 2, f);
        fwrite(js, 1, jn, f);
        for (size_t i = jn; i < jpad; i++)
                fputc(' ', f);
        fwrite(bh, 4, 2, f);
        fwrite(b->data, 1, b->size, f);
        for (size_t i = b->size; i < bpad; i++)
                fputc(0, f);
        bool ok = !ferror(f);
        ok = (fclose(f) == 0) && ok;
        return ok ? 0 : imp_error_set(err, -EIO, "%s: write failed", path);
}

int imp_export_glb(const struct imp_mesh *m, const struct imp_copy *c, const char *path, struct imp_error *err) {
        char dir[4096];
        snprintf(dir, sizeof dir, "%s", path);
        char *slash = strrchr(dir, '/');
        if (slash)
                *slash = 0;
        else
                snprintf(dir, sizeof dir, ".");
        _cleanup_free_ uint8_t *alb = NULL, *nrm = NULL;
        size_t na, nn;
        int r = imp_export_maps(c, dir, &alb, &na, &nrm, &nn, err);
        if (r < 0)
                return r;
        size_t nv = m->n_vertices;
        _cleanup_free_ float *pos = malloc(sizeof(float) * 3 * (nv ? nv : 1));
        if (!pos)
                return imp_error_set(err, -ENOMEM, "out of memory");
        float lo[3] = { FLT_MAX, FLT_MAX, FLT_MAX }, hi[3] = { -FLT_MAX, -FLT_MAX, -FLT_MAX };
        for (size_t i = 0; i < 3 * nv; i++) {
                pos[i] = m->pos[i] * 1e-3f;   /* mm → m */
                lo[i % 3] = IMP_MIN(lo[i % 3], pos[i]);
                hi[i % 3] = IMP_MAX(hi[i % 3], pos[i]);
        }
        struct bin b = {};
        long off[6];
        size_t len[6] = { 12 * nv, 12 * nv, 8 * nv, 12 * m->n_triangles, na, nn };
        const void *src[6] = { pos, m->normal, m->uv, m->tri, alb, nrm };
        for (int i = 0; i < 6; i++)
                if ((off[i] = bin_add(&b, src[i], len[i])) < 0) {
                        free(b.data);
                        return imp_error_set(err, -ENOMEM, "out of memory");
                }
        _cleanup_json_ json_t *doc = document(m, off, len, (b.size + 3) & ~(size_t) 3, lo, hi);
        char *js = doc ? json_dumps(doc, JSON_COMPACT) : NULL;
        r = js ? write_glb(path, js, &b, err) : imp_error_set(err, -ENOMEM, "%s: cannot describe the glTF", path);
        free(js);
        free(b.data);
        return r;
}
