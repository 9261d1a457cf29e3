/* C shim over cv::triangulatePoints (cv-triangulate.h). */
#include <cerrno>
#include <new>
#include <vector>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include "cv-triangulate.h"

namespace {

cv::Mat camera_matrix(const struct imp_pinhole *m) {
        return (cv::Mat_<double>(3, 3) << m->fx, 0, m->cx, 0, m->fy, m->cy, 0, 0, 1);
}

/* Undistorted pixels (still in pixels: P = K) as a 2×n matrix. */
cv::Mat undistort(const struct imp_pinhole *m, const double *px, size_t n) {
        std::vector<cv::Point2d> in(n), out;
        for (size_t i = 0; i < n; i++)
                in[i] = cv::Point2d(px[2 * i], px[2 * i + 1]);
        cv::Mat K = camera_matrix(m);
        cv::Mat dist = (cv::Mat_<double>(1, 5) << m->k1, m->k2, m->p1, m->p2, m->k3);
        cv::undistortPoints(in, out, K, dist, cv::noArray(), K);
        cv::Mat r(2, (int) n, CV_64F);
        for (size_t i = 0; i < n; i++) {
                r.at<double>(0, (int) i) = out[i].x;
                r.at<double>(1, (int) i) = out[i].y;
        }
        return r;
}

cv::Mat projection(const struct imp_pinhole *m) {
        cv::Mat Rt(3, 4, CV_64F);
        for (int j = 0; j < 3; j++) {
                for (int k = 0; k < 3; k++)
                        Rt.at<double>(j, k) = m->R[3 * j + k];
                Rt.at<double>(j, 3) = m->t[j];
        }
        return camera_matrix(m) * Rt;
}

}  // namespace

extern "C" int imp_cv_triangulate(const struct imp_pinhole *a, const struct imp_pinhole *b, const double *a_px,
                                  const double *b_px, size_t n, double *ret_xyz, struct imp_error *err) {
        if (!a || !b || !a_px || !b_px || !ret_xyz || n == 0 || n > (size_t) INT32_MAX)
                return imp_error_set(err, -EINVAL, "OpenCV triangulation: bad arguments");
        try {
                cv::Mat X;
                cv::triangulatePoints(projection(a), projection(b), undistort(a, a_px, n), undistort(b, b_px, n), X);
                X.convertTo(X, CV_64F);
                for (size_t i = 0; i < n; i++) {
                        double w = X.at<double>(3, (int) i);
                        for (int k = 0; k < 3; k++)
                                ret_xyz[3 * i + k] = X.at<double>(k, (int) i) / w;
                }
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "OpenCV triangulation: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "OpenCV triangulation: %s", e.what());
        }
        return 0;
}
