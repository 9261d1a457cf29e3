/* What one normal per texel can promise: the copy's final normals checked against their
 * own neighbourhood, after every stage has given its σ_n and flags (docs/copy-quality.md
 * "Normals one texel cannot represent").
 *
 * A texel's normal is the shading (or the range plane) of its whole footprint, while the
 * surface it describes may bend within it: where the relief changes direction within a
 * texel (a stroke's edge, a groove's wall), the one normal is a blend and its error grows
 * with the bend. The bend is seen in the copy itself, as the angle between a texel's
 * normal and its neighbours'. Three rules, all from the copy's own evidence:
 *
 *  1. roughness: σ_n grows in quadrature by rough_k × the largest angle between the
 *     texel's normal and a 4-neighbour's (on the demo the error's rms is ≈ 0.1× that
 *     angle: 0.3° below 3°, 2.9° at 16–24°, 4.6° beyond 32°);
 *  2. edge of an unvouched region: a texel touching (8-neighbourhood) a texel whose normal
 *     is not vouched for (a flag other than frame_adjacent and fit_failed, σ_n above the
 *     limit after rule 1, or a hole in the mask) takes at least that neighbour's σ_n and the flag
 *     IMP_TEXEL_NORMAL_UNCERTAIN: such rims are where the relief or the shadows change
 *     within a texel (79 % of the demo's unflagged normals more than 10° off were there);
 *  3. relief finer than the texel: σ_n grows in quadrature by fine_k × the rms, over the
 *     (2·fine_radius + 1)² window, of the fine bend: the sixth differences
 *     [1 −6 15 −20 15 −6 1]/64 of the normals along x plus along y, what of the bend at the
 *     grid's own scale smooth relief does not explain. Relief at and beyond the texel's
 *     wavelength is blended by the footprint and aliases into the copy as a weak trace that
 *     may vanish at the texel itself: on a painting tile at 1 camera pixel per texel
 *     (0.2 mm bristle grooves of up to ±40°), 1.8 % of the unflagged normals were more than 10°
 *     off under σ_n of 1–2° with rules 1 and 2 alone, with their copy's 4-neighbour angles
 *     only 2–12°. Relief the grid resolves bends as much between neighbours but its one
 *     normal is good to ≈ 0.1× that angle (rule 1 covers it), and the sixth difference
 *     keeps only sin⁴(πf) of its bend (1 % at 10 texels per period, 25 % at 4, all of it
 *     at 2). fine_k 2.4 was calibrated on painting tiles with the spec cone at 30°
 *     (docs/copy-quality.md).
 *
 * Texels whose σ_n then exceeds IMP_TEXEL_NORMAL_SIGMA_MAX_DEG get NORMAL_UNCERTAIN too.
 * Library code: no logging; errors are negative errno. */
#pragma once
#include <stdbool.h>
#include <stdint.h>

struct imp_normal_trust_params {
        double rough_k;               /* σ per degree of the largest neighbour angle (0.1) */
        bool edge;                    /* rule 2 on (true) */
        double fine_k;                /* rule 3: σ per degree of the window's rms fine bend (2.4; 0 off) */
        int fine_radius;              /* rule 3: window radius in texels (2: 5 × 5) */
};
void imp_normal_trust_params_default(struct imp_normal_trust_params *ret);

struct imp_normal_trust_stats {
        long n_texels;                /* mask texels */
        long n_rough_flagged;         /* newly NORMAL_UNCERTAIN by rule 1 (σ_n was within the
                                         limit before) */
        long n_fine_flagged;          /* newly NORMAL_UNCERTAIN by rule 3 (and not by rule 1) */
        long n_edge_flagged;          /* newly NORMAL_UNCERTAIN by rule 2 (and not by rules 1, 3) */
};

/* nx·ny texels; mask ≠ 0 on the canvas; nx_, ny_ the unit normals' x, y in the canvas
 * frame (z ≥ 0 implied); sigma_n_deg and texel_flags (quality.h bits) updated in place on
 * the mask. ret_stats may be NULL. -EINVAL on bad arguments, -ENOMEM. */
int imp_normal_trust(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_, float *sigma_n_deg,
                     uint16_t *texel_flags, const struct imp_normal_trust_params *p,
                     struct imp_normal_trust_stats *ret_stats);

/* Rules 1 and 3 read only the mask and the normals (the neighbour angles and the window's
 * rms fine bend); a caller running imp_normal_trust() twice on the same mask and normals
 * with other σ_n or flags keeps them here: the first call with a cache computes them, the
 * next ones read them. The caller promises that mask, nx_ and ny_ did not change between
 * the calls (the cache checks the size and the rule-3 radius only). Free with
 * imp_normal_trust_cache_done(). */
struct imp_normal_trust_cache {
        int nx, ny, fine_radius;
        float *angle_max;             /* rule 1's largest neighbour angle (degrees) */
        double *fine_rms;             /* rule 3's window rms (degrees); NULL when not computed */
};
void imp_normal_trust_cache_done(struct imp_normal_trust_cache *c);
/* imp_normal_trust() with cache (NULL: none); the same results as without. */
int imp_normal_trust_cached(int nx, int ny, const uint8_t *mask, const float *nx_, const float *ny_,
                            float *sigma_n_deg, uint16_t *texel_flags, const struct imp_normal_trust_params *p,
                            struct imp_normal_trust_cache *cache, struct imp_normal_trust_stats *ret_stats);
