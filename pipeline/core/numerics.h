/* Small dense numerics every layer shares: 3-vectors, the symmetric eigen-problem (cyclic
 * Jacobi), Cholesky, and order statistics (comparators, selection, quantiles). Pure
 * functions: no allocation, no logging. */
#pragma once
#include <math.h>
#include <stdbool.h>
#include <stddef.h>

/* ---- 3-vectors ---- */

static inline double imp_dot3(const double a[3], const double b[3]) {
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static inline double imp_norm3(const double a[3]) { return sqrt(imp_dot3(a, a)); }
static inline void imp_cross3(const double a[3], const double b[3], double ret[3]) {
        double r[3] = { a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0] };
        ret[0] = r[0], ret[1] = r[1], ret[2] = r[2];
}
static inline void imp_sub3(const double a[3], const double b[3], double ret[3]) {
        ret[0] = a[0] - b[0], ret[1] = a[1] - b[1], ret[2] = a[2] - b[2];
}
/* Scales v to unit length; false (v untouched) when its length is 0 or not finite. */
static inline bool imp_normalize3(double v[3]) {
        double l = imp_norm3(v);
        if (!(l > 0) || !isfinite(l))
                return false;
        v[0] /= l, v[1] /= l, v[2] /= l;
        return true;
}

/* ---- symmetric eigen-problem ---- */

/* Eigen-decomposition of the symmetric n×n A (row-major, destroyed) by cyclic Jacobi
 * rotations (Golub & Van Loan, Matrix Computations, §8.5): eigenvalues ascending into
 * ret_val[n]; eigenvector k as column k of ret_vec (n×n row-major, ret_vec[i*n + k]), or
 * ret_vec NULL. Stops when the off-diagonal sum of squares is ≤ 1e-30 × the diagonal's, or
 * after 60 sweeps (a symmetric input converges in < 10). Repeated eigenvalues are fine:
 * their vectors are an orthonormal basis of the eigenspace. Only the upper and lower
 * triangles' agreement is assumed, not checked. */
void imp_eigen_sym(int n, double *A, double *ret_val, double *ret_vec);

/* The same for a 3×3 A (not modified): eigenvalues ascending in ret_val, the unit
 * eigenvector of ret_val[k] in ret_vec[3k .. 3k+2] (one vector per row). */
void imp_eigen_sym3(const double A[9], double ret_val[3], double ret_vec[9]);

/* ---- Cholesky ---- */

/* In-place Cholesky A = L Lᵀ of the symmetric n×n A (row-major): L in the lower triangle
 * (the strict upper triangle is left as it was). Reads only the lower triangle. Returns
 * false when A is not positive definite (a pivot ≤ 0 or NaN); A is then partly overwritten. */
bool imp_cholesky_factor(int n, double *A);

/* Solves L Lᵀ x = b in place (b becomes x), L from imp_cholesky_factor(). */
void imp_cholesky_solve(int n, const double *L, double *b);

/* ---- order statistics ---- */

/* qsort comparators, ascending (desc: descending). NaN sorts after every number in both,
 * so that a sort is well defined on any input and the NaNs gather at the end. */
int imp_cmp_float(const void *a, const void *b);
int imp_cmp_double(const void *a, const void *b);
int imp_cmp_double_desc(const void *a, const void *b);

/* k-th smallest (0-based, k < n) of v[0..n), by quickselect (Hoare partition, middle pivot);
 * reorders v. The input must hold no NaN (the result is then unspecified, though the
 * call stays within v and returns one of its elements). */
float imp_select_kth_float(float *v, size_t n, size_t k);

/* On an ascending array without NaN: the median (mean of the two middle values when n is
 * even) and the q-quantile by nearest rank (the ⌈qn⌉-th smallest, 1-based; q = 0.5 gives
 * the median). n must be ≥ 1, 0 ≤ q ≤ 1. */
double imp_median_sorted(const double *v, size_t n);
double imp_quantile_sorted(const double *v, size_t n, double q);

/* Sorts v[0..n) (NaN last) and returns in *ret the q-quantile of its values that are not
 * NaN, as imp_quantile_sorted(). -ENODATA when none is (n = 0 or all NaN), -EINVAL when q
 * is not within [0, 1]; *ret untouched then. */
int imp_quantile(double *v, size_t n, double q, double *ret);

/* ---- phase shifting ---- */

/* The phase θ ∈ (−π, π] of N-step phase-shift samples I_k = A + B cos(θ + 2πk/n),
 * k = 0 … n−1 (n ≥ 3): θ = atan2(−Σ I_k sin δ_k, Σ I_k cos δ_k), δ_k = 2πk/n, the phase of
 * the samples' first Fourier coefficient (Malacara, Optical Shop Testing, §14.2). */
double imp_phase_nstep(const double *I, int n);
