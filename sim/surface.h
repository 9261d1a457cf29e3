/* What the simulator's effects see of a scene: the sampled painting surface (canvas and
 * frame as one heightfield over the world x–y plane) and the counters by which the
 * "an effect not listed costs nothing" promise is measured. */
#pragma once
#include <stdbool.h>
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
        /* A gantry tile's window (placed): the samples lie on the painting's own lattice, fixed
         * to the painting and the same for every tile: sample (i, j) sits at painting
         * ((lattice0[0] + i) · pitch, (lattice0[1] + j) · pitch), and origin_mm, canvas_*_mm
         * are in the painting frame. The tile's pose maps world to it: painting_xy =
         * R(θ)·world_xy + offset_mm (rot = cos θ, sin θ); z is the same in both. Unplaced:
         * the samples lie at world origin_mm + (i, j) · pitch. */
        bool placed;
        int lattice0[2];
        double rot[2], offset_mm[2];
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

/* Heightfield lookup with bilinear interpolation at (x, y) in the frame of the samples (world
 * unless placed); outside the sampled area returns the nearest edge sample. */
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

/* World (x, y) → the frame of the samples (the painting frame of a placed surface). */
static inline void imp_sim_surface_to_lattice(const struct imp_sim_surface *s, const double w[2], double ret[2]) {
        if (!s->placed) {
                ret[0] = w[0], ret[1] = w[1];
                return;
        }
        double x = w[0], y = w[1];
        ret[0] = s->rot[0] * x - s->rot[1] * y + s->offset_mm[0];
        ret[1] = s->rot[1] * x + s->rot[0] * y + s->offset_mm[1];
}

/* A direction (x, y components) from world to the frame of the samples and back. */
static inline void imp_sim_surface_dir_to_lattice(const struct imp_sim_surface *s, const double w[2], double ret[2]) {
        double x = w[0], y = w[1];
        ret[0] = s->placed ? s->rot[0] * x - s->rot[1] * y : x;
        ret[1] = s->placed ? s->rot[1] * x + s->rot[0] * y : y;
}
static inline void imp_sim_surface_dir_to_world(const struct imp_sim_surface *s, const double l[2], double ret[2]) {
        double x = l[0], y = l[1];
        ret[0] = s->placed ? s->rot[0] * x + s->rot[1] * y : x;
        ret[1] = s->placed ? -s->rot[1] * x + s->rot[0] * y : y;
}

/* The frame of the samples (x, y) → world. */
static inline void imp_sim_surface_to_world(const struct imp_sim_surface *s, const double l[2], double ret[2]) {
        if (!s->placed) {
                ret[0] = l[0], ret[1] = l[1];
                return;
        }
        double d[2] = { l[0] - s->offset_mm[0], l[1] - s->offset_mm[1] };
        imp_sim_surface_dir_to_world(s, d, ret);
}

/* The position of sample (i, j) in the frame of the samples. */
static inline void imp_sim_surface_sample_xy(const struct imp_sim_surface *s, int i, int j, double ret[2]) {
        if (s->placed) {
                ret[0] = (double) (s->lattice0[0] + i) * s->pitch_mm;
                ret[1] = (double) (s->lattice0[1] + j) * s->pitch_mm;
        } else {
                ret[0] = s->origin_mm[0] + i * s->pitch_mm;
                ret[1] = s->origin_mm[1] + j * s->pitch_mm;
        }
}

/* The surface's height under world (x, y): the same point of the painting in every tile. */
static inline double imp_sim_surface_height_world(const struct imp_sim_surface *s, double x, double y) {
        double w[2] = { x, y }, l[2];
        imp_sim_surface_to_lattice(s, w, l);
        return imp_sim_surface_height(s, l[0], l[1]);
}
