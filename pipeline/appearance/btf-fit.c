/* Per-texel one-lobe Lafortune fit (seed 000 eq. 1; docs/btf-fit.md): variable projection
 * — for a fixed lobe the model is linear in ρd, ρs, solved per channel by a closed-form
 * 2-variable NNLS — and Levenberg–Marquardt on the lobe (Cx, Cy, log k) in the Cz = 1
 * gauge, with bounds, a Huber loss scaled by the MAD, a k-grid multi-start, and honest
 * flags when the data cannot determine the lobe. Then hole filling and the tiled driver. */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "btf.h"
#include "numerics.h"
#include "quality.h"
#ifdef _OPENMP
#include <omp.h>
#define IMP_BTF_THREAD_NUM() omp_get_thread_num()
#else
#define IMP_BTF_THREAD_NUM() 0
#endif

#define MAXP 3                        /* lobe parameters: (cx, cy, log k) or (cxy, log k) */
#define COND_MAX 1e12                 /* reported condition numbers are capped here */
#define RHO_S_MAX 1e4                 /* last-resort cap of the reported ρs */
#define PEAK_SEEN_FLAG 0.15           /* LOBE_UNCERTAIN when the brightest seen lobe value is
                                         below this fraction of the lobe's peak */
#define LAMBDA_INIT 1e-3
#define LAMBDA_MAX 1e8
#define STEP_MIN 1e-4                 /* stop when no parameter moves more than this */

static const double k_grid[] = { 2, 5, 12, 30, 80, 200, 500 };

/* The per-sample loops below are built three times, for AVX-512 (16 float lanes), AVX2
 * (8) and the x86-64 baseline (SSE2, 4), and the CPU picks at load time (ifunc). Not FMA:
 * contraction would make the result depend on the machine (GCC's avx512f target enables
 * FMA, hence -ffp-contract=off for this file: pipeline/CMakeLists.txt). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define CLONES
#endif

/* The per-sample arrays are padded to a whole number of VEC_PAD samples (the widest vector,
 * 16 float lanes) with samples that add exact zeros to every sum (W = 0, y = 0, outside
 * the lobe): the vector loops of the lobe run without a scalar remainder (the demo's
 * texels have ≈ 36 samples: two vectors and 4 scalar iterations of the exp). */
#define VEC_PAD 16

void imp_btf_fit_params_default(struct imp_btf_fit_params *ret) {
        *ret = (struct imp_btf_fit_params) {
                .min_samples = 6,
                .k_min = 1.0,
                .k_max = 1000.0,
                .c_max = 1.0,
                .max_iter = 30,
                .tol = 1e-4,
                .robust_passes = 2,
                .huber_delta = 1.345,
                .sigma_floor = 0.002,
                .matte_threshold = 0.01,
                .cxy_tau = 1e-3,
                .k_rel_uncertain = 0.2,
                .k_default = 10.0,
                .c_prior_sigma = 0.5,
                .peak_seen_min = PEAK_SEEN_FLAG,
        };
}

/* Per-texel workspace (on the stack: ~40 kB). W = l_z² · robust weight: residuals are
 * those of V/E, i.e. cos θl · (y − model) with y = V / (E cos θl). Wy = W·y and the sums
 * that depend on the weights only (sw, sy, syy) are refreshed by set_weights(). */
struct work {
        int n, np;                    /* samples; padded to a multiple of VEC_PAD */
        float ax[IMP_BTF_MAX_SAMPLES], ay[IMP_BTF_MAX_SAMPLES], az[IMP_BTF_MAX_SAMPLES];
        float wl[IMP_BTF_MAX_SAMPLES], om[IMP_BTF_MAX_SAMPLES], W[IMP_BTF_MAX_SAMPLES];
        float y[3][IMP_BTF_MAX_SAMPLES], Wy[3][IMP_BTF_MAX_SAMPLES];
        float d[IMP_BTF_MAX_SAMPLES], g[IMP_BTF_MAX_SAMPLES], ld[IMP_BTF_MAX_SAMPLES];
        float res[IMP_BTF_MAX_SAMPLES];
        double sw, sy[3], syy[3];
};

/* One evaluation of the reduced problem at a lobe. g is normalised by its largest value
 * over the samples (ρs absorbs any scale), so it lies in [0, 1] for every k. */
struct eval {
        double cx, cy, k;
        double ldmax;                 /* max ln d over samples with d > 0 (-HUGE_VAL: none) */
        double rd[3], rs[3];          /* NNLS solution per channel (rs for normalised g) */
        bool rd_active[3];            /* ρd_c > 0 (free) */
        double sw, sg, sgg;
        double cost;                  /* Σ W Σ_c r² */
};

/* ---- float exp and log that vectorise ------------------------------------------ */

/* These run inside `omp simd` loops (glibc's expf/logf are calls that block the
 * vectoriser). Both are the Cephes single-precision polynomials: relative error within
 * 1 ulp of the correctly rounded value over the ranges used here. Branch-free: both
 * operations run unconditionally and only values or constants are selected, and the
 * comparisons are the quiet ones (isgreater): under -ftrapping-math GCC will not
 * if-convert a floating-point operation or an ordered comparison that may trap. */
static inline float bits_to_float(uint32_t u) { float f; memcpy(&f, &u, sizeof f); return f; }
static inline uint32_t float_to_bits(float f) { uint32_t u; memcpy(&u, &f, sizeof u); return u; }

/* e^x for x ≤ 0 (x may be -inf); 0 below -87 (where e^x leaves the normal floats: no denormals, no slow
 * path). */
static inline float exp_neg(float x) {
        const float ln2_hi = 0.693359375f, ln2_lo = -2.12194440e-4f;
        const float round_magic = 12582912.0f;        /* 1.5·2^23: adds round to nearest */
        const uint32_t lim = 0xc2ae0000u;             /* bits of -87.0f */
        uint32_t xb = float_to_bits(x);
        bool ok = xb <= lim;                          /* x ≥ -87 (x ≤ 0: bits grow with |x|) */
        float xc = bits_to_float(ok ? xb : lim);
        float fn = (xc * 1.44269504088896341f + round_magic) - round_magic;
        float r = xc - fn * ln2_hi - fn * ln2_lo;
        float p = 1.9875691500e-4f;
        p = p * r + 1.3981999507e-3f;
        p = p * r + 8.3334519073e-3f;
        p = p * r + 4.1665795894e-2f;
        p = p * r + 1.6666665459e-1f;
        p = p * r + 5.0000001201e-1f;
        p = p * r * r + r + 1.0f;
        uint32_t scale = (uint32_t) ((int32_t) fn + 127) << 23;
        return p * bits_to_float(ok ? scale : 0u);
}

/* ln x for finite x ≥ FLT_MIN (callers floor x there). x = 2^e · m with m in
 * [√2/2, √2), found with integer arithmetic only: subtracting the bits of √2/2 makes the
 * exponent field count from there (the trick of ARM's optimized-routines logf). */
static inline float log_pos(float x) {
        const uint32_t off = 0x3f3504f3u;             /* bits of √2/2 */
        uint32_t u = float_to_bits(x), tmp = u - off;
        int32_t e = (int32_t) tmp >> 23;              /* arithmetic shift: floor */
        float m = bits_to_float(u - (tmp & 0xff800000u));
        float f = m - 1.0f, z = f * f, fe = (float) e;
        float p = 7.0376836292e-2f;
        p = p * f - 1.1514610310e-1f;
        p = p * f + 1.1676998740e-1f;
        p = p * f - 1.2420140846e-1f;
        p = p * f + 1.4249322787e-1f;
        p = p * f - 1.6668057665e-1f;
        p = p * f + 2.0000714765e-1f;
        p = p * f - 2.4999993993e-1f;
        p = p * f + 3.3333331174e-1f;
        float r = f * z * p - 2.12194440e-4f * fe;
        r += -0.5f * z;
        return f + r + 0.693359375f * fe;
}

/* ---- the linear part: 2-variable non-negative least squares ---------------------- */

static double q_cost(double a, double b, double sw, double sg, double sgg, double sy, double sgy, double syy) {
        return syy - 2.0 * (a * sy + b * sgy) + a * a * sw + 2.0 * a * b * sg + b * b * sgg;
}

/* min Σ W (y − a − b g)², a, b ≥ 0: the unconstrained optimum when feasible, otherwise
 * the best of the KKT faces (a = 0, b = 0, both 0) — exact for this convex 2-D QP. */
static inline double nnls2(double sw, double sg, double sgg, double sy, double sgy, double syy,
                    double *ret_a, double *ret_b) {
        double det = sw * sgg - sg * sg;
        if (det > 1e-12 * sw * sgg && sgg > 0.0) {
                double a = (sgg * sy - sg * sgy) / det, b = (sw * sgy - sg * sy) / det;
                if (a >= 0.0 && b >= 0.0) {
                        *ret_a = a;
                        *ret_b = b;
                        return q_cost(a, b, sw, sg, sgg, sy, sgy, syy);
                }
        }
        double best_a = 0.0, best_b = 0.0, best = syy;
        if (sgg > 0.0 && sgy > 0.0) {
                double b = sgy / sgg, c = q_cost(0.0, b, sw, sg, sgg, sy, sgy, syy);
                if (c < best) { best = c; best_a = 0.0; best_b = b; }
        }
        if (sw > 0.0 && sy > 0.0) {
                double a = sy / sw, c = q_cost(a, 0.0, sw, sg, sgg, sy, sgy, syy);
                if (c < best) { best = c; best_a = a; best_b = 0.0; }
        }
        *ret_a = best_a;
        *ret_b = best_b;
        return best;
}

/* After a change of W: Wy and the weight-only sums. */
CLONES static void set_weights(struct work *w) {
        double sw = 0.0, sy0 = 0, sy1 = 0, sy2 = 0, syy0 = 0, syy1 = 0, syy2 = 0;
        const float *restrict WW = w->W, *restrict Y0 = w->y[0], *restrict Y1 = w->y[1], *restrict Y2 = w->y[2];
        float *restrict Wy0 = w->Wy[0], *restrict Wy1 = w->Wy[1], *restrict Wy2 = w->Wy[2];
#pragma omp simd reduction(+ : sw, sy0, sy1, sy2, syy0, syy1, syy2)
        for (int i = 0; i < w->np; i++) {
                double W = WW[i], a = W * Y0[i], b = W * Y1[i], c = W * Y2[i];
                Wy0[i] = (float) a;
                Wy1[i] = (float) b;
                Wy2[i] = (float) c;
                sw += W;
                sy0 += a;
                sy1 += b;
                sy2 += c;
                syy0 += a * Y0[i];
                syy1 += b * Y1[i];
                syy2 += c * Y2[i];
        }
        w->sw = sw;
        w->sy[0] = sy0;
        w->sy[1] = sy1;
        w->sy[2] = sy2;
        w->syy[0] = syy0;
        w->syy[1] = syy1;
        w->syy[2] = syy2;
}

/* Fills w->d (floored at FLT_MIN) and w->ld (its log; LD_NONE where d ≤ 0) for the
 * lobe (cx, cy, 1); returns the largest ln d (-HUGE_VAL: no d > 0). Every stored value is
 * finite, so that samples outside the lobe (g = 0) contribute exact zeros to the
 * vectorised sums of normal_matrix() instead of 0·∞. */
#define LD_NONE (-1e30f)
CLONES static double lobe_logs(struct work *w, double cx, double cy) {
        int n = w->np;
        float fx = (float) cx, fy = (float) cy, ldmax = LD_NONE;
        float *restrict d = w->d, *restrict ld = w->ld;
        const float *restrict ax = w->ax, *restrict ay = w->ay, *restrict az = w->az;
#pragma omp simd reduction(max : ldmax)
        for (int i = 0; i < n; i++) {
                float di = fx * ax[i] + fy * ay[i] + az[i];
                /* Integer max and masks on the bits: as signed integers, non-negative
                 * floats order like their values (and no float select, see above). */
                int32_t db = (int32_t) float_to_bits(di), lo = (int32_t) float_to_bits(FLT_MIN);
                uint32_t neg = (uint32_t) -(int32_t) (db <= 0);
                float df = bits_to_float((uint32_t) (db > lo ? db : lo));
                float l = log_pos(df) + bits_to_float(neg & float_to_bits(LD_NONE));
                d[i] = df;
                ld[i] = l;
                ldmax = isgreater(l, ldmax) ? l : ldmax;
        }
        return ldmax > 0.5f * LD_NONE ? ldmax : -HUGE_VAL;
}

/* The linear part of e from the lobe sums sg, sgg and Σ W y g per channel. */
static void solve_linear(const struct work *w, double k, double ldmax, double sg, double sgg, const double sgy[3],
                         struct eval *e) {
        e->k = k;
        e->ldmax = ldmax;
        e->sw = w->sw;
        e->sg = sg;
        e->sgg = sgg;
        e->cost = 0.0;
        for (int c = 0; c < 3; c++) {
                double cc = nnls2(w->sw, sg, sgg, w->sy[c], sgy[c], w->syy[c], &e->rd[c], &e->rs[c]);
                e->cost += fmax(cc, 0.0);
                e->rd_active[c] = e->rd[c] > 0.0;
        }
}

/* Fills w->g for exponent k (the logs of lobe_logs() with their maximum ldmax) and
 * solves the linear part. */
CLONES static void lobe_solve(struct work *w, double k, double ldmax, struct eval *e) {
        int n = w->np;
        double sg = 0, sgg = 0, sgy0 = 0, sgy1 = 0, sgy2 = 0;
        float kf = (float) k, lm = (float) ldmax;
        float *restrict g = w->g;
        const float *restrict ld = w->ld, *restrict W = w->W;
        const float *restrict wy0 = w->Wy[0], *restrict wy1 = w->Wy[1], *restrict wy2 = w->Wy[2];
        if (ldmax > -HUGE_VAL) {
#pragma omp simd reduction(+ : sg, sgg, sgy0, sgy1, sgy2)
                for (int i = 0; i < n; i++) {
                        float gi = exp_neg(kf * (ld[i] - lm));     /* ld = -inf → 0 */
                        g[i] = gi;
                        float Wg = W[i] * gi;
                        sg += Wg;
                        sgg += Wg * gi;
                        sgy0 += wy0[i] * gi;
                        sgy1 += wy1[i] * gi;
                        sgy2 += wy2[i] * gi;
                }
        } else {
                memset(g, 0, n * sizeof *g);
        }
        solve_linear(w, k, ldmax, sg, sgg, (const double[3]) { sgy0, sgy1, sgy2 }, e);
}

/* e re-solved after a change of the weights, at the same lobe: w->g (that of e) is
 * kept, only the sums are formed again (the same sums as lobe_solve(), without the exps). */
CLONES static void lobe_resolve(const struct work *w, struct eval *e) {
        int n = w->np;
        double sg = 0, sgg = 0, sgy0 = 0, sgy1 = 0, sgy2 = 0;
        const float *restrict g = w->g, *restrict W = w->W;
        const float *restrict wy0 = w->Wy[0], *restrict wy1 = w->Wy[1], *restrict wy2 = w->Wy[2];
        if (e->ldmax > -HUGE_VAL) {
#pragma omp simd reduction(+ : sg, sgg, sgy0, sgy1, sgy2)
                for (int i = 0; i < n; i++) {
                        float gi = g[i], Wg = W[i] * gi;
                        sg += Wg;
                        sgg += Wg * gi;
                        sgy0 += wy0[i] * gi;
                        sgy1 += wy1[i] * gi;
                        sgy2 += wy2[i] * gi;
                }
        }
        solve_linear(w, e->k, e->ldmax, sg, sgg, (const double[3]) { sgy0, sgy1, sgy2 }, e);
}

/* Fills w->d, w->ld, w->g for the lobe and solves the linear part. */
static void evaluate(struct work *w, double cx, double cy, double k, struct eval *e) {
        lobe_solve(w, k, lobe_logs(w, cx, cy), e);
        e->cx = cx;
        e->cy = cy;
}

/* ---- the lobe: Gauss–Newton matrix of the reduced problem ------------------------ */

/* H = Jᵀ(I − P)J (variable projection, Kaufman) and b = −½ ∇cost, at the lobe of e (w's
 * d, ld, g must be those of e). Returns the number of parameters. J is the Jacobian of
 * g w.r.t. (Cx, Cy, log k): g·k·(ax/d, ay/d, ln d − ldmax); scale terms (the derivative
 * of the normalisation) are dropped: they lie in the span of g and are projected out
 * with the linear parameters. Under CX_EQ_CY the parameter Cxy moves both: its column is
 * the sum of the first two. Samples with g = 0 add exact zeros (lobe_logs()). */
CLONES static int normal_matrix(const struct work *w, const struct eval *e, bool cxy, double H[MAXP][MAXP],
                         double b[MAXP]) {
        const double k = e->k, lm = e->ldmax;
        double c0 = 0.0, css = 0.0;
        for (int c = 0; c < 3; c++) {
                c0 += e->rs[c] * e->rd[c];
                css += e->rs[c] * e->rs[c];
        }
        const double r0 = e->rs[0], r1 = e->rs[1], r2 = e->rs[2];
        double s1x = 0, s1y = 0, s1k = 0, s2x = 0, s2y = 0, s2k = 0, bx = 0, by = 0, bk = 0;
        double axx = 0, axy = 0, ayy = 0, akx = 0, aky = 0, akk = 0;
        const float *restrict G = w->g, *restrict D = w->d, *restrict LD = w->ld, *restrict WW = w->W;
        const float *restrict AX = w->ax, *restrict AY = w->ay;
        const float *restrict Y0 = w->y[0], *restrict Y1 = w->y[1], *restrict Y2 = w->y[2];
#pragma omp simd reduction(+ : s1x, s1y, s1k, s2x, s2y, s2k, bx, by, bk, axx, axy, ayy, akx, aky, akk)
        for (int i = 0; i < w->np; i++) {
                double g = G[i], W = WW[i], q = k * g / D[i];
                double jx = q * AX[i], jy = q * AY[i], jk = k * g * (LD[i] - lm);
                double R = r0 * Y0[i] + r1 * Y1[i] + r2 * Y2[i] - c0 - css * g;
                double wx = W * jx, wy = W * jy, wk = W * jk;
                s1x += wx;
                s1y += wy;
                s1k += wk;
                s2x += wx * g;
                s2y += wy * g;
                s2k += wk * g;
                bx += wx * R;
                by += wy * R;
                bk += wk * R;
                axx += wx * jx;
                axy += wx * jy;
                ayy += wy * jy;
                akx += wk * jx;
                aky += wk * jy;
                akk += wk * jk;
        }
        double A[MAXP][MAXP] = { { 0 } }, s1[MAXP], s2[MAXP];
        int np;
        if (cxy) {
                np = 2;
                s1[0] = s1x + s1y;
                s2[0] = s2x + s2y;
                b[0] = bx + by;
                s1[1] = s1k;
                s2[1] = s2k;
                b[1] = bk;
                A[0][0] = axx + 2.0 * axy + ayy;
                A[1][0] = akx + aky;
                A[1][1] = akk;
        } else {
                np = 3;
                s1[0] = s1x; s1[1] = s1y; s1[2] = s1k;
                s2[0] = s2x; s2[1] = s2y; s2[2] = s2k;
                b[0] = bx; b[1] = by; b[2] = bk;
                A[0][0] = axx;
                A[1][0] = axy;
                A[1][1] = ayy;
                A[2][0] = akx;
                A[2][1] = aky;
                A[2][2] = akk;
        }
        memset(H, 0, sizeof(double) * MAXP * MAXP);
        double det = e->sw * e->sgg - e->sg * e->sg;
        for (int c = 0; c < 3; c++) {
                double rs2 = e->rs[c] * e->rs[c];
                if (rs2 == 0.0)
                        continue;
                for (int j = 0; j < np; j++)
                        for (int l = 0; l <= j; l++) {
                                double proj;
                                if (e->rd_active[c] && det > 0.0)
                                        proj = (e->sgg * s1[j] * s1[l] - e->sg * (s1[j] * s2[l] + s2[j] * s1[l]) +
                                                e->sw * s2[j] * s2[l]) / det;
                                else
                                        proj = e->sgg > 0.0 ? s2[j] * s2[l] / e->sgg : 0.0;
                                H[j][l] += rs2 * (A[j][l] - proj);
                        }
        }
        for (int j = 0; j < np; j++)
                for (int l = 0; l < j; l++)
                        H[l][j] = H[j][l];
        for (int j = 0; j < np; j++)
                H[j][j] = fmax(H[j][j], 0.0);
        return np;
}

/* Cholesky solve of the small SPD system M x = r; false when not positive definite. */
static bool chol_solve(int np, double M[MAXP][MAXP], const double r[MAXP], double x[MAXP]) {
        double L[MAXP * MAXP];
        for (int i = 0; i < np; i++)
                for (int j = 0; j < np; j++)
                        L[i * np + j] = M[i][j];
        if (!imp_cholesky_factor(np, L))
                return false;
        memcpy(x, r, (size_t) np * sizeof *x);
        imp_cholesky_solve(np, L, x);
        return true;
}

/* Condition number of H after scaling it to unit diagonal; COND_MAX when singular. */
static double equilibrated_cond(int np, const double H[MAXP][MAXP]) {
        double S[MAXP * MAXP], ev[MAXP], lo = HUGE_VAL, hi = 0.0;
        for (int j = 0; j < np; j++)
                if (!(H[j][j] > 0.0))
                        return COND_MAX;
        for (int j = 0; j < np; j++)
                for (int l = 0; l < np; l++)
                        S[j * np + l] = H[j][l] / sqrt(H[j][j] * H[l][l]);
        imp_eigen_sym(np, S, ev, NULL);
        for (int j = 0; j < np; j++) {
                lo = fmin(lo, ev[j]);
                hi = fmax(hi, ev[j]);
        }
        if (!(lo > hi / COND_MAX))
                return COND_MAX;
        return hi / lo;
}

/* ---- Levenberg–Marquardt on the lobe --------------------------------------------- */

/* Bounds and the prior of the lobe parameters. The prior mu·Σ(c + 1)² (Cz = 1 gauge)
 * pulls Cx, Cy towards the mirror lobe only along directions the data leave free. */
struct bounds { double c_max, lk_min, lk_max, mu; };

static double prior_cost(bool cxy, const struct bounds *bd, const double th[MAXP]) {
        if (cxy)
                return 2.0 * bd->mu * (th[0] + 1.0) * (th[0] + 1.0);
        return bd->mu * ((th[0] + 1.0) * (th[0] + 1.0) + (th[1] + 1.0) * (th[1] + 1.0));
}

static void theta_to_lobe(bool cxy, const double th[MAXP], double *cx, double *cy, double *k) {
        *cx = th[0];
        *cy = cxy ? th[0] : th[1];
        *k = exp(th[cxy ? 1 : 2]);
}

static void clamp_theta(bool cxy, const struct bounds *bd, double th[MAXP]) {
        int np = cxy ? 2 : 3;
        for (int j = 0; j < np - 1; j++)
                th[j] = IMP_CLAMP(th[j], -bd->c_max, bd->c_max);
        th[np - 1] = IMP_CLAMP(th[np - 1], bd->lk_min, bd->lk_max);
}

/* Minimises the reduced cost from th (updated in place); e must hold the evaluation at th
 * with w's arrays matching it on entry, and does so on return. Stopping rule: relative cost decrease < tol on an
 * accepted step, no parameter moving more than STEP_MIN, λ > LAMBDA_MAX, or max_evals. */
static void lm(struct work *w, bool cxy, const struct bounds *bd, double tol, int max_evals,
               double th[MAXP], struct eval *e) {
        int np = cxy ? 2 : 3;
        double cx, cy, k, lambda = LAMBDA_INIT;
        bool stale = false;           /* w's arrays hold a rejected trial, not th */
        double lo[MAXP], hi[MAXP];
        for (int j = 0; j < np - 1; j++) {
                lo[j] = -bd->c_max;
                hi[j] = bd->c_max;
        }
        lo[np - 1] = bd->lk_min;
        hi[np - 1] = bd->lk_max;
        double cost = e->cost + prior_cost(cxy, bd, th);
        for (int evals = 1; evals < max_evals;) {
                double H[MAXP][MAXP], b[MAXP];
                normal_matrix(w, e, cxy, H, b);
                for (int j = 0; j < np - 1; j++) {
                        double m = cxy ? 2.0 * bd->mu : bd->mu;
                        H[j][j] += m;
                        b[j] -= m * (th[j] + 1.0);
                }
                double dmax = 0.0;
                for (int j = 0; j < np; j++)
                        dmax = fmax(dmax, H[j][j]);
                if (!(dmax > 0.0) || !(cost > 0.0))
                        break;                /* the lobe does not affect the fit, or exact */
                bool accepted = false, done = false;
                while (!accepted && !done && evals < max_evals) {
                        double M[MAXP][MAXP], rhs[MAXP], step[MAXP], nt[MAXP], moved = 0.0;
                        memcpy(M, H, sizeof M);
                        memcpy(rhs, b, sizeof rhs);
                        for (int j = 0; j < np; j++)
                                M[j][j] += lambda * fmax(H[j][j], 1e-9 * dmax);
                        /* Projected step: a parameter on a bound whose descent direction
                         * points outwards is held (its row and column removed). */
                        for (int j = 0; j < np; j++)
                                if ((th[j] <= lo[j] && b[j] < 0.0) || (th[j] >= hi[j] && b[j] > 0.0)) {
                                        for (int l = 0; l < np; l++)
                                                M[j][l] = M[l][j] = 0.0;
                                        M[j][j] = 1.0;
                                        rhs[j] = 0.0;
                                }
                        if (!chol_solve(np, M, rhs, step)) {
                                lambda *= 4.0;
                                done = lambda > LAMBDA_MAX;
                                continue;
                        }
                        for (int j = 0; j < np; j++)
                                nt[j] = th[j] + step[j];
                        clamp_theta(cxy, bd, nt);
                        for (int j = 0; j < np; j++)
                                moved = fmax(moved, fabs(nt[j] - th[j]));
                        if (moved < STEP_MIN) {
                                done = true;
                                break;
                        }
                        struct eval ne;
                        theta_to_lobe(cxy, nt, &cx, &cy, &k);
                        evaluate(w, cx, cy, k, &ne);
                        evals++;
                        double ncost = ne.cost + prior_cost(cxy, bd, nt);
                        if (ncost < cost) {
                                double rel = (cost - ncost) / cost;
                                memcpy(th, nt, sizeof(double) * np);
                                *e = ne;
                                cost = ncost;
                                stale = false;
                                lambda = fmax(lambda / 3.0, 1e-9);
                                accepted = true;
                                done = rel < tol;
                        } else {
                                stale = true;
                                lambda *= 4.0;
                                done = lambda > LAMBDA_MAX;
                        }
                }
                if (!accepted || done)
                        break;
        }
        if (stale) {
                theta_to_lobe(cxy, th, &cx, &cy, &k);
                evaluate(w, cx, cy, k, e);
        }
}

/* ---- robust weights -------------------------------------------------------------- */


/* Squared residuals of all samples in white units (V/E), channels pooled, into w->res. */
CLONES static void residuals2(struct work *w, const double rd[3], const double rs[3]) {
        const float a0 = (float) rd[0], a1 = (float) rd[1], a2 = (float) rd[2];
        const float b0 = (float) rs[0], b1 = (float) rs[1], b2 = (float) rs[2];
        const float *restrict G = w->g, *restrict WL = w->wl;
        const float *restrict Y0 = w->y[0], *restrict Y1 = w->y[1], *restrict Y2 = w->y[2];
        float *restrict R = w->res;
#pragma omp simd
        for (int i = 0; i < w->n; i++) {
                float r0 = Y0[i] - a0 - b0 * G[i], r1 = Y1[i] - a1 - b1 * G[i], r2 = Y2[i] - a2 - b2 * G[i];
                R[i] = WL[i] * (r0 * r0 + r1 * r1 + r2 * r2) * (1.0f / 3.0f);
        }
}

/* Σ ω r² and Σ ω over the samples (ω the robust weights), from w->res. */
static void robust_sums(struct work *w, const double rd[3], const double rs[3], double *ss, double *so) {
        residuals2(w, rd, rs);
        double a = 0.0, b = 0.0;
        const float *restrict OM = w->om, *restrict R = w->res;
#pragma omp simd reduction(+ : a, b)
        for (int i = 0; i < w->n; i++) {
                a += (double) OM[i] * R[i];
                b += OM[i];
        }
        *ss = a;
        *so = b;
}

/* The k-th smallest of v[0..n) (0-based; v unchanged): the element whose rank — the
 * count of smaller elements, ties broken by position — is k. Branch-free counting
 * (n² compares) beats a quickselect's mispredicted branches at the sample counts of a
 * texel. The ranks of RANK_LANES candidates are counted at once, one vector lane each,
 * against every element in turn: no horizontal sum per candidate. */
#define RANK_LANES 16
CLONES static float kth_by_rank(const float *restrict v, int n, int k) {
        for (int i0 = 0; i0 < n; i0 += RANK_LANES) {
                float x[RANK_LANES];
                int rank[RANK_LANES] = { 0 };
                for (int l = 0; l < RANK_LANES; l++)
                        x[l] = v[IMP_MIN(i0 + l, n - 1)];
                for (int j = 0; j < n; j++) {
                        const float vj = v[j];
                        const int ji = j - i0;
#pragma omp simd
                        for (int l = 0; l < RANK_LANES; l++)    /* smaller, or equal and before */
                                rank[l] += (vj < x[l]) | ((vj == x[l]) & (ji < l));
                }
                for (int l = 0; l < RANK_LANES && i0 + l < n; l++)
                        if (rank[l] == k)
                                return x[l];
        }
        return v[0];            /* not reached: the ranks are a permutation of 0..n−1 */
}

float imp_btf_kth_smallest(const float *v, int n, int k) {
        if (!v || n < 1 || k < 0 || k >= n)
                return NAN;
        return kth_by_rank(v, n, k);
}

/* ω = min(1, thr/|r|) from the squared residuals, W = l_z² ω (both computed in every
 * lane, the select after: a conditional division would keep the loop scalar). */
CLONES static void huber_weights(struct work *w, float thr, float thr2) {
        const float *restrict R = w->res, *restrict WL = w->wl;
        float *restrict OM = w->om, *restrict WW = w->W;
#pragma omp simd
        for (int i = 0; i < w->n; i++) {
                float r2 = R[i], q = thr / sqrtf(r2 > FLT_MIN ? r2 : FLT_MIN);
                float om = r2 > thr2 ? q : 1.0f;
                OM[i] = om;
                WW[i] = WL[i] * om;
        }
}

/* Huber weights with σ = 1.4826 · MAD (floored): W = l_z² · min(1, δσ/|r|). Works on
 * squared residuals (the median commutes with the square root). */
static void huber_reweight(struct work *w, const double rd[3], const double rs[3],
                           const struct imp_btf_fit_params *p) {
        residuals2(w, rd, rs);
        double med = sqrt(kth_by_rank(w->res, w->n, w->n / 2));
        double sigma = fmax(1.4826 * med, p->sigma_floor), thr = p->huber_delta * sigma, thr2 = thr * thr;
        huber_weights(w, (float) thr, (float) thr2);
        set_weights(w);
}

/* ---- the texel -------------------------------------------------------------------- */

static inline int finite_bits(float x) {
        return (float_to_bits(x) & 0x7f800000u) != 0x7f800000u;
}

/* A sample as SAMPLE_FLOATS consecutive floats (struct imp_btf_sample: v, l, e_cos,
 * value), so that the loops below read it with a constant stride and vectorise. */
#define SAMPLE_FLOATS 10
_Static_assert(sizeof(struct imp_btf_sample) == SAMPLE_FLOATS * sizeof(float) &&
              offsetof(struct imp_btf_sample, l) == 3 * sizeof(float) &&
              offsetof(struct imp_btf_sample, e_cos) == 6 * sizeof(float) &&
              offsetof(struct imp_btf_sample, value) == 7 * sizeof(float), "imp_btf_sample is 10 packed floats");

/* Whether a sample can enter the fit (finite, lit from above with E cos θl > 0). */
static inline int sample_ok(const float *q) {
        int ok = isgreater(q[6], 0.0f) & isgreater(q[5], 0.0f);
        for (int c = 0; c < SAMPLE_FLOATS; c++)
                ok &= finite_bits(q[c]);
        return ok;
}

static inline void load_sample(struct work *w, int m, const float *q) {
        w->ax[m] = q[0] * q[3];
        w->ay[m] = q[1] * q[4];
        w->az[m] = q[2] * q[5];
        w->wl[m] = q[5] * q[5];
        w->om[m] = 1.0f;
        w->W[m] = w->wl[m];
        w->y[0][m] = q[7] / q[6];
        w->y[1][m] = q[8] / q[6];
        w->y[2][m] = q[9] / q[6];
}

/* The usable samples into w's arrays (structure of arrays). The common case, every
 * sample usable: the fields are first copied apart into w's arrays (d, g, ld ← v;
 * res, om, wl ← l; W ← E cos θl; y ← V), then checked and combined in vector loops. */
CLONES static int load_work(struct work *w, const struct imp_btf_sample *s, int n) {
        const float *f = n > 0 ? s[0].v : NULL;
        float *restrict v0 = w->d, *restrict v1 = w->g, *restrict v2 = w->ld;
        float *restrict l0 = w->res, *restrict l1 = w->om, *restrict l2 = w->wl, *restrict ec = w->W;
        float *restrict y0 = w->y[0], *restrict y1 = w->y[1], *restrict y2 = w->y[2];
        float *restrict ax = w->ax, *restrict ay = w->ay, *restrict az = w->az;
        for (int i = 0; i < n; i++) {
                const float *q = f + SAMPLE_FLOATS * i;
                v0[i] = q[0], v1[i] = q[1], v2[i] = q[2];
                l0[i] = q[3], l1[i] = q[4], l2[i] = q[5];
                ec[i] = q[6];
                y0[i] = q[7], y1[i] = q[8], y2[i] = q[9];
        }
        int bad = 0, m = 0;
#pragma omp simd reduction(+ : bad)
        for (int i = 0; i < n; i++)
                bad += !(isgreater(ec[i], 0.0f) & isgreater(l2[i], 0.0f) & finite_bits(ec[i]) &
                         finite_bits(v0[i]) & finite_bits(v1[i]) & finite_bits(v2[i]) & finite_bits(l0[i]) &
                         finite_bits(l1[i]) & finite_bits(l2[i]) & finite_bits(y0[i]) & finite_bits(y1[i]) &
                         finite_bits(y2[i]));
        if (!bad) {
#pragma omp simd
                for (int i = 0; i < n; i++) {
                        float e = ec[i], lz = l2[i];
                        ax[i] = v0[i] * l0[i];
                        ay[i] = v1[i] * l1[i];
                        az[i] = v2[i] * lz;
                        y0[i] = y0[i] / e;
                        y1[i] = y1[i] / e;
                        y2[i] = y2[i] / e;
                        l2[i] = lz * lz;            /* wl */
                        ec[i] = lz * lz;            /* W */
                        l1[i] = 1.0f;               /* om */
                }
                m = n;
        } else {
                for (int i = 0; i < n; i++)
                        if (sample_ok(f + SAMPLE_FLOATS * i))
                                load_sample(w, m++, f + SAMPLE_FLOATS * i);
        }
        /* Padding: outside the lobe (d = 0), no weight, no value. */
        int np = (m + VEC_PAD - 1) / VEC_PAD * VEC_PAD;
        for (int i = m; i < np; i++) {
                ax[i] = ay[i] = az[i] = 0.0f;
                w->wl[i] = w->om[i] = w->W[i] = 0.0f;
                y0[i] = y1[i] = y2[i] = 0.0f;
        }
        w->n = m;
        w->np = np;
        set_weights(w);
        return m;
}

static void set_default_lobe(const struct imp_btf_fit_params *p, struct imp_btf_texel *t) {
        t->cx = -1.0f;
        t->cy = -1.0f;
        t->cz = 1.0f;
        t->k = (float) p->k_default;
        for (int c = 0; c < 3; c++)
                t->rho_s[c] = 0.0f;
        t->cond = 0.0f;
}

/* ρd only (ρs = 0): Huber-reweighted weighted mean per channel. */
static void fit_matte(struct work *w, const struct imp_btf_fit_params *p, struct imp_btf_texel *t) {
        double rd[3] = { 0 }, rs[3] = { 0 };
        for (int i = 0; i < w->np; i++)
                w->g[i] = 0.0f;
        for (int pass = 0; pass <= p->robust_passes && w->n > 0; pass++) {
                if (pass > 0)
                        huber_reweight(w, rd, rs, p);
                for (int c = 0; c < 3; c++)
                        rd[c] = w->sw > 0.0 ? fmax(w->sy[c] / w->sw, 0.0) : 0.0;
        }
        double ss, so;
        robust_sums(w, rd, rs, &ss, &so);
        for (int c = 0; c < 3; c++)
                t->rho_d[c] = (float) rd[c];
        set_default_lobe(p, t);
        t->rms = so > 0.0 ? (float) sqrt(ss / so) : 0.0f;
}

/* Whether Cx and Cy can be told apart: the information about the weaker combination of
 * (Cx, Cy), relative to the information the lobe carries about Cz, at the lobe whose
 * d and g are in w. */
static bool cx_cy_separable(const struct work *w, double tau) {
        double gxx = 0, gxy = 0, gyy = 0, gz = 0;
        for (int i = 0; i < w->n; i++) {
                if (!(w->g[i] > 0.0f))
                        continue;
                double q = w->g[i] / w->d[i], Wq2 = w->W[i] * q * q;
                gxx += Wq2 * w->ax[i] * w->ax[i];
                gxy += Wq2 * w->ax[i] * w->ay[i];
                gyy += Wq2 * w->ay[i] * w->ay[i];
                gz += Wq2 * w->az[i] * w->az[i];
        }
        double tr = gxx + gyy, disc = sqrt(fmax(0.25 * (gxx - gyy) * (gxx - gyy) + gxy * gxy, 0.0));
        double lmin = 0.5 * tr - disc;
        return gz > 0.0 && lmin >= tau * gz;
}

/* Multi-start: the mirror lobe C = (-1, -1, 1) over the grid of k; the best evaluation
 * into *best with w's arrays matching it (LM starts there without evaluating it again).
 * Each k is exp(log k), as LM computes it; returns that log k. */
static double multi_start(struct work *w, const struct imp_btf_fit_params *p, struct eval *best) {
        struct eval e;
        double lk_best = 0.0;
        float g_best[IMP_BTF_MAX_SAMPLES];
        const int last = (int) ARRAY_SIZE(k_grid) - 1;
        int i_best = last;                           /* w->g is the best's g when the last */
        double ldmax = lobe_logs(w, -1.0, -1.0);     /* the same lobe shape for every k */
        *best = (struct eval) { .cost = HUGE_VAL };
        for (int i = 0; i <= last; i++) {
                double lk = log(IMP_CLAMP(k_grid[i], p->k_min, p->k_max));
                lobe_solve(w, exp(lk), ldmax, &e);
                e.cx = e.cy = -1.0;
                if (e.cost < best->cost) {
                        *best = e;
                        lk_best = lk;
                        i_best = i;
                        if (i < last)
                                memcpy(g_best, w->g, (size_t) w->np * sizeof *g_best);
                }
        }
        if (i_best < last)
                memcpy(w->g, g_best, (size_t) w->np * sizeof *g_best);
        return lk_best;
}

static int fit_texel(const struct imp_btf_sample *samples, int n, const struct imp_btf_fit_params *p,
                     struct imp_btf_texel *ret) {
        if (n < 0 || (n > 0 && !samples) || !p || !ret || !(p->k_min > 0.0) || !(p->k_max >= p->k_min) ||
            !(p->c_max > 0.0) || p->min_samples < 1 || !(p->c_prior_sigma > 0.0) || !(p->sigma_floor > 0.0) ||
            !(p->peak_seen_min > 0.0 && p->peak_seen_min <= 1.0))
                return -EINVAL;
        if (n > IMP_BTF_MAX_SAMPLES)
                return -E2BIG;

        struct work w;
        struct imp_btf_texel t = { 0 };
        int m = load_work(&w, samples, n);
        t.n_samples = (uint16_t) m;
        if (m < p->min_samples) {
                fit_matte(&w, p, &t);
                t.flags = IMP_BTF_FEW_SAMPLES;
                *ret = t;
                return 0;
        }

        /* Multi-start: the mirror lobe C = (-1, -1, 1) over a grid of k; LM from the best. */
        struct bounds bd = { p->c_max, log(p->k_min), log(p->k_max),
                             p->sigma_floor * p->sigma_floor / (p->c_prior_sigma * p->c_prior_sigma) };
        struct eval e, best;
        double lk_best = multi_start(&w, p, &best);
        double spec = fmax(best.rs[0], fmax(best.rs[1], best.rs[2]));
        if (!(best.ldmax > -HUGE_VAL) || spec < p->matte_threshold) {
                fit_matte(&w, p, &t);
                t.flags = IMP_BTF_MATTE;
                *ret = t;
                return 0;
        }
        e = best;
        bool cxy = !cx_cy_separable(&w, p->cxy_tau);
        double th[MAXP];
        if (cxy) {
                th[0] = -1.0;
                th[1] = lk_best;
        } else {
                th[0] = -1.0;
                th[1] = -1.0;
                th[2] = lk_best;
        }
        lm(&w, cxy, &bd, p->tol, p->max_iter, th, &e);
        for (int pass = 0; pass < p->robust_passes; pass++) {
                huber_reweight(&w, e.rd, e.rs, p);
                lobe_resolve(&w, &e);            /* same lobe, new weights */
                lm(&w, cxy, &bd, p->tol, IMP_MAX(p->max_iter / 3, 2), th, &e);
        }

        spec = fmax(e.rs[0], fmax(e.rs[1], e.rs[2]));
        if (!(e.ldmax > -HUGE_VAL) || spec < p->matte_threshold) {
                fit_matte(&w, p, &t);
                t.flags = IMP_BTF_MATTE;
                *ret = t;
                return 0;
        }

        /* Bound the extrapolation from the brightest seen lobe value to the lobe's peak:
         * lower k (same C) until peak_seen ≥ p->peak_seen_min, and re-solve ρ. */
        double cx, cy, k;
        theta_to_lobe(cxy, th, &cx, &cy, &k);
        double mx = fmax(1.0, fmax(fabs(cx), fabs(cy)));
        double peak_seen = exp(k * (e.ldmax - log(mx)));   /* brightest seen / peak, ≤ 1 */
        bool extrapolated = peak_seen < PEAK_SEEN_FLAG;
        if (peak_seen < p->peak_seen_min) {
                k = fmax(log(p->peak_seen_min) / (e.ldmax - log(mx)), p->k_min);
                th[cxy ? 1 : 2] = log(k);
                evaluate(&w, cx, cy, k, &e);
                peak_seen = exp(k * (e.ldmax - log(mx)));
        }

        /* Uncertainty of log k and conditioning, from the projected normal matrix with
         * the prior (the curvature of what LM minimised). */
        double H[MAXP][MAXP], b[MAXP], Hi[MAXP][MAXP], unit[MAXP] = { 0 }, col[MAXP];
        int np = normal_matrix(&w, &e, cxy, H, b);
        for (int j = 0; j < np - 1; j++)
                H[j][j] += cxy ? 2.0 * bd.mu : bd.mu;
        double so, ss;
        robust_sums(&w, e.rd, e.rs, &ss, &so);
        double dof = fmax(3.0 * so - np - 6.0, 1.0);
        double sigma2 = fmax(e.cost / dof, p->sigma_floor * p->sigma_floor);
        double var_lk = HUGE_VAL;
        memcpy(Hi, H, sizeof Hi);
        unit[np - 1] = 1.0;
        if (chol_solve(np, Hi, unit, col))
                var_lk = col[np - 1];
        double se_lk = var_lk < HUGE_VAL ? sqrt(sigma2 * var_lk) : HUGE_VAL;
        double lk = th[np - 1];

        /* Report the lobe with max |C_i| = 1: ρs becomes the peak specular albedo. */
        for (int c = 0; c < 3; c++) {
                t.rho_d[c] = (float) e.rd[c];
                t.rho_s[c] = (float) fmin(e.rs[c] / fmax(peak_seen, 1e-300), RHO_S_MAX);
        }
        t.cx = (float) (cx / mx);
        t.cy = (float) (cy / mx);
        t.cz = (float) (1.0 / mx);
        t.k = (float) k;
        t.rms = so > 0.0 ? (float) sqrt(ss / so) : 0.0f;
        t.cond = (float) equilibrated_cond(np, H);
        t.flags = cxy ? IMP_BTF_CX_EQ_CY : 0;
        if (lk <= bd.lk_min + 1e-3 || lk >= bd.lk_max - 1e-3)
                t.flags |= IMP_BTF_K_BOUND;
        if (!(se_lk <= p->k_rel_uncertain) || extrapolated)
                t.flags |= IMP_BTF_LOBE_UNCERTAIN;
        *ret = t;
        return 0;
}

uint16_t imp_btf_texel_flags(uint16_t f) {
        if (f & IMP_BTF_MASKED)
                return 0;
        return (uint16_t) ((f & IMP_BTF_FEW_SAMPLES ? IMP_TEXEL_FEW_SAMPLES : 0) |
                           (f & IMP_BTF_SATURATED ? IMP_TEXEL_SATURATED : 0) |
                           (f & IMP_BTF_FIT_FAILED ? IMP_TEXEL_FIT_FAILED : 0));
}

/* Whether a fitted texel is a physical one-lobe Lafortune BRDF (btf.h IMP_BTF_FIT_FAILED);
 * a non-finite value is replaced by 0 so that every output stays finite. */
static bool physical(struct imp_btf_texel *t, const struct imp_btf_fit_params *p) {
        bool ok = true;
        float *v[] = { &t->rho_d[0], &t->rho_d[1], &t->rho_d[2], &t->rho_s[0], &t->rho_s[1], &t->rho_s[2],
                       &t->cx, &t->cy, &t->cz, &t->k, &t->rms, &t->cond };
        for (size_t i = 0; i < ARRAY_SIZE(v); i++)
                if (!isfinite(*v[i])) {
                        *v[i] = 0.0f;
                        ok = false;
                }
        for (int c = 0; c < 3; c++)
                ok = ok && t->rho_d[c] >= 0.0f && t->rho_d[c] <= 1.0f && t->rho_s[c] >= 0.0f &&
                     t->rho_s[c] < (float) RHO_S_MAX;
        float cmax = fmaxf(fabsf(t->cx), fmaxf(fabsf(t->cy), fabsf(t->cz)));
        return ok && t->k > 0.0f && t->k >= (float) p->k_min * (1 - 1e-6f) && fabsf(cmax - 1.0f) <= 1e-4f;
}

int imp_btf_fit_texel(const struct imp_btf_sample *samples, int n, const struct imp_btf_fit_params *p,
                      struct imp_btf_texel *ret) {
        int r = fit_texel(samples, n, p, ret);
        if (r < 0)
                return r;
        if (!physical(ret, p))
                ret->flags |= IMP_BTF_FIT_FAILED;
        return 0;
}

/* ---- hole filling ----------------------------------------------------------------- */

static bool needs_fill(uint16_t f) {
        return !(f & IMP_BTF_MASKED) && (f & (IMP_BTF_FEW_SAMPLES | IMP_BTF_HIDDEN));
}

int imp_btf_fill(struct imp_btf_texel *texels, int width, int height) {
        if (!texels || width <= 0 || height <= 0)
                return -EINVAL;
        size_t n = (size_t) width * height;
        /* gen: 0 = valid source, -1 = still to fill, g > 0 = filled in pass g. */
        _cleanup_free_ int *gen = malloc(n * sizeof *gen);
        _cleanup_free_ int *todo = malloc(n * sizeof *todo);
        if (!gen || !todo)
                return -ENOMEM;
        size_t n_todo = 0;
        for (size_t i = 0; i < n; i++) {
                bool f = needs_fill(texels[i].flags);
                gen[i] = (texels[i].flags & IMP_BTF_MASKED) ? -2 : f ? -1 : 0;
                if (f)
                        todo[n_todo++] = (int) i;
        }
        int filled = 0;
        for (int pass = 1; n_todo > 0; pass++) {
                size_t keep = 0;
                int before = filled;
                for (size_t q = 0; q < n_todo; q++) {
                        int i = todo[q], u = i % width, v = i / width, cnt = 0, lobes = 0;
                        double acc[10] = { 0 }, lk = 0.0, lobe[3] = { 0 };
                        for (int dv = -1; dv <= 1; dv++)
                                for (int du = -1; du <= 1; du++) {
                                        int uu = u + du, vv = v + dv;
                                        if ((!du && !dv) || uu < 0 || vv < 0 || uu >= width || vv >= height)
                                                continue;
                                        int j = vv * width + uu;
                                        if (gen[j] < 0 || gen[j] == pass)
                                                continue;
                                        const struct imp_btf_texel *s = &texels[j];
                                        for (int c = 0; c < 3; c++) {
                                                acc[c] += s->rho_d[c];
                                                acc[3 + c] += s->rho_s[c];
                                        }
                                        acc[6] += s->rms;
                                        cnt++;
                                        if (!(s->flags & IMP_BTF_MATTE)) {
                                                lobe[0] += s->cx;
                                                lobe[1] += s->cy;
                                                lobe[2] += s->cz;
                                                lk += log(fmax(s->k, 1e-6));
                                                lobes++;
                                        }
                                }
                        if (!cnt) {
                                todo[keep++] = i;
                                continue;
                        }
                        struct imp_btf_texel *t = &texels[i];
                        for (int c = 0; c < 3; c++) {
                                t->rho_d[c] = (float) (acc[c] / cnt);
                                t->rho_s[c] = (float) (acc[3 + c] / cnt);
                        }
                        t->rms = (float) (acc[6] / cnt);
                        t->cond = 0.0f;
                        t->flags |= IMP_BTF_FILLED;
                        if (lobes) {
                                t->cx = (float) (lobe[0] / lobes);
                                t->cy = (float) (lobe[1] / lobes);
                                t->cz = (float) (lobe[2] / lobes);
                                t->k = (float) exp(lk / lobes);
                                t->flags &= (uint16_t) ~IMP_BTF_MATTE;
                        } else {
                                t->flags |= IMP_BTF_MATTE;
                        }
                        gen[i] = pass;
                        filled++;
                }
                n_todo = keep;
                if (filled == before)
                        break;
        }
        return filled;
}

/* ---- the tiled driver ------------------------------------------------------------- */

/* The samples s[0..n) of a texel, extracted in the frame of unit normal n0, in the frame of
 * unit normal n1 (both canvas frame, imp_local_frame()): l turned, v (the camera's, the
 * same for every sample) turned once, e_cos = E·cos θl with the new cos θl; a sample whose
 * new l[2] < min_cos_l or e_cos < min_e_cos goes, as the extractor drops it. In float,
 * as the samples are (the extractor's values in the new frame to float rounding). Returns the
 * samples left (compacted in place); false in *ret_seen when the camera is below the new
 * frame's horizon (the texel is hidden there). */
static int rotate_samples(struct imp_btf_sample *s, int n, const float n0[3], const float n1[3],
                          const struct imp_btf_sample_params *sp, bool *ret_seen) {
        double a[3] = { n0[0], n0[1], n0[2] }, b[3] = { n1[0], n1[1], n1[2] }, ta[3], ba[3], tb[3], bb[3];
        imp_local_frame(a, ta, ba);
        imp_local_frame(b, tb, bb);
        const double *fa[3] = { ta, ba, a }, *fb[3] = { tb, bb, b };
        float M[3][3];   /* local a → local b: M[i][k] = fb[i] · fa[k] */
        for (int i = 0; i < 3; i++)
                for (int k = 0; k < 3; k++)
                        M[i][k] = (float) (fb[i][0] * fa[k][0] + fb[i][1] * fa[k][1] + fb[i][2] * fa[k][2]);
        *ret_seen = true;
        if (n == 0)
                return 0;
        float v[3];
        for (int i = 0; i < 3; i++)
                v[i] = M[i][0] * s[0].v[0] + M[i][1] * s[0].v[1] + M[i][2] * s[0].v[2];
        if (!(v[2] > 0.0f)) {
                *ret_seen = false;
                return 0;
        }
        const float min_cos = (float) sp->min_cos_l, min_ec = (float) sp->min_e_cos;
        int m = 0;
        for (int j = 0; j < n; j++) {
                const float *l = s[j].l;
                float l0 = M[0][0] * l[0] + M[0][1] * l[1] + M[0][2] * l[2];
                float l1 = M[1][0] * l[0] + M[1][1] * l[1] + M[1][2] * l[2];
                float l2 = M[2][0] * l[0] + M[2][1] * l[1] + M[2][2] * l[2];
                float ec = s[j].e_cos / l[2] * l2;
                if (!(l2 >= min_cos) || !(ec >= min_ec))
                        continue;
                struct imp_btf_sample *q = &s[m++];
                q->v[0] = v[0], q->v[1] = v[1], q->v[2] = v[2];
                q->l[0] = l0, q->l[1] = l1, q->l[2] = l2;
                q->e_cos = ec;
                if (q != &s[j])
                        memcpy(q->value, s[j].value, sizeof q->value);
        }
        return m;
}

/* What imp_btf_fit_grid's texels share: the extractor of hf's frames and, with frames
 * estimated in EXTRACT mode, the one of the estimated frames (xf: the same heightfield
 * with normal = frames->normal). */
struct fit_grid {
        const struct imp_btf_heightfield *hf;
        const struct imp_btf_sample_params *sp;
        const struct imp_btf_fit_params *fp;
        const struct imp_btf_extractor *x, *xf;
        struct imp_btf_texel dflt;
};

/* Texel i (u, v) of the grid: its samples (in its estimated frame with fp->frames), the fit
 * into *t. Returns the samples taken; *ret_shadowed those rejected as self-shadowed. */
static int fit_grid_texel(const struct fit_grid *G, const struct imp_btf_band *b, long i, struct imp_btf_sample *smp,
                          struct imp_btf_texel *t, uint16_t *ret_shadowed) {
        const struct imp_btf_frames *fr = G->fp->frames;
        int W = G->hf->width, u = (int) (i % W), v = (int) (i / W);
        uint16_t sf;
        int n = imp_btf_extract_texel_band(G->x, b, u, v, smp, NULL, &sf, ret_shadowed);
        const float *n0 = &G->hf->normal[3 * i];
        float *nf = fr ? &fr->normal[3 * i] : NULL;
        if (nf)
                memcpy(nf, n0, 3 * sizeof *nf);
        bool seen = !(sf & (IMP_BTF_MASKED | IMP_BTF_HIDDEN));
        if (seen && nf && fr->estimate(fr->data, i, smp, n, n0, nf)) {
                if (fr->mode == IMP_BTF_FRAMES_ROTATE)
                        n = rotate_samples(smp, n, n0, nf, G->sp, &seen);
                else
                        n = imp_btf_extract_texel_band(G->xf, b, u, v, smp, NULL, &sf, ret_shadowed);
                if (!seen)
                        sf = IMP_BTF_HIDDEN;
                seen = !(sf & (IMP_BTF_MASKED | IMP_BTF_HIDDEN));
        }
        if (!seen) {
                *t = G->dflt;
                t->flags = sf;
                return n;
        }
        /* Cannot fail: fp checked by the caller, n ≤ IMP_BTF_MAX_SAMPLES. */
        (void) imp_btf_fit_texel(smp, n, G->fp, t);
        t->flags |= sf;
        return n;
}

int imp_btf_fit_grid(const struct imp_btf_heightfield *hf, const struct imp_btf_capture *cap,
                     const struct imp_btf_sample_params *sp, const struct imp_btf_fit_params *fp,
                     int tile_texels, struct imp_btf_texel *ret_texels, struct imp_btf_stats *ret_stats) {
        if (!hf || !cap || !sp || !fp || !ret_texels || tile_texels < 0)
                return -EINVAL;
        const struct imp_btf_frames *fr = fp->frames;
        if (fr && (!fr->estimate || !fr->normal || fr->normal == hf->normal ||
                   (fr->mode != IMP_BTF_FRAMES_EXTRACT && fr->mode != IMP_BTF_FRAMES_ROTATE)))
                return -EINVAL;
        if (cap->n_lights <= 0 || cap->n_lights > IMP_BTF_MAX_SAMPLES)
                return -E2BIG;
        struct imp_btf_stats st = { 0 };
        struct fit_grid G = { .hf = hf, .sp = sp, .fp = fp };
        int r = imp_btf_fit_texel(NULL, 0, fp, &G.dflt);    /* checks fp */
        if (r < 0)
                return r;
        G.dflt = (struct imp_btf_texel) { 0 };
        set_default_lobe(fp, &G.dflt);
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        _cleanup_(imp_btf_extractor_freep) struct imp_btf_extractor *x = NULL, *xf = NULL;
        /* the estimated frames' extractor reads the normals each texel's thread writes
         * before it extracts there */
        struct imp_btf_heightfield hf_frames = *hf;
        hf_frames.normal = fr ? fr->normal : NULL;
        /* with the rays of an earlier extraction reused, few are marched: no horizon for
         * them (docs/processing-speed.md "The fit's horizon") */
        bool reuse = sp->rays && sp->rays_mode == IMP_BTF_RAYS_REUSE;
        if ((r = imp_btf_hf_pyramid_new_horizon(hf, !reuse, &py)) < 0 || (r = imp_btf_extractor_new(hf, cap, sp, py, &x)) < 0 ||
            (fr && fr->mode == IMP_BTF_FRAMES_EXTRACT &&
             (r = imp_btf_extractor_new(&hf_frames, cap, sp, py, &xf)) < 0))
                return r;
        G.x = x;
        G.xf = xf;

        /* One parallel loop per band of texel rows: each thread extracts a texel's samples
         * into its own buffer and fits them at once (no tile buffer, no barrier between the
         * two; chunks of consecutive texels keep the heightfield in cache), the taps read
         * from the band's frames interleaved by light (btf.h, struct imp_btf_band; the
         * estimated frames' extraction reads the same band: its box depends on the heights
         * alone). */
        const int W = hf->width;
        const long nt = (long) W * hf->height, chunk = tile_texels > 0 ? tile_texels : 64;
        long n_samples = 0, n_shadowed = 0, n_done = 0, next_report = nt / 50;
        struct imp_btf_band band = {};
        for (int v0 = 0; v0 < hf->height; v0 += IMP_BTF_BAND_ROWS) {
                int rows = IMP_MIN(IMP_BTF_BAND_ROWS, hf->height - v0);
                const struct imp_btf_band *b = imp_btf_band_load(x, v0, rows, 1, &band) ? &band : NULL;
#pragma omp parallel reduction(+ : n_samples, n_shadowed)
                {
                        struct imp_btf_sample smp[IMP_BTF_MAX_SAMPLES];
#pragma omp for schedule(dynamic, chunk)
                        for (long i = (long) v0 * W; i < (long) (v0 + rows) * W; i++) {
                                if (fp->progress) {   /* reported by the calling thread alone */
                                        long d = __atomic_add_fetch(&n_done, 1, __ATOMIC_RELAXED);
                                        if (IMP_BTF_THREAD_NUM() == 0 && d >= next_report && d < nt) {
                                                next_report = d + nt / 50;
                                                fp->progress(fp->progress_data, d, nt);
                                        }
                                }
                                uint16_t nsh;
                                n_samples += fit_grid_texel(&G, b, i, smp, &ret_texels[i], &nsh);
                                n_shadowed += nsh;
                        }
                }
        }
        imp_btf_band_done(&band);
        st.n_samples = n_samples;
        st.n_shadowed = n_shadowed;
        if (fp->progress)
                fp->progress(fp->progress_data, nt, nt);

        r = imp_btf_fill(ret_texels, hf->width, hf->height);
        if (r < 0)
                return r;
        for (size_t i = 0; i < (size_t) hf->width * hf->height; i++) {
                uint16_t f = ret_texels[i].flags;
                st.n_masked += !!(f & IMP_BTF_MASKED);
                st.n_hidden += !!(f & IMP_BTF_HIDDEN);
                st.n_few += !!(f & IMP_BTF_FEW_SAMPLES);
                st.n_filled += !!(f & IMP_BTF_FILLED);
                st.n_matte += !!(f & IMP_BTF_MATTE);
                st.n_cx_eq_cy += !!(f & IMP_BTF_CX_EQ_CY);
                st.n_fitted += !(f & (IMP_BTF_MASKED | IMP_BTF_HIDDEN | IMP_BTF_FEW_SAMPLES));
        }
        if (ret_stats)
                *ret_stats = st;
        return 0;
}
