/* Synthetic ground truth for the BTF tests and the benchmark: a near-field light dome, a
 * look-at pinhole camera, analytic radiance samples of a texel with a known Lafortune
 * BRDF, and frames of a flat canvas rendered pixel by pixel (no distortion). */
#pragma once
#include <math.h>
#include <stdint.h>
#include <string.h>

#include "btf.h"

#define SYNTH_DEG (M_PI / 180.0)

/* Deterministic normal noise (xorshift64* + Box–Muller). */
static inline double synth_uniform(uint64_t *s) {
        *s ^= *s >> 12;
        *s ^= *s << 25;
        *s ^= *s >> 27;
        return ((*s * 2685821657736338717ULL) >> 11) * (1.0 / 9007199254740992.0);
}
static inline double synth_gauss(uint64_t *s) {
        double u = synth_uniform(s), v = synth_uniform(s);
        return sqrt(-2.0 * log(u + 1e-300)) * cos(2.0 * M_PI * v);
}

/* Rings of lights at the given elevations (degrees) on a sphere of radius_mm around
 * centre, per_ring lights each (azimuths offset by half a step on odd rings), pointing at
 * the centre. Returns the count written. */
static inline int synth_dome(struct imp_rig_light *L, const double *elev_deg, int n_rings, int per_ring,
                             double radius_mm, const double centre[3], double intensity, double profile_exp) {
        int n = 0;
        for (int r = 0; r < n_rings; r++)
                for (int i = 0; i < per_ring; i++) {
                        double az = (i + 0.5 * (r & 1)) * 2.0 * M_PI / per_ring, el = elev_deg[r] * SYNTH_DEG;
                        struct imp_rig_light *l = &L[n];
                        memset(l, 0, sizeof *l);
                        l->id = n;
                        l->pos_mm[0] = centre[0] + radius_mm * cos(el) * cos(az);
                        l->pos_mm[1] = centre[1] + radius_mm * cos(el) * sin(az);
                        l->pos_mm[2] = centre[2] + radius_mm * sin(el);
                        for (int k = 0; k < 3; k++) {
                                l->axis[k] = (centre[k] - l->pos_mm[k]) / radius_mm;
                                l->colour[k] = 1.0;
                        }
                        l->intensity = intensity;
                        l->profile_exp = profile_exp;
                        n++;
                }
        return n;
}

/* A pinhole at eye looking at target, image x along world +x projected (no distortion). */
static inline void synth_camera(struct imp_pinhole *m, const double eye[3], const double target[3],
                                int width, int height, double f_px) {
        memset(m, 0, sizeof *m);
        m->width = width;
        m->height = height;
        m->fx = m->fy = f_px;
        m->cx = 0.5 * (width - 1);
        m->cy = 0.5 * (height - 1);
        double z[3], x[3] = { 1, 0, 0 }, y[3], n = 0.0;
        for (int i = 0; i < 3; i++) {
                z[i] = target[i] - eye[i];
                n += z[i] * z[i];
        }
        for (int i = 0; i < 3; i++)
                z[i] /= sqrt(n);
        if (fabs(z[0]) > 0.99) { x[0] = 0; x[1] = 1; }
        double d = x[0] * z[0] + x[1] * z[1] + x[2] * z[2];
        n = 0.0;
        for (int i = 0; i < 3; i++) {
                x[i] -= d * z[i];
                n += x[i] * x[i];
        }
        for (int i = 0; i < 3; i++)
                x[i] /= sqrt(n);
        y[0] = z[1] * x[2] - z[2] * x[1];
        y[1] = z[2] * x[0] - z[0] * x[2];
        y[2] = z[0] * x[1] - z[1] * x[0];
        for (int i = 0; i < 3; i++) {
                m->R[i] = x[i];
                m->R[3 + i] = y[i];
                m->R[6 + i] = z[i];
        }
        for (int i = 0; i < 3; i++)
                m->t[i] = -(m->R[3 * i] * eye[0] + m->R[3 * i + 1] * eye[1] + m->R[3 * i + 2] * eye[2]);
}

/* Local view/light directions and E·cos θl of texel (P, n) for a camera at eye and a light;
 * false when the light or the camera is below the tangent plane. */
static inline bool synth_geometry(const double P[3], const double n[3], const double eye[3],
                                  const struct imp_rig_light *L, double v[3], double l[3], double *e_cos) {
        double t[3], b[3], wv[3], wl[3], nv = 0.0, nl = 0.0;
        imp_local_frame(n, t, b);
        for (int i = 0; i < 3; i++) {
                wv[i] = eye[i] - P[i];
                wl[i] = L->pos_mm[i] - P[i];
                nv += wv[i] * wv[i];
                nl += wl[i] * wl[i];
        }
        for (int i = 0; i < 3; i++) {
                wv[i] /= sqrt(nv);
                wl[i] /= sqrt(nl);
        }
        imp_to_local(t, b, n, wv, v);
        imp_to_local(t, b, n, wl, l);
        *e_cos = imp_btf_light_irradiance(L, P) * l[2];
        return v[2] > 0.0 && l[2] > 0.0;
}

/* Radiance samples of a texel at canvas point P (canvas = world), normal n, seen from eye,
 * with relative Gaussian noise noise_rel (σ = noise_rel · V). Returns the count. */
static inline int synth_samples(const double P[3], const double n[3], const double eye[3],
                                const struct imp_rig_light *L, int n_lights, const struct imp_lafortune *brdf,
                                double noise_rel, uint64_t *rng, struct imp_btf_sample *out) {
        int m = 0;
        for (int j = 0; j < n_lights; j++) {
                double v[3], l[3], ec;
                if (!synth_geometry(P, n, eye, &L[j], v, l, &ec) || !(l[2] >= 0.02))
                        continue;
                struct imp_btf_sample *s = &out[m++];
                for (int c = 0; c < 3; c++) {
                        double V = ec * imp_lafortune_eval(brdf, c, v, l);
                        s->value[c] = (float) (V * (1.0 + noise_rel * synth_gauss(rng)));
                        s->v[c] = (float) v[c];
                        s->l[c] = (float) l[c];
                }
                s->e_cos = (float) ec;
        }
        return m;
}

/* Renders frame j of a flat canvas at height z0 (canvas = world) with the BRDF given per
 * point by brdf_at(x, y, ctx); noise as above. frame: f32, 3 channels, camera size. */
typedef void (*synth_brdf_fn)(double x, double y, void *ctx, struct imp_lafortune *ret);
static inline void synth_render_flat(const struct imp_pinhole *m, const struct imp_rig_light *L, double z0,
                                     synth_brdf_fn brdf_at, void *ctx, double noise_rel, uint64_t *rng,
                                     struct imp_image *frame) {
        double eye[3], n[3] = { 0, 0, 1 };
        for (int i = 0; i < 3; i++)
                eye[i] = -(m->R[i] * m->t[0] + m->R[3 + i] * m->t[1] + m->R[6 + i] * m->t[2]);
        for (int py = 0; py < m->height; py++)
                for (int px = 0; px < m->width; px++) {
                        double dc[3] = { (px - m->cx) / m->fx, (py - m->cy) / m->fy, 1.0 }, dw[3];
                        for (int i = 0; i < 3; i++)
                                dw[i] = m->R[i] * dc[0] + m->R[3 + i] * dc[1] + m->R[6 + i] * dc[2];
                        float *q = imp_image_f32(frame, px, py);
                        q[0] = q[1] = q[2] = 0.0f;
                        if (!(dw[2] < 0.0))
                                continue;
                        double s = (z0 - eye[2]) / dw[2];
                        double P[3] = { eye[0] + s * dw[0], eye[1] + s * dw[1], z0 }, v[3], l[3], ec;
                        struct imp_lafortune b;
                        brdf_at(P[0], P[1], ctx, &b);
                        if (!synth_geometry(P, n, eye, L, v, l, &ec))
                                continue;
                        for (int c = 0; c < 3; c++) {
                                double V = ec * imp_lafortune_eval(&b, c, v, l);
                                q[c] = (float) (V * (1.0 + noise_rel * synth_gauss(rng)));
                        }
                }
}

/* Normalise a Lafortune lobe to max |C_i| = 1 (ρs scaled to match), as the fit reports. */
static inline void synth_normalise(struct imp_lafortune *b) {
        double m = fmax(fabs(b->cx), fmax(fabs(b->cy), fabs(b->cz)));
        double s = pow(m, b->k);
        b->cx /= m;
        b->cy /= m;
        b->cz /= m;
        for (int c = 0; c < 3; c++)
                b->rho_s[c] *= s;
}
