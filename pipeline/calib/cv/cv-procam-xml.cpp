/* OpenCV FileStorage calibration → rig (cv-procam-xml.h). */
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <new>
#include <unistd.h>
#include <opencv2/core.hpp>
#include "cv-procam-xml.h"

namespace {

/* A rows×cols double matrix under `key` (cols may be a range for distortion). */
int get_mat(const cv::FileStorage &fs, const char *path, const char *key, int rows, int min_n, int max_n,
            cv::Mat &ret, struct imp_error *err) {
        cv::FileNode node = fs[key];
        if (node.empty())
                return imp_error_set(err, -EBADMSG, "%s: no '%s'", path, key);
        cv::Mat m;
        node >> m;
        if (m.empty())
                return imp_error_set(err, -EBADMSG, "%s: '%s' is not a matrix", path, key);
        m.convertTo(m, CV_64F);
        int n = (int) m.total();
        if ((rows > 0 && (m.rows != rows || m.cols != rows)) || (rows == 0 && (n < min_n || n > max_n)))
                return imp_error_set(err, -EBADMSG, "%s: '%s' is %dx%d, expected %s", path, key, m.rows, m.cols,
                                     rows > 0 ? "3x3" : "1 to 5 (distortion) or 3 (translation) values");
        ret = m.reshape(1, 1);
        if (rows > 0)
                ret = m;
        for (int i = 0; i < n; i++)
                if (!std::isfinite(ret.at<double>(i / ret.cols, i % ret.cols)))
                        return imp_error_set(err, -EBADMSG, "%s: '%s' has a non-finite value", path, key);
        return 0;
}

void fill(struct imp_pinhole *m, const cv::Mat &K, const cv::Mat &d) {
        m->fx = K.at<double>(0, 0), m->fy = K.at<double>(1, 1);
        m->cx = K.at<double>(0, 2), m->cy = K.at<double>(1, 2);
        double *dist[5] = { &m->k1, &m->k2, &m->p1, &m->p2, &m->k3 };
        for (int i = 0; i < 5; i++)
                *dist[i] = i < (int) d.total() ? d.at<double>(0, i) : 0.0;
}

int read(const char *path, struct imp_rig *rig, struct imp_error *err) {
        if (access(path, R_OK) != 0)   /* before OpenCV, which logs its own complaint */
                return imp_error_set(err, -errno, "%s: cannot open: %s", path, strerror(errno));
        cv::FileStorage fs;
        if (!fs.open(path, cv::FileStorage::READ))
                return imp_error_set(err, -ENOENT, "%s: cannot open as an OpenCV XML/YAML file", path);
        cv::Mat ck, cd, pk, pd, R, t;
        const char *rkey = fs["roration"].empty() ? "rotation" : "roration";
        int r;
        if ((r = get_mat(fs, path, "cam_int", 3, 9, 9, ck, err)) < 0 ||
            (r = get_mat(fs, path, "cam_dist", 0, 1, 5, cd, err)) < 0 ||
            (r = get_mat(fs, path, "proj_int", 3, 9, 9, pk, err)) < 0 ||
            (r = get_mat(fs, path, "proj_dist", 0, 1, 5, pd, err)) < 0 ||
            (r = get_mat(fs, path, rkey, 3, 9, 9, R, err)) < 0 ||
            (r = get_mat(fs, path, "translation", 0, 3, 3, t, err)) < 0)
                return r;
        rig->n_cameras = 1;
        snprintf(rig->cameras[0].name, sizeof rig->cameras[0].name, "camera0");
        struct imp_pinhole *c = &rig->cameras[0].model, *p = &rig->projector.model;
        fill(c, ck, cd);
        c->R[0] = c->R[4] = c->R[8] = 1;
        rig->has_projector = true;
        snprintf(rig->projector.name, sizeof rig->projector.name, "projector");
        fill(p, pk, pd);
        for (int i = 0; i < 9; i++)
                p->R[i] = R.at<double>(i / 3, i % 3);
        for (int i = 0; i < 3; i++)
                p->t[i] = t.at<double>(0, i);
        rig->projector.gamma = 1;
        return 0;
}

}  // namespace

extern "C" int imp_cv_procam_xml_rig(const char *path, struct imp_rig *ret, struct imp_error *err) {
        if (!path || !ret)
                return imp_error_set(err, -EINVAL, "OpenCV calibration: bad arguments");
        struct imp_rig rig = {};
        try {
                int r = read(path, &rig, err);
                if (r < 0)
                        return r;
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EBADMSG, "%s: not a valid OpenCV XML/YAML file: %s", path, e.what());
        }
        *ret = rig;
        return 0;
}
