/* Joint refinement of dome light positions and mirror centres from shared highlights: a
 * small bundle adjustment (Triggs et al., "Bundle Adjustment — A Modern Synthesis", 2000:
 * §4 Gauss–Newton/LM on the normal equations, §6 the Schur complement used here for the
 * conditioning check) whose "cameras" are the mirrors. docs/calibration-lights.md. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "calib-lights-joint.h"
#include "macro.h"
#include "numerics.h"

#define HELD_Z_SIGMA_MM 0.001
#define OUTLIER_K 5.0
#define MAX_ITER 50
#define MAX_PASSES 4
#define LIGHT_COND_MAX 1000.0
#define LIGHT_PRIOR_SIGMA_MM 1000.0
#define COND_DATA_MAX 1e8
#define COND_MAX 1e10                 /* with the priors: should never be reached */
#define COND_CAP 1e30
#define MIN_CENTRE_SIGMA_MM 1e-5      /* a prior never stiffer than 10 nm */
#define RAYLEIGH_MEDIAN 1.1774        /* median of |r| for a 2D unit normal: √(2 ln 2) */
#define PX_STEP 0.25                  /* ∂(camera ray)/∂px by central differences of this, px */
#define DIR_STEP 1e-3                 /* ∂d/∂px through the ray: pixel step, px */
#define X_STEP_MM 1e-3                /* numerical Jacobian steps */
#define C_STEP_MM 1e-5
#define LM_LAMBDA0 1e-4
#define LM_LAMBDA_MAX 1e10
#define COST_RTOL 1e-12
#define STEP_TOL_MM 1e-9

/* Per highlight, what does not depend on the parameters: the camera ray through the
 * centroid and its derivative with respect to the pixel. */
struct pre {
        double O[3], u[3], du[2][3];
        double G[2][3];               /* (GᵀG)⁻¹Gᵀ, G = ∂d/∂px at the current centre */
        bool ok;                      /* the ray meets the mirror (at the current centre) */
};

/* G⁺ = (GᵀG)⁻¹Gᵀ of G = ∂d/∂px at centre C: maps a small change of the reflected direction
 * to the pixel shift that would cause it. */
static bool pixel_inverse(struct pre *p, const double C[3], double r) {
        double G[2][3];
        for (int a = 0; a < 2; a++) {
                double dd[2][3];
                for (int s = 0; s < 2; s++) {
                        double h = s ? -DIR_STEP : DIR_STEP, u[3], P[3];
                        for (int k = 0; k < 3; k++)
                                u[k] = p->u[k] + h * p->du[a][k];
                        double l = imp_norm3(u);
                        for (int k = 0; k < 3; k++)
                                u[k] /= l;
                        if (!imp_lights_reflect_ray(p->O, u, C, r, P, dd[s]))
                                return false;
                }
                for (int k = 0; k < 3; k++)
                        G[a][k] = (dd[0][k] - dd[1][k]) / (2 * DIR_STEP);
        }
        double a = imp_dot3(G[0], G[0]), b = imp_dot3(G[0], G[1]), c = imp_dot3(G[1], G[1]), det = a * c - b * b;
        if (!(det > 0))
                return false;
        for (int k = 0; k < 3; k++) {
                p->G[0][k] = (c * G[0][k] - b * G[1][k]) / det;
                p->G[1][k] = (a * G[1][k] - b * G[0][k]) / det;
        }
        return true;
}

/* The whitened residual of a highlight (pixel shift / σ_px) for light X, centre C.
 * ret_dist: the distance of X from the reflected ray (may be NULL). */
static bool residual(const struct pre *p, const struct imp_joint_obs *o, const double X[3], const double C[3],
                     double r, double res[2], double *ret_dist, bool *ret_behind) {
        double P[3], d[3];
        if (!imp_lights_reflect_ray(p->O, p->u, C, r, P, d))
                return false;
        double v[3] = { X[0] - P[0], X[1] - P[1], X[2] - P[2] }, lv = imp_norm3(v), s = imp_dot3(v, d), e[3];
        if (!(lv > 0))
                return false;
        for (int k = 0; k < 3; k++)
                e[k] = (v[k] - s * d[k]) / lv;
        for (int a = 0; a < 2; a++)
                res[a] = imp_dot3(p->G[a], e) / o->sigma_px;
        if (ret_dist)
                *ret_dist = imp_norm3(e) * lv;
        if (ret_behind)
                *ret_behind = s < 0;
        return true;
}

/* ---- dense symmetric helpers ---- */

static bool inv3(const double A[9], double ret[9]) {
        double a = A[0], b = A[1], c = A[2], d = A[3], e = A[4], f = A[5], g = A[6], h = A[7], i = A[8];
        double det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
        if (!(fabs(det) > 0) || !isfinite(det))
                return false;
        double r[9] = { (e * i - f * h), (c * h - b * i), (b * f - c * e), (f * g - d * i), (a * i - c * g),
                        (c * d - a * f), (d * h - e * g), (b * g - a * h), (a * e - b * d) };
        for (int k = 0; k < 9; k++)
                ret[k] = r[k] / det;
        return true;
}

/* Condition number of the Jacobi-scaled (unit diagonal) symmetric n×n S (destroyed). */
static double scaled_cond(int n, double *S, double *work_l) {
        for (int i = 0; i < n; i++)
                if (!(S[i * n + i] > 0))
                        return COND_CAP;
        for (int i = 0; i < n; i++)
                for (int j = 0; j < n; j++)
                        if (i != j)
                                S[i * n + j] /= sqrt(S[i * n + i] * S[j * n + j]);
        for (int i = 0; i < n; i++)
                S[i * n + i] = 1;
        imp_eigen_sym(n, S, work_l, NULL);
        return work_l[0] > work_l[n - 1] / COND_CAP ? work_l[n - 1] / work_l[0] : COND_CAP;
}

/* ---- the problem ---- */

struct problem {
        int L, M, n_obs, np;          /* lights, mirrors, observations, parameters (3L + 3M) */
        const struct imp_joint_mirror *mir;
        const struct imp_joint_obs *obs;
        struct pre *pre;
        bool *out;                    /* outlier (or missed) */
        double *X0, *C0;              /* starts (priors) */
        double *Cinfo;                /* per mirror Σ⁻¹ (9) */
        double light_info;            /* 1/σ_p² */
        double *N, *g, *A, *theta, *trial, *step, *cov;
};

static double *light_at(double *theta, int l) { return theta + 3 * l; }
static double *centre_at(const struct problem *pb, double *theta, int m) { return theta + 3 * pb->L + 3 * m; }

/* Recomputes G⁺ of every highlight at the centres of theta; a ray that now misses is an
 * outlier. */
static void update_pixel_inverse(struct problem *pb, double *theta) {
        for (int i = 0; i < pb->n_obs; i++) {
                const struct imp_joint_obs *o = &pb->obs[i];
                pb->pre[i].ok = pixel_inverse(&pb->pre[i], centre_at(pb, theta, o->mirror), pb->mir[o->mirror].sphere.radius_mm);
        }
}

/* Cost at theta: data (inliers) + priors; ret_chi2 the data part. false when an inlier's
 * ray misses its mirror. */
static bool cost(const struct problem *pb, double *theta, double *ret_cost, double *ret_chi2) {
        double chi2 = 0, prior = 0;
        for (int i = 0; i < pb->n_obs; i++) {
                const struct imp_joint_obs *o = &pb->obs[i];
                if (pb->out[i])
                        continue;
                double r[2];
                if (!residual(&pb->pre[i], o, light_at(theta, o->light), centre_at(pb, theta, o->mirror),
                              pb->mir[o->mirror].sphere.radius_mm, r, NULL, NULL))
                        return false;
                chi2 += r[0] * r[0] + r[1] * r[1];
        }
        for (int m = 0; m < pb->M; m++) {
                const double *C = centre_at(pb, theta, m), *I = pb->Cinfo + 9 * m;
                double e[3] = { C[0] - pb->C0[3 * m], C[1] - pb->C0[3 * m + 1], C[2] - pb->C0[3 * m + 2] };
                for (int a = 0; a < 3; a++)
                        for (int b = 0; b < 3; b++)
                                prior += e[a] * I[a * 3 + b] * e[b];
        }
        for (int l = 0; l < pb->L; l++) {
                const double *X = light_at(theta, l);
                for (int k = 0; k < 3; k++)
                        prior += (X[k] - pb->X0[3 * l + k]) * (X[k] - pb->X0[3 * l + k]) * pb->light_info;
        }
        *ret_cost = chi2 + prior;
        if (ret_chi2)
                *ret_chi2 = chi2;
        return true;
}

/* Normal equations at theta: N = JᵀJ (+ priors when `priors`), g = Jᵀr (+ priors). Central
 * differences, one highlight at a time: its residual depends on one light and one centre. */
static void normal_equations(const struct problem *pb, double *theta, bool priors) {
        int np = pb->np;
        memset(pb->N, 0, sizeof *pb->N * (size_t) np * np);
        memset(pb->g, 0, sizeof *pb->g * (size_t) np);
        for (int i = 0; i < pb->n_obs; i++) {
                const struct imp_joint_obs *o = &pb->obs[i];
                if (pb->out[i])
                        continue;
                double *X = light_at(theta, o->light), *C = centre_at(pb, theta, o->mirror), r = pb->mir[o->mirror].sphere.radius_mm;
                double res[2], J[2][6];
                int idx[6];
                if (!residual(&pb->pre[i], o, X, C, r, res, NULL, NULL))
                        continue;
                for (int j = 0; j < 6; j++) {
                        double *p = j < 3 ? &X[j] : &C[j - 3], h = j < 3 ? X_STEP_MM : C_STEP_MM, keep = *p, rp[2], rm[2];
                        idx[j] = j < 3 ? 3 * o->light + j : 3 * pb->L + 3 * o->mirror + j - 3;
                        *p = keep + h;
                        bool okp = residual(&pb->pre[i], o, X, C, r, rp, NULL, NULL);
                        *p = keep - h;
                        bool okm = residual(&pb->pre[i], o, X, C, r, rm, NULL, NULL);
                        *p = keep;
                        for (int a = 0; a < 2; a++)
                                J[a][j] = okp && okm ? (rp[a] - rm[a]) / (2 * h) : 0;
                }
                for (int j = 0; j < 6; j++) {
                        pb->g[idx[j]] += J[0][j] * res[0] + J[1][j] * res[1];
                        for (int k = 0; k < 6; k++)
                                pb->N[(size_t) idx[j] * np + idx[k]] += J[0][j] * J[0][k] + J[1][j] * J[1][k];
                }
        }
        if (!priors)
                return;
        for (int l = 0; l < pb->L; l++)
                for (int k = 0; k < 3; k++) {
                        int q = 3 * l + k;
                        pb->N[(size_t) q * np + q] += pb->light_info;
                        pb->g[q] += pb->light_info * (theta[q] - pb->X0[q]);
                }
        for (int m = 0; m < pb->M; m++) {
                const double *I = pb->Cinfo + 9 * m;
                int q0 = 3 * pb->L + 3 * m;
                for (int a = 0; a < 3; a++)
                        for (int b = 0; b < 3; b++) {
                                pb->N[(size_t) (q0 + a) * np + q0 + b] += I[a * 3 + b];
                                pb->g[q0 + a] += I[a * 3 + b] * (theta[q0 + b] - pb->C0[3 * m + b]);
                        }
        }
}

/* Levenberg–Marquardt from pb->theta (updated); returns the iterations, sets *ret_conv. */
static int solve(struct problem *pb, int max_iter, bool *ret_conv) {
        int np = pb->np, it;
        double lambda = LM_LAMBDA0, f;
        *ret_conv = false;
        update_pixel_inverse(pb, pb->theta);
        if (!cost(pb, pb->theta, &f, NULL))
                return 0;
        for (it = 0; it < max_iter; it++) {
                normal_equations(pb, pb->theta, true);
                bool accepted = false;
                while (!accepted && lambda <= LM_LAMBDA_MAX) {
                        memcpy(pb->A, pb->N, sizeof *pb->A * (size_t) np * np);
                        for (int q = 0; q < np; q++) {
                                pb->A[(size_t) q * np + q] *= 1 + lambda;
                                pb->step[q] = -pb->g[q];
                        }
                        double fn;
                        if (!imp_cholesky_factor(np, pb->A)) {
                                lambda *= 10;
                                continue;
                        }
                        imp_cholesky_solve(np, pb->A, pb->step);
                        for (int q = 0; q < np; q++)
                                pb->trial[q] = pb->theta[q] + pb->step[q];
                        if (cost(pb, pb->trial, &fn, NULL) && fn <= f) {
                                double smax = 0;
                                for (int q = 0; q < np; q++)
                                        smax = IMP_MAX(smax, fabs(pb->step[q]));
                                memcpy(pb->theta, pb->trial, sizeof *pb->theta * (size_t) np);
                                lambda = IMP_MAX(lambda / 10, 1e-12);
                                accepted = true;
                                bool done = f - fn <= COST_RTOL * f || smax < STEP_TOL_MM;
                                f = fn;
                                update_pixel_inverse(pb, pb->theta);
                                cost(pb, pb->theta, &f, NULL);   /* G⁺ moved a little */
                                if (done) {
                                        *ret_conv = true;
                                        return it + 1;
                                }
                        } else
                                lambda *= 10;
                }
                if (!accepted) {   /* no descent at any damping: at the minimum to rounding */
                        *ret_conv = true;
                        return it + 1;
                }
        }
        return it;
}

/* |r| of every highlight at theta (misses: INFINITY), into res. */
static void all_residuals(struct problem *pb, double *theta, double *res) {
        update_pixel_inverse(pb, theta);
        for (int i = 0; i < pb->n_obs; i++) {
                const struct imp_joint_obs *o = &pb->obs[i];
                double r[2];
                res[i] = pb->pre[i].ok && residual(&pb->pre[i], o, light_at(theta, o->light), centre_at(pb, theta, o->mirror),
                                                   pb->mir[o->mirror].sphere.radius_mm, r, NULL, NULL)
                         ? hypot(r[0], r[1]) : INFINITY;
        }
}

/* RMS pixel residual and χ² of the inliers. */
static void fit_stats(const struct problem *pb, const double *res, double *ret_rms_px, double *ret_chi2) {
        double ss = 0, chi2 = 0;
        int n = 0;
        for (int i = 0; i < pb->n_obs; i++)
                if (!pb->out[i] && isfinite(res[i])) {
                        double px = res[i] * pb->obs[i].sigma_px;
                        ss += px * px;
                        chi2 += res[i] * res[i];
                        n++;
                }
        *ret_rms_px = n ? sqrt(ss / n) : 0;
        *ret_chi2 = chi2;
}

static int check_input(int n_lights, const struct imp_light_estimate *lights, int n_mirrors,
                       const struct imp_joint_mirror *mirrors, int n_obs, const struct imp_joint_obs *obs) {
        if (n_lights < 0 || n_mirrors < 0 || n_obs < 0 || (n_lights && !lights) || (n_mirrors && !mirrors) ||
            (n_obs && !obs))
                return -EINVAL;
        for (int l = 0; l < n_lights; l++)
                if (!isfinite(lights[l].pos_mm[0] + lights[l].pos_mm[1] + lights[l].pos_mm[2]))
                        return -EINVAL;
        for (int m = 0; m < n_mirrors; m++) {
                const struct imp_sphere *s = &mirrors[m].sphere;
                double t = 0;
                for (int k = 0; k < 9; k++)
                        t += s->centre_cov_mm2[k];
                if (!mirrors[m].cam || !(s->radius_mm > 0) || !isfinite(s->centre_mm[0] + s->centre_mm[1] + s->centre_mm[2]) ||
                    !isfinite(t) || !isfinite(s->centre_sigma_mm))
                        return -EINVAL;
        }
        for (int i = 0; i < n_obs; i++)
                if (obs[i].light < 0 || obs[i].light >= n_lights || obs[i].mirror < 0 || obs[i].mirror >= n_mirrors ||
                    !isfinite(obs[i].px[0] + obs[i].px[1]) || !(obs[i].sigma_px > 0) || !isfinite(obs[i].sigma_px))
                        return -EINVAL;
        return 0;
}

/* The prior information of a mirror's centre: the silhouette covariance (or σ² I), plus the
 * held height's σ² along z, floored at MIN_CENTRE_SIGMA_MM. */
static void centre_prior(const struct imp_sphere *s, double held_z_sigma, double ret_info[9]) {
        double C[9] = { 0 }, t = 0;
        for (int k = 0; k < 9; k++)
                t += fabs(s->centre_cov_mm2[k]);
        if (t > 0)
                memcpy(C, s->centre_cov_mm2, sizeof C);
        else
                C[0] = C[4] = C[8] = s->centre_sigma_mm * s->centre_sigma_mm;
        if (s->centre_z_held)
                C[8] += held_z_sigma * held_z_sigma;
        for (int k = 0; k < 3; k++)
                C[k * 4] += MIN_CENTRE_SIGMA_MM * MIN_CENTRE_SIGMA_MM;
        if (!inv3(C, ret_info))
                for (int k = 0; k < 9; k++)
                        ret_info[k] = k % 4 ? 0 : 1 / (MIN_CENTRE_SIGMA_MM * MIN_CENTRE_SIGMA_MM);
}

/* Per-light result from the covariance (pb->cov, np×np). Its conditioning is the geometric
 * one of imp_lights_triangulate, λmax/λmin of Σ (I − d dᵀ) over its inlier rays (equal
 * weights; two rays at angle α: ≈ 4/α²), so that the flag means "rays nearly parallel" in
 * both: the pixel-whitened block of the normal matrix adds the anisotropy of ∂d/∂px (a
 * highlight far off the mirror's top is foreshortened), ~1.7× larger here. */
static void light_result(const struct problem *pb, int l, const struct imp_light_estimate *in, double cov_scale,
                         double cond_max, double ps, struct imp_light_estimate *ret) {
        int np = pb->np, q = 3 * l, n = 0;
        const double *X = pb->theta + q;
        struct imp_light_estimate e = { .flags = in->flags & IMP_LIGHT_SATURATED };
        bool sat = false;
        double ss = 0, cov[9], blk[9] = { 0 }, lam[3], V[9];
        for (int i = 0; i < pb->n_obs; i++) {
                const struct imp_joint_obs *o = &pb->obs[i];
                double r[2], dist;
                bool behind;
                const double *C = pb->theta + 3 * pb->L + 3 * o->mirror;
                double P[3], d[3];
                if (o->light != l || pb->out[i] ||
                    !residual(&pb->pre[i], o, X, C, pb->mir[o->mirror].sphere.radius_mm, r, &dist, &behind) ||
                    !imp_lights_reflect_ray(pb->pre[i].O, pb->pre[i].u, C, pb->mir[o->mirror].sphere.radius_mm, P, d))
                        continue;
                for (int a = 0; a < 3; a++)
                        for (int b = 0; b < 3; b++)
                                blk[a * 3 + b] += (a == b) - d[a] * d[b];
                n++;
                ss += dist * dist;
                sat |= o->saturated;
                if (behind)
                        e.flags |= IMP_LIGHT_BEHIND;
        }
        for (int a = 0; a < 3; a++)
                for (int b = 0; b < 3; b++)
                        cov[a * 3 + b] = pb->cov[(size_t) (q + a) * np + q + b] * cov_scale;
        imp_eigen_sym(3, blk, lam, V);
        e.cond = lam[0] > lam[2] / COND_CAP ? lam[2] / lam[0] : COND_CAP;
        if (n < 2)
                e.flags |= IMP_LIGHT_FEW_RAYS;
        if (sat)
                e.flags |= IMP_LIGHT_SATURATED;
        if (e.cond > cond_max) {
                e.flags |= IMP_LIGHT_ILL_CONDITIONED;
                for (int k = 0; k < 3; k++)
                        if (!(lam[k] * cond_max > lam[2]))
                                for (int a = 0; a < 3; a++)
                                        for (int b = 0; b < 3; b++)
                                                cov[a * 3 + b] += ps * ps * V[a * 3 + k] * V[b * 3 + k];
        }
        double cl[3], tmp[9];
        memcpy(tmp, cov, sizeof tmp);
        imp_eigen_sym(3, tmp, cl, NULL);
        memcpy(e.pos_mm, X, sizeof e.pos_mm);
        memcpy(e.cov_mm2, cov, sizeof cov);
        e.sigma_mm = sqrt(IMP_MAX(cl[2], 0.0));
        e.rms_mm = n ? sqrt(ss / n) : 0;
        e.n_rays = n;
        *ret = e;
}

/* Conditioning of the centres after eliminating the lights (Schur complement S = N_CC −
 * N_CX N_XX⁻¹ N_XC; N_XX is block diagonal, one 3×3 per light): with the priors (N) and from
 * the highlights alone (N without the centre priors). */
static int centre_conditioning(const struct problem *pb, bool with_prior, double *ret_cond) {
        int np = pb->np, L = pb->L, nc = 3 * pb->M;
        if (nc == 0) {
                *ret_cond = 1;
                return 0;
        }
        _cleanup_free_ double *S = calloc((size_t) nc * nc, sizeof *S);
        _cleanup_free_ double *W = calloc((size_t) nc * 3, sizeof *W);
        _cleanup_free_ double *l = calloc((size_t) nc, sizeof *l);
        if (!S || !W || !l)
                return -ENOMEM;
        const double *N = pb->N;
        for (int i = 0; i < nc; i++)
                for (int j = 0; j < nc; j++)
                        S[i * nc + j] = N[(size_t) (3 * L + i) * np + 3 * L + j];
        if (!with_prior)
                for (int m = 0; m < pb->M; m++)
                        for (int a = 0; a < 3; a++)
                                for (int b = 0; b < 3; b++)
                                        S[(3 * m + a) * nc + 3 * m + b] -= pb->Cinfo[9 * m + a * 3 + b];
        for (int li = 0; li < L; li++) {
                double B[9], Bi[9];
                for (int a = 0; a < 3; a++)
                        for (int b = 0; b < 3; b++)
                                B[a * 3 + b] = N[(size_t) (3 * li + a) * np + 3 * li + b];
                if (!inv3(B, Bi))
                        continue;
                /* W = N_CX(:, light) · B⁻¹ (nc×3), S −= W · N_XC(light, :) */
                for (int i = 0; i < nc; i++)
                        for (int b = 0; b < 3; b++) {
                                double t = 0;
                                for (int a = 0; a < 3; a++)
                                        t += N[(size_t) (3 * L + i) * np + 3 * li + a] * Bi[a * 3 + b];
                                W[i * 3 + b] = t;
                        }
                for (int i = 0; i < nc; i++)
                        for (int j = 0; j < nc; j++) {
                                double t = 0;
                                for (int b = 0; b < 3; b++)
                                        t += W[i * 3 + b] * N[(size_t) (3 * li + b) * np + 3 * L + j];
                                S[i * nc + j] -= t;
                        }
        }
        *ret_cond = scaled_cond(nc, S, l);
        return 0;
}

static void problem_free(struct problem *pb) {
        free(pb->pre);
        free(pb->out);
        free(pb->X0);
        free(pb->C0);
        free(pb->Cinfo);
        free(pb->N);
        free(pb->g);
        free(pb->A);
        free(pb->theta);
        free(pb->trial);
        free(pb->step);
        free(pb->cov);
}

static int problem_init(struct problem *pb, int L, const struct imp_light_estimate *lights, int M,
                        const struct imp_joint_mirror *mir, int n_obs, const struct imp_joint_obs *obs,
                        double held_z, double ps) {
        int np = 3 * (L + M);
        *pb = (struct problem) { .L = L, .M = M, .n_obs = n_obs, .np = np, .mir = mir, .obs = obs,
                                 .light_info = 1 / (ps * ps) };
        size_t nn = (size_t) np * np;
        pb->pre = calloc((size_t) n_obs + 1, sizeof *pb->pre);
        pb->out = calloc((size_t) n_obs + 1, sizeof *pb->out);
        pb->X0 = calloc((size_t) 3 * L + 1, sizeof *pb->X0);
        pb->C0 = calloc((size_t) 3 * M + 1, sizeof *pb->C0);
        pb->Cinfo = calloc((size_t) 9 * M + 1, sizeof *pb->Cinfo);
        pb->N = calloc(nn + 1, sizeof *pb->N);
        pb->A = calloc(nn + 1, sizeof *pb->A);
        pb->cov = calloc(nn + 1, sizeof *pb->cov);
        pb->g = calloc((size_t) np + 1, sizeof *pb->g);
        pb->theta = calloc((size_t) np + 1, sizeof *pb->theta);
        pb->trial = calloc((size_t) np + 1, sizeof *pb->trial);
        pb->step = calloc((size_t) np + 1, sizeof *pb->step);
        if (!pb->pre || !pb->out || !pb->X0 || !pb->C0 || !pb->Cinfo || !pb->N || !pb->A || !pb->cov || !pb->g ||
            !pb->theta || !pb->trial || !pb->step)
                return -ENOMEM;
        for (int l = 0; l < L; l++)
                memcpy(pb->X0 + 3 * l, lights[l].pos_mm, 3 * sizeof(double));
        for (int m = 0; m < M; m++) {
                memcpy(pb->C0 + 3 * m, mir[m].sphere.centre_mm, 3 * sizeof(double));
                centre_prior(&mir[m].sphere, held_z, pb->Cinfo + 9 * m);
        }
        memcpy(pb->theta, pb->X0, 3 * L * sizeof(double));
        memcpy(pb->theta + 3 * L, pb->C0, 3 * M * sizeof(double));
        for (int i = 0; i < n_obs; i++) {
                struct pre *p = &pb->pre[i];
                const struct imp_pinhole *cam = mir[obs[i].mirror].cam;
                double O2[3], up[3], um[3];
                imp_pinhole_ray_world(cam, obs[i].px, p->O, p->u);
                for (int a = 0; a < 2; a++) {
                        double q[2] = { obs[i].px[0], obs[i].px[1] };
                        q[a] += PX_STEP;
                        imp_pinhole_ray_world(cam, q, O2, up);
                        q[a] -= 2 * PX_STEP;
                        imp_pinhole_ray_world(cam, q, O2, um);
                        for (int k = 0; k < 3; k++)
                                p->du[a][k] = (up[k] - um[k]) / (2 * PX_STEP);
                }
        }
        return 0;
}

/* pb->cov = N⁻¹ (the normal matrix with the priors), column by column through Cholesky. */
static int invert_normal(struct problem *pb) {
        memcpy(pb->A, pb->N, sizeof *pb->A * (size_t) pb->np * pb->np);
        if (!imp_cholesky_factor(pb->np, pb->A))
                return -EDOM;   /* cannot happen: every parameter has a prior */
        for (int q = 0; q < pb->np; q++) {
                double *col = pb->step;
                memset(col, 0, sizeof *col * (size_t) pb->np);
                col[q] = 1;
                imp_cholesky_solve(pb->np, pb->A, col);
                for (int k = 0; k < pb->np; k++)
                        pb->cov[(size_t) k * pb->np + q] = col[k];
        }
        return 0;
}

/* The refined mirror centres with their covariance (scaled by rep->cov_scale) and shift
 * from the silhouette fits; the shift statistics into rep. */
static void centre_results(const struct problem *pb, struct imp_joint_centre *ret_centres, struct imp_joint_report *rep) {
        const int n_lights = pb->L, n_mirrors = pb->M;
        double ss = 0;
        for (int m = 0; m < n_mirrors; m++) {
                struct imp_joint_centre jc = { 0 };
                int q = 3 * n_lights + 3 * m;
                double tmp[9], lam[3];
                for (int a = 0; a < 3; a++) {
                        jc.centre_mm[a] = pb->theta[q + a];
                        for (int b = 0; b < 3; b++)
                                jc.cov_mm2[a * 3 + b] = pb->cov[(size_t) (q + a) * pb->np + q + b] * rep->cov_scale;
                }
                memcpy(tmp, jc.cov_mm2, sizeof tmp);
                imp_eigen_sym(3, tmp, lam, NULL);
                jc.sigma_mm = sqrt(IMP_MAX(lam[2], 0.0));
                double dc[3] = { jc.centre_mm[0] - pb->C0[3 * m], jc.centre_mm[1] - pb->C0[3 * m + 1],
                                 jc.centre_mm[2] - pb->C0[3 * m + 2] };
                jc.shift_mm = imp_norm3(dc);
                ss += jc.shift_mm * jc.shift_mm;
                rep->centre_shift_max_mm = IMP_MAX(rep->centre_shift_max_mm, jc.shift_mm);
                ret_centres[m] = jc;
        }
        rep->centre_shift_rms_mm = n_mirrors ? sqrt(ss / n_mirrors) : 0;
}

int imp_lights_joint_refine(int n_lights, const struct imp_light_estimate *lights, int n_mirrors,
                            const struct imp_joint_mirror *mirrors, int n_obs, const struct imp_joint_obs *obs,
                            const struct imp_joint_opts *opts, struct imp_light_estimate *ret_lights,
                            struct imp_joint_centre *ret_centres, double *ret_residual_px, bool *ret_outlier,
                            struct imp_joint_report *ret_report) {
        if (!ret_lights || (n_mirrors && !ret_centres) || !ret_report)
                return -EINVAL;
        int r = check_input(n_lights, lights, n_mirrors, mirrors, n_obs, obs);
        if (r < 0)
                return r;
        double held_z = opts && opts->held_z_sigma_mm > 0 ? opts->held_z_sigma_mm : HELD_Z_SIGMA_MM;
        double k_out = opts && opts->outlier_k > 0 ? opts->outlier_k : OUTLIER_K;
        int max_iter = opts && opts->max_iter > 0 ? opts->max_iter : MAX_ITER;
        double cond_max = opts && opts->cond_max > 0 ? opts->cond_max : LIGHT_COND_MAX;
        double ps = opts && opts->prior_sigma_mm > 0 ? opts->prior_sigma_mm : LIGHT_PRIOR_SIGMA_MM;
        double cdm = opts && opts->cond_data_max > 0 ? opts->cond_data_max : COND_DATA_MAX;
        _cleanup_(problem_free) struct problem pb = { 0 };
        if ((r = problem_init(&pb, n_lights, lights, n_mirrors, mirrors, n_obs, obs, held_z, ps)) < 0)
                return r;
        _cleanup_free_ double *res = calloc((size_t) n_obs + 1, sizeof *res);
        _cleanup_free_ double *sorted = calloc((size_t) n_obs + 1, sizeof *sorted);
        _cleanup_free_ bool *newout = calloc((size_t) n_obs + 1, sizeof *newout);
        if (!res || !sorted || !newout)
                return -ENOMEM;
        struct imp_joint_report rep = { .n_obs = n_obs, .n_params = pb.np, .n_lights = n_lights, .n_mirrors = n_mirrors,
                                        .scale = 1 };
        all_residuals(&pb, pb.theta, res);
        for (int i = 0; i < n_obs; i++)
                pb.out[i] = !isfinite(res[i]);
        fit_stats(&pb, res, &rep.rms_px_before, &rep.chi2_before);

        bool conv = true;
        for (int pass = 0; pass < MAX_PASSES; pass++) {
                bool c;
                rep.iterations += solve(&pb, max_iter, &c);
                rep.passes++;
                conv = c;
                all_residuals(&pb, pb.theta, res);
                int m = 0;
                for (int i = 0; i < n_obs; i++)
                        if (!pb.out[i] && isfinite(res[i]))
                                sorted[m++] = res[i];
                if (m == 0)
                        break;
                qsort(sorted, (size_t) m, sizeof *sorted, imp_cmp_double);
                rep.scale = sorted[m / 2] / RAYLEIGH_MEDIAN;
                /* never below 1: lights with two or three rays fit them almost exactly, and a
                 * median of such residuals would make every honest highlight an outlier */
                double thr = k_out * IMP_MAX(rep.scale, 1.0);
                bool changed = false;
                for (int i = 0; i < n_obs; i++) {
                        newout[i] = !(res[i] <= thr);
                        changed |= newout[i] != pb.out[i];
                }
                if (!changed || pass == MAX_PASSES - 1)   /* the last set is the one solved */
                        break;
                memcpy(pb.out, newout, sizeof *newout * (size_t) n_obs);
        }
        if (!conv)
                rep.flags |= IMP_JOINT_NOT_CONVERGED;
        for (int i = 0; i < n_obs; i++)
                rep.n_outliers += pb.out[i];
        fit_stats(&pb, res, &rep.rms_px_after, &rep.chi2_after);
        int lights_seen = 0;
        for (int l = 0; l < n_lights; l++)
                for (int i = 0; i < n_obs; i++)
                        if (obs[i].light == l && !pb.out[i]) {
                                lights_seen++;
                                break;
                        }
        rep.dof = 2 * (n_obs - rep.n_outliers) - 3 * lights_seen;
        rep.cov_scale = rep.dof > 0 ? IMP_MAX(1.0, rep.chi2_after / rep.dof) : 1.0;

        /* covariance: the inverse of the normal matrix with the priors, at the solution */
        update_pixel_inverse(&pb, pb.theta);
        normal_equations(&pb, pb.theta, true);
        if ((r = centre_conditioning(&pb, true, &rep.cond)) < 0 || (r = centre_conditioning(&pb, false, &rep.cond_data)) < 0)
                return r;
        if (rep.cond_data > cdm)
                rep.flags |= IMP_JOINT_WEAK_CENTRES;
        if (rep.cond > COND_MAX)
                rep.flags |= IMP_JOINT_ILL_CONDITIONED;
        if ((r = invert_normal(&pb)) < 0)
                return r;
        for (int l = 0; l < n_lights; l++)
                light_result(&pb, l, &lights[l], rep.cov_scale, cond_max, ps, &ret_lights[l]);
        centre_results(&pb, ret_centres, &rep);
        for (int i = 0; i < n_obs; i++) {
                if (ret_residual_px)
                        ret_residual_px[i] = isfinite(res[i]) ? res[i] * obs[i].sigma_px : 1e30;
                if (ret_outlier)
                        ret_outlier[i] = pb.out[i];
        }
        *ret_report = rep;
        return 0;
}
