/* The copy's honesty vocabulary: per-texel reliability flags, shared by every stage that
 * can fail, and the verdict on a whole copy (copy.json "quality", docs/copy-quality.md).
 * A texel's σ (height and normal) must cover its real error when it carries no flag; a
 * flag says why it may not. Stages set flags, never clear another stage's. */
#pragma once
#include <stddef.h>
#include <stdint.h>

/* Per-texel flags (bits of heightfield.exr's "flags" channel, stored as float). */
enum imp_texel_flag {
        IMP_TEXEL_SATURATED      = 1u << 0,  /* a sample it relies on was saturated */
        IMP_TEXEL_DARK           = 1u << 1,  /* signal below the noise floor in most samples */
        IMP_TEXEL_SHADOWED       = 1u << 2,  /* projector or light shadow: few usable samples */
        IMP_TEXEL_INTERREFLECTION= 1u << 3,  /* indirect light suspected (residual pattern) */
        IMP_TEXEL_PHOTOMETRIC_REJECTED = 1u << 4, /* photometric model did not fit: the
                                                     geometric normal was kept */
        IMP_TEXEL_FILLED         = 1u << 5,  /* no position measured: shape from normals */
        IMP_TEXEL_FEW_SAMPLES    = 1u << 6,  /* fewer samples than the fit needs */
        IMP_TEXEL_FRAME_ADJACENT = 1u << 7,  /* within a few texels of the frame or the
                                                canvas edge */
        IMP_TEXEL_PHASE_REJECTED = 1u << 8,  /* structured-light decode inconsistent
                                                (Gray vs phase), position from Gray only */
        IMP_TEXEL_FIT_FAILED     = 1u << 9,  /* BTF fit did not converge or hit a bound */
        IMP_TEXEL_NORMAL_UNCERTAIN = 1u << 10, /* normal σ above IMP_TEXEL_NORMAL_SIGMA_MAX_DEG,
                                                 or next to a texel whose normal is not
                                                 vouched for (normal-trust.h): the normal
                                                 cannot be promised within 10° */
};
#define IMP_TEXEL_FLAG_COUNT 11
#define IMP_TEXEL_NORMAL_SIGMA_MAX_DEG (10.0 / 3)   /* 3σ_n = 10° */

/* The flag's name as it appears in copy.json ("saturated", "dark", …); NULL past the end. */
const char *imp_texel_flag_name(unsigned bit_index);
/* What the flag means on the painting and what would lift it, one clause; NULL past the end. */
const char *imp_texel_flag_advice(unsigned bit_index);

/* The verdict on a whole copy. */
enum imp_verdict {
        IMP_VERDICT_OK = 0,      /* σ and flags describe the copy; nothing unusual */
        IMP_VERDICT_DEGRADED,    /* usable, but a notable fraction is flagged or a stage
                                    backed off: the reasons say which */
        IMP_VERDICT_UNUSABLE,    /* not a measurement of this painting: refused */
};
const char *imp_verdict_name(enum imp_verdict v);   /* "ok", "degraded", "unusable" */
