/* The one-lobe Lafortune BRDF of seed 000 eq. 1 (after McAllister et al.), shared by the
 * simulator (truth) and the fit (estimate), so both mean the same numbers:
 *
 *   f(v, l) = ρd + ρs · max(0, Cx vx lx + Cy vy ly + Cz vz lz)^k
 *
 * with v, l unit vectors in the texel's local frame (z = surface normal, x = the canvas x
 * axis projected on the tangent plane). impasto's radiometric convention (ARCHITECTURE.md):
 * 1.0 is a white Lambertian reference under the light's calibrated irradiance, so a
 * measured value is  V = E · cos θl · f(v, l)  with E the irradiance at normal incidence;
 * ρd is then the albedo (white = 1) — this f is π times the physical BRDF. */
#pragma once
#include <math.h>

struct imp_lafortune {
        float rho_d[3];               /* diffuse albedo, RGB, >= 0 */
        float rho_s[3];               /* specular scale, RGB, >= 0 */
        float cx, cy, cz;             /* lobe axes weights: mirror-like lobe is (-1, -1, 1) */
        float k;                      /* lobe exponent, >= 0 */
};

/* The lobe term max(0, C·(v⊙l))^k; 0 for a back-facing configuration. */
static inline double imp_lafortune_lobe(const struct imp_lafortune *b, const double v[3],
                                        const double l[3]) {
        double d = b->cx * v[0] * l[0] + b->cy * v[1] * l[1] + b->cz * v[2] * l[2];
        if (d <= 0.0)
                return 0.0;
        return pow(d, b->k);
}

/* f(v, l) for channel c (0..2). Returns 0 when v or l is below the surface. */
static inline double imp_lafortune_eval(const struct imp_lafortune *b, int c, const double v[3],
                                        const double l[3]) {
        if (v[2] <= 0.0 || l[2] <= 0.0)
                return 0.0;
        return b->rho_d[c] + b->rho_s[c] * imp_lafortune_lobe(b, v, l);
}

/* Local frame of a unit normal n: t along world x projected, b = n × t. Falls back to
 * world y when n is (nearly) along x. */
static inline void imp_local_frame(const double n[3], double t[3], double b[3]) {
        double ax[3] = { 1, 0, 0 };
        if (fabs(n[0]) > 0.99) { ax[0] = 0; ax[1] = 1; }
        double d = ax[0] * n[0] + ax[1] * n[1] + ax[2] * n[2];
        for (int i = 0; i < 3; i++) t[i] = ax[i] - d * n[i];
        double len = sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
        for (int i = 0; i < 3; i++) t[i] /= len;
        b[0] = n[1] * t[2] - n[2] * t[1];
        b[1] = n[2] * t[0] - n[0] * t[2];
        b[2] = n[0] * t[1] - n[1] * t[0];
}

/* World direction w → local coordinates in the frame (t, b, n). */
static inline void imp_to_local(const double t[3], const double b[3], const double n[3],
                                const double w[3], double ret[3]) {
        ret[0] = t[0] * w[0] + t[1] * w[1] + t[2] * w[2];
        ret[1] = b[0] * w[0] + b[1] * w[1] + b[2] * w[2];
        ret[2] = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
}
