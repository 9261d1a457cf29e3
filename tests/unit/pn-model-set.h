/* A synthetic set of texels for the photometric texel model (bench-pn-model,
 * test-photometric-model): the demo rig's dome (56 lights in rings at 15°, 35°, 60° and 80°
 * elevation, 500 mm, camera 600 mm overhead), normals tilted up to 40°, matte and glossy
 * Lafortune paints with 1 % noise, and the cases that take the model's other branches:
 * an ambient term (inter-reflection), cast shadows (the shadow-trimmed mode of the
 * shadow-filled texels), dark paint, few lights. */
#pragma once
#include <string.h>
#include "btf-synth.h"
#include "pn-synth.h"

struct pn_set_texel {
        int n, filled;                /* sample count; filled: solve with the filled params */
        struct imp_btf_sample s[64];
};

static inline int pn_set_dome(struct imp_rig_light *L) {
        static const double elev[4] = { 15, 35, 60, 80 }, centre[3] = { 0, 0, 0 };
        static const int per_ring[4] = { 16, 16, 16, 8 };
        int n = 0;
        for (int r = 0; r < 4; r++)
                n += synth_dome(L + n, &elev[r], 1, per_ring[r], 500.0, centre, 1.0, 1.0);
        return n;
}

/* Texel i of the set (deterministic in seed and i). */
static inline void pn_set_texel(uint64_t seed, int i, const struct imp_rig_light *L, int nl,
                                struct pn_set_texel *t) {
        uint64_t rng = seed ^ (0x9e3779b97f4a7c15ULL * (uint64_t) (i + 1));
        static const double eye[3] = { 0, 0, 600 }, z[3] = { 0, 0, 1 };
        double P[3] = { 80 * (synth_uniform(&rng) - 0.5), 80 * (synth_uniform(&rng) - 0.5), 0 }, nt[3];
        tilt(z, 40.0 * pow(synth_uniform(&rng), 2), 2 * M_PI * synth_uniform(&rng), nt);
        double kind = synth_uniform(&rng), rd = 0.05 + 0.7 * synth_uniform(&rng);
        struct imp_lafortune b = { { (float) rd, (float) (0.9 * rd), (float) (0.8 * rd) }, { 0, 0, 0 },
                                   -1, -1, 1, 5 };
        if (kind < 0.35) {            /* glossy */
                float rs = (float) (0.05 + 0.3 * synth_uniform(&rng));
                b.rho_s[0] = b.rho_s[1] = b.rho_s[2] = rs;
                b.k = (float) (5 + 60 * synth_uniform(&rng));
                b.cx = b.cy = -1.0f, b.cz = 1.0f;
        }
        if (kind > 0.97)              /* dark paint */
                for (int c = 0; c < 3; c++)
                        b.rho_d[c] *= 0.02f;
        int use = kind > 0.95 && kind <= 0.97 ? 8 : nl;   /* few lights */
        t->n = synth_samples(P, nt, eye, L, use, &b, 0.01, &rng, t->s);
        t->filled = kind > 0.85 && kind <= 0.9;
        if (kind > 0.75 && kind <= 0.85) {   /* inter-reflection: light from everywhere */
                double mean = 0, add = 0.05 + 0.2 * synth_uniform(&rng);
                for (int k = 0; k < t->n; k++)
                        mean += t->s[k].value[1] / t->n;
                for (int k = 0; k < t->n; k++)
                        for (int c = 0; c < 3; c++)
                                t->s[k].value[c] += (float) (add * mean);
        }
        if (t->filled || (kind > 0.9 && kind <= 0.95)) {   /* a cast shadow over a sector */
                double az0 = 2 * M_PI * synth_uniform(&rng), w = 0.5 + 1.5 * synth_uniform(&rng);
                for (int k = 0; k < t->n; k++) {
                        double az = atan2(t->s[k].l[1], t->s[k].l[0]);
                        if (fabs(remainder(az - az0, 2 * M_PI)) < w / 2 && t->s[k].l[2] < 0.7)
                                for (int c = 0; c < 3; c++)
                                        t->s[k].value[c] *= 0.15f;
                }
        }
}

static inline void pn_set_filled_params(struct imp_photometric_params *p) {
        p->shadow_trim_sigma = p->filled_trim_sigma;
        if (p->passes < p->filled_passes)
                p->passes = p->filled_passes;
        p->max_dev_deg = p->filled_max_dev_deg;
}
