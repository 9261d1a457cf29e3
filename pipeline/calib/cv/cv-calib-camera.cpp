/* Camera-only calibration (cv-calib-camera.h): the procam procedure's device fit
 * (imp_cv_calib_device), per-view poses and residuals under the fitted intrinsics, one
 * round of view rejection, few-view σ inflation. Every OpenCV exception stops here. */
#include <algorithm>
#include <cerrno>
#include <cfloat>
#include <cmath>
#include <new>
#include <string>
#include <vector>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>
#include "cv-calib-camera.h"
#include "cv-calib.h"

namespace {

/* View v's pose under in (solvePnP, then Levenberg–Marquardt), its RMS residual and tilt. */
void view_pose(const struct imp_calib_view &v, const struct imp_calib_intrinsics &in,
               struct imp_calib_camera_view *out) {
        std::vector<cv::Point3d> obj;
        std::vector<cv::Point2d> img;
        for (int i = 0; i < v.n; i++) {
                obj.emplace_back(v.obj[3 * i], v.obj[3 * i + 1], v.obj[3 * i + 2]);
                img.emplace_back(v.img[2 * i], v.img[2 * i + 1]);
        }
        cv::Mat K = (cv::Mat_<double>(3, 3) << in.fx, 0, in.cx, 0, in.fy, in.cy, 0, 0, 1);
        cv::Mat D(1, 5, CV_64F, const_cast<double *>(in.dist)), rv, tv, R;
        out->rms_px = HUGE_VAL;
        if (!cv::solvePnP(obj, img, K, D, rv, tv, false, cv::SOLVEPNP_ITERATIVE))
                return;
        cv::solvePnPRefineLM(obj, img, K, D, rv, tv);
        std::vector<cv::Point2d> proj;
        cv::projectPoints(obj, rv, tv, K, D, proj);
        double ss = 0;
        for (int i = 0; i < v.n; i++)
                ss += (proj[i].x - img[i].x) * (proj[i].x - img[i].x) + (proj[i].y - img[i].y) * (proj[i].y - img[i].y);
        cv::Rodrigues(rv, R);
        for (int k = 0; k < 3; k++) {
                out->rvec[k] = rv.at<double>(k);
                out->tvec[k] = tv.at<double>(k);
        }
        out->tilt_deg = std::acos(std::min(std::fabs(R.at<double>(2, 2)), 1.0)) * 180.0 / M_PI;
        out->rms_px = std::isfinite(ss) ? std::sqrt(ss / std::max(v.n, 1)) : HUGE_VAL;
}

/* Scales row and column i of cov (and std[i]) so that std[i] ≥ floor; returns the factor. */
double raise_std(struct imp_calib_intrinsics *in, int i, double floor) {
        if (!(in->std[i] < floor))
                return 1.0;
        double s = floor / std::max(in->std[i], DBL_MIN);
        in->std[i] = floor;
        for (int k = 0; k < IMP_CALIB_N_INTR; k++) {
                in->cov[i * IMP_CALIB_N_INTR + k] *= s;
                in->cov[k * IMP_CALIB_N_INTR + i] *= s;
        }
        return s;
}

int fit(const struct imp_calib_view *views, int width, int height, const struct imp_calib_camera_opts *o,
        struct imp_calib_camera *io, int n_warnings_before, struct imp_error *err) {
        std::vector<struct imp_calib_view> used;
        for (int i = 0; i < io->n_views; i++)
                if (io->views[i].used)
                        used.push_back(views[i]);
        io->n_warnings = n_warnings_before;
        int r = imp_cv_calib_device(used.data(), (int) used.size(), width, height, o->k3, o->k2, o->opencv_only,
                                    "camera", &io->camera, io->warnings, IMP_CALIB_MAX_WARNINGS,
                                    &io->n_warnings, err);
        if (r < 0)
                return r;
        for (int i = 0; i < io->n_views; i++)
                if (io->views[i].found)
                        view_pose(views[i], io->camera, &io->views[i]);
        return 0;
}

/* Drops views far above the median view RMS; true when any was dropped. */
bool reject_views(struct imp_calib_camera *io, int min_views) {
        std::vector<double> rms;
        for (int i = 0; i < io->n_views; i++)
                if (io->views[i].used)
                        rms.push_back(io->views[i].rms_px);
        std::nth_element(rms.begin(), rms.begin() + (long) rms.size() / 2, rms.end());
        const double median = rms[rms.size() / 2];
        const double limit = std::max(IMP_CALIB_VIEW_REJECT_FACTOR * median, IMP_CALIB_VIEW_REJECT_MIN_PX);
        int n_bad = 0;
        for (int i = 0; i < io->n_views; i++)
                n_bad += io->views[i].used && !(io->views[i].rms_px <= limit);
        if (!n_bad)
                return false;
        if ((int) rms.size() - n_bad < std::max(min_views, 1)) {
                imp_calib_camera_warn(io, "%d view%s fit badly (RMS above %.3f px, %.0f× the median view's) "
                                      "but too few would remain without them; kept", n_bad,
                                      n_bad == 1 ? "" : "s", limit, IMP_CALIB_VIEW_REJECT_FACTOR);
                return false;
        }
        for (int i = 0; i < io->n_views; i++) {
                struct imp_calib_camera_view *v = &io->views[i];
                if (!v->used || v->rms_px <= limit)
                        continue;
                v->used = false;
                io->n_rejected++;
                snprintf(v->why, sizeof v->why, "rejected: RMS %.3f px against a median view's %.3f px "
                         "(limit %.3f px); a mislabelled board or a moved frame", v->rms_px, median, limit);
                imp_calib_camera_warn(io, "%s: %s", v->name, v->why);
        }
        return true;
}

void warn_flags(struct imp_calib_camera *io) {
        char buf[1024];
        if (imp_calib_flags_describe(&io->camera, "camera", buf, sizeof buf) <= 0)
                return;
        for (char *save = nullptr, *line = strtok_r(buf, "\n", &save); line; line = strtok_r(nullptr, "\n", &save))
                imp_calib_camera_warn(io, "%s", line);
}

int camera_cpp(const struct imp_calib_view *views, int width, int height, const struct imp_calib_camera_opts *o,
               struct imp_calib_camera *io, struct imp_error *err) {
        io->n_found = io->n_used = io->n_rejected = 0;
        for (int i = 0; i < io->n_views; i++) {
                struct imp_calib_camera_view *v = &io->views[i];
                v->used = v->found && views[i].n >= 4;
                io->n_found += v->used;
        }
        const int min_views = std::max(o->min_views, 1);
        if (io->n_found < min_views) {
                std::string why;
                for (int i = 0; i < io->n_views; i++)
                        if (!io->views[i].used)
                                why += std::string("\n  ") + io->views[i].name + ": " + io->views[i].why;
                return imp_error_set(err, -EDOM, "the board (%dx%d inner corners) was found in %d of %d "
                                     "view%s, at least %d needed%s", o->board_cols, o->board_rows, io->n_found,
                                     io->n_views, io->n_views == 1 ? "" : "s", min_views, why.c_str());
        }
        const int n_warn0 = io->n_warnings;
        int r = fit(views, width, height, o, io, n_warn0, err);
        if (r < 0)
                return r;
        if (reject_views(io, min_views)) {
                int n_warn1 = io->n_warnings;
                r = fit(views, width, height, o, io, n_warn1, err);
                if (r < 0)
                        return r;
        }
        for (int i = 0; i < io->n_views; i++)
                io->n_used += io->views[i].used;
        struct imp_calib_intrinsics *in = &io->camera;
        if (io->n_used < IMP_CALIB_MIN_VIEWS) {
                in->flags |= IMP_CALIB_FEW_VIEWS;
                double s = std::max({ raise_std(in, 0, IMP_CALIB_FEW_VIEWS_STD_REL * std::fabs(in->fx)),
                                      raise_std(in, 1, IMP_CALIB_FEW_VIEWS_STD_REL * std::fabs(in->fy)),
                                      raise_std(in, 2, IMP_CALIB_FEW_VIEWS_STD_PP * width),
                                      raise_std(in, 3, IMP_CALIB_FEW_VIEWS_STD_PP * height) });
                /* Σq = Jθ cov Jθᵀ grows by at most s² when rows and columns grow by ≤ s. */
                in->proj_unc_centre_px *= s;
                in->proj_unc_corner_px *= s;
                imp_calib_intrinsics_assess(in);
        }
        warn_flags(io);
        return 0;
}

}  // namespace

extern "C" int imp_cv_calib_camera(const struct imp_calib_view *views, int width, int height,
                                   const struct imp_calib_camera_opts *o, struct imp_calib_camera *io,
                                   struct imp_error *err) {
        if (!views || !o || !io || io->n_views < 1 || io->n_views > IMP_CALIB_CAMERA_MAX_VIEWS || width < 1 ||
            height < 1 || o->board_cols < 2 || o->board_rows < 2 || !(o->square > 0))
                return imp_error_set(err, -EINVAL, "camera calibration: bad arguments");
        try {
                return camera_cpp(views, width, height, o, io, err);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "camera calibration: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EDOM, "camera calibration: %s", e.what());
        }
}
