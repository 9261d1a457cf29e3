/* The "libcamera" camera backend where libcamera sees no camera: opening any camera answers
 * -ENODEV (the shim builds and runs; there is no libcamera emulator to go further). Skips
 * (77) when libcamera's camera manager cannot start here, or when real cameras are present. */
#include "camera.h"
#include "camera-libcamera.h"
#include "unit/test.h"

int main(void) {
#ifndef IMP_CAMERA_HAVE_LAST_ERROR
        TEST_SKIP("the camera wrapper has no libcamera entry yet");
#endif
        unsigned n = 0;
        int r = imp_camera_libcamera_probe(&n);
        if (r < 0)
                TEST_SKIP("libcamera's camera manager cannot start here: %s", strerror(-r));
        if (n > 0)
                TEST_SKIP("libcamera sees %u real camera(s); this test wants none", n);
        CHECK(imp_camera_backend("libcamera") != NULL);
        struct imp_camera *cam = NULL;
        CHECK_ERR(imp_camera_open("libcamera", "*", 1000, &cam), -ENODEV);
        CHECK_ERR(imp_camera_open("libcamera", "/base/soc/i2c0mux/i2c@1/imx477@1a", 1000, &cam), -ENODEV);
        CHECK_ERR(imp_camera_open("libcamera", "", 1000, &cam), -EINVAL);
        CHECK(cam == NULL);
        /* The manager is shared and released with the last camera: a second probe works. */
        CHECK_OK(imp_camera_libcamera_probe(&n));
        CHECK_INT_EQ(n, 0);
        return TEST_DONE();
}
