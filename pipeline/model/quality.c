/* Names of the per-texel flags and copy verdicts (quality.h), as copy.json spells them. */
#include "quality.h"

static const char *const flag_names[IMP_TEXEL_FLAG_COUNT] = {
        "saturated", "dark", "shadowed", "interreflection", "photometric_rejected",
        "filled", "few_samples", "frame_adjacent", "phase_rejected", "fit_failed", "normal_uncertain",
};

const char *imp_texel_flag_name(unsigned bit_index) {
        return bit_index < IMP_TEXEL_FLAG_COUNT ? flag_names[bit_index] : NULL;
}

const char *imp_verdict_name(enum imp_verdict v) {
        switch (v) {
        case IMP_VERDICT_OK:       return "ok";
        case IMP_VERDICT_DEGRADED: return "degraded";
        case IMP_VERDICT_UNUSABLE: return "unusable";
        }
        return "unknown";
}
