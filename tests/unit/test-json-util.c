/* JSON helpers: typed getters name the document and key; load names file:line:column;
 * atomic writes leave no .tmp and replace the old content; mkdir -p. */
#include <errno.h>
#include <sys/stat.h>
#include <unistd.h>
#include "json-util.h"
#include "test.h"

static void test_getters(void) {
        _cleanup_json_ json_t *j = json_pack("{s:f, s:i, s:s, s:[f,i,f], s:n, s:[i,s]}", "exposure_us",
                                             1250.5, "seq", 17, "camera", "cam0", "pos_mm", 1.0, 2,
                                             3.0, "gone", "bad", 1, "x");
        struct imp_error e = {};
        double d = 0, v[3] = {};
        long long i = 0;
        const char *s = NULL;
        CHECK_OK(imp_json_get_double(j, "exposure_us", true, &d, "manifest.jsonl:17", &e));
        CHECK_NEAR(d, 1250.5, 0);
        CHECK_OK(imp_json_get_double(j, "seq", true, &d, "m", &e));   /* integer as number */
        CHECK_NEAR(d, 17, 0);
        CHECK_OK(imp_json_get_int(j, "seq", true, &i, "m", &e));
        CHECK_INT_EQ(i, 17);
        CHECK_OK(imp_json_get_string(j, "camera", true, &s, "m", &e));
        CHECK_STR_EQ(s, "cam0");
        CHECK_OK(imp_json_get_doubles(j, "pos_mm", true, 3, v, "m", &e));
        CHECK_NEAR(v[1], 2, 0);

        /* optional: absent or null leaves *ret untouched */
        d = 5;
        CHECK_ERR(imp_json_get_double(j, "missing", false, &d, "m", &e), 0);
        CHECK_ERR(imp_json_get_double(j, "gone", false, &d, "m", &e), 0);
        CHECK_NEAR(d, 5, 0);

        CHECK_ERR(imp_json_get_double(j, "camera", true, &d, "manifest.jsonl:17", &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "manifest.jsonl:17: camera: expected a number, got a string");
        CHECK_ERR(imp_json_get_int(j, "exposure_us", true, &i, "m", &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "m: exposure_us: expected an integer, got a number");
        CHECK_ERR(imp_json_get_string(j, "gone", true, &s, "rig.json", &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "rig.json: gone: expected a string, got null");
        CHECK_ERR(imp_json_get_double(j, "gain_db", true, &d, "manifest.jsonl:3", &e), -ENOENT);
        CHECK_STR_EQ(e.msg, "manifest.jsonl:3: gain_db: missing (required)");
        CHECK_ERR(imp_json_get_doubles(j, "pos_mm", true, 2, v, "m", &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "m: pos_mm: expected 2 numbers, got 3");
        CHECK_ERR(imp_json_get_doubles(j, "bad", true, 2, v, "m", &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "m: bad[1]: expected a number, got a string");
        CHECK_NEAR(v[0], 1, 0);   /* untouched by the failed call */
        /* a prefix ending in '.' is a path */
        CHECK_ERR(imp_json_get_int(j, "camera", true, &i, "rig.json: cameras[0].sensor.", &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "rig.json: cameras[0].sensor.camera: expected an integer, got a string");
        CHECK_INT_EQ(i, 17);
        _cleanup_json_ json_t *arr = json_array();
        CHECK_ERR(imp_json_get_int(arr, "x", true, &i, "doc", &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "doc: expected an object");
}

static void test_files(void) {
        char dir[512], path[600], tmp[640];
        struct imp_error e = {};
        snprintf(dir, sizeof dir, "%s/a/b/c", test_tmpdir());
        CHECK_OK(imp_mkdir_p(dir, 0755));
        CHECK_OK(imp_mkdir_p(dir, 0755));   /* existing is fine */
        struct stat st;
        CHECK(stat(dir, &st) == 0 && S_ISDIR(st.st_mode));

        snprintf(path, sizeof path, "%s/doc.json", dir);
        snprintf(tmp, sizeof tmp, "%s.tmp", path);
        _cleanup_json_ json_t *j = json_pack("{s:f, s:s}", "x", 0.1, "name", "ü");
        CHECK_OK(imp_json_save_atomic(path, j, &e));
        CHECK(access(tmp, F_OK) < 0);
        _cleanup_json_ json_t *back = NULL;
        CHECK_OK(imp_json_load(path, &back, &e));
        CHECK(back && json_equal(j, back));   /* reals round-trip exactly */

        /* replacing: the old content is gone, still no .tmp */
        CHECK_OK(imp_file_write_atomic(path, "[1]\n", 4, &e));
        CHECK(access(tmp, F_OK) < 0);
        CHECK(stat(path, &st) == 0 && st.st_size == 4);

        /* a file under a regular file cannot be made */
        char bad[700];
        snprintf(bad, sizeof bad, "%s/x/y", path);
        CHECK_ERR(imp_mkdir_p(bad, 0755), -ENOTDIR);
        snprintf(bad, sizeof bad, "%s/nodir/f.json", dir);
        CHECK_ERR(imp_file_write_atomic(bad, "x", 1, &e), -ENOENT);
        CHECK_STR_CONTAINS(e.msg, "nodir/f.json.tmp");

        /* parse errors: file:line:column */
        snprintf(path, sizeof path, "%s/broken.json", dir);
        CHECK_OK(imp_file_write_atomic(path, "{\n  \"a\": 1,\n  \"b\": ]\n}\n", 21, &e));
        json_t *none = NULL;
        CHECK_ERR(imp_json_load(path, &none, &e), -EINVAL);
        char want[700];
        snprintf(want, sizeof want, "%s:3:", path);
        CHECK_STR_CONTAINS(e.msg, want);
        CHECK(none == NULL);
        CHECK_OK(imp_file_write_atomic(path, "{\"a\": 1, \"a\": 2}", 16, &e));
        CHECK_ERR(imp_json_load(path, &none, &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "duplicate");
        snprintf(path, sizeof path, "%s/absent.json", dir);
        CHECK_ERR(imp_json_load(path, &none, &e), -ENOENT);
        CHECK_STR_CONTAINS(e.msg, "absent.json");
}

/* imp_utf8_sanitize: whole valid characters kept, every other byte '?', and jansson takes
 * the result. */
static void test_utf8(void) {
        static const struct {
                const char *in, *out;
                size_t replaced;
        } c[] = {
                { "abc", "abc", 0 },
                { "n\xc3\xa9" "e \xe2\x82\xac \xf0\x9f\x8e\xa8", "n\xc3\xa9" "e \xe2\x82\xac \xf0\x9f\x8e\xa8", 0 },
                { "cut \xc3", "cut ?", 1 },                         /* snprintf's cut inside é */
                { "cut \xe2\x82", "cut ??", 2 },
                { "latin-1 caf\xe9!", "latin-1 caf?!", 1 },
                { "\xc0\x80", "??", 2 },                             /* overlong NUL */
                { "\xed\xa0\x80", "???", 3 },                         /* a surrogate */
                { "\xf4\x90\x80\x80", "????", 4 },                   /* past U+10FFFF */
                { "\x80x", "?x", 1 },                                 /* a lone continuation byte */
        };
        for (size_t i = 0; i < sizeof c / sizeof c[0]; i++) {
                char buf[64];
                snprintf(buf, sizeof buf, "%s", c[i].in);
                CHECK_INT_EQ(imp_utf8_sanitize(buf), c[i].replaced);
                CHECK_STR_EQ(buf, c[i].out);
                json_t *j = json_string(buf);
                CHECK_MSG(j != NULL, "case %zu: jansson refuses the result", i);
                json_decref(j);
        }
}

int main(void) {
        test_getters();
        test_files();
        test_utf8();
        return TEST_DONE();
}
