/* Names of the per-texel flags and copy verdicts (quality.h), as copy.json spells them. */
#include "quality.h"

static const char *const flag_names[IMP_TEXEL_FLAG_COUNT] = {
        "saturated", "dark", "shadowed", "interreflection", "photometric_rejected",
        "filled", "few_samples", "frame_adjacent", "phase_rejected", "fit_failed", "normal_uncertain",
};

/* What each flag means on the painting and what would lift it: the words of a verdict's reason. */
static const char *const flag_advice[IMP_TEXEL_FLAG_COUNT] = {
        "samples clipped at full scale: shorter exposures, or a bracket reaching further down",
        "too little signal: longer exposures or brighter lights",
        "lights or the projector shadowed by the relief or the frame: lights at higher elevation",
        "indirect light suspected: mask or darken what surrounds the canvas",
        "the paint does not follow the reflectance model there (gloss, translucency, varnish)",
        "no position measured, the shape integrated from normals",
        "fewer light samples than the fit needs (lights hidden by a deep frame or the relief, or too few "
        "in the plan): more lights, at higher elevations",
        "next to the frame or the canvas edge",
        "the structured-light code is inconsistent: projector focus and exposure",
        "the BTF fit did not converge",
        "the relief bends within one texel, so one normal per texel is not promised within 10° at 3σ: "
        "a camera resolving finer (closer, or a longer lens) and a finer --pitch",
};

const char *imp_texel_flag_advice(unsigned bit_index) {
        return bit_index < IMP_TEXEL_FLAG_COUNT ? flag_advice[bit_index] : NULL;
}

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
