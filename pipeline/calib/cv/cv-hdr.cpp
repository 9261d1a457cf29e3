/* C shim over OpenCV's Debevec HDR merge (see cv-hdr.h): frames are wrapped, not copied,
 * as cv::Mat headers; every OpenCV exception stops at this boundary. */
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <new>
#include <string>
#include <vector>
#include <opencv2/core.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/photo.hpp>
#include "cv-hdr.h"

namespace {

int cv_type(const struct imp_image *im) {
        switch (im->type) {
        case IMP_PIX_U8:  return CV_MAKETYPE(CV_8U, im->channels);
        case IMP_PIX_U16: return CV_MAKETYPE(CV_16U, im->channels);
        default:          return CV_MAKETYPE(CV_32F, im->channels);
        }
}

cv::Mat wrap(const struct imp_image *im) {
        return cv::Mat(im->height, im->width, cv_type(im), im->data, im->stride);
}

/* Common argument checks; fills mats and times. */
int gather(const struct imp_image *const *frames, const double *exposure_s, size_t n,
           std::vector<cv::Mat> &mats, cv::Mat &times, struct imp_error *err) {
        if (!frames || !exposure_s || n == 0)
                return imp_error_set(err, -EINVAL, "OpenCV HDR: bad arguments");
        const struct imp_image *f0 = frames[0];
        for (size_t i = 0; i < n; i++) {
                const struct imp_image *f = frames[i];
                if (!f || !f->data || f->type == IMP_PIX_F32 || (f->channels != 1 && f->channels != 3) ||
                    f->width != f0->width || f->height != f0->height || f->channels != f0->channels ||
                    f->type != f0->type || !(exposure_s[i] > 0))
                        return imp_error_set(err, -EINVAL, "OpenCV HDR: frame %zu: bad layout or exposure", i);
        }
        mats.reserve(n);
        times.create((int) n, 1, CV_32F);
        for (size_t i = 0; i < n; i++) {
                mats.push_back(wrap(frames[i]));
                times.at<float>((int) i) = (float) exposure_s[i];
        }
        return 0;
}

}  // namespace

extern "C" int imp_cv_hdr_threads_get(void) {
        return cv::getNumThreads();
}

extern "C" void imp_cv_hdr_threads_set(int n) {
        cv::setNumThreads(n);
}

extern "C" const char *imp_cv_hdr_parallel_framework(void) {
        /* Not in OpenCV 4.6's public headers: read it from the build information. */
        static char name[64];
        if (!name[0]) {
                try {
                        const std::string &info = cv::getBuildInformation();
                        size_t at = info.find("Parallel framework:");
                        std::string v = "unknown";
                        if (at != std::string::npos) {
                                size_t b = info.find_first_not_of(" \t", at + 19);
                                size_t e = info.find('\n', b);
                                v = info.substr(b, e == std::string::npos ? std::string::npos : e - b);
                        }
                        snprintf(name, sizeof name, "%s", v.c_str());
                } catch (...) {
                        snprintf(name, sizeof name, "unknown");
                }
        }
        return name;
}

extern "C" int imp_cv_hdr_merge_debevec(const struct imp_image *const *frames, const double *exposure_s,
                                        size_t n, const float *response, struct imp_image *out,
                                        struct imp_error *err) {
        try {
                std::vector<cv::Mat> mats;
                cv::Mat times;
                int r = gather(frames, exposure_s, n, mats, times, err);
                if (r < 0)
                        return r;
                int C = frames[0]->channels;
                if (!out || !out->data || out->type != IMP_PIX_F32 || out->channels != C ||
                    out->width != frames[0]->width || out->height != frames[0]->height)
                        return imp_error_set(err, -EINVAL, "OpenCV MergeDebevec: bad output image");
                cv::Mat resp;
                if (response)
                        resp = cv::Mat(IMP_CV_HDR_LUT, 1, CV_MAKETYPE(CV_32F, C), (void *) response).clone();
                cv::Mat hdr;
                auto m = cv::createMergeDebevec();
                if (response)
                        m->process(mats, hdr, times, resp);
                else
                        m->process(mats, hdr, times);
                cv::Mat dst = wrap(out);
                hdr.copyTo(dst);
                return 0;
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "OpenCV MergeDebevec: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "OpenCV MergeDebevec: %s", e.what());
        }
}

extern "C" int imp_cv_hdr_calibrate_debevec(const struct imp_image *const *frames, const double *exposure_s,
                                            size_t n, int samples, float lambda, bool random,
                                            float *ret_response, struct imp_error *err) {
        if (!ret_response)
                return imp_error_set(err, -EINVAL, "OpenCV CalibrateDebevec: bad arguments");
        try {
                std::vector<cv::Mat> mats;
                cv::Mat times;
                int r = gather(frames, exposure_s, n, mats, times, err);
                if (r < 0)
                        return r;
                int C = frames[0]->channels;
                auto c = cv::createCalibrateDebevec(samples > 0 ? samples : 70, lambda > 0 ? lambda : 10.0f, random);
                cv::Mat resp;
                c->process(mats, resp, times);
                if (resp.rows != IMP_CV_HDR_LUT || resp.cols != 1 || resp.type() != CV_MAKETYPE(CV_32F, C))
                        return imp_error_set(err, -EINVAL, "OpenCV CalibrateDebevec: unexpected response %dx%d",
                                             resp.rows, resp.cols);
                cv::Mat dst(IMP_CV_HDR_LUT, 1, CV_MAKETYPE(CV_32F, C), ret_response);
                resp.copyTo(dst);
                return 0;
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "OpenCV CalibrateDebevec: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "OpenCV CalibrateDebevec: %s", e.what());
        }
}
