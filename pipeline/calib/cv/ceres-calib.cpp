/* Ceres bundle refinement of a planar-target calibration (see ceres-calib.h): intrinsics,
 * Brown–Conrady distortion and one pose per view, robust loss, outlier rejection, then
 * the covariance (ceres::Covariance, all blocks) and an mrcal-style projection
 * uncertainty. Every exception stops at this boundary. */
#include <algorithm>
#include <cerrno>
#include <cmath>
#include <new>
#include <vector>
#include <opencv2/calib3d.hpp>
#include "ceres-calib.h"
#ifdef IMPASTO_HAVE_CERES
#include <ceres/ceres.h>
#include "ceres-common.hpp"
#endif

#ifdef IMPASTO_HAVE_CERES
namespace {

using imp_ceres::NI;
using imp_ceres::NP;
using imp_ceres::project;

struct corner_cost {
        double X[3], u, v;
        template <typename T>
        bool operator()(const T *in, const T *pose, T *res) const {
                T P[3] = { T(X[0]), T(X[1]), T(X[2]) }, q[2];
                project(in, pose, P, q);
                res[0] = q[0] - T(u);
                res[1] = q[1] - T(v);
                return true;
        }
};

struct point_ref { int view, index; };

struct bundle {
        const struct imp_calib_view *views;
        int n_views;
        double intr[NI];
        std::vector<double> poses;              /* NP per view */
        std::vector<point_ref> pts;             /* every point, in view order */
        std::vector<uint8_t> inlier;

        double residual(const point_ref &p) const {
                const double *X = views[p.view].obj + 3 * p.index, *m = views[p.view].img + 2 * p.index;
                double q[2];
                project(intr, &poses[NP * (size_t) p.view], X, q);
                return std::hypot(q[0] - m[0], q[1] - m[1]);
        }
};

/* The problem over the inliers; loss may be null (plain least squares). The problem owns
 * the cost functions and the (shared) loss. */
void build(bundle &b, ceres::Problem &pb, ceres::LossFunction *loss, bool fix_k3, bool fix_k2) {
        for (size_t i = 0; i < b.pts.size(); i++) {
                if (!b.inlier[i])
                        continue;
                const point_ref &p = b.pts[i];
                const struct imp_calib_view &v = b.views[p.view];
                auto *c = new corner_cost{ { v.obj[3 * p.index], v.obj[3 * p.index + 1], v.obj[3 * p.index + 2] },
                                           v.img[2 * p.index], v.img[2 * p.index + 1] };
                pb.AddResidualBlock(new ceres::AutoDiffCostFunction<corner_cost, 2, NI, NP>(c), loss, b.intr,
                                    &b.poses[NP * (size_t) p.view]);
        }
        std::vector<int> fixed;
        if (fix_k2)
                fixed.push_back(5);
        if (fix_k3)
                fixed.push_back(NI - 1);
        if (!fixed.empty())
                pb.SetManifold(b.intr, new ceres::SubsetManifold(NI, fixed));
}

int solve(bundle &b, const struct imp_ceres_calib_opts *o, bool robust, int *iterations) {
        ceres::Problem pb;
        ceres::LossFunction *loss = robust ? imp_ceres::make_loss(o->loss, o->loss_scale_px) : nullptr;
        build(b, pb, loss, o->fix_k3, o->fix_k2);
        ceres::Solver::Options so = imp_ceres::solver_options(o->max_iterations);
        ceres::Solver::Summary sum;
        ceres::Solve(so, &pb, &sum);
        *iterations += (int) sum.iterations.size();
        return sum.IsSolutionUsable() ? 0 : -EDOM;
}

/* Drops points whose residual exceeds max(k·σ_robust, min_px); returns how many. */
int reject(bundle &b, const struct imp_ceres_calib_opts *o) {
        std::vector<double> e(b.pts.size());
        for (size_t i = 0; i < b.pts.size(); i++)
                e[i] = b.residual(b.pts[i]);
        double limit = imp_ceres::outlier_limit(e, o);
        int n = 0;
        for (size_t i = 0; i < b.pts.size(); i++)
                if (e[i] > limit) {
                        b.inlier[i] = 0;
                        n++;
                }
        return n;
}

/* mrcal's projection uncertainty (Kogan, mrcal docs "projection uncertainty"): the point
 * seen at pixel q at range d is carried into every board's frame, and after a parameter
 * perturbation back into the camera by the mean of the perturbed poses, then projected
 * with the perturbed intrinsics. Σq = J C Jᵀ with J = ∂q/∂θ over all parameters (central
 * differences) and C their full covariance; returns √λmax(Σq). A shift of (cx, cy) that
 * the poses compensate therefore does not count, unlike the intrinsics-only figure. */
double mrcal_uncertainty(const bundle &b, const std::vector<double> &C, double qx, double qy, double range) {
        double pc[3];
        imp_ceres::unproject(b.intr, qx, qy, range, pc);
        const int M = b.n_views;
        std::vector<double> board((size_t) 3 * M);      /* pc in each board's frame */
        for (int v = 0; v < M; v++)
                imp_ceres::pose_inverse_apply(&b.poses[NP * (size_t) v], pc, &board[3 * (size_t) v]);
        std::vector<double> theta(b.intr, b.intr + NI);
        theta.insert(theta.end(), b.poses.begin(), b.poses.end());
        return imp_ceres::propagate(theta, C, [&](const std::vector<double> &th, double out[2]) {
                double mean[3] = { 0, 0, 0 };
                for (int v = 0; v < M; v++) {
                        double p[3];
                        imp_ceres::pose_apply(&th[NI + NP * (size_t) v], &board[3 * (size_t) v], p);
                        for (int k = 0; k < 3; k++)
                                mean[k] += p[k] / M;
                }
                const double zero[NP] = { 0, 0, 0, 0, 0, 0 };
                project(th.data(), zero, mean, out);
        });
}

/* Residual statistics over the inliers, covariance of all parameters, std, σ and the
 * projection uncertainty into r. Returns false when Ceres finds the Jacobian rank
 * deficient (r's std/cov then untouched). */
bool assess(bundle &b, const struct imp_ceres_calib_opts *o, struct imp_calib_intrinsics *r) {
        const double sse = imp_ceres::residual_stats(b, [&](size_t i) { return b.inlier[i] != 0; }, r);
        const int N = r->n_points;
        const int M = b.n_views, n_intr = NI - o->fix_k3 - o->fix_k2, P = NI + NP * M;
        const int dof = N - (n_intr + NP * M);     /* OpenCV's convention, see calib.h */
        const double sigma2 = sse / std::max(dof, 1);
        r->sigma_px = std::sqrt(sigma2);

        ceres::Problem pb;
        build(b, pb, nullptr, o->fix_k3, o->fix_k2);
        std::vector<const double *> blocks{ b.intr };
        for (int v = 0; v < M; v++)
                blocks.push_back(&b.poses[NP * (size_t) v]);
        std::vector<double> C((size_t) P * P);
        bool ok = false;
        for (auto alg : { ceres::SPARSE_QR, ceres::DENSE_SVD }) {
                ceres::Covariance::Options co;
                co.algorithm_type = alg;
                co.null_space_rank = 0;         /* fail, rather than truncate, when singular */
                ceres::Covariance cov(co);
                if (cov.Compute(blocks, &pb) && cov.GetCovarianceMatrix(blocks, C.data())) {
                        ok = true;
                        break;
                }
        }
        if (!ok || dof <= 0)
                return false;
        for (double &c : C)
                c *= sigma2;
        for (int a = 0; a < NI; a++) {
                for (int c = 0; c < NI; c++)
                        r->cov[a * NI + c] = C[(size_t) a * P + c];
                r->std[a] = std::sqrt(std::max(C[(size_t) a * P + a], 0.0));
        }
        double range = 0;
        for (int v = 0; v < M; v++)
                range += b.poses[NP * (size_t) v + 5] / M;
        r->proj_unc_centre_px = mrcal_uncertainty(b, C, (r->width - 1) / 2.0, (r->height - 1) / 2.0, range);
        r->proj_unc_corner_px = mrcal_uncertainty(b, C, 0.0, 0.0, range);
        return true;
}

using imp_ceres::finite_all;

int refine_cpp(const struct imp_calib_view *views, int n_views, const struct imp_ceres_calib_opts *o,
               struct imp_calib_intrinsics *io, double *io_rvecs, double *io_tvecs, uint8_t *ret_inlier,
               struct imp_ceres_calib_report *ret_report, struct imp_error *err) {
        bundle b;
        b.views = views;
        b.n_views = n_views;
        const double start[NI] = { io->fx, io->fy, io->cx, io->cy, io->dist[0], io->dist[1], io->dist[2],
                                   io->dist[3], io->dist[4] };
        std::copy(start, start + NI, b.intr);
        b.poses.resize((size_t) NP * n_views);
        for (int v = 0; v < n_views; v++)
                for (int k = 0; k < 3; k++) {
                        b.poses[NP * (size_t) v + k] = io_rvecs[3 * v + k];
                        b.poses[NP * (size_t) v + 3 + k] = io_tvecs[3 * v + k];
                }
        for (int v = 0; v < n_views; v++)
                for (int i = 0; i < views[v].n; i++)
                        b.pts.push_back({ v, i });
        b.inlier.assign(b.pts.size(), 1);
        struct imp_ceres_calib_report rep = {};
        double s0 = 0;
        for (const auto &p : b.pts)
                s0 += b.residual(p) * b.residual(p);
        rep.initial_rms_px = std::sqrt(s0 / std::max<size_t>(b.pts.size(), 1));

        struct imp_ceres_calib_opts oo = *o;
        oo.fix_k3 = o->fix_k3 || io->k3_fixed;
        oo.fix_k2 = o->fix_k2 || io->k2_fixed;
        const bool robust = oo.loss != IMP_CERES_LOSS_NONE;
        if (solve(b, &oo, robust, &rep.iterations) < 0)
                return imp_error_set(err, -EDOM, "ceres refinement: the solver gave no usable solution");
        if (oo.outlier_sigmas > 0) {
                rep.n_outliers = reject(b, &oo);
                for (int v = 0, base = 0; v < n_views; base += views[v].n, v++) {
                        int kept = 0;
                        for (int i = 0; i < views[v].n; i++)
                                kept += b.inlier[(size_t) base + i];
                        if (kept < 4)
                                return imp_error_set(err, -EDOM, "ceres refinement: view %d keeps %d of %d "
                                                     "points after outlier rejection", v, kept, views[v].n);
                }
                if (rep.n_outliers > 0 && solve(b, &oo, robust, &rep.iterations) < 0)
                        return imp_error_set(err, -EDOM, "ceres refinement: the solver gave no usable "
                                             "solution after outlier rejection");
        }
        if (!finite_all(b.intr, NI) || !finite_all(b.poses.data(), b.poses.size()) || !(b.intr[0] > 0) ||
            !(b.intr[1] > 0))
                return imp_error_set(err, -EDOM, "ceres refinement gave a non-finite or non-positive result");

        struct imp_calib_intrinsics r = *io;
        r.fx = b.intr[0];
        r.fy = b.intr[1];
        r.cx = b.intr[2];
        r.cy = b.intr[3];
        std::copy(b.intr + 4, b.intr + NI, r.dist);
        r.k3_fixed = oo.fix_k3;
        r.k2_fixed = oo.fix_k2;
        rep.covariance_ok = assess(b, &oo, &r);
        if (!rep.covariance_ok)
                r.flags |= IMP_CALIB_RANK_DEFICIENT;
        if (!finite_all(r.std, NI) || !finite_all(r.cov, NI * NI) || !std::isfinite(r.proj_unc_centre_px) ||
            !std::isfinite(r.proj_unc_corner_px))
                return imp_error_set(err, -EDOM, "ceres refinement: non-finite uncertainty");
        if (oo.fix_k3)
                r.std[NI - 1] = 0;
        if (oo.fix_k2)
                r.std[5] = 0;
        *io = r;
        for (int v = 0; v < n_views; v++)
                for (int k = 0; k < 3; k++) {
                        io_rvecs[3 * v + k] = b.poses[NP * (size_t) v + k];
                        io_tvecs[3 * v + k] = b.poses[NP * (size_t) v + 3 + k];
                }
        if (ret_inlier)
                std::copy(b.inlier.begin(), b.inlier.end(), ret_inlier);
        if (ret_report)
                *ret_report = rep;
        return 0;
}

}  // namespace
#endif

extern "C" bool imp_ceres_calib_available(void) {
#ifdef IMPASTO_HAVE_CERES
        return true;
#else
        return false;
#endif
}

extern "C" int imp_ceres_calib_refine(const struct imp_calib_view *views, int n_views,
                                      const struct imp_ceres_calib_opts *opts, struct imp_calib_intrinsics *io,
                                      double *io_rvecs, double *io_tvecs, uint8_t *ret_inlier,
                                      struct imp_ceres_calib_report *ret_report, struct imp_error *err) {
        if (!views || n_views < 1 || !opts || !io || !io_rvecs || !io_tvecs || io->width < 1 || io->height < 1 ||
            (opts->loss != IMP_CERES_LOSS_NONE && !(opts->loss_scale_px > 0)) || !(opts->outlier_sigmas >= 0))
                return imp_error_set(err, -EINVAL, "ceres refinement: bad arguments");
        for (int v = 0; v < n_views; v++)
                if (views[v].n < 4 || !views[v].obj || !views[v].img)
                        return imp_error_set(err, -EINVAL, "ceres refinement: view %d has %d points, at "
                                             "least 4 needed", v, views[v].n);
#ifdef IMPASTO_HAVE_CERES
        try {
                return refine_cpp(views, n_views, opts, io, io_rvecs, io_tvecs, ret_inlier, ret_report, err);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "ceres refinement: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "ceres refinement: %s", e.what());
        }
#else
        (void) ret_inlier;
        (void) ret_report;
        return imp_error_set(err, -EOPNOTSUPP, "ceres refinement: impasto was built without Ceres "
                             "(IMPASTO_WITH_CERES off)");
#endif
}
