/* core/numerics: the Jacobi eigen-solver on matrices with known spectra (distinct and
 * repeated eigenvalues), Cholesky on SPD and non-SPD matrices, selection, quantiles and
 * the NaN policy of the comparators. Tolerances: 1e-12 on O(1) quantities (the methods
 * converge to a few ulps). */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "numerics.h"
#include "test.h"

#define TOL 1e-12

/* A·v = λ·v and |v| = 1 for each returned pair; the vectors mutually orthogonal. */
static void check_eigen3(const double A[9], const double want[3]) {
        double val[3], vec[9];
        imp_eigen_sym3(A, val, vec);
        for (int k = 0; k < 3; k++) {
                CHECK_NEAR(val[k], want[k], TOL);
                const double *v = vec + 3 * k;
                CHECK_NEAR(imp_norm3(v), 1.0, TOL);
                for (int i = 0; i < 3; i++)
                        CHECK_NEAR(A[3 * i] * v[0] + A[3 * i + 1] * v[1] + A[3 * i + 2] * v[2], val[k] * v[i], TOL);
                for (int l = k + 1; l < 3; l++)
                        CHECK_NEAR(imp_dot3(v, vec + 3 * l), 0.0, TOL);
        }
}

/* R·diag(d)·Rᵀ for a fixed rotation R (about an oblique axis), so the spectrum is d. */
static void rotated_diag(const double d[3], double ret[9]) {
        double ax[3] = { 1, 2, 3 }, th = 0.7;
        imp_normalize3(ax);
        double c = cos(th), s = sin(th), R[9] = {
                c + ax[0] * ax[0] * (1 - c), ax[0] * ax[1] * (1 - c) - ax[2] * s, ax[0] * ax[2] * (1 - c) + ax[1] * s,
                ax[1] * ax[0] * (1 - c) + ax[2] * s, c + ax[1] * ax[1] * (1 - c), ax[1] * ax[2] * (1 - c) - ax[0] * s,
                ax[2] * ax[0] * (1 - c) - ax[1] * s, ax[2] * ax[1] * (1 - c) + ax[0] * s, c + ax[2] * ax[2] * (1 - c),
        };
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        double t = 0;
                        for (int k = 0; k < 3; k++)
                                t += R[3 * i + k] * d[k] * R[3 * j + k];
                        ret[3 * i + j] = t;
                }
}

static void test_eigen(void) {
        const double diag[9] = { 3, 0, 0, 0, 1, 0, 0, 0, 2 }, want_diag[3] = { 1, 2, 3 };
        check_eigen3(diag, want_diag);
        /* [[2,1,0],[1,2,0],[0,0,5]]: 1, 3, 5 */
        const double B[9] = { 2, 1, 0, 1, 2, 0, 0, 0, 5 }, want_B[3] = { 1, 3, 5 };
        check_eigen3(B, want_B);
        const double d1[3] = { -0.5, 0.25, 4 }, d2[3] = { 2, 2, 7 }, d3[3] = { 1.5, 1.5, 1.5 }, d4[3] = { 0, 0, 1 };
        const double *ds[] = { d1, d2, d3, d4 };
        for (int t = 0; t < 4; t++) {
                double A[9];
                rotated_diag(ds[t], A);
                check_eigen3(A, ds[t]);
        }
        /* general n: 4×4 tridiagonal [2 -1; -1 2 -1; …]: λ_k = 2 − 2 cos(kπ/5) */
        double T[16] = { 2, -1, 0, 0, -1, 2, -1, 0, 0, -1, 2, -1, 0, 0, -1, 2 }, T0[16], l[4], V[16];
        memcpy(T0, T, sizeof T);
        imp_eigen_sym(4, T, l, V);
        for (int k = 0; k < 4; k++) {
                CHECK_NEAR(l[k], 2 - 2 * cos((k + 1) * M_PI / 5), TOL);
                for (int i = 0; i < 4; i++) {
                        double av = 0;
                        for (int j = 0; j < 4; j++)
                                av += T0[4 * i + j] * V[4 * j + k];
                        CHECK_NEAR(av, l[k] * V[4 * i + k], TOL);
                }
        }
}

static void test_cholesky(void) {
        /* SPD: A = M Mᵀ + I; solve against a known x */
        const double A0[9] = { 4, 2, 0.4, 2, 10, 3, 0.4, 3, 6 }, x[3] = { 1, -2, 0.5 };
        double A[9], b[3];
        memcpy(A, A0, sizeof A);
        for (int i = 0; i < 3; i++)
                b[i] = A0[3 * i] * x[0] + A0[3 * i + 1] * x[1] + A0[3 * i + 2] * x[2];
        CHECK(imp_cholesky_factor(3, A));
        CHECK_NEAR(A[0], 2.0, TOL);          /* L00 = √4 */
        CHECK_NEAR(A[3], 1.0, TOL);          /* L10 = 2/2 */
        imp_cholesky_solve(3, A, b);
        for (int i = 0; i < 3; i++)
                CHECK_NEAR(b[i], x[i], TOL);
        /* not positive definite: indefinite, singular, NaN */
        double indef[4] = { 1, 2, 2, 1 }, sing[4] = { 1, 1, 1, 1 }, nanm[4] = { NAN, 0, 0, 1 };
        CHECK(!imp_cholesky_factor(2, indef));
        CHECK(!imp_cholesky_factor(2, sing));
        CHECK(!imp_cholesky_factor(2, nanm));
}

static void test_order(void) {
        double odd[5] = { 5, 1, 4, 2, 3 }, even[4] = { 4, 1, 3, 2 }, q;
        CHECK_OK(imp_quantile(odd, 5, 0.5, &q));
        CHECK_NEAR(q, 3.0, 0);
        CHECK_OK(imp_quantile(even, 4, 0.5, &q));
        CHECK_NEAR(q, 2.5, 0);               /* even n: mean of the middle two */
        CHECK_OK(imp_quantile(odd, 5, 0.9, &q));
        CHECK_NEAR(q, 5.0, 0);               /* nearest rank ⌈4.5⌉ = 5th */
        CHECK_OK(imp_quantile(odd, 5, 0.2, &q));
        CHECK_NEAR(q, 1.0, 0);               /* ⌈1⌉ = 1st */
        CHECK_OK(imp_quantile(odd, 5, 0.0, &q));
        CHECK_NEAR(q, 1.0, 0);
        CHECK_OK(imp_quantile(odd, 5, 1.0, &q));
        CHECK_NEAR(q, 5.0, 0);
        /* NaN: ignored by the quantile, sorted last by the comparators */
        double withnan[6] = { NAN, 3, 1, NAN, 2, 4 };
        CHECK_OK(imp_quantile(withnan, 6, 0.5, &q));
        CHECK_NEAR(q, 2.5, 0);
        CHECK(isnan(withnan[4]) && isnan(withnan[5]) && withnan[0] == 1 && withnan[3] == 4);
        double allnan[2] = { NAN, NAN };
        q = -7;
        CHECK_ERR(imp_quantile(allnan, 2, 0.5, &q), -ENODATA);
        CHECK_ERR(imp_quantile(allnan, 0, 0.5, &q), -ENODATA);
        CHECK_ERR(imp_quantile(odd, 5, 1.5, &q), -EINVAL);
        CHECK_ERR(imp_quantile(odd, 5, NAN, &q), -EINVAL);
        CHECK_NEAR(q, -7, 0);                /* untouched on failure */
        double desc[5] = { 2, NAN, 5, 1, 3 };
        qsort(desc, 5, sizeof *desc, imp_cmp_double_desc);
        CHECK(desc[0] == 5 && desc[1] == 3 && desc[2] == 2 && desc[3] == 1 && isnan(desc[4]));
        float f[7] = { 0.5f, NAN, -1, 3, 2, NAN, 0 };
        qsort(f, 7, sizeof *f, imp_cmp_float);
        CHECK(f[0] == -1 && f[1] == 0 && f[2] == 0.5f && f[3] == 2 && f[4] == 3 && isnan(f[5]) && isnan(f[6]));
        /* selection agrees with a sort for every k, with repeated values */
        enum { N = 41 };
        float v[N], s[N];
        for (int i = 0; i < N; i++)
                s[i] = (float) ((i * 17) % 13);
        memcpy(v, s, sizeof v);
        qsort(s, N, sizeof *s, imp_cmp_float);
        for (size_t k = 0; k < N; k++) {
                float w[N];
                memcpy(w, v, sizeof w);
                CHECK_NEAR(imp_select_kth_float(w, N, k), s[k], 0);
        }
        float one = 7;
        CHECK_NEAR(imp_select_kth_float(&one, 1, 0), 7, 0);
}

static void test_vec3(void) {
        double a[3] = { 1, 0, 0 }, b[3] = { 0, 1, 0 }, c[3], z[3] = { 0, 0, 0 }, inf[3] = { INFINITY, 0, 0 };
        imp_cross3(a, b, c);
        CHECK(c[0] == 0 && c[1] == 0 && c[2] == 1);
        imp_cross3(a, b, a);                 /* aliasing the output is allowed */
        CHECK(a[0] == 0 && a[1] == 0 && a[2] == 1);
        CHECK(!imp_normalize3(z));
        CHECK(!imp_normalize3(inf) && isinf(inf[0]));
        double d[3] = { 3, 0, 4 };
        CHECK(imp_normalize3(d));
        CHECK_NEAR(d[0], 0.6, TOL);
        CHECK_NEAR(d[2], 0.8, TOL);
}

int main(void) {
        test_eigen();
        test_cholesky();
        test_order();
        test_vec3();
        return TEST_DONE();
}
