/* Helpers shared by the photometric-normal tests: tilting a normal and the angle between
 * a texel's photometric normal (local frame of ng) and the truth. */
#pragma once
#include "btf-synth.h"
#include "photometric.h"

static inline void tilt(const double n0[3], double deg, double az, double ret[3]) {
        double t[3], b[3], th = deg * SYNTH_DEG;
        imp_local_frame(n0, t, b);
        for (int k = 0; k < 3; k++)
                ret[k] = cos(th) * n0[k] + sin(th) * (cos(az) * t[k] + sin(az) * b[k]);
}

/* Local photometric normal (frame of ng) → world; angle to nt in degrees. */
static inline double err_deg(const struct imp_pn_texel *r, const double ng[3], const double nt[3]) {
        double t[3], b[3], n[3], d = 0, len = 0;
        imp_local_frame(ng, t, b);
        for (int k = 0; k < 3; k++) {
                n[k] = r->n[0] * t[k] + r->n[1] * b[k] + r->n[2] * ng[k];
                len += n[k] * n[k];
        }
        for (int k = 0; k < 3; k++)
                d += n[k] * nt[k] / sqrt(len);
        return acos(fmin(1.0, d)) / SYNTH_DEG;
}

