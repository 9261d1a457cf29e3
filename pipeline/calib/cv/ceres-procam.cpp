/* Joint Ceres refinement of a projector–camera pair (see ceres-procam.h): both devices'
 * intrinsics, the board poses and the camera → projector pose in one robust problem, then
 * the covariance of all of it (dense, pseudo-inverse with floored eigenvalues) and the
 * mrcal-style projection uncertainty of each device. Every exception stops here. */
#include <algorithm>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <new>
#include <vector>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include "ceres-procam.h"
#ifdef IMPASTO_HAVE_CERES
#include <ceres/ceres.h>
#include "ceres-common.hpp"
#endif

#ifdef IMPASTO_HAVE_CERES
namespace {

using imp_ceres::NI;
using imp_ceres::NP;
using imp_ceres::project;

enum { CAM = 0, PROJ = 1 };
/* Parameter layout of the covariance: camera intrinsics, projector intrinsics, the
 * camera → projector pose, then one pose per view. */
constexpr int OFF_CAM = 0, OFF_PROJ = NI, OFF_EXT = 2 * NI, OFF_POSES = 2 * NI + NP;
/* Eigenvalues of the column-scaled normal matrix below this fraction of the largest are
 * floored (as cv-calib.cpp): huge, finite σ for what the views do not determine. */
constexpr double NORMAL_EIG_FLOOR_REL = 1e-12;

struct cam_cost {
        double X[3], u, v, w;
        template <typename T>
        bool operator()(const T *in, const T *pose, T *res) const {
                T P[3] = { T(X[0]), T(X[1]), T(X[2]) }, q[2];
                project(in, pose, P, q);
                res[0] = T(w) * (q[0] - T(u));
                res[1] = T(w) * (q[1] - T(v));
                return true;
        }
};

struct proj_cost {
        double X[3], u, v, w;
        template <typename T>
        bool operator()(const T *in, const T *pose, const T *ext, T *res) const {
                T P[3] = { T(X[0]), T(X[1]), T(X[2]) }, pc[3], q[2];
                ceres::AngleAxisRotatePoint(pose, P, pc);
                for (int k = 0; k < 3; k++)
                        pc[k] += pose[3 + k];
                project(in, ext, pc, q);
                res[0] = T(w) * (q[0] - T(u));
                res[1] = T(w) * (q[1] - T(v));
                return true;
        }
};

struct obs { int dev, view, index; };

struct joint {
        const struct imp_calib_view *views[2];
        int M;
        double intr[2][NI];
        bool fix_k3[2], fix_k2[2];
        double ext[NP];
        std::vector<double> poses;              /* NP per view */
        std::vector<obs> pts;                   /* camera points, then projector points */
        std::vector<uint8_t> inlier;
        double w[2] = { 1, 1 };                 /* 1/σ per device */

        const double *X(const obs &p) const { return views[p.dev][p.view].obj + 3 * p.index; }
        const double *m(const obs &p) const { return views[p.dev][p.view].img + 2 * p.index; }
        double residual(const obs &p) const {
                double q[2], pc[3];
                const double *pose = &poses[NP * (size_t) p.view];
                if (p.dev == CAM) {
                        project(intr[CAM], pose, X(p), q);
                } else {
                        imp_ceres::pose_apply(pose, X(p), pc);
                        project(intr[PROJ], ext, pc, q);
                }
                return std::hypot(q[0] - m(p)[0], q[1] - m(p)[1]);
        }
};

/* The problem over the inliers with weights b.w; loss[dev] may be null. The problem owns
 * the cost functions and losses. */
void build(joint &b, ceres::Problem &pb, ceres::LossFunction *loss[2], bool manifolds) {
        for (size_t i = 0; i < b.pts.size(); i++) {
                if (!b.inlier[i])
                        continue;
                const obs &p = b.pts[i];
                const double *X = b.X(p), *m = b.m(p);
                double *pose = &b.poses[NP * (size_t) p.view];
                if (p.dev == CAM)
                        pb.AddResidualBlock(new ceres::AutoDiffCostFunction<cam_cost, 2, NI, NP>(
                                                    new cam_cost{ { X[0], X[1], X[2] }, m[0], m[1], b.w[CAM] }),
                                            loss[CAM], b.intr[CAM], pose);
                else
                        pb.AddResidualBlock(new ceres::AutoDiffCostFunction<proj_cost, 2, NI, NP, NP>(
                                                    new proj_cost{ { X[0], X[1], X[2] }, m[0], m[1], b.w[PROJ] }),
                                            loss[PROJ], b.intr[PROJ], pose, b.ext);
        }
        for (int d = 0; manifolds && d < 2; d++) {
                std::vector<int> fixed;
                if (b.fix_k2[d])
                        fixed.push_back(5);
                if (b.fix_k3[d])
                        fixed.push_back(NI - 1);
                if (!fixed.empty() && pb.HasParameterBlock(b.intr[d]))
                        pb.SetManifold(b.intr[d], new ceres::SubsetManifold(NI, fixed));
        }
}

int solve(joint &b, const struct imp_ceres_calib_opts *o, bool *converged, int *iterations) {
        ceres::Problem pb;
        ceres::LossFunction *loss[2];
        for (int d = 0; d < 2; d++)     /* weighted units: the loss turns robust at loss_scale_px */
                loss[d] = imp_ceres::make_loss(o->loss, o->loss_scale_px * b.w[d]);
        build(b, pb, loss, true);
        ceres::Solver::Options so = imp_ceres::solver_options(o->max_iterations);
        ceres::Solver::Summary sum;
        ceres::Solve(so, &pb, &sum);
        *iterations += (int) sum.iterations.size();
        *converged = sum.termination_type == ceres::CONVERGENCE;
        return sum.IsSolutionUsable() ? 0 : -EDOM;
}

/* Per device: drops points whose residual exceeds max(k·σ_robust, min_px); returns how many. */
int reject(joint &b, int dev, const struct imp_ceres_calib_opts *o) {
        std::vector<double> e;
        std::vector<size_t> idx;
        for (size_t i = 0; i < b.pts.size(); i++)
                if (b.pts[i].dev == dev) {
                        e.push_back(b.residual(b.pts[i]));
                        idx.push_back(i);
                }
        if (e.empty())
                return 0;
        double limit = imp_ceres::outlier_limit(e, o);
        int n = 0;
        for (size_t k = 0; k < e.size(); k++)
                if (e[k] > limit) {
                        b.inlier[idx[k]] = 0;
                        n++;
                }
        return n;
}

/* RMS norm of device dev's inlier residuals (all points when all is set). */
double rms(const joint &b, int dev, bool all) {
        double s = 0;
        int n = 0;
        for (size_t i = 0; i < b.pts.size(); i++)
                if (b.pts[i].dev == dev && (all || b.inlier[i])) {
                        double e = b.residual(b.pts[i]);
                        s += e * e;
                        n++;
                }
        return std::sqrt(s / std::max(n, 1));
}

/* σ_w² (JᵀWJ)⁻¹ over all parameters (layout OFF_*), P_all × P_all with zero rows and columns
 * for held k3 and k2; *deficient when eigenvalues were floored or there are no degrees of freedom. */
std::vector<double> covariance(joint &b, bool *deficient, double *ret_s2) {
        ceres::Problem pb;
        ceres::LossFunction *none[2] = { nullptr, nullptr };
        build(b, pb, none, false);
        std::vector<double *> blocks{ b.intr[CAM], b.intr[PROJ], b.ext };
        for (int v = 0; v < b.M; v++)
                blocks.push_back(&b.poses[NP * (size_t) v]);
        const int P_all = OFF_POSES + NP * b.M;
        std::vector<int> col;                   /* estimated parameter → layout index */
        for (int k = 0; k < P_all; k++)
                if (!((k == OFF_CAM + NI - 1 && b.fix_k3[CAM]) || (k == OFF_PROJ + NI - 1 && b.fix_k3[PROJ]) ||
                      (k == OFF_CAM + 5 && b.fix_k2[CAM]) || (k == OFF_PROJ + 5 && b.fix_k2[PROJ])))
                        col.push_back(k);
        for (double *blk : blocks)              /* a block no residual uses (no projector points) */
                if (!pb.HasParameterBlock(blk))
                        pb.AddParameterBlock(blk, blk == b.intr[CAM] || blk == b.intr[PROJ] ? NI : NP);
        ceres::Problem::EvaluateOptions eo;
        eo.parameter_blocks = blocks;
        eo.apply_loss_function = false;
        eo.num_threads = 1;
        double cost = 0;
        std::vector<double> res;
        ceres::CRSMatrix crs;
        pb.Evaluate(eo, &cost, &res, nullptr, &crs);
        const int P = (int) col.size(), rows = crs.num_rows;
        std::vector<int> where((size_t) P_all, -1);
        for (int k = 0; k < P; k++)
                where[(size_t) col[k]] = k;
        cv::Mat J = cv::Mat::zeros(rows, P, CV_64F);
        for (int r = 0; r < rows; r++)
                for (int k = crs.rows[r]; k < crs.rows[r + 1]; k++)
                        if (where[(size_t) crs.cols[k]] >= 0)
                                J.at<double>(r, where[(size_t) crs.cols[k]]) = crs.values[k];
        double ssw = 0;
        for (double r : res)
                ssw += r * r;
        const int N = rows / 2, dof = N - P;       /* points, not coordinates: OpenCV's */
        const double s2 = ssw / std::max(dof, 1);
        *ret_s2 = s2;
        cv::Mat scale(P, 1, CV_64F);
        for (int c = 0; c < P; c++) {
                double n = cv::norm(J.col(c));
                scale.at<double>(c) = n > 0 ? 1.0 / n : 1.0;
                J.col(c) *= scale.at<double>(c);
        }
        cv::Mat JtJ = J.t() * J, evals, evecs;
        cv::eigen(JtJ, evals, evecs);
        double emax = std::max(evals.at<double>(0), DBL_MIN);
        *deficient = dof <= 0;
        cv::Mat inv_e(P, 1, CV_64F);
        for (int i = 0; i < P; i++) {
                double e = evals.at<double>(i);
                if (!(e >= emax * NORMAL_EIG_FLOOR_REL)) {
                        e = emax * NORMAL_EIG_FLOOR_REL;
                        *deficient = true;
                }
                inv_e.at<double>(i) = 1.0 / e;
        }
        cv::Mat ci = evecs.t() * cv::Mat::diag(inv_e) * evecs;
        std::vector<double> C((size_t) P_all * P_all, 0.0);
        for (int a = 0; a < P; a++)
                for (int c = 0; c < P; c++)
                        C[(size_t) col[a] * P_all + col[c]] =
                                s2 * ci.at<double>(a, c) * scale.at<double>(a) * scale.at<double>(c);
        return C;
}

/* The full parameter vector in the covariance's layout. */
std::vector<double> theta_of(const joint &b) {
        std::vector<double> t(b.intr[CAM], b.intr[CAM] + NI);
        t.insert(t.end(), b.intr[PROJ], b.intr[PROJ] + NI);
        t.insert(t.end(), b.ext, b.ext + NP);
        t.insert(t.end(), b.poses.begin(), b.poses.end());
        return t;
}

/* mrcal-style projection uncertainty (ceres-calib.cpp, docs/calibration.md) of device dev at
 * pixel (qx, qy), depth range in that device: the point is carried into every board's frame;
 * after a perturbation it comes back through the mean of the perturbed board poses (camera
 * frame), for the projector then through the perturbed camera → projector pose, and is
 * projected by the perturbed intrinsics. */
double mrcal_uncertainty(const joint &b, const std::vector<double> &C, int dev, double qx, double qy,
                         double range) {
        double pd[3], pc[3];
        imp_ceres::unproject(b.intr[dev], qx, qy, range, pd);
        if (dev == PROJ)
                imp_ceres::pose_inverse_apply(b.ext, pd, pc);
        else
                std::copy(pd, pd + 3, pc);
        const int M = b.M;
        std::vector<double> board((size_t) 3 * M);
        for (int v = 0; v < M; v++)
                imp_ceres::pose_inverse_apply(&b.poses[NP * (size_t) v], pc, &board[3 * (size_t) v]);
        return imp_ceres::propagate(theta_of(b), C, [&](const std::vector<double> &th, double out[2]) {
                double mean[3] = { 0, 0, 0 }, p[3];
                for (int v = 0; v < M; v++) {
                        imp_ceres::pose_apply(&th[OFF_POSES + NP * (size_t) v], &board[3 * (size_t) v], p);
                        for (int k = 0; k < 3; k++)
                                mean[k] += p[k] / M;
                }
                const double zero[NP] = { 0, 0, 0, 0, 0, 0 };
                if (dev == PROJ) {
                        imp_ceres::pose_apply(&th[OFF_EXT], mean, p);
                        project(&th[OFF_PROJ], zero, p, out);
                } else {
                        project(&th[OFF_CAM], zero, mean, out);
                }
        });
}

/* R (row-major) of a Rodrigues vector. */
void rotation(const double *r, double R[9]) {
        cv::Mat m;
        cv::Rodrigues(cv::Mat(3, 1, CV_64F, const_cast<double *>(r)), m);
        for (int i = 0; i < 9; i++)
                R[i] = m.at<double>(i / 3, i % 3);
}

/* Residual statistics, tilt, covariance blocks, flags and projection uncertainty of device
 * dev into r (which holds the refined intrinsics). C is the joint covariance, inflated here
 * for fx, fy when the tilt test fails. */
void assess_device(const joint &b, int dev, std::vector<double> &C, bool deficient, struct imp_calib_intrinsics *r) {
        imp_ceres::residual_stats(b, [&](size_t i) { return b.pts[i].dev == dev && b.inlier[i]; }, r);
        r->n_views = b.M;
        r->max_tilt_deg = 0;
        double Rext[9], range = 0;
        rotation(b.ext, Rext);
        for (int v = 0; v < b.M; v++) {
                const double *pose = &b.poses[NP * (size_t) v];
                double Rv[9], Rd[9], z = pose[5];
                rotation(pose, Rv);
                std::copy(Rv, Rv + 9, Rd);
                if (dev == PROJ) {
                        for (int i = 0; i < 3; i++)
                                for (int j = 0; j < 3; j++)
                                        Rd[3 * i + j] = Rext[3 * i] * Rv[j] + Rext[3 * i + 1] * Rv[3 + j] +
                                                        Rext[3 * i + 2] * Rv[6 + j];
                        z = Rext[6] * pose[3] + Rext[7] * pose[4] + Rext[8] * pose[5] + b.ext[5];
                }
                r->max_tilt_deg = std::max(r->max_tilt_deg, imp_ceres::tilt_deg(Rd));
                range += z / b.M;
        }
        const size_t P_all = OFF_POSES + NP * (size_t) b.M;
        const int off = dev == CAM ? OFF_CAM : OFF_PROJ;
        r->flags = deficient ? (unsigned) IMP_CALIB_RANK_DEFICIENT : 0u;
        for (int a = 0; a < NI; a++)
                for (int c = 0; c < NI; c++)
                        r->cov[a * NI + c] = C[(size_t) (off + a) * P_all + off + c];
        for (int a = 0; a < NI; a++)
                r->std[a] = std::sqrt(std::max(r->cov[a * NI + a], 0.0));
        if (r->max_tilt_deg < IMP_CALIB_MIN_TILT_DEG) {
                /* Boards square to the device: f/Z is a scale ambiguity and, with it, the principal
                 * point trades against the boards' sideways offsets, so the solve wanders along
                 * that valley and the local covariance means little (the stability test saw f at
                 * 9 % of the truth). σ(f) goes to |f|, σ(cx), σ(cy) to half the image at least. */
                r->flags |= IMP_CALIB_FOCAL_UNDETERMINED;
                const double floor_std[4] = { std::fabs(r->fx), std::fabs(r->fy), 0.5 * r->width, 0.5 * r->height };
                for (int i = 0; i < 4; i++) {
                        double s = std::max(floor_std[i], r->std[i]) / std::max(r->std[i], DBL_MIN);
                        r->std[i] *= s;
                        for (int k = 0; k < NI; k++) {
                                r->cov[i * NI + k] *= s;
                                r->cov[k * NI + i] *= s;
                        }
                        for (size_t k = 0; k < P_all; k++) {    /* the same in the joint covariance */
                                C[(size_t) (off + i) * P_all + k] *= s;
                                C[k * P_all + off + i] *= s;
                        }
                }
        }
        r->proj_unc_centre_px = mrcal_uncertainty(b, C, dev, (r->width - 1) / 2.0, (r->height - 1) / 2.0, range);
        r->proj_unc_corner_px = mrcal_uncertainty(b, C, dev, 0.0, 0.0, range);
        imp_calib_intrinsics_assess(r);
}

using imp_ceres::finite_all;

void intrinsics_from(const joint &b, int dev, struct imp_calib_intrinsics *r) {
        r->fx = b.intr[dev][0];
        r->fy = b.intr[dev][1];
        r->cx = b.intr[dev][2];
        r->cy = b.intr[dev][3];
        std::copy(b.intr[dev] + 4, b.intr[dev] + NI, r->dist);
        r->k3_fixed = b.fix_k3[dev];
        r->k2_fixed = b.fix_k2[dev];
}

/* Stereo figures: pose, RMS over both devices, worst per-view RMS, σ of the pose. */
void stereo_from(const joint &b, const std::vector<double> &C, struct imp_calib_stereo *s) {
        rotation(b.ext, s->R);
        std::copy(b.ext + 3, b.ext + 6, s->t);
        std::vector<double> ss((size_t) 2 * b.M, 0.0);
        std::vector<int> n((size_t) 2 * b.M, 0);
        double tot = 0;
        int nt = 0;
        for (size_t i = 0; i < b.pts.size(); i++) {
                if (!b.inlier[i])
                        continue;
                double e = b.residual(b.pts[i]);
                size_t k = 2 * (size_t) b.pts[i].view + (size_t) b.pts[i].dev;
                ss[k] += e * e;
                n[k]++;
                tot += e * e;
                nt++;
        }
        s->rms_px = std::sqrt(tot / std::max(nt, 1));
        s->worst_view_rms_px = -1;
        for (size_t k = 0; k < ss.size(); k++) {
                double r = std::sqrt(ss[k] / std::max(n[k], 1));
                if (r > s->worst_view_rms_px) {
                        s->worst_view_rms_px = r;
                        s->worst_view = (int) (k / 2);
                }
        }
        const size_t P_all = OFF_POSES + NP * (size_t) b.M;
        for (int a = 0; a < NP; a++)
                for (int c = 0; c < NP; c++)
                        s->cov[a * NP + c] = C[(size_t) (OFF_EXT + a) * P_all + OFF_EXT + c];
        for (int a = 0; a < 3; a++) {
                s->r_std_deg[a] = std::sqrt(std::max(s->cov[a * NP + a], 0.0)) * 180.0 / M_PI;
                s->t_std[a] = std::sqrt(std::max(s->cov[(3 + a) * NP + 3 + a], 0.0));
        }
        s->have_std = true;
}

int refine_cpp(const struct imp_calib_view *cam, const struct imp_calib_view *proj, int n_views,
               const struct imp_ceres_calib_opts *o, struct imp_calib_intrinsics *io_cam,
               struct imp_calib_intrinsics *io_proj, struct imp_calib_stereo *io_stereo, double *io_rvecs,
               double *io_tvecs, struct imp_ceres_procam_report *ret_report, struct imp_error *err) {
        joint b;
        b.views[CAM] = cam;
        b.views[PROJ] = proj;
        b.M = n_views;
        const struct imp_calib_intrinsics *in[2] = { io_cam, io_proj };
        for (int d = 0; d < 2; d++) {
                const double s[NI] = { in[d]->fx, in[d]->fy, in[d]->cx, in[d]->cy, in[d]->dist[0], in[d]->dist[1],
                                       in[d]->dist[2], in[d]->dist[3], in[d]->dist[4] };
                std::copy(s, s + NI, b.intr[d]);
                b.fix_k3[d] = in[d]->k3_fixed;
                b.fix_k2[d] = in[d]->k2_fixed;
        }
        cv::Mat rv;
        cv::Rodrigues(cv::Mat(3, 3, CV_64F, io_stereo->R), rv);
        for (int k = 0; k < 3; k++) {
                b.ext[k] = rv.at<double>(k);
                b.ext[3 + k] = io_stereo->t[k];
        }
        b.poses.resize((size_t) NP * n_views);
        for (int v = 0; v < n_views; v++)
                for (int k = 0; k < 3; k++) {
                        b.poses[NP * (size_t) v + k] = io_rvecs[3 * v + k];
                        b.poses[NP * (size_t) v + 3 + k] = io_tvecs[3 * v + k];
                }
        for (int d = 0; d < 2; d++)
                for (int v = 0; v < n_views; v++)
                        for (int i = 0; i < b.views[d][v].n; i++)
                                b.pts.push_back({ d, v, i });
        b.inlier.assign(b.pts.size(), 1);
        struct imp_ceres_procam_report rep = {};
        rep.initial_rms_cam_px = rms(b, CAM, true);
        rep.initial_rms_proj_px = rms(b, PROJ, true);

        if (solve(b, o, &rep.converged, &rep.iterations) < 0)
                return imp_error_set(err, -EDOM, "joint refinement: the solver gave no usable solution");
        if (o->outlier_sigmas > 0) {
                rep.n_outliers_cam = reject(b, CAM, o);
                rep.n_outliers_proj = reject(b, PROJ, o);
                for (int v = 0, base = 0; v < n_views; base += cam[v].n, v++) {
                        int kept = 0;
                        for (int i = 0; i < cam[v].n; i++)
                                kept += b.inlier[(size_t) base + i];
                        if (kept < 4)
                                return imp_error_set(err, -EDOM, "joint refinement: view %d keeps %d of %d "
                                                     "camera points after outlier rejection", v, kept, cam[v].n);
                }
        }
        /* Weights: each device's residual scale, so that neither dominates by its noise. */
        for (int d = 0; d < 2; d++) {
                double s = rms(b, d, false);
                b.w[d] = 1.0 / std::max(s, 1e-6);
        }
        rep.sigma_cam_px = 1 / b.w[CAM];
        rep.sigma_proj_px = 1 / b.w[PROJ];
        if (solve(b, o, &rep.converged, &rep.iterations) < 0)
                return imp_error_set(err, -EDOM, "joint refinement: the solver gave no usable solution "
                                     "after outlier rejection");
        if (!finite_all(b.intr[CAM], NI) || !finite_all(b.intr[PROJ], NI) || !finite_all(b.ext, NP) ||
            !finite_all(b.poses.data(), b.poses.size()) || !(b.intr[CAM][0] > 0) || !(b.intr[CAM][1] > 0) ||
            !(b.intr[PROJ][0] > 0) || !(b.intr[PROJ][1] > 0))
                return imp_error_set(err, -EDOM, "joint refinement gave a non-finite or non-positive result");

        bool deficient = false;
        double s2 = 1;
        std::vector<double> C = covariance(b, &deficient, &s2);
        rep.rank_deficient = deficient;
        struct imp_calib_intrinsics r[2] = { *io_cam, *io_proj };
        struct imp_calib_stereo st = *io_stereo;
        for (int d = 0; d < 2; d++) {
                intrinsics_from(b, d, &r[d]);
                assess_device(b, d, C, deficient, &r[d]);
                r[d].sigma_px = std::sqrt(s2) / b.w[d];   /* the σ the covariance used */
                r[d].ceres_refined = true;
                r[d].joint_refined = true;
                r[d].n_outliers = d == CAM ? rep.n_outliers_cam : rep.n_outliers_proj;
                if (!finite_all(r[d].std, NI) || !finite_all(r[d].cov, NI * NI) ||
                    !std::isfinite(r[d].proj_unc_centre_px) || !std::isfinite(r[d].proj_unc_corner_px))
                        return imp_error_set(err, -EDOM, "joint refinement: non-finite uncertainty");
        }
        stereo_from(b, C, &st);
        if (!finite_all(st.cov, 36) || !finite_all(st.R, 9))
                return imp_error_set(err, -EDOM, "joint refinement: non-finite pose uncertainty");
        *io_cam = r[CAM];
        *io_proj = r[PROJ];
        *io_stereo = st;
        for (int v = 0; v < n_views; v++)
                for (int k = 0; k < 3; k++) {
                        io_rvecs[3 * v + k] = b.poses[NP * (size_t) v + k];
                        io_tvecs[3 * v + k] = b.poses[NP * (size_t) v + 3 + k];
                }
        if (ret_report)
                *ret_report = rep;
        return 0;
}

}  // namespace
#endif

static bool views_ok(const struct imp_calib_view *v, int n, int min_points) {
        for (int i = 0; i < n; i++)
                if (v[i].n < min_points || (v[i].n > 0 && (!v[i].obj || !v[i].img)))
                        return false;
        return true;
}

extern "C" int imp_ceres_procam_refine(const struct imp_calib_view *cam, const struct imp_calib_view *proj,
                                       int n_views, const struct imp_ceres_calib_opts *opts,
                                       struct imp_calib_intrinsics *io_cam, struct imp_calib_intrinsics *io_proj,
                                       struct imp_calib_stereo *io_stereo, double *io_rvecs, double *io_tvecs,
                                       struct imp_ceres_procam_report *ret_report, struct imp_error *err) {
        if (!cam || !proj || n_views < 1 || !opts || !io_cam || !io_proj || !io_stereo || !io_rvecs || !io_tvecs ||
            io_cam->width < 1 || io_cam->height < 1 || io_proj->width < 1 || io_proj->height < 1 ||
            (opts->loss != IMP_CERES_LOSS_NONE && !(opts->loss_scale_px > 0)) || !(opts->outlier_sigmas >= 0))
                return imp_error_set(err, -EINVAL, "joint refinement: bad arguments");
        if (!views_ok(cam, n_views, 4) || !views_ok(proj, n_views, 0))
                return imp_error_set(err, -EINVAL, "joint refinement: every view needs at least 4 camera "
                                     "points");
#ifdef IMPASTO_HAVE_CERES
        try {
                return refine_cpp(cam, proj, n_views, opts, io_cam, io_proj, io_stereo, io_rvecs, io_tvecs,
                                  ret_report, err);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "joint refinement: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "joint refinement: %s", e.what());
        }
#else
        (void) ret_report;
        return imp_error_set(err, -EOPNOTSUPP, "joint refinement: impasto was built without Ceres "
                             "(IMPASTO_WITH_CERES off)");
#endif
}
