/* A capture set as a painting's tile (process-painting.h, docs/painting.md). */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "heightfield.h"
#include "json-util.h"
#include "plan.h"
#include "process-painting.h"
#include "tiles.h"
#include "macro.h"

/* The camera's footprint on the rig's canvas plane (world z = 0, rig.json's convention)
 * between the principal point and the pixel beside it along x; 0 when a ray misses it. */
static double footprint_on_canvas_plane(const struct imp_pinhole *cam) {
        double px[2][2] = { { cam->cx, cam->cy }, { cam->cx + 1, cam->cy } }, P[2][3];
        for (int k = 0; k < 2; k++) {
                double o[3], d[3];
                imp_pinhole_ray_world(cam, px[k], o, d);
                if (!(fabs(d[2]) > 1e-12))
                        return 0;
                double s = -o[2] / d[2];
                if (!(s > 0))
                        return 0;
                for (int q = 0; q < 3; q++)
                        P[k][q] = o[q] + s * d[q];
        }
        return sqrt(pow(P[0][0] - P[1][0], 2) + pow(P[0][1] - P[1][1], 2) + pow(P[0][2] - P[1][2], 2));
}

/* DIR/../../painting.json when it exists: *ret NULL otherwise. */
static int load_painting_json(const char *dir, char *path, size_t size, json_t **ret, struct imp_error *err) {
        *ret = NULL;
        if (snprintf(path, size, "%s/../../painting.json", dir) >= (int) size)
                return 0;
        if (access(path, F_OK) < 0)
                return 0;
        return imp_painting_json_load(path, ret, err);     /* bounded, every field checked */
}

/* The entry of painting.json whose "capture" is tiles/BASENAME(dir): its index, or -1. */
static int tile_index(const json_t *painting, const char *dir) {
        char buf[PATH_MAX];
        snprintf(buf, sizeof buf, "%s", dir);
        size_t n = strlen(buf);
        while (n > 1 && buf[n - 1] == '/')
                buf[--n] = 0;
        const char *base = strrchr(buf, '/');
        base = base ? base + 1 : buf;
        size_t k;
        json_t *t;
        json_array_foreach(json_object_get(painting, "tiles"), k, t) {
                const char *cap = json_string_value(json_object_get(t, "capture"));
                const char *slash = cap ? strrchr(cap, '/') : NULL;
                if (cap && !strcmp(slash ? slash + 1 : cap, base)) {
                        json_t *idx = json_object_get(t, "index");
                        return json_is_integer(idx) ? (int) json_integer_value(idx) : (int) k;
                }
        }
        return -1;
}

static int pitch_of(const struct imp_captureset *cs, const json_t *painting, const char *path,
                    struct imp_painting_tile *ret, struct imp_error *err) {
        double pitch = 0;
        int r = painting ? imp_json_get_double(painting, "pitch_mm", false, &pitch, path, err) : 0;
        if (r < 0)
                return r;
        if (painting && json_object_get(painting, "pitch_mm")) {
                if (!(pitch > 0 && pitch <= 1000))
                        return imp_error_set(err, -EBADMSG, "%s: pitch_mm: expected a number in (0, 1000] mm, got %g",
                                             path, pitch);
                ret->pitch_mm = pitch;
                ret->pitch_source = "painting.json pitch_mm";
                return 0;
        }
        const struct imp_rig *rig = imp_captureset_rig(cs);
        pitch = rig->n_cameras > 0 ? footprint_on_canvas_plane(&rig->cameras[0].model) : 0;
        if (!(pitch > 0))
                return 0;   /* no pitch to give: the copy chooses its own */
        ret->pitch_mm = round(IMP_HF_PITCH_NOISE_CAP * pitch * 1e4) / 1e4;
        ret->pitch_source = "1.02 x the camera footprint on the painting's plane";
        return 0;
}

int imp_painting_tile_detect(const struct imp_captureset *cs, struct imp_painting_tile *ret, struct imp_error *err) {
        *ret = (struct imp_painting_tile) { .index = -1 };
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        int r = imp_captureset_load_plan(cs, &plan, err);
        if (r < 0)
                return r;
        bool by_plan = plan && imp_plan_tiles(plan);
        const char *dir = imp_captureset_dir(cs);
        char path[PATH_MAX];
        _cleanup_json_ json_t *painting = NULL;
        if ((r = load_painting_json(dir, path, sizeof path, &painting, err)) < 0)
                return imp_error_prefix(err, "%s: a painting.json beside the capture set that cannot be read: ", dir);
        ret->index = painting ? tile_index(painting, dir) : -1;
        bool by_json = ret->index >= 0;
        if (!by_plan && !by_json)
                return 0;
        ret->is_tile = true;
        ret->marker = by_plan && by_json ? "plan.cfg painting group, painting.json"
                      : by_plan ? "plan.cfg painting group" : "painting.json";
        return pitch_of(cs, by_json ? painting : NULL, path, ret, err);
}
