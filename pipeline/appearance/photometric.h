/* Photometric normal refinement from the dome sweep: per texel, Lambertian
 * photometric stereo on the near-field samples of imp_btf_samples_extract(),
 *
 *     V / E = g · l,   g = ρd · n   (3 unknowns, linear least squares),
 *
 * with l the light direction and E the irradiance at normal incidence at the texel (both
 * from the sample), the samples near the mirror direction and those predicted to be in
 * attached shadow left out, and Huber reweighting (IRLS). n = g/|g| replaces (or, with
 * geo_sigma_deg > 0, is fused with) the geometric normal; where the data cannot
 * determine it (too few samples, ill-conditioned lighting, black paint, or a normal that
 * disagrees with the geometry by more than max_dev_deg) the geometric normal is kept and
 * the texel is flagged. The stage checks its own model before a normal replaces the
 * geometric one: a significant ambient term (a 4th unknown c in V/E = g·l + c: light that
 * arrives whatever the light direction, i.e. inter-reflection or a wrong irradiance), a
 * residual far above its robust noise, or a σ above max_sigma_deg make it back off to the
 * geometric normal with a flag. Every texel gets a σ in degrees (imp_pn_texel.sigma_deg,
 * imp_photometric_out.sigma_deg) meant to cover its error: the fit's covariance with the
 * residual scale, the normal's shift when the ambient term is freed, and the
 * interpolation floor measured on the demo (grows with the surface's slope).
 * Parameterisation, bounds, initial guess and stopping rule: docs/geometry.md
 * "Photometric normals". Library code: no logging; errors are negative errno. */
#pragma once
#include <stdint.h>
#include "btf.h"

enum imp_pn_flag {
        IMP_PN_FEW_SAMPLES = 1 << 0,  /* fewer than min_samples usable samples */
        IMP_PN_ILL_COND    = 1 << 1,  /* light directions span too little (cond > max_cond) */
        IMP_PN_DARK        = 1 << 2,  /* |g| below min_albedo: no shading signal */
        IMP_PN_DISAGREES   = 1 << 3,  /* photometric and geometric normals > max_dev_deg apart */
        IMP_PN_MASKED      = 1 << 4,  /* outside the mask or hidden: no samples at all */
        IMP_PN_AMBIENT     = 1 << 5,  /* a significant ambient term (> max_ambient_rel·|g|):
                                         inter-reflection suspected, Lambert does not fit */
        IMP_PN_RESIDUAL    = 1 << 6,  /* residual RMS > max_rms_ratio × its robust σ or
                                         > max_rel_rms × the signal, or σ > max_sigma_deg:
                                         the model does not fit */
        IMP_PN_SATURATED   = 1 << 7,  /* the extractor dropped saturated samples (set with
                                         FEW_SAMPLES when that is why too few are left) */
};
/* The kernel imp_photometric_normals() re-reads the frames with (imp_photometric_params.kernel). */
enum imp_pn_kernel {
        IMP_PN_KERNEL_LANCZOS = 0,    /* Lanczos of order lanczos */
        IMP_PN_KERNEL_LANCZOS_CLAMPED,/* the same with its negative lobes set to 0 */
        IMP_PN_KERNEL_MITCHELL,       /* Mitchell–Netravali B = C = 1/3, 4 × 4 pixels */
        IMP_PN_KERNEL_BSPLINE,        /* cubic B-spline (non-negative, smoothing), 4 × 4 */
        IMP_PN_KERNEL_PREFILTERED,    /* frames smoothed by the binomial [1 2 1]/4 in x and
                                         y, then Lanczos of order lanczos (≤ 3) */
};

#define IMP_PN_KEPT (IMP_PN_FEW_SAMPLES | IMP_PN_ILL_COND | IMP_PN_DARK | IMP_PN_DISAGREES | IMP_PN_MASKED | \
                     IMP_PN_AMBIENT | IMP_PN_RESIDUAL)

/* The per-texel flags of quality.h (IMP_TEXEL_*) that a texel's IMP_PN_* flags imply:
 * FEW_SAMPLES, ILL_COND → FEW_SAMPLES; DARK → DARK; AMBIENT → INTERREFLECTION; RESIDUAL,
 * DISAGREES → PHOTOMETRIC_REJECTED; SATURATED → SATURATED; and PHOTOMETRIC_REJECTED
 * with any kept flag (the geometric normal was kept). MASKED alone → 0 (not paint). */
uint16_t imp_photometric_texel_flags(uint16_t pn_flags);

struct imp_photometric_params {
        int min_samples;              /* fewer usable samples → FEW_SAMPLES (6) */
        double spec_cone_deg;         /* leave out samples whose l is within this of the
                                         mirror direction of v about the current normal (30) */
        double min_cos;               /* leave out samples with n·l below this for the
                                         current normal: attached shadow (0.05) */
        double max_cond;              /* condition number of Σ w l lᵀ above this → ILL_COND (100) */
        double min_albedo;            /* |g| below this → DARK (0.01) */
        double max_dev_deg;           /* photometric vs geometric normal bound (25) */
        int passes;                   /* solves: 1 least-squares + Huber reweightings (5) */
        double huber_delta;           /* Huber threshold in robust σ (1.345) */
        double sigma_floor;           /* lower bound of the robust σ of V/E (0.002) */
        double tol_deg;               /* stop when the normal moves less than this (0.01) */
        double geo_sigma_deg;         /* > 0: fuse n = normalise(n_p/σp² + n_g/σg²) with this
                                         σ of the geometric normal; <= 0: replace (0) */
        int lanczos;                  /* imp_photometric_normals() reads the frames again at
                                         each sample with a Lanczos kernel of this order
                                         (1..4; 3) instead of the extractor's bilinear value;
                                         0: keep the bilinear values */
        int kernel;                   /* enum imp_pn_kernel of that re-read (LANCZOS); the
                                         cubics ignore the order but lanczos = 0 still turns
                                         the re-read off; PREFILTERED needs lanczos ≤ 3 */
        double shadow_trim_sigma;     /* > 0: samples darker than the current fit by more
                                         than this many robust σ get weight 0 in the next
                                         solve (a cast shadow only darkens). 0 (default) */
        /* imp_photometric_normals() solves the texels with mask value 2
         * (heightfield.h IMP_HF_MASK_FILLED: shadow-filled, no triangulated position,
         * usually next to the frame, which is not in the heightfield and so casts shadows
         * the extractor does not predict) with shadow_trim_sigma = filled_trim_sigma, at
         * least filled_passes solves and max_dev_deg = filled_max_dev_deg (their geometric
         * normal is only the canvas plane's). */
        double filled_trim_sigma;     /* 3 */
        int filled_passes;            /* 10 */
        double filled_max_dev_deg;    /* 60 */
        /* Model checks (texel flags above). */
        double max_ambient_rel;       /* ambient term c above this × |g| and above
                                         ambient_sigma × its σ → AMBIENT (0.05) */
        double ambient_sigma;         /* (4) */
        double max_rms_ratio;         /* weighted residual RMS above this × the robust σ
                                         (MAD) → RESIDUAL (3) */
        double max_rel_rms;           /* weighted residual RMS above this × the mean V/E of
                                         the samples taking part → RESIDUAL: a misfit that
                                         is smooth (MAD ≈ RMS), e.g. light from a groove's
                                         wall for half the dome (≈ 9 % in
                                         test-photometric-stability). 0.06: at 0.03 the
                                         demo's glossy and steep texels (3–6 %) backed off
                                         by the tens of thousands, normals 1.71° → 1.94° */
        double max_sigma_deg;         /* σ above this → RESIDUAL (DARK when the noise term
                                         alone exceeds it): 3σ stays within 10° (3.3) */
        /* Interpolation floor of σ (what reading 50 µm pixels at a texel leaves on detail
         * of a few pixels; docs/geometry.md "Normal error: diagnosis", demo table by slope):
         * interp_sigma_deg + interp_sigma_per_deg × the normal's tilt in degrees
         * (0.55, 0.1). */
        double interp_sigma_deg, interp_sigma_per_deg;
        double geo_min_sigma_deg;     /* floor of the σ given to a kept geometric normal (1) */
        /* Agreement with the geometric normals (imp_photometric_agreement): the window
         * radius (texels) over which their difference is pooled into a bias (3), the
         * geometric normals' correlation length in texels (their 3×3 plane fits: 3) and
         * the multiple of the combined σ beyond which one texel's two normals disagree (3). */
        int agree_radius;
        double agree_corr_texels, agree_k;
};
void imp_photometric_params_default(struct imp_photometric_params *ret);

/* The result of one texel. n is in the local frame of the samples (z = the normal the
 * samples were extracted with); when a KEPT flag is set, n = (0, 0, 1). All finite. */
struct imp_pn_texel {
        float n[3];
        float albedo;                 /* |g|: the Lambertian albedo (mean of the channels) */
        float dev_deg;                /* angle between the photometric and the sample normal */
        float sigma_deg;              /* 1σ angular uncertainty (RMS angle): covariance with the
                                         residual scale ⊕ the ambient-term shift (no
                                         interpolation floor: that needs the canvas tilt,
                                         imp_photometric_normals adds it); 180 if unknown */
        float ambient;                /* the ambient term c of the 4-unknown check (V/E units) */
        float rms;                    /* weighted RMS residual of V/E */
        float cond;                   /* condition number of the normal matrix (≤ 1e12) */
        uint16_t n_used;              /* samples in the last solve */
        uint16_t flags;               /* enum imp_pn_flag */
};

/* One texel from n samples (0 ≤ n ≤ IMP_BTF_MAX_SAMPLES; non-finite samples, e_cos ≤ 0 or
 * l[2] ≤ 0 are ignored). Thread-safe, allocates nothing; always fills *ret with finite
 * values. -E2BIG when n is too large, -EINVAL on bad params. */
int imp_photometric_texel(const struct imp_btf_sample *samples, int n, const struct imp_photometric_params *p,
                          struct imp_pn_texel *ret);

/* Whether the refined normals agree with the geometric ones they refine, two independent
 * measurements of the same normal (nx·ny texels, canvas frame). A refined texel (pn_flags
 * without IMP_PN_KEPT, mask ≠ 0) gets the bias its neighbourhood shows: the mean of the
 * difference vectors (photometric − geometric) over the (2·agree_radius+1)² window, less
 * what the two normals' noise explains (their σ² over the effective number of independent
 * geometric normals in the window), is added to its σ in quadrature (an ambient term,
 * inter-reflection or shadowed samples bias a whole region the same way). A texel whose two
 * normals differ by more than agree_k × their combined σ gets that angle as its σ: one of
 * the two is that far off, and which cannot be told. geo_sigma_deg NULL: 1° everywhere.
 * sigma_deg is updated in place. Returns the number of texels whose σ grew by more than
 * 10 %, -EINVAL, -ENOMEM. */
long imp_photometric_agreement(int nx, int ny, const uint8_t *mask, const uint16_t *pn_flags, const float *normal,
                               const float *geo_normal, const float *geo_sigma_deg,
                               const struct imp_photometric_params *p, float *sigma_deg);

struct imp_photometric_stats {
        long n_texels, n_refined, n_few, n_ill, n_dark, n_disagree, n_masked;
        long n_ambient, n_residual, n_saturated;
        double dev_deg_mean, dev_deg_median;   /* over refined texels */
        double sigma_deg_median, rms_median;   /* over refined texels */
        long n_resampled;             /* samples whose value was read with the Lanczos kernel
                                         (the others keep the bilinear value: window off the
                                         frame or touching a saturated/invalid pixel) */
        bool ambient_canvas;          /* the ambient term was found on so many texels that
                                         every refined normal went back to the geometric one
                                         (then every texel's normal is the geometric one) */
};

/* Where imp_photometric_normals() writes (every array nx·ny texels of hf; NULL: not
 * wanted, except normal).
 * normal: 3 floats per texel, canvas frame, unit; the refined normal where refined and
 *   hf->normal elsewhere (may not alias hf->normal).
 * flags: enum imp_pn_flag per texel (of normal).
 * texel_flags: quality.h IMP_TEXEL_* bits per texel (imp_photometric_texel_flags()).
 * sigma_deg: 1σ of normal in degrees (RMS angle), finite: for a refined texel its
 *   sigma_deg with the interpolation floor; where the geometric normal was kept, that
 *   normal's σ from hf->sigma_mm (slope σ of a central difference, √2·σh / 2·pitch,
 *   at least geo_min_sigma_deg) or 180 without hf->sigma_mm; 0 off the mask. */
struct imp_photometric_out {
        float *normal;
        uint16_t *flags;
        uint16_t *texel_flags;
        float *sigma_deg;
};

/* The whole grid: tile by tile, extract the samples (shadow rays on the heightfield) and
 * refine each texel (OpenMP) into out. ret_stats may be NULL. Errors as
 * imp_btf_samples_extract(), -EINVAL, -ENOMEM. */
int imp_photometric_normals(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *sp, const struct imp_photometric_params *p,
                            const struct imp_photometric_out *out, struct imp_photometric_stats *ret_stats);

/* The BTF fit's local frames (btf.h struct imp_btf_frames) as this model's normals of the
 * fit's own samples: the model on the values the fit reads (the extractor's bilinear ones,
 * not the Lanczos re-read: the fit's ρd needs frames whose shading matches its values,
 * docs/processing-speed.md "The fit takes the photometric stage's ray decisions"), with
 * the parameters imp_photometric_normals() uses (those of mask value 2 on shadow-filled
 * texels), in the frame of the normal the fit extracts with: a texel the model keeps
 * (IMP_PN_KEPT) keeps that normal. The fit takes its samples in mode (enum
 * imp_btf_frames_mode) and writes the frames to normal (3 floats per texel of hf). f holds
 * the parameters and must outlive *ret; hf->mask is read when the fit runs.
 * -EINVAL on bad arguments. */
struct imp_photometric_frames {
        const uint8_t *mask;
        int width, height;
        struct imp_photometric_params p, pf;   /* pf: shadow-filled texels */
};
int imp_photometric_frames(const struct imp_btf_heightfield *hf, const struct imp_photometric_params *p, int mode,
                           float *normal, struct imp_photometric_frames *f, struct imp_btf_frames *ret);
