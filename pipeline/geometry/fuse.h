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
        double lambda;                /* position weight relative to one unweighted
                                         gradient row (0.3): positions and normals share the
                                         frequency where 4 sin²ω = λ (period ≈ 23 texels);
                                         see row_weight_gain for the weighted rows */
        double min_nz;                /* normals with nz below this give no gradient row (0.2) */
        int max_iter;                 /* CG iterations (500) */
        double tol;                   /* stop when |r| ≤ tol·|b| (1e-6) */
        /* Back-off (with imp_fuse_texels.normal_sigma_deg): a gradient row whose measured
         * heights disagree with the normal's slope by more than max_row_sigma × the
         * row's σ (both heights' σ and the slope σ the normal's σ implies) is left out:
         * the measured heights stay there and the texel is flagged. (3) */
        double max_row_sigma;
        double fill_normal_sigma_deg; /* σ of a normal when none is given, for the σ of
                                         filled texels (3) */
        /* The back-off over longer baselines (with normal_sigma_deg and sigma_mm): a row is
         * also left out when the slopes integrated along the segment of half-length
         * 2 … segment_max texels centred on it disagree with the measured heights at the
         * segment's ends beyond max_row_sigma × those heights' σ (the normals' σ left
         * out: a coherent error hides behind it). < 2: off. Default 4 (8 measured the same
         * on hard-tilted-10/25, and leaves out twice the rows). */
        int segment_max;
#define IMP_FUSE_SEGMENT_MAX 256
        /* Gradient rows weighted by their normal's σ (with imp_fuse_texels.normal_sigma_deg):
         * (σ_ref/σ_t)² of the slope σ, σ_ref the median over the rows, kept within
         * [1/row_weight_max, row_weight_max]; ≤ 1: every row weighs 1. (10) */
        double row_weight_max;
        /* The weighted rows (those not touching a filled texel) are multiplied by this: the
         * median row against a position weighs row_weight_gain / λ (6 / 0.3: they cross at
         * a period of ~56 texels), while the rows that shape filled texels keep 1 against λ,
         * as before the weights. (6) */
        double row_weight_gain;
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
        long n_rows_rejected;         /* gradient rows left out by the back-off */
        long n_backed_off;            /* texels whose rows were all left out that way */
        double fill_sigma_max_mm;     /* largest σ given to a filled texel (0: none) */
};

/* Optional per-texel inputs and outputs of imp_fuse_heights (each may be NULL).
 * normal_sigma_deg: in, 1σ of each normal in degrees (photometric.h sigma_deg): turns
 *   the back-off on and sets the σ of filled texels.
 * sigma_mm: out (may alias the sigma_mm input): the height σ after fusion. Measured
 *   texels keep theirs (fusion only lowers the noise); a filled texel (mask 2) gets the
 *   σ its shape inherits from the normals it was integrated from: the cheapest path from
 *   a measured texel, σ of that texel + Σ pitch · σ_slope over the path (σ_slope the
 *   slope σ of each normal, tan σn / nz², accumulated linearly because a normal's error
 *   is mostly a bias, not noise), and never below the input σ.
 * flags: out, quality.h IMP_TEXEL_* ORed in: FILLED on mask-2 texels,
 *   PHOTOMETRIC_REJECTED where the back-off left out a row centred on the texel. */
struct imp_fuse_texels {
        const float *normal_sigma_deg;
        float *sigma_mm;
        uint16_t *flags;
        const float *row_sigma_deg;   /* in, the σ the rows are weighted by (row_weight_max);
                                         NULL: normal_sigma_deg */
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
                     const struct imp_fuse_texels *tex, struct imp_fuse_stats *ret_stats);
