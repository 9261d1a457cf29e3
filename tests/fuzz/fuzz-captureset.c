/* Target 2: a capture set as a worker opens it (pipeline/model/captureset.c): set.json,
 * rig.json, manifest.jsonl, plan.cfg and frames/NNNNNN.tiff, given as the parts of one input
 * ("--8<-- NAME" lines, fuzz.h). Opened, every frame loaded, checked against its plan, and a
 * dry-run repair. Checked: a refusal says why; a loaded frame is 16-bit at the rig camera's
 * size; and nothing on disk changes (a reader never modifies what it reads). */
#include <dirent.h>
#include <string.h>
#include "captureset.h"
#include "fuzz.h"
#include "plan.h"

#define MAX_PARTS 16

struct snapshot {
        char name[64];
        void *data;
        size_t size;
};

static size_t count_entries(const char *dir) {
        DIR *d = opendir(dir);
        size_t n = 0;
        if (!d)
                return 0;
        struct dirent *de;
        while ((de = readdir(d)))
                n += de->d_name[0] != '.';
        closedir(d);
        return n;
}

static bool name_ok(const char *name) {
        static const char *const top[] = { "set.json", "rig.json", "manifest.jsonl", "plan.cfg", NULL };
        for (size_t i = 0; top[i]; i++)
                if (!strcmp(name, top[i]))
                        return true;
        /* frames/NNNNNN.tiff and nothing else: the harness writes only where it means to */
        return strlen(name) == 18 && !strncmp(name, "frames/", 7) && !strcmp(name + 13, ".tiff") &&
               strspn(name + 7, "0123456789") == 6;
}

static void exercise(const char *dir, const char *frames_dir) {
        struct imp_error err = {};
        struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(dir, &cs, &err);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "open: %d %s\n", r, err.msg);
        if (r < 0) {
                FUZZ_CHECK(err.msg[0], "open refused (%d) without a message", r);
                return;
        }
        const struct imp_rig *rig = imp_captureset_rig(cs);
        for (size_t i = 0; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                /* seq is the plan's position, not the line's: a re-captured step repeats one */
                FUZZ_CHECK(rec && rec->seq >= 0, "record %zu has seq %lld", i, rec ? rec->seq : -1);
                struct imp_image *img = NULL;
                err = (struct imp_error) {};
                r = imp_captureset_load_frame(cs, i, &img, &err);
                if (getenv("FUZZ_VERBOSE"))
                        fprintf(stderr, "frame %zu: %d %s\n", i, r, err.msg);
                if (r < 0) {
                        FUZZ_CHECK(err.msg[0], "frame %zu refused (%d) without a message", i, r);
                        continue;
                }
                FUZZ_CHECK(img && img->type == IMP_PIX_U16 && img->width > 0 && img->height > 0,
                           "frame %zu loaded but not a 16-bit image", i);
                for (int c = 0; c < rig->n_cameras; c++)
                        if (!strcmp(rig->cameras[c].name, rec->camera))
                                FUZZ_CHECK(img->width == rig->cameras[c].model.width &&
                                                   img->height == rig->cameras[c].model.height,
                                           "frame %zu is %dx%d, camera %s is %dx%d", i, img->width, img->height,
                                           rec->camera, rig->cameras[c].model.width,
                                           rig->cameras[c].model.height);
                imp_image_free(img);
        }
        json_t *missing = NULL;
        err = (struct imp_error) {};
        r = imp_captureset_check_complete(cs, &missing, &err);
        FUZZ_CHECK(r >= 0 || err.msg[0], "check_complete refused (%d) without a message", r);
        json_decref(missing);
        struct imp_plan *plan = NULL;
        err = (struct imp_error) {};
        r = imp_captureset_load_plan(cs, &plan, &err);
        FUZZ_CHECK(r >= 0 || err.msg[0], "load_plan refused (%d) without a message", r);
        imp_plan_free(plan);
        imp_captureset_close(cs);
        json_t *report = NULL;
        err = (struct imp_error) {};
        r = imp_captureset_repair(dir, true, &report, &err);
        FUZZ_CHECK(r >= 0 || err.msg[0], "repair --dry-run refused (%d) without a message", r);
        json_decref(report);
        (void) frames_dir;
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
        struct fuzz_part parts[MAX_PARTS];
        size_t n = fuzz_split(data, size, parts, MAX_PARTS);
        fuzz_clear_scratch();
        const char *dir = fuzz_scratch_dir();
        char frames[4608];
        snprintf(frames, sizeof frames, "%s/frames", dir);
        struct snapshot snap[MAX_PARTS];
        size_t ns = 0;
        for (size_t i = 0; i < n; i++) {
                if (!name_ok(parts[i].name))
                        continue;
                bool dup = false;
                for (size_t k = 0; k < ns; k++)
                        dup |= !strcmp(snap[k].name, parts[i].name);
                if (dup)
                        continue;
                fuzz_write_file(parts[i].name, parts[i].data, parts[i].size);
                snprintf(snap[ns].name, sizeof snap[ns].name, "%s", parts[i].name);
                snap[ns].data = (void *) parts[i].data;
                snap[ns].size = parts[i].size;
                ns++;
        }
        size_t top = count_entries(dir), nframes = count_entries(frames);

        exercise(dir, frames);

        for (size_t k = 0; k < ns; k++) {
                char p[4608];
                snprintf(p, sizeof p, "%s/%s", dir, snap[k].name);
                size_t got = 0;
                void *now = fuzz_read_file(p, &got);
                FUZZ_CHECK(now && got == snap[k].size && !memcmp(now, snap[k].data, got),
                           "%s changed on disk while read", snap[k].name);
                free(now);
        }
        FUZZ_CHECK(count_entries(dir) == top && count_entries(frames) == nframes, "files appeared in the set");
        return 0;
}
