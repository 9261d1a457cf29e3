/* The photometric texel model (imp_photometric_texel) against main's as it was before it
 * was made faster (pn-model-peer.c, copied unchanged): on texels of pn-model-set.h (the
 * demo's dome; matte and glossy paints, ambient terms, cast shadows under the filled
 * texels' parameters, dark paint, few lights) and on the edge cases the set does not
 * reach (lights from one side only, rows that load_rows drops, too few rows), the two
 * must give the same flags and sample counts, normals within 1e-6 rad and every other
 * figure within 1e-6 relative. They are bit-identical today; the tolerances are what a
 * faster model that is not may differ by. The set must reach every flag the model sets,
 * or the comparison would not cover that branch. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include "pn-model-peer.h"
#include "pn-model-set.h"
#include "test.h"

#define N_TEXELS 3000

static long n_identical, n_compared;
static uint16_t flags_seen;

static bool rel_close(double a, double b) {
        return fabs(a - b) <= 1e-6 * fmax(1e-12, fmax(fabs(a), fabs(b)));
}

static void compare_texel(const struct imp_btf_sample *s, int n, const struct imp_photometric_params *p, int id) {
        struct imp_pn_texel a, b;
        CHECK_OK(imp_photometric_texel(s, n, p, &a));
        CHECK_OK(pn_model_peer_texel(s, n, p, &b));
        n_compared++;
        n_identical += !memcmp(&a, &b, sizeof a);
        flags_seen |= b.flags;
        CHECK_MSG(a.flags == b.flags, "texel %d: flags %#x, main's %#x", id, a.flags, b.flags);
        CHECK_MSG(a.n_used == b.n_used, "texel %d: %d samples used, main's %d", id, a.n_used, b.n_used);
        double d = 0, la = 0, lb = 0;
        for (int k = 0; k < 3; k++) {
                d += (double) a.n[k] * b.n[k];
                la += (double) a.n[k] * a.n[k];
                lb += (double) b.n[k] * b.n[k];
        }
        double ang = acos(fmin(1.0, d / sqrt(la * lb)));
        CHECK_MSG(ang <= 1e-6, "texel %d: normal %.3g rad from main's", id, ang);
        CHECK_MSG(rel_close(a.sigma_deg, b.sigma_deg) && rel_close(a.albedo, b.albedo) && rel_close(a.rms, b.rms) &&
                          rel_close(a.ambient, b.ambient) && rel_close(a.cond, b.cond) &&
                          rel_close(a.dev_deg, b.dev_deg),
                  "texel %d: σ %.9g/%.9g albedo %.9g/%.9g rms %.9g/%.9g c %.9g/%.9g cond %.9g/%.9g dev %.9g/%.9g",
                  id, a.sigma_deg, b.sigma_deg, a.albedo, b.albedo, a.rms, b.rms, a.ambient, b.ambient, a.cond,
                  b.cond, a.dev_deg, b.dev_deg);
}

/* The set's texels, each also with only the samples whose light lies within ±30° of
 * azimuth of a random direction (lights from one side: ill-conditioned or few). */
static void test_set(const struct imp_photometric_params *p, const struct imp_photometric_params *pf) {
        struct imp_rig_light L[64];
        int nl = pn_set_dome(L);
        static struct pn_set_texel t;
        struct imp_btf_sample side[64];
        uint64_t rng = 0xabcdefULL;
        for (int i = 0; i < N_TEXELS; i++) {
                pn_set_texel(0x7e57ULL, i, L, nl, &t);
                compare_texel(t.s, t.n, t.filled ? pf : p, i);
                double az0 = 2 * M_PI * test_urand(&rng);
                int m = 0;
                for (int k = 0; k < t.n; k++)
                        if (fabs(remainder(atan2(t.s[k].l[1], t.s[k].l[0]) - az0, 2 * M_PI)) < 30 * M_PI / 180)
                                side[m++] = t.s[k];
                compare_texel(side, m, p, N_TEXELS + i);
        }
}

/* Rows load_rows() drops (non-finite, e_cos ≤ 0, l[2] ≤ 0) mixed into good ones, and
 * samples under one light repeated (a singular normal matrix: the Jacobi solver's path). */
static void test_bad_rows(const struct imp_photometric_params *p) {
        struct imp_rig_light L[64];
        int nl = pn_set_dome(L);
        static struct pn_set_texel t;
        for (int i = 0; i < 200; i++) {
                pn_set_texel(0xbadULL, i, L, nl, &t);
                for (int k = i % 5; k < t.n; k += 5)
                        switch ((k / 5) % 4) {
                        case 0: t.s[k].value[1] = NAN; break;
                        case 1: t.s[k].e_cos = 0; break;
                        case 2: t.s[k].l[2] = -0.1f; break;
                        default: t.s[k].v[0] = INFINITY; break;
                        }
                compare_texel(t.s, t.n, p, 10 * N_TEXELS + i);
                for (int k = 1; k < t.n; k++)   /* one light, many times: singular */
                        t.s[k] = t.s[k % 2];
                compare_texel(t.s, t.n, p, 11 * N_TEXELS + i);
        }
        compare_texel(t.s, 0, p, -1);
}

int main(void) {
        struct imp_photometric_params p, pf;
        imp_photometric_params_default(&p);
        pf = p;
        pn_set_filled_params(&pf);
        test_set(&p, &pf);
        test_bad_rows(&p);
        static const uint16_t all = IMP_PN_FEW_SAMPLES | IMP_PN_ILL_COND | IMP_PN_DARK | IMP_PN_DISAGREES |
                                    IMP_PN_MASKED | IMP_PN_AMBIENT | IMP_PN_RESIDUAL;
        CHECK_MSG((flags_seen & all) == all, "the texels reach flags %#x of %#x", flags_seen & all, all);
        fprintf(stderr, "%ld of %ld texels bit-identical to main's model\n", n_identical, n_compared);
        return TEST_DONE();
}
