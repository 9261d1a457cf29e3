/* The photometric texel model (imp_photometric_texel) against main's as it was before it
 * was made faster (pn-model-peer.c, copied unchanged): on texels of pn-model-set.h (the
 * demo's dome; matte and glossy paints, ambient terms, cast shadows under the filled
 * texels' parameters, dark paint, few lights) and on the edge cases the set does not
 * reach (lights from one side only, rows that load_rows drops, too few rows), the two
 * must give the same flags and sample counts, normals within 1e-6 rad and every other
 * figure within 1e-6 relative. They are bit-identical today; the tolerances are what a
 * faster model that is not may differ by. The set must reach every flag the model sets,
 * or the comparison would not cover that branch. The model's median (pn-median.h) is built
 * for AVX-512, AVX2 and the baseline; each build the CPU can run must give a sort's
 * median, bit for bit. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include "pn-model-peer.h"
#include "pn-model-set.h"
#include "pn-median.h"
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

static double median_base(const double *v, int n, double *tmp) {
        return imp_pn_median_small(v, n, tmp);
}
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
__attribute__((target("avx2"))) static double median_avx2(const double *v, int n, double *tmp) {
        return imp_pn_median_small(v, n, tmp);
}
__attribute__((target("avx512f"))) static double median_avx512(const double *v, int n, double *tmp) {
        return imp_pn_median_small(v, n, tmp);
}
#endif

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return x < y ? -1 : x > y;
}

/* Values of kind k: uniform, few distinct (ties), sorted up, sorted down, all equal, and
 * residual-like |N(0, 1)| with a few outliers. */
static void median_values(int kind, int n, uint64_t *rng, double *v) {
        for (int i = 0; i < n; i++) {
                double u = test_urand(rng);
                switch (kind) {
                case 0: v[i] = u - 0.5; break;
                case 1: v[i] = floor(4 * u); break;
                case 2: v[i] = i + 0.25 * u; break;
                case 3: v[i] = n - i; break;
                case 4: v[i] = 1.5; break;
                default: v[i] = fabs(test_nrand(rng)) * (u < 0.1 ? 30 : 1); break;
                }
        }
}

static void test_median(void) {
        typedef double (*median_fn)(const double *, int, double *);
        struct { const char *name; median_fn f; bool ok; } builds[] = {
                { "baseline", median_base, true },
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
                { "avx2", median_avx2, __builtin_cpu_supports("avx2") },
                { "avx512f", median_avx512, __builtin_cpu_supports("avx512f") },
#endif
        };
        static double v[IMP_BTF_MAX_SAMPLES], sorted[IMP_BTF_MAX_SAMPLES], tmp[IMP_BTF_MAX_SAMPLES + 8];
        uint64_t rng = 0x3edULL;
        long n_checked = 0;
        for (int n = 1; n <= IMP_BTF_MAX_SAMPLES; n += n < 80 ? 1 : 37)
                for (int kind = 0; kind < 6; kind++)
                        for (int rep = 0; rep < 4; rep++) {
                                median_values(kind, n, &rng, v);
                                memcpy(sorted, v, sizeof v[0] * n);
                                qsort(sorted, n, sizeof sorted[0], cmp_double);
                                double want = n & 1 ? sorted[n / 2] : 0.5 * (sorted[n / 2 - 1] + sorted[n / 2]);
                                for (size_t b = 0; b < sizeof builds / sizeof builds[0]; b++) {
                                        if (!builds[b].ok)
                                                continue;
                                        double got = builds[b].f(v, n, tmp);
                                        n_checked++;
                                        CHECK_MSG(!memcmp(&got, &want, sizeof got), "median %s, n %d, kind %d: %.17g, sort's %.17g",
                                                  builds[b].name, n, kind, got, want);
                                }
                        }
        for (size_t b = 0; b < sizeof builds / sizeof builds[0]; b++)
                fprintf(stderr, "median %s: %s\n", builds[b].name, builds[b].ok ? "checked" : "not on this CPU");
        CHECK(n_checked > 0);
}

int main(void) {
        test_median();
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
