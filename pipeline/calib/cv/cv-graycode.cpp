/* C shim over OpenCV's GrayCodePattern (see cv-graycode.h): frames are wrapped, not
 * copied, as cv::Mat headers; every OpenCV exception stops at this boundary. */
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <new>
#include <vector>
#include <opencv2/core.hpp>
#include <opencv2/structured_light.hpp>
#include "cv-graycode.h"

namespace {

cv::Mat wrap(const struct imp_image *im) {
        return cv::Mat(im->height, im->width, CV_8UC1, im->data, im->stride);
}

bool is_u8_gray(const struct imp_image *im, const struct imp_image *like) {
        return im && im->data && im->type == IMP_PIX_U8 && im->channels == 1 &&
               (!like || (im->width == like->width && im->height == like->height));
}

}  // namespace

extern "C" int imp_cv_graycode_count(int proj_w, int proj_h) {
        if (proj_w < 1 || proj_h < 1)
                return -EINVAL;
        try {
                auto g = cv::structured_light::GrayCodePattern::create(proj_w, proj_h);
                return (int) g->getNumberOfPatternImages();
        } catch (const std::bad_alloc &) {
                return -ENOMEM;
        } catch (...) {
                return -EINVAL;
        }
}

extern "C" void imp_cv_graycode_images_free(struct imp_image **images, size_t n) {
        if (!images)
                return;
        for (size_t i = 0; i < n; i++)
                imp_image_free(images[i]);
        free(images);
}

extern "C" int imp_cv_graycode_generate(int proj_w, int proj_h, struct imp_image ***ret_images,
                                        size_t *ret_n, struct imp_error *err) {
        if (proj_w < 1 || proj_h < 1 || !ret_images || !ret_n)
                return imp_error_set(err, -EINVAL, "OpenCV Gray code: bad arguments");
        std::vector<cv::Mat> pats;
        try {
                auto g = cv::structured_light::GrayCodePattern::create(proj_w, proj_h);
                g->generate(pats);
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "OpenCV Gray code: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "OpenCV Gray code: %s", e.what());
        }
        size_t n = pats.size();
        struct imp_image **v = (struct imp_image **) calloc(n ? n : 1, sizeof *v);
        if (!v)
                return imp_error_set(err, -ENOMEM, "OpenCV Gray code: out of memory");
        for (size_t i = 0; i < n; i++) {
                cv::Mat m = pats[i];
                if (m.type() != CV_8UC1 || m.rows != proj_h || m.cols != proj_w) {
                        imp_cv_graycode_images_free(v, n);
                        return imp_error_set(err, -EINVAL, "OpenCV Gray code: pattern %zu has an "
                                             "unexpected layout (type %d, %dx%d)", i, m.type(),
                                             m.cols, m.rows);
                }
                int r = imp_image_new(proj_w, proj_h, 1, IMP_PIX_U8, &v[i]);
                if (r < 0) {
                        imp_cv_graycode_images_free(v, n);
                        return imp_error_set(err, r, "OpenCV Gray code: out of memory");
                }
                for (int y = 0; y < proj_h; y++)
                        memcpy(imp_image_row(v[i], y), m.ptr<uint8_t>(y), (size_t) proj_w);
        }
        *ret_images = v;
        *ret_n = n;
        return 0;
}

extern "C" int imp_cv_graycode_decode(int proj_w, int proj_h, const struct imp_image *const *frames,
                                      size_t n_frames, const struct imp_image *white,
                                      const struct imp_image *black, int black_threshold,
                                      int white_threshold, int32_t *proj_x, int32_t *proj_y,
                                      uint8_t *valid, size_t *ret_n_valid, struct imp_error *err) {
        int want = imp_cv_graycode_count(proj_w, proj_h);
        if (want < 0)
                return imp_error_set(err, want, "OpenCV Gray code: bad projector size %dx%d",
                                     proj_w, proj_h);
        if (!frames || n_frames != (size_t) want)
                return imp_error_set(err, -EINVAL, "OpenCV Gray code: %zu frames, expected %d",
                                     n_frames, want);
        if (!is_u8_gray(white, NULL) || !is_u8_gray(black, white))
                return imp_error_set(err, -EINVAL, "OpenCV Gray code: white/black must be u8 grey "
                                     "of one size");
        if (!proj_x || !proj_y || !valid || black_threshold < 0 || white_threshold < 0)
                return imp_error_set(err, -EINVAL, "OpenCV Gray code: bad arguments");
        for (size_t i = 0; i < n_frames; i++)
                if (!is_u8_gray(frames[i], white))
                        return imp_error_set(err, -EINVAL, "OpenCV Gray code: frame %zu is not u8 "
                                             "grey %dx%d", i, white->width, white->height);
        size_t n_valid = 0;
        try {
                auto g = cv::structured_light::GrayCodePattern::create(proj_w, proj_h);
                g->setBlackThreshold((size_t) black_threshold);
                g->setWhiteThreshold((size_t) white_threshold);
                std::vector<cv::Mat> mats;
                mats.reserve(n_frames);
                for (size_t i = 0; i < n_frames; i++)
                        mats.push_back(wrap(frames[i]));
                cv::Mat wm = wrap(white), bm = wrap(black);
                const int w = white->width, h = white->height;
                for (int y = 0; y < h; y++) {
                        const uint8_t *wr = wm.ptr<uint8_t>(y), *br = bm.ptr<uint8_t>(y);
                        for (int x = 0; x < w; x++) {
                                size_t o = (size_t) y * w + x;
                                proj_x[o] = proj_y[o] = -1;
                                valid[o] = 0;
                                if ((int) wr[x] - (int) br[x] <= black_threshold)
                                        continue;
                                cv::Point pp;
                                bool error = g->getProjPixel(mats, x, y, pp);
                                if (error)
                                        continue;
                                proj_x[o] = pp.x;
                                proj_y[o] = pp.y;
                                valid[o] = 1;
                                n_valid++;
                        }
                }
        } catch (const std::bad_alloc &) {
                return imp_error_set(err, -ENOMEM, "OpenCV Gray code: out of memory");
        } catch (const cv::Exception &e) {
                return imp_error_set(err, -EINVAL, "OpenCV Gray code: %s", e.what());
        }
        if (ret_n_valid)
                *ret_n_valid = n_valid;
        return 0;
}
