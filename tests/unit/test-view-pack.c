/* The viewer's conversion of a copy (pipeline/export/view-pack.h, copy-load.h) on the
 * synthetic copy of copy-synth.h: half floats round exactly where they must; every texel
 * of the four textures holds the copy's value within half precision (relative 2^-11, with
 * heights relative to the plane); off-mask texels sit on the plane with black paint; box
 * tops are the CPU renderer's; the cache returns the same bytes and refuses a truncated
 * blob; the cache key changes when a file of the copy changes; bad copies are named. */
#include <errno.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include "copy-load.h"
#include "copy-synth.h"
#include "test.h"
#include "view-pack.h"

#define HALF_REL 4.9e-4               /* 2^-11: half precision, relative */

static float texel(const struct imp_view_pack *p, int t, int i, int j, int c) {
        size_t n = (size_t) COPY_SYNTH_NX * COPY_SYNTH_NY, k = (size_t) j * COPY_SYNTH_NX + i;
        return imp_half_to_float(p->data[((size_t) t * n + k) * 4 + c]);
}

static void test_half(void) {
        static const float exact[] = { 0, 1, -2, 0.5f, 1024, 2047, 65504, 6.103515625e-05f, 5.9604645e-08f };
        for (size_t i = 0; i < ARRAY_SIZE(exact); i++)
                CHECK_NEAR(imp_half_to_float(imp_half_from_float(exact[i])), exact[i], 0);
        CHECK_INT_EQ(imp_half_from_float(1.0f), 0x3c00);
        CHECK_INT_EQ(imp_half_from_float(-2.0f), 0xc000);
        CHECK_INT_EQ(imp_half_from_float(1.0f + 1.0f / 2048), 0x3c00);       /* tie to even */
        CHECK_INT_EQ(imp_half_from_float(1.0f + 3.0f / 2048), 0x3c02);       /* tie to even, up */
        CHECK_INT_EQ(imp_half_from_float(1e6f), 0x7c00);                     /* overflow: inf */
        CHECK(isnan(imp_half_to_float(imp_half_from_float(NAN))));
        for (float x = 1e-3f; x < 6e4f; x *= 1.37f)
                CHECK_NEAR(imp_half_to_float(imp_half_from_float(x)), x, x * HALF_REL);
}

static void test_pack(const char *dir) {
        struct imp_error err = {};
        struct imp_copy c;
        CHECK_OK(imp_copy_load(dir, &c, &err));
        CHECK_INT_EQ(c.n_boxes, 2);
        CHECK(c.has_flags);
        CHECK(c.has_fit_flags);
        /* The texel flags from heightfield.exr, the fit's own from fit-flags.exr, each kept apart. */
        CHECK_INT_EQ(c.texel_flags[6 * COPY_SYNTH_NX + 5], copy_synth_flags(5, 6));
        CHECK_INT_EQ(c.fit_flags[3 * COPY_SYNTH_NX + 7], copy_synth_fit_flags(7, 3));
        CHECK_INT_EQ(c.texel_flags[3 * COPY_SYNTH_NX + 7], 0);
        CHECK_NEAR(c.plane_mm, COPY_SYNTH_HREF + COPY_SYNTH_DELTA0, 1e-12);
        struct imp_view_pack p;
        CHECK_OK(imp_view_pack_build(&c, &p, &err));
        CHECK_INT_EQ(p.size, (size_t) COPY_SYNTH_NX * COPY_SYNTH_NY * 16 * 2);
        size_t bad = 0;
        for (int j = 0; j < COPY_SYNTH_NY; j++)
                for (int i = 0; i < COPY_SYNTH_NX; i++) {
                        bool in = copy_synth_in(i, j);
                        double h = in ? copy_synth_height(i, j) - c.plane_mm : 0;
                        bad += fabs(texel(&p, 0, i, j, 0) - h) > fabs(h) * HALF_REL + 1e-7;
                        bad += texel(&p, 0, i, j, 3) != (in ? 1 : 0);
                        double sg = in ? copy_synth_sigma(i, j) : 0;
                        bad += fabs(texel(&p, 1, i, j, 3) - sg) > sg * HALF_REL;
                        bad += texel(&p, 2, i, j, 3) != copy_synth_flags(i, j);
                        bad += fabs(texel(&p, 3, i, j, 3) - copy_synth_k(i, j)) > copy_synth_k(i, j) * HALF_REL;
                        for (int q = 0; q < 3; q++) {
                                double d = in ? copy_synth_rho_d(i, j, q) : 0, s = in ? copy_synth_rho_s(i, j, q) : 0;
                                bad += fabs(texel(&p, 1, i, j, q) - d) > d * HALF_REL;
                                bad += fabs(texel(&p, 2, i, j, q) - s) > s * HALF_REL;
                        }
                }
        CHECK_INT_EQ(bad, 0);
        CHECK_STR_CONTAINS(p.meta, "\"nx\":40");
        /* box 2's top is the bump's peak (its highest texel), as relief-render.c computes it */
        _cleanup_json_ json_t *m = json_loads(p.meta, 0, NULL);
        CHECK(m != NULL);
        json_t *b1 = json_array_get(json_object_get(m, "boxes"), 1);
        CHECK_NEAR(json_real_value(json_array_get(b1, 7)), copy_synth_height(20, 15), 1e-6);
        CHECK_NEAR(json_real_value(json_object_get(m, "height_max_mm")), copy_synth_height(20, 15), 1e-6);

        /* the cache: same bytes back; a truncated blob refused */
        char cache[512], path[600], key[32], key2[32];
        snprintf(cache, sizeof cache, "%s/cache", test_tmpdir());
        CHECK_OK(imp_view_pack_key(dir, key, sizeof key, &err));
        CHECK_OK(imp_view_pack_cache_save(cache, key, &p, &err));
        struct imp_view_pack q;
        CHECK_OK(imp_view_pack_cache_load(cache, key, &q, &err));
        CHECK(q.size == p.size && q.data && !memcmp(q.data, p.data, p.size) && q.meta && !strcmp(q.meta, p.meta));
        imp_view_pack_done(&q);
        CHECK_ERR(imp_view_pack_cache_load(cache, "0000000000000000", &q, &err), -ENOENT);
        snprintf(path, sizeof path, "%s/%s.bin", cache, key);
        CHECK_OK(truncate(path, (off_t) p.size - 2));
        CHECK_ERR(imp_view_pack_cache_load(cache, key, &q, &err), -EBADMSG);
        /* touching a file of the copy changes the key */
        snprintf(path, sizeof path, "%s/rho_s.exr", dir);
        usleep(20000);
        FILE *f = fopen(path, "ab");
        CHECK(f != NULL);
        if (f)
                fclose(f);
        CHECK_OK(utimensat(AT_FDCWD, path, NULL, 0));
        CHECK_OK(imp_view_pack_key(dir, key2, sizeof key2, &err));
        CHECK(strcmp(key, key2) != 0);
        imp_view_pack_done(&p);
        imp_copy_done(&c);
}

static void test_reclassify(const char *dir) {
        struct imp_error err = {};
        struct imp_copy c;
        CHECK_OK(imp_copy_load(dir, &c, &err));
        double plane = c.plane_mm;
        CHECK_OK(imp_copy_reclassify(&c, 5, &err));
        /* 5-texel cells over the bump: more, smaller boxes, each with hmax above the plane */
        CHECK_GE(c.n_boxes, 3);
        for (size_t b = 0; b < c.n_boxes; b++) {
                CHECK_INT_EQ(c.boxes[b].w <= 5 && c.boxes[b].h <= 5, 1);
                CHECK_GE(c.boxes[b].hmax_mm, c.plane_mm);
        }
        CHECK_NEAR(c.plane_mm, plane, 0.05);
        imp_copy_done(&c);
}

static void test_bad(const char *tmp) {
        struct imp_error err = {};
        struct imp_copy c;
        char dir[512], path[600];
        snprintf(dir, sizeof dir, "%s/nothing-here", tmp);
        CHECK(imp_copy_load(dir, &c, &err) < 0);
        CHECK_STR_CONTAINS(err.msg, "nothing-here");
        imp_copy_done(&c);
        snprintf(dir, sizeof dir, "%s/bad", tmp);
        CHECK_OK(copy_synth_write(dir, &err));
        snprintf(path, sizeof path, "%s/boxes.json", dir);
        FILE *f = fopen(path, "w");
        if (f) {
                fputs("{\"h_ref\": 0, \"delta0\": 0.1, \"boxes\": [{\"u0\": 35, \"v0\": 0, \"w\": 10, \"h\": 4, "
                      "\"hmax\": 1, \"umax\": 0, \"vmax\": 0}]}", f);
                fclose(f);
        }
        imp_error_clear(&err);
        CHECK_ERR(imp_copy_load(dir, &c, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "boxes[0]");
        imp_copy_done(&c);
        snprintf(path, sizeof path, "%s/lobe.exr", dir);
        unlink(path);
        imp_error_clear(&err);
        CHECK(imp_copy_load(dir, &c, &err) < 0);
        imp_copy_done(&c);
}

int main(void) {
        const char *tmp = test_tmpdir();
        char dir[512];
        snprintf(dir, sizeof dir, "%s/copy", tmp);
        struct imp_error err = {};
        CHECK_OK(copy_synth_write(dir, &err));
        test_half();
        test_pack(dir);
        test_reclassify(dir);
        test_bad(tmp);
        return TEST_DONE();
}
