/* Projector–camera calibration over OpenCV (see cv-calib.h): corner detection, local
 * homographies from decoded Gray code, calibrateCamera / stereoCalibrate, and the
 * first-order covariance behind the reported uncertainties. Every OpenCV exception stops
 * at this boundary. */
#include <algorithm>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <new>
#include <string>
#include <vector>
#include <sys/stat.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/structured_light.hpp>
#include "ceres-calib.h"
#include "ceres-procam.h"
#include "cv-calib.h"
#include "cv-graycode.h"

namespace {

/* Eigenvalues of the column-scaled normal matrix below this fraction of the largest are
 * treated as zero: the pseudo-inverse then floors them here, so the corresponding
 * uncertainties come out huge (and finite) instead of NaN or silently small. */
constexpr double NORMAL_EIG_FLOOR_REL = 1e-12;
/* RANSAC reprojection threshold of the local homographies, projector pixels: decoded
 * coordinates are integers (±0.5 px quantisation) plus a little noise; decoding errors at
 * code transitions are far larger. */
constexpr double HOMOGRAPHY_RANSAC_PX = 2.0;
/* cornerSubPix half window (pixels) and stopping rule. */
constexpr int SUBPIX_HALF_PX = 5;

bool is_u8_gray(const struct imp_image *im) {
        return im && im->data && im->type == IMP_PIX_U8 && im->channels == 1;
}

cv::Mat wrap(const struct imp_image *im) {
        return cv::Mat(im->height, im->width, CV_8UC1, im->data, im->stride);
}

bool all_finite(const cv::Mat &m) {
        return cv::checkRange(m, true, nullptr, -DBL_MAX, DBL_MAX);
}

std::vector<cv::Point3f> obj_points(const struct imp_calib_view &v) {
        std::vector<cv::Point3f> o((size_t) v.n);
        for (int i = 0; i < v.n; i++)
                o[i] = cv::Point3f((float) v.obj[3 * i], (float) v.obj[3 * i + 1], (float) v.obj[3 * i + 2]);
        return o;
}

std::vector<cv::Point2f> img_points(const struct imp_calib_view &v) {
        std::vector<cv::Point2f> p((size_t) v.n);
        for (int i = 0; i < v.n; i++)
                p[i] = cv::Point2f((float) v.img[2 * i], (float) v.img[2 * i + 1]);
        return p;
}

/* Covariance of the estimated parameters [fx fy cx cy k1 k2 p1 p2 (k3) | r0 t0 | r1 t1 …]
 * as σ² (JᵀJ)⁻¹, J from projectPoints' analytic derivatives at the solution; n_intr is 8
 * when k3 was held fixed (its column is left out, its row and column of cov are 0). Columns
 * are scaled to unit norm before the (pseudo-)inverse; returns true when JᵀJ was rank
 * deficient and eigenvalues had to be floored. Also fills rms, worst residual, σ. */
bool covariance(const std::vector<std::vector<cv::Point3f>> &obj,
                const std::vector<std::vector<cv::Point2f>> &img, const cv::Mat &K, const cv::Mat &D,
                const std::vector<cv::Mat> &rv, const std::vector<cv::Mat> &tv, unsigned fit,
                struct imp_calib_intrinsics *out) {
        std::vector<int> est;                   /* the estimated intrinsics, OpenCV's order */
        for (int c = 0; c < IMP_CALIB_N_INTR; c++)
                if (!((c == 5 && (fit & IMP_CALIB_FIT_FIX_K2)) || (c == 8 && (fit & IMP_CALIB_FIT_FIX_K3))))
                        est.push_back(c);
        const int n_intr = (int) est.size(), M = (int) obj.size(), P = n_intr + 6 * M;
        int N = 0;
        for (const auto &o : obj)
                N += (int) o.size();
        cv::Mat J = cv::Mat::zeros(2 * N, P, CV_64F);
        double sse = 0, worst = -1;
        int row = 0;
        for (int v = 0; v < M; v++) {
                std::vector<cv::Point2f> proj;
                cv::Mat jac;
                cv::projectPoints(obj[v], rv[v], tv[v], K, D, proj, jac);
                for (size_t i = 0; i < proj.size(); i++) {
                        double dx = proj[i].x - img[v][i].x, dy = proj[i].y - img[v][i].y;
                        double e2 = dx * dx + dy * dy;
                        sse += e2;
                        if (e2 > worst) {
                                worst = e2;
                                out->worst_view = v;
                                out->worst_point = (int) i;
                        }
                        for (int k = 0; k < 2; k++) {
                                const double *jr = jac.ptr<double>((int) (2 * i + k));
                                double *Jr = J.ptr<double>(row + (int) (2 * i + k));
                                for (int c = 0; c < n_intr; c++)
                                        Jr[c] = jr[6 + est[c]];     /* f(2) c(2) dist(3 to 5) */
                                for (int c = 0; c < 6; c++)
                                        Jr[n_intr + 6 * v + c] = jr[c];   /* r(3) t(3) */
                        }
                }
                row += 2 * (int) proj.size();
        }
        out->n_points = N;
        out->rms_px = std::sqrt(sse / std::max(N, 1));
        out->worst_px = std::sqrt(std::max(worst, 0.0));
        /* OpenCV's convention (calibrateCamera's stdDeviations*): σ² = Σr² / (N − P) with N
         * counting points, not coordinates. The textbook 2N − P would give std smaller by
         * √((2N − P)/(N − P)) (≈ 1.46 on the real captures); we keep OpenCV's, conservative,
         * so that std and cov agree. */
        int dof = N - P;
        double sigma2 = sse / std::max(dof, 1);
        out->sigma_px = std::sqrt(sigma2);

        cv::Mat scale(P, 1, CV_64F);
        for (int c = 0; c < P; c++) {
                double n = cv::norm(J.col(c));
                scale.at<double>(c) = n > 0 ? 1.0 / n : 1.0;
        }
        for (int c = 0; c < P; c++)
                J.col(c) *= scale.at<double>(c);
        cv::Mat JtJ = J.t() * J, evals, evecs;
        cv::eigen(JtJ, evals, evecs);                      /* descending */
        double emax = std::max(evals.at<double>(0), DBL_MIN);
        bool deficient = dof <= 0;
        cv::Mat inv_e(P, 1, CV_64F);
        for (int i = 0; i < P; i++) {
                double e = evals.at<double>(i);
                if (!(e >= emax * NORMAL_EIG_FLOOR_REL)) {
                        e = emax * NORMAL_EIG_FLOOR_REL;
                        deficient = true;
                }
                inv_e.at<double>(i) = 1.0 / e;
        }
        cv::Mat cov = evecs.t() * cv::Mat::diag(inv_e) * evecs;
        std::fill(out->cov, out->cov + IMP_CALIB_N_INTR * IMP_CALIB_N_INTR, 0.0);   /* fixed: 0 */
        for (int a = 0; a < n_intr; a++)
                for (int b = 0; b < n_intr; b++)
                        out->cov[est[a] * IMP_CALIB_N_INTR + est[b]] =
                                sigma2 * cov.at<double>(a, b) * scale.at<double>(a) * scale.at<double>(b);
        return deficient;
}

/* 1σ, worst direction, of where the camera-frame point seen at pixel q reprojects when
 * the intrinsics vary with covariance cov (first order). */
double projection_uncertainty(const cv::Mat &K, const cv::Mat &D, const double *cov, double qx, double qy) {
        std::vector<cv::Point2f> q{ cv::Point2f((float) qx, (float) qy) }, n;
        cv::undistortPoints(q, n, K, D, cv::noArray(), cv::noArray(),
                            cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 100, 1e-12));
        std::vector<cv::Point3f> P{ cv::Point3f(n[0].x, n[0].y, 1.0f) };
        std::vector<cv::Point2f> out;
        cv::Mat jac, zero = cv::Mat::zeros(3, 1, CV_64F);
        cv::projectPoints(P, zero, zero, K, D, out, jac);
        cv::Mat Jt = jac(cv::Rect(6, 0, IMP_CALIB_N_INTR, 2)).clone();
        cv::Mat C(IMP_CALIB_N_INTR, IMP_CALIB_N_INTR, CV_64F, const_cast<double *>(cov));
        cv::Mat S = Jt * C * Jt.t(), ev;
        cv::eigen(S, ev);
        return std::sqrt(std::max(ev.at<double>(0), 0.0));
}

int intrinsics_cpp(const struct imp_calib_view *views, int n_views, int width, int height,
                   unsigned fit, struct imp_calib_intrinsics *ret, double *ret_rvecs, double *ret_tvecs,
                   struct imp_error *err) {
        std::vector<std::vector<cv::Point3f>> obj;
        std::vector<std::vector<cv::Point2f>> img;
        for (int v = 0; v < n_views; v++) {
                obj.push_back(obj_points(views[v]));
                img.push_back(img_points(views[v]));
        }
        cv::Mat K, D, stdI, stdE, perView;
        std::vector<cv::Mat> rv, tv;
        double rms;
        const bool fix_k3 = fit & IMP_CALIB_FIT_FIX_K3, fix_k2 = fit & IMP_CALIB_FIT_FIX_K2;
        try {
                rms = cv::calibrateCamera(obj, img, cv::Size(width, height), K, D, rv, tv, stdI, stdE,
                                          perView, (fix_k3 ? cv::CALIB_FIX_K3 : 0) | (fix_k2 ? cv::CALIB_FIX_K2 : 0),
                                          cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS,
                                                           100, DBL_EPSILON));
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "calibrateCamera failed on %d views (the data do not "
                                     "determine the intrinsics): %s", n_views, e.what());
        }
        K.convertTo(K, CV_64F);
        D.convertTo(D, CV_64F);
        D = D.reshape(1, 1);
        if (!std::isfinite(rms) || !all_finite(K) || !all_finite(D) || D.cols < 5 ||
            K.at<double>(0, 0) <= 0 || K.at<double>(1, 1) <= 0)
                return imp_error_set(err, -EDOM, "calibrateCamera gave a non-finite or non-positive "
                                     "result on %d views: the views do not determine the intrinsics",
                                     n_views);
        for (int v = 0; v < n_views; v++)
                if (!all_finite(rv[v]) || !all_finite(tv[v]))
                        return imp_error_set(err, -EDOM, "calibrateCamera gave a non-finite pose for "
                                             "view %d", v);

        struct imp_calib_intrinsics r = {};
        r.width = width;
        r.height = height;
        r.fx = K.at<double>(0, 0);
        r.fy = K.at<double>(1, 1);
        r.cx = K.at<double>(0, 2);
        r.cy = K.at<double>(1, 2);
        for (int i = 0; i < 5; i++)
                r.dist[i] = D.at<double>(0, i);
        r.n_views = n_views;
        r.k3_fixed = fix_k3;
        r.k2_fixed = fix_k2;
        if (covariance(obj, img, K, D, rv, tv, fit, &r))
                r.flags |= IMP_CALIB_RANK_DEFICIENT;
        /* OpenCV's own std (same σ² and J up to scaling); ours where it is not finite. */
        stdI.convertTo(stdI, CV_64F);
        for (int i = 0; i < IMP_CALIB_N_INTR; i++) {
                double s = i < (int) stdI.total() ? stdI.at<double>(i) : NAN;
                double mine = std::sqrt(std::max(r.cov[i * IMP_CALIB_N_INTR + i], 0.0));
                if (!std::isfinite(s) || (r.flags & IMP_CALIB_RANK_DEFICIENT))
                        s = mine;
                r.std[i] = (fix_k3 && i == 8) || (fix_k2 && i == 5) ? 0.0 : s;   /* fixed: not estimated */
        }
        /* Tilt of each board: angle between its normal (R's third column) and the axis. */
        for (int v = 0; v < n_views; v++) {
                cv::Mat Rv;
                cv::Rodrigues(rv[v], Rv);
                double c = std::fabs(Rv.at<double>(2, 2));
                r.max_tilt_deg = std::max(r.max_tilt_deg, std::acos(std::min(c, 1.0)) * 180.0 / M_PI);
        }
        if (r.max_tilt_deg < IMP_CALIB_MIN_TILT_DEG) {
                r.flags |= IMP_CALIB_FOCAL_UNDETERMINED;
                imp_calib_inflate_focal(&r);
        }
        r.proj_unc_centre_px = projection_uncertainty(K, D, r.cov, (width - 1) / 2.0, (height - 1) / 2.0);
        r.proj_unc_corner_px = projection_uncertainty(K, D, r.cov, 0.0, 0.0);
        if (!std::isfinite(r.proj_unc_centre_px) || !std::isfinite(r.proj_unc_corner_px))
                return imp_error_set(err, -EDOM, "projection uncertainty is not finite");
        imp_calib_intrinsics_assess(&r);
        if (ret_rvecs && ret_tvecs)
                for (int v = 0; v < n_views; v++)
                        for (int k = 0; k < 3; k++) {
                                ret_rvecs[3 * v + k] = rv[v].at<double>(k);
                                ret_tvecs[3 * v + k] = tv[v].at<double>(k);
                        }
        *ret = r;
        return 0;
}

cv::Mat K_of(const struct imp_calib_intrinsics *in) {
        return (cv::Mat_<double>(3, 3) << in->fx, 0, in->cx, 0, in->fy, in->cy, 0, 0, 1);
}

cv::Mat D_of(const struct imp_calib_intrinsics *in) {
        return cv::Mat(1, 5, CV_64F, const_cast<double *>(in->dist)).clone();
}

}  // namespace

extern "C" int imp_cv_calib_find_corners(const struct imp_image *img, int cols, int rows,
                                         double *ret_px, struct imp_error *err) {
        if (!is_u8_gray(img) || cols < 2 || rows < 2 || !ret_px)
                return imp_error_set(err, -EINVAL, "chessboard: bad arguments (u8 grey image and "
                                     ">= 2x2 inner corners expected)");
        std::vector<cv::Point2f> c;
        try {
                cv::Mat m = wrap(img);
                bool found = cv::findChessboardCorners(m, cv::Size(cols, rows), c,
                                                       cv::CALIB_CB_ADAPTIVE_THRESH |
                                                       cv::CALIB_CB_NORMALIZE_IMAGE);
                if (!found || (int) c.size() != cols * rows)
                        return imp_error_set(err, -ENOENT, "no chessboard with %dx%d inner corners found",
                                             cols, rows);
                cv::cornerSubPix(m, c, cv::Size(SUBPIX_HALF_PX, SUBPIX_HALF_PX), cv::Size(-1, -1),
                                 cv::TermCriteria(cv::TermCriteria::COUNT + cv::TermCriteria::EPS, 50, 1e-3));
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "chessboard: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "chessboard: %s", e.what());
        }
        for (size_t i = 0; i < c.size(); i++) {
                ret_px[2 * i] = c[i].x;
                ret_px[2 * i + 1] = c[i].y;
        }
        return 0;
}

extern "C" int imp_cv_calib_points_to_projector(int proj_w, int proj_h, const struct imp_image *const *frames,
                                                size_t n_frames, const struct imp_image *white,
                                                const struct imp_image *black, int black_threshold,
                                                int white_threshold, int half_px, const double *cam_px,
                                                int n, double *ret_proj, uint8_t *ret_ok, int *ret_n_decoded,
                                                struct imp_error *err) {
        if (proj_w < 1 || proj_h < 1 || !frames || !is_u8_gray(white) || !is_u8_gray(black) ||
            black->width != white->width || black->height != white->height || half_px < 1 ||
            !cam_px || n < 0 || !ret_proj || !ret_ok || black_threshold < 0 || white_threshold < 0)
                return imp_error_set(err, -EINVAL, "local homographies: bad arguments");
        for (size_t i = 0; i < n_frames; i++)
                if (!is_u8_gray(frames[i]) || frames[i]->width != white->width ||
                    frames[i]->height != white->height)
                        return imp_error_set(err, -EINVAL, "local homographies: frame %zu is not u8 "
                                             "grey %dx%d", i, white->width, white->height);
        std::vector<double> proj((size_t) 2 * n, -1.0);
        std::vector<uint8_t> ok((size_t) n, 0);
        int n_decoded = 0;
        try {
                auto g = cv::structured_light::GrayCodePattern::create(proj_w, proj_h);
                if (n_frames != g->getNumberOfPatternImages())
                        return imp_error_set(err, -EINVAL, "local homographies: %zu frames, a %dx%d "
                                             "projector needs %zu", n_frames, proj_w, proj_h,
                                             (size_t) g->getNumberOfPatternImages());
                g->setBlackThreshold((size_t) black_threshold);
                g->setWhiteThreshold((size_t) white_threshold);
                std::vector<cv::Mat> mats;
                for (size_t i = 0; i < n_frames; i++)
                        mats.push_back(wrap(frames[i]));
                cv::Mat wm = wrap(white), bm = wrap(black);
                const int W = white->width, H = white->height;
                for (int i = 0; i < n; i++) {
                        int cx = (int) std::lround(cam_px[2 * i]), cy = (int) std::lround(cam_px[2 * i + 1]);
                        std::vector<cv::Point2f> src, dst;
                        for (int y = std::max(cy - half_px, 0); y <= std::min(cy + half_px, H - 1); y++)
                                for (int x = std::max(cx - half_px, 0); x <= std::min(cx + half_px, W - 1); x++) {
                                        if ((int) wm.at<uint8_t>(y, x) - (int) bm.at<uint8_t>(y, x) <= black_threshold)
                                                continue;
                                        cv::Point pp;
                                        if (g->getProjPixel(mats, x, y, pp))
                                                continue;       /* true means "not decoded" */
                                        src.emplace_back((float) x, (float) y);
                                        dst.emplace_back((float) pp.x, (float) pp.y);
                                }
                        n_decoded += (int) src.size();
                        if ((int) src.size() < half_px * half_px)
                                continue;
                        cv::Mat Hm = cv::findHomography(src, dst, cv::RANSAC, HOMOGRAPHY_RANSAC_PX);
                        if (Hm.empty() || !all_finite(Hm))
                                continue;
                        std::vector<cv::Point2d> in{ cv::Point2d(cam_px[2 * i], cam_px[2 * i + 1]) }, out;
                        cv::perspectiveTransform(in, out, Hm);
                        if (!std::isfinite(out[0].x) || !std::isfinite(out[0].y))
                                continue;
                        proj[2 * i] = out[0].x;
                        proj[2 * i + 1] = out[0].y;
                        ok[i] = 1;
                }
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "local homographies: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "local homographies: %s", e.what());
        }
        std::copy(proj.begin(), proj.end(), ret_proj);
        std::copy(ok.begin(), ok.end(), ret_ok);
        if (ret_n_decoded)
                *ret_n_decoded = n_decoded;
        return 0;
}

extern "C" int imp_cv_calib_intrinsics(const struct imp_calib_view *views, int n_views, int width,
                                       int height, struct imp_calib_intrinsics *ret, double *ret_rvecs,
                                       double *ret_tvecs, struct imp_error *err) {
        return imp_cv_calib_intrinsics_fit(views, n_views, width, height, 0, ret, ret_rvecs, ret_tvecs, err);
}

extern "C" int imp_cv_calib_intrinsics_fit(const struct imp_calib_view *views, int n_views, int width,
                                           int height, unsigned fit, struct imp_calib_intrinsics *ret,
                                           double *ret_rvecs, double *ret_tvecs, struct imp_error *err) {
        if (!views || n_views < 1 || width < 1 || height < 1 || !ret)
                return imp_error_set(err, -EINVAL, "calibration: bad arguments");
        for (int v = 0; v < n_views; v++) {
                if (views[v].n < 4 || !views[v].obj || !views[v].img)
                        return imp_error_set(err, -EINVAL, "calibration: view %d has %d points, at "
                                             "least 4 needed", v, views[v].n);
                for (int i = 0; i < 3 * views[v].n; i++)
                        if (!std::isfinite(views[v].obj[i]))
                                return imp_error_set(err, -EINVAL, "calibration: view %d: object point "
                                                     "%d is not finite", v, i / 3);
                for (int i = 0; i < 2 * views[v].n; i++)
                        if (!std::isfinite(views[v].img[i]))
                                return imp_error_set(err, -EINVAL, "calibration: view %d: image point "
                                                     "%d is not finite", v, i / 2);
        }
        try {
                return intrinsics_cpp(views, n_views, width, height, fit, ret, ret_rvecs, ret_tvecs, err);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "calibration: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "calibration: %s", e.what());
        }
}

extern "C" int imp_cv_calib_stereo(const struct imp_calib_view *views_a, const struct imp_calib_view *views_b,
                                   int n_views, const struct imp_calib_intrinsics *a,
                                   const struct imp_calib_intrinsics *b, struct imp_calib_stereo *ret,
                                   struct imp_error *err) {
        if (!views_a || !views_b || n_views < 1 || !a || !b || !ret)
                return imp_error_set(err, -EINVAL, "stereo calibration: bad arguments");
        std::vector<std::vector<cv::Point3f>> obj;
        std::vector<std::vector<cv::Point2f>> ia, ib;
        for (int v = 0; v < n_views; v++) {
                if (views_a[v].n != views_b[v].n || views_a[v].n < 4)
                        return imp_error_set(err, -EINVAL, "stereo calibration: view %d: %d and %d "
                                             "points (equal and >= 4 expected)", v, views_a[v].n,
                                             views_b[v].n);
                obj.push_back(obj_points(views_a[v]));
                ia.push_back(img_points(views_a[v]));
                ib.push_back(img_points(views_b[v]));
        }
        struct imp_calib_stereo r = {};
        try {
                cv::Mat KA = K_of(a), DA = D_of(a), KB = K_of(b), DB = D_of(b), R, T, E, F, perView;
                r.rms_px = cv::stereoCalibrate(obj, ia, ib, KA, DA, KB, DB, cv::Size(a->width, a->height),
                                               R, T, E, F, perView, cv::CALIB_FIX_INTRINSIC,
                                               cv::TermCriteria(cv::TermCriteria::COUNT +
                                                                cv::TermCriteria::EPS, 100, 1e-10));
                R.convertTo(R, CV_64F);
                T.convertTo(T, CV_64F);
                perView.convertTo(perView, CV_64F);
                if (!std::isfinite(r.rms_px) || !all_finite(R) || !all_finite(T))
                        return imp_error_set(err, -EDOM, "stereoCalibrate gave a non-finite pose");
                for (int i = 0; i < 9; i++)
                        r.R[i] = R.at<double>(i / 3, i % 3);
                for (int i = 0; i < 3; i++)
                        r.t[i] = T.at<double>(i);
                r.worst_view_rms_px = -1;
                for (int v = 0; v < perView.rows; v++)
                        for (int c = 0; c < perView.cols; c++)
                                if (perView.at<double>(v, c) > r.worst_view_rms_px) {
                                        r.worst_view_rms_px = perView.at<double>(v, c);
                                        r.worst_view = v;
                                }
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "stereo calibration: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "stereo calibration: %s", e.what());
        }
        *ret = r;
        return 0;
}

/* ---- the whole procedure on capture directories ---- */

namespace {

void copy_str(char *dst, size_t size, const std::string &s) {
        size_t n = std::min(s.size(), size - 1);
        memcpy(dst, s.data(), n);
        dst[n] = 0;
}

struct images {
        std::vector<struct imp_image *> v;
        ~images() {
                for (auto *im : v)
                        imp_image_free(im);
        }
};

int load_frame(const std::string &dir, int idx, struct imp_image **ret, struct imp_error *err) {
        char name[32];
        snprintf(name, sizeof name, "/graycode_%02d.png", idx);
        std::string path = dir + name;
        struct imp_image *im = nullptr;
        int r = imp_png_read(path.c_str(), &im, err);
        if (r < 0)
                return r;
        if (!is_u8_gray(im)) {
                imp_image_free(im);
                return imp_error_set(err, -EMEDIUMTYPE, "%s: expected an 8-bit greyscale PNG (%s, %d "
                                     "channels)", path.c_str(), imp_pixel_type_name(im->type), im->channels);
        }
        *ret = im;
        return 0;
}

/* The directory layout of the real captures: DIR/graycode_NN.png. */
int dir_loader(void *user, int capture, int index, struct imp_image **ret, struct imp_error *err) {
        const char *const *dirs = (const char *const *) user;
        return load_frame(dirs[capture], index, ret, err);
}

/* Labels the corners consistently (calib.h, orient_board): board x × y must point at the
 * camera — in image coordinates (y down) the cross product of the x and y directions is
 * then negative — and the square between corners 0, 1, cols, cols + 1 must be the darker
 * of it and its right-hand neighbour. */
void orient_corners(const cv::Mat &white, int cols, int rows, std::vector<double> &c) {
        auto P = [&](int i, int k) { return c[2 * (size_t) i + k]; };
        double dx[2] = { P(1, 0) - P(0, 0), P(1, 1) - P(0, 1) };
        double dy[2] = { P(cols, 0) - P(0, 0), P(cols, 1) - P(0, 1) };
        if (dx[0] * dy[1] - dx[1] * dy[0] > 0)
                for (int j = 0; j < rows; j++)
                        for (int i = 0; i < cols / 2; i++)
                                for (int k = 0; k < 2; k++)
                                        std::swap(c[2 * (size_t) (j * cols + i) + k],
                                                  c[2 * (size_t) (j * cols + cols - 1 - i) + k]);
        auto quad_mean = [&](int i0) {
                double x = 0.25 * (P(i0, 0) + P(i0 + 1, 0) + P(i0 + cols, 0) + P(i0 + cols + 1, 0));
                double y = 0.25 * (P(i0, 1) + P(i0 + 1, 1) + P(i0 + cols, 1) + P(i0 + cols + 1, 1));
                int xi = (int) std::lround(x), yi = (int) std::lround(y), n = 0;
                double s = 0;
                for (int v = yi - 1; v <= yi + 1; v++)
                        for (int u = xi - 1; u <= xi + 1; u++)
                                if (u >= 0 && v >= 0 && u < white.cols && v < white.rows) {
                                        s += white.at<uint8_t>(v, u);
                                        n++;
                                }
                return n ? s / n : 0.0;
        };
        if (cols >= 3 && quad_mean(0) > quad_mean(1)) {
                size_t n = (size_t) cols * rows;
                for (size_t i = 0; i < n / 2; i++)
                        for (int k = 0; k < 2; k++)
                                std::swap(c[2 * i + k], c[2 * (n - 1 - i) + k]);
        }
}

struct capture_points {
        std::vector<double> obj;                 /* all corners, 3 per corner */
        std::vector<double> cam;                 /* 2 per corner */
        std::vector<double> obj_p, cam_p, proj;  /* the corners that got a projector coordinate */
};

/* One capture: -errno on bad input (missing/unreadable file, size mismatch); 1 when the
 * capture is to be skipped (cap->why says why); 0 when used. */
struct source {
        imp_calib_frame_loader load;
        void *user;
        bool png_dirs;                           /* names are graycode_NN.png directories */
};

int load_u8(const source &src, int capture, int index, struct imp_image **ret, struct imp_error *err) {
        int r = src.load(src.user, capture, index, ret, err);
        if (r < 0)
                return r;
        if (!is_u8_gray(*ret)) {
                imp_image_free(*ret);
                *ret = nullptr;
                return imp_error_set(err, -EMEDIUMTYPE, "capture %d frame %d: the loader gave no u8 grey "
                                     "image", capture, index);
        }
        return 0;
}

int do_capture(const source &src, int idx, const char *dir, const struct imp_calib_procam_opts *o, int n_pat,
               int *cam_w, int *cam_h, int *half_px, struct imp_calib_capture *cap, capture_points *pts,
               std::vector<double> *ret_corners, struct imp_error *err) {
        struct stat st;
        if (src.png_dirs && (stat(dir, &st) < 0 || !S_ISDIR(st.st_mode)))
                return imp_error_set(err, -ENOENT, "capture %s: not a directory (expected "
                                     "graycode_00.png … graycode_%02d.png in it)", dir, n_pat + 1);
        images im;
        im.v.assign((size_t) n_pat + 2, nullptr);
        int r = load_u8(src, idx, n_pat, &im.v[n_pat], err);           /* white */
        if (r < 0)
                return r;
        r = load_u8(src, idx, n_pat + 1, &im.v[n_pat + 1], err);       /* black */
        if (r < 0)
                return r;
        const struct imp_image *white = im.v[n_pat], *black = im.v[n_pat + 1];
        if (*cam_w == 0) {
                *cam_w = white->width;
                *cam_h = white->height;
                if (*half_px <= 0)
                        *half_px = (int) std::ceil(white->width / 180.0);   /* procam-calibration's */
        }
        if (white->width != *cam_w || white->height != *cam_h || black->width != *cam_w ||
            black->height != *cam_h)
                return imp_error_set(err, -EINVAL, "capture %s: images are %dx%d, the first capture's "
                                     "are %dx%d", dir, white->width, white->height, *cam_w, *cam_h);
        const int nc = o->board_cols * o->board_rows;
        std::vector<double> corners((size_t) 2 * nc);
        struct imp_error cerr = {};
        r = imp_cv_calib_find_corners(white, o->board_cols, o->board_rows, corners.data(), &cerr);
        char wname[32] = " (white frame)";
        if (src.png_dirs)
                snprintf(wname, sizeof wname, "/graycode_%02d.png", n_pat);
        if (r == -ENOENT) {
                copy_str(cap->why, sizeof cap->why, std::string(dir) + wname + (src.png_dirs ? " (white frame): " : ": ") + cerr.msg);
                return 1;
        }
        if (r < 0)
                return imp_error_set(err, r, "%s%s: %s", dir, wname, cerr.msg);
        if (o->orient_board)
                orient_corners(wrap(white), o->board_cols, o->board_rows, corners);
        cap->n_corners_cam = nc;
        for (int i = 0; i < n_pat; i++) {
                r = load_u8(src, idx, i, &im.v[i], err);
                if (r < 0)
                        return r;
                if (im.v[i]->width != *cam_w || im.v[i]->height != *cam_h)
                        return imp_error_set(err, -EINVAL, "%s/graycode_%02d.png: %dx%d, expected %dx%d",
                                             dir, i, im.v[i]->width, im.v[i]->height, *cam_w, *cam_h);
        }
        std::vector<double> proj((size_t) 2 * nc);
        std::vector<uint8_t> ok((size_t) nc);
        r = imp_cv_calib_points_to_projector(o->proj_w, o->proj_h, im.v.data(), (size_t) n_pat, white,
                                             black, o->black_threshold, o->white_threshold, *half_px,
                                             corners.data(), nc, proj.data(), ok.data(),
                                             &cap->n_decoded_px, err);
        if (r < 0)
                return imp_error_prefix(err, "capture %s: ", dir);
        for (int i = 0; i < nc; i++) {
                double X = o->square * (i % o->board_cols), Y = o->square * (i / o->board_cols);
                pts->obj.insert(pts->obj.end(), { X, Y, 0.0 });
                pts->cam.insert(pts->cam.end(), { corners[2 * i], corners[2 * i + 1] });
                if (!ok[i])
                        continue;
                cap->n_corners_proj++;
                pts->obj_p.insert(pts->obj_p.end(), { X, Y, 0.0 });
                pts->cam_p.insert(pts->cam_p.end(), { corners[2 * i], corners[2 * i + 1] });
                pts->proj.insert(pts->proj.end(), { proj[2 * i], proj[2 * i + 1] });
        }
        *ret_corners = corners;
        if (cap->n_corners_proj < 4) {
                copy_str(cap->why, sizeof cap->why, "capture " + std::string(dir) + ": only " +
                         std::to_string(cap->n_corners_proj) + " of " + std::to_string(nc) +
                         " corners got a projector coordinate (too few decoded pixels within ±" +
                         std::to_string(*half_px) + " px; check the black/white thresholds)");
                return 1;
        }
        return 0;
}

void warn_flags(struct imp_calib_procam *r, const struct imp_calib_intrinsics *in, const char *who) {
        char buf[1024];
        if (imp_calib_flags_describe(in, who, buf, sizeof buf) <= 0)
                return;
        for (char *line = strtok(buf, "\n"); line; line = strtok(nullptr, "\n"))
                imp_calib_warn(r, "%s", line);
}

/* Camera pose in the canvas frame from the reference view (calib.h): solvePnP with the
 * estimated intrinsics on the board corners shifted by board_origin. */
int world_pose(const struct imp_calib_procam_opts *o, const std::vector<double> &corners,
               struct imp_calib_procam *res, struct imp_error *err) {
        const int nc = o->board_cols * o->board_rows;
        std::vector<cv::Point3d> obj;
        std::vector<cv::Point2d> img;
        for (int i = 0; i < nc; i++) {
                obj.emplace_back(o->board_origin[0] + o->square * (i % o->board_cols),
                                 o->board_origin[1] + o->square * (i / o->board_cols), 0.0);
                img.emplace_back(corners[2 * i], corners[2 * i + 1]);
        }
        cv::Mat K = K_of(&res->camera), D = D_of(&res->camera), rv, tv, R;
        if (!cv::solvePnP(obj, img, K, D, rv, tv, false, cv::SOLVEPNP_ITERATIVE))
                return imp_error_set(err, -EDOM, "reference view: solvePnP failed");
        cv::solvePnPRefineLM(obj, img, K, D, rv, tv);
        cv::Rodrigues(rv, R);
        R.convertTo(R, CV_64F);
        tv.convertTo(tv, CV_64F);
        if (!all_finite(R) || !all_finite(tv))
                return imp_error_set(err, -EDOM, "reference view: non-finite pose");
        std::vector<cv::Point2d> proj;
        cv::projectPoints(obj, rv, tv, K, D, proj);
        double ss = 0;
        for (int i = 0; i < nc; i++)
                ss += (proj[i].x - img[i].x) * (proj[i].x - img[i].x) + (proj[i].y - img[i].y) * (proj[i].y - img[i].y);
        for (int i = 0; i < 9; i++)
                res->world_R[i] = R.at<double>(i / 3, i % 3);
        for (int i = 0; i < 3; i++)
                res->world_t[i] = tv.at<double>(i);
        res->world_rms_px = std::sqrt(ss / nc);
        res->have_world = true;
        res->reference = o->reference;
        return 0;
}

/* Intrinsics of one device with opts.k3 and opts.k2 (calib.h): k3 held at 0 first; with
 * IMP_CALIB_K3_AUTO refitted with k3 when that estimate's diagonal field of view reaches
 * IMP_CALIB_K3_MIN_FOV_DEG, and with k2 held at 0 when it stays below
 * IMP_CALIB_K2_MIN_FOV_DEG. Then, built with Ceres and unless opts.opencv_only, the
 * robust bundle refinement (ceres-calib.h) — skipped on views that do not determine the
 * focal length (the flags and inflated σ of the OpenCV fit stand), and with a warning
 * (keeping OpenCV's result) when it fails. rv, tv: the board poses of the result. */
int device_intrinsics(const std::vector<struct imp_calib_view> &v, int w, int h,
                      const struct imp_calib_procam_opts *o, const char *who, struct imp_calib_procam *res,
                      struct imp_calib_intrinsics *ret, std::vector<double> &rv, std::vector<double> &tv,
                      struct imp_error *err) {
        const int n = (int) v.size();
        rv.assign((size_t) 3 * n, 0.0);
        tv.assign((size_t) 3 * n, 0.0);
        const unsigned first = (o->k3 == IMP_CALIB_K3_FIT ? 0u : (unsigned) IMP_CALIB_FIT_FIX_K3) |
                               (o->k2 == IMP_CALIB_K3_FIX ? (unsigned) IMP_CALIB_FIT_FIX_K2 : 0u);
        int r = imp_cv_calib_intrinsics_fit(v.data(), n, w, h, first, ret, rv.data(), tv.data(), err);
        if (r < 0)
                return r;
        double hx = 0.5 * w / ret->fx, hy = 0.5 * h / ret->fy;
        double fov = 2 * std::atan(std::sqrt(hx * hx + hy * hy)) * 180 / M_PI;
        unsigned fit = first;
        if (o->k3 == IMP_CALIB_K3_AUTO && fov >= IMP_CALIB_K3_MIN_FOV_DEG)
                fit &= ~(unsigned) IMP_CALIB_FIT_FIX_K3;
        if (o->k2 == IMP_CALIB_K3_AUTO && fov < IMP_CALIB_K2_MIN_FOV_DEG)
                fit |= IMP_CALIB_FIT_FIX_K2;
        if (fit != first) {
                r = imp_cv_calib_intrinsics_fit(v.data(), n, w, h, fit, ret, rv.data(), tv.data(), err);
                if (r < 0)
                        return r;
        }
        if (o->opencv_only || !imp_ceres_calib_available() ||
            (ret->flags & (IMP_CALIB_FOCAL_UNDETERMINED | IMP_CALIB_FEW_VIEWS | IMP_CALIB_RANK_DEFICIENT)))
                return 0;
        struct imp_ceres_calib_opts co;
        imp_ceres_calib_opts_default(&co);
        struct imp_calib_intrinsics refined = *ret;
        struct imp_ceres_calib_report rep = {};
        struct imp_error cerr = {};
        r = imp_ceres_calib_refine(v.data(), n, &co, &refined, rv.data(), tv.data(), nullptr, &rep, &cerr);
        if (r < 0) {
                imp_calib_warn(res, "%s: %s; keeping OpenCV's estimate", who, cerr.msg);
                return 0;
        }
        refined.ceres_refined = true;
        refined.n_outliers = rep.n_outliers;
        if (rep.n_outliers > 0)
                imp_calib_warn(res, "%s: %d of %d points dropped as outliers by the refinement", who,
                               rep.n_outliers, refined.n_points + rep.n_outliers);
        refined.flags &= ~(unsigned) (IMP_CALIB_PP_UNDETERMINED | IMP_CALIB_FOCAL_UNDETERMINED);
        imp_calib_intrinsics_assess(&refined);
        *ret = refined;
        return 0;
}

/* The joint refinement falls back to the per-device results when it fits a device worse than
 * this (RMS over its inliers against the device's own refinement): sharing the board poses
 * costs a little RMS when both fits are right, much more when the devices disagree about
 * the boards (mislabelled corners, a moved board, a wrong projector coordinate map). */
constexpr double JOINT_WORSE_RMS_RATIO = 1.25;
constexpr double JOINT_WORSE_RMS_PX = 0.02;

/* Camera, projector and their pose in one problem (ceres-procam.h), started from the
 * per-device results, their board poses (camera) and stereoCalibrate's pose. Its values
 * replace those unless it fails or fits a device clearly worse; then a warning says why and
 * the per-device + stereoCalibrate values stand. */
int joint_refine(const struct imp_calib_view *vc, const struct imp_calib_view *vp, int n,
                 struct imp_calib_procam *res, std::vector<double> rv, std::vector<double> tv) {
        struct imp_calib_joint *j = &res->joint;
        const unsigned undetermined = IMP_CALIB_FOCAL_UNDETERMINED | IMP_CALIB_FEW_VIEWS | IMP_CALIB_RANK_DEFICIENT;
        if ((res->camera.flags | res->projector.flags) & undetermined) {
                /* The joint fit flags such views too, but it wanders along the unobservable
                 * direction first (test-calib-joint-stability); the per-device result with its
                 * flags and inflated σ is the more useful answer. */
                copy_str(j->why_not_used, sizeof j->why_not_used, "not run: the per-device fits say the views "
                         "do not determine the intrinsics (see the flags)");
                return 0;
        }
        j->attempted = true;
        struct imp_ceres_calib_opts co;
        imp_ceres_calib_opts_default(&co);
        struct imp_calib_intrinsics cam = res->camera, proj = res->projector;
        struct imp_calib_stereo st = res->stereo;
        struct imp_ceres_procam_report rep = {};
        struct imp_error cerr = {};
        int r = imp_ceres_procam_refine(vc, vp, n, &co, &cam, &proj, &st, rv.data(), tv.data(), &rep, &cerr);
        if (r < 0) {
                copy_str(j->why_not_used, sizeof j->why_not_used, cerr.msg);
                imp_calib_warn(res, "%s; keeping the per-device calibration and stereoCalibrate's pose", cerr.msg);
                return 0;
        }
        j->converged = rep.converged;
        j->iterations = rep.iterations;
        j->rms_camera_px = cam.rms_px;
        j->rms_projector_px = proj.rms_px;
        j->rms_px = st.rms_px;
        j->outliers_camera = rep.n_outliers_cam;
        j->outliers_projector = rep.n_outliers_proj;
        j->k3_fixed_camera = cam.k3_fixed;
        j->k3_fixed_projector = proj.k3_fixed;
        j->k2_fixed_camera = cam.k2_fixed;
        j->k2_fixed_projector = proj.k2_fixed;
        const struct imp_calib_intrinsics *alone[2] = { &res->camera, &res->projector }, *joint[2] = { &cam, &proj };
        for (int d = 0; d < 2; d++)
                if (joint[d]->rms_px > JOINT_WORSE_RMS_RATIO * alone[d]->rms_px + JOINT_WORSE_RMS_PX) {
                        char why[IMP_CALIB_WARNING_LEN];
                        snprintf(why, sizeof why, "joint refinement fits the %s at %.3f px RMS against %.3f px "
                                 "alone (limit %.2f × + %.2f px)", d ? "projector" : "camera", joint[d]->rms_px,
                                 alone[d]->rms_px, JOINT_WORSE_RMS_RATIO, JOINT_WORSE_RMS_PX);
                        copy_str(j->why_not_used, sizeof j->why_not_used, why);
                        imp_calib_warn(res, "%s; keeping the per-device calibration and stereoCalibrate's "
                                       "pose", why);
                        return 0;
                }
        if (!rep.converged)
                imp_calib_warn(res, "joint refinement stopped after %d iterations without converging; its "
                               "result is used", rep.iterations);
        if (rep.n_outliers_cam + rep.n_outliers_proj > 0)
                imp_calib_warn(res, "joint refinement: %d camera and %d projector points dropped as outliers",
                               rep.n_outliers_cam, rep.n_outliers_proj);
        res->camera = cam;
        res->projector = proj;
        res->stereo = st;
        j->used = true;
        return 1;
}

int procam_cpp(const char *const *dirs, int n_dirs, const source &src, const struct imp_calib_procam_opts *o,
               struct imp_calib_procam *ret, struct imp_error *err) {
        int n_pat = imp_cv_graycode_count(o->proj_w, o->proj_h);
        if (n_pat < 0)
                return imp_error_set(err, -EINVAL, "bad projector size %dx%d", o->proj_w, o->proj_h);
        std::unique_ptr<struct imp_calib_procam> res(new struct imp_calib_procam());
        std::vector<capture_points> pts((size_t) n_dirs);
        std::vector<double> ref_corners;
        int cam_w = 0, cam_h = 0, half_px = o->window_half_px;
        for (int d = 0; d < n_dirs; d++) {
                struct imp_calib_capture *cap = &res->captures[d];
                copy_str(cap->dir, sizeof cap->dir, dirs[d]);
                std::vector<double> corners;
                int r = do_capture(src, d, dirs[d], o, n_pat, &cam_w, &cam_h, &half_px, cap, &pts[d],
                                   &corners, err);
                if (r < 0)
                        return r;
                if (d == o->reference) {
                        if (r != 0)
                                return imp_error_set(err, -EDOM, "reference capture %s is not usable: %s",
                                                     dirs[d], cap->why);
                        ref_corners = corners;
                }
                cap->used = r == 0;
                if (!cap->used) {
                        imp_calib_warn(res.get(), "%s; capture skipped", cap->why);
                        continue;
                }
                res->n_used++;
                if (cap->n_corners_proj < cap->n_corners_cam)
                        imp_calib_warn(res.get(), "capture %s: %d of %d corners had too few decoded "
                                       "pixels within ±%d px and are left out of the projector "
                                       "calibration", dirs[d], cap->n_corners_cam - cap->n_corners_proj,
                                       cap->n_corners_cam, half_px);
        }
        res->n_captures = n_dirs;
        res->window_half_px = half_px;
        if (res->n_used < IMP_CALIB_MIN_VIEWS) {
                std::string why;
                for (int d = 0; d < n_dirs; d++)
                        if (!res->captures[d].used)
                                why += std::string("\n  ") + res->captures[d].why;
                return imp_error_set(err, -EDOM, "%d usable capture%s of %d, at least %d needed "
                                     "(board %dx%d inner corners)%s", res->n_used,
                                     res->n_used == 1 ? "" : "s", n_dirs, IMP_CALIB_MIN_VIEWS,
                                     o->board_cols, o->board_rows, why.c_str());
        }
        std::vector<struct imp_calib_view> vc, vp, vcp;
        for (int d = 0; d < n_dirs; d++) {
                if (!res->captures[d].used)
                        continue;
                const capture_points &p = pts[d];
                vc.push_back({ (int) p.cam.size() / 2, p.obj.data(), p.cam.data() });
                vp.push_back({ (int) p.proj.size() / 2, p.obj_p.data(), p.proj.data() });
                vcp.push_back({ (int) p.cam_p.size() / 2, p.obj_p.data(), p.cam_p.data() });
        }
        std::vector<double> rv, tv, prv, ptv;
        int r = device_intrinsics(vc, cam_w, cam_h, o, "camera", res.get(), &res->camera, rv, tv, err);
        if (r < 0)
                return imp_error_prefix(err, "camera: ");
        r = device_intrinsics(vp, o->proj_w, o->proj_h, o, "projector", res.get(), &res->projector, prv, ptv,
                              err);
        if (r < 0)
                return imp_error_prefix(err, "projector: ");
        r = imp_cv_calib_stereo(vcp.data(), vp.data(), (int) vp.size(), &res->camera, &res->projector,
                                &res->stereo, err);
        if (r < 0)
                return r;
        if (!o->opencv_only && !o->no_joint && imp_ceres_calib_available())
                joint_refine(vc.data(), vp.data(), (int) vc.size(), res.get(), rv, tv);
        res->reference = -1;
        if (o->reference >= 0) {
                r = world_pose(o, ref_corners, res.get(), err);
                if (r < 0)
                        return r;
        }
        warn_flags(res.get(), &res->camera, "camera");
        warn_flags(res.get(), &res->projector, "projector");
        *ret = *res;
        return 0;
}

int check_opts(const struct imp_calib_procam_opts *opts, int n, struct imp_error *err) {
        if (opts->board_cols < 2 || opts->board_rows < 2 || !(opts->square > 0) ||
            !std::isfinite(opts->square) || opts->black_threshold < 0 || opts->white_threshold < 0 ||
            opts->window_half_px < 0)
                return imp_error_set(err, -EINVAL, "procam calibration: bad options (board %dx%d, "
                                     "square %g)", opts->board_cols, opts->board_rows, opts->square);
        if (opts->reference >= n || (opts->reference >= 0 && !opts->orient_board) ||
            !std::isfinite(opts->board_origin[0]) || !std::isfinite(opts->board_origin[1]))
                return imp_error_set(err, -EINVAL, "procam calibration: reference capture %d of %d "
                                     "(needs orient_board and a finite board origin)", opts->reference, n);
        return 0;
}

}  // namespace

extern "C" int imp_cv_calib_procam_source(const char *const *names, int n, imp_calib_frame_loader load,
                                          void *user, const struct imp_calib_procam_opts *opts,
                                          struct imp_calib_procam *ret, struct imp_error *err) {
        if (!names || n < 1 || !load || !opts || !ret)
                return imp_error_set(err, -EINVAL, "procam calibration: no captures given");
        if (n > IMP_CALIB_MAX_CAPTURES)
                return imp_error_set(err, -EINVAL, "procam calibration: %d captures, at most %d",
                                     n, IMP_CALIB_MAX_CAPTURES);
        int r = check_opts(opts, n, err);
        if (r < 0)
                return r;
        try {
                return procam_cpp(names, n, source{ load, user, false }, opts, ret, err);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "procam calibration: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "procam calibration: %s", e.what());
        }
}

extern "C" int imp_cv_calib_procam(const char *const *dirs, int n_dirs,
                                   const struct imp_calib_procam_opts *opts, struct imp_calib_procam *ret,
                                   struct imp_error *err) {
        if (!dirs || n_dirs < 1 || !opts || !ret)
                return imp_error_set(err, -EINVAL, "procam calibration: no captures given");
        if (n_dirs > IMP_CALIB_MAX_CAPTURES)
                return imp_error_set(err, -EINVAL, "procam calibration: %d captures, at most %d",
                                     n_dirs, IMP_CALIB_MAX_CAPTURES);
        int r = check_opts(opts, n_dirs, err);
        if (r < 0)
                return r;
        try {
                return procam_cpp(dirs, n_dirs, source{ dir_loader, (void *) dirs, true }, opts, ret, err);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "procam calibration: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "procam calibration: %s", e.what());
        }
}

/* ---- one device on its own (camera-only calibration, cv-calib-camera.cpp) ---- */

extern "C" int imp_cv_calib_device(const struct imp_calib_view *views, int n_views, int width, int height,
                                   int k3, int k2, bool opencv_only, const char *who,
                                   struct imp_calib_intrinsics *ret,
                                   char (*ret_warnings)[IMP_CALIB_WARNING_LEN], int max_warnings,
                                   int *ret_n_warnings, struct imp_error *err) {
        if (!views || n_views < 1 || width < 1 || height < 1 || !who || !ret || max_warnings < 0 ||
            (max_warnings > 0 && (!ret_warnings || !ret_n_warnings)))
                return imp_error_set(err, -EINVAL, "calibration: bad arguments");
        try {
                std::unique_ptr<struct imp_calib_procam> sink(new struct imp_calib_procam());
                struct imp_calib_procam_opts o;
                imp_calib_procam_opts_default(&o);
                o.k3 = k3;
                o.k2 = k2;
                o.opencv_only = opencv_only;
                std::vector<struct imp_calib_view> v(views, views + n_views);
                struct imp_calib_intrinsics in = {};
                std::vector<double> rv, tv;
                int r = device_intrinsics(v, width, height, &o, who, sink.get(), &in, rv, tv, err);
                if (r < 0)
                        return r;
                for (int i = 0; max_warnings > 0 && i < sink->n_warnings && *ret_n_warnings < max_warnings; i++)
                        copy_str(ret_warnings[(*ret_n_warnings)++], IMP_CALIB_WARNING_LEN, sink->warnings[i]);
                *ret = in;
                return 0;
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "calibration: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "calibration: %s", e.what());
        }
}

extern "C" int imp_cv_calib_procam_joint(const struct imp_calib_view *cam, const struct imp_calib_view *proj,
                                         int n_views, const double *rvecs, const double *tvecs,
                                         struct imp_calib_procam *io) {
        if (!cam || !proj || n_views < 1 || !rvecs || !tvecs || !io)
                return -EINVAL;
        try {
                return joint_refine(cam, proj, n_views, io, std::vector<double>(rvecs, rvecs + 3 * n_views),
                                    std::vector<double>(tvecs, tvecs + 3 * n_views));
        } catch (const std::bad_alloc &) {
                return -ENOMEM;
        }
}
