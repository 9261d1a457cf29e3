/* Argument helpers the calibrate subcommands share. */
#pragma once
#include "rig.h"

/* "A,B,C": between min_n and max_n finite numbers separated by commas into v; the count in
 * *ret_n. Logs the error naming opt and returns -EINVAL otherwise. */
int imp_cli_parse_list(const char *opt, const char *s, double *v, int min_n, int max_n, int *ret_n);

/* Index of the camera called name in rig (NULL: the first camera); -ENOENT when none. */
int imp_cli_camera_index(const struct imp_rig *rig, const char *name);
