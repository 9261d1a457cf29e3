/* Camera backend "v4l2": monochrome capture devices through the kernel V4L2 API (no
 * libv4l). Opens /dev/videoN by path, negotiates GREY/Y12/Y16 and reports what the driver
 * granted, exposure (V4L2_CID_EXPOSURE_ABSOLUTE, 100 µs units) and gain (V4L2_CID_GAIN, raw),
 * and streams with the I/O method it can get: mmap, else user pointers, else read(). */
#include <fcntl.h>
#include <linux/videodev2.h>
#include <math.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <time.h>
#include <unistd.h>
#include "address.h"
#include "camera.h"

#define MAX_BUFFERS 32
#define EXPOSURE_UNIT_US 100.0          /* V4L2_CID_EXPOSURE_ABSOLUTE counts 100 µs steps */
/* poll() is a hint, not the deadline: a device may not wake pollers (umockdev forwards
 * ioctl and read but not poll), so DQBUF is retried at least this often. */
#define POLL_SLICE_MS 5

enum io_method { IO_NONE, IO_MMAP, IO_USERPTR, IO_READ };
static const char *const io_names[] = { [IO_NONE] = "auto", [IO_MMAP] = "mmap",
                                        [IO_USERPTR] = "userptr", [IO_READ] = "read" };

struct buffer {
        void *start;
        size_t length;
};

struct cam_v4l2 {
        char path[128];
        int fd;
        struct v4l2_capability cap;
        uint32_t caps;                  /* the node's own capabilities */
        enum io_method io_forced;       /* address option io=, IO_NONE: choose */
        enum io_method io;              /* of the running stream, IO_NONE when stopped */
        struct v4l2_pix_format pix;     /* granted by the driver */
        unsigned n_buffers;
        struct buffer buffers[MAX_BUFFERS];
        void *read_buf;                 /* read() I/O: one frame */
        bool have_sequence;
        uint32_t last_sequence;
        uint64_t n_read_frames;
        uint64_t n_underruns;
        uint64_t n_failures;
        char error[384];
};

static const struct {
        enum imp_pixel_format format;
        uint32_t fourcc;
} formats[] = {
        { IMP_PIXEL_MONO8, V4L2_PIX_FMT_GREY },
        { IMP_PIXEL_MONO12, V4L2_PIX_FMT_Y12 },
        { IMP_PIXEL_MONO16, V4L2_PIX_FMT_Y16 },
};

static enum imp_pixel_format format_of(uint32_t fourcc) {
        for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                if (formats[i].fourcc == fourcc)
                        return formats[i].format;
        return IMP_PIXEL_NONE;
}

static int xioctl(int fd, unsigned long request, void *arg) {
        int r;
        do
                r = ioctl(fd, request, arg);
        while (r < 0 && errno == EINTR);
        return r < 0 ? negative_errno() : 0;
}

/* Keep the detail of a failure for last_error, naming the device; returns r. */
_printf_(3, 4)
static int fail(struct cam_v4l2 *c, int r, const char *fmt, ...) {
        char what[192];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(what, sizeof what, fmt, ap);
        va_end(ap);
        snprintf(c->error, sizeof c->error, "%s: %s: %s", c->path, what, strerror(-r));
        return r;
}

static uint64_t clock_ns(clockid_t id) {
        struct timespec ts;
        clock_gettime(id, &ts);
        return (uint64_t) ts.tv_sec * 1000000000u + (uint64_t) ts.tv_nsec;
}

static uint32_t supported_formats(struct cam_v4l2 *c) {
        uint32_t set = 0;
        for (uint32_t i = 0; i < 64; i++) {
                struct v4l2_fmtdesc fd = { .index = i, .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };
                if (xioctl(c->fd, VIDIOC_ENUM_FMT, &fd) < 0)
                        break;
                enum imp_pixel_format f = format_of(fd.pixelformat);
                if (f != IMP_PIXEL_NONE)
                        set |= IMP_PIXEL_BIT(f);
        }
        return set;
}

static int get_format(struct cam_v4l2 *c) {
        struct v4l2_format f = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };
        int r = xioctl(c->fd, VIDIOC_G_FMT, &f);
        if (r < 0)
                return fail(c, r, "VIDIOC_G_FMT");
        c->pix = f.fmt.pix;
        return 0;
}

static int set_format(struct cam_v4l2 *c, uint32_t fourcc) {
        struct v4l2_format f = { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };
        f.fmt.pix = c->pix;
        f.fmt.pix.pixelformat = fourcc;
        f.fmt.pix.field = V4L2_FIELD_NONE;
        f.fmt.pix.bytesperline = 0;     /* let the driver choose its stride */
        f.fmt.pix.sizeimage = 0;
        int r = xioctl(c->fd, VIDIOC_S_FMT, &f);
        if (r < 0)
                return fail(c, r, "VIDIOC_S_FMT %.4s", (const char *) &fourcc);
        c->pix = f.fmt.pix;             /* what was granted, which is what frames will be */
        if (c->pix.pixelformat != fourcc)
                return fail(c, -EOPNOTSUPP, "asked for %.4s, the driver granted %.4s",
                            (const char *) &fourcc, (const char *) &c->pix.pixelformat);
        return 0;
}

static int parse_io(const char *address, enum io_method *ret) {
        char buf[16];
        int r = address_option(address, "io", buf, sizeof buf);
        if (r == -ENOENT)
                return 0;
        if (r < 0)
                return r;
        for (size_t i = 0; i < ARRAY_SIZE(io_names); i++)
                if (strcmp(buf, io_names[i]) == 0) {
                        *ret = (enum io_method) i;
                        return 0;
                }
        return -EINVAL;
}

static void cam_close(void *state);

static int cam_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct cam_v4l2 *c = calloc(1, sizeof *c);
        if (!c)
                return -ENOMEM;
        c->fd = -1;
        char node[sizeof c->path - 8];     /* room for "/dev/" */
        int r = address_main(address, node, sizeof node);
        if (r >= 0)
                r = parse_io(address, &c->io_forced);
        if (r < 0)
                goto fail;
        /* "video0" is short for "/dev/video0". */
        snprintf(c->path, sizeof c->path, "%s%s", node[0] == '/' ? "" : "/dev/", node);
        /* Non-blocking: DQBUF and read answer EAGAIN, grab waits with its own deadline. */
        c->fd = open(c->path, O_RDWR | O_NONBLOCK | O_CLOEXEC);
        if (c->fd < 0) {
                r = errno == ENOENT ? -ENODEV : negative_errno();
                goto fail;
        }
        if ((r = xioctl(c->fd, VIDIOC_QUERYCAP, &c->cap)) < 0) {
                if (r == -ENOTTY || r == -EINVAL)
                        r = -ENODEV;    /* not a V4L2 node */
                goto fail;
        }
        c->caps = c->cap.capabilities & V4L2_CAP_DEVICE_CAPS ? c->cap.device_caps : c->cap.capabilities;
        r = -ENODEV;
        if (!(c->caps & V4L2_CAP_VIDEO_CAPTURE) || !(c->caps & (V4L2_CAP_STREAMING | V4L2_CAP_READWRITE)))
                goto fail;
        if ((r = get_format(c)) < 0)
                goto fail;
        /* Start from a format this interface knows, when the device offers one. */
        if (format_of(c->pix.pixelformat) == IMP_PIXEL_NONE) {
                uint32_t set = supported_formats(c);
                for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                        if (set & IMP_PIXEL_BIT(formats[i].format)) {
                                (void) set_format(c, formats[i].fourcc);
                                break;
                        }
        }
        /* UVC cameras ignore the absolute exposure while auto exposure is on; devices
         * without the control answer EINVAL, which is fine. */
        struct v4l2_control manual = { .id = V4L2_CID_EXPOSURE_AUTO, .value = V4L2_EXPOSURE_MANUAL };
        (void) xioctl(c->fd, VIDIOC_S_CTRL, &manual);
        c->error[0] = 0;
        *ret_state = c;
        return 0;
fail:
        cam_close(c);
        return r;
}

static int cam_get_info(void *state, struct imp_camera_info *ret) {
        struct cam_v4l2 *c = state;
        int r = get_format(c);
        if (r < 0)
                return r;
        snprintf(ret->vendor, sizeof ret->vendor, "%s", (const char *) c->cap.driver);
        snprintf(ret->model, sizeof ret->model, "%s", (const char *) c->cap.card);
        snprintf(ret->serial, sizeof ret->serial, "%s", (const char *) c->cap.bus_info);
        ret->sensor_width = ret->width = c->pix.width;
        ret->sensor_height = ret->height = c->pix.height;
        ret->pixel_format = format_of(c->pix.pixelformat);
        ret->pixel_formats = supported_formats(c);
        struct v4l2_control ctrl = { .id = V4L2_CID_EXPOSURE_ABSOLUTE };
        if (xioctl(c->fd, VIDIOC_G_CTRL, &ctrl) == 0)
                ret->exposure_us = ctrl.value * EXPOSURE_UNIT_US;
        ctrl = (struct v4l2_control) { .id = V4L2_CID_GAIN };
        if (xioctl(c->fd, VIDIOC_G_CTRL, &ctrl) == 0)
                ret->gain_db = ctrl.value;
        return 0;
}

/* An integer control within its advertised range: -EOPNOTSUPP when the device lacks it,
 * -EINVAL outside the range (the kernel would clamp silently and mislabel the frames). */
static int set_control(struct cam_v4l2 *c, uint32_t id, const char *name, double value) {
        struct v4l2_queryctrl q = { .id = id };
        int r = xioctl(c->fd, VIDIOC_QUERYCTRL, &q);
        if (r == -EINVAL || (r == 0 && (q.flags & V4L2_CTRL_FLAG_DISABLED)))
                return fail(c, -EOPNOTSUPP, "no %s control", name);
        if (r < 0)
                return fail(c, r, "VIDIOC_QUERYCTRL %s", name);
        long v = lround(value);
        if (v < q.minimum || v > q.maximum)
                return fail(c, -EINVAL, "%s %ld outside %d..%d", name, v, q.minimum, q.maximum);
        struct v4l2_control ctrl = { .id = id, .value = (int32_t) v };
        r = xioctl(c->fd, VIDIOC_S_CTRL, &ctrl);
        return r < 0 ? fail(c, r, "VIDIOC_S_CTRL %s=%ld", name, v) : 0;
}

static int cam_set_exposure_us(void *state, double exposure_us) {
        return set_control(state, V4L2_CID_EXPOSURE_ABSOLUTE, "exposure",
                           fmax(1, exposure_us / EXPOSURE_UNIT_US));
}

static int cam_set_gain_db(void *state, double gain_db) {
        return set_control(state, V4L2_CID_GAIN, "gain", gain_db);     /* raw units */
}

static int cam_set_pixel_format(void *state, enum imp_pixel_format format) {
        struct cam_v4l2 *c = state;
        if (c->io != IO_NONE)
                return -EBUSY;
        if (!(supported_formats(c) & IMP_PIXEL_BIT(format)))
                return fail(c, -EOPNOTSUPP, "%s not offered", imp_pixel_format_to_string(format));
        int r = get_format(c);
        if (r < 0)
                return r;
        for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                if (formats[i].format == format)
                        return set_format(c, formats[i].fourcc);
        return -EOPNOTSUPP;
}

static void release_buffers(struct cam_v4l2 *c, enum io_method io) {
        for (unsigned i = 0; i < c->n_buffers; i++) {
                struct buffer *b = &c->buffers[i];
                if (io == IO_MMAP && b->start && b->start != MAP_FAILED)
                        munmap(b->start, b->length);
                else if (io == IO_USERPTR)
                        free(b->start);
                *b = (struct buffer) {};
        }
        c->n_buffers = 0;
        free(c->read_buf);
        c->read_buf = NULL;
}

/* Ask for count buffers of memory type; 0 or a negative errno (the device refuses). */
static int request_buffers(struct cam_v4l2 *c, uint32_t memory, unsigned count) {
        struct v4l2_requestbuffers rb = { .count = count, .type = V4L2_BUF_TYPE_VIDEO_CAPTURE,
                                          .memory = memory };
        int r = xioctl(c->fd, VIDIOC_REQBUFS, &rb);
        if (r < 0)
                return r;
        if (count > 0 && rb.count == 0)
                return -ENOMEM;
        c->n_buffers = IMP_MIN(rb.count, (uint32_t) MAX_BUFFERS);
        return 0;
}

static void free_request(struct cam_v4l2 *c, uint32_t memory, enum io_method io) {
        release_buffers(c, io);
        (void) request_buffers(c, memory, 0);
}

static int queue_buffer(struct cam_v4l2 *c, unsigned index) {
        struct v4l2_buffer b = { .index = index, .type = V4L2_BUF_TYPE_VIDEO_CAPTURE };
        if (c->io == IO_MMAP)
                b.memory = V4L2_MEMORY_MMAP;
        else {
                b.memory = V4L2_MEMORY_USERPTR;
                b.m.userptr = (unsigned long) c->buffers[index].start;
                b.length = (uint32_t) c->buffers[index].length;
        }
        int r = xioctl(c->fd, VIDIOC_QBUF, &b);
        return r < 0 ? fail(c, r, "VIDIOC_QBUF %u", index) : 0;
}

static int setup_mmap(struct cam_v4l2 *c, unsigned count) {
        int r = request_buffers(c, V4L2_MEMORY_MMAP, count);
        if (r < 0)
                return r;
        for (unsigned i = 0; i < c->n_buffers; i++) {
                struct v4l2_buffer b = { .index = i, .type = V4L2_BUF_TYPE_VIDEO_CAPTURE,
                                         .memory = V4L2_MEMORY_MMAP };
                if ((r = xioctl(c->fd, VIDIOC_QUERYBUF, &b)) < 0)
                        break;
                void *p = mmap(NULL, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, c->fd, b.m.offset);
                if (p == MAP_FAILED) {
                        r = negative_errno();
                        break;
                }
                c->buffers[i] = (struct buffer) { .start = p, .length = b.length };
        }
        if (r < 0)
                free_request(c, V4L2_MEMORY_MMAP, IO_MMAP);
        return r;
}

static int setup_userptr(struct cam_v4l2 *c, unsigned count) {
        long page = sysconf(_SC_PAGESIZE);
        size_t length = ((size_t) c->pix.sizeimage + (size_t) page - 1) / (size_t) page * (size_t) page;
        int r = request_buffers(c, V4L2_MEMORY_USERPTR, count);
        if (r < 0)
                return r;
        for (unsigned i = 0; i < c->n_buffers && r == 0; i++) {
                if (posix_memalign(&c->buffers[i].start, (size_t) page, length) != 0)
                        r = -ENOMEM;
                else
                        c->buffers[i].length = length;
        }
        if (r < 0)
                free_request(c, V4L2_MEMORY_USERPTR, IO_USERPTR);
        return r;
}

static int setup_read(struct cam_v4l2 *c) {
        if (!(c->caps & V4L2_CAP_READWRITE))
                return -EOPNOTSUPP;
        c->read_buf = malloc(c->pix.sizeimage);
        return c->read_buf ? 0 : -ENOMEM;
}

/* The first method the device grants, in order of preference, or the forced one. */
static int setup_io(struct cam_v4l2 *c, unsigned count) {
        bool streaming = c->caps & V4L2_CAP_STREAMING;
        int r = -EOPNOTSUPP;
        if (streaming && (c->io_forced == IO_NONE || c->io_forced == IO_MMAP)) {
                if ((r = setup_mmap(c, count)) == 0)
                        return c->io = IO_MMAP, 0;
                if (c->io_forced == IO_MMAP)
                        return fail(c, r, "mmap streaming I/O");
        }
        if (streaming && (c->io_forced == IO_NONE || c->io_forced == IO_USERPTR)) {
                if ((r = setup_userptr(c, count)) == 0)
                        return c->io = IO_USERPTR, 0;
                if (c->io_forced == IO_USERPTR)
                        return fail(c, r, "user-pointer streaming I/O");
        }
        if ((r = setup_read(c)) == 0)
                return c->io = IO_READ, 0;
        return fail(c, r, "no I/O method: mmap, user pointers and read() all refused");
}

static int cam_stop(void *state) {
        struct cam_v4l2 *c = state;
        int r = 0;
        if (c->io == IO_MMAP || c->io == IO_USERPTR) {
                int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
                uint32_t memory = c->io == IO_MMAP ? V4L2_MEMORY_MMAP : V4L2_MEMORY_USERPTR;
                r = xioctl(c->fd, VIDIOC_STREAMOFF, &type);
                if (r < 0)
                        (void) fail(c, r, "VIDIOC_STREAMOFF");
                /* Unmap before REQBUFS 0: the driver keeps mapped buffers alive (EBUSY). */
                free_request(c, memory, c->io);
        } else
                release_buffers(c, c->io);
        c->io = IO_NONE;
        return r;
}

static void cam_close(void *state) {
        struct cam_v4l2 *c = state;
        if (!c)
                return;
        (void) cam_stop(c);
        if (c->fd >= 0)
                close(c->fd);
        free(c);
}

static int cam_start(void *state, const struct imp_camera_acq *acq) {
        struct cam_v4l2 *c = state;
        if (c->io != IO_NONE)
                return -EBUSY;
        if (acq->software_trigger)
                return fail(c, -EOPNOTSUPP, "V4L2 has no software trigger");
        int r = get_format(c);
        if (r < 0)
                return r;
        if (format_of(c->pix.pixelformat) == IMP_PIXEL_NONE)
                return fail(c, -EOPNOTSUPP, "format %.4s is not monochrome", (const char *) &c->pix.pixelformat);
        c->have_sequence = false;
        c->n_read_frames = c->n_underruns = c->n_failures = 0;
        if ((r = setup_io(c, IMP_MIN(acq->n_buffers, (unsigned) MAX_BUFFERS))) < 0)
                return r;
        if (c->io == IO_READ)
                return 0;
        for (unsigned i = 0; i < c->n_buffers && r == 0; i++)
                r = queue_buffer(c, i);
        int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        if (r == 0 && (r = xioctl(c->fd, VIDIOC_STREAMON, &type)) < 0)
                (void) fail(c, r, "VIDIOC_STREAMON");
        if (r < 0)
                (void) cam_stop(c);
        return r;
}

/* Wait for the device until deadline; -ETIMEDOUT once it has passed. */
static int wait_readable(struct cam_v4l2 *c, uint64_t deadline_ns) {
        uint64_t now = clock_ns(CLOCK_MONOTONIC);
        if (now >= deadline_ns)
                return -ETIMEDOUT;
        uint64_t left_ms = (deadline_ns - now + 999999) / 1000000;
        struct pollfd p = { .fd = c->fd, .events = POLLIN };
        if (poll(&p, 1, (int) IMP_MIN(left_ms, (uint64_t) POLL_SLICE_MS)) < 0 && errno != EINTR)
                return fail(c, negative_errno(), "poll");
        return 0;
}

/* Copy the rows of one frame, dropping the driver's line padding. */
static int copy_frame(struct cam_v4l2 *c, const void *src, size_t src_size, void *dst, size_t dst_size,
                      struct imp_frame *ret) {
        enum imp_pixel_format f = format_of(c->pix.pixelformat);
        size_t row = (size_t) c->pix.width * imp_pixel_format_bytes(f);
        size_t stride = IMP_MAX((size_t) c->pix.bytesperline, row);
        size_t need = row * c->pix.height;
        if (need > dst_size)
                return -EMSGSIZE;
        if (src_size < stride * (c->pix.height - 1) + row)
                return fail(c, -EIO, "short frame: %zu bytes of %zu", src_size, stride * c->pix.height);
        for (unsigned y = 0; y < c->pix.height; y++)
                memcpy((uint8_t *) dst + y * row, (const uint8_t *) src + y * stride, row);
        ret->width = c->pix.width;
        ret->height = c->pix.height;
        ret->stride_bytes = (unsigned) row;
        ret->size = need;
        ret->pixel_format = f;
        ret->meta.system_timestamp_ns = clock_ns(CLOCK_REALTIME);
        return 0;
}

static int grab_read(struct cam_v4l2 *c, uint64_t deadline_ns, void *dst, size_t dst_size,
                     struct imp_frame *ret) {
        for (;;) {
                ssize_t n = read(c->fd, c->read_buf, c->pix.sizeimage);
                if (n >= 0) {
                        int r = copy_frame(c, c->read_buf, (size_t) n, dst, dst_size, ret);
                        if (r == -EIO)
                                c->n_failures++;
                        if (r < 0)
                                return r;
                        /* read() carries no metadata: host clock, our own count. */
                        ret->meta.timestamp_ns = clock_ns(CLOCK_MONOTONIC);
                        ret->meta.frame_id = c->n_read_frames++;
                        ret->meta.n_failures = c->n_failures;
                        return 0;
                }
                if (errno != EAGAIN && errno != EINTR)
                        return fail(c, negative_errno(), "read");
                int r = wait_readable(c, deadline_ns);
                if (r < 0)
                        return r;
        }
}

static int grab_stream(struct cam_v4l2 *c, uint64_t deadline_ns, void *dst, size_t dst_size,
                       struct imp_frame *ret) {
        struct v4l2_buffer b;
        for (;;) {
                b = (struct v4l2_buffer) { .type = V4L2_BUF_TYPE_VIDEO_CAPTURE,
                                           .memory = c->io == IO_MMAP ? V4L2_MEMORY_MMAP : V4L2_MEMORY_USERPTR };
                int r = xioctl(c->fd, VIDIOC_DQBUF, &b);
                if (r == 0)
                        break;
                if (r != -EAGAIN)
                        return fail(c, r, "VIDIOC_DQBUF");
                if ((r = wait_readable(c, deadline_ns)) < 0)
                        return r;
        }
        if (b.index >= c->n_buffers)
                return fail(c, -EIO, "VIDIOC_DQBUF gave buffer %u of %u", b.index, c->n_buffers);
        /* A gap in the sequence is frames the driver dropped for want of a queued buffer. */
        if (c->have_sequence && b.sequence != c->last_sequence + 1)
                c->n_underruns += b.sequence - c->last_sequence - 1;
        c->have_sequence = true;
        c->last_sequence = b.sequence;
        int r;
        if (b.flags & V4L2_BUF_FLAG_ERROR) {
                c->n_failures++;
                r = fail(c, -EIO, "frame %u corrupt (V4L2_BUF_FLAG_ERROR)", b.sequence);
        } else
                r = copy_frame(c, c->buffers[b.index].start, IMP_MIN((size_t) b.bytesused, c->buffers[b.index].length),
                               dst, dst_size, ret);
        if (r == 0) {
                ret->meta.timestamp_ns = (uint64_t) b.timestamp.tv_sec * 1000000000u +
                                         (uint64_t) b.timestamp.tv_usec * 1000u;
                ret->meta.frame_id = b.sequence;
                ret->meta.n_underruns = c->n_underruns;
                ret->meta.n_failures = c->n_failures;
        }
        int q = queue_buffer(c, b.index);        /* back into the pool either way */
        return r < 0 ? r : q;
}

static int cam_grab(void *state, unsigned timeout_ms, void *dst, size_t dst_size, struct imp_frame *ret) {
        struct cam_v4l2 *c = state;
        uint64_t deadline_ns = clock_ns(CLOCK_MONOTONIC) + (uint64_t) timeout_ms * 1000000u;
        switch (c->io) {
        case IO_MMAP:
        case IO_USERPTR: return grab_stream(c, deadline_ns, dst, dst_size, ret);
        case IO_READ: return grab_read(c, deadline_ns, dst, dst_size, ret);
        default: return -ENOTCONN;
        }
}

_unused_ static const char *cam_last_error(void *state) {
        struct cam_v4l2 *c = state;
        return c->error;
}

const struct imp_camera_ops imp_camera_v4l2_ops = {
        .name = "v4l2",
        .open = cam_open,                       /* "/dev/video0[;io=mmap|userptr|read]" or "video0" */
        .close = cam_close,                     /* stops streaming, closes the node */
        .get_info = cam_get_info,               /* QUERYCAP, G_FMT, ENUM_FMT, G_CTRL */
        .set_exposure_us = cam_set_exposure_us, /* V4L2_CID_EXPOSURE_ABSOLUTE, 100 µs units */
        .set_gain_db = cam_set_gain_db,         /* V4L2_CID_GAIN, raw units */
        .set_pixel_format = cam_set_pixel_format, /* GREY, Y12, Y16 via S_FMT; -EOPNOTSUPP if not granted */
        .set_roi = NULL,                        /* cropping differs per driver: not supported */
        .start = cam_start,                     /* mmap, else USERPTR, else read() */
        .stop = cam_stop,                       /* STREAMOFF, buffers released */
        .trigger_software = NULL,               /* V4L2 has no software trigger */
        .grab = cam_grab,                       /* DQBUF (or read) with a deadline, copy, requeue */
#ifdef IMP_CAMERA_HAVE_LAST_ERROR
        .last_error = cam_last_error,           /* "/dev/video0: VIDIOC_DQBUF: ..." */
#endif
};
