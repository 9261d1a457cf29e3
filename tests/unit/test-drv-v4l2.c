/* The "v4l2" camera backend (kernel V4L2 API) against an emulated /dev/video0 answered by a
 * umockdev ioctl handler (sim/emu/emu-v4l2.c): the mmap buffers cannot be mapped there, so
 * the backend falls back to user pointers (or to read()); GREY and Y16 negotiated; 20+
 * frames byte-equal to the fill with rising sequence numbers and timestamps; exposure in
 * the frame; a dropped frame counted, EIO naming the device, unplugging → -ENODEV and the
 * camera left stopped. Needs the umockdev preload: without it the test re-executes itself
 * under umockdev-wrapper, and skips (77) when that is not installed. */
#include <linux/videodev2.h>
#include <unistd.h>
#include "camera.h"
#include "emu.h"
#include "unit/test.h"

#ifndef IMP_CAMERA_HAVE_LAST_ERROR
int main(void) {
        TEST_SKIP("the camera wrapper has no imp_camera_last_error() and no v4l2 entry yet");
}
#else

#define WIDTH 160
#define HEIGHT 120
#define N_FRAMES 24
#define DEVNODE "/dev/video0"

static struct imp_emu_rig *rig;
static uint8_t expected[WIDTH * HEIGHT * 2];

static void reexec_under_umockdev(char **argv) {
        if (imp_emu_gpio_available())
                return;
        if (getenv("IMPASTO_UMOCKDEV_REEXEC"))
                TEST_SKIP("umockdev preload not active even under umockdev-wrapper");
        setenv("IMPASTO_UMOCKDEV_REEXEC", "1", 1);
        /* Under ASan the preload comes before the ASan runtime; the test runs clean anyway. */
        char asan[512];
        const char *old = getenv("ASAN_OPTIONS");
        snprintf(asan, sizeof asan, "%s%sverify_asan_link_order=0", old ? old : "", old && *old ? ":" : "");
        setenv("ASAN_OPTIONS", asan, 1);
        char *args[] = { "umockdev-wrapper", argv[0], NULL };
        execvp(args[0], args);
        TEST_SKIP("umockdev-wrapper not found (%m): cannot emulate " DEVNODE);
}

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
        uint32_t exp_us = 0;
        CHECK_OK(imp_emu_decode_default(f->data, WIDTH, HEIGHT, bpp, NULL, NULL, &exp_us));
        CHECK_INT_EQ(exp_us, exposure_us);
}

static struct imp_camera *open_camera(const char *address) {
        struct imp_camera *cam = NULL;
        int r = imp_camera_open("v4l2", address, 1000, &cam);
        CHECK_OK(r);
        return r < 0 ? NULL : cam;
}

/* N frames in a row: byte-equal, sequence +1 each, timestamps rising. */
static void stream_frames(struct imp_camera *cam, enum imp_pixel_format fmt, uint32_t exposure_us, int n) {
        const struct imp_frame *f;
        uint64_t last_id = 0, last_ts = 0;
        for (int i = 0; i < n; i++) {
                int r = imp_camera_grab(cam, 2000, &f);
                CHECK_OK(r);
                if (r < 0) {
                        fprintf(stderr, "  %s\n", imp_camera_last_error(cam));
                        return;
                }
                check_frame(f, fmt, exposure_us);
                if (i > 0) {
                        CHECK_INT_EQ(f->meta.frame_id, last_id + 1);
                        CHECK_MSG(f->meta.timestamp_ns > last_ts, "timestamp %" PRIu64 " after %" PRIu64,
                                  f->meta.timestamp_ns, last_ts);
                }
                last_id = f->meta.frame_id;
                last_ts = f->meta.timestamp_ns;
                CHECK_INT_EQ(f->meta.n_underruns, 0);
                CHECK(f->meta.system_timestamp_ns > 0);
        }
}

static void test_formats_and_stream(struct imp_emu_v4l2 *emu) {
        _cleanup_(imp_camera_closep) struct imp_camera *cam = open_camera(DEVNODE);
        if (!cam)
                return;
        struct imp_camera_info info;
        CHECK_OK(imp_camera_get_info(cam, &info));
        CHECK_STR_EQ(info.vendor, "impasto-emu");
        CHECK_STR_EQ(info.model, "impasto emulated camera");
        CHECK_INT_EQ(info.width, WIDTH);
        CHECK_INT_EQ(info.height, HEIGHT);
        CHECK_INT_EQ(info.pixel_formats, IMP_PIXEL_BIT(IMP_PIXEL_MONO8) | IMP_PIXEL_BIT(IMP_PIXEL_MONO16));
        CHECK_ERR(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO12), -EOPNOTSUPP);
        CHECK_ERR(imp_camera_set_roi(cam, 0, 0, 16, 16), -EOPNOTSUPP);
        CHECK_ERR(imp_camera_set_exposure_us(cam, 20e6), -EINVAL);      /* range is 100 µs..10 s */

        /* GREY: mmap requested and refused by mmap(), so user pointers. */
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO8));
        CHECK_OK(imp_camera_set_exposure_us(cam, 4000));
        CHECK_OK(imp_camera_get_info(cam, &info));
        CHECK_INT_EQ(info.pixel_format, IMP_PIXEL_MONO8);
        CHECK_NEAR(info.exposure_us, 4000, 0);
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4 }));
        CHECK_INT_EQ(imp_emu_v4l2_memory(emu), V4L2_MEMORY_USERPTR);
        CHECK(imp_emu_v4l2_streaming(emu));
        CHECK_ERR(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO16), -EBUSY);
        stream_frames(cam, IMP_PIXEL_MONO8, 4000, N_FRAMES);

        /* Exposure changed while streaming shows in the next frames; so does the scene. */
        CHECK_OK(imp_camera_set_exposure_us(cam, 12340));      /* 100 µs units: 12300 */
        imp_emu_rig_set_light(rig, 2, 0);
        imp_emu_rig_set_light(rig, 5, 1000);
        const struct imp_frame *f;
        int seen = 0;
        for (int i = 0; i < 8 && !seen; i++) {
                if (imp_camera_grab(cam, 2000, &f) < 0)
                        break;
                uint32_t exp_us = 0;
                int light = -9;
                if (imp_emu_decode_default(f->data, WIDTH, HEIGHT, 1, &light, NULL, &exp_us) == 0 &&
                    exp_us == 12300 && light == 5)
                        seen = 1;
        }
        CHECK_MSG(seen, "exposure 12300 µs / light 5 never showed in the frames");
        CHECK_OK(imp_camera_stop(cam));
        CHECK(!imp_emu_v4l2_streaming(emu));

        /* Y16, granted and reported. */
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO16));
        CHECK_OK(imp_camera_get_info(cam, &info));
        CHECK_INT_EQ(info.pixel_format, IMP_PIXEL_MONO16);
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 3 }));
        stream_frames(cam, IMP_PIXEL_MONO16, 12300, N_FRAMES);

        /* Nothing due: the deadline holds. */
        imp_emu_v4l2_pause(emu, true);
        CHECK_ERR(imp_camera_grab(cam, 50, &f), -ETIMEDOUT);
        imp_emu_v4l2_pause(emu, false);
        CHECK_OK(imp_camera_stop(cam));
        CHECK_ERR(imp_camera_start(cam, &(struct imp_camera_acq) { .software_trigger = true }), -EOPNOTSUPP);
}

static void test_faults(struct imp_emu_v4l2 *emu) {
        _cleanup_(imp_camera_closep) struct imp_camera *cam = open_camera("video0;io=userptr");
        if (!cam)
                return;
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO8));
        CHECK_OK(imp_camera_set_exposure_us(cam, 4000));
        CHECK_OK(imp_camera_start(cam, NULL));
        const struct imp_frame *f;
        CHECK_OK(imp_camera_grab(cam, 2000, &f));
        uint64_t id0 = f->meta.frame_id;

        /* Dropped frame: a gap in the sequence, counted as an underrun. */
        imp_emu_v4l2_drop_nth(emu, 2);
        CHECK_OK(imp_camera_grab(cam, 2000, &f));
        CHECK_INT_EQ(f->meta.frame_id, id0 + 1);
        CHECK_OK(imp_camera_grab(cam, 2000, &f));
        CHECK_INT_EQ(f->meta.frame_id, id0 + 3);
        CHECK_INT_EQ(f->meta.n_underruns, 1);
        check_frame(f, IMP_PIXEL_MONO8, 4000);

        /* EIO on a DQBUF: the error names the device and the call; the stream goes on. */
        imp_emu_v4l2_fail_dqbuf_nth(emu, 1, EIO);
        CHECK_ERR(imp_camera_grab(cam, 2000, &f), -EIO);
        CHECK_STR_CONTAINS(imp_camera_last_error(cam), DEVNODE ": VIDIOC_DQBUF");
        CHECK_OK(imp_camera_grab(cam, 2000, &f));
        CHECK_INT_EQ(f->meta.frame_id, id0 + 4);

        /* Unplugged: -ENODEV, and the camera is left stopped. */
        imp_emu_v4l2_disconnect(emu);
        CHECK_ERR(imp_camera_grab(cam, 2000, &f), -ENODEV);
        CHECK_STR_CONTAINS(imp_camera_last_error(cam), DEVNODE);
        CHECK_ERR(imp_camera_grab(cam, 10, &f), -ENOTCONN);
        CHECK_OK(imp_camera_stop(cam));
        struct imp_camera *again = NULL;
        CHECK_ERR(imp_camera_open("v4l2", DEVNODE, 100, &again), -ENODEV);
        CHECK(again == NULL);
}

/* A device whose buffers can be neither mapped nor user pointers: read() I/O. Its own
 * testbed, gone before the next one (one umockdev testbed per process at a time). */
static void test_read_io(void) {
        _cleanup_(imp_emu_v4l2_freep) struct imp_emu_v4l2 *emu = NULL;
        struct imp_emu_v4l2_config cfg = { .width = WIDTH, .height = HEIGHT,
                                           .no_userptr = true, .frame_interval_us = 2000 };
        CHECK_OK(imp_emu_v4l2_new(&cfg, rig, NULL, NULL, &emu));
        if (!emu)
                return;
        _cleanup_(imp_camera_closep) struct imp_camera *cam = open_camera(DEVNODE);
        if (!cam)
                return;
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO16));
        CHECK_OK(imp_camera_set_exposure_us(cam, 2500));
        CHECK_OK(imp_camera_start(cam, NULL));
        const struct imp_frame *f;
        for (int i = 0; i < 5; i++) {
                int r = imp_camera_grab(cam, 2000, &f);
                CHECK_OK(r);
                if (r < 0) {
                        fprintf(stderr, "  %s\n", imp_camera_last_error(cam));
                        break;
                }
                check_frame(f, IMP_PIXEL_MONO16, 2500);
                CHECK_INT_EQ(f->meta.frame_id, (uint64_t) i);
        }
        CHECK_INT_EQ(imp_emu_v4l2_memory(emu), 0);     /* frames came by read() */
        CHECK_OK(imp_camera_stop(cam));
}

int main(int argc, char **argv) {
        reexec_under_umockdev(argv);
        if (!imp_camera_backend("v4l2"))
                TEST_SKIP("the v4l2 backend is not built");
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *r = NULL;
        CHECK_OK(imp_emu_rig_new(8, &r));
        rig = r;
        imp_emu_rig_set_light(rig, 2, 1000);
        imp_emu_rig_set_pattern(rig, 3);
        test_read_io();
        _cleanup_(imp_emu_v4l2_freep) struct imp_emu_v4l2 *emu = NULL;
        struct imp_emu_v4l2_config cfg = { .width = WIDTH, .height = HEIGHT, .frame_interval_us = 1000 };
        CHECK_OK(imp_emu_v4l2_new(&cfg, rig, NULL, NULL, &emu));
        if (!emu)
                return TEST_DONE();
        CHECK_STR_EQ(imp_emu_v4l2_devnode(emu), DEVNODE);
        struct imp_camera *none = NULL;
        CHECK_ERR(imp_camera_open("v4l2", "/dev/video7", 100, &none), -ENODEV);
        test_formats_and_stream(emu);
        test_faults(emu);
        return TEST_DONE();
}
#endif
