/* V4L2 capture device emulator: a umockdev testbed /dev/videoN whose ioctls (and read())
 * are answered here, so the real "v4l2" backend runs against it. Single-planar capture,
 * GREY and Y16, exposure and gain controls, MMAP/USERPTR buffer queues and read() I/O.
 *
 * umockdev forwards ioctl() and read() on the node to this handler but not mmap() or
 * poll(): MMAP buffers can be requested and queried (so a driver meets a device that
 * offers them) but mapping fails, as it does for the client; USERPTR buffers are filled at
 * DQBUF by writing through the caller's pointer (umockdev_ioctl_data_resolve on the
 * m.userptr field, set from what QBUF gave); DQBUF never blocks and answers EAGAIN until a
 * frame is due, so a client has to treat poll() as a hint. */
#include <linux/videodev2.h>
#include <pthread.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <umockdev.h>
#include "emu.h"

#define MAX_BUFFERS 32
#define PFNC_MONO8 0x01080001u
#define PFNC_MONO16 0x01100007u
#define EXPOSURE_MIN_100US 1
#define EXPOSURE_MAX_100US 100000       /* 10 s */
#define EXPOSURE_DEFAULT_100US 100      /* 10 ms */
#define GAIN_MAX 255
#define PAGE_BYTES 4096u

struct buffer {
        bool queued;
        unsigned long userptr;
        uint32_t length;
};

struct imp_emu_v4l2 {
        struct imp_emu_v4l2_config cfg;
        char devnode[64];
        struct imp_emu_rig *rig;
        imp_emu_fill_fn fill;
        void *userdata;
        UMockdevTestbed *tb;
        UMockdevIoctlBase *handler;
        pthread_mutex_t lock;

        uint32_t pixelformat;           /* V4L2_PIX_FMT_GREY or _Y16 */
        int32_t exposure_100us;
        int32_t gain;
        unsigned memory;                /* of the requested buffers, 0 none */
        unsigned last_memory;
        unsigned n_buffers;
        struct buffer buffers[MAX_BUFFERS];
        unsigned queue[MAX_BUFFERS];    /* FIFO of queued indices */
        unsigned q_head, q_len;
        bool streaming;
        uint32_t sequence;
        uint64_t last_frame_ns;
        uint64_t frames;
        uint8_t *read_frame;            /* read() I/O: one frame rendered here, then copied */

        unsigned drop_countdown;
        unsigned fail_countdown;
        int fail_errno;
        bool disconnected;
        bool paused;
};

static const uint32_t pixel_formats[] = { V4L2_PIX_FMT_GREY, V4L2_PIX_FMT_Y16 };

static uint64_t now_ns(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000000u + (uint64_t) ts.tv_nsec;
}

static unsigned bpp_locked(const struct imp_emu_v4l2 *e) {
        return e->pixelformat == V4L2_PIX_FMT_Y16 ? 2 : 1;
}

static uint32_t frame_bytes_locked(const struct imp_emu_v4l2 *e) {
        return e->cfg.width * e->cfg.height * bpp_locked(e);
}

static void *resolve(UMockdevIoctlData *arg, size_t size) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, size, &err);
        g_clear_error(&err);
        return d ? d->data : NULL;
}

static int do_querycap(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg) {
        struct v4l2_capability *cap = resolve(arg, sizeof *cap);
        if (!cap)
                return EFAULT;
        memset(cap, 0, sizeof *cap);
        snprintf((char *) cap->driver, sizeof cap->driver, "impasto-emu");
        snprintf((char *) cap->card, sizeof cap->card, "%s", e->cfg.card);
        snprintf((char *) cap->bus_info, sizeof cap->bus_info, "platform:v4l2-emu.0");
        cap->version = 0x060100;
        cap->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING |
                           (e->cfg.no_read ? 0 : V4L2_CAP_READWRITE);
        cap->capabilities = cap->device_caps | V4L2_CAP_DEVICE_CAPS;
        return 0;
}

static int do_enum_fmt(UMockdevIoctlData *arg) {
        struct v4l2_fmtdesc *fd = resolve(arg, sizeof *fd);
        if (!fd)
                return EFAULT;
        if (fd->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || fd->index >= ARRAY_SIZE(pixel_formats))
                return EINVAL;
        uint32_t index = fd->index;
        memset(fd, 0, sizeof *fd);
        fd->index = index;
        fd->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        fd->pixelformat = pixel_formats[index];
        snprintf((char *) fd->description, sizeof fd->description, "%s",
                 index == 0 ? "8-bit Greyscale" : "16-bit Greyscale");
        return 0;
}

static void fill_pix_locked(const struct imp_emu_v4l2 *e, struct v4l2_format *f) {
        memset(&f->fmt.pix, 0, sizeof f->fmt.pix);
        f->fmt.pix.width = e->cfg.width;
        f->fmt.pix.height = e->cfg.height;
        f->fmt.pix.pixelformat = e->pixelformat;
        f->fmt.pix.field = V4L2_FIELD_NONE;
        f->fmt.pix.bytesperline = e->cfg.width * bpp_locked(e);
        f->fmt.pix.sizeimage = frame_bytes_locked(e);
        f->fmt.pix.colorspace = V4L2_COLORSPACE_RAW;
}

/* S_FMT and TRY_FMT: the sensor size is fixed; an unknown format becomes GREY, as drivers
 * substitute rather than refuse. */
static int do_fmt(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg, bool set, bool try) {
        struct v4l2_format *f = resolve(arg, sizeof *f);
        if (!f)
                return EFAULT;
        if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
                return EINVAL;
        if (!set) {
                fill_pix_locked(e, f);
                return 0;
        }
        uint32_t want = f->fmt.pix.pixelformat == V4L2_PIX_FMT_Y16 ? V4L2_PIX_FMT_Y16 : V4L2_PIX_FMT_GREY;
        if (!try && e->n_buffers > 0)
                return EBUSY;
        uint32_t keep = e->pixelformat;
        e->pixelformat = want;
        fill_pix_locked(e, f);
        if (try)
                e->pixelformat = keep;
        return 0;
}

static int do_queryctrl(UMockdevIoctlData *arg) {
        struct v4l2_queryctrl *q = resolve(arg, sizeof *q);
        if (!q)
                return EFAULT;
        uint32_t id = q->id;
        memset(q, 0, sizeof *q);
        q->id = id;
        q->type = V4L2_CTRL_TYPE_INTEGER;
        q->step = 1;
        if (id == V4L2_CID_EXPOSURE_ABSOLUTE) {
                snprintf((char *) q->name, sizeof q->name, "Exposure Time, Absolute");
                q->minimum = EXPOSURE_MIN_100US;
                q->maximum = EXPOSURE_MAX_100US;
                q->default_value = EXPOSURE_DEFAULT_100US;
        } else if (id == V4L2_CID_GAIN) {
                snprintf((char *) q->name, sizeof q->name, "Gain");
                q->maximum = GAIN_MAX;
        } else
                return EINVAL;
        return 0;
}

/* Integer controls are clamped to their range, as the kernel's control framework does. */
static int do_ctrl(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg, bool set) {
        struct v4l2_control *c = resolve(arg, sizeof *c);
        if (!c)
                return EFAULT;
        int32_t *v;
        int32_t lo, hi;
        if (c->id == V4L2_CID_EXPOSURE_ABSOLUTE) {
                v = &e->exposure_100us;
                lo = EXPOSURE_MIN_100US;
                hi = EXPOSURE_MAX_100US;
        } else if (c->id == V4L2_CID_GAIN) {
                v = &e->gain;
                lo = 0;
                hi = GAIN_MAX;
        } else
                return EINVAL;
        if (set)
                *v = IMP_CLAMP(c->value, lo, hi);
        c->value = *v;
        return 0;
}

static int do_reqbufs(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg) {
        struct v4l2_requestbuffers *rb = resolve(arg, sizeof *rb);
        if (!rb)
                return EFAULT;
        if (rb->type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
                return EINVAL;
        if (rb->memory != V4L2_MEMORY_MMAP && rb->memory != V4L2_MEMORY_USERPTR)
                return EINVAL;
        if (rb->memory == V4L2_MEMORY_USERPTR && e->cfg.no_userptr)
                return EINVAL;
        if (e->streaming)
                return EBUSY;
        memset(e->buffers, 0, sizeof e->buffers);
        e->q_head = e->q_len = 0;
        e->n_buffers = IMP_MIN(rb->count, (uint32_t) MAX_BUFFERS);
        e->memory = e->n_buffers ? rb->memory : 0;
        if (e->n_buffers)
                e->last_memory = rb->memory;
        rb->count = e->n_buffers;
        rb->capabilities = V4L2_BUF_CAP_SUPPORTS_MMAP | (e->cfg.no_userptr ? 0 : V4L2_BUF_CAP_SUPPORTS_USERPTR);
        memset(rb->reserved, 0, sizeof rb->reserved);
        return 0;
}

static uint32_t mmap_stride_locked(const struct imp_emu_v4l2 *e) {
        return (frame_bytes_locked(e) + PAGE_BYTES - 1) / PAGE_BYTES * PAGE_BYTES;
}

static void describe_buffer_locked(const struct imp_emu_v4l2 *e, unsigned index, struct v4l2_buffer *b) {
        const struct buffer *buf = &e->buffers[index];
        b->index = index;
        b->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
        b->memory = e->memory;
        b->field = V4L2_FIELD_NONE;
        b->flags = V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC | V4L2_BUF_FLAG_TSTAMP_SRC_EOF |
                   (buf->queued ? V4L2_BUF_FLAG_QUEUED : 0);
        if (e->memory == V4L2_MEMORY_MMAP) {
                b->m.offset = index * mmap_stride_locked(e);
                b->length = frame_bytes_locked(e);
        } else {
                b->m.userptr = buf->userptr;
                b->length = buf->length;
        }
}

static int do_querybuf(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg) {
        struct v4l2_buffer *b = resolve(arg, sizeof *b);
        if (!b)
                return EFAULT;
        if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->index >= e->n_buffers)
                return EINVAL;
        describe_buffer_locked(e, b->index, b);
        return 0;
}

static int do_qbuf(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg) {
        struct v4l2_buffer *b = resolve(arg, sizeof *b);
        if (!b)
                return EFAULT;
        if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->index >= e->n_buffers || b->memory != e->memory)
                return EINVAL;
        struct buffer *buf = &e->buffers[b->index];
        if (buf->queued)
                return EINVAL;
        if (e->memory == V4L2_MEMORY_USERPTR) {
                if (!b->m.userptr || b->length < frame_bytes_locked(e))
                        return EINVAL;
                buf->userptr = b->m.userptr;
                buf->length = b->length;
        }
        buf->queued = true;
        e->queue[(e->q_head + e->q_len++) % MAX_BUFFERS] = b->index;
        describe_buffer_locked(e, b->index, b);
        return 0;
}

static bool frame_due_locked(struct imp_emu_v4l2 *e, uint64_t now) {
        return !e->paused && (e->cfg.frame_interval_us == 0 ||
                              now >= e->last_frame_ns + (uint64_t) e->cfg.frame_interval_us * 1000u);
}

static int render_locked(struct imp_emu_v4l2 *e, void *pixels) {
        struct imp_emu_camera_state st = {
                .exposure_us = (uint32_t) e->exposure_100us * 100u,
                .gain_raw = (uint32_t) e->gain,
                .pixel_format = bpp_locked(e) == 2 ? PFNC_MONO16 : PFNC_MONO8,
                .lit_light = imp_emu_rig_lit_light(e->rig),
                .pattern = imp_emu_rig_get_pattern(e->rig),
                .n_lights = imp_emu_rig_n_lights(e->rig),
                .frame_index = e->frames,
        };
        imp_emu_rig_get_lights(e->rig, st.level_permille, IMP_EMU_MAX_LIGHTS);
        int r = e->fill(e->userdata, &st, pixels, (int) e->cfg.width, (int) e->cfg.height, (int) bpp_locked(e));
        e->frames++;
        return r;
}

/* A frame is due now; the drop fault spends its sequence number without a buffer. */
static void advance_frame_locked(struct imp_emu_v4l2 *e, uint64_t now) {
        e->last_frame_ns = now;
        if (e->drop_countdown && --e->drop_countdown == 0)
                e->sequence++;
}

static int do_dqbuf(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg) {
        GError *err = NULL;
        UMockdevIoctlData *d = umockdev_ioctl_data_resolve(arg, 0, sizeof(struct v4l2_buffer), &err);
        g_clear_error(&err);
        if (!d)
                return EFAULT;
        struct v4l2_buffer *b = (struct v4l2_buffer *) d->data;
        if (b->type != V4L2_BUF_TYPE_VIDEO_CAPTURE || b->memory != e->memory)
                return EINVAL;
        if (e->fail_countdown && --e->fail_countdown == 0)
                return e->fail_errno;
        if (!e->streaming)
                return EINVAL;
        uint64_t now = now_ns();
        if (e->q_len == 0 || !frame_due_locked(e, now))
                return EAGAIN;
        advance_frame_locked(e, now);
        unsigned index = e->queue[e->q_head];
        e->q_head = (e->q_head + 1) % MAX_BUFFERS;
        e->q_len--;
        e->buffers[index].queued = false;
        memset(b, 0, sizeof *b);
        describe_buffer_locked(e, index, b);
        if (e->memory == V4L2_MEMORY_USERPTR) {
                /* m.userptr now holds the caller's address: resolving it gives a local copy
                 * that umockdev writes back into the caller's buffer when the ioctl completes. */
                UMockdevIoctlData *pix = umockdev_ioctl_data_resolve(d, offsetof(struct v4l2_buffer, m.userptr),
                                                                     frame_bytes_locked(e), &err);
                g_clear_error(&err);
                if (!pix)
                        return EFAULT;
                (void) render_locked(e, pix->data);
        } else
                e->frames++;    /* MMAP: nobody can see the pixels, the frame still counts */
        b->bytesused = frame_bytes_locked(e);
        b->sequence = e->sequence++;
        b->timestamp.tv_sec = (time_t) (now / 1000000000u);
        b->timestamp.tv_usec = (suseconds_t) (now % 1000000000u / 1000u);
        return 0;
}

static int do_stream(struct imp_emu_v4l2 *e, UMockdevIoctlData *arg, bool on) {
        int *type = resolve(arg, sizeof *type);
        if (!type)
                return EFAULT;
        if (*type != V4L2_BUF_TYPE_VIDEO_CAPTURE)
                return EINVAL;
        if (!on) {
                /* STREAMOFF returns every buffer to the caller, queued or not. */
                e->streaming = false;
                for (unsigned i = 0; i < e->n_buffers; i++)
                        e->buffers[i].queued = false;
                e->q_head = e->q_len = 0;
                return 0;
        }
        if (e->n_buffers == 0)
                return EINVAL;
        if (!e->streaming) {
                e->streaming = true;
                e->sequence = 0;
                e->last_frame_ns = now_ns();
        }
        return 0;
}

static gboolean on_ioctl(UMockdevIoctlBase *handler, UMockdevIoctlClient *client, gpointer data) {
        struct imp_emu_v4l2 *e = data;
        gulong request = umockdev_ioctl_client_get_request(client);
        UMockdevIoctlData *arg = umockdev_ioctl_client_get_arg(client);
        int err;
        pthread_mutex_lock(&e->lock);
        if (e->disconnected)
                err = ENODEV;
        else
                switch (request) {
                case VIDIOC_QUERYCAP: err = do_querycap(e, arg); break;
                case VIDIOC_ENUM_FMT: err = do_enum_fmt(arg); break;
                case VIDIOC_G_FMT: err = do_fmt(e, arg, false, false); break;
                case VIDIOC_S_FMT: err = do_fmt(e, arg, true, false); break;
                case VIDIOC_TRY_FMT: err = do_fmt(e, arg, true, true); break;
                case VIDIOC_QUERYCTRL: err = do_queryctrl(arg); break;
                case VIDIOC_G_CTRL: err = do_ctrl(e, arg, false); break;
                case VIDIOC_S_CTRL: err = do_ctrl(e, arg, true); break;
                case VIDIOC_REQBUFS: err = do_reqbufs(e, arg); break;
                case VIDIOC_QUERYBUF: err = do_querybuf(e, arg); break;
                case VIDIOC_QBUF: err = do_qbuf(e, arg); break;
                case VIDIOC_DQBUF: err = do_dqbuf(e, arg); break;
                case VIDIOC_STREAMON: err = do_stream(e, arg, true); break;
                case VIDIOC_STREAMOFF: err = do_stream(e, arg, false); break;
                default: err = ENOTTY; break;
                }
        pthread_mutex_unlock(&e->lock);
        umockdev_ioctl_client_complete(client, err ? -1 : 0, err);
        return TRUE;
}

/* read() I/O: one whole frame per call (a short buffer gets its first bytes), EAGAIN
 * until a frame is due, EBUSY while streaming buffers are set up. */
static gboolean on_read(UMockdevIoctlBase *handler, UMockdevIoctlClient *client, gpointer data) {
        struct imp_emu_v4l2 *e = data;
        UMockdevIoctlData *arg = umockdev_ioctl_client_get_arg(client);
        long res = -1;
        int err = 0;
        pthread_mutex_lock(&e->lock);
        uint64_t now = now_ns();
        size_t frame = frame_bytes_locked(e);
        if (e->disconnected)
                err = ENODEV;
        else if (e->cfg.no_read)
                err = EINVAL;
        else if (e->n_buffers > 0)
                err = EBUSY;
        else if (!frame_due_locked(e, now))
                err = EAGAIN;
        else {
                if (e->fail_countdown && --e->fail_countdown == 0)
                        err = e->fail_errno;
                else {
                        advance_frame_locked(e, now);
                        e->sequence++;
                        e->last_memory = 0;
                        (void) render_locked(e, e->read_frame);
                        size_t n = IMP_MIN(frame, (size_t) arg->data_len);
                        umockdev_ioctl_data_update(arg, 0, e->read_frame, (gint) n);
                        res = (long) n;
                }
        }
        pthread_mutex_unlock(&e->lock);
        umockdev_ioctl_client_complete(client, res, err);
        return TRUE;
}

int imp_emu_v4l2_new(const struct imp_emu_v4l2_config *cfg, struct imp_emu_rig *rig,
                     imp_emu_fill_fn fill, void *userdata, struct imp_emu_v4l2 **ret_emu) {
        if (!ret_emu)
                return -EINVAL;
        if (!imp_emu_gpio_available())  /* the same preload check */
                return -ENOTSUP;
        struct imp_emu_v4l2 *e = calloc(1, sizeof *e);
        if (!e)
                return -ENOMEM;
        if (cfg)
                e->cfg = *cfg;
        if (!e->cfg.video_name)
                e->cfg.video_name = "video0";
        if (!e->cfg.card)
                e->cfg.card = "impasto emulated camera";
        if (!e->cfg.width)
                e->cfg.width = 320;
        if (!e->cfg.height)
                e->cfg.height = 240;
        e->rig = rig;
        e->fill = fill ? fill : imp_emu_fill_default;
        e->userdata = userdata;
        e->pixelformat = V4L2_PIX_FMT_GREY;
        e->exposure_100us = EXPOSURE_DEFAULT_100US;
        pthread_mutex_init(&e->lock, NULL);
        int r = -EINVAL;
        if (strlen(e->cfg.video_name) > 32 || e->cfg.width > 16384 || e->cfg.height > 16384)
                goto fail;
        r = -ENOMEM;
        e->read_frame = malloc((size_t) e->cfg.width * e->cfg.height * 2);
        if (!e->read_frame)
                goto fail;
        snprintf(e->devnode, sizeof e->devnode, "/dev/%s", e->cfg.video_name);

        e->tb = umockdev_testbed_new();
        char record[512];
        /* Attribute values carry their trailing newline, as in real sysfs. */
        snprintf(record, sizeof record,
                 "P: /devices/platform/v4l2-emu.0/video4linux/%s\nN: %s\nE: SUBSYSTEM=video4linux\n"
                 "E: DEVNAME=%s\nA: dev=81:0\\n\nA: name=%s\\n\n",
                 e->cfg.video_name, e->cfg.video_name, e->devnode, e->cfg.card);
        GError *err = NULL;
        r = -EIO;
        if (!umockdev_testbed_add_from_string(e->tb, record, &err))
                goto fail_gerror;
        e->handler = umockdev_ioctl_base_new();
        g_signal_connect(e->handler, "handle-ioctl", G_CALLBACK(on_ioctl), e);
        g_signal_connect(e->handler, "handle-read", G_CALLBACK(on_read), e);
        if (!umockdev_testbed_attach_ioctl(e->tb, e->devnode, e->handler, &err))
                goto fail_gerror;
        *ret_emu = e;
        return 0;
fail_gerror:
        g_clear_error(&err);
fail:
        imp_emu_v4l2_free(e);
        return r;
}

void imp_emu_v4l2_free(struct imp_emu_v4l2 *e) {
        if (!e)
                return;
        if (e->tb && e->handler)
                umockdev_testbed_detach_ioctl(e->tb, e->devnode, NULL);
        g_clear_object(&e->handler);
        g_clear_object(&e->tb);
        pthread_mutex_destroy(&e->lock);
        free(e->read_frame);
        free(e);
}

const char *imp_emu_v4l2_devnode(const struct imp_emu_v4l2 *e) {
        return e ? e->devnode : NULL;
}

#define LOCKED(e, stmt) do { pthread_mutex_lock(&(e)->lock); stmt; pthread_mutex_unlock(&(e)->lock); } while (0)

uint64_t imp_emu_v4l2_frames_filled(struct imp_emu_v4l2 *e) {
        uint64_t n;
        LOCKED(e, n = e->frames);
        return n;
}

void imp_emu_v4l2_drop_nth(struct imp_emu_v4l2 *e, unsigned nth) {
        LOCKED(e, e->drop_countdown = nth);
}

void imp_emu_v4l2_fail_dqbuf_nth(struct imp_emu_v4l2 *e, unsigned nth, int err) {
        LOCKED(e, e->fail_countdown = nth; e->fail_errno = err);
}

void imp_emu_v4l2_disconnect(struct imp_emu_v4l2 *e) {
        LOCKED(e, e->disconnected = true; e->streaming = false);
}

void imp_emu_v4l2_pause(struct imp_emu_v4l2 *e, bool paused) {
        LOCKED(e, e->paused = paused);
}

unsigned imp_emu_v4l2_memory(struct imp_emu_v4l2 *e) {
        unsigned m;
        LOCKED(e, m = e->last_memory);
        return m;
}

bool imp_emu_v4l2_streaming(struct imp_emu_v4l2 *e) {
        bool s;
        LOCKED(e, s = e->streaming);
        return s;
}
