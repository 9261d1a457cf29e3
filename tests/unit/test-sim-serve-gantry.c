/* A gantry scene served through the real drivers (sim/serve.c): the GRBL stage driver on the
 * served pseudo-terminal, the Aravis camera and the Modbus dome. A frame grabbed with the
 * carriage at a tile's target must equal, bit for bit, the renderer's frame of that tile as
 * `impasto sim render --painting` places it (stage_error included), and differ from the
 * first tile's; without the plan the gantry scene is refused with a message saying so.
 * Modbus port 15933; run in a private network namespace. */
#include <math.h>
#include "camera.h"
#include "dome.h"
#include "emu.h"
#include "gantry.h"
#include "render.h"
#include "scene.h"
#include "serve.h"
#include "stage.h"
#include "unit/test.h"

#define ADDRESS "127.0.0.1"
#define PORT 15933
#define MB_ADDR "127.0.0.1:15933;timeout_ms=500"
#define GRAB_TIMEOUT_MS 5000
#define SETTLE_MS 30000U
#define SCENE IMPASTO_SOURCE_DIR "/config/scenes/painting-small.cfg"
#define PLAN IMPASTO_SOURCE_DIR "/config/plans/painting-small.cfg"

/* The renderer's frame of tile k for this record (a scene of its own, placed as sim render does). */
static struct imp_image *rendered(const struct imp_plan *plan, size_t k, const struct imp_frame_record *rec) {
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        CHECK_OK(imp_scene_load(SCENE, &scene, &err));
        if (!scene)
                return NULL;
        struct imp_sim_tile_pose pose;
        imp_sim_tile_pose(scene, imp_plan_tiles(plan), k, &pose);
        struct imp_painting_place pl;
        imp_sim_tile_place(imp_plan_tiles(plan), &pose, &pl);
        CHECK_OK(imp_scene_place(scene, &pl, &err));
        _cleanup_(imp_render_freep) struct imp_render *rd = NULL;
        CHECK_OK(imp_render_new(scene, &rd, &err));
        struct imp_image *img = NULL;
        if (rd)
                CHECK_OK(imp_render_frame(rd, rec, &img, &err));
        return img;
}

/* Pixels differing between the grabbed frame and img. */
static size_t n_differ(const struct imp_frame *f, const struct imp_image *img) {
        if (!f || !img || (int) f->width != img->width || (int) f->height != img->height)
                return SIZE_MAX;
        size_t n = 0;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        n += ((const uint16_t *) f->data)[(size_t) y * img->width + x] !=
                             ((const uint16_t *) ((const uint8_t *) img->data + y * img->stride))[x];
        return n;
}

int main(void) {
        if (!imp_emu_gige_port_free(ADDRESS))
                TEST_SKIP("UDP %s:3956 (GVCP) is taken by another camera", ADDRESS);
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        CHECK_OK(imp_scene_load(SCENE, &scene, &err));
        if (!scene)
                return TEST_DONE();
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        CHECK_OK(imp_plan_load(PLAN, imp_scene_rig(scene), &plan, &err));
        if (!plan || !imp_plan_tiles(plan))
                return TEST_DONE();
        struct imp_serve *none = NULL;
        CHECK_ERR(imp_serve_new(scene, &(struct imp_serve_config) { .address = ADDRESS, .modbus_port = PORT }, &none,
                                &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "painting on a gantry: give the plan");
        _cleanup_(imp_serve_freep) struct imp_serve *srv = NULL;
        int r = imp_serve_new(scene, &(struct imp_serve_config) { .address = ADDRESS, .modbus_port = PORT,
                                                                  .tiles = imp_plan_tiles(plan) }, &srv, &err);
        if (r == -EADDRINUSE)
                TEST_SKIP("%s", err.msg);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        CHECK(imp_serve_stage_device(srv) != NULL);
        _cleanup_free_ char *desc = imp_serve_describe(srv);
        CHECK_STR_CONTAINS(desc, "stage: GRBL 1.1 on /dev/pts/");

        char addr[256];
        snprintf(addr, sizeof addr, "%s;baud=115200;timeout_ms=1000", imp_serve_stage_device(srv));
        _cleanup_(imp_stage_closep) struct imp_stage *st = NULL;
        _cleanup_(imp_camera_closep) struct imp_camera *cam = NULL;
        _cleanup_(imp_dome_closep) struct imp_dome *dome = NULL;
        CHECK_OK(imp_stage_open("grbl", addr, 0, &st));
        CHECK_OK(imp_camera_open("aravis", ADDRESS, 3000, &cam));
        CHECK_OK(imp_dome_open("modbus", MB_ADDR, 0, &dome));
        if (!st || !cam || !dome)
                return TEST_DONE();
        CHECK_OK(imp_stage_clear_fault(st));
        CHECK_OK(imp_stage_home(st));
        CHECK_OK(imp_stage_wait_settled(st, SETTLE_MS, NULL));
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO16));
        CHECK_OK(imp_camera_set_exposure_us(cam, 10000));
        CHECK_OK(imp_camera_set_gain_db(cam, 0));
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4, .software_trigger = true }));
        CHECK_OK(imp_dome_set_light(dome, 0, 1000, 0));
        const struct imp_rig *rig = imp_serve_rig(srv);

        /* tile 4 (col 1, row 1): the frame is that tile's render, not tile 0's */
        size_t k = 4;
        CHECK_OK(imp_stage_move_to(st, imp_tile_plan_tile(imp_plan_tiles(plan), k)->stage_mm, IMP_STAGE_XYZ));
        CHECK_OK(imp_stage_wait_settled(st, SETTLE_MS, NULL));
        const struct imp_frame *f = NULL;
        CHECK_OK(imp_camera_trigger_software(cam));
        CHECK_OK(imp_camera_grab(cam, GRAB_TIMEOUT_MS, &f));
        if (!f)
                return TEST_DONE();
        struct imp_frame_record rec = { .seq = (long long) f->meta.frame_id, .camera = "cam0", .step = "dome",
                                        .light = rig->lights[0].id, .exposure_us = 10000 };
        _cleanup_image_ struct imp_image *at_k = rendered(plan, k, &rec);
        _cleanup_image_ struct imp_image *at_0 = rendered(plan, 0, &rec);
        CHECK_INT_EQ(n_differ(f, at_k), 0);
        size_t d0 = n_differ(f, at_0);
        CHECK_MSG(d0 > (size_t) (f->width * f->height / 2) && d0 != SIZE_MAX,
                  "tile %zu's frame equals tile 0's in all but %zu pixels", k, d0);
        return TEST_DONE();
}
