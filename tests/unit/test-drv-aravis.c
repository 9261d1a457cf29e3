/* The "aravis" camera backend against an emulated GigE Vision camera on 127.0.0.1 (Aravis'
 * fake camera in this process, pixels from sim/emu's default fill): frames byte-exact to
 * what the fill produced, Mono8 and Mono16, exposure honoured, 20+ frames in a row with no
 * missing packet, software trigger, and the settings the camera does not offer refused. */
#include <time.h>
#include "camera.h"
#include "emu.h"
#include "unit/gige-emu-setup.h"
#include "unit/test.h"

#define ADDRESS "127.0.0.1"
#define SERIAL "IMP-H7-0001"
#define WIDTH 320
#define HEIGHT 240
#define N_CONTINUOUS 24

static struct imp_emu_rig *rig;
static uint8_t expected[WIDTH * HEIGHT * 2];

/* What the emulator must have produced for this state. */
static const void *expect(uint32_t exposure_us, int bpp) {
        struct imp_emu_camera_state st = { .exposure_us = exposure_us,
                                           .lit_light = imp_emu_rig_lit_light(rig),
                                           .pattern = imp_emu_rig_get_pattern(rig) };
        CHECK_OK(imp_emu_fill_default(NULL, &st, expected, WIDTH, HEIGHT, bpp));
        return expected;
}

static void check_frame(const struct imp_frame *f, enum imp_pixel_format fmt, uint32_t exposure_us) {
        int bpp = (int) imp_pixel_format_bytes(fmt);
        CHECK_INT_EQ(f->width, WIDTH);
        CHECK_INT_EQ(f->height, HEIGHT);
        CHECK_INT_EQ(f->pixel_format, fmt);
        CHECK_INT_EQ(f->size, (size_t) WIDTH * HEIGHT * bpp);
        CHECK_MSG(memcmp(f->data, expect(exposure_us, bpp), f->size) == 0,
                  "frame %" PRIu64 " (%s) differs from the fill", f->meta.frame_id,
                  imp_pixel_format_to_string(fmt));
        int light, pattern;
        uint32_t exp_us;
        CHECK_OK(imp_emu_decode_default(f->data, WIDTH, HEIGHT, bpp, &light, &pattern, &exp_us));
        CHECK_INT_EQ(exp_us, exposure_us);
        CHECK_INT_EQ(light, imp_emu_rig_lit_light(rig));
        CHECK_INT_EQ(pattern, imp_emu_rig_get_pattern(rig));
}

static void test_continuous_mono8(struct imp_camera *cam) {
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO8));
        CHECK_OK(imp_camera_set_exposure_us(cam, 4000));
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 8 }));
        CHECK_ERR(imp_camera_set_roi(cam, 0, 0, 64, 64), -EBUSY);
        uint64_t last_id = 0;
        const struct imp_frame *f = NULL;
        for (int i = 0; i < N_CONTINUOUS; i++) {
                int r = imp_camera_grab(cam, 2000, &f);
                CHECK_OK(r);
                if (r < 0)
                        break;
                check_frame(f, IMP_PIXEL_MONO8, 4000);
                /* GigE Vision block ids are 16-bit and skip 0 when they wrap. */
                if (i > 0)
                        CHECK_MSG(f->meta.frame_id == last_id + 1 || (last_id == 0xffff && f->meta.frame_id == 1),
                                  "frame id %" PRIu64 " after %" PRIu64 ": a frame went missing",
                                  f->meta.frame_id, last_id);
                last_id = f->meta.frame_id;
        }
        if (f) {
                CHECK_INT_EQ(f->meta.n_missing_packets, 0);
                CHECK_INT_EQ(f->meta.n_failures, 0);
                CHECK_INT_EQ(f->meta.n_underruns, 0);
                CHECK(f->meta.system_timestamp_ns > 0);
        }
        /* The scene changes mid-stream: the next frames show it. */
        imp_emu_rig_set_light(rig, 2, 0);
        imp_emu_rig_set_light(rig, 6, 1000);
        imp_emu_rig_set_pattern(rig, 9);
        int seen = 0;
        for (int i = 0; i < 10 && !seen; i++) {
                if (imp_camera_grab(cam, 2000, &f) < 0)
                        break;
                int light, pattern;
                if (imp_emu_decode_default(f->data, WIDTH, HEIGHT, 1, &light, &pattern, NULL) == 0 &&
                    light == 6 && pattern == 9)
                        seen = 1;
        }
        CHECK_MSG(seen, "light 6 / pattern 9 never showed in the frames");
        CHECK_OK(imp_camera_stop(cam));
}

static void test_triggered_mono16(struct imp_camera *cam) {
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO16));
        CHECK_OK(imp_camera_set_exposure_us(cam, 12345));
        struct imp_camera_info info;
        CHECK_OK(imp_camera_get_info(cam, &info));
        CHECK_INT_EQ(info.pixel_format, IMP_PIXEL_MONO16);
        CHECK_NEAR(info.exposure_us, 12345, 0.5);
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4, .software_trigger = true }));
        const struct imp_frame *f;
        /* No trigger, no frame. */
        CHECK_ERR(imp_camera_grab(cam, 300, &f), -ETIMEDOUT);
        for (int i = 0; i < 5; i++) {
                imp_emu_rig_set_light(rig, 6, 0);
                imp_emu_rig_set_light(rig, (unsigned) i, 1000);
                CHECK_OK(imp_camera_trigger_software(cam));
                int r = imp_camera_grab(cam, 2000, &f);
                CHECK_OK(r);
                if (r == 0)
                        check_frame(f, IMP_PIXEL_MONO16, 12345);
                imp_emu_rig_set_light(rig, (unsigned) i, 0);
        }
        CHECK_INT_EQ(f->meta.n_missing_packets, 0);
        CHECK_OK(imp_camera_stop(cam));
        CHECK_ERR(imp_camera_grab(cam, 10, &f), -ENOTCONN);
}

int main(void) {
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *r = NULL;
        _cleanup_(imp_emu_gige_freep) struct imp_emu_gige *emu = NULL;
        if (gige_emu_setup(ADDRESS, SERIAL, 8, &r, &emu) < 0)
                return TEST_DONE();
        rig = r;
        imp_emu_rig_set_light(rig, 2, 1000);
        imp_emu_rig_set_pattern(rig, 5);

        CHECK_ERR(imp_camera_open("nonesuch", ADDRESS, 1000, &(struct imp_camera *){ NULL }), -ENOENT);
        _cleanup_(imp_camera_closep) struct imp_camera *cam = NULL;
        CHECK_OK(imp_camera_open("aravis", ADDRESS, 3000, &cam));
        if (!cam)
                return TEST_DONE();
        struct imp_camera_info info;
        CHECK_OK(imp_camera_get_info(cam, &info));
        CHECK_STR_EQ(info.serial, SERIAL);
        CHECK(info.pixel_formats & IMP_PIXEL_BIT(IMP_PIXEL_MONO8));
        CHECK(info.pixel_formats & IMP_PIXEL_BIT(IMP_PIXEL_MONO16));
        /* The fake camera offers no Mono12. */
        CHECK(!(info.pixel_formats & IMP_PIXEL_BIT(IMP_PIXEL_MONO12)));
        CHECK_ERR(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO12), -EOPNOTSUPP);
        CHECK_ERR(imp_camera_set_roi(cam, info.sensor_width, 0, 16, 16), -EINVAL);
        CHECK_ERR(imp_camera_grab(cam, 10, &(const struct imp_frame *){ NULL }), -ENOTCONN);
        CHECK_OK(imp_camera_set_roi(cam, 0, 0, WIDTH, HEIGHT));

        test_continuous_mono8(cam);
        test_triggered_mono16(cam);
        CHECK(imp_emu_gige_frames_filled(emu) >= N_CONTINUOUS + 5);
        return TEST_DONE();
}
