/* Target 4: the JSON documents of a painting and of a copy, as view, export and mosaic read
 * them. The first byte picks the reader: 0 painting.json (imp_painting_json_load: the
 * daemon's resume, `impasto process`, `impasto mosaic`); 1 a digital copy read whole
 * (imp_copy_load: copy.json, boxes.json and the EXR maps given as "--8<-- NAME" parts).
 * Checked: a refusal says why; an accepted painting.json passes its own check again; an
 * accepted copy holds finite values only, with every box inside the grid; nothing on disk
 * changes. */
#include <errno.h>
#include <math.h>
#include <string.h>
#include "copy-load.h"
#include "fuzz.h"
#include "tiles.h"

#define MAX_PARTS 12

static void fuzz_painting(const uint8_t *data, size_t size) {
        const char *path = fuzz_write_file("painting.json", data, size);
        char p[4608];
        snprintf(p, sizeof p, "%s", path);
        json_t *j = NULL;
        struct imp_error err = {};
        int r = imp_painting_json_load(p, &j, &err);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "painting.json: %d %s\n", r, err.msg);
        if (r < 0) {
                FUZZ_CHECK(err.msg[0], "painting.json refused (%d) without a message", r);
        } else {
                struct imp_error e2 = {};
                FUZZ_CHECK(imp_painting_json_check(j, "again", &e2) == 0, "accepted, then refused: %s", e2.msg);
                json_decref(j);
        }
        size_t n = 0;
        void *now = fuzz_read_file(p, &n);
        FUZZ_CHECK(now && n == size && !memcmp(now, data, n), "painting.json changed while read");
        free(now);
}

static bool copy_part(const char *name) {
        static const char *const files[] = { "copy.json", "boxes.json", "heightfield.exr", "rho_d.exr",
                                             "rho_s.exr", "lobe.exr", "fit-flags.exr", NULL };
        for (size_t i = 0; files[i]; i++)
                if (!strcmp(name, files[i]))
                        return true;
        return false;
}

static void check_copy(const struct imp_copy *c) {
        size_t n = (size_t) c->nx * c->ny;
        FUZZ_CHECK(isfinite(c->pitch_mm) && c->pitch_mm > 0, "pitch %g", c->pitch_mm);
        FUZZ_CHECK(isfinite(c->plane_mm), "plane %g", c->plane_mm);
        for (size_t k = 0; k < n; k++) {
                FUZZ_CHECK(isfinite(c->height[k]) && isfinite(c->normal_x[k]) && isfinite(c->normal_y[k]) &&
                                   isfinite(c->sigma[k]) && c->sigma[k] >= 0,
                           "texel %zu: height %g n %g %g sigma %g", k, c->height[k], c->normal_x[k], c->normal_y[k],
                           c->sigma[k]);
                const struct imp_lafortune *b = &c->brdf[k];
                for (int q = 0; q < 3; q++)
                        FUZZ_CHECK(isfinite(b->rho_d[q]) && isfinite(b->rho_s[q]) && b->rho_d[q] >= 0 &&
                                           b->rho_s[q] >= 0,
                                   "texel %zu: rho_d %g rho_s %g", k, b->rho_d[q], b->rho_s[q]);
                FUZZ_CHECK(isfinite(b->cx) && isfinite(b->cy) && isfinite(b->cz) && isfinite(b->k) && b->k >= 0,
                           "texel %zu: lobe %g %g %g k %g", k, b->cx, b->cy, b->cz, b->k);
        }
        for (size_t i = 0; i < c->n_boxes; i++) {
                const struct imp_relief_box *b = &c->boxes[i];
                FUZZ_CHECK(b->u0 >= 0 && b->v0 >= 0 && b->w >= 1 && b->h >= 1 && b->u0 + b->w <= c->nx &&
                                   b->v0 + b->h <= c->ny,
                           "box %zu outside the %dx%d grid", i, c->nx, c->ny);
        }
}

static void fuzz_copy(const uint8_t *data, size_t size) {
        struct fuzz_part parts[MAX_PARTS];
        size_t n = fuzz_split(data, size, parts, MAX_PARTS);
        const struct fuzz_part *written[MAX_PARTS];
        size_t nw = 0;
        for (size_t i = 0; i < n; i++) {
                bool dup = false;
                for (size_t k = 0; k < nw; k++)
                        dup |= !strcmp(written[k]->name, parts[i].name);
                if (!copy_part(parts[i].name) || dup)
                        continue;
                fuzz_write_file(parts[i].name, parts[i].data, parts[i].size);
                written[nw++] = &parts[i];
        }
        struct imp_copy c;
        struct imp_error err = {};
        int r = imp_copy_load(fuzz_scratch_dir(), &c, &err);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "copy: %d %s\n", r, err.msg);
        if (r < 0) {
                FUZZ_CHECK(err.msg[0], "copy refused (%d) without a message", r);
                /* a few KB of files never justify running out of memory: a size field trusted */
                FUZZ_CHECK(r != -ENOMEM, "copy of %zu bytes refused for memory: %s", size, err.msg);
        } else
                check_copy(&c);
        imp_copy_done(&c);
        for (size_t k = 0; k < nw; k++) {
                char p[4608];
                snprintf(p, sizeof p, "%s/%s", fuzz_scratch_dir(), written[k]->name);
                size_t got = 0;
                void *now = fuzz_read_file(p, &got);
                FUZZ_CHECK(now && got == written[k]->size && !memcmp(now, written[k]->data, got),
                           "%s changed while read", written[k]->name);
                free(now);
        }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
        if (size < 1)
                return 0;
        fuzz_clear_scratch();
        if (data[0] & 1)
                fuzz_copy(data + 1, size - 1);
        else
                fuzz_painting(data + 1, size - 1);
        return 0;
}
