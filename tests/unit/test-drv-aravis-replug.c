/* An Aravis camera unplugged mid-stream and plugged back in: the emulated GigE camera on
 * 127.0.0.1 is destroyed while imp_camera_grab() waits for frames. The grab answers
 * -ENODEV naming the camera's address, after its timeout plus one control read; the
 * wrapper leaves the camera stopped (-ENOTCONN). After the replug the camera is opened
 * again and frames flow, byte-equal to the emulator's fill. */
#include <time.h>
#include "camera.h"
#include "emu.h"
#include "unit/gige-emu-setup.h"
#include "unit/test.h"

#define ADDRESS "127.0.0.1"
#define SERIAL "IMP-REPLUG-01"
#define WIDTH 256
#define HEIGHT 192
#define EXPOSURE_US 3000
#define GRAB_TIMEOUT_MS 1000
/* The probe is an Aravis GVCP register read, which gives up only after Aravis' own
 * timeouts and retries, queued behind its heartbeat: measured 9.6 s with Aravis 0.8.26 on
 * loopback. The grab adds that to its timeout before it answers -ENODEV (issue #6: a
 * probe with its own short deadline would bring it within the timeout). */
#define PROBE_MAX_S 14.0

static struct imp_emu_rig *rig;
static uint8_t expected[WIDTH * HEIGHT];

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (double) ts.tv_sec + ts.tv_nsec * 1e-9;
}

static struct imp_camera *open_and_start(void) {
        struct imp_camera *cam = NULL;
        CHECK_OK(imp_camera_open("aravis", ADDRESS, 3000, &cam));
        if (!cam)
                return NULL;
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO8));
        CHECK_OK(imp_camera_set_exposure_us(cam, EXPOSURE_US));
        CHECK_OK(imp_camera_set_roi(cam, 0, 0, WIDTH, HEIGHT));
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4 }));
        return cam;
}

/* n frames, each byte-equal to what the fill makes of the rig now. */
static void check_frames(struct imp_camera *cam, int n) {
        struct imp_emu_camera_state st = { .exposure_us = EXPOSURE_US,
                                           .lit_light = imp_emu_rig_lit_light(rig),
                                           .pattern = imp_emu_rig_get_pattern(rig) };
        CHECK_OK(imp_emu_fill_default(NULL, &st, expected, WIDTH, HEIGHT, 1));
        for (int i = 0; i < n; i++) {
                const struct imp_frame *f = NULL;
                int r = imp_camera_grab(cam, GRAB_TIMEOUT_MS, &f);
                CHECK_OK(r);
                if (r < 0) {
                        fprintf(stderr, "  grab %d: %s\n", i, imp_camera_last_error(cam));
                        return;
                }
                CHECK_INT_EQ(f->width, WIDTH);
                CHECK_INT_EQ(f->height, HEIGHT);
                CHECK_INT_EQ(f->size, sizeof expected);
                CHECK_MSG(memcmp(f->data, expected, sizeof expected) == 0,
                          "frame %" PRIu64 " differs from the fill", f->meta.frame_id);
        }
}

int main(void) {
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *r = NULL;
        _cleanup_(imp_emu_gige_freep) struct imp_emu_gige *emu = NULL;
        if (gige_emu_setup(ADDRESS, SERIAL, 8, &r, &emu) < 0)
                return TEST_DONE();
        rig = r;
        imp_emu_rig_set_light(rig, 3, 1000);
        imp_emu_rig_set_pattern(rig, 2);

        struct imp_camera *cam = open_and_start();
        if (!cam)
                return TEST_DONE();
        check_frames(cam, 5);

        /* Pulled out mid-stream. */
        CHECK_OK(imp_emu_gige_unplug(emu));
        CHECK_ERR(imp_emu_gige_unplug(emu), -EALREADY);
        const struct imp_frame *f = NULL;
        /* Frames already in the pool may still come; then nothing. */
        double t0 = now_s();
        int rc = 0;
        for (int i = 0; i < 8 && rc == 0; i++) {
                t0 = now_s();
                rc = imp_camera_grab(cam, GRAB_TIMEOUT_MS, &f);
        }
        double dt = now_s() - t0;
        fprintf(stderr, "unplugged: grab answered %d after %.2f s: %s\n", rc, dt, imp_camera_last_error(cam));
        CHECK_ERR(rc, -ENODEV);
        CHECK_LE(dt, GRAB_TIMEOUT_MS / 1000.0 + PROBE_MAX_S);
        CHECK_GE(dt, GRAB_TIMEOUT_MS / 1000.0 * 0.9);
        CHECK_STR_CONTAINS(imp_camera_last_error(cam), ADDRESS);
        CHECK_STR_CONTAINS(imp_camera_last_error(cam), "unplugged");
        /* The wrapper stopped it: no waiting on a dead device. */
        t0 = now_s();
        CHECK_ERR(imp_camera_grab(cam, GRAB_TIMEOUT_MS, &f), -ENOTCONN);
        CHECK_LE(now_s() - t0, 0.1);
        CHECK_OK(imp_camera_stop(cam));
        imp_camera_close(cam);
        /* Nothing is there to open meanwhile. */
        struct imp_camera *none = NULL;
        CHECK(imp_camera_open("aravis", ADDRESS, 1000, &none) < 0);
        CHECK(!none);

        /* Plugged back in: open again, frames flow, showing the scene as it is now. */
        uint64_t filled = imp_emu_gige_frames_filled(emu);
        CHECK_OK(imp_emu_gige_replug(emu));
        CHECK_ERR(imp_emu_gige_replug(emu), -EALREADY);
        imp_emu_rig_set_light(rig, 3, 0);
        imp_emu_rig_set_light(rig, 5, 1000);
        cam = open_and_start();
        if (!cam)
                return TEST_DONE();
        struct imp_camera_info info;
        CHECK_OK(imp_camera_get_info(cam, &info));
        CHECK_STR_EQ(info.serial, SERIAL);
        check_frames(cam, 10);
        CHECK(imp_emu_gige_frames_filled(emu) >= filled + 10);
        CHECK_OK(imp_camera_stop(cam));
        imp_camera_close(cam);
        return TEST_DONE();
}
