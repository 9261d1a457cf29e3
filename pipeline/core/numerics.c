/* Shared small numerics: Jacobi eigen-solver, Cholesky, selection and quantiles.
 * numerics.h states each function's domain. */
#include <errno.h>
#include <string.h>
#include <stdlib.h>
#include "numerics.h"

#define JACOBI_MAX_SWEEPS 60
#define JACOBI_REL_OFF 1e-30          /* stop: Σ offdiag² ≤ this × Σ diag² */

/* One Jacobi rotation zeroing A[p][q]: A ← Jᵀ A J, V ← V J. */
static void jacobi_rotate(int n, double *A, double *V, int p, int q) {
        double apq = A[p * n + q];
        if (apq == 0)
                return;
        double th = (A[q * n + q] - A[p * n + p]) / (2 * apq);
        double t = (th >= 0 ? 1 : -1) / (fabs(th) + sqrt(th * th + 1));
        double c = 1 / sqrt(t * t + 1), s = t * c;
        for (int k = 0; k < n; k++) {
                double akp = A[k * n + p], akq = A[k * n + q];
                A[k * n + p] = c * akp - s * akq;
                A[k * n + q] = s * akp + c * akq;
        }
        for (int k = 0; k < n; k++) {
                double apk = A[p * n + k], aqk = A[q * n + k];
                A[p * n + k] = c * apk - s * aqk;
                A[q * n + k] = s * apk + c * aqk;
        }
        if (V)
                for (int k = 0; k < n; k++) {
                        double vkp = V[k * n + p], vkq = V[k * n + q];
                        V[k * n + p] = c * vkp - s * vkq;
                        V[k * n + q] = s * vkp + c * vkq;
                }
}

/* Selection sort of the eigenvalues ascending, carrying V's columns. */
static void sort_eigen(int n, double *val, double *V) {
        for (int i = 0; i < n; i++) {
                int m = i;
                for (int j = i + 1; j < n; j++)
                        if (val[j] < val[m])
                                m = j;
                if (m == i)
                        continue;
                double t = val[i];
                val[i] = val[m];
                val[m] = t;
                if (V)
                        for (int k = 0; k < n; k++) {
                                t = V[k * n + i];
                                V[k * n + i] = V[k * n + m];
                                V[k * n + m] = t;
                        }
        }
}

void imp_eigen_sym(int n, double *A, double *ret_val, double *ret_vec) {
        if (ret_vec)
                for (int i = 0; i < n * n; i++)
                        ret_vec[i] = i % (n + 1) == 0;
        for (int sweep = 0; sweep < JACOBI_MAX_SWEEPS; sweep++) {
                double off = 0, diag = 0;
                for (int i = 0; i < n; i++) {
                        diag += A[i * n + i] * A[i * n + i];
                        for (int j = i + 1; j < n; j++)
                                off += A[i * n + j] * A[i * n + j];
                }
                if (!(off > JACOBI_REL_OFF * diag))
                        break;
                for (int p = 0; p < n - 1; p++)
                        for (int q = p + 1; q < n; q++)
                                jacobi_rotate(n, A, ret_vec, p, q);
        }
        for (int i = 0; i < n; i++)
                ret_val[i] = A[i * n + i];
        sort_eigen(n, ret_val, ret_vec);
}

void imp_eigen_sym3(const double A[9], double ret_val[3], double ret_vec[9]) {
        double a[9], V[9];
        memcpy(a, A, sizeof a);
        imp_eigen_sym(3, a, ret_val, V);
        for (int k = 0; k < 3; k++)
                for (int i = 0; i < 3; i++)
                        ret_vec[3 * k + i] = V[i * 3 + k];
}

bool imp_cholesky_factor(int n, double *A) {
        for (int j = 0; j < n; j++) {
                double s = A[(size_t) j * n + j];
                for (int k = 0; k < j; k++)
                        s -= A[(size_t) j * n + k] * A[(size_t) j * n + k];
                if (!(s > 0))
                        return false;
                double l = sqrt(s);
                A[(size_t) j * n + j] = l;
                for (int i = j + 1; i < n; i++) {
                        double t = A[(size_t) i * n + j];
                        for (int k = 0; k < j; k++)
                                t -= A[(size_t) i * n + k] * A[(size_t) j * n + k];
                        A[(size_t) i * n + j] = t / l;
                }
        }
        return true;
}

void imp_cholesky_solve(int n, const double *L, double *b) {
        for (int i = 0; i < n; i++) {
                double t = b[i];
                for (int k = 0; k < i; k++)
                        t -= L[(size_t) i * n + k] * b[k];
                b[i] = t / L[(size_t) i * n + i];
        }
        for (int i = n - 1; i >= 0; i--) {
                double t = b[i];
                for (int k = i + 1; k < n; k++)
                        t -= L[(size_t) k * n + i] * b[k];
                b[i] = t / L[(size_t) i * n + i];
        }
}

/* NaN after every number; otherwise ascending. */
#define CMP_NAN_LAST(x, y) (isnan(x) ? !isnan(y) : isnan(y) ? -1 : ((x) > (y)) - ((x) < (y)))

int imp_cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return CMP_NAN_LAST(x, y);
}

int imp_cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return CMP_NAN_LAST(x, y);
}

int imp_cmp_double_desc(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return isnan(x) || isnan(y) ? CMP_NAN_LAST(x, y) : CMP_NAN_LAST(y, x);
}

float imp_select_kth_float(float *v, size_t n, size_t k) {
        size_t lo = 0, hi = n - 1;
        while (lo < hi) {
                float pivot = v[lo + (hi - lo) / 2];
                size_t i = lo, j = hi;
                while (i <= j) {
                        while (v[i] < pivot)
                                i++;
                        while (v[j] > pivot)
                                j--;
                        if (i <= j) {
                                float t = v[i];
                                v[i] = v[j];
                                v[j] = t;
                                i++;
                                if (j == 0)
                                        break;
                                j--;
                        }
                }
                if (k <= j)
                        hi = j;
                else if (k >= i)
                        lo = i;
                else
                        break;
        }
        return v[k];
}

double imp_median_sorted(const double *v, size_t n) {
        return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

double imp_quantile_sorted(const double *v, size_t n, double q) {
        if (q == 0.5)
                return imp_median_sorted(v, n);
        size_t k = (size_t) ceil(q * (double) n);
        return v[k ? k - 1 : 0];
}

int imp_quantile(double *v, size_t n, double q, double *ret) {
        if (!(q >= 0 && q <= 1))
                return -EINVAL;
        qsort(v, n, sizeof *v, imp_cmp_double);
        while (n > 0 && isnan(v[n - 1]))
                n--;
        if (n == 0)
                return -ENODATA;
        *ret = imp_quantile_sorted(v, n, q);
        return 0;
}

double imp_phase_nstep(const double *I, int n) {
        double s = 0, c = 0;
        for (int k = 0; k < n; k++) {
                double a = 2 * M_PI * k / n;
                s += I[k] * sin(a);
                c += I[k] * cos(a);
        }
        return atan2(-s, c);
}
