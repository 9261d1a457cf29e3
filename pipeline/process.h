/* The processing service's job: a capture set in, the digital copy out (see process.c).
 * Used by `impasto process` and by impasto-worker. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include "error.h"

struct imp_process_options {
        double pitch_mm;              /* heightfield grid pitch; <= 0: camera footprint */
        int cell_px;                  /* relief box cell size n; <= 0: default 20 */
        double delta_frac;            /* δ0 as a fraction of the max height; <= 0: 0.3 */
        bool btf;                     /* fit the BTF when the set holds a dome sweep */
        /* Progress per stage (may be NULL); called from the calling thread. */
        void (*progress)(void *userdata, const char *stage, size_t done, size_t total);
        void *userdata;
};

void imp_process_options_default(struct imp_process_options *o);
/* Writes COPY_DIR/{heightfield.exr, boxes.json, rho_d.exr, rho_s.exr, lobe.exr, copy.json,
 * previews/}. -EINVAL/-EBADMSG for a capture set that cannot be processed (message names
 * the file and what is wrong), other negative errnos for I/O and memory. */
int imp_process_capture(const char *capture_dir, const char *copy_dir,
                        const struct imp_process_options *o, struct imp_error *err);
