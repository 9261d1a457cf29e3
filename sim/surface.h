/* What the simulator's effects see of a scene: the sampled painting surface (canvas and
 * frame as one heightfield over the world x–y plane) and the counters by which the
 * "an effect not listed costs nothing" promise is measured. */
#pragma once
#include <stdint.h>

struct imp_sim_surface {
        int nx, ny;                   /* samples along x and y */
        double pitch_mm;              /* sample spacing */
        double origin_mm[2];          /* world x, y of sample (0, 0) */
        const float *height_mm;       /* ny × nx heights (z), canvas and frame */
        const float *albedo;          /* ny × nx × 3 diffuse albedo ρd (for interreflection) */
        const uint8_t *is_frame;      /* ny × nx: 1 where the sample belongs to the frame */
        double canvas_min_mm[2];      /* canvas extent in world x, y (inside the frame) */
        double canvas_max_mm[2];
};

/* Work done by the renderer, per effect. Each counter stays 0 unless its effect is in
 * the scene's list; tests assert exactly that. Updated atomically or per thread and
 * summed, so counts are exact. */
struct imp_sim_counters {
        uint64_t shading_evals;       /* direct: BRDF evaluations */
        uint64_t shadow_rays;         /* shadows: rays marched */
        uint64_t shadow_steps;        /* shadows: heightfield samples visited */
        uint64_t indirect_paths;      /* indirect: paths traced while building grids */
        uint64_t grid_vertices;       /* indirect: grid vertices computed */
        uint64_t indirect_lookups;    /* indirect: grid interpolations at render time */
        uint64_t random_draws;        /* noise and any other random numbers */
        uint64_t projector_lookups;   /* projector: pattern samples */
        uint64_t distortion_evals;    /* distortion: pixel remaps */
        uint64_t defocus_taps;        /* defocus / projector defocus: filter taps */
};

/* Heightfield lookup with bilinear interpolation at world (x, y); outside the sampled
 * area returns the nearest edge sample. */
static inline double imp_sim_surface_height(const struct imp_sim_surface *s, double x, double y) {
        double fx = (x - s->origin_mm[0]) / s->pitch_mm, fy = (y - s->origin_mm[1]) / s->pitch_mm;
        if (fx < 0) fx = 0;
        if (fy < 0) fy = 0;
        if (fx > s->nx - 1) fx = s->nx - 1;
        if (fy > s->ny - 1) fy = s->ny - 1;
        int x0 = (int) fx, y0 = (int) fy;
        int x1 = x0 + 1 < s->nx ? x0 + 1 : x0, y1 = y0 + 1 < s->ny ? y0 + 1 : y0;
        double ax = fx - x0, ay = fy - y0;
        const float *h = s->height_mm;
        double a = h[(size_t) y0 * s->nx + x0], b = h[(size_t) y0 * s->nx + x1];
        double c = h[(size_t) y1 * s->nx + x0], d = h[(size_t) y1 * s->nx + x1];
        return (a * (1 - ax) + b * ax) * (1 - ay) + (c * (1 - ax) + d * ax) * ay;
}
