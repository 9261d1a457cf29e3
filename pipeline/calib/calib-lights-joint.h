/* Joint refinement of dome light positions and mirror centres: one least-squares
 * problem over every light and every mirror of every capture, from the highlights they share,
 * with each centre held to its silhouette fit by a prior. Method, figures:
 * docs/calibration-lights.md, "Joint refinement". Library code: no logging. */
#pragma once
#include <stdbool.h>
#include "calib-lights.h"
#include "rig.h"

/* A mirror as the silhouette fit left it: the prior of the refinement. */
struct imp_joint_mirror {
        const struct imp_pinhole *cam;   /* the camera of the capture that saw it */
        struct imp_sphere sphere;        /* centre_mm, radius_mm, centre_cov_mm2 (or centre_sigma_mm), centre_z_held */
};

/* One highlight: light `light` seen in mirror `mirror` at pixel px. */
struct imp_joint_obs {
        int light, mirror;               /* indices into the lights and mirrors passed */
        double px[2];                    /* highlight centroid, full-frame pixels */
        double sigma_px;                 /* its 1σ (imp_highlight.sigma_px) */
        bool saturated;
};

struct imp_joint_opts {
        double held_z_sigma_mm;          /* prior 1σ of a centre height the silhouette fit held; 0 → 0.001 */
        double outlier_k;                /* reject |r| > k × max(robust scale, 1) (whitened residuals); 0 → 5 */
        int max_iter;                    /* LM iterations per pass; 0 → 50 */
        double cond_max;                 /* per-light flag, as imp_lights_triangulate; 0 → 1000 */
        double prior_sigma_mm;           /* weak prior on each light around its start; 0 → 1000 */
        double cond_data_max;            /* centres from highlights alone: flag above; 0 → 1e8 */
};

enum {
        IMP_JOINT_NOT_CONVERGED = 1 << 0,   /* iteration limit reached */
        IMP_JOINT_WEAK_CENTRES = 1 << 1,    /* the highlights alone do not pin the centres (cond_data > max):
                                             * the centres are (mostly) their silhouette priors */
        IMP_JOINT_ILL_CONDITIONED = 1 << 2, /* the centres' normal matrix with priors is ill-conditioned */
};

/* The refined centre of one mirror. */
struct imp_joint_centre {
        double centre_mm[3];
        double cov_mm2[9];               /* marginal covariance (row-major), scaled as the lights' */
        double sigma_mm;                 /* √λmax(cov) */
        double shift_mm;                 /* |refined − silhouette| */
};

struct imp_joint_report {
        int iterations;                  /* LM iterations, all passes */
        int passes;                      /* outlier passes (≥ 1) */
        int n_obs, n_outliers, n_params, n_lights, n_mirrors;
        double rms_px_before, rms_px_after;     /* RMS highlight residual (inliers), pixels */
        double chi2_before, chi2_after;         /* Σ (residual/σ_px)², inliers; dof below */
        int dof;                                /* 2 × inliers − 3 × lights */
        double scale;                           /* robust residual scale (1 when σ_px is honest) */
        double cov_scale;                       /* max(1, χ²/dof): applied to every covariance */
        double cond;                            /* centres' information (lights eliminated), with priors */
        double cond_data;                       /* the same from the highlights alone */
        double centre_shift_rms_mm, centre_shift_max_mm;
        unsigned flags;                         /* IMP_JOINT_* */
};

/* Refines every light position and every mirror centre together: minimises
 *   Σ_obs ρ(|r_i|²) + Σ_m (C_m − C⁰_m)ᵀ Σ_m⁻¹ (C_m − C⁰_m) + Σ_l |X_l − X⁰_l|²/σ_p²
 * where r_i (2-vector) is the highlight's pixel residual in units of its σ_px: the camera ray
 * through the observed centroid meets mirror C_m (radius known, first intersection),
 * reflects to direction d; the angle e between d and the direction to X_l is turned into the
 * pixel shift of the highlight that would make the reflected ray pass through X_l (the
 * least-squares inverse of ∂d/∂px, recomputed each iteration: the pixel-space residual to
 * first order, exact at zero). Σ_m: the silhouette fit's covariance (centre_cov_mm2; all 0 →
 * centre_sigma_mm² I), held_z_sigma_mm² added along z when the fit held C_z. X⁰: `lights`
 * (e.g. imp_lights_triangulate), σ_p the weak prior that keeps an undetermined light finite.
 * Levenberg–Marquardt on dense normal equations (3 × (lights + mirrors) parameters, numerical
 * Jacobians by central differences), ≤ max_iter iterations, stops when the relative cost
 * decrease < 1e-12 or the step < 1e-9 mm. Outliers: after each pass, highlights whose |r| >
 * outlier_k × max(s, 1) (s = median |r| / 1.1774, the Rayleigh median) are dropped and the problem
 * solved again (≤ 4 passes, until the set stops changing); a pixel ray that misses the moved
 * mirror is an outlier too. Covariance: the inverse normal matrix × max(1, χ²/dof); a light
 * whose own data block has cond > cond_max is flagged IMP_LIGHT_ILL_CONDITIONED and gets
 * σ_p² along its weak directions (as imp_lights_triangulate). Always finite.
 * lights[n_lights]: start values (pos_mm; flags IMP_LIGHT_SATURATED kept); a light with no
 * inlier keeps its position, flagged IMP_LIGHT_FEW_RAYS | IMP_LIGHT_ILL_CONDITIONED with the
 * prior's σ. ret_lights[n_lights], ret_centres[n_mirrors], ret_report written on
 * success only; ret_residual_px[n_obs] (|r| × σ_px, pixels) and ret_outlier[n_obs] may be NULL.
 * -EINVAL bad arguments (index out of range, non-finite values, σ_px ≤ 0, radius ≤ 0);
 * -ENOMEM. */
int imp_lights_joint_refine(int n_lights, const struct imp_light_estimate *lights, int n_mirrors,
                            const struct imp_joint_mirror *mirrors, int n_obs, const struct imp_joint_obs *obs,
                            const struct imp_joint_opts *opts, struct imp_light_estimate *ret_lights,
                            struct imp_joint_centre *ret_centres, double *ret_residual_px, bool *ret_outlier,
                            struct imp_joint_report *ret_report);
