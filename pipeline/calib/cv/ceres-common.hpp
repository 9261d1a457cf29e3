/* Pieces shared by the Ceres refinements (ceres-calib.cpp: one device; ceres-procam.cpp:
 * camera and projector jointly): OpenCV's projection as a template, rigid-pose helpers, the
 * Rayleigh median and first-order propagation of a covariance through a projection (the
 * mrcal-style uncertainty). Internal to impasto_cv; included only when built with Ceres. */
#pragma once
#include <algorithm>
#include <cmath>
#include <functional>
#include <vector>
#include <opencv2/calib3d.hpp>
#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include "ceres-calib.h"

namespace imp_ceres {

constexpr int NI = IMP_CALIB_N_INTR;    /* fx fy cx cy k1 k2 p1 p2 k3 */
constexpr int NP = 6;                   /* pose: Rodrigues r (3), t (3); X' = R(r) X + t */
/* Median of the norm of a 2-D isotropic Gaussian residual is σ·√(2 ln 2). */
inline double rayleigh_median() { return std::sqrt(2.0 * std::log(2.0)); }

/* The solver settings of both refinements: Levenberg–Marquardt with a Schur complement over
 * the independent poses, tolerances 1e-12, at most max_iterations (200 when ≤ 0), silent. */
inline ceres::Solver::Options solver_options(int max_iterations) {
        ceres::Solver::Options so;
        so.linear_solver_type = ceres::DENSE_SCHUR;
        so.max_num_iterations = max_iterations > 0 ? max_iterations : 200;
        so.function_tolerance = 1e-12;
        so.parameter_tolerance = 1e-12;
        so.gradient_tolerance = 1e-14;
        so.num_threads = 1;
        so.logging_type = ceres::SILENT;
        return so;
}

/* The robust loss of opts with scale a (residual units); nullptr for none. */
inline ceres::LossFunction *make_loss(enum imp_ceres_loss loss, double a) {
        if (loss == IMP_CERES_LOSS_HUBER)
                return new ceres::HuberLoss(a);
        if (loss == IMP_CERES_LOSS_CAUCHY)
                return new ceres::CauchyLoss(a);
        return nullptr;
}

/* Outlier limit on residual norms e (not empty): max(k · σ_robust, min_px), σ_robust from the
 * median (ceres-calib.h). */
inline double outlier_limit(std::vector<double> e, const struct imp_ceres_calib_opts *o) {
        std::nth_element(e.begin(), e.begin() + (long) e.size() / 2, e.end());
        return std::max(o->outlier_sigmas * e[e.size() / 2] / rayleigh_median(), o->outlier_min_px);
}

/* n_points, rms_px, worst_px, worst_view, worst_point of r over the points b.pts[i] with
 * keep(i) (b: a bundle with pts[].view, pts[].index and residual(pt), the norm in px);
 * returns Σ r². */
template <typename B, typename Keep>
double residual_stats(const B &b, Keep keep, struct imp_calib_intrinsics *r) {
        double sse = 0, worst = -1;
        int N = 0;
        for (size_t i = 0; i < b.pts.size(); i++) {
                if (!keep(i))
                        continue;
                double e = b.residual(b.pts[i]);
                sse += e * e;
                N++;
                if (e > worst) {
                        worst = e;
                        r->worst_view = b.pts[i].view;
                        r->worst_point = b.pts[i].index;
                }
        }
        r->n_points = N;
        r->rms_px = std::sqrt(sse / std::max(N, 1));
        r->worst_px = std::max(worst, 0.0);
        return sse;
}

inline bool finite_all(const double *v, size_t n) {
        for (size_t i = 0; i < n; i++)
                if (!std::isfinite(v[i]))
                        return false;
        return true;
}

/* OpenCV's projection (projectPoints with 5 distortion terms) of point X through pose. */
template <typename T>
void project(const T *in, const T *pose, const T X[3], T out[2]) {
        T p[3];
        ceres::AngleAxisRotatePoint(pose, X, p);
        for (int k = 0; k < 3; k++)
                p[k] += pose[3 + k];
        T x = p[0] / p[2], y = p[1] / p[2], r2 = x * x + y * y;
        T rad = T(1) + r2 * (in[4] + r2 * (in[5] + r2 * in[8]));
        T xd = x * rad + T(2) * in[6] * x * y + in[7] * (r2 + T(2) * x * x);
        T yd = y * rad + in[6] * (r2 + T(2) * y * y) + T(2) * in[7] * x * y;
        out[0] = in[0] * xd + in[2];
        out[1] = in[1] * yd + in[3];
}

/* out = R(pose) X + t. */
inline void pose_apply(const double *pose, const double X[3], double out[3]) {
        ceres::AngleAxisRotatePoint(pose, X, out);
        for (int k = 0; k < 3; k++)
                out[k] += pose[3 + k];
}

/* out = R(pose)ᵀ (X − t). */
inline void pose_inverse_apply(const double *pose, const double X[3], double out[3]) {
        const double d[3] = { X[0] - pose[3], X[1] - pose[4], X[2] - pose[5] }, ir[3] = { -pose[0], -pose[1], -pose[2] };
        ceres::AngleAxisRotatePoint(ir, d, out);
}

/* The device-frame point at depth `range` seen at pixel (qx, qy) by intrinsics in. */
inline void unproject(const double *in, double qx, double qy, double range, double out[3]) {
        cv::Mat K = (cv::Mat_<double>(3, 3) << in[0], 0, in[2], 0, in[1], in[3], 0, 0, 1);
        cv::Mat D = (cv::Mat_<double>(1, 5) << in[4], in[5], in[6], in[7], in[8]);
        std::vector<cv::Point2d> q{ { qx, qy } }, n;
        cv::undistortPoints(q, n, K, D, cv::noArray(), cv::noArray(),
                            cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-14));
        out[0] = range * n[0].x;
        out[1] = range * n[0].y;
        out[2] = range;
}

/* √λmax of J C Jᵀ (the 1σ of a 2-vector along its worst direction), J = ∂F/∂θ at theta0 by
 * central differences (step 1e-6 · max(|θk|, 1)); C is P × P row-major, P = theta0.size(). */
inline double propagate(const std::vector<double> &theta0, const std::vector<double> &C,
                        const std::function<void(const std::vector<double> &, double[2])> &F) {
        const size_t P = theta0.size();
        std::vector<double> J(2 * P), t = theta0;
        for (size_t k = 0; k < P; k++) {
                double h = 1e-6 * std::max(std::fabs(theta0[k]), 1.0), a[2], c[2];
                t[k] = theta0[k] + h;
                F(t, a);
                t[k] = theta0[k] - h;
                F(t, c);
                t[k] = theta0[k];
                J[k] = (a[0] - c[0]) / (2 * h);
                J[P + k] = (a[1] - c[1]) / (2 * h);
        }
        double S[3] = { 0, 0, 0 };      /* Sxx, Sxy, Syy */
        for (size_t i = 0; i < P; i++)
                for (size_t j = 0; j < P; j++) {
                        double c = C[i * P + j];
                        S[0] += J[i] * c * J[j];
                        S[1] += J[i] * c * J[P + j];
                        S[2] += J[P + i] * c * J[P + j];
                }
        double tr = 0.5 * (S[0] + S[2]), det = S[0] * S[2] - S[1] * S[1];
        double lmax = tr + std::sqrt(std::max(tr * tr - det, 0.0));
        return std::sqrt(std::max(lmax, 0.0));
}

/* Largest angle (deg) between a board's normal and the device's optical axis; R row-major. */
inline double tilt_deg(const double R[9]) {
        return std::acos(std::min(std::fabs(R[8]), 1.0)) * 180.0 / M_PI;
}

}  // namespace imp_ceres
