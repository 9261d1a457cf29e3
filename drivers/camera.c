/* Camera wrapper: backend lookup by name, argument checks, -EOPNOTSUPP for missing
 * operations, and the one frame buffer per camera (sized at start, reused by every grab). */
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include "camera.h"

#ifdef IMPASTO_HAVE_ARAVIS
extern const struct imp_camera_ops imp_camera_aravis_ops;
#endif
#ifdef IMPASTO_HAVE_V4L2
extern const struct imp_camera_ops imp_camera_v4l2_ops;
#endif
#ifdef IMPASTO_HAVE_LIBCAMERA
extern const struct imp_camera_ops imp_camera_libcamera_ops;
#endif

static const struct imp_camera_ops *const camera_backends[] = {
#ifdef IMPASTO_HAVE_ARAVIS
        &imp_camera_aravis_ops,
#endif
#ifdef IMPASTO_HAVE_V4L2
        &imp_camera_v4l2_ops,
#endif
#ifdef IMPASTO_HAVE_LIBCAMERA
        &imp_camera_libcamera_ops,
#endif
        NULL,
};

struct imp_camera {
        const struct imp_camera_ops *ops;
        void *state;
        bool acquiring;
        void *buf;              /* frame pixels, allocated at start */
        size_t buf_size;
        struct imp_frame frame;
};

static const char *const pixel_format_names[] = {
        [IMP_PIXEL_NONE] = "none",
        [IMP_PIXEL_MONO8] = "Mono8",
        [IMP_PIXEL_MONO12] = "Mono12",
        [IMP_PIXEL_MONO16] = "Mono16",
};

const char *imp_pixel_format_to_string(enum imp_pixel_format f) {
        return (unsigned) f < ARRAY_SIZE(pixel_format_names) ? pixel_format_names[f] : "invalid";
}

int imp_pixel_format_from_string(const char *s) {
        if (!s)
                return -EINVAL;
        for (unsigned i = IMP_PIXEL_MONO8; i < ARRAY_SIZE(pixel_format_names); i++)
                if (strcasecmp(s, pixel_format_names[i]) == 0)
                        return (int) i;
        return -EINVAL;
}

unsigned imp_pixel_format_bytes(enum imp_pixel_format f) {
        switch (f) {
        case IMP_PIXEL_MONO8: return 1;
        case IMP_PIXEL_MONO12:
        case IMP_PIXEL_MONO16: return 2;
        default: return 0;
        }
}

const struct imp_camera_ops *imp_camera_backend(const char *name) {
        if (!name)
                return NULL;
        for (size_t i = 0; camera_backends[i]; i++)
                if (strcmp(camera_backends[i]->name, name) == 0)
                        return camera_backends[i];
        return NULL;
}

int imp_camera_open(const char *backend, const char *address, unsigned timeout_ms,
                    struct imp_camera **ret_camera) {
        if (!backend || !address || !ret_camera)
                return -EINVAL;
        const struct imp_camera_ops *ops = imp_camera_backend(backend);
        if (!ops)
                return -ENOENT;
        struct imp_camera *c = calloc(1, sizeof *c);
        if (!c)
                return -ENOMEM;
        c->ops = ops;
        int r = ops->open(address, timeout_ms, &c->state);
        if (r < 0) {
                free(c);
                return r;
        }
        *ret_camera = c;
        return 0;
}

void imp_camera_close(struct imp_camera *c) {
        if (!c)
                return;
        if (c->acquiring && c->ops->stop)
                (void) c->ops->stop(c->state);
        c->ops->close(c->state);
        free(c->buf);
        free(c);
}

const char *imp_camera_backend_name(const struct imp_camera *c) {
        return c ? c->ops->name : NULL;
}

int imp_camera_get_info(struct imp_camera *c, struct imp_camera_info *ret_info) {
        if (!c || !ret_info)
                return -EINVAL;
        if (!c->ops->get_info)
                return -EOPNOTSUPP;
        struct imp_camera_info info = {};
        int r = c->ops->get_info(c->state, &info);
        if (r < 0)
                return r;
        *ret_info = info;
        return 0;
}

int imp_camera_set_exposure_us(struct imp_camera *c, double exposure_us) {
        if (!c || !(exposure_us > 0) || exposure_us > 1e9)
                return -EINVAL;
        return c->ops->set_exposure_us ? c->ops->set_exposure_us(c->state, exposure_us) : -EOPNOTSUPP;
}

int imp_camera_set_gain_db(struct imp_camera *c, double gain_db) {
        if (!c || gain_db != gain_db)
                return -EINVAL;
        return c->ops->set_gain_db ? c->ops->set_gain_db(c->state, gain_db) : -EOPNOTSUPP;
}

int imp_camera_set_pixel_format(struct imp_camera *c, enum imp_pixel_format format) {
        if (!c || imp_pixel_format_bytes(format) == 0)
                return -EINVAL;
        if (c->acquiring)
                return -EBUSY;
        return c->ops->set_pixel_format ? c->ops->set_pixel_format(c->state, format) : -EOPNOTSUPP;
}

int imp_camera_set_roi(struct imp_camera *c, unsigned x, unsigned y, unsigned width, unsigned height) {
        if (!c || width == 0 || height == 0)
                return -EINVAL;
        if (c->acquiring)
                return -EBUSY;
        return c->ops->set_roi ? c->ops->set_roi(c->state, x, y, width, height) : -EOPNOTSUPP;
}

int imp_camera_start(struct imp_camera *c, const struct imp_camera_acq *acq) {
        if (!c)
                return -EINVAL;
        if (c->acquiring)
                return -EBUSY;
        if (!c->ops->start || !c->ops->grab || !c->ops->get_info)
                return -EOPNOTSUPP;
        struct imp_camera_acq a = acq ? *acq : (struct imp_camera_acq) {};
        if (a.n_buffers == 0)
                a.n_buffers = 4;
        if (a.n_buffers > 256)
                return -EINVAL;
        struct imp_camera_info info;
        int r = c->ops->get_info(c->state, &info);
        if (r < 0)
                return r;
        size_t need = (size_t) info.width * info.height * imp_pixel_format_bytes(info.pixel_format);
        if (need == 0)
                return -EINVAL;
        if (need > c->buf_size) {
                void *b = realloc(c->buf, need);
                if (!b)
                        return -ENOMEM;
                c->buf = b;
                c->buf_size = need;
        }
        r = c->ops->start(c->state, &a);
        if (r < 0)
                return r;
        c->acquiring = true;
        return 0;
}

int imp_camera_stop(struct imp_camera *c) {
        if (!c)
                return -EINVAL;
        if (!c->acquiring)
                return 0;
        c->acquiring = false;
        return c->ops->stop ? c->ops->stop(c->state) : 0;
}

bool imp_camera_is_acquiring(const struct imp_camera *c) {
        return c && c->acquiring;
}

int imp_camera_trigger_software(struct imp_camera *c) {
        if (!c)
                return -EINVAL;
        if (!c->acquiring)
                return -ENOTCONN;
        return c->ops->trigger_software ? c->ops->trigger_software(c->state) : -EOPNOTSUPP;
}

int imp_camera_set_free_run(struct imp_camera *c, bool on) {
        if (!c)
                return -EINVAL;
        if (!c->acquiring)
                return -ENOTCONN;
        return c->ops->set_free_run ? c->ops->set_free_run(c->state, on) : -EOPNOTSUPP;
}

uint64_t imp_camera_frames_skipped(uint64_t prev_id, uint64_t id) {
        const uint64_t gv1_max = 0xffff;
        if (id > prev_id)
                return id - prev_id - 1;
        if (prev_id <= gv1_max && id <= gv1_max)
                return (gv1_max - prev_id) + (id - 1);
        return 0;
}

int imp_camera_grab_into(struct imp_camera *c, unsigned timeout_ms, void *dst, size_t dst_size,
                         struct imp_frame *ret_frame) {
        if (!c || !ret_frame)
                return -EINVAL;
        if (!c->acquiring)
                return -ENOTCONN;
        if (!dst)
                return -EINVAL;
        struct imp_frame f = {};
        int r = c->ops->grab(c->state, timeout_ms, dst, dst_size, &f);
        if (r == -ENODEV) {
                /* Unplugged: release the stream now, so nothing waits on a dead device. */
                c->acquiring = false;
                if (c->ops->stop)
                        (void) c->ops->stop(c->state);
        }
        if (r < 0)
                return r;
        f.data = dst;
        *ret_frame = f;
        return 0;
}

int imp_camera_grab(struct imp_camera *c, unsigned timeout_ms, const struct imp_frame **ret_frame) {
        if (!c || !ret_frame)
                return -EINVAL;
        int r = imp_camera_grab_into(c, timeout_ms, c->buf, c->buf_size, &c->frame);
        if (r < 0)
                return r;
        *ret_frame = &c->frame;
        return 0;
}

const char *imp_camera_last_error(const struct imp_camera *c) {
        const char *e = c && c->ops->last_error ? c->ops->last_error(c->state) : NULL;
        return e ? e : "";
}
