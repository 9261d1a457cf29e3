/* Camera backend "aravis": GigE Vision and USB3 Vision cameras through Aravis 0.8.
 * Opens by address or device id, Mono8/12/16, exposure, gain, ROI, software trigger, a
 * stream with a buffer pool sized at start, stream statistics as frame counters. */
#include <arv.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "camera.h"

#define GV_FRAME_RETENTION_US 500000

/* GigE Vision bootstrap register "Version", readable on every GVCP device: a probe. */
#define GVBS_VERSION 0x0000

/* Stream buffers while free running: frames arrive without waiting for the client, so a
 * client busy for a few frame periods needs more than the triggered pool. */
#define FREE_RUN_MIN_BUFFERS 12

struct cam_arv {
        ArvCamera *cam;
        ArvStream *stream;
        struct imp_camera_acq acq;      /* as started: a restart repeats it */
        guint payload;
        unsigned extra_buffers;         /* pushed for free running, gone with the stream */
        char address[128];
        bool gone;              /* a grab found it unplugged: talk to it no more */
        char error[256];
};

static const struct {
        enum imp_pixel_format format;
        const char *name;
        ArvPixelFormat pfnc;
} formats[] = {
        { IMP_PIXEL_MONO8, "Mono8", ARV_PIXEL_FORMAT_MONO_8 },
        { IMP_PIXEL_MONO12, "Mono12", ARV_PIXEL_FORMAT_MONO_12 },
        { IMP_PIXEL_MONO16, "Mono16", ARV_PIXEL_FORMAT_MONO_16 },
};

/* Map an Aravis error once, keep its message for the caller, free it. */
static int take_error(struct cam_arv *c, GError **error) {
        if (!*error)
                return 0;
        int r = -EIO;
        if ((*error)->domain == ARV_DEVICE_ERROR) {
                switch ((*error)->code) {
                case ARV_DEVICE_ERROR_TIMEOUT: r = -ETIMEDOUT; break;
                case ARV_DEVICE_ERROR_NOT_FOUND: r = -ENODEV; break;
                case ARV_DEVICE_ERROR_FEATURE_NOT_FOUND: r = -EOPNOTSUPP; break;
                case ARV_DEVICE_ERROR_NOT_CONNECTED: r = -ENOTCONN; break;
                /* another controller holds the camera: one that died (SIGKILL, power loss)
                 * lets go when the camera's heartbeat timeout expires */
                case ARV_DEVICE_ERROR_NOT_CONTROLLER: r = -EBUSY; break;
                default: break;
                }
        } else if ((*error)->domain == ARV_GC_ERROR)
                r = -EINVAL;    /* value out of range, not writable, invalid enum entry */
        if (c)
                snprintf(c->error, sizeof c->error, "%s", (*error)->message);
        g_clear_error(error);
        return r;
}

static int cam_open(const char *address, unsigned timeout_ms, void **ret_state) {
        struct cam_arv *c = calloc(1, sizeof *c);
        if (!c)
                return -ENOMEM;
        GError *err = NULL;
        /* Aravis has its own GVCP timeouts and retries; timeout_ms is not applied here. */
        snprintf(c->address, sizeof c->address, "%s", address);
        c->cam = arv_camera_new(address, &err);
        if (!c->cam) {
                int r = take_error(NULL, &err);
                free(c);
                return r < 0 ? r : -ENODEV;
        }
        *ret_state = c;
        return 0;
}

static int cam_stop(void *state) {
        struct cam_arv *c = state;
        GError *err = NULL;
        if (!c->stream)
                return 0;
        int r = 0;
        if (!c->gone) { /* an unplugged camera would only time out again, seconds later */
                arv_camera_stop_acquisition(c->cam, &err);
                r = take_error(c, &err);
        }
        g_clear_object(&c->stream);     /* joins the receiving thread, frees the buffers */
        return r;
}

static void cam_close(void *state) {
        struct cam_arv *c = state;
        if (!c)
                return;
        (void) cam_stop(c);
        g_clear_object(&c->cam);
        free(c);
}

static void copy_str(char *dst, size_t size, const char *src) {
        snprintf(dst, size, "%s", src ? src : "");
}

static int cam_get_info(void *state, struct imp_camera_info *ret) {
        struct cam_arv *c = state;
        GError *err = NULL;
        int r;
        copy_str(ret->vendor, sizeof ret->vendor, arv_camera_get_vendor_name(c->cam, NULL));
        copy_str(ret->model, sizeof ret->model, arv_camera_get_model_name(c->cam, NULL));
        copy_str(ret->serial, sizeof ret->serial, arv_camera_get_device_serial_number(c->cam, NULL));
        gint sw = 0, sh = 0, x = 0, y = 0, w = 0, h = 0;
        arv_camera_get_sensor_size(c->cam, &sw, &sh, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        arv_camera_get_region(c->cam, &x, &y, &w, &h, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        ret->sensor_width = (unsigned) sw;
        ret->sensor_height = (unsigned) sh;
        ret->offset_x = (unsigned) x;
        ret->offset_y = (unsigned) y;
        ret->width = (unsigned) w;
        ret->height = (unsigned) h;
        ArvPixelFormat pf = arv_camera_get_pixel_format(c->cam, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        ret->pixel_format = IMP_PIXEL_NONE;
        for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                if (formats[i].pfnc == pf)
                        ret->pixel_format = formats[i].format;
        guint n = 0;
        const char **names = arv_camera_dup_available_pixel_formats_as_strings(c->cam, &n, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        ret->pixel_formats = 0;
        for (guint k = 0; names && k < n; k++)
                for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                        if (names[k] && strcmp(names[k], formats[i].name) == 0)
                                ret->pixel_formats |= IMP_PIXEL_BIT(formats[i].format);
        g_free(names);
        ret->exposure_us = arv_camera_get_exposure_time(c->cam, NULL);
        ret->gain_db = arv_camera_get_gain(c->cam, NULL);
        return 0;
}

static int cam_set_exposure_us(void *state, double exposure_us) {
        struct cam_arv *c = state;
        GError *err = NULL;
        arv_camera_set_exposure_time(c->cam, exposure_us, &err);
        return take_error(c, &err);
}

static int cam_set_gain_db(void *state, double gain_db) {
        struct cam_arv *c = state;
        GError *err = NULL;
        arv_camera_set_gain(c->cam, gain_db, &err);
        return take_error(c, &err);
}

static int cam_set_pixel_format(void *state, enum imp_pixel_format format) {
        struct cam_arv *c = state;
        struct imp_camera_info info = {};
        int r = cam_get_info(c, &info);
        if (r < 0)
                return r;
        if (!(info.pixel_formats & IMP_PIXEL_BIT(format)))
                return -EOPNOTSUPP;
        GError *err = NULL;
        for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                if (formats[i].format == format)
                        arv_camera_set_pixel_format(c->cam, formats[i].pfnc, &err);
        return take_error(c, &err);
}

static int cam_set_roi(void *state, unsigned x, unsigned y, unsigned width, unsigned height) {
        struct cam_arv *c = state;
        GError *err = NULL;
        gint sw = 0, sh = 0;
        arv_camera_get_sensor_size(c->cam, &sw, &sh, &err);
        int r = take_error(c, &err);
        if (r < 0)
                return r;
        if ((uint64_t) x + width > (uint64_t) sw || (uint64_t) y + height > (uint64_t) sh)
                return -EINVAL;
        arv_camera_set_region(c->cam, (gint) x, (gint) y, (gint) width, (gint) height, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        gint rx, ry, rw, rh;
        arv_camera_get_region(c->cam, &rx, &ry, &rw, &rh, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        /* The camera may round to its increments; a silent change would mislabel frames. */
        if ((unsigned) rx != x || (unsigned) ry != y || (unsigned) rw != width || (unsigned) rh != height)
                return -ERANGE;
        return 0;
}

static int cam_start(void *state, const struct imp_camera_acq *acq) {
        struct cam_arv *c = state;
        GError *err = NULL;
        int r;
        if (c->stream)
                return -EBUSY;
        if (c->gone)
                return -ENODEV;         /* reopen it once it is back */
        /* A controller that died (SIGKILL, power loss) leaves the camera acquiring, and it may
         * stream to the dead controller's port: Aravis' fake camera, once its heartbeat expires and
         * we take control, streams to the stream destination it read when it started, before
         * create_stream writes ours, and never re-reads it while acquiring. Stopping first makes
         * the start below read our destination. Its error is the next call's to report. */
        arv_camera_stop_acquisition(c->cam, &err);
        g_clear_error(&err);
        arv_camera_set_acquisition_mode(c->cam, ARV_ACQUISITION_MODE_CONTINUOUS, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        if (acq->software_trigger)
                arv_camera_set_trigger(c->cam, "Software", &err);
        else
                arv_camera_clear_triggers(c->cam, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        guint payload = arv_camera_get_payload(c->cam, &err);
        if ((r = take_error(c, &err)) < 0)
                return r;
        c->acq = *acq;
        c->payload = payload;
        c->extra_buffers = 0;
        c->stream = arv_camera_create_stream(c->cam, NULL, NULL, &err);
        if (!c->stream)
                return (r = take_error(c, &err)) < 0 ? r : -EIO;
        if (ARV_IS_GV_STREAM(c->stream))
                /* A receive buffer that holds a whole frame, and frames kept waiting for late
                 * or resent packets longer than the 100 ms default: a loaded host (or a
                 * shared loopback) otherwise drops frames that are only slow. */
                g_object_set(c->stream, "socket-buffer", ARV_GV_STREAM_SOCKET_BUFFER_AUTO,
                             "frame-retention", (guint) GV_FRAME_RETENTION_US, NULL);
        for (unsigned i = 0; i < acq->n_buffers; i++)
                arv_stream_push_buffer(c->stream, arv_buffer_new(payload, NULL));
        arv_camera_start_acquisition(c->cam, &err);
        if ((r = take_error(c, &err)) < 0) {
                g_clear_object(&c->stream);
                return r;
        }
        return 0;
}

static int cam_trigger_software(void *state) {
        struct cam_arv *c = state;
        GError *err = NULL;
        arv_camera_software_trigger(c->cam, &err);
        return take_error(c, &err);
}

/* Free running: TriggerMode Off on the FrameStart trigger (the selector arv_camera_set_trigger
 * left), with more buffers. Back to triggers: the stream is stopped and created anew in
 * software-trigger mode. Frames the camera exposed meanwhile were sent to the old stream's
 * socket, which is closed with it: no later grab can return one of them, whatever the
 * timing of their packets. */
static int cam_set_free_run(void *state, bool on) {
        struct cam_arv *c = state;
        GError *err = NULL;
        int r;
        if (!c->stream)
                return -ENOTCONN;
        if (c->gone)
                return -ENODEV;
        if (!c->acq.software_trigger)
                return on ? 0 : -EINVAL;
        if (on) {
                if (!arv_camera_is_feature_available(c->cam, "TriggerMode", NULL))
                        return -EOPNOTSUPP;
                for (unsigned n = c->acq.n_buffers + c->extra_buffers; n < FREE_RUN_MIN_BUFFERS; n++) {
                        arv_stream_push_buffer(c->stream, arv_buffer_new(c->payload, NULL));
                        c->extra_buffers++;
                }
                arv_camera_set_string(c->cam, "TriggerMode", "Off", &err);
                return take_error(c, &err);
        }
        struct imp_camera_acq acq = c->acq;
        if ((r = cam_stop(c)) < 0)
                return r;
        return cam_start(c, &acq);
}

/* Cumulative stream counters by name; a name the stream lacks reads as 0. */
static void stream_counters(ArvStream *s, struct imp_frame_meta *m) {
        guint64 completed = 0, failures = 0, underruns = 0;
        arv_stream_get_statistics(s, &completed, &failures, &underruns);
        m->n_failures = failures;
        m->n_underruns = underruns;
        guint n = arv_stream_get_n_infos(s);
        for (guint i = 0; i < n; i++) {
                const char *name = arv_stream_get_info_name(s, i);
                if (!name || arv_stream_get_info_type(s, i) != G_TYPE_UINT64)
                        continue;
                if (strcmp(name, "n_missing_packets") == 0)
                        m->n_missing_packets = arv_stream_get_info_uint64(s, i);
                else if (strcmp(name, "n_resent_packets") == 0)
                        m->n_resent_packets = arv_stream_get_info_uint64(s, i);
        }
}

/* No frame within the timeout: a slow or untriggered camera (-ETIMEDOUT), or one that is
 * gone. One control read tells them apart; an unplugged camera does not answer it within
 * Aravis' GVCP timeout and retries, and is -ENODEV. Neither Aravis' stream nor its
 * heartbeat says so sooner: the stream only sees no packets. */
static int grab_timed_out(struct cam_arv *c, unsigned timeout_ms) {
        GError *err = NULL;
        guint32 v = 0;
        if (arv_device_read_register(arv_camera_get_device(c->cam), GVBS_VERSION, &v, &err)) {
                snprintf(c->error, sizeof c->error, "camera %s: no frame within %u ms", c->address, timeout_ms);
                return -ETIMEDOUT;
        }
        snprintf(c->error, sizeof c->error, "camera %s: no frame within %u ms and no answer to a control read (%s): unplugged?",
                 c->address, timeout_ms, err ? err->message : "no detail");
        g_clear_error(&err);
        c->gone = true;
        return -ENODEV;
}

static int cam_grab(void *state, unsigned timeout_ms, void *dst, size_t dst_size,
                    struct imp_frame *ret) {
        struct cam_arv *c = state;
        if (!c->stream)
                return -ENOTCONN;
        /* A buffer can come back CLEARED, never filled (seen right after a start on a
         * loaded host): not a frame, so wait on for one within the same deadline. */
        gint64 deadline_us = g_get_monotonic_time() + (gint64) timeout_ms * 1000;
        ArvBuffer *b;
        ArvBufferStatus status;
        for (;;) {
                gint64 left_us = deadline_us - g_get_monotonic_time();
                b = left_us > 0 ? arv_stream_timeout_pop_buffer(c->stream, (guint64) left_us) : NULL;
                if (!b)
                        return grab_timed_out(c, timeout_ms);
                status = arv_buffer_get_status(b);
                if (status != ARV_BUFFER_STATUS_CLEARED)
                        break;
                arv_stream_push_buffer(c->stream, b);
        }
        int r = 0;
        size_t size = 0;
        const void *data = arv_buffer_get_image_data(b, &size);
        int w = arv_buffer_get_image_width(b), h = arv_buffer_get_image_height(b);
        ArvPixelFormat pf = arv_buffer_get_image_pixel_format(b);
        unsigned bpp = ARV_PIXEL_FORMAT_BIT_PER_PIXEL(pf) <= 8 ? 1 : 2;
        if (status != ARV_BUFFER_STATUS_SUCCESS) {
                snprintf(c->error, sizeof c->error, "frame %" G_GUINT64_FORMAT " incomplete (buffer status %d)",
                         arv_buffer_get_frame_id(b), (int) status);
                r = -EIO;
        } else if (!data || w <= 0 || h <= 0 || size < (size_t) w * h * bpp)
                r = -EIO;
        else if ((size_t) w * h * bpp > dst_size)
                r = -EMSGSIZE;
        if (r == 0) {
                memcpy(dst, data, (size_t) w * h * bpp);
                ret->width = (unsigned) w;
                ret->height = (unsigned) h;
                ret->stride_bytes = (unsigned) w * bpp;
                ret->size = (size_t) w * h * bpp;
                ret->pixel_format = IMP_PIXEL_NONE;
                for (size_t i = 0; i < ARRAY_SIZE(formats); i++)
                        if (formats[i].pfnc == pf)
                                ret->pixel_format = formats[i].format;
                ret->meta.timestamp_ns = arv_buffer_get_timestamp(b);
                ret->meta.system_timestamp_ns = arv_buffer_get_system_timestamp(b);
                ret->meta.frame_id = arv_buffer_get_frame_id(b);
        }
        arv_stream_push_buffer(c->stream, b);  /* back into the pool either way */
        if (r == 0)
                stream_counters(c->stream, &ret->meta);
        return r;
}

static const char *cam_last_error(void *state) {
        struct cam_arv *c = state;
        return c->error;
}

const struct imp_camera_ops imp_camera_aravis_ops = {
        .name = "aravis",
        .open = cam_open,                       /* address, IP or Aravis device id */
        .close = cam_close,                     /* stops the stream, drops the device */
        .get_info = cam_get_info,               /* GenICam standard features */
        .set_exposure_us = cam_set_exposure_us, /* ExposureTime / ExposureTimeAbs */
        .set_gain_db = cam_set_gain_db,         /* Gain, or GainRaw where that is all there is */
        .set_pixel_format = cam_set_pixel_format, /* Mono8, Mono12, Mono16 when offered */
        .set_roi = cam_set_roi,                 /* OffsetX/Y, Width, Height; exact or -ERANGE */
        .start = cam_start,                     /* continuous or software-triggered, pool pushed */
        .stop = cam_stop,                       /* AcquisitionStop, stream released */
        .trigger_software = cam_trigger_software, /* TriggerSoftware command */
        .set_free_run = cam_set_free_run,       /* TriggerMode Off; back: a new stream */
        .grab = cam_grab,                       /* arv_stream_timeout_pop_buffer, copy, push back;
                                                 * no frame and no control answer: -ENODEV */
        .last_error = cam_last_error,           /* names the camera's address */
};
