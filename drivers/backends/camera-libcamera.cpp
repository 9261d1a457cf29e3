/* Camera backend "libcamera": a thin C++17 shim behind the C camera interface, for cameras
 * only libcamera drives (CSI sensors behind an ISP). One process-wide CameraManager shared
 * by the open cameras; one stream (StillCapture, or Raw with ";role=raw"); a request per
 * buffer, completed requests handed from libcamera's thread to grab() through a queue. */
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstring>
#include <deque>
#include <memory>
#include <mutex>
#include <string>
#include <vector>
#include <sys/mman.h>
#include <time.h>
#include <libcamera/libcamera.h>
#include "camera-libcamera.h"

using namespace libcamera;

namespace {

/* libcamera allows one CameraManager per process: shared, started on first use. */
std::mutex manager_lock;
std::unique_ptr<CameraManager> manager;
unsigned manager_users;

int manager_get(CameraManager **ret) {
        std::lock_guard<std::mutex> g(manager_lock);
        if (!manager) {
                logSetTarget(LoggingTargetNone);        /* drivers do not log */
                auto m = std::make_unique<CameraManager>();
                int r = m->start();
                if (r < 0)
                        return r;
                manager = std::move(m);
        }
        manager_users++;
        *ret = manager.get();
        return 0;
}

void manager_put() {
        std::lock_guard<std::mutex> g(manager_lock);
        if (manager_users > 0 && --manager_users == 0) {
                manager->stop();
                manager.reset();
        }
}

/* formats::R16 is not in 0.0.3: DRM_FORMAT_R16 by its fourcc. */
const PixelFormat pixel_r16{ uint32_t('R') | uint32_t('1') << 8 | uint32_t('6') << 16 | uint32_t(' ') << 24 };

struct FormatMap {
        imp_pixel_format format;
        PixelFormat pixel;
};
const FormatMap format_map[] = {
        { IMP_PIXEL_MONO8, formats::R8 },
        { IMP_PIXEL_MONO12, formats::R12 },     /* 12 bits in 16-bit little-endian words */
        { IMP_PIXEL_MONO16, pixel_r16 },
};

imp_pixel_format format_of(const PixelFormat &p) {
        for (const auto &m : format_map)
                if (m.pixel == p)
                        return m.format;
        return IMP_PIXEL_NONE;
}

struct Mapped {
        void *start = MAP_FAILED;
        size_t length = 0;
};

struct CamLibcamera {
        CameraManager *cm = nullptr;
        std::shared_ptr<Camera> camera;
        bool acquired = false;
        StreamRole role = StreamRole::StillCapture;
        std::unique_ptr<CameraConfiguration> config;
        std::unique_ptr<FrameBufferAllocator> allocator;
        std::vector<std::unique_ptr<Request>> requests;
        std::vector<Mapped> maps;       /* one per buffer, plane 0 */
        bool running = false;
        double exposure_us = 0;         /* 0: leave to the camera */
        double gain_db = NAN;
        std::mutex lock;
        std::condition_variable done_cv;
        std::deque<Request *> done;
        char error[256] = "";

        void on_complete(Request *r) {
                std::lock_guard<std::mutex> g(lock);
                done.push_back(r);
                done_cv.notify_one();
        }
};

int fail(CamLibcamera *c, int r, const char *what) {
        snprintf(c->error, sizeof c->error, "libcamera %s: %s: %s",
                 c->camera ? c->camera->id().c_str() : "?", what, strerror(-r));
        return r;
}

StreamConfiguration &stream_config(CamLibcamera *c) {
        return c->config->at(0);
}

/* Generate, validate and apply a configuration with pixel (or the role's default). */
int configure(CamLibcamera *c, const PixelFormat *pixel) {
        auto cfg = c->camera->generateConfiguration({ c->role });
        if (!cfg || cfg->empty())
                return fail(c, -EOPNOTSUPP, "no configuration for the stream role");
        if (pixel)
                cfg->at(0).pixelFormat = *pixel;
        if (cfg->validate() == CameraConfiguration::Invalid)
                return fail(c, -EINVAL, "configuration invalid");
        if (pixel && cfg->at(0).pixelFormat != *pixel)
                return fail(c, -EOPNOTSUPP, "pixel format not granted");
        int r = c->camera->configure(cfg.get());
        if (r < 0)
                return fail(c, r, "configure");
        c->config = std::move(cfg);
        return 0;
}

void set_controls(CamLibcamera *c, ControlList &ctrls) {
        if (c->exposure_us > 0) {
                ctrls.set(controls::AeEnable, false);
                ctrls.set(controls::ExposureTime, (int32_t) std::lround(c->exposure_us));
        }
        if (!std::isnan(c->gain_db))
                ctrls.set(controls::AnalogueGain, (float) std::pow(10.0, c->gain_db / 20.0));
}

int cam_stop(void *state);

void cam_close(void *state) {
        auto *c = static_cast<CamLibcamera *>(state);
        if (!c)
                return;
        (void) cam_stop(c);
        c->config.reset();
        if (c->acquired)
                c->camera->release();
        c->camera.reset();
        if (c->cm)
                manager_put();
        delete c;
}

/* address: a libcamera camera id, or "*" for the first camera; option role=raw|still. */
int cam_open(const char *address, unsigned timeout_ms, void **ret_state) try {
        std::string addr(address), id = addr.substr(0, addr.find(';'));
        if (id.empty())
                return -EINVAL;
        std::unique_ptr<CamLibcamera, void (*)(void *)> c(new CamLibcamera, cam_close);
        if (addr.find(";role=raw") != std::string::npos)
                c->role = StreamRole::Raw;
        int r = manager_get(&c->cm);
        if (r < 0) {
                c->cm = nullptr;
                return r;
        }
        if (id == "*") {
                auto cams = c->cm->cameras();
                if (!cams.empty())
                        c->camera = cams.front();
        } else
                c->camera = c->cm->get(id);
        if (!c->camera)
                return -ENODEV;
        if ((r = c->camera->acquire()) < 0)
                return r;
        c->acquired = true;
        if ((r = configure(c.get(), nullptr)) < 0)
                return r;
        c->camera->requestCompleted.connect(c.get(), &CamLibcamera::on_complete);
        *ret_state = c.release();
        return 0;
} catch (const std::bad_alloc &) {
        return -ENOMEM;
}

int cam_get_info(void *state, imp_camera_info *ret) {
        auto *c = static_cast<CamLibcamera *>(state);
        const StreamConfiguration &sc = stream_config(c);
        snprintf(ret->vendor, sizeof ret->vendor, "libcamera");
        snprintf(ret->model, sizeof ret->model, "%s", c->camera->id().c_str());
        ret->sensor_width = ret->width = sc.size.width;
        ret->sensor_height = ret->height = sc.size.height;
        ret->pixel_format = format_of(sc.pixelFormat);
        ret->pixel_formats = 0;
        for (const PixelFormat &p : sc.formats().pixelformats())
                if (format_of(p) != IMP_PIXEL_NONE)
                        ret->pixel_formats |= IMP_PIXEL_BIT(format_of(p));
        ret->exposure_us = c->exposure_us;
        ret->gain_db = std::isnan(c->gain_db) ? 0 : c->gain_db;
        return 0;
}

/* Carried by every request queued from now on (libcamera sets controls per request). */
int cam_set_exposure_us(void *state, double exposure_us) {
        static_cast<CamLibcamera *>(state)->exposure_us = exposure_us;
        return 0;
}

int cam_set_gain_db(void *state, double gain_db) {
        static_cast<CamLibcamera *>(state)->gain_db = gain_db;
        return 0;
}

int cam_set_pixel_format(void *state, imp_pixel_format format) {
        auto *c = static_cast<CamLibcamera *>(state);
        if (c->running)
                return -EBUSY;
        for (const auto &m : format_map)
                if (m.format == format) {
                        int r = configure(c, &m.pixel);
                        if (r < 0)
                                (void) configure(c, nullptr);
                        return r;
                }
        return -EOPNOTSUPP;
}

int cam_start(void *state, const imp_camera_acq *acq) {
        auto *c = static_cast<CamLibcamera *>(state);
        if (c->running)
                return -EBUSY;
        if (acq->software_trigger)
                return fail(c, -EOPNOTSUPP, "no software trigger");
        Stream *stream = stream_config(c).stream();
        c->allocator = std::make_unique<FrameBufferAllocator>(c->camera);
        int r = c->allocator->allocate(stream);
        if (r <= 0)
                return fail(c, r < 0 ? r : -ENOMEM, "allocate buffers");
        for (const auto &fb : c->allocator->buffers(stream)) {
                const FrameBuffer::Plane &p = fb->planes()[0];
                Mapped m;
                m.length = p.length;
                m.start = mmap(nullptr, p.length, PROT_READ, MAP_SHARED, p.fd.get(),
                               p.offset == FrameBuffer::Plane::kInvalidOffset ? 0 : p.offset);
                if (m.start == MAP_FAILED) {
                        r = fail(c, -errno, "map buffer");
                        break;
                }
                fb->setCookie(c->maps.size());
                c->maps.push_back(m);
                std::unique_ptr<Request> req = c->camera->createRequest(c->maps.size() - 1);
                if (!req || (r = req->addBuffer(stream, fb.get())) < 0) {
                        r = fail(c, req ? r : -ENOMEM, "create request");
                        break;
                }
                set_controls(c, req->controls());
                c->requests.push_back(std::move(req));
        }
        if (r >= 0 && (r = c->camera->start()) < 0)
                (void) fail(c, r, "start");
        if (r < 0) {
                (void) cam_stop(c);
                return r;
        }
        c->running = true;
        for (auto &req : c->requests)
                if ((r = c->camera->queueRequest(req.get())) < 0) {
                        (void) fail(c, r, "queue request");
                        (void) cam_stop(c);
                        return r;
                }
        return 0;
}

int cam_stop(void *state) {
        auto *c = static_cast<CamLibcamera *>(state);
        int r = 0;
        if (c->running) {
                r = c->camera->stop();          /* completes (cancels) every queued request */
                c->running = false;
        }
        {
                std::lock_guard<std::mutex> g(c->lock);
                c->done.clear();
        }
        c->requests.clear();
        for (Mapped &m : c->maps)
                if (m.start != MAP_FAILED)
                        munmap(m.start, m.length);
        c->maps.clear();
        if (c->allocator && c->config)
                (void) c->allocator->free(stream_config(c).stream());
        c->allocator.reset();
        return r;
}

uint64_t realtime_ns() {
        struct timespec ts;
        clock_gettime(CLOCK_REALTIME, &ts);
        return (uint64_t) ts.tv_sec * 1000000000u + (uint64_t) ts.tv_nsec;
}

int cam_grab(void *state, unsigned timeout_ms, void *dst, size_t dst_size, imp_frame *ret) {
        auto *c = static_cast<CamLibcamera *>(state);
        if (!c->running)
                return -ENOTCONN;
        Request *req;
        {
                std::unique_lock<std::mutex> g(c->lock);
                if (!c->done_cv.wait_for(g, std::chrono::milliseconds(timeout_ms), [c] { return !c->done.empty(); }))
                        return -ETIMEDOUT;
                req = c->done.front();
                c->done.pop_front();
        }
        const StreamConfiguration &sc = stream_config(c);
        imp_pixel_format f = format_of(sc.pixelFormat);
        size_t row = (size_t) sc.size.width * imp_pixel_format_bytes(f);
        size_t stride = std::max<size_t>(sc.stride, row);
        size_t need = row * sc.size.height;
        int r = 0;
        FrameBuffer *fb = req->buffers().begin()->second;
        const FrameMetadata &md = fb->metadata();
        const Mapped &m = c->maps.at(req->cookie());
        if (req->status() != Request::RequestComplete || md.status != FrameMetadata::FrameSuccess)
                r = fail(c, -EIO, "frame incomplete or cancelled");
        else if (f == IMP_PIXEL_NONE)
                r = fail(c, -EOPNOTSUPP, "frame format is not monochrome");
        else if (need > dst_size)
                r = -EMSGSIZE;
        else if (m.length < stride * (sc.size.height - 1) + row)
                r = fail(c, -EIO, "short buffer");
        if (r == 0) {
                for (unsigned y = 0; y < sc.size.height; y++)
                        memcpy(static_cast<uint8_t *>(dst) + y * row, static_cast<const uint8_t *>(m.start) + y * stride, row);
                ret->width = sc.size.width;
                ret->height = sc.size.height;
                ret->stride_bytes = (unsigned) row;
                ret->size = need;
                ret->pixel_format = f;
                ret->meta.timestamp_ns = md.timestamp;
                ret->meta.system_timestamp_ns = realtime_ns();
                ret->meta.frame_id = md.sequence;
        }
        req->reuse(Request::ReuseBuffers);      /* back into the loop either way */
        set_controls(c, req->controls());
        int q = c->camera->queueRequest(req);
        if (q < 0 && r == 0)
                r = fail(c, q, "queue request");
        return r;
}

[[maybe_unused]] const char *cam_last_error(void *state) {
        return static_cast<CamLibcamera *>(state)->error;
}

} /* namespace */

extern "C" int imp_camera_libcamera_probe(unsigned *ret_n_cameras) {
        CameraManager *cm;
        int r = manager_get(&cm);
        if (r < 0)
                return r;
        if (ret_n_cameras)
                *ret_n_cameras = (unsigned) cm->cameras().size();
        manager_put();
        return 0;
}

extern "C" const struct imp_camera_ops imp_camera_libcamera_ops = {
        .name = "libcamera",
        .open = cam_open,                       /* camera id or "*" (the first); ;role=raw */
        .close = cam_close,                     /* stops, releases the camera and the manager */
        .get_info = cam_get_info,               /* configured stream size and format */
        .set_exposure_us = cam_set_exposure_us, /* controls::ExposureTime on every request, AE off */
        .set_gain_db = cam_set_gain_db,         /* controls::AnalogueGain = 10^(dB/20) */
        .set_pixel_format = cam_set_pixel_format, /* R8, R12, R16 when the pipeline grants them */
        .set_roi = nullptr,                     /* not supported */
        .start = cam_start,                     /* allocate, map, one request per buffer, start */
        .stop = cam_stop,                       /* stop (cancels requests), unmap, free */
        .trigger_software = nullptr,            /* not supported */
        .grab = cam_grab,                       /* wait for a completed request, copy, requeue */
#ifdef IMP_CAMERA_HAVE_LAST_ERROR
        .last_error = cam_last_error,           /* "libcamera <id>: <what>: <errno text>" */
#endif
};
