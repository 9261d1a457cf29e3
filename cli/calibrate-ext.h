/* `impasto calibrate lights` (cli/cmd-calibrate-lights.c) and `impasto calibrate radiometric`
 * (cli/cmd-calibrate-radiometric.c),
 * dispatched from cli/cmd-calibrate.c. argv[0] is the target name ("lights", …); the
 * return value is the process exit code (0, 1 failure, 2 usage, 3 bad input). */
#pragma once

int imp_calibrate_lights_main(int argc, char **argv);
int imp_calibrate_radiometric_main(int argc, char **argv);
/* `impasto calibrate camera` (cli/calibrate-camera.c). */
int imp_calibrate_camera_main(int argc, char **argv);
