/* Light → settle → trigger → frame → light off, across the emulated dome (Modbus TCP
 * controller) and the emulated GigE camera, both reached through the real backends. For
 * every light the frame must show that light (decoded from its pixels) and nothing else,
 * and at no moment may two lights be on. */
#include <time.h>
#include "camera.h"
#include "dome.h"
#include "emu.h"
#include "unit/test.h"

#define PORT 15823
#define N_LIGHTS 8
#define WIDTH 256
#define HEIGHT 64
#define EXPOSURE_US 2000
#define SETTLE_US 20000         /* LED driver rise time the capture waits out */

int main(void) {
        if (!imp_emu_gige_port_free("127.0.0.1"))
                TEST_SKIP("UDP 127.0.0.1:3956 (GVCP) is taken by another camera");
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        CHECK_OK(imp_emu_rig_new(N_LIGHTS, &rig));
        _cleanup_(imp_emu_modbus_freep) struct imp_emu_modbus *mb = NULL;
        struct imp_emu_modbus_config cfg = { .port = PORT, .n_lights = N_LIGHTS, .n_axes = 1 };
        int r = imp_emu_modbus_new(&cfg, rig, &mb);
        if (r == -EADDRINUSE)
                TEST_SKIP("TCP port %d on 127.0.0.1 is busy", PORT);
        CHECK_OK(r);
        _cleanup_(imp_emu_gige_freep) struct imp_emu_gige *gige = NULL;
        r = imp_emu_gige_new("127.0.0.1", "IMP-SYNC", rig, NULL, NULL, &gige);
        if (r == -EADDRINUSE)
                TEST_SKIP("UDP 127.0.0.1:3956 (GVCP) is taken by another camera");
        CHECK_OK(r);
        if (!mb || !gige)
                return TEST_DONE();

        _cleanup_(imp_dome_closep) struct imp_dome *dome = NULL;
        _cleanup_(imp_camera_closep) struct imp_camera *cam = NULL;
        char addr[64];
        snprintf(addr, sizeof addr, "127.0.0.1:%d", PORT);
        CHECK_OK(imp_dome_open("modbus", addr, 200, &dome));
        CHECK_OK(imp_camera_open("aravis", "127.0.0.1", 3000, &cam));
        if (!dome || !cam)
                return TEST_DONE();
        CHECK_OK(imp_camera_set_roi(cam, 0, 0, WIDTH, HEIGHT));
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO8));
        CHECK_OK(imp_camera_set_exposure_us(cam, EXPOSURE_US));
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4, .software_trigger = true }));

        static const unsigned order[N_LIGHTS] = { 5, 2, 7, 0, 3, 6, 1, 4 };
        static uint8_t expected[WIDTH * HEIGHT];
        for (unsigned k = 0; k < N_LIGHTS; k++) {
                unsigned id = order[k];
                CHECK_OK(imp_dome_set_light(dome, id, 1000, 0));
                usleep(SETTLE_US);
                CHECK_OK(imp_camera_trigger_software(cam));
                const struct imp_frame *f;
                r = imp_camera_grab(cam, 2000, &f);
                CHECK_OK(r);
                CHECK_OK(imp_dome_all_off(dome));
                if (r < 0)
                        continue;
                int light, pattern;
                uint32_t exposure_us;
                CHECK_OK(imp_emu_decode_default(f->data, WIDTH, HEIGHT, 1, &light, &pattern, &exposure_us));
                CHECK_MSG(light == (int) id, "frame for light %u shows light %d", id, light);
                CHECK_INT_EQ(exposure_us, EXPOSURE_US);
                struct imp_emu_camera_state st = { .exposure_us = EXPOSURE_US, .lit_light = (int) id, .pattern = -1 };
                CHECK_OK(imp_emu_fill_default(NULL, &st, expected, WIDTH, HEIGHT, 1));
                CHECK_MSG(memcmp(f->data, expected, sizeof expected) == 0, "frame for light %u not byte-exact", id);
        }
        /* Dark frame after the last light went off. */
        CHECK_OK(imp_camera_trigger_software(cam));
        const struct imp_frame *f;
        if (imp_camera_grab(cam, 2000, &f) == 0) {
                int light;
                CHECK_OK(imp_emu_decode_default(f->data, WIDTH, HEIGHT, 1, &light, NULL, NULL));
                CHECK_INT_EQ(light, -1);
        } else
                CHECK_MSG(0, "no dark frame");
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(rig), 1);
        CHECK_OK(imp_camera_stop(cam));
        return TEST_DONE();
}
