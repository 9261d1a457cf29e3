/* Heights from positions and normals (Nehab, Rusinkiewicz, Davis, Ramamoorthi 2005,
 * "Efficiently combining positions and normals for precise 3D geometry"), on the
 * heightfield grid: the triangulated heights give the low frequencies, the (photometric)
 * normals the high ones, as one sparse linear least-squares problem
 *
 *     min_z  Σ_t w_t (z_t − z0_t)²  +  Σ_t [ (z_{i+1,j} − z_{i−1,j}) − 2p·gx_t ]²
 *                                     +  Σ_t [ (z_{i,j+1} − z_{i,j−1}) − 2p·gy_t ]²,
 *
 * z0 the measured heights, g = (−nx/nz, −ny/nz) the slope the normal asks for at texel t,
 * p the pitch, w_t = λ·(σ_ref/σ_t)² the position weight (σ_t the texel's height σ, σ_ref
 * its median). The gradient term is the central difference at the texel, the stencil a
 * normal of a sampled surface is defined with (the simulator's truth normals and the
 * copy's mesh normals alike), so the grooves the normals carry are integrated at their
 * full amplitude; its blind mode (the 2-texel checkerboard) is held by the positions.
 * Rows need t and both neighbours in the mask. Solved by Jacobi-preconditioned conjugate
 * gradients from z0, per connected region implicitly (the position term makes every
 * region determined). Library code: no logging; errors are negative errno. */
#pragma once
#include <stddef.h>
#include <stdint.h>

struct imp_fuse_params {
        double lambda;                /* position weight relative to one gradient row (0.3):
                                         positions and normals share the frequency
                                         ω ≈ √λ rad/texel (period ≈ 11 texels at 0.3) */
        double min_nz;                /* normals with nz below this give no gradient row (0.2) */
        int max_iter;                 /* CG iterations (500) */
        double tol;                   /* stop when |r| ≤ tol·|b| (1e-6) */
};
void imp_fuse_params_default(struct imp_fuse_params *ret);

struct imp_fuse_stats {
        long n_texels;                /* unknowns (mask texels) */
        long n_rows;                  /* gradient rows used */
        int iterations;
        double residual_rel;          /* |r| / |b| at the end */
        double change_rms_mm;         /* rms of (z − z0) over the mask */
        double agree_deg_before, agree_deg_after;  /* mean angle between the normals and the
                                                      central-difference normals of z0 / z */
};

/* Fuses in place: height_mm (nx·ny, row-major) is replaced by z on mask texels (others
 * untouched). Mask value 2 (IMP_HF_MASK_FILLED: a texel without a triangulated position,
 * e.g. in projector shadow) is an unknown with position weight 0: its height_mm is only
 * the starting value, the result comes from the gradient rows that tie it to measured
 * texels (a filled texel in no row keeps its start value). normal: 3 floats per texel, unit, canvas frame. sigma_mm may be NULL (equal
 * weights). mask NULL = all texels. Returns 0; -EINVAL on bad arguments, -ENOMEM. When
 * nothing can be solved (no mask texel) the heights are left as they are. */
int imp_fuse_heights(int nx, int ny, double pitch_mm, float *height_mm, const float *normal,
                     const float *sigma_mm, const uint8_t *mask, const struct imp_fuse_params *p,
                     struct imp_fuse_stats *ret_stats);
