/* Bidirectional texture recovery (seed 000 §4.4): radiance samples
 * per texel of a heightfield (local view/light directions, irradiance, measured value,
 * self-shadowed and hidden samples rejected by ray casting on the heightfield, §5.2's
 * linear-then-binary search), and a per-texel one-lobe Lafortune fit (lafortune.h).
 * The fit's parameterisation, bounds, initial guesses, stopping rule and flags are in
 * docs/btf-fit.md. Library code: no logging; errors are negative errno. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "image.h"
#include "lafortune.h"
#include "rig.h"

/* ---- input: the heightfield and the capture ------------------------------------- */

/* A heightfield on a regular grid (read-only view; nothing is owned). Texel (u, v) sits
 * at canvas point (u·pitch_mm, v·pitch_mm, height_mm[v·width + u]); canvas_to_world
 * maps canvas points (row-major 4×4, last row 0 0 0 1) to the world frame of the rig and
 * must be rigid (rotation + translation). Non-finite heights never occlude. */
struct imp_btf_heightfield {
        int width, height;            /* texels */
        double pitch_mm;              /* grid spacing, > 0 */
        const float *height_mm;       /* width·height, row-major */
        const float *normal;          /* 3 per texel, unit, canvas frame (z out of the paint) */
        const uint8_t *mask;          /* width·height, non-zero = paint; NULL = all */
        double canvas_to_world[16];
        const float *sigma_mm;        /* width·height height σ, may be NULL (photometric.h
                                         uses it for the σ of a kept geometric normal) */
};

/* Per-pixel flags of the optional validity images (one u8 channel per frame). */
enum {
        IMP_BTF_PIX_SATURATED = 1 << 0,   /* clipped in every exposure of the merge */
        IMP_BTF_PIX_INVALID   = 1 << 1,   /* no usable exposure (too dark, defect) */
};

/* The validity image of a frame from the per-channel flags of its HDR merge (hdr.h, u8):
 * SATURATED in any channel → IMP_BTF_PIX_SATURATED, DARK in any → IMP_BTF_PIX_INVALID.
 * Caller frees *ret. -EINVAL, -ENOMEM. */
int imp_btf_valid_from_hdr(const struct imp_image *hdr_flags, struct imp_image **ret);

/* One camera and one HDR-merged linear frame per light (frames[i] lit by lights[i]).
 * Frames: f32, 1 or 3 channels, camera->width × camera->height; 1.0 = a white
 * Lambertian reference at normal incidence under irradiance 1. valid: NULL, or one u8
 * image per frame (NULL entries allowed) with the IMP_BTF_PIX_* flags. */
struct imp_btf_capture {
        const struct imp_pinhole *camera;
        const struct imp_rig_light *lights;
        int n_lights;                 /* 1 .. IMP_BTF_MAX_SAMPLES */
        const struct imp_image *const *frames;
        const struct imp_image *const *valid;
};

/* ---- samples --------------------------------------------------------------------- */

#define IMP_BTF_MAX_SAMPLES 512       /* per texel; the fit's workspace is on the stack */

/* One radiance sample of one texel, in the texel's local frame (imp_local_frame()).
 * value is the frame value divided by the light's colour (a colour of (0,0,0) counts as
 * white), so value / e_cos estimates f(v, l) of lafortune.h. */
struct imp_btf_sample {
        float v[3];                   /* unit, towards the camera */
        float l[3];                   /* unit, towards the light; l[2] = cos θl > 0 */
        float e_cos;                  /* E · cos θl, E = irradiance at normal incidence */
        float value[3];               /* measured V, RGB (mono frames: replicated) */
};

/* Per-texel flags: sample stage (HIDDEN, SATURATED, MASKED) and fit stage (the rest). */
enum imp_btf_flag {
        IMP_BTF_FEW_SAMPLES    = 1 << 0,  /* fewer than min_samples usable samples */
        IMP_BTF_CX_EQ_CY       = 1 << 1,  /* Cx, Cy not separable: constrained Cx = Cy */
        IMP_BTF_MATTE          = 1 << 2,  /* no specular seen: ρs = 0, lobe = default */
        IMP_BTF_SATURATED      = 1 << 3,  /* ≥ 1 sample rejected as saturated */
        IMP_BTF_HIDDEN         = 1 << 4,  /* camera cannot see the texel */
        IMP_BTF_FILLED         = 1 << 5,  /* values copied from neighbours */
        IMP_BTF_MASKED         = 1 << 6,  /* outside the paint mask (or no normal): zeros */
        IMP_BTF_K_BOUND        = 1 << 7,  /* k ended at k_min or k_max */
        IMP_BTF_LOBE_UNCERTAIN = 1 << 8,  /* lobe width poorly determined (see docs) */
        IMP_BTF_FIT_FAILED     = 1 << 9,  /* the result is not a physical BRDF (ρd outside
                                             [0, 1], ρs < 0 or at its cap, k ≤ 0, a lobe
                                             not normalised, anything non-finite): values
                                             finite but not to be trusted */
};

/* The per-texel flags of quality.h (IMP_TEXEL_*) a texel's fit flags imply:
 * FEW_SAMPLES → FEW_SAMPLES, SATURATED → SATURATED, FIT_FAILED → FIT_FAILED; MASKED → 0.
 * K_BOUND and LOBE_UNCERTAIN say how well the lobe is known, not that the fit failed:
 * they stay in fit-flags.exr (compare counts them apart). */
uint16_t imp_btf_texel_flags(uint16_t btf_flags);

struct imp_btf_sample_params {
        double min_cos_l;             /* discard lights with cos θl below this (0.02) */
        double min_e_cos;             /* discard samples with E·cos θl below this (1e-6) */
        double saturation_value;      /* any channel ≥ this is saturated; 0 = use flags only */
        double dark_value;            /* discard when every channel < this (-HUGE_VAL: off) */
        double march_step_texels;     /* linear-search step along the ray, texels (0.5) */
        int march_refine;             /* binary-refinement steps after a hit (8) */
        double shadow_bias_texels;    /* a ray is blocked when it is this far below (0.05) */
        /* The ray decisions of an earlier extraction (struct imp_btf_rays, below; NULL:
         * march every ray): rays_mode IMP_BTF_RAYS_RECORD stores each texel's, REUSE takes
         * them instead of marching. */
        struct imp_btf_rays *rays;
        int rays_mode;
};
void imp_btf_sample_params_default(struct imp_btf_sample_params *ret);

/* The shadow and camera-visibility decisions of an extraction, per texel: for each light
 * whether its shadow ray was decided (marched or cleared by the horizon) and whether it
 * was blocked, and the camera ray's outcome. They depend on the heights alone, not on
 * the normal or the frames: a second extraction on the same heights (the fit after the
 * photometric stage) with REUSE gets the same samples without marching a ray the first
 * one decided; it marches only those the first did not (a light below the horizon of the
 * other normal, a texel it masked). On heights moved since (the height fusion, µm) the
 * decisions are those of the recorded heights: docs/btf-fit.md says what that changes.
 * Recording: each texel's decisions are written by the thread extracting it. */
enum { IMP_BTF_RAYS_OFF, IMP_BTF_RAYS_RECORD, IMP_BTF_RAYS_REUSE };
enum { IMP_BTF_CAM_UNKNOWN, IMP_BTF_CAM_CLEAR, IMP_BTF_CAM_BLOCKED };
struct imp_btf_rays {
        int width, height, n_lights;
        int words;                    /* 64-bit words per texel and set: ⌈n_lights / 64⌉ */
        uint64_t *known, *blocked;    /* [texel][words], bit j: light j */
        uint8_t *camera;              /* per texel: IMP_BTF_CAM_* */
};
/* All undecided. -EINVAL, -ENOMEM. */
int imp_btf_rays_new(int width, int height, int n_lights, struct imp_btf_rays **ret);
void imp_btf_rays_free(struct imp_btf_rays *r);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_btf_rays *, imp_btf_rays_free);

/* The samples of one tile of texels. Texel i (row-major in the tile) has its samples at
 * samples[i·max_per_texel .. + count[i]). Caller frees with imp_btf_samples_free(). */
struct imp_btf_samples {
        int capacity_texels, max_per_texel;
        int x0, y0, w, h;             /* the tile extracted last */
        uint16_t *count;              /* per texel */
        uint16_t *flags;              /* per texel: HIDDEN, SATURATED, MASKED */
        uint16_t *n_shadowed;         /* per texel: samples rejected as self-shadowed */
        struct imp_btf_sample *samples;
};
int imp_btf_samples_new(int capacity_texels, int max_per_texel, struct imp_btf_samples **ret);
void imp_btf_samples_free(struct imp_btf_samples *s);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_btf_samples *, imp_btf_samples_free);
#define _cleanup_btf_samples_ _cleanup_(imp_btf_samples_freep)

/* Extract the samples of texels [x0, x0+w) × [y0, y0+h) into out (w·h ≤ capacity,
 * n_lights ≤ max_per_texel). Texels are processed in parallel (OpenMP). -EINVAL on bad
 * arguments (frame size or type, non-rigid transform, tile outside the grid), -E2BIG
 * when the tile or the light count exceeds out's capacity. */
int imp_btf_samples_extract(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *p, int x0, int y0, int w, int h,
                            struct imp_btf_samples *out);

/* A max pyramid of a heightfield's cells, which lets the shadow and visibility rays of
 * the extraction skip, exactly, the stretches where they pass above every height (same
 * hits as the plain march), and the heightfield's conservative horizon (below), which
 * spares the march altogether for the rays it clears. It refers to hf->height_mm: heights must not change while it
 * is in use. Caller frees with imp_btf_hf_pyramid_free(). -EINVAL, -ENOMEM. */
struct imp_btf_hf_pyramid;
int imp_btf_hf_pyramid_new(const struct imp_btf_heightfield *hf, struct imp_btf_hf_pyramid **ret);
/* The same, with the horizon below only when horizon is true: without it every ray that is
 * not taken from a record is marched (the same decisions, the horizon only spares marches
 * that find no hit), for an extraction that reuses recorded rays and marches few (the
 * fit after the photometric stage: docs/processing-speed.md "The fit's horizon"). */
int imp_btf_hf_pyramid_new_horizon(const struct imp_btf_heightfield *hf, bool horizon,
                                   struct imp_btf_hf_pyramid **ret);
void imp_btf_hf_pyramid_free(struct imp_btf_hf_pyramid *py);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_btf_hf_pyramid *, imp_btf_hf_pyramid_free);

/* A conservative horizon (btf-horizon.c): per texel and quadrant of azimuth, an upper
 * bound on the slope at which a ray leaving the texel can still pass below the surface
 * by more than bias_mm. Built once per heightfield (O(texels · log size)) for every light
 * and the camera: imp_btf_hf_pyramid_new() builds one for bias 0 (valid for any bias ≥ 0)
 * and the extractor marches only the rays it cannot clear, so its decisions are the
 * march's. -EINVAL, -ENOMEM. */
struct imp_btf_horizon;
int imp_btf_horizon_new(const struct imp_btf_heightfield *hf, double bias_mm, struct imp_btf_horizon **ret);
void imp_btf_horizon_free(struct imp_btf_horizon *hz);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_btf_horizon *, imp_btf_horizon_free);
/* True when the ray from texel (u, v) (on the surface) along unit direction d cannot be
 * blocked: imp_btf_heightfield_ray() with the same bias would then find no hit. False
 * says nothing (march it). */
bool imp_btf_horizon_clear(const struct imp_btf_horizon *hz, int u, int v, const double d[3]);
/* The bound itself (rise over run) at texel (u, v) for quadrant q = (du < 0) | (dv < 0)·2. */
double imp_btf_horizon_slope(const struct imp_btf_horizon *hz, int u, int v, int q);
/* The four bounds of texel (u, v) (q = 0..3) into ret, for a caller testing many rays of
 * one texel: imp_btf_horizon_clear() is d[2] > 0 && d[2] ≥ ret[q] · √(d[0]² + d[1]²) in
 * double. False (ret untouched) when hz is NULL. */
bool imp_btf_horizon_texel(const struct imp_btf_horizon *hz, int u, int v, float ret[4]);
/* The bound's two parts (btf-horizon.c): a ray into quadrant q with d[2] ≥ ret_near[q] · run
 * cannot be blocked within IMP_BTF_HORIZON_SPLIT texels of horizontal run, one with
 * d[2] ≥ ret_far[q] · run (d[2] > 0) not beyond them; the bound of imp_btf_horizon_texel()
 * is their maximum. False (ret_* untouched) when hz is NULL. */
#define IMP_BTF_HORIZON_SPLIT 6
bool imp_btf_horizon_split(const struct imp_btf_horizon *hz, int u, int v, float ret_near[4], float ret_far[4]);

/* imp_btf_samples_extract() with a pyramid built once for many tiles (the plain call
 * builds one per call). -EINVAL also when py was built from another heightfield. */
int imp_btf_samples_extract_pyramid(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                                    const struct imp_btf_sample_params *p, const struct imp_btf_hf_pyramid *py,
                                    int x0, int y0, int w, int h, struct imp_btf_samples *out);

/* One texel at a time, for callers that fit as they extract (no tile buffer, no barrier
 * between extraction and fit): the per-capture set-up of imp_btf_samples_extract_pyramid()
 * once, then imp_btf_extract_texel() from any thread. The extractor refers to hf, cap
 * and py (they must outlive it); p is copied. -EINVAL, -E2BIG, -ENOMEM as above. */
struct imp_btf_extractor;
int imp_btf_extractor_new(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                          const struct imp_btf_sample_params *p, const struct imp_btf_hf_pyramid *py,
                          struct imp_btf_extractor **ret);
void imp_btf_extractor_free(struct imp_btf_extractor *x);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_btf_extractor *, imp_btf_extractor_free);
/* The samples of texel (u, v) (inside the grid) into out (room for cap->n_lights);
 * returns their number; *ret_flags: HIDDEN, SATURATED, MASKED; *ret_shadowed: samples
 * rejected as self-shadowed. Thread-safe. */
int imp_btf_extract_texel(const struct imp_btf_extractor *x, int u, int v, struct imp_btf_sample *out,
                          uint16_t *ret_flags, uint16_t *ret_shadowed);

/* The frames of one band of texel rows interleaved by light (mono f32 frames of one size
 * only): over the pixel box the band's texels project into (± margin pixels), pixel
 * (x, y)'s values of every light side by side, NaN where that light's validity mask is
 * set, and beside them each pixel's state for the extractor's taps (non-finite, saturated
 * by value or mask, masked). Both appearance stages read their bilinear taps from it, the
 * photometric stage its Lanczos windows too: one texel's 2 × 2 taps of all L lights are 4
 * runs of L values instead of 4 scattered reads in each of L frames and L masks. The
 * values and decisions are those read from the frames (imp_btf_extract_texel_band()). */
#define IMP_BTF_BAND_ROWS  64                   /* texel rows per band */
#define IMP_BTF_BAND_BYTES ((size_t) 80 << 20)  /* larger boxes: read the frames as they are */
struct imp_btf_band {
        float *v;                     /* [rows][cols][L] */
        uint8_t *st;                  /* [rows][cols][L], the extractor's tap states */
        int x0, y0, cols, rows, L;    /* the box in frame pixels */
        size_t have;                  /* bytes allocated (reused from band to band) */
};
/* Loads texel rows [v0, v0 + rows) of x's heightfield into b (its buffer reused when large
 * enough): true when loaded; false when the frames are not mono f32 of one size, no texel
 * of the rows projects, the box exceeds IMP_BTF_BAND_BYTES or memory runs out (the caller
 * then reads the frames: pass NULL for the band). Parallel (OpenMP): call it outside a
 * parallel region. */
bool imp_btf_band_load(const struct imp_btf_extractor *x, int v0, int rows, int margin, struct imp_btf_band *b);
void imp_btf_band_done(struct imp_btf_band *b);
/* imp_btf_extract_texel() reading the taps from band b when they lie inside its box (b
 * may be NULL; the samples are the same bit for bit), and each sample's light index
 * (into cap->lights) into ret_light (may be NULL), so a caller re-reading the samples
 * need not find their lights again. */
int imp_btf_extract_texel_band(const struct imp_btf_extractor *x, const struct imp_btf_band *b, int u, int v,
                               struct imp_btf_sample *out, uint16_t *ret_light, uint16_t *ret_flags,
                               uint16_t *ret_shadowed);
/* imp_btf_extract_texel_band() for a caller that reads the values itself (the photometric
 * stage's Lanczos re-read, before the extraction): a sample of light j with given_ok[j]
 * set gets given[j] (final, the light colour applied) as its value instead of the bilinear
 * reading, which is then not computed when the taps lie in band b and no dark_value test
 * needs it. Everything else is the full extraction's: which samples exist (the taps'
 * states, the rays), their geometry, flags, shadowed count and light indices. given and
 * given_ok: room for cap->n_lights (both NULL: imp_btf_extract_texel_band()). */
int imp_btf_extract_texel_given(const struct imp_btf_extractor *x, const struct imp_btf_band *b, int u, int v,
                                const float (*given)[3], const uint8_t *given_ok, struct imp_btf_sample *out,
                                uint16_t *ret_light, uint16_t *ret_flags, uint16_t *ret_shadowed);

/* Ray against the heightfield in canvas coordinates: origin o (on the surface), unit
 * direction d. Linear search in steps of march_step_texels·pitch, then march_refine
 * bisections (seed §5.2). True when the ray passes below the surface (by more than the
 * bias) before it rises above the highest texel, leaves the grid or reaches max_t_mm;
 * *ret_t_mm (may be NULL) gets the refined distance of the hit. hmax_mm: the grid's
 * highest finite height (imp_btf_heightfield_hmax()). */
bool imp_btf_heightfield_ray(const struct imp_btf_heightfield *hf, const struct imp_btf_sample_params *p,
                             double hmax_mm, const double o[3], const double d[3], double max_t_mm,
                             double *ret_t_mm);
double imp_btf_heightfield_hmax(const struct imp_btf_heightfield *hf);

/* Irradiance at normal incidence of a near-field light at world point X (mm):
 * E = intensity · (1000 / |X − pos|)² · max(0, cos ∠(X − pos, axis))^profile_exp
 * (profile_exp = 0: isotropic). */
double imp_btf_light_irradiance(const struct imp_rig_light *light, const double X[3]);

/* ---- fit ------------------------------------------------------------------------- */

/* The fit's local frames estimated from its own samples (imp_btf_fit_params.frames; NULL:
 * the fit takes every texel's samples in the frame of hf->normal). Per texel, estimate()
 * gets the samples extracted in the frame of n0 = hf->normal (canvas frame) and returns
 * true with the texel's frame normal (canvas frame, unit) in ret_n, or false to keep n0
 * (a model that failed or backed off keeps the incoming normal). The fit then takes the
 * samples in that frame (mode, below) and fits them there; masked and hidden texels keep
 * n0. normal (3 floats per texel, not hf->normal) receives the frame every texel was fitted
 * in, for a caller that reads the frames again in the same frames (the held-out
 * validation). estimate() runs in the fit's threads (thread-safe, no allocation).
 * photometric.h imp_photometric_frames() gives the photometric model's normals of the
 * bilinear reading, the frames whose shading matches the values the fit reads. */
enum imp_btf_frames_mode {
        IMP_BTF_FRAMES_EXTRACT,       /* extract the texel again in its frame (the rays of
                                         the first extraction reused through sp->rays when
                                         it records or reuses them; the others marched) */
        IMP_BTF_FRAMES_ROTATE,        /* turn the samples' l, v and e_cos into the new frame:
                                         no second extraction, but the lights the first
                                         frame cut (l[2] < min_cos_l) are missing */
};
struct imp_btf_frames {
        bool (*estimate)(const void *data, long texel, const struct imp_btf_sample *samples, int n,
                         const float n0[3], float ret_n[3]);
        const void *data;
        int mode;                     /* enum imp_btf_frames_mode */
        float *normal;                /* out: width·height·3, canvas frame */
};

struct imp_btf_fit_params {
        int min_samples;              /* fewer → FEW_SAMPLES, filled from neighbours (6) */
        double k_min, k_max;          /* lobe exponent bounds (1, 1000) */
        double c_max;                 /* |Cx|, |Cy| ≤ c_max in the Cz = 1 gauge (1: the lobe
                                         peaks at the mirror direction, see docs) */
        int max_iter;                 /* LM iterations per pass (30) */
        double tol;                   /* stop: relative cost decrease below this (1e-4) */
        int robust_passes;            /* Huber reweightings after the least-squares pass (2) */
        double huber_delta;           /* Huber threshold in robust σ (1.345) */
        double sigma_floor;           /* lower bound of the robust σ, white units (0.002) */
        double matte_threshold;       /* MATTE when the largest seen specular term < this (0.01) */
        double cxy_tau;               /* CX_EQ_CY when the Cx/Cy information ratio < this (1e-3) */
        double k_rel_uncertain;       /* LOBE_UNCERTAIN when σ(log k) > this (0.2) */
        double k_default;             /* k of the default lobe of MATTE / FEW_SAMPLES texels (10) */
        double c_prior_sigma;         /* prior σ of Cx, Cy around the mirror lobe (-1), as a
                                         pseudo-observation of σ sigma_floor (0.5) */
        double peak_seen_min;         /* k is lowered until the brightest seen lobe value is at
                                         least this fraction of the lobe's peak (0.15, the
                                         LOBE_UNCERTAIN level: no peak far above the data) */
        /* imp_btf_fit_grid's progress (NULL: none): texels done of total, some 50 times in a
         * fit, always from the calling thread; the last call has done == total. */
        void (*progress)(void *data, long done, long total);
        void *progress_data;
        /* imp_btf_fit_grid's frames estimated from the samples (struct imp_btf_frames
         * above; NULL: hf->normal's frames) */
        const struct imp_btf_frames *frames;
};
void imp_btf_fit_params_default(struct imp_btf_fit_params *ret);

/* The fitted texture of one texel. The lobe is normalised so that max(|Cx|,|Cy|,|Cz|)
 * = 1: the lobe peaks at 1 and ρs is the peak specular albedo. All fields are finite. */
struct imp_btf_texel {
        float rho_d[3], rho_s[3];
        float cx, cy, cz, k;
        float rms;                    /* RMS residual of V/E (white units, robust weights) */
        float cond;                   /* condition number of the equilibrated lobe normal
                                         matrix (1 = ideal; 0 = no lobe fitted; ≤ 1e12) */
        uint16_t n_samples;           /* usable samples */
        uint16_t flags;               /* enum imp_btf_flag */
};


/* Fit one texel from n samples (0 ≤ n ≤ IMP_BTF_MAX_SAMPLES; samples that are not
 * finite or have e_cos ≤ 0 or l[2] ≤ 0 are ignored). Thread-safe, allocates nothing.
 * Always fills *ret with finite values and flags (n < min_samples: matte estimate,
 * default lobe, FEW_SAMPLES). -E2BIG when n is too large, -EINVAL on bad params. */
int imp_btf_fit_texel(const struct imp_btf_sample *samples, int n, const struct imp_btf_fit_params *p,
                      struct imp_btf_texel *ret);

/* The k-th smallest of v[0..n) (0-based; v unchanged): the selection behind the fit's
 * robust scale (the median of the squared residuals), exported for its test. NaN when
 * n < 1 or k is outside [0, n). */
float imp_btf_kth_smallest(const float *v, int n, int k);

/* Fill texels flagged FEW_SAMPLES or HIDDEN (not MASKED) with the mean of their valid
 * 8-neighbours, growing inwards pass by pass; filled texels get FILLED. Texels with no
 * valid texel in reach keep their values. Returns the number filled. */
int imp_btf_fill(struct imp_btf_texel *texels, int width, int height);

struct imp_btf_stats {
        long n_fitted, n_matte, n_few, n_hidden, n_masked, n_filled, n_cx_eq_cy;
        long n_samples, n_shadowed;
};

/* The whole stage: one parallel loop (OpenMP) over the texels in which each thread
 * extracts a texel's samples into its own stack buffer and fits them, then imp_btf_fill().
 * tile_texels: the loop's scheduling chunk of consecutive texels (0 = 64); memory does not
 * depend on it. ret_texels: caller's array of hf->width·hf->height texels. ret_stats may
 * be NULL. Errors as the functions above, -ENOMEM. */
int imp_btf_fit_grid(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                     const struct imp_btf_sample_params *sp, const struct imp_btf_fit_params *fp,
                     int tile_texels, struct imp_btf_texel *ret_texels, struct imp_btf_stats *ret_stats);
