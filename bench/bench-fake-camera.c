/* Aravis's fake GigE Vision camera (the same ArvGvFakeCamera as arv-fake-gv-camera-0.8) with
 * a settable software-trigger polling rate. In TriggerMode=On the fake camera looks for a
 * TriggerSoftware command only once per 1/trigger_frequency, 25 Hz unless told otherwise: a
 * client triggering every frame can never get more than 25 frames/s out of
 * arv-fake-gv-camera-0.8, however fast it is. bench/bench-capture-daemon.sh -c fast runs this
 * instead, so that a triggered capture is limited by the client and not by that poll; free
 * running (TriggerMode=Off) it behaves exactly as arv-fake-gv-camera-0.8.
 *
 * Usage: bench-fake-camera [-i ADDRESS] [-s SERIAL] [-t TRIGGER_HZ]; runs until SIGTERM/SIGINT. */
#include <arv.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

int main(int argc, char **argv) {
        const char *address = "127.0.0.1", *serial = "BENCHFAST";
        double trigger_hz = 1000.0;
        int opt;
        while ((opt = getopt(argc, argv, "i:s:t:")) != -1) {
                switch (opt) {
                case 'i': address = optarg; break;
                case 's': serial = optarg; break;
                case 't': trigger_hz = strtod(optarg, NULL); break;
                default:
                        fprintf(stderr, "usage: %s [-i ADDRESS] [-s SERIAL] [-t TRIGGER_HZ]\n", argv[0]);
                        return 2;
                }
        }
        if (!(trigger_hz > 0.0 && trigger_hz <= 100000.0)) {
                fprintf(stderr, "bench-fake-camera: -t: expected 0 < Hz <= 100000\n");
                return 2;
        }
        sigset_t set;
        sigemptyset(&set);
        sigaddset(&set, SIGTERM);
        sigaddset(&set, SIGINT);
        pthread_sigmask(SIG_BLOCK, &set, NULL);         /* before the camera's thread starts */
        ArvGvFakeCamera *gv = arv_gv_fake_camera_new(address, serial);
        if (!gv || !arv_gv_fake_camera_is_running(gv)) {
                fprintf(stderr, "bench-fake-camera: cannot listen on %s:3956\n", address);
                g_clear_object(&gv);
                return 1;
        }
        arv_fake_camera_set_trigger_frequency(arv_gv_fake_camera_get_fake_camera(gv), trigger_hz);
        fprintf(stderr, "bench-fake-camera: %s on %s, software trigger polled at %g Hz\n", serial, address,
                trigger_hz);
        int sig = 0;
        sigwait(&set, &sig);
        g_object_unref(gv);
        return 0;
}
