/* Interreflection for the simulator through irradiance-vector grids (seed 002): six
 * directional irradiance vectors (±x, ±y, ±z) per grid vertex, a 2D grid over the canvas
 * and a 3D grid around the frame, precomputed by path tracing on simplified geometry for
 * one light, invalid vertices filled from valid neighbours; at a point with normal n:
 *   I_n = I_x n_x² + I_y n_y² + I_z n_z²   with I_x = I_{+x} if n_x >= 0 else I_{−x} (sign rule).
 * Built only when a scene lists `indirect`. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "rig.h"
#include "surface.h"

struct imp_indirect;   /* opaque: the grids for one light */

struct imp_indirect_params {
        double canvas_pitch_mm;       /* 2D grid spacing over the canvas (e.g. 2 mm) */
        double frame_pitch_mm;        /* 3D grid spacing around the frame (e.g. 4 mm) */
        int paths_per_vertex;         /* per direction class; e.g. 64 */
        int max_bounces;              /* 1 = one indirect bounce */
        int simplify;                 /* heightfield decimation factor for path tracing */
        uint64_t seed;                /* deterministic: same seed, same grids */
};

/* Builds the grids for `light` over `surf`. Caller frees with imp_indirect_free().
 * Adds its work to cnt (grid_vertices, indirect_paths, random_draws). */
int imp_indirect_build(const struct imp_sim_surface *surf, const struct imp_rig_light *light,
                       const struct imp_indirect_params *p, struct imp_indirect **ret,
                       struct imp_sim_counters *cnt);
void imp_indirect_free(struct imp_indirect *g);
/* Indirect irradiance (RGB, same units as the direct E·cosθ term) arriving at world point
 * p on a surface with unit normal n; trilinear/bilinear interpolation of the vectors. */
void imp_indirect_eval(const struct imp_indirect *g, const double p_mm[3], const double n[3],
                       float ret_rgb[3], struct imp_sim_counters *cnt);
/* Reference: brute-force path-traced indirect irradiance at p, n (for tests). */
void imp_indirect_reference(const struct imp_sim_surface *surf, const struct imp_rig_light *light,
                            const double p_mm[3], const double n[3], int paths, uint64_t seed,
                            float ret_rgb[3]);
