/* Argument helpers the calibrate subcommands share (calibrate-args.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "calibrate-args.h"
#include "log.h"

int imp_cli_parse_list(const char *opt, const char *s, double *v, int min_n, int max_n, int *ret_n) {
        int n = 0;
        const char *p = s;
        while (*p && n < max_n) {
                char *end;
                v[n] = strtod(p, &end);
                if (end == p || !isfinite(v[n]))
                        break;
                n++;
                p = end;
                if (*p == ',')
                        p++;
                else
                        break;
        }
        if (*p || n < min_n) {
                log_error("%s: expected %d to %d numbers separated by commas, got '%s'", opt, min_n, max_n, s);
                return -EINVAL;
        }
        *ret_n = n;
        return 0;
}

int imp_cli_camera_index(const struct imp_rig *rig, const char *name) {
        if (!name)
                return rig->n_cameras > 0 ? 0 : -ENOENT;
        for (int i = 0; i < rig->n_cameras; i++)
                if (!strcmp(rig->cameras[i].name, name))
                        return i;
        return -ENOENT;
}
