/* A controller dies while its camera acquires (SIGKILL: no AcquisitionStop, no release of the
 * control channel); another process opens the camera once the heartbeat expired, is slow
 * between open and start (a loaded host), starts in software-trigger mode and must get its
 * frames, byte-equal to the emulator's fill. Aravis' fake camera, once the new controller
 * holds the channel, goes on acquiring and streams to the dead controller's port unless the
 * new one stops the acquisition before it starts its own: impastod's resume after a SIGKILL
 * timed out on every grab that way. */
#include <errno.h>
#include <signal.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "camera.h"
#include "emu.h"
#include "unit/gige-emu-setup.h"
#include "unit/test.h"

#define ADDRESS "127.0.0.1"
#define SERIAL "IMP-TAKEOVER-01"
#define WIDTH 256
#define HEIGHT 192
#define EXPOSURE_US 3000
#define GRAB_TIMEOUT_MS 2000
/* the fake camera's heartbeat timeout is 3 s (GevHeartbeatTimeout's default there) */
#define HEARTBEAT_WAIT_US 3600000
/* the new controller's pause between open and start: the fake camera takes up its stale
 * acquisition within 100 ms */
#define SLOW_HOST_US 400000

static struct imp_camera *open_started(bool slow) {
        struct imp_camera *cam = NULL;
        CHECK_OK(imp_camera_open("aravis", ADDRESS, 3000, &cam));
        if (!cam)
                return NULL;
        if (slow)
                usleep(SLOW_HOST_US);
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO8));
        CHECK_OK(imp_camera_set_exposure_us(cam, EXPOSURE_US));
        CHECK_OK(imp_camera_set_roi(cam, 0, 0, WIDTH, HEIGHT));
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4, .software_trigger = true }));
        return cam;
}

static int grab_one(struct imp_camera *cam, const struct imp_frame **f) {
        int r = imp_camera_trigger_software(cam);
        return r < 0 ? r : imp_camera_grab(cam, GRAB_TIMEOUT_MS, f);
}

/* The controller that dies: started, one frame, then SIGKILL by its own hand. */
static int dying_controller(void) {
        struct imp_camera *cam = open_started(false);
        const struct imp_frame *f = NULL;
        if (!cam || grab_one(cam, &f) < 0)
                return 3;
        raise(SIGKILL);
        return 4;
}

int main(int argc, char **argv) {
        if (argc > 1 && !strcmp(argv[1], "--dying-controller"))
                return dying_controller();
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        _cleanup_(imp_emu_gige_freep) struct imp_emu_gige *emu = NULL;
        if (gige_emu_setup(ADDRESS, SERIAL, 8, &rig, &emu) < 0)
                return TEST_DONE();
        imp_emu_rig_set_light(rig, 2, 1000);

        /* a process of its own (a fresh exec, not a fork of this threaded one) */
        pid_t pid = fork();
        if (pid == 0) {
                execl("/proc/self/exe", argv[0], "--dying-controller", (char *) NULL);
                _exit(5);
        }
        CHECK(pid > 0);
        int st = 0;
        CHECK(waitpid(pid, &st, 0) == pid);
        CHECK_MSG(WIFSIGNALED(st) && WTERMSIG(st) == SIGKILL, "the first controller did not get its frame "
                  "and die (status %d)", st);
        /* At once the dead controller still holds the channel: a start is refused as busy
         * (impastod's `devices` says so and to probe again), not as an I/O error. */
        struct imp_camera *early = NULL;
        CHECK_OK(imp_camera_open("aravis", ADDRESS, 3000, &early));
        if (early) {
                int r = imp_camera_start(early, &(struct imp_camera_acq) { .n_buffers = 4, .software_trigger = true });
                CHECK_MSG(r == -EBUSY, "start while the dead controller holds the camera: %d (%s), not -EBUSY", r,
                          strerror(r < 0 ? -r : r));
                imp_camera_close(early);
        }
        usleep(HEARTBEAT_WAIT_US);

        struct imp_camera *cam = open_started(true);
        if (!cam)
                return TEST_DONE();
        uint8_t expected[WIDTH * HEIGHT];
        struct imp_emu_camera_state cs = { .exposure_us = EXPOSURE_US, .lit_light = imp_emu_rig_lit_light(rig),
                                           .pattern = imp_emu_rig_get_pattern(rig) };
        CHECK_OK(imp_emu_fill_default(NULL, &cs, expected, WIDTH, HEIGHT, 1));
        for (int i = 0; i < 3; i++) {
                const struct imp_frame *f = NULL;
                int r = grab_one(cam, &f);
                CHECK_MSG(r == 0, "frame %d after the takeover: %s (%s)", i, strerror(r < 0 ? -r : r),
                          imp_camera_last_error(cam));
                if (r < 0)
                        break;
                CHECK_INT_EQ(f->size, sizeof expected);
                CHECK_MSG(f->size == sizeof expected && !memcmp(f->data, expected, sizeof expected),
                          "frame %d after the takeover differs from the fill", i);
        }
        CHECK_OK(imp_camera_stop(cam));
        imp_camera_close(cam);
        return TEST_DONE();
}
