/* Photometric normal refinement (photometric.h; method in docs/geometry.md). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "heightfield.h"
#include "numerics.h"
#include "photometric.h"
#include "pn-median.h"
#include "macro.h"
#include "quality.h"

#define DEG (M_PI / 180.0)
#define PN_SHADOW_FRAC  0.5           /* trimmed samples read below this × the fit */
#define PN_SHADOW_START 0.25          /* trimming: first solve without samples below this × median */

void imp_photometric_params_default(struct imp_photometric_params *ret) {
        *ret = (struct imp_photometric_params) {
                .min_samples = 6, .spec_cone_deg = 30, .min_cos = 0.05, .max_cond = 100,
                .min_albedo = 0.01, .max_dev_deg = 25, .passes = 5, .huber_delta = 1.345,
                .sigma_floor = 0.002, .tol_deg = 0.01, .geo_sigma_deg = 0, .lanczos = 3,
                .shadow_trim_sigma = 0, .filled_trim_sigma = 3, .filled_passes = 10, .filled_max_dev_deg = 60,
                .max_ambient_rel = 0.05, .ambient_sigma = 4, .max_rms_ratio = 3, .max_rel_rms = 0.06,
                .max_sigma_deg = 3.3,
                .interp_sigma_deg = 0.55, .interp_sigma_per_deg = 0.1, .geo_min_sigma_deg = 1,
                .agree_radius = 3, .agree_corr_texels = 3, .agree_k = 3,
        };
}

uint16_t imp_photometric_texel_flags(uint16_t f) {
        if ((f & IMP_PN_MASKED) && !(f & ~(IMP_PN_MASKED | IMP_PN_FEW_SAMPLES)))
                return 0;
        uint16_t t = 0;
        if (f & (IMP_PN_FEW_SAMPLES | IMP_PN_ILL_COND))
                t |= IMP_TEXEL_FEW_SAMPLES;
        if (f & IMP_PN_DARK)
                t |= IMP_TEXEL_DARK;
        if (f & IMP_PN_AMBIENT)
                t |= IMP_TEXEL_INTERREFLECTION;
        if (f & IMP_PN_SATURATED)
                t |= IMP_TEXEL_SATURATED;
        if (f & IMP_PN_KEPT)
                t |= IMP_TEXEL_PHOTOMETRIC_REJECTED;
        return t;
}

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return x < y ? -1 : x > y;
}

/* The per-sample loops below are built for AVX2 and the x86-64 baseline, the CPU picks at
 * load time; no FMA, so that the results do not depend on the machine. */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define PN_CLONES __attribute__((target_clones("avx2", "default")))
/* comparisons only (pn-median.h): AVX-512 gives the same values too */
#define PN_CLONES_CMP __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define PN_CLONES
#define PN_CLONES_CMP
#endif

/* The median of v[0..n) (pn-median.h; tmp holds n + 8 values) */
PN_CLONES_CMP static double median_small(const double *restrict v, int n, double *restrict tmp) {
        return imp_pn_median_small(v, n, tmp);
}

static void keep_geometric(struct imp_pn_texel *ret, uint16_t flags) {
        ret->n[0] = ret->n[1] = 0;
        ret->n[2] = 1;
        ret->flags |= flags;
}

typedef double pn_v4 __attribute__((vector_size(32)));

/* The usable samples of a texel as rows of V/E = g·l (at most IMP_BTF_MAX_SAMPLES), one
 * array per component, so that the per-row loops run in vector lanes. */
struct pn_rows {
        /* (l, V/E) of each row again as one vector: the solve's and the ambient check's
         * sums add each row's products in vector lanes across the sums (below) */
        pn_v4 q[IMP_BTF_MAX_SAMPLES];
        double lx[IMP_BTF_MAX_SAMPLES], ly[IMP_BTF_MAX_SAMPLES], lz[IMP_BTF_MAX_SAMPLES];
        double vx[IMP_BTF_MAX_SAMPLES], vy[IMP_BTF_MAX_SAMPLES], vz[IMP_BTF_MAX_SAMPLES];
        double y[IMP_BTF_MAX_SAMPLES], w[IMP_BTF_MAX_SAMPLES], res[IMP_BTF_MAX_SAMPLES];
        double tmp[IMP_BTF_MAX_SAMPLES + 8];   /* median_small's */
        double vl[IMP_BTF_MAX_SAMPLES];   /* v·l, for takes_part */
        /* takes_part() of each row for the state's current normal and cone, once per
         * normal: the solve, the model check and the mean read it (valid when part_ok) */
        bool part[IMP_BTF_MAX_SAMPLES], part_ok;
        int m;
};

/* Branch-free: every sample is written at row m, which advances only for a usable one (its
 * divisions then overlap those of the next samples instead of waiting on the tests). */
static void load_rows(const struct imp_btf_sample *s, int n, struct pn_rows *R) {
        int m = 0;
        for (int i = 0; i < n; i++) {
                const struct imp_btf_sample *q = &s[i];
                double V = (q->value[0] + q->value[1] + q->value[2]) / 3.0;
                double E = q->e_cos / q->l[2];
                const bool ok = (q->e_cos > 0) & (q->l[2] > 0) & isfinite(V) & isfinite(q->l[0]) & isfinite(q->l[1]) &
                                isfinite(q->v[0]) & isfinite(q->v[1]) & isfinite(q->v[2]) & isfinite(E) & (E > 0);
                const double lx = q->l[0], ly = q->l[1], lz = q->l[2], vx = q->v[0], vy = q->v[1], vz = q->v[2];
                R->lx[m] = lx, R->ly[m] = ly, R->lz[m] = lz;
                R->vx[m] = vx, R->vy[m] = vy, R->vz[m] = vz;
                R->vl[m] = vx * lx + vy * ly + vz * lz;
                R->y[m] = V / E;
                R->q[m] = (pn_v4) { lx, ly, lz, R->y[m] };
                R->w[m] = 1;
                m += ok;
        }
        R->m = m;
        R->part_ok = false;
}

/* Whether each row takes part for normal nc: not near the mirror direction (cone: the
 * cosine of the cone's half angle), not in attached shadow. */
PN_CLONES static void takes_part(const struct pn_rows *restrict R, const double nc[3], double cone, double min_cos,
                                 bool *restrict ret) {
        const double n0 = nc[0], n1 = nc[1], n2 = nc[2];
#pragma omp simd
        for (int i = 0; i < R->m; i++) {
                /* r·l with r = 2(n·v)n − v the mirror direction: 2(n·v)(n·l) − v·l */
                double nv = n0 * R->vx[i] + n1 * R->vy[i] + n2 * R->vz[i];
                double nl = n0 * R->lx[i] + n1 * R->ly[i] + n2 * R->lz[i];
                ret[i] = (2 * nv * nl - R->vl[i] <= cone) & (nl >= min_cos);
        }
}

/* The smallest and largest eigenvalues of the symmetric 3×3 A by the trigonometric solution
 * of the characteristic cubic (Smith, "Eigenvalues of a symmetric 3×3 matrix", CACM 4(4),
 * 1961). */
static void sym3_extremes(const double A[9], double *ret_lmin, double *ret_lmax) {
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
        *ret_lmin = lmin;
        *ret_lmax = lmax;
}

/* Condition number (largest / smallest eigenvalue) and inverse of the symmetric 3×3 A in
 * closed form: the eigenvalues by sym3_extremes(), the inverse by the adjugate. False when A
 * is nearly singular (smallest eigenvalue ≤ 1e-6 × the largest), where the cubic's roots
 * lose their relative accuracy: the caller then takes the Jacobi solver. Far cheaper than
 * Jacobi's sweeps; the same figures to rounding.
 * The cubic's trigonometry is the larger part of that; the solve needs the condition number
 * only to compare it with max_cond, and the texel reports only its last solve's. So when
 * the bound cond ≤ tr³ / (4 det) (λmax ≤ tr, and the two larger eigenvalues' product is at
 * most (tr / 2)², so λmin ≥ 4 det / tr²) is below half of max_cond and of 1e6, the test
 * would pass whatever the rounding: *ret_lazy is set and *ret_cond left for sym3_cond() to
 * compute from A when it is read, the same bits. */
static bool sym3_cond_inverse(const double A[9], double max_cond, double *ret_cond, bool *ret_lazy,
                              double Ainv[9]) {
        double c00 = A[4] * A[8] - A[5] * A[7], c01 = A[5] * A[6] - A[3] * A[8], c02 = A[3] * A[7] - A[4] * A[6];
        double det = A[0] * c00 + A[1] * c01 + A[2] * c02, tr = A[0] + A[4] + A[8];
        /* A positive definite (Sylvester) and the bound well inside both limits */
        *ret_lazy = det > 0 && isfinite(det) && A[0] > 0 && A[0] * A[4] - A[1] * A[3] > 0 && A[8] >= 0 &&
                    tr * tr * tr <= 2 * det * fmin(max_cond, 1e6);
        if (!*ret_lazy) {
                double lmin, lmax;
                sym3_extremes(A, &lmin, &lmax);
                if (!(lmin > 1e-6 * lmax) || !isfinite(lmax))
                        return false;
                if (!(det > 0))
                        return false;
                *ret_cond = lmax / lmin;
        }
        double id = 1 / det;
        Ainv[0] = c00 * id;
        Ainv[1] = Ainv[3] = c01 * id;
        Ainv[2] = Ainv[6] = c02 * id;
        Ainv[4] = (A[0] * A[8] - A[2] * A[6]) * id;
        Ainv[5] = Ainv[7] = (A[2] * A[3] - A[0] * A[5]) * id;
        Ainv[8] = (A[0] * A[4] - A[1] * A[3]) * id;
        return true;
}

struct pn_state {
        double nc[3], g[3], Ainv[9], sigma, rms, cone;
        double cond;                  /* of the last solve; lazy: still to compute from A */
        double A[9];
        bool cond_lazy;
        int used;
};

/* The condition number of the state's last solve. */
static double pn_cond(struct pn_state *S) {
        if (S->cond_lazy) {
                double lmin, lmax;
                sym3_extremes(S->A, &lmin, &lmax);
                S->cond = lmax / lmin;
                S->cond_lazy = false;
        }
        return S->cond;
}

/* The solve's normal equations over the rows taking part: c[j] = Σ w l_j (l, y), so
 * (A row j | b_j) but for the lower triangle. In registers and without a branch: a row that
 * does not take part (or has weight 0) is weighted 0, and its products ±0 (every row is
 * finite) leave every sum as it was (none is ever −0), so the sums are those of the rows
 * taking part, in their order. The lanes run across the sums, not the rows: each sum adds
 * the same products (w·l_j)·l_k in the same order as a scalar sum per entry, the same bits,
 * but one vector add a row instead of a dependent chain of nine scalar ones. Returns the
 * rows' count. */
PN_CLONES static int solve_sums(const struct pn_rows *restrict R, pn_v4 c[3]) {
        pn_v4 c0 = { 0 }, c1 = { 0 }, c2 = { 0 };
        int used = 0;
        for (int i = 0; i < R->m; i++) {
                const bool on = R->part[i] & (R->w[i] > 0);
                const double wi = on ? R->w[i] : 0.0;
                const pn_v4 r = R->q[i], wr = wi * r;
                used += on;
                c0 += wr[0] * r;
                c1 += wr[1] * r;
                c2 += wr[2] * r;
        }
        c[0] = c0, c[1] = c1, c[2] = c2;
        return used;
}

/* One weighted solve for the current normal: g, A⁻¹, cond. Returns 0 or the flag that
 * keeps the geometric normal. */
static uint16_t solve_pass(struct pn_rows *R, const struct imp_photometric_params *p, struct pn_state *S) {
        double A[9], b[3];
        if (!R->part_ok) {
                takes_part(R, S->nc, S->cone, p->min_cos, R->part);
                R->part_ok = true;
        }
        pn_v4 c[3];
        S->used = solve_sums(R, c);
        if (S->used < p->min_samples)
                return IMP_PN_FEW_SAMPLES;
        A[0] = c[0][0], A[1] = A[3] = c[0][1], A[2] = A[6] = c[0][2], A[4] = c[1][1], A[5] = A[7] = c[1][2];
        A[8] = c[2][2];
        b[0] = c[0][3], b[1] = c[1][3], b[2] = c[2][3];
        memcpy(S->A, A, sizeof A);
        if (!sym3_cond_inverse(A, p->max_cond, &S->cond, &S->cond_lazy, S->Ainv)) {
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
        } else if (!S->cond_lazy && !(S->cond <= p->max_cond))
                return IMP_PN_ILL_COND;
        for (int j = 0; j < 3; j++)
                S->g[j] = S->Ainv[3 * j] * b[0] + S->Ainv[3 * j + 1] * b[1] + S->Ainv[3 * j + 2] * b[2];
        double gl = sqrt(S->g[0] * S->g[0] + S->g[1] * S->g[1] + S->g[2] * S->g[2]);
        if (!(gl >= p->min_albedo) || !isfinite(gl))
                return IMP_PN_DARK;
        return 0;
}

/* The residuals of every row for fit g, and whether each takes part for normal nn. */
PN_CLONES static void residuals_part(struct pn_rows *restrict R, const double g[3], const double nn[3], double cone,
                                     double min_cos) {
        const double g0 = g[0], g1 = g[1], g2 = g[2];
#pragma omp simd
        for (int i = 0; i < R->m; i++)
                R->res[i] = R->y[i] - (g0 * R->lx[i] + g1 * R->ly[i] + g2 * R->lz[i]);
        takes_part(R, nn, cone, min_cos, R->part);
}

/* Huber: min(1, δ/u) with u = |r|/σ, which is 1 exactly where u ≤ δ; branch-free, so that
 * the two divisions run in vector lanes (as a clone: the divider takes four lanes in the
 * time of one or two). */
PN_CLONES static void huber_weights(struct pn_rows *restrict R, double sigma, double delta) {
#pragma omp simd
        for (int i = 0; i < R->m; i++) {
                double q = delta / (fabs(R->res[i]) / sigma);
                R->w[i] = isless(q, 1.0) ? q : 1.0;
        }
}

/* Residuals over every sample (an excluded one may come back), the robust σ (MAD) and
 * weighted RMS of those taking part for normal nn, and the Huber (and cast-shadow) weights
 * for the next solve when reweight. R->part is then nn's: the caller makes nn the state's
 * normal. */
static void residuals(struct pn_rows *R, const struct imp_photometric_params *p, const double nn[3],
                      struct pn_state *S, bool reweight) {
        residuals_part(R, S->g, nn, S->cone, p->min_cos);
        int k2 = 0;
        double ss = 0, sw = 0, mad[IMP_BTF_MAX_SAMPLES + 8];
        /* branch-free as in solve_pass: +0 for a row that does not take part */
        for (int i = 0; i < R->m; i++) {
                const bool on = R->part[i];
                const double r = R->res[i], wi = R->w[i];
                R->tmp[k2] = fabs(r);
                k2 += on;
                ss += on ? wi * r * r : 0.0;
                sw += on ? wi : 0.0;
        }
        R->part_ok = true;
        S->sigma = fmax(p->sigma_floor, 1.4826 * median_small(R->tmp, k2, mad));
        S->rms = sqrt(ss / fmax(sw, 1e-30));
        if (!reweight)
                return;
        huber_weights(R, S->sigma, p->huber_delta);
        if (p->shadow_trim_sigma > 0)
                for (int i = 0; i < R->m; i++)
                        /* cast shadow: far below the fit and under half of it */
                        if (R->res[i] < -p->shadow_trim_sigma * S->sigma &&
                            R->y[i] < PN_SHADOW_FRAC * (R->y[i] - R->res[i]))
                                R->w[i] = 0;
}

/* The normal equations of the 4-unknown fit over the rows in[]: M = Σ w r rᵀ with
 * r = (l, 1), right-hand side Σ w r y in M[·][4], and Σ w y². In registers and branch-free
 * (weight 0 for a row left out, lanes across the sums, as in solve_sums); each entry the same
 * product in the same order as the plain loop over (j, k) would add (w·r_j)·r_k, so M is not
 * made symmetric: its two triangles differ in their last bits, and the solve reads both. */
PN_CLONES static void ambient_sums(const struct pn_rows *restrict R, const bool *restrict in, double M[4][5],
                                   double *ret_yy, double *ret_sw, int *ret_cnt) {
        pn_v4 c0 = { 0 }, c1 = { 0 }, c2 = { 0 }, c3 = { 0 };
        double m33 = 0, yy = 0;
        int cnt = 0;
        for (int i = 0; i < R->m; i++) {
                const bool on = in[i];
                const double w = on ? R->w[i] : 0.0;
                const pn_v4 r = R->q[i], wr = w * r;   /* (w·x, w·y, w·z, w·v) */
                cnt += on;
                c0 += wr[0] * r;   /* (M[0][0..2], b0): (w·x)·(x, y, z, v) */
                c1 += wr[1] * r;
                c2 += wr[2] * r;
                c3 += wr;          /* (M[0..2][3], b3): (w·r_j)·1 and w·v */
                m33 += w;
                yy += wr[3] * r[3];   /* w·v·v */
        }
        double rows[4][5] = { { c0[0], c0[1], c0[2], c3[0], c0[3] }, { c1[0], c1[1], c1[2], c3[1], c1[3] },
                              { c2[0], c2[1], c2[2], c3[2], c2[3] }, { c3[0], c3[1], c3[2], m33, c3[3] } };
        memcpy(M, rows, sizeof rows);
        *ret_yy = yy;
        *ret_sw = m33;   /* Σ w, in the same order */
        *ret_cnt = cnt;
}

/* The model check: the same rows with a 4th unknown, an ambient term c (V/E = g·l + c).
 * Returns c, its σ (residual scale s) and the cosine of the angle between the two fits'
 * normals (clamped to [−1, 1]; 2 when the 4-unknown fit has no normal): the caller takes
 * its acos only where it reads the angle. False when the 4×4 system is singular (then
 * nothing is said). */
static bool ambient_check(const struct pn_rows *R, const struct imp_photometric_params *p,
                          const struct pn_state *S, double s, bool all_lit, double *ret_c, double *ret_sc,
                          double *ret_shift_cos) {
        double M[4][5], yy, sw;
        int cnt;
        bool in[IMP_BTF_MAX_SAMPLES];
        if (all_lit)   /* the samples near the mirror direction too (no cone) */
                takes_part(R, S->nc, 2.0, p->min_cos, in);
        else
                memcpy(in, R->part, sizeof in[0] * R->m);
        for (int i = 0; i < R->m; i++)
                in[i] &= R->w[i] > 0;
        ambient_sums(R, in, M, &yy, &sw, &cnt);
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
        const double c4 = *ret_c;
        for (int i = 0; i < R->m; i++) {
                double f = g4[0] * R->lx[i] + g4[1] * R->ly[i] + g4[2] * R->lz[i] + c4;
                bx += in[i] ? R->w[i] * R->y[i] * f : 0.0;
        }
        ss -= bx;
        double s4 = cnt > 4 && sw > 0 ? sqrt(fmax(0.0, ss) / sw * cnt / (cnt - 4)) : s;
        s4 = fmin(s, fmax(p->sigma_floor, s4));
        *ret_sc = s4 * sqrt(fmax(inv[3] / M[3][3], 0));   /* (M⁻¹)₃₃ = e₄ᵀ M⁻¹ e₄ */
        *ret_shift_cos = gl > 0 ? fmax(-1.0, fmin(1.0, dot / gl)) : 2;
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
        double c = 0, sc = 0, shift = 0, shift_cos;
        uint16_t why = 0;
        /* The check over the samples taking part has the power to see a term that matters
         * (max_ambient_rel·|g|) only when its σ is below that / ambient_sigma. */
        bool powered = ambient_check(R, p, S, s, false, &c, &sc, &shift_cos) &&
                       p->ambient_sigma * sc < p->max_ambient_rel * gl;
        if (powered) {
                shift = shift_cos <= 1 ? acos(shift_cos) / DEG : 90;
                if (fabs(c) > p->ambient_sigma * sc && fabs(c) > p->max_ambient_rel * gl)
                        why |= IMP_PN_AMBIENT;
        } else if (ambient_check(R, p, S, s, true, &c, &sc, &shift_cos)) {
                /* The samples taking part cannot tell an ambient term from the normal's z (all
                 * lights at one elevation, or the other ring only at the cone's edge: it would
                 * tilt every normal towards the view unseen). The lit samples near the mirror
                 * direction can; a specular lobe there gives a negative term, so only added
                 * light counts. The shift is not the normal's (shift stays 0). */
                if (c > p->ambient_sigma * sc && c > p->max_ambient_rel * gl)
                        why |= IMP_PN_AMBIENT;
        } else
                c = sc = shift = 0;
        double ysum = 0, wsum = 0;
        for (int i = 0; i < R->m; i++) {   /* branch-free as in solve_pass */
                const bool on = R->w[i] > 0 && R->part[i];
                ysum += on ? R->w[i] * R->y[i] : 0.0;
                wsum += on ? R->w[i] : 0.0;
        }
        double ymean = wsum > 0 ? ysum / wsum : 0;
        if (S->rms > p->max_rms_ratio * S->sigma || S->rms > p->max_rel_rms * ymean)
                why |= IMP_PN_RESIDUAL;
        double sig = hypot(sig_noise, shift);
        if (!(sig <= p->max_sigma_deg))
                why |= !(sig_noise <= p->max_sigma_deg) && gl < 10 * p->min_albedo ? IMP_PN_DARK : IMP_PN_RESIDUAL;
        ret->albedo = (float) gl;
        ret->rms = (float) S->rms;
        ret->cond = (float) S->cond;   /* pn_cond(): the caller's */
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

/* cos(deg°), remembered per thread for the last two angles asked (slot 0, 1): the texels
 * of a stage all ask the same two. */
static double cos_deg_cached(int slot, double deg) {
        static _Thread_local double key[2] = { NAN, NAN }, val[2];
        if (!(key[slot] == deg)) {
                val[slot] = cos(deg * DEG);
                key[slot] = deg;
        }
        return val[slot];
}

int imp_photometric_texel(const struct imp_btf_sample *s, int n, const struct imp_photometric_params *p,
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
                              .cone = cos_deg_cached(0, p->spec_cone_deg) };
        const double cos_tol = p->tol_deg > 0 ? cos_deg_cached(1, p->tol_deg) : INFINITY;
        for (int pass = 0; pass < p->passes; pass++) {
                uint16_t fail = solve_pass(&R, p, &S);
                if (fail) {
                        ret->cond = (float) fmin(pn_cond(&S), 1e12);
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
        pn_cond(&S);
        finish_texel(&R, p, &S, ret);
        return 0;
}

/* ---- re-sampling the frames with a Lanczos kernel ----------------------------------
 * The extractor reads each frame bilinearly at the texel's projection. Between pixels
 * that blends the shading of the neighbouring pixels' normals: on the demo's 0.2 mm
 * grooves (4 pixels per period) bilinear reading alone leaves 2.9° between the truth
 * normals at the pixels and at the texel, Lanczos-3 1.3° (docs/geometry.md). The
 * extractor keeps the geometry (directions, irradiance, shadow and visibility rays);
 * here each sample's value is read again with the Lanczos kernel, the extractor naming
 * each sample's light. Where the window lies in the band (struct imp_btf_band) every
 * light's value is read before the extraction and handed to it, which then skips the
 * bilinear values it would compute only to be replaced. */

#define PN_MAX_LANCZOS 4

/* The re-read reads the band the extractor reads its taps from (btf.h, struct
 * imp_btf_band): the frames interleaved by light over the pixel box of one band of texel
 * rows, NaN where a light's validity mask is set. A texel's 2a × 2a window then holds all
 * its lights in 2a contiguous runs of 2a·L floats (a few KiB, in L1 after the first
 * sample) instead of 2a rows of each of L frames and L masks, each frame read at a
 * different place. The values are the frames' own: the re-read's arithmetic and its
 * decisions are the same whichever of the two it reads. */

struct resample {
        const struct imp_btf_heightfield *hf;
        const struct imp_btf_capture *cap;
        double R[9], t[3];            /* canvas → world */
        double sat;                   /* saturation value (0: flags only) */
        int a;                        /* the window's half width in pixels, 0 = off */
        int order;                    /* Lanczos order */
        int kernel;                   /* IMP_PN_KERNEL_* */
        const struct imp_btf_band *band;  /* the current band's frames, NULL: read the frames */
};

static double lanczos(double x, int a) {
        x = fabs(x);
        if (x < 1e-9)
                return 1;
        if (x >= a)
                return 0;
        return a * sin(M_PI * x) * sin(M_PI * x / a) / (M_PI * M_PI * x * x);
}

/* Mitchell–Netravali cubic with parameters (B, C): B = 1, C = 0 is the cubic B-spline
 * (non-negative, smoothing), B = C = 1/3 Mitchell's filter (small negative lobes). */
static double bc_cubic(double x, double B, double C) {
        x = fabs(x);
        if (x < 1)
                return ((12 - 9 * B - 6 * C) * x * x * x + (-18 + 12 * B + 6 * C) * x * x + (6 - 2 * B)) / 6;
        if (x < 2)
                return ((-B - 6 * C) * x * x * x + (6 * B + 30 * C) * x * x + (-12 * B - 48 * C) * x + (8 * B + 24 * C)) /
                       6;
        return 0;
}

/* Weight of the re-read's kernel at distance x (pixels) from the sample's position;
 * the caller normalises the window's weights to sum 1. */
static double kernel_weight(const struct resample *rs, double x) {
        switch (rs->kernel) {
        case IMP_PN_KERNEL_LANCZOS_CLAMPED:
                return fmax(0.0, lanczos(x, rs->order));
        case IMP_PN_KERNEL_MITCHELL:
                return bc_cubic(x, 1.0 / 3, 1.0 / 3);
        case IMP_PN_KERNEL_BSPLINE:
                return bc_cubic(x, 1, 0);
        case IMP_PN_KERNEL_PREFILTERED:
                /* frames smoothed by the binomial [1 2 1]/4, then read with Lanczos */
                return 0.25 * lanczos(x - 1, rs->order) + 0.5 * lanczos(x, rs->order) + 0.25 * lanczos(x + 1, rs->order);
        default:
                return lanczos(x, rs->order);
        }
}

/* Half width of the re-read's window in pixels for kernel k of Lanczos order a; 0 when
 * the pair is not valid (the window must fit in PN_MAX_LANCZOS). */
static int kernel_half_width(int k, int a) {
        if (a <= 0)
                return 0;
        switch (k) {
        case IMP_PN_KERNEL_LANCZOS:
        case IMP_PN_KERNEL_LANCZOS_CLAMPED:
                return a <= PN_MAX_LANCZOS ? a : -1;
        case IMP_PN_KERNEL_MITCHELL:
        case IMP_PN_KERNEL_BSPLINE:
                return 2;
        case IMP_PN_KERNEL_PREFILTERED:
                return a + 1 <= PN_MAX_LANCZOS ? a + 1 : -1;
        default:
                return -1;
        }
}

/* lanczos_sample of every light at once from the band, (bx, by) the window's corner in
 * the box, into acc[l] and ok[l] (its value and result): each light's sums in the same
 * order as from the frame, so the same values, the mask read as the NaN it left; the
 * lights side by side in vector lanes (one light's sums are a chain of dependent
 * additions, L chains at once are not). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
/* AVX-512 as well (8 lights a vector); GCC's avx512f target enables FMA, which would
 * round row[l] += w·v once instead of twice: contraction off, so every target sums the
 * same values as the x86-64 baseline. */
#define PN_BAND_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define PN_BAND_CLONES
#endif
/* gcc 12 vectorises float compares only with no-trapping-math */
__attribute__((optimize("no-trapping-math", "fp-contract=off"))) PN_BAND_CLONES
static void lanczos_band_all(const struct imp_btf_band *b, int bx, int by, int n, float sat, const double *wx,
                             const double *wy, double *acc, uint8_t *ok) {
        const int L = b->L;
        double row[IMP_BTF_MAX_SAMPLES];
        for (int l = 0; l < L; l++)
                acc[l] = 0, ok[l] = 1;
        for (int dy = 0; dy < n; dy++) {
                const float *q = b->v + ((size_t) (by + dy) * b->cols + bx) * L;
                for (int l = 0; l < L; l++)
                        row[l] = 0;
                for (int dx = 0; dx < n; dx++) {
                        const float *p = q + (size_t) dx * L;
                        const double w = wx[dx];
#pragma omp simd
                        for (int l = 0; l < L; l++) {
                                float v = p[l];
                                ok[l] &= (uint8_t) ((v < sat) & (v > -INFINITY));
                                row[l] += w * v;
                        }
                }
                const double w = wy[dy];
#pragma omp simd
                for (int l = 0; l < L; l++)
                        acc[l] += w * row[l];
        }
}

/* Lanczos value of frame f with the window's corner at (x0, y0) into ret[3]; false when
 * the window leaves the frame or holds a non-finite, saturated or invalid pixel (the
 * caller keeps the bilinear value). Separable: each window row is summed with wx, the row
 * sums with wy; the checks of a row are folded into one test after it. */
static bool lanczos_sample(const struct resample *rs, int light, int x0, int y0, const double *wx,
                           const double *wy, float ret[3]) {
        const struct imp_image *f = rs->cap->frames[light];
        const struct imp_image *val = rs->cap->valid ? rs->cap->valid[light] : NULL;
        const int n = 2 * rs->a;
        /* v < sat and v > −∞ hold for every finite, unsaturated sample and fail on NaN */
        const float sat = rs->sat > 0 ? (float) rs->sat : INFINITY;
        if (x0 < 0 || y0 < 0 || x0 + n > f->width || y0 + n > f->height)
                return false;
        double acc[3] = { 0, 0, 0 };
        for (int dy = 0; dy < n; dy++) {
                if (val) {
                        const uint8_t *vr = imp_image_u8(val, x0, y0 + dy);
                        unsigned bad = 0;
                        for (int dx = 0; dx < n; dx++)
                                bad |= vr[dx];
                        if (bad)
                                return false;
                }
                const float *q = imp_image_f32(f, x0, y0 + dy);
                bool ok = true;
                if (f->channels == 3) {
                        double row[3] = { 0, 0, 0 };
                        for (int dx = 0; dx < n; dx++)
                                for (int c = 0; c < 3; c++) {
                                        float v = q[3 * dx + c];
                                        ok &= v < sat && v > -INFINITY;
                                        row[c] += wx[dx] * v;
                                }
                        for (int c = 0; c < 3; c++)
                                acc[c] += wy[dy] * row[c];
                } else {
                        double row = 0;
                        for (int dx = 0; dx < n; dx++) {
                                float v = q[(size_t) dx * f->channels];
                                ok &= v < sat && v > -INFINITY;
                                row += wx[dx] * v;
                        }
                        acc[0] += wy[dy] * row;
                }
                if (!ok)
                        return false;
        }
        if (f->channels != 3)
                acc[1] = acc[2] = acc[0];
        for (int c = 0; c < 3; c++)
                ret[c] = (float) acc[c];
        return true;
}

/* Canvas point P (mm) → its pixel in the frames; false when behind the camera. */
static bool canvas_pixel(const struct resample *rs, const double P[3], double px[2]) {
        double Pw[3];
        for (int i = 0; i < 3; i++)
                Pw[i] = rs->R[3 * i] * P[0] + rs->R[3 * i + 1] * P[1] + rs->R[3 * i + 2] * P[2] + rs->t[i];
        return imp_pinhole_project(rs->cap->camera, Pw, px);
}

/* The 2a Lanczos weights of the window whose sample lies f ∈ [0, 1) past its pixel a − 1,
 * at x_k = f + a − 1 − k (k < 2a), into w; false for another kernel or f within 1e-9 of a
 * pixel (kernel_weight() then). L(x) = a·sin(πx)·sin(πx/a)/(π²x²) (seed: Duchon, "Lanczos
 * filtering in one and two dimensions", 1979) from one sin and one sincos instead of two
 * sins per tap: with x = g + m, g = f or f − 1 (|g| ≤ ½, exact) and m an integer,
 * sin(πx) = (−1)^m·sin(πg) and sin(πx/a) = sin(πg/a)·cos(πm/a) + cos(πg/a)·sin(πm/a).
 * Within 1e-15 of kernel_weight()'s values (test-photometric-lanczos). */
#define R2 0.70710678118654752440   /* √2/2 */
#define R3 0.86602540378443864676   /* √3/2 */
static const double lanczos_cs[PN_MAX_LANCZOS][2 * PN_MAX_LANCZOS + 1][2] = {   /* cos, sin of πm/a, m = −a … a */
        { { -1, 0 }, { 1, 0 }, { -1, 0 } },
        { { -1, 0 }, { 0, -1 }, { 1, 0 }, { 0, 1 }, { -1, 0 } },
        { { -1, 0 }, { -0.5, -R3 }, { 0.5, -R3 }, { 1, 0 }, { 0.5, R3 }, { -0.5, R3 }, { -1, 0 } },
        { { -1, 0 }, { -R2, -R2 }, { 0, -1 }, { R2, -R2 }, { 1, 0 }, { R2, R2 }, { 0, 1 }, { -R2, R2 }, { -1, 0 } },
};
#undef R2
#undef R3

static bool lanczos_weights(const struct resample *rs, double f, double *w) {
        const int a = rs->order;
        if ((rs->kernel != IMP_PN_KERNEL_LANCZOS && rs->kernel != IMP_PN_KERNEL_LANCZOS_CLAMPED) || rs->a != a ||
            a > PN_MAX_LANCZOS || !(f >= 1e-9 && f <= 1 - 1e-9))
                return false;
        const int up = f > 0.5;
        const double g = up ? f - 1 : f;
        double s1 = sin(M_PI * g), sa = sin(M_PI * g / a), ca = cos(M_PI * g / a);   /* gcc: one sincos */
        for (int k = 0; k < 2 * a; k++) {
                int m = a - 1 - k + up;
                const double *cs = lanczos_cs[a - 1][m + a];
                double x = g + m;
                double v = a * ((m & 1) ? -s1 : s1) * (sa * cs[0] + ca * cs[1]) / (M_PI * M_PI * x * x);
                w[k] = rs->kernel == IMP_PN_KERNEL_LANCZOS_CLAMPED ? fmax(0.0, v) : v;
        }
        return true;
}

/* Texel (u, v)'s Lanczos window: its corner (x0, y0) in frame pixels and its normalised
 * weights wx, wy; false when nothing is re-read (a texel the extractor masks or finds
 * outside the frame, re-reading off). */
static bool texel_window(const struct resample *rs, int u, int v, int *ret_x0, int *ret_y0, double *wx,
                         double *wy) {
        const struct imp_btf_heightfield *hf = rs->hf;
        size_t idx = (size_t) v * hf->width + u;
        const float *nf = hf->normal + 3 * idx;
        double nl = sqrt(nf[0] * nf[0] + nf[1] * nf[1] + nf[2] * nf[2]);
        if (!(nl > 0.5 && nl < 2.0) || rs->a <= 0 || !isfinite(hf->height_mm[idx]))
                return false;
        double P[3] = { u * hf->pitch_mm, v * hf->pitch_mm, hf->height_mm[idx] }, px[2];
        /* the extractor's visibility test: outside the frame its texel is HIDDEN */
        if (!canvas_pixel(rs, P, px) || !(px[0] >= 0.0 && px[1] >= 0.0 && px[0] <= rs->cap->camera->width - 1 &&
                                          px[1] <= rs->cap->camera->height - 1))
                return false;
        double sx = 0, sy = 0;
        int x0 = (int) floor(px[0]) - rs->a + 1, y0 = (int) floor(px[1]) - rs->a + 1;
        if (!lanczos_weights(rs, px[0] - floor(px[0]), wx) || !lanczos_weights(rs, px[1] - floor(px[1]), wy))
                for (int k = 0; k < 2 * rs->a; k++) {
                        wx[k] = kernel_weight(rs, px[0] - (x0 + k));
                        wy[k] = kernel_weight(rs, px[1] - (y0 + k));
                }
        for (int k = 0; k < 2 * rs->a; k++)
                sx += wx[k], sy += wy[k];
        for (int k = 0; k < 2 * rs->a; k++)
                wx[k] /= sx, wy[k] /= sy;
        *ret_x0 = x0, *ret_y0 = y0;
        return true;
}

/* Light j's re-read value val (the same in every channel of a mono frame) with its colour
 * applied as the extractor applies it, into ret. */
static void apply_colour(const struct resample *rs, int j, const float val[3], float ret[3]) {
        const double *col = rs->cap->lights[j].colour;
        bool white = col[0] == 0 && col[1] == 0 && col[2] == 0;
        for (int c = 0; c < 3; c++)
                ret[c] = white ? val[c] : col[c] > 0 ? (float) (val[c] / col[c]) : 0.0f;
}

/* The window at (x0, y0) inside the current band: every light's value at once. */
static bool window_in_band(const struct resample *rs, int x0, int y0) {
        const struct imp_btf_band *b = rs->band;
        const int nw = 2 * rs->a;
        return b && x0 >= b->x0 && y0 >= b->y0 && x0 + nw <= b->x0 + b->cols && y0 + nw <= b->y0 + b->rows;
}

/* Re-reads the values of texel (u, v)'s n samples, sample s of light light[s] (as the
 * extractor gave them), the light colour applied as the extractor does. Returns how many
 * were re-read. */
static int resample_texel(const struct resample *rs, int u, int v, struct imp_btf_sample *smp,
                          const uint16_t *light, int n) {
        double wx[2 * PN_MAX_LANCZOS], wy[2 * PN_MAX_LANCZOS];
        int x0, y0;
        if (n <= 0 || !texel_window(rs, u, v, &x0, &y0, wx, wy))
                return 0;
        const struct imp_btf_band *b = rs->band;
        bool all = window_in_band(rs, x0, y0);
        double acc[IMP_BTF_MAX_SAMPLES];
        uint8_t ok[IMP_BTF_MAX_SAMPLES];
        if (all)
                lanczos_band_all(b, x0 - b->x0, y0 - b->y0, 2 * rs->a, rs->sat > 0 ? (float) rs->sat : INFINITY, wx,
                                 wy, acc, ok);
        int done = 0;
        for (int s = 0; s < n; s++) {
                int j = light[s];
                float val[3];
                if (all && ok[j])
                        val[0] = val[1] = val[2] = (float) acc[j];
                if (all ? ok[j] : lanczos_sample(rs, j, x0, y0, wx, wy, val)) {
                        apply_colour(rs, j, val, smp[s].value);
                        done++;
                }
        }
        return done;
}

/* The re-read ahead of the extraction, for imp_btf_extract_texel_given(): every light's
 * Lanczos value of texel (u, v), colour applied, into given[j] and ok[j] (read cleanly);
 * false when its window is not inside the band (the caller extracts, then resample_texel()
 * re-reads what it can from the frames). The values are resample_texel()'s. */
static bool reread_ahead(const struct resample *rs, int u, int v, float (*given)[3], uint8_t *ok) {
        double wx[2 * PN_MAX_LANCZOS], wy[2 * PN_MAX_LANCZOS], acc[IMP_BTF_MAX_SAMPLES];
        int x0, y0;
        if (!texel_window(rs, u, v, &x0, &y0, wx, wy) || !window_in_band(rs, x0, y0))
                return false;
        const struct imp_btf_band *b = rs->band;
        lanczos_band_all(b, x0 - b->x0, y0 - b->y0, 2 * rs->a, rs->sat > 0 ? (float) rs->sat : INFINITY, wx, wy,
                         acc, ok);
        for (int j = 0; j < b->L; j++)
                if (ok[j]) {
                        float val[3] = { (float) acc[j], (float) acc[j], (float) acc[j] };
                        apply_colour(rs, j, val, given[j]);
                }
        return true;
}

/* Texel result (local frame of the geometric normal ng) → unit canvas normal in out;
 * out untouched when the texel kept the geometric normal. */
static void to_canvas(const float *ng, const struct imp_pn_texel *t, const struct imp_photometric_params *p,
                      float *out) {
        if (t->flags & IMP_PN_KEPT)
                return;
        double n0[3] = { ng[0], ng[1], ng[2] }, tt[3], bb[3], nn[3], len = 0;
        imp_local_frame(n0, tt, bb);
        double wp = 1, wg = 0;
        if (p->geo_sigma_deg > 0) {
                double sp2 = fmax(1e-6, (double) t->sigma_deg * t->sigma_deg);
                wp = 1 / sp2;
                wg = 1 / (p->geo_sigma_deg * p->geo_sigma_deg);
        }
        for (int c = 0; c < 3; c++) {
                nn[c] = wp * (t->n[0] * tt[c] + t->n[1] * bb[c] + t->n[2] * n0[c]) + wg * n0[c];
                len += nn[c] * nn[c];
        }
        len = sqrt(len);
        if (!(len > 0) || !isfinite(len))
                return;
        for (int c = 0; c < 3; c++)
                out[c] = (float) (nn[c] / len);
}

/* σ of the geometric normal kept at texel i: the slope σ of a central difference of
 * heights with σh, √2·σh / (2·pitch), at least geo_min_sigma_deg; 180 without σh. */
static float geometric_sigma_deg(const struct imp_btf_heightfield *hf, const struct imp_photometric_params *p,
                                 size_t i) {
        if (!hf->sigma_mm || !(hf->sigma_mm[i] >= 0))
                return 180.0f;
        double s = atan(M_SQRT2 * hf->sigma_mm[i] / (2 * hf->pitch_mm)) / DEG;
        return (float) fmin(180.0, fmax(s, p->geo_min_sigma_deg));
}

/* The interpolation floor of a refined normal (canvas frame, unit) added to its σ. */
static float refined_sigma_deg(const struct imp_photometric_params *p, const float *n, float sigma_deg) {
        double tilt = acos(fmax(-1.0, fmin(1.0, n[2]))) / DEG;
        return (float) fmin(180.0, hypot(sigma_deg, p->interp_sigma_deg + p->interp_sigma_per_deg * tilt));
}

/* The parameters of the shadow-filled texels (mask value 2): cast-shadow trimming
 * (photometric.h). */
static void filled_params(const struct imp_photometric_params *p, struct imp_photometric_params *ret) {
        *ret = *p;
        ret->shadow_trim_sigma = p->filled_trim_sigma;
        ret->passes = IMP_MAX(p->passes, p->filled_passes);
        ret->max_dev_deg = p->filled_max_dev_deg > 0 ? p->filled_max_dev_deg : p->max_dev_deg;
}

struct pn_grid {
        const struct imp_btf_heightfield *hf;
        const struct imp_photometric_params *p, *pf;   /* pf: shadow-filled texels */
        const struct imp_photometric_out *out;
        const struct imp_btf_extractor *x;
        struct resample rs;
        double *dev, *sig, *rmsv;                    /* per texel, NAN where not refined */
};

/* Extracts and refines every texel of the w × h block at (x0, y0): one parallel loop, each
 * texel's samples in its thread's stack, no barrier between extraction and refinement. */
static void refine_tile(const struct pn_grid *G, int x0, int y0, int w, int h,
                        struct imp_photometric_stats *st) {
        const struct imp_btf_heightfield *hf = G->hf;
        const struct imp_photometric_out *out = G->out;
        long few = 0, ill = 0, dark = 0, dis = 0, msk = 0, res = 0, amb = 0, rsd = 0, sat = 0;
#pragma omp parallel for schedule(dynamic, 16) reduction(+ : few, ill, dark, dis, msk, res, amb, rsd, sat)
        for (int k = 0; k < w * h; k++) {
                size_t i = (size_t) (y0 + k / w) * hf->width + x0 + k % w;
                struct imp_btf_sample ts[IMP_BTF_MAX_SAMPLES];   /* 20 KiB of stack */
                uint16_t sflags, n_shadowed, light[IMP_BTF_MAX_SAMPLES];
                float given[IMP_BTF_MAX_SAMPLES][3];
                uint8_t given_ok[IMP_BTF_MAX_SAMPLES];
                /* the re-read first (every light's window at once), the extractor then skips the
                 * bilinear values it replaces; off the band the re-read comes after */
                bool ahead = !(hf->mask && !hf->mask[i]) &&
                             reread_ahead(&G->rs, x0 + k % w, y0 + k / w, given, given_ok);
                int count = imp_btf_extract_texel_given(G->x, G->rs.band, x0 + k % w, y0 + k / w, ahead ? given : NULL,
                                                        ahead ? given_ok : NULL, ts, light, &sflags, &n_shadowed);
                struct imp_pn_texel t;
                bool masked = (sflags & (IMP_BTF_MASKED | IMP_BTF_HIDDEN)) || (hf->mask && !hf->mask[i]);
                if (masked) {
                        t = (struct imp_pn_texel) { .n = { 0, 0, 1 }, .sigma_deg = 180, .flags = IMP_PN_MASKED };
                } else {
                        const struct imp_photometric_params *pt = hf->mask && hf->mask[i] == 2 ? G->pf : G->p;
                        if (ahead)
                                for (int s = 0; s < count; s++)
                                        res += given_ok[light[s]];
                        else
                                res += resample_texel(&G->rs, x0 + k % w, y0 + k / w, ts, light, count);
                        imp_photometric_texel(ts, count, pt, &t);
                        if ((sflags & IMP_BTF_SATURATED) && (t.flags & IMP_PN_FEW_SAMPLES))
                                t.flags |= IMP_PN_SATURATED;
                }
                if (out->flags)
                        out->flags[i] = t.flags;
                if (out->texel_flags)
                        out->texel_flags[i] = imp_photometric_texel_flags(t.flags);
                few += !!(t.flags & IMP_PN_FEW_SAMPLES) && !(t.flags & IMP_PN_MASKED);
                ill += !!(t.flags & IMP_PN_ILL_COND);
                dark += !!(t.flags & IMP_PN_DARK);
                dis += !!(t.flags & IMP_PN_DISAGREES);
                msk += !!(t.flags & IMP_PN_MASKED);
                amb += !!(t.flags & IMP_PN_AMBIENT);
                rsd += !!(t.flags & IMP_PN_RESIDUAL);
                sat += !!(t.flags & IMP_PN_SATURATED);
                G->dev[i] = G->sig[i] = G->rmsv[i] = NAN;
                if (t.flags & IMP_PN_KEPT) {
                        if (out->sigma_deg)
                                out->sigma_deg[i] = masked ? 0.0f : geometric_sigma_deg(hf, G->p, i);
                        continue;
                }
                to_canvas(&hf->normal[3 * i], &t, G->p, &out->normal[3 * i]);
                float sd = refined_sigma_deg(G->p, &out->normal[3 * i], t.sigma_deg);
                if (out->sigma_deg)
                        out->sigma_deg[i] = sd;
                G->dev[i] = t.dev_deg;
                G->sig[i] = sd;
                G->rmsv[i] = t.rms;
        }
        st->n_few += few;
        st->n_ill += ill;
        st->n_dark += dark;
        st->n_disagree += dis;
        st->n_masked += msk;
        st->n_ambient += amb;
        st->n_residual += rsd;
        st->n_saturated += sat;
        st->n_resampled += res;
}

/* refine_tile over bands of IMP_BTF_BAND_ROWS texel rows, the extractor's taps and the
 * re-read's windows read from the band when the frames allow one and its box fits
 * IMP_BTF_BAND_BYTES (else, or without memory for it, from the frames: the same values
 * either way). */
static void refine_bands(struct pn_grid *G, struct imp_photometric_stats *st) {
        const struct imp_btf_heightfield *hf = G->hf;
        struct imp_btf_band b = {};
        for (int v0 = 0; v0 < hf->height; v0 += IMP_BTF_BAND_ROWS) {
                int rows = IMP_MIN(IMP_BTF_BAND_ROWS, hf->height - v0);
                G->rs.band = imp_btf_band_load(G->x, v0, rows, G->rs.a, &b) ? &b : NULL;
                refine_tile(G, 0, v0, hf->width, rows, st);
        }
        G->rs.band = NULL;
        imp_btf_band_done(&b);
}

/* Ambient light is the room's, not a texel's: it adds ρd·A to every frame, whatever the
 * light. The 4-unknown check cannot see it where the samples taking part are all at one
 * elevation (the other ring in the mirror cone of an overhead camera) and, on all the lit
 * samples, a specular lobe cancels it; on the hard suite's ambient scene it found the term
 * on 69 % of the texels and the other 31 % kept normals up to 44° off under a σ of 1–2°.
 * So when it finds a significant term on more than PN_AMBIENT_CANVAS_FRAC of the texels it
 * decided on (the demo: 2 in 930,000), every refined normal goes back to the geometric one
 * with IMP_PN_AMBIENT, as a texel where it was found. */
#define PN_AMBIENT_CANVAS_FRAC 0.10
static void ambient_canvas_wide(const struct pn_grid *G, struct imp_photometric_stats *st) {
        const struct imp_btf_heightfield *hf = G->hf;
        const struct imp_photometric_out *out = G->out;
        size_t nt = (size_t) hf->width * hf->height;
        long refined = 0;
        for (size_t i = 0; i < nt; i++)
                refined += isfinite(G->dev[i]);
        if (!(st->n_ambient > PN_AMBIENT_CANVAS_FRAC * (double) (refined + st->n_ambient)))
                return;
        for (size_t i = 0; i < nt; i++) {
                if (!isfinite(G->dev[i]))
                        continue;
                memcpy(&out->normal[3 * i], &hf->normal[3 * i], 3 * sizeof *out->normal);
                if (out->flags)
                        out->flags[i] |= IMP_PN_AMBIENT;
                if (out->texel_flags)
                        out->texel_flags[i] |= imp_photometric_texel_flags(IMP_PN_AMBIENT);
                if (out->sigma_deg)
                        out->sigma_deg[i] = geometric_sigma_deg(hf, G->p, i);
                G->dev[i] = G->sig[i] = G->rmsv[i] = NAN;
                st->n_ambient++;
        }
        st->ambient_canvas = true;
}

/* Figures over the refined texels (compacts the finite entries of dev, sig, rmsv). */
static void summarise(double *dev, double *sig, double *rmsv, size_t nt, struct imp_photometric_stats *st) {
        size_t n_ref = 0;
        double dev_sum = 0;
        for (size_t i = 0; i < nt; i++)
                if (isfinite(dev[i])) {
                        dev_sum += dev[i];
                        dev[n_ref] = dev[i];
                        sig[n_ref] = sig[i];
                        rmsv[n_ref] = rmsv[i];
                        n_ref++;
                }
        st->n_refined = (long) n_ref;
        if (!n_ref)
                return;
        st->dev_deg_mean = dev_sum / n_ref;
        /* the middle elements by selection: the values are floats widened, so a float copy
         * selects the same ones (a sort of three 10⁶ arrays was a serial second) */
        float *tmp = malloc(n_ref * sizeof *tmp);
        double *v[3] = { dev, sig, rmsv }, *med[3] = { &st->dev_deg_median, &st->sigma_deg_median, &st->rms_median };
        for (int k = 0; k < 3; k++) {
                if (!tmp) {
                        qsort(v[k], n_ref, sizeof *v[k], cmp_double);
                        *med[k] = v[k][n_ref / 2];
                        continue;
                }
                for (size_t i = 0; i < n_ref; i++)
                        tmp[i] = (float) v[k][i];
                *med[k] = imp_select_kth_float(tmp, n_ref, n_ref / 2);
        }
        free(tmp);
}

int imp_photometric_normals(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                            const struct imp_btf_sample_params *sp, const struct imp_photometric_params *p,
                            const struct imp_photometric_out *out, struct imp_photometric_stats *ret_stats) {
        if (!hf || !cap || !sp || !p || !out || !out->normal || out->normal == hf->normal || !hf->normal ||
            hf->width <= 0 || hf->height <= 0)
                return -EINVAL;
        if (p->lanczos < 0 || p->lanczos > PN_MAX_LANCZOS || kernel_half_width(p->kernel, p->lanczos) < 0)
                return -EINVAL;
        size_t nt = (size_t) hf->width * hf->height;
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL;
        int r;
        if ((r = imp_btf_hf_pyramid_new(hf, &py)) < 0 || (r = imp_btf_extractor_new(hf, cap, sp, py, &x)) < 0)
                return r;
        _cleanup_free_ double *dev = malloc(nt * sizeof *dev), *sig = malloc(nt * sizeof *sig),
                              *rmsv = malloc(nt * sizeof *rmsv);
        if (!dev || !sig || !rmsv)
                return -ENOMEM;
        struct imp_photometric_params pf;
        filled_params(p, &pf);
        struct pn_grid G = { .hf = hf, .p = p, .pf = &pf, .out = out, .x = x, .dev = dev, .sig = sig, .rmsv = rmsv,
                             .rs = { .hf = hf, .cap = cap, .sat = sp->saturation_value,
                                     .a = kernel_half_width(p->kernel, p->lanczos), .order = p->lanczos,
                                     .kernel = p->kernel } };
        for (int i = 0; i < 3; i++) {
                for (int k = 0; k < 3; k++)
                        G.rs.R[3 * i + k] = hf->canvas_to_world[4 * i + k];
                G.rs.t[i] = hf->canvas_to_world[4 * i + 3];
        }
        memcpy(out->normal, hf->normal, nt * 3 * sizeof *out->normal);
        struct imp_photometric_stats st = { .n_texels = (long) nt };
        refine_bands(&G, &st);
        ambient_canvas_wide(&G, &st);
        summarise(dev, sig, rmsv, nt, &st);
        if (ret_stats)
                *ret_stats = st;
        return 0;
}

/* imp_btf_frames.estimate of imp_photometric_frames(): the model on the fit's samples. */
static bool frame_estimate(const void *data, long texel, const struct imp_btf_sample *samples, int n,
                           const float n0[3], float ret_n[3]) {
        const struct imp_photometric_frames *f = data;
        const struct imp_photometric_params *p = f->mask && f->mask[texel] == 2 ? &f->pf : &f->p;
        struct imp_pn_texel t;
        if (imp_photometric_texel(samples, n, p, &t) < 0 || (t.flags & IMP_PN_KEPT))
                return false;
        memcpy(ret_n, n0, 3 * sizeof *ret_n);
        to_canvas(n0, &t, p, ret_n);
        return true;
}

int imp_photometric_frames(const struct imp_btf_heightfield *hf, const struct imp_photometric_params *p, int mode,
                           float *normal, struct imp_photometric_frames *f, struct imp_btf_frames *ret) {
        if (!hf || !p || !normal || !f || !ret || normal == hf->normal ||
            (mode != IMP_BTF_FRAMES_EXTRACT && mode != IMP_BTF_FRAMES_ROTATE))
                return -EINVAL;
        struct imp_pn_texel t;
        int r = imp_photometric_texel(NULL, 0, p, &t);   /* checks p */
        if (r < 0)
                return r;
        *f = (struct imp_photometric_frames) { .mask = hf->mask, .width = hf->width, .height = hf->height, .p = *p };
        filled_params(p, &f->pf);
        *ret = (struct imp_btf_frames) { .estimate = frame_estimate, .data = f, .mode = mode, .normal = normal };
        return 0;
}

/* The difference of refined normal a from geometric normal g as a tangent vector of g whose
 * length is the angle between them (degrees). */
static double diff_vec(const float *a, const float *g, double d[3]) {
        double c = a[0] * g[0] + a[1] * g[1] + a[2] * g[2], len = 0;
        for (int k = 0; k < 3; k++) {
                d[k] = a[k] - c * g[k];
                len += d[k] * d[k];
        }
        len = sqrt(len);
        double ang = atan2(len, c) / DEG;
        for (int k = 0; k < 3; k++)
                d[k] = len > 0 ? d[k] / len * ang : 0;
        return ang;
}

long imp_photometric_agreement(int nx, int ny, const uint8_t *mask, const uint16_t *pn_flags, const float *normal,
                               const float *geo_normal, const float *geo_sigma_deg,
                               const struct imp_photometric_params *p, float *sigma_deg) {
        if (nx <= 0 || ny <= 0 || !pn_flags || !normal || !geo_normal || !p || !sigma_deg || p->agree_radius < 0 ||
            !(p->agree_corr_texels >= 1) || !(p->agree_k > 0))
                return -EINVAL;
        size_t n = (size_t) nx * ny;
        _cleanup_free_ double *d = malloc(n * 4 * sizeof *d);   /* difference vector, σg² + σp² */
        _cleanup_free_ float *out = malloc(n * sizeof *out);
        if (!d || !out)
                return -ENOMEM;
        for (size_t t = 0; t < n; t++) {
                bool ref = !(pn_flags[t] & IMP_PN_KEPT) && (!mask || mask[t]);
                double sg = geo_sigma_deg && isfinite(geo_sigma_deg[t]) ? geo_sigma_deg[t] : 1.0;
                d[4 * t + 3] = ref ? sg * sg + (double) sigma_deg[t] * sigma_deg[t] : NAN;
                if (ref)
                        diff_vec(&normal[3 * t], &geo_normal[3 * t], &d[4 * t]);
                out[t] = sigma_deg[t];
        }
        int R = p->agree_radius;
        long grown = 0;
#pragma omp parallel for schedule(dynamic, 8) reduction(+ : grown)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!isfinite(d[4 * t + 3]))
                                continue;
                        double m[3] = { 0, 0, 0 }, v = 0, a2 = 0;
                        int cnt = 0;
                        for (int y = IMP_MAX(0, j - R); y <= IMP_MIN(ny - 1, j + R); y++)
                                for (int x = IMP_MAX(0, i - R); x <= IMP_MIN(nx - 1, i + R); x++) {
                                        const double *q = &d[4 * ((size_t) y * nx + x)];
                                        if (!isfinite(q[3]))
                                                continue;
                                        m[0] += q[0], m[1] += q[1], m[2] += q[2], v += q[3];
                                        a2 += q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
                                        cnt++;
                                }
                        double neff = fmax(1.0, cnt / (p->agree_corr_texels * p->agree_corr_texels));
                        double mm = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]) / ((double) cnt * cnt);
                        /* a bias the same over the window (the mean difference), or one that
                         * follows the relief (the mean squared difference beyond the noise, by
                         * more than twice that excess's own scatter, v/cnt·√(2/neff)) */
                        double vm = v / cnt, bias2 = fmax(0.0, fmax(mm - 2 * vm / neff,
                                                                    a2 / cnt - vm * (1 + 2 * sqrt(2 / neff))));
                        double sp = sigma_deg[t], s = sqrt(sp * sp + bias2);
                        const double *q = &d[4 * t];
                        double ang = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
                        if (ang > p->agree_k * sqrt(q[3] + bias2))
                                s = fmax(s, ang);
                        s = fmin(180.0, s);
                        grown += s > sp * 1.1;
                        out[t] = (float) s;
                }
        memcpy(sigma_deg, out, n * sizeof *out);
        return grown;
}
