/* Capture sets: the on-disk layout, record and pattern JSON, frames with their metadata
 * and checksums, and what open() repairs (torn last line, strays, .tmp) or refuses
 * (damaged middle line, missing or resized frame, checksum mismatch on load). */
#include <errno.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include "captureset.h"
#include "json-util.h"
#include "test.h"

#define W 64
#define H 48

static struct imp_rig small_rig(void) {
        struct imp_rig rig = { .n_cameras = 1, .settle_us = 500 };
        snprintf(rig.cameras[0].name, sizeof rig.cameras[0].name, "cam0");
        struct imp_pinhole *m = &rig.cameras[0].model;
        *m = (struct imp_pinhole){ .width = W, .height = H, .fx = 80, .fy = 80, .cx = 32, .cy = 24 };
        imp_pinhole_look_at(m, (double[]){ 0, 0, 500 }, (double[]){ 0, 0, 0 }, (double[]){ 1, 0, 0 });
        rig.cameras[0].sensor = (struct imp_sensor){ .bits = 12, .gain_e_per_dn = 1,
                                                     .full_well_e = 4000, .quantum_scale = 1 };
        rig.n_lights = 1;
        rig.lights = calloc(1, sizeof *rig.lights);
        rig.lights[0] = (struct imp_rig_light){ .id = 7, .pos_mm = { 0, 300, 300 }, .intensity = 1,
                                                .colour = { 1, 1, 1 }, .axis = { 0, 0, -1 } };
        return rig;
}

static struct imp_image *make_frame(int seed) {
        struct imp_image *img = NULL;
        if (imp_image_new(W, H, 1, IMP_PIX_U16, &img) < 0)
                abort();
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        *imp_image_u16(img, x, y) = (uint16_t) (seed * 977 + x * 31 + y * 1013);
        return img;
}

static struct imp_frame_record make_record(long long seq, int kind) {
        struct imp_frame_record r = { .seq = seq, .tile = 0, .light = -1, .exposure_us = 1250.5,
                                      .gain_db = 1.5, .t_light_on_ns = 1000 + seq,
                                      .t_trigger_ns = 2000 + seq, .t_frame_ns = 3000 + seq };
        snprintf(r.step, sizeof r.step, "structured-light");
        snprintf(r.camera, sizeof r.camera, "cam0");
        r.exposure_index = (int) (seq % 3);
        switch (kind % 5) {
        case 0: r.pattern = (struct imp_pattern){ .kind = IMP_PAT_GRAY, .axis = 0, .bit = 3, .nbits = 10 }; break;
        case 1: r.pattern = (struct imp_pattern){ .kind = IMP_PAT_PHASE, .axis = 1, .period_px = 16,
                                                  .step = 2, .steps = 4 }; break;
        case 2: r.pattern.kind = IMP_PAT_WHITE; break;
        case 3: r.pattern.kind = IMP_PAT_BLACK; break;
        default: r.pattern.kind = IMP_PAT_NONE; r.light = 7; snprintf(r.step, sizeof r.step, "dome");
        }
        return r;
}

static char *pathf(const char *fmt, ...) _printf_(1, 2);
static char *pathf(const char *fmt, ...) {
        static char bufs[8][1024];
        static int k;
        char *b = bufs[k++ % 8];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(b, 1024, fmt, ap);
        va_end(ap);
        return b;
}

/* A path that outlives the next pathf() calls. */
#define LOCAL_PATH(name, ...) char name[1024]; snprintf(name, sizeof name, __VA_ARGS__)

static bool exists(const char *p) { return access(p, F_OK) == 0; }

static long long file_size(const char *p) {
        struct stat st;
        return stat(p, &st) == 0 ? (long long) st.st_size : -1;
}

static void write_file(const char *p, const char *text, int flags) {
        int fd = open(p, O_WRONLY | O_CREAT | flags, 0644);
        if (fd < 0 || write(fd, text, strlen(text)) != (ssize_t) strlen(text))
                abort();
        close(fd);
}

static bool records_equal(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        _cleanup_json_ json_t *ja = imp_frame_record_to_json(a), *jb = imp_frame_record_to_json(b);
        return json_equal(ja, jb);
}

static void test_pattern_json(void) {
        struct imp_frame_record r = make_record(5, 0);
        _cleanup_json_ json_t *j = imp_frame_record_to_json(&r);
        _cleanup_json_ json_t *want = json_pack("{s:s, s:s, s:i, s:i, s:b}", "kind", "gray", "axis", "x",
                                                "bit", 3, "nbits", 10, "inverse", 0);
        CHECK(json_equal(json_object_get(j, "pattern"), want));
        r = make_record(5, 1);
        json_decref(j);
        j = imp_frame_record_to_json(&r);
        json_decref(want);
        want = json_pack("{s:s, s:s, s:f, s:i, s:i}", "kind", "phase", "axis", "y", "period_px", 16.0,
                         "step", 2, "steps", 4);
        CHECK(json_equal(json_object_get(j, "pattern"), want));
        r = make_record(5, 4);
        json_decref(j);
        j = imp_frame_record_to_json(&r);
        CHECK(json_is_null(json_object_get(j, "pattern")));
        /* keys are the struct's field names */
        static const char *const keys[] = { "seq", "step", "camera", "tile", "pattern", "light",
                                            "exposure_index", "exposure_us", "gain_db",
                                            "t_light_on_ns", "t_trigger_ns", "t_frame_ns", "file",
                                            "crc32", NULL };
        for (int i = 0; keys[i]; i++)
                CHECK_MSG(json_object_get(j, keys[i]), "record JSON has %s", keys[i]);
        CHECK_INT_EQ(json_object_size(j), 14);

        /* round trips, and errors naming the field */
        struct imp_error e = {};
        for (int k = 0; k < 5; k++) {
                struct imp_frame_record a = make_record(k, k), b;
                _cleanup_json_ json_t *ja = imp_frame_record_to_json(&a);
                CHECK_OK(imp_frame_record_from_json(ja, "m", &b, &e));
                CHECK(records_equal(&a, &b));
                CHECK_INT_EQ(b.pattern.kind, a.pattern.kind);
        }
        r = make_record(1, 0);
        struct imp_frame_record untouched = { .seq = 42 };
        json_decref(j);
        j = imp_frame_record_to_json(&r);
        json_object_set_new(json_object_get(j, "pattern"), "bit", json_integer(10));
        CHECK_ERR(imp_frame_record_from_json(j, "manifest.jsonl:17", &untouched, &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:17: pattern.bit: expected an integer in [0, 9], got 10");
        json_object_set_new(json_object_get(j, "pattern"), "kind", json_string("grey"));
        CHECK_ERR(imp_frame_record_from_json(j, "manifest.jsonl:17", &untouched, &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:17: pattern.kind: expected \"gray\"");
        json_object_set_new(j, "pattern", json_null());
        json_object_set_new(j, "exposure_us", json_string("1 ms"));
        CHECK_ERR(imp_frame_record_from_json(j, "manifest.jsonl:17", &untouched, &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "manifest.jsonl:17: exposure_us: expected a number, got a string");
        json_object_del(j, "camera");
        CHECK_ERR(imp_frame_record_from_json(j, "manifest.jsonl:17", &untouched, &e), -ENOENT);
        CHECK_STR_EQ(e.msg, "manifest.jsonl:17: camera: missing (required)");
        CHECK_INT_EQ(untouched.seq, 42);
}

static const char *new_set(const char *name, struct imp_captureset **ret) {
        static char dirs[8][512];
        static int k;
        char *dir = dirs[k++ % 8];
        snprintf(dir, sizeof dirs[0], "%s/%s", test_tmpdir(), name);
        *ret = NULL;
        struct imp_rig rig = small_rig();
        struct imp_error e = {};
        const char *plan = pathf("%s/plan-%s.cfg", test_tmpdir(), name);
        write_file(plan, "# plan\nsteps = ( \"structured-light\" );\n", O_TRUNC);
        CHECK_OK(imp_captureset_create(dir, &rig, plan, ret, &e));
        imp_rig_free(&rig);
        return dir;
}

static void add_frames(struct imp_captureset *cs, int n) {
        struct imp_error e = {};
        for (int i = 0; i < n; i++) {
                size_t seq = imp_captureset_count(cs);
                _cleanup_image_ struct imp_image *img = make_frame((int) seq);
                struct imp_frame_record r = make_record((long long) seq, (int) seq);
                CHECK_OK(imp_captureset_add_frame(cs, &r, img, &e));
                CHECK_STR_EQ(r.file, pathf("frames/%06zu.tiff", seq));
        }
}

static void test_layout(void) {
        struct imp_captureset *cs = NULL;
        struct imp_error e = {};
        const char *dir = new_set("layout", &cs);
        if (!cs)
                return;
        for (const char *const *f = (const char *const[]){ "set.json", "rig.json", "plan.cfg", "frames",
                                                           "manifest.jsonl", "session.log", NULL };
             *f; f++)
                CHECK_MSG(exists(pathf("%s/%s", dir, *f)), "%s exists", *f);
        _cleanup_json_ json_t *set = NULL;
        CHECK_OK(imp_json_load(pathf("%s/set.json", dir), &set, &e));
        CHECK_STR_EQ(json_string_value(json_object_get(set, "format")), "impasto-capture-set");
        CHECK_INT_EQ(json_integer_value(json_object_get(set, "version")), 1);
        CHECK(json_is_string(json_object_get(set, "created")));
        CHECK_INT_EQ(file_size(pathf("%s/plan.cfg", dir)),
                     file_size(pathf("%s/plan-layout.cfg", test_tmpdir())));
        CHECK_STR_EQ(imp_captureset_dir(cs), dir);
        CHECK_INT_EQ(imp_captureset_rig(cs)->n_lights, 1);
        CHECK_INT_EQ(imp_captureset_rig(cs)->lights[0].id, 7);

        /* a non-empty directory is refused */
        struct imp_rig rig = small_rig();
        struct imp_captureset *other = NULL;
        CHECK_ERR(imp_captureset_create(dir, &rig, NULL, &other, &e), -EEXIST);
        CHECK_STR_CONTAINS(e.msg, "not empty");
        /* an existing empty one is fine, and the plan is optional */
        const char *empty = pathf("%s/empty", test_tmpdir());
        CHECK_OK(imp_mkdir_p(empty, 0755));
        CHECK_OK(imp_captureset_create(empty, &rig, NULL, &other, &e));
        CHECK(!exists(pathf("%s/plan.cfg", empty)));
        imp_captureset_close(other);
        imp_rig_free(&rig);

        add_frames(cs, 5);
        CHECK_INT_EQ(imp_captureset_count(cs), 5);
        /* u8 frames are not raw frames */
        struct imp_image *u8 = NULL;
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U8, &u8));
        struct imp_frame_record r = make_record(9, 0);
        CHECK_ERR(imp_captureset_add_frame(cs, &r, u8, &e), -EINVAL);
        imp_image_free(u8);
        CHECK_INT_EQ(imp_captureset_count(cs), 5);
        struct imp_frame_record saved[5];
        for (size_t i = 0; i < 5; i++)
                saved[i] = *imp_captureset_record(cs, i);
        CHECK(imp_captureset_record(cs, 5) == NULL);
        imp_captureset_close(cs);
        cs = NULL;

        CHECK_OK(imp_captureset_open(dir, &cs, &e));
        if (!cs)
                return;
        CHECK_INT_EQ(imp_captureset_count(cs), 5);
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                CHECK(records_equal(imp_captureset_record(cs, i), &saved[i]));
                _cleanup_image_ struct imp_image *img = NULL, *want = make_frame((int) i);
                CHECK_OK(imp_captureset_load_frame(cs, i, &img, &e));
                CHECK(img && img->type == IMP_PIX_U16 && img->width == W && img->height == H);
                bool same = img != NULL;
                for (int y = 0; same && y < H; y++)
                        same = memcmp(imp_image_row(img, y), imp_image_row(want, y), W * 2) == 0;
                CHECK_MSG(same, "frame %zu pixels round-trip", i);
        }
        /* the TIFF carries its record */
        char *desc = NULL;
        struct imp_image *img = NULL;
        CHECK_OK(imp_tiff_read(pathf("%s/frames/000001.tiff", dir), &img, &desc, &e));
        json_error_t je;
        _cleanup_json_ json_t *dj = desc ? json_loads(desc, 0, &je) : NULL;
        CHECK(dj != NULL);
        CHECK_INT_EQ(json_integer_value(json_object_get(dj, "seq")), 1);
        CHECK_STR_EQ(json_string_value(json_object_get(dj, "file")), "frames/000001.tiff");
        CHECK_STR_EQ(json_string_value(json_object_get(json_object_get(dj, "pattern"), "kind")), "phase");
        free(desc);
        imp_image_free(img);
        CHECK_ERR(imp_captureset_load_frame(cs, 5, &img, &e), -ERANGE);

        /* a second opener while this one holds the set reads but cannot append */
        struct imp_captureset *reader = NULL;
        CHECK_OK(imp_captureset_open(dir, &reader, &e));
        if (reader) {
                CHECK_INT_EQ(imp_captureset_count(reader), 5);
                _cleanup_image_ struct imp_image *f = make_frame(1);
                r = make_record(5, 0);
                CHECK_ERR(imp_captureset_add_frame(reader, &r, f, &e), -EBUSY);
                CHECK_STR_CONTAINS(e.msg, "another process");
                imp_captureset_close(reader);
        }
        add_frames(cs, 1);
        imp_captureset_close(cs);
        imp_captureset_close(NULL);
}

static int report_count(json_t *report, const char *path_prefix) {
        int n = 0;
        size_t i;
        json_t *item;
        json_array_foreach(report, i, item)
                n += strncmp(json_string_value(json_object_get(item, "path")), path_prefix, strlen(path_prefix)) == 0;
        return n;
}

static void test_repairs(void) {
        struct imp_captureset *cs = NULL;
        struct imp_error e = {};
        const char *dir = new_set("repair", &cs);
        if (!cs)
                return;
        add_frames(cs, 4);
        imp_captureset_close(cs);
        cs = NULL;
        LOCAL_PATH(manifest, "%s/manifest.jsonl", dir);
        long long good = file_size(manifest);

        /* what a crash leaves: a torn line, a renamed but unrecorded frame, .tmp files */
        write_file(manifest, "{\"seq\":4,\"step\":\"struc", O_APPEND);
        CHECK_INT_EQ(link(pathf("%s/frames/000000.tiff", dir), pathf("%s/frames/000004.tiff", dir)), 0);
        write_file(pathf("%s/frames/000005.tiff.tmp", dir), "partial", O_TRUNC);
        write_file(pathf("%s/rig.json.tmp", dir), "{", O_TRUNC);
        write_file(pathf("%s/frames/notes.txt", dir), "operator's file", O_TRUNC);
        long long torn_size = file_size(manifest);
        /* open() changes nothing and refuses the torn tail, pointing at repair */
        CHECK_ERR(imp_captureset_open(dir, &cs, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:5: the last line is incomplete");
        CHECK_STR_CONTAINS(e.msg, "impasto repair");
        CHECK_INT_EQ(file_size(manifest), torn_size);
        CHECK(exists(pathf("%s/frames/000004.tiff", dir)));
        CHECK(exists(pathf("%s/frames/000005.tiff.tmp", dir)));
        CHECK(exists(pathf("%s/rig.json.tmp", dir)));
        /* a dry run reports, and changes nothing */
        json_t *report = NULL;
        CHECK_INT_EQ(imp_captureset_repair(dir, true, &report, &e), 4);
        CHECK_INT_EQ(report_count(report, "manifest.jsonl:5"), 1);
        CHECK_INT_EQ(report_count(report, "frames/"), 2);   /* 000004.tiff and 000005.tiff.tmp */
        CHECK_INT_EQ(report_count(report, "rig.json.tmp"), 1);
        CHECK(json_object_get(json_array_get(report, 0), "moved_to") == NULL);
        json_decref(report);
        CHECK_INT_EQ(file_size(manifest), torn_size);
        CHECK(exists(pathf("%s/frames/000004.tiff", dir)));
        CHECK(!exists(pathf("%s/quarantine", dir)));
        /* the repair moves each item into quarantine/, deleting nothing */
        CHECK_INT_EQ(imp_captureset_repair(dir, false, &report, &e), 4);
        CHECK_STR_EQ(json_string_value(json_object_get(json_array_get(report, 0), "moved_to")),
                     "quarantine/manifest-tail.jsonl");
        json_decref(report);
        CHECK_INT_EQ(file_size(manifest), good);
        CHECK_INT_EQ(file_size(pathf("%s/quarantine/manifest-tail.jsonl", dir)), torn_size - good);
        CHECK_INT_EQ(file_size(pathf("%s/quarantine/000004.tiff", dir)), file_size(pathf("%s/frames/000000.tiff", dir)));
        CHECK(exists(pathf("%s/quarantine/000005.tiff.tmp", dir)));
        CHECK(exists(pathf("%s/quarantine/rig.json.tmp", dir)));
        CHECK(!exists(pathf("%s/frames/000004.tiff", dir)));
        CHECK(!exists(pathf("%s/frames/000005.tiff.tmp", dir)));
        CHECK(!exists(pathf("%s/rig.json.tmp", dir)));
        CHECK(exists(pathf("%s/frames/notes.txt", dir)));   /* not ours: left alone */
        CHECK_INT_EQ(imp_captureset_repair(dir, false, &report, &e), 0);   /* nothing left to do */
        json_decref(report);
        CHECK_OK(imp_captureset_open(dir, &cs, &e));
        if (!cs)
                return;
        CHECK_INT_EQ(imp_captureset_count(cs), 4);
        add_frames(cs, 1);   /* continues at frames/000004.tiff */
        CHECK_INT_EQ(imp_captureset_record(cs, 4)->seq, 4);
        imp_captureset_close(cs);
        cs = NULL;

        /* add_frame never overwrites a file it did not record */
        write_file(pathf("%s/frames/000005.tiff", dir), "someone's", O_TRUNC);
        CHECK_OK(imp_captureset_open(dir, &cs, &e));
        if (!cs)
                return;
        struct imp_frame_record r = make_record(5, 0);
        _cleanup_image_ struct imp_image *f = make_frame(5);
        CHECK_ERR(imp_captureset_add_frame(cs, &r, f, &e), -EEXIST);
        CHECK_STR_CONTAINS(e.msg, "impasto repair");
        CHECK_INT_EQ(file_size(pathf("%s/frames/000005.tiff", dir)), 9);
        imp_captureset_close(cs);
        cs = NULL;
        CHECK_INT_EQ(imp_captureset_repair(dir, false, &report, &e), 1);
        json_decref(report);
        CHECK(exists(pathf("%s/quarantine/000005.tiff", dir)));

        /* a complete but unreadable last line (power loss: the size grew, the data did not
         * reach the disk) is refused by open, and moved by repair like a torn one */
        good = file_size(manifest);
        write_file(manifest, "{\"seq\": oops}\n", O_APPEND);
        CHECK_ERR(imp_captureset_open(dir, &cs, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:6: the last line is unreadable");
        CHECK_INT_EQ(imp_captureset_repair(dir, false, &report, &e), 1);
        CHECK_STR_EQ(json_string_value(json_object_get(json_array_get(report, 0), "moved_to")),
                     "quarantine/manifest-tail.jsonl.1");
        json_decref(report);
        CHECK_OK(imp_captureset_open(dir, &cs, &e));
        if (!cs)
                return;
        CHECK_INT_EQ(imp_captureset_count(cs), 5);
        CHECK_INT_EQ(file_size(manifest), good);
        imp_captureset_close(cs);
        cs = NULL;
        /* ... but the same line followed by a good one is damage, not a crash: open and
         * repair both refuse, and repair moves nothing */
        write_file(manifest, "{\"seq\": oops}\n", O_APPEND);
        write_file(manifest, "{}\n", O_APPEND);
        long long damaged = file_size(manifest);
        CHECK_ERR(imp_captureset_open(dir, &cs, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:6:");
        CHECK(cs == NULL);
        report = NULL;
        CHECK_ERR(imp_captureset_repair(dir, false, &report, &e), -EBADMSG);
        CHECK(report == NULL);
        CHECK_INT_EQ(file_size(manifest), damaged);
}

static void test_damage(void) {
        struct imp_captureset *cs = NULL;
        struct imp_error e = {};
        const char *dir = new_set("damage", &cs);
        if (!cs)
                return;
        add_frames(cs, 3);
        imp_captureset_close(cs);
        cs = NULL;
        LOCAL_PATH(manifest, "%s/manifest.jsonl", dir);
        LOCAL_PATH(f1, "%s/frames/000001.tiff", dir);

        /* a flipped byte: open (size check) passes, load_frame names the file */
        int fd = open(f1, O_RDWR);
        char byte;
        CHECK(pread(fd, &byte, 1, 200) == 1);
        byte ^= 0x40;
        CHECK(pwrite(fd, &byte, 1, 200) == 1);
        CHECK_OK(imp_captureset_open(dir, &cs, &e));
        if (!cs)
                return;
        struct imp_image *img = NULL;
        CHECK_OK(imp_captureset_load_frame(cs, 0, &img, &e));
        imp_image_free(img);
        img = NULL;
        CHECK_ERR(imp_captureset_load_frame(cs, 1, &img, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "frames/000001.tiff: checksum mismatch");
        CHECK(img == NULL);
        imp_captureset_close(cs);
        cs = NULL;
        byte ^= 0x40;
        CHECK(pwrite(fd, &byte, 1, 200) == 1);

        /* a resized frame is caught at open */
        CHECK(ftruncate(fd, file_size(f1) - 1) == 0);
        CHECK_ERR(imp_captureset_open(dir, &cs, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "frames/000001.tiff");
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:2");
        close(fd);
        /* a missing one too */
        CHECK(unlink(f1) == 0);
        CHECK_ERR(imp_captureset_open(dir, &cs, &e), -ENOENT);
        CHECK_STR_CONTAINS(e.msg, "frames/000001.tiff");

        /* a malformed line in the middle is an error naming line and field */
        const char *dir2 = new_set("damage2", &cs);
        if (!cs)
                return;
        add_frames(cs, 3);
        imp_captureset_close(cs);
        cs = NULL;
        LOCAL_PATH(m2, "%s/manifest.jsonl", dir2);
        _cleanup_free_ char *text = NULL;
        size_t len = 0;
        FILE *f = fopen(m2, "r");
        CHECK(getdelim(&text, &len, 0, f) > 0);
        fclose(f);
        char *p = strstr(strchr(text, '\n'), "\"exposure_us\":");
        CHECK(p != NULL);
        if (!p)
                return;
        memcpy(p + strlen("\"exposure_us\":"), "\"x\"", 3);   /* 1250.5 → "x"0.5: a string, then junk */
        char *q = p + strlen("\"exposure_us\":\"x\"");
        while (*q != ',')
                *q++ = ' ';
        write_file(m2, text, O_TRUNC);
        CHECK_ERR(imp_captureset_open(dir2, &cs, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:2: exposure_us: expected a number");
        (void) manifest;

        /* a file field pointing outside the set */
        const char *dir3 = new_set("damage3", &cs);
        if (!cs)
                return;
        add_frames(cs, 2);
        imp_captureset_close(cs);
        cs = NULL;
        LOCAL_PATH(m3, "%s/manifest.jsonl", dir3);
        f = fopen(m3, "r");
        free(text);
        text = NULL;
        CHECK(getdelim(&text, &len, 0, f) > 0);
        fclose(f);
        p = strstr(text, "frames/000000.tiff");
        memcpy(p, "../../../etc/passwd", 18);
        write_file(m3, text, O_TRUNC);
        CHECK_ERR(imp_captureset_open(dir3, &cs, &e), -EBADMSG);
        CHECK_STR_CONTAINS(e.msg, "manifest.jsonl:1: file");

        /* not a set */
        CHECK_ERR(imp_captureset_open(test_tmpdir(), &cs, &e), -ENOENT);
        CHECK_STR_CONTAINS(e.msg, "not a capture set");
}

int main(void) {
        test_pattern_json();
        test_layout();
        test_repairs();
        test_damage();
        return TEST_DONE();
}
