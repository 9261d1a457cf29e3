/* σ_h of heights the fusion moved (imp_heightfield_sigma_moved, docs/copy-quality.md): a
 * measured texel moved by Δ gets √(σ_h² + Δ²) (tolerance 1e-6 mm), one that did not move
 * keeps its σ_h exactly, a filled texel and one off the mask keep theirs whatever moved,
 * and a NaN height leaves σ_h as it was (no NaN written); a NULL reference changes
 * nothing. On hard-tilted-25 the fusion moved a ridge's cliff by 60–130 µm under the
 * triangulation's σ_h of 19 µm: 2.9 % of the unflagged heights beyond 3σ before. */
#include <math.h>
#include <string.h>
#include "heightfield.h"
#include "unit/test.h"

#define N 5

int main(void) {
        float h[N] = { 1.0f, 0.5f, 0.2f, 0.3f, NAN };
        float ref[N] = { 1.1f, 0.5f, 0.0f, 0.0f, 0.4f };
        float sig[N] = { 0.02f, 0.02f, 0.01f, 0.01f, 0.02f };
        uint8_t mask[N] = { IMP_HF_MASK_MEASURED, IMP_HF_MASK_MEASURED, IMP_HF_MASK_FILLED, 0, IMP_HF_MASK_MEASURED };
        struct imp_heightfield hf = { .nx = N, .ny = 1, .height_mm = h, .sigma_mm = sig, .mask = mask };

        imp_heightfield_sigma_moved(&hf, NULL);
        CHECK_NEAR(sig[0], 0.02, 1e-9);

        imp_heightfield_sigma_moved(&hf, ref);
        CHECK_NEAR(sig[0], hypot(0.02, 0.1), 1e-6);    /* moved by 0.1 mm */
        CHECK_MSG(sig[1] == 0.02f, "an unmoved texel's σ_h changed: %g", sig[1]);
        CHECK_MSG(sig[2] == 0.01f, "a filled texel's σ_h changed: %g", sig[2]);
        CHECK_MSG(sig[3] == 0.01f, "a texel off the mask changed: %g", sig[3]);
        CHECK_MSG(sig[4] == 0.02f, "a NaN height changed σ_h to %g", sig[4]);
        return TEST_DONE();
}
