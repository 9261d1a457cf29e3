/* The median of a photometric texel's few values (photometric.c's residual scale and shadow
 * trim) in vector lanes, as an inline body: photometric.c builds it for AVX-512, AVX2 and the
 * x86-64 baseline as target clones, and tests/unit/test-photometric-model.c builds each of
 * them to compare them with a sort. Comparisons only, so every build gives the same value. */
#pragma once
#include <math.h>
#include <stdbool.h>
#include <string.h>

typedef double imp_pn_v8 __attribute__((vector_size(64)));
typedef long long imp_pn_v8l __attribute__((vector_size(64)));

/* The counts of a[0..n) below and at or below each lane of *c. */
static inline __attribute__((always_inline)) void imp_pn_median_counts(const double *a, int n, const imp_pn_v8 *c,
                                                                       imp_pn_v8l *ret_lt, imp_pn_v8l *ret_le) {
        imp_pn_v8l lt = { 0 }, le = { 0 };
        for (int j = 0; j < n; j++) {
                lt -= a[j] < *c;   /* a true lane is −1 */
                le -= a[j] <= *c;
        }
        *ret_lt = lt, *ret_le = le;
}

/* Median of v[0..n) (n ≤ IMP_BTF_MAX_SAMPLES, no NaN; tmp holds n + 8): the values of sorted
 * ranks n/2 and, for an even n, n/2 − 1. The value of rank k is the x with lt(x) ≤ k < le(x)
 * (the counts below x and at or below it), whatever the ties. Eight elements spread over v
 * are counted at once in vector lanes as pivots: the largest pivot c with le(c) ≤ lo and
 * the smallest with lt(c) > hi bracket both ranks, which are then ranks k − le(c) among the
 * elements strictly inside the bracket (2n/9 of them on average), and those are counted
 * among themselves eight at a time. No branch on the data but the loops' lengths (the
 * lanes' selections are masks); the comparisons only, so that every clone gives the same
 * value (but for the sign of a zero among tied zeros, which no comparison with the median
 * can tell). On the bench's 52 369 medians of 41.6 values, timed alone: ≈ 235 ns a call
 * against 360–370 ns for the bracketed rank counts before it and 1 220 ns for qsort
 * (docs/processing-speed.md, h20m-model). */
static inline __attribute__((always_inline)) double imp_pn_median_small(const double *restrict v, int n,
                                                                        double *restrict tmp) {
        if (n <= 0)
                return 0;
        const int hi = n / 2, lo = n & 1 ? hi : hi - 1;
        imp_pn_v8 c;
        for (int l = 0; l < 8; l++)
                c[l] = v[l * n / 8];
        imp_pn_v8l lt, le;
        imp_pn_median_counts(v, n, &c, &lt, &le);
        /* the bracket, without a branch: lanes outside it masked to ∓∞ (lv, uv) and 0 (base) */
        const imp_pn_v8l below = le <= lo, above = lt > hi;
        const imp_pn_v8 inf = { INFINITY, INFINITY, INFINITY, INFINITY, INFINITY, INFINITY, INFINITY, INFINITY };
        const imp_pn_v8 cb = (imp_pn_v8) (((imp_pn_v8l) c & below) | ((imp_pn_v8l) -inf & ~below));
        const imp_pn_v8 ca = (imp_pn_v8) (((imp_pn_v8l) c & above) | ((imp_pn_v8l) inf & ~above));
        const imp_pn_v8l lb = le & below;
        double lv = -INFINITY, uv = INFINITY;
        long long base = 0;   /* le(lv), le being monotonic in the value */
        for (int l = 0; l < 8; l++) {
                lv = cb[l] > lv ? cb[l] : lv;
                uv = ca[l] < uv ? ca[l] : uv;
                base = lb[l] > base ? lb[l] : base;
        }
        int s = 0;
        for (int i = 0; i < n; i++) {
                tmp[s] = v[i];
                s += (lv < v[i]) & (v[i] < uv);
        }
        for (int i = s; i < s + 8; i++)   /* NaN: counted in no lane, found in none */
                tmp[i] = NAN;
        const long long klo = lo - base, khi = hi - base;
        /* the lanes holding ranks klo and khi, ORed in: one value each (ties: the same bits) */
        imp_pn_v8l fa = { 0 }, fb = { 0 };
        for (int i = 0; i < s; i += 8) {
                imp_pn_v8 w;
                memcpy(&w, tmp + i, sizeof w);
                imp_pn_median_counts(tmp, s, &w, &lt, &le);
                fa |= (imp_pn_v8l) w & ((lt <= klo) & (le > klo));
                fb |= (imp_pn_v8l) w & ((lt <= khi) & (le > khi));
        }
        long long ba = 0, bb = 0;
        for (int l = 0; l < 8; l++)
                ba |= fa[l], bb |= fb[l];
        double a, b;
        memcpy(&a, &ba, sizeof a);
        memcpy(&b, &bb, sizeof b);
        return lo == hi ? b : 0.5 * (a + b);
}
