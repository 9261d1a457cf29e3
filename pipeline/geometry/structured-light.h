/* Structured-light decoding: Gray-code frames (with inverses) and
 * optional N-step phase-shift frames, described by struct imp_pattern, become a
 * camera→projector correspondence map. Conventions, decision rules and measured figures:
 * docs/structured-light.md.
 *
 * Projector coordinates are continuous, in projector pixels, with the centre of pixel
 * column c at c + 0.5 (so pixel c covers [c, c+1)). Gray-only decoding returns the code's
 * centre c + 0.5; with phase frames the position is sub-pixel. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "captureset.h"
#include "image.h"

/* Per-pixel flags (result->flags). A pixel has a usable correspondence on an axis iff
 * its VALID_X / VALID_Y bit is set; every other bit says why not, or how weak it is. */
enum {
        IMP_SL_VALID_X        = 1 << 0,  /* proj_x decoded */
        IMP_SL_VALID_Y        = 1 << 1,  /* proj_y decoded */
        IMP_SL_SHADOW         = 1 << 2,  /* no projector modulation: white−black ≤ shadow
                                            threshold, or L_d < m (Xu & Aliaga rule 1) */
        IMP_SL_SATURATED      = 1 << 3,  /* some frame reached the saturation level */
        IMP_SL_WEAK_BIT       = 1 << 4,  /* exactly one Gray bit of an axis undecided:
                                            decided by sign, error ≤ 1 code, confidence halved */
        IMP_SL_UNDECODABLE    = 1 << 5,  /* ≥ 2 Gray bits of an axis undecided */
        IMP_SL_OUT_OF_RANGE   = 1 << 6,  /* code ≥ projector width/height */
        IMP_SL_LOW_MODULATION = 1 << 7,  /* phase amplitude below min_modulation (or a
                                            phase frame saturated): phase not used */
        IMP_SL_DISAGREE       = 1 << 8,  /* unwrapped phase and Gray code differ by more
                                            than max_disagreement_px: axis invalid */
        IMP_SL_SUBPIXEL_X     = 1 << 9,  /* proj_x refined by phase */
        IMP_SL_SUBPIXEL_Y     = 1 << 10, /* proj_y refined by phase */
        IMP_SL_PHASE_REJECTED = 1 << 11, /* the Gray centre was kept instead of the phase:
                                            the axis's phase as a whole disagreed with its
                                            Gray code more than the code's quantisation
                                            (imp_sl_result.phase_rejected), or this pixel's
                                            phase lies outside its Gray cell by more than
                                            phase_margin_px (sigma_px covers the
                                            disagreement) */
};

/* Value written to proj_x / proj_y where the axis is not valid (finite, out of range). */
#define IMP_SL_INVALID_COORD (-1.0f)

struct imp_sl_params {
        int proj_width, proj_height;  /* projector size in pixels; 0: 2^nbits of the axis */
        /* Intensity thresholds are in the input's units: digital numbers for u8/u16
         * frames, linear values for f32 frames. imp_sl_params_default() picks values. */
        double shadow_threshold;      /* white − black must exceed this (OpenCV's
                                         "black threshold", 40 for 8-bit) */
        double min_bit_contrast;      /* |p − p̄| below this: bit undecided (OpenCV's
                                         "white threshold", 5 for 8-bit) */
        double min_direct;            /* m of Xu & Aliaga: L_d below it → shadow */
        double black_level;           /* b, projector black/white ratio in [0, 1) */
        double saturation;            /* sample ≥ this counts as saturated; ≤ 0: full
                                         scale of the type (255, 65535; f32: never) */
        double min_modulation;        /* phase amplitude B below it: phase not used */
        double max_disagreement_px;   /* |phase − Gray centre| allowed (projector px) */
        int dg_planes;                /* finest Gray planes per axis used for L_d/L_g */
        /* Phase response: a projector with gamma γ turns the sinusoid into one with
         * harmonics, which N steps alias onto the fundamental (harmonic N−1 and N+1: for
         * N = 3 the 2nd, ≈ 0.28 rad at γ = 2.2). With γ known (radiometric calibration)
         * the decoder inverts that response; 0 or 1: taken as linear. */
        double projector_gamma;
        double projector_defocus_px;  /* Gaussian σ of the projector's blur, projector px,
                                         for the phase response (0: sharp) */
        double phase_margin_px;       /* a pixel whose phase lies farther than q/2 + this
                                         from its Gray centre (q the code's quantum; one
                                         code more with a weak bit) but within
                                         max_disagreement_px keeps the Gray centre and is
                                         flagged IMP_SL_PHASE_REJECTED: Gray and phase
                                         cannot both be right there. Default 0.5 px;
                                         INFINITY: off */
        bool keep_phase;              /* false (default): an axis whose phase disagrees with
                                         its Gray code more than the code's quantisation
                                         falls back to the Gray centre; true: keep it */
        bool robust;                  /* Xu & Aliaga classification; false: sign only */
        bool coords_only;             /* true: the result has no direct, global and
                                         modulation maps (NULL; 12 of its 26 bytes a pixel
                                         neither allocated nor written), for callers that
                                         read only coordinates, flags, confidence and σ
                                         (triangulation). Every other map and count is
                                         the same as without it. Default false */
        bool direct_only;             /* true (without coords_only): of the light maps only
                                         direct is kept (global and modulation NULL, 8
                                         bytes a pixel fewer), for callers that read L_d
                                         alone (process.c's albedo for the flush-frame
                                         trim). Every other map and count is the same.
                                         Default false */
        int threads;                  /* OpenMP threads; 0: OpenMP default */
};

/* Defaults for frames of the given pixel type (8-bit values scaled to the type's range;
 * f32 frames are taken as linear with white ≈ 1). */
void imp_sl_params_default(struct imp_sl_params *p, enum imp_pixel_type type);

/* The frames of one camera view: patterns[i] was projected while images[i] was taken.
 * Images: 1 channel, all the same size and pixel type (u8, u16 or f32). Order is free.
 * Gray planes need their inverses, or else WHITE and BLACK frames (then p̄ = W + B − p).
 * saturated (may be NULL, entries may be NULL): a u8 image per frame, same size, nonzero
 * where the sample was clipped — what a value cannot say once an HDR merge has turned
 * the frames into f32 (the merge's IMP_HDR_SATURATED; imp_hdr_saturated_mask()). A pixel
 * saturated in any frame the decode reads is IMP_SL_SATURATED; saturation in a phase
 * frame also sets IMP_SL_LOW_MODULATION (the clipped sinusoid's phase is biased: the
 * Gray centre is kept, with its σ). */
struct imp_sl_frames {
        const struct imp_pattern *patterns;
        const struct imp_image *const *images;
        int n;
        const struct imp_image *const *saturated;
};

struct imp_sl_result {
        int width, height;            /* camera pixels; maps are row-major, width apart */
        float *proj_x, *proj_y;       /* projector coordinates (see top); INVALID_COORD
                                         where the axis is not valid */
        /* 0..1 in 16-bit fixed point: imp_sl_conf() reads it (within 7.8e-6 of the
         * decoder's value); 0 where neither axis is valid */
        uint16_t *confidence;
        uint16_t *flags;              /* IMP_SL_* */
        float *direct, *global;       /* L_d, L_g estimates (input units, ≥ 0); NULL
                                         with coords_only, as is modulation; global and
                                         modulation NULL with direct_only */
        float *modulation;            /* phase amplitude B (min over axes), 0 without phase */
        /* 1σ of the decoded projector coordinate, projector px, the larger over the valid
         * axes (0 where none is valid): what the decoder knows of its own error. A Gray
         * centre: q/√12 (q the code's quantum), √(q²/12 + q²/4) with a weak bit (one code
         * may be wrong); a phase rejected on this pixel: √(q²/12 + d²), d its
         * disagreement with the Gray centre; a phase: phase_err_px of the axis where
         * measured, else 0 (the caller's own model applies, e.g. imp_triangulate's
         * sigma_proj_px / confidence, which takes the larger of the two).
         * Stored as bfloat16 (a float's upper half, rounded to nearest even): imp_sl_sigma()
         * reads it, within 2^-8 of the value relative (0.4 %); 0 stays 0. */
        uint16_t *sigma_px;
        size_t n_valid_x, n_valid_y, n_valid_xy;
        size_t n_shadow, n_saturated, n_weak, n_disagree;
        /* Per axis (x, y), for axes with Gray code and phase: the phase's error RMS in
         * projector pixels estimated from its disagreement with the Gray code,
         * √(mean (u − Gray centre)² − q²/12) with q the Gray code's quantum, over pixels
         * with every Gray bit decided; −1 where not measured. phase_rejected: that error
         * exceeded the Gray code's own (q/√12), so the axis holds Gray centres instead. */
        float phase_err_px[2];
        bool phase_rejected[2];
};

/* The maps' narrow encodings. Confidence c ∈ [0, 1] is stored as ⌊c·65535 + ½⌋ (error ≤
 * 0.51/65535 with the float product's rounding); σ as bfloat16 (round to nearest even:
 * relative error ≤ 2^-8; 0 and every value with 8 significant bits exact). */
#define IMP_SL_CONF_ONE 65535
static inline float imp_sl_conf(uint16_t c) {
        return (float) c / (float) IMP_SL_CONF_ONE;
}
static inline float imp_sl_sigma(uint16_t s) {
        union { uint32_t u; float f; } v = { .u = (uint32_t) s << 16 };
        return v.f;
}
/* The encoders the decoder uses (exported for tests and writers of results). c outside
 * [0, 1] or NaN: clamped (NaN → 0); s ≥ 0 finite. */
static inline uint16_t imp_sl_conf16(float c) {
        c = c > 1.0f ? 1.0f : c > 0.0f ? c : 0.0f;
        return (uint16_t) (int32_t) (c * (float) IMP_SL_CONF_ONE + 0.5f);
}
static inline uint16_t imp_sl_sigma16(float s) {
        union { float f; uint32_t u; } v = { .f = s };
        return (uint16_t) ((v.u + 0x7fffu + ((v.u >> 16) & 1u)) >> 16);
}

/* Decodes one view. *ret is allocated here; caller frees with imp_sl_result_free().
 * -EINVAL with a message in err for an inconsistent pattern set (missing or duplicate
 * bit planes or phase steps, N < 3, mismatched images), -ENOMEM. */
int imp_sl_decode(const struct imp_sl_frames *in, const struct imp_sl_params *p,
                  struct imp_sl_result **ret, struct imp_error *err);
/* As imp_sl_decode, into *ret when it is a result of the frames' size (from an earlier
 * decode with the same coords_only and direct_only): every map and count is written anew, so a caller
 * decoding view after view saves allocating and faulting in 26 bytes a pixel each time (page
 * faults and the kernel's zeroing of the fresh pages). Otherwise (NULL, another size, or maps
 * that coords_only or direct_only adds or drops) *ret is freed and replaced by a new result. On error *ret is left as it was (its maps' contents unspecified). */
int imp_sl_decode_reuse(const struct imp_sl_frames *in, const struct imp_sl_params *p,
                        struct imp_sl_result **ret, struct imp_error *err);
void imp_sl_result_free(struct imp_sl_result *r);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_sl_result *, imp_sl_result_free);

/* Number of Gray bits needed for `extent` projector pixels: ceil(log2(extent)). */
int imp_sl_gray_bits(int extent);

/* Projector intensity (0 = black, 1 = white, before gamma and black level) that pattern
 * `pat` gives to projector pixel (px, py). Gray: bit `bit` (0 = MSB) of the reflected
 * binary code px ^ (px >> 1), lit when 1 — exactly OpenCV's GrayCodePattern (4.x).
 * Phase: ½ + ½ cos(2π (c + 0.5) / period_px + 2π step / steps), c the axis coordinate. */
double imp_sl_pattern_value(const struct imp_pattern *pat, int px, int py);

/* The standard sequence for a proj_w × proj_h projector, in OpenCV's order: column planes
 * MSB→LSB each followed by its inverse, then row planes, then WHITE, BLACK; then, when
 * phase_steps ≥ 3, phase_steps frames per axis for each period in periods_px (n_periods).
 * *ret is malloc'd (caller frees with free()), *ret_n its length. */
int imp_sl_sequence(int proj_w, int proj_h, int phase_steps, const double *periods_px,
                    int n_periods, struct imp_pattern **ret, int *ret_n);
