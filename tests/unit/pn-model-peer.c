/* The photometric texel model as main had it at cfe4354 (pipeline/appearance/photometric.c,
 * median_small .. imp_photometric_texel, copied unchanged but for the entry point's name):
 * the peer bench-pn-model times the current imp_photometric_texel against, and whose
 * results it and test-photometric-model compare with. Not a second implementation to keep
 * up to date: it stays main's as it was when the model was made faster. */
#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#include "numerics.h"
#include "photometric.h"
#include "pn-model-peer.h"

#define DEG (M_PI / 180.0)
#define PN_SHADOW_FRAC  0.5
#define PN_SHADOW_START 0.25

/* The per-sample loops below are built for AVX2 and the x86-64 baseline, the CPU picks at
 * load time; no FMA, so that the results do not depend on the machine. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define PN_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define PN_CLONES
#endif

/* Median of v[0..n) (n ≤ IMP_BTF_MAX_SAMPLES, no NaN): the elements of ranks n/2 and, for
 * an even n, n/2 − 1, the rank of v[i] being the count of smaller elements, ties broken by
 * position (the ranks are a permutation of 0..n−1). Counting in vector lanes stops once both
 * are found; at a texel's sample count it beats qsort's comparator calls several times over
 * and gives the same value. tmp is unused. */
PN_CLONES static double median_small(const double *restrict v, int n, double *tmp) {
        (void) tmp;
        if (n <= 0)
                return 0;
        const int hi = n / 2, lo = n & 1 ? hi : hi - 1;
        double a = v[0], b = v[0];
        int found = lo == hi ? 1 : 0;
        for (int i = 0; i < n; i++) {
                const double x = v[i];
                int rank = 0;
#pragma omp simd reduction(+ : rank)
                for (int j = 0; j < n; j++)
                        rank += (v[j] < x) | ((v[j] == x) & (j < i));
                if (rank == hi)
                        b = x, found++;
                if (rank == lo && lo != hi)
                        a = x, found++;
                if (found == 2)
                        break;
        }
        return lo == hi ? b : 0.5 * (a + b);
}

static void keep_geometric(struct imp_pn_texel *ret, uint16_t flags) {
        ret->n[0] = ret->n[1] = 0;
        ret->n[2] = 1;
        ret->flags |= flags;
}

/* The usable samples of a texel as rows of V/E = g·l (at most IMP_BTF_MAX_SAMPLES). */
struct pn_rows {
        double a[IMP_BTF_MAX_SAMPLES][3], y[IMP_BTF_MAX_SAMPLES], vv[IMP_BTF_MAX_SAMPLES][3];
        double w[IMP_BTF_MAX_SAMPLES], res[IMP_BTF_MAX_SAMPLES], tmp[IMP_BTF_MAX_SAMPLES];
        double vl[IMP_BTF_MAX_SAMPLES];   /* v·l, for takes_part */
        /* takes_part() of each row for the state's current normal and cone, once per
         * normal: the solve, the model check and the mean read it (valid when part_ok) */
        bool part[IMP_BTF_MAX_SAMPLES], part_ok;
        int m;
};

static void load_rows(const struct imp_btf_sample *s, int n, struct pn_rows *R) {
        int m = 0;
        for (int i = 0; i < n; i++) {
                const struct imp_btf_sample *q = &s[i];
                double V = (q->value[0] + q->value[1] + q->value[2]) / 3.0;
                if (!(q->e_cos > 0) || !(q->l[2] > 0) || !isfinite(V) || !isfinite(q->l[0]) ||
                    !isfinite(q->l[1]) || !isfinite(q->v[0]) || !isfinite(q->v[1]) || !isfinite(q->v[2]))
                        continue;
                double E = q->e_cos / q->l[2];
                if (!isfinite(E) || !(E > 0))
                        continue;
                for (int k = 0; k < 3; k++) {
                        R->a[m][k] = q->l[k];
                        R->vv[m][k] = q->v[k];
                }
                R->vl[m] = R->vv[m][0] * R->a[m][0] + R->vv[m][1] * R->a[m][1] + R->vv[m][2] * R->a[m][2];
                R->y[m] = V / E;
                R->w[m] = 1;
                m++;
        }
        R->m = m;
        R->part_ok = false;
}

/* Whether sample i takes part for normal nc: not near the mirror direction, not in
 * attached shadow. */
static inline __attribute__((always_inline)) bool takes_part(const struct pn_rows *R, int i, const double nc[3],
                                                              double cone, double min_cos) {
        /* r·l with r = 2(n·v)n − v the mirror direction: 2(n·v)(n·l) − v·l */
        double nv = nc[0] * R->vv[i][0] + nc[1] * R->vv[i][1] + nc[2] * R->vv[i][2];
        double nl = nc[0] * R->a[i][0] + nc[1] * R->a[i][1] + nc[2] * R->a[i][2];
        return 2 * nv * nl - R->vl[i] <= cone && nl >= min_cos;
}

/* Condition number (largest / smallest eigenvalue) and inverse of the symmetric 3×3 A in
 * closed form: the eigenvalues by the trigonometric solution of the characteristic cubic
 * (Smith, "Eigenvalues of a symmetric 3×3 matrix", CACM 4(4), 1961), the inverse by the
 * adjugate. False when A is nearly singular (smallest eigenvalue ≤ 1e-6 × the largest),
 * where the cubic's roots lose their relative accuracy: the caller then takes the Jacobi
 * solver. Far cheaper than Jacobi's sweeps; the same figures to rounding. */
static bool sym3_cond_inverse(const double A[9], double *ret_cond, double Ainv[9]) {
        double q = (A[0] + A[4] + A[8]) / 3, p1 = A[1] * A[1] + A[2] * A[2] + A[5] * A[5];
        double d0 = A[0] - q, d1 = A[4] - q, d2 = A[8] - q;
        double p = sqrt((d0 * d0 + d1 * d1 + d2 * d2 + 2 * p1) / 6), lmax = q, lmin = q;
        if (p > 0) {
                /* r = det((A − qI)/p) / 2 */
                double r = (d0 * (d1 * d2 - A[5] * A[5]) - A[1] * (A[1] * d2 - A[5] * A[2]) +
                            A[2] * (A[1] * A[5] - d1 * A[2])) / (2 * p * p * p);
                double phi = acos(fmax(-1.0, fmin(1.0, r))) / 3;
                lmax = q + 2 * p * cos(phi);
                lmin = q + 2 * p * cos(phi + 2 * M_PI / 3);
        }
        if (!(lmin > 1e-6 * lmax) || !isfinite(lmax))
                return false;
        double c00 = A[4] * A[8] - A[5] * A[7], c01 = A[5] * A[6] - A[3] * A[8], c02 = A[3] * A[7] - A[4] * A[6];
        double det = A[0] * c00 + A[1] * c01 + A[2] * c02;
        if (!(det > 0))
                return false;
        double id = 1 / det;
        Ainv[0] = c00 * id;
        Ainv[1] = Ainv[3] = c01 * id;
        Ainv[2] = Ainv[6] = c02 * id;
        Ainv[4] = (A[0] * A[8] - A[2] * A[6]) * id;
        Ainv[5] = Ainv[7] = (A[2] * A[3] - A[0] * A[5]) * id;
        Ainv[8] = (A[0] * A[4] - A[1] * A[3]) * id;
        *ret_cond = lmax / lmin;
        return true;
}

struct pn_state {
        double nc[3], g[3], Ainv[9], sigma, rms, cond, cone;
        int used;
};

/* One weighted solve for the current normal: g, A⁻¹, cond. Returns 0 or the flag that
 * keeps the geometric normal. */
static uint16_t solve_pass(struct pn_rows *R, const struct imp_photometric_params *p, struct pn_state *S) {
        double A[9] = {}, b[3] = {};
        S->used = 0;
        if (!R->part_ok) {
                for (int i = 0; i < R->m; i++)
                        R->part[i] = takes_part(R, i, S->nc, S->cone, p->min_cos);
                R->part_ok = true;
        }
        for (int i = 0; i < R->m; i++) {
                double wi = R->part[i] ? R->w[i] : 0.0;
                if (wi <= 0)
                        continue;
                S->used++;
                for (int j = 0; j < 3; j++) {
                        b[j] += wi * R->a[i][j] * R->y[i];
                        for (int k = j; k < 3; k++)
                                A[3 * j + k] += wi * R->a[i][j] * R->a[i][k];
                }
        }
        A[3] = A[1], A[6] = A[2], A[7] = A[5];
        if (S->used < p->min_samples)
                return IMP_PN_FEW_SAMPLES;
        if (!sym3_cond_inverse(A, &S->cond, S->Ainv)) {
                double lam[3], vec[9];
                imp_eigen_sym3(A, lam, vec);
                S->cond = lam[0] > 0 ? lam[2] / lam[0] : 1e12;
                if (!(S->cond <= p->max_cond))
                        return IMP_PN_ILL_COND;
                for (int j = 0; j < 9; j++)
                        S->Ainv[j] = 0;
                for (int e = 0; e < 3; e++)
                        for (int j = 0; j < 3; j++)
                                for (int k = 0; k < 3; k++)
                                        S->Ainv[3 * j + k] += vec[3 * e + j] * vec[3 * e + k] / lam[e];
        } else if (!(S->cond <= p->max_cond))
                return IMP_PN_ILL_COND;
        for (int j = 0; j < 3; j++)
                S->g[j] = S->Ainv[3 * j] * b[0] + S->Ainv[3 * j + 1] * b[1] + S->Ainv[3 * j + 2] * b[2];
        double gl = sqrt(S->g[0] * S->g[0] + S->g[1] * S->g[1] + S->g[2] * S->g[2]);
        if (!(gl >= p->min_albedo) || !isfinite(gl))
                return IMP_PN_DARK;
        return 0;
}

/* Residuals over every sample (an excluded one may come back), the robust σ (MAD) and
 * weighted RMS of those taking part for normal nn, and the Huber (and cast-shadow) weights
 * for the next solve when reweight. R->part is then nn's: the caller makes nn the state's
 * normal. */
static void residuals(struct pn_rows *R, const struct imp_photometric_params *p, const double nn[3],
                      struct pn_state *S, bool reweight) {
        const double *g = S->g;
        int k2 = 0;
        double ss = 0, sw = 0, mad[IMP_BTF_MAX_SAMPLES];
        for (int i = 0; i < R->m; i++) {
                R->res[i] = R->y[i] - (g[0] * R->a[i][0] + g[1] * R->a[i][1] + g[2] * R->a[i][2]);
                R->part[i] = takes_part(R, i, nn, S->cone, p->min_cos);
                if (R->part[i]) {
                        R->tmp[k2++] = fabs(R->res[i]);
                        ss += R->w[i] * R->res[i] * R->res[i];
                        sw += R->w[i];
                }
        }
        R->part_ok = true;
        S->sigma = fmax(p->sigma_floor, 1.4826 * median_small(R->tmp, k2, mad));
        S->rms = sqrt(ss / fmax(sw, 1e-30));
        if (!reweight)
                return;
        const double sigma = S->sigma, delta = p->huber_delta;
        /* Huber: min(1, δ/u) with u = |r|/σ, which is 1 exactly where u ≤ δ; branch-free,
         * so that the two divisions run in vector lanes */
#pragma omp simd
        for (int i = 0; i < R->m; i++) {
                double q = delta / (fabs(R->res[i]) / sigma);
                R->w[i] = isless(q, 1.0) ? q : 1.0;
        }
        if (p->shadow_trim_sigma > 0)
                for (int i = 0; i < R->m; i++)
                        /* cast shadow: far below the fit and under half of it */
                        if (R->res[i] < -p->shadow_trim_sigma * S->sigma &&
                            R->y[i] < PN_SHADOW_FRAC * (R->y[i] - R->res[i]))
                                R->w[i] = 0;
}

/* The model check: the same rows with a 4th unknown, an ambient term c (V/E = g·l + c).
 * Returns c, its σ (residual scale s) and the angle between the two fits' normals. False
 * when the 4×4 system is singular (then nothing is said). */
static bool ambient_check(const struct pn_rows *R, const struct imp_photometric_params *p,
                          const struct pn_state *S, double s, bool all_lit, double *ret_c, double *ret_sc,
                          double *ret_shift_deg) {
        double M[4][5] = {}, yy = 0, sw = 0;
        int cnt = 0;
        bool in[IMP_BTF_MAX_SAMPLES];
        for (int i = 0; i < R->m; i++)
                /* all_lit: the samples near the mirror direction too (no cone) */
                in[i] = (all_lit ? takes_part(R, i, S->nc, 2.0, p->min_cos) : R->part[i]) && R->w[i] > 0;
        for (int i = 0; i < R->m; i++) {
                if (!in[i])
                        continue;
                yy += R->w[i] * R->y[i] * R->y[i];
                sw += R->w[i];
                cnt++;
                double r[4] = { R->a[i][0], R->a[i][1], R->a[i][2], 1 };
                for (int j = 0; j < 4; j++) {
                        for (int k = 0; k < 4; k++)
                                M[j][k] += R->w[i] * r[j] * r[k];
                        M[j][4] += R->w[i] * r[j] * R->y[i];
                }
        }
        /* Gauss–Jordan with partial pivoting on [M | b], carrying the inverse's last column
         * (e₄) for var(c). */
        double inv[4] = { 0, 0, 0, 1 }, scale = M[0][0] + M[1][1] + M[2][2] + M[3][3];
        for (int c = 0; c < 4; c++) {
                int piv = c;
                for (int r = c + 1; r < 4; r++)
                        if (fabs(M[r][c]) > fabs(M[piv][c]))
                                piv = r;
                if (!(fabs(M[piv][c]) > 1e-9 * scale))
                        return false;
                for (int k = 0; k < 5; k++) {
                        double t = M[c][k];
                        M[c][k] = M[piv][k];
                        M[piv][k] = t;
                }
                double t = inv[c];
                inv[c] = inv[piv];
                inv[piv] = t;
                for (int r = 0; r < 4; r++) {
                        if (r == c)
                                continue;
                        double f = M[r][c] / M[c][c];
                        for (int k = c; k < 5; k++)
                                M[r][k] -= f * M[c][k];
                        inv[r] -= f * inv[c];
                }
        }
        double g4[3], gl = 0, dot = 0;
        for (int j = 0; j < 3; j++) {
                g4[j] = M[j][4] / M[j][j];
                gl += g4[j] * g4[j];
                dot += g4[j] * S->nc[j];
        }
        gl = sqrt(gl);
        *ret_c = M[3][4] / M[3][3];
        /* c's σ from the 4-unknown fit's own residual scale (a t-test of c): the 3-unknown
         * scale s is inflated by the very term under test. Never above s. Σw r² of the
         * least-squares solution x = M⁻¹b is Σw y² − xᵀb, b the original right-hand side:
         * recomputed from the rows below. */
        double ss = yy, bx = 0;
        for (int i = 0; i < R->m; i++) {
                if (!in[i])
                        continue;
                double f = g4[0] * R->a[i][0] + g4[1] * R->a[i][1] + g4[2] * R->a[i][2] + *ret_c;
                bx += R->w[i] * R->y[i] * f;
        }
        ss -= bx;
        double s4 = cnt > 4 && sw > 0 ? sqrt(fmax(0.0, ss) / sw * cnt / (cnt - 4)) : s;
        s4 = fmin(s, fmax(p->sigma_floor, s4));
        *ret_sc = s4 * sqrt(fmax(inv[3] / M[3][3], 0));   /* (M⁻¹)₃₃ = e₄ᵀ M⁻¹ e₄ */
        *ret_shift_deg = gl > 0 ? acos(fmax(-1.0, fmin(1.0, dot / gl))) / DEG : 90;
        return isfinite(*ret_c) && isfinite(*ret_sc);
}

/* σ, checks and result of a texel whose Lambertian fit converged. */
static void finish_texel(const struct pn_rows *R, const struct imp_photometric_params *p,
                         const struct pn_state *S, struct imp_pn_texel *ret) {
        double gl = sqrt(S->g[0] * S->g[0] + S->g[1] * S->g[1] + S->g[2] * S->g[2]);
        double tr = S->Ainv[0] + S->Ainv[4] + S->Ainv[8], nAn = 0;
        for (int j = 0; j < 3; j++)
                for (int k = 0; k < 3; k++)
                        nAn += S->nc[j] * S->Ainv[3 * j + k] * S->nc[k];
        double var_t = fmax(0, tr - nAn);
        /* The residual scale is the larger of the robust σ and the weighted RMS: a misfit
         * that is systematic rather than noisy shows in the second. */
        double s = fmax(S->sigma, S->rms);
        /* A residual scale from few samples is itself uncertain: the normal's error then
         * follows Student's t with used − 3 degrees of freedom, whose σ is √(ν/(ν−2)) ×
         * the Gaussian one (1.7 at 6 samples, 1.03 at 40). */
        double nu = S->used - 3;
        double sig_noise = s * sqrt(var_t) / gl / DEG * (nu > 2 ? sqrt(nu / (nu - 2)) : 1e3);
        double c = 0, sc = 0, shift = 0;
        uint16_t why = 0;
        /* The check over the samples taking part has the power to see a term that matters
         * (max_ambient_rel·|g|) only when its σ is below that / ambient_sigma. */
        bool powered = ambient_check(R, p, S, s, false, &c, &sc, &shift) &&
                       p->ambient_sigma * sc < p->max_ambient_rel * gl;
        if (powered) {
                if (fabs(c) > p->ambient_sigma * sc && fabs(c) > p->max_ambient_rel * gl)
                        why |= IMP_PN_AMBIENT;
        } else if (ambient_check(R, p, S, s, true, &c, &sc, &shift)) {
                /* The samples taking part cannot tell an ambient term from the normal's z (all
                 * lights at one elevation, or the other ring only at the cone's edge: it would
                 * tilt every normal towards the view unseen). The lit samples near the mirror
                 * direction can; a specular lobe there gives a negative term, so only added
                 * light counts. The shift is not the normal's. */
                shift = 0;
                if (c > p->ambient_sigma * sc && c > p->max_ambient_rel * gl)
                        why |= IMP_PN_AMBIENT;
        } else
                c = sc = shift = 0;
        double ysum = 0, wsum = 0;
        for (int i = 0; i < R->m; i++)
                if (R->w[i] > 0 && R->part[i]) {
                        ysum += R->w[i] * R->y[i];
                        wsum += R->w[i];
                }
        double ymean = wsum > 0 ? ysum / wsum : 0;
        if (S->rms > p->max_rms_ratio * S->sigma || S->rms > p->max_rel_rms * ymean)
                why |= IMP_PN_RESIDUAL;
        double sig = hypot(sig_noise, shift);
        if (!(sig <= p->max_sigma_deg))
                why |= !(sig_noise <= p->max_sigma_deg) && gl < 10 * p->min_albedo ? IMP_PN_DARK : IMP_PN_RESIDUAL;
        ret->albedo = (float) gl;
        ret->rms = (float) S->rms;
        ret->cond = (float) S->cond;
        ret->n_used = (uint16_t) S->used;
        ret->ambient = (float) c;
        ret->sigma_deg = (float) fmin(180.0, sig);
        ret->dev_deg = (float) (acos(fmax(-1.0, fmin(1.0, S->nc[2]))) / DEG);
        if (!(ret->dev_deg <= p->max_dev_deg))
                why |= IMP_PN_DISAGREES;
        if (why) {
                keep_geometric(ret, why);
                return;
        }
        for (int k = 0; k < 3; k++)
                ret->n[k] = (float) S->nc[k];
}

int pn_model_peer_texel(const struct imp_btf_sample *s, int n, const struct imp_photometric_params *p,
                        struct imp_pn_texel *ret) {
        *ret = (struct imp_pn_texel) { .n = { 0, 0, 1 }, .sigma_deg = 180 };
        if (n < 0 || n > IMP_BTF_MAX_SAMPLES)
                return -E2BIG;
        if (!p || p->min_samples < 3 || p->passes < 1 || !(p->max_cond > 1) || !(p->huber_delta > 0) ||
            !(p->sigma_floor > 0) || !(p->max_dev_deg > 0) || !(p->max_sigma_deg > 0) ||
            !(p->max_rms_ratio > 0) || !(p->max_rel_rms > 0) || !(p->max_ambient_rel > 0) || !(p->ambient_sigma >= 0))
                return -EINVAL;
        struct pn_rows R;
        load_rows(s, n, &R);
        int m = R.m;
        if (m < p->min_samples) {
                keep_geometric(ret, m == 0 ? IMP_PN_MASKED | IMP_PN_FEW_SAMPLES : IMP_PN_FEW_SAMPLES);
                ret->n_used = (uint16_t) m;
                return 0;
        }
        if (p->shadow_trim_sigma > 0) {
                /* Cast shadows expected: the first solve leaves out the samples darker than
                 * PN_SHADOW_START × the median, so that the shadows do not bias the fit the
                 * trimming starts from; they come back when the fit explains them. */
                double ymed = median_small(R.y, m, R.tmp);
                for (int i = 0; i < m; i++)
                        if (R.y[i] < PN_SHADOW_START * ymed)
                                R.w[i] = 0;
        }
        struct pn_state S = { .nc = { 0, 0, 1 }, .sigma = p->sigma_floor, .cond = 1e12,
                              .cone = cos(p->spec_cone_deg * DEG) };
        const double cos_tol = p->tol_deg > 0 ? cos(p->tol_deg * DEG) : INFINITY;
        for (int pass = 0; pass < p->passes; pass++) {
                uint16_t fail = solve_pass(&R, p, &S);
                if (fail) {
                        ret->cond = (float) fmin(S.cond, 1e12);
                        ret->n_used = (uint16_t) S.used;
                        keep_geometric(ret, fail);
                        return 0;
                }
                double gl = sqrt(S.g[0] * S.g[0] + S.g[1] * S.g[1] + S.g[2] * S.g[2]);
                double nn[3] = { S.g[0] / gl, S.g[1] / gl, S.g[2] / gl };
                /* moved < tol_deg, as cosines (no acos per pass) */
                bool still = fabs(nn[0] * S.nc[0] + nn[1] * S.nc[1] + nn[2] * S.nc[2]) > cos_tol;
                bool more = pass + 1 < p->passes;
                residuals(&R, p, nn, &S, more);
                for (int k = 0; k < 3; k++)
                        S.nc[k] = nn[k];
                if (more && pass > 0 && still)
                        break;
        }
        finish_texel(&R, p, &S, ret);
        return 0;
}

