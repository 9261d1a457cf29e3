/* `impasto calibrate start|list|show` (cli/calibrate-remote.c): calibrations run by impastod.
 * argv[0] is the verb; the return value is the client's exit code (proto/PROTOCOL.md §9). */
#pragma once

int imp_calibrate_remote_main(int argc, char **argv);
