/* Camera device class: one constant table of operations per backend (Aravis, later V4L2,
 * libcamera, sim), chosen by name, and an opaque handle whose wrapper checks arguments,
 * answers -EOPNOTSUPP for NULL slots and owns the frame buffer. Negative errno on failure. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "macro.h"

enum imp_pixel_format {
        IMP_PIXEL_NONE   = 0,
        IMP_PIXEL_MONO8  = 1,
        IMP_PIXEL_MONO12 = 2,   /* unpacked: 12 significant bits in 16-bit little-endian words */
        IMP_PIXEL_MONO16 = 3,   /* 16-bit little-endian words */
};
#define IMP_PIXEL_BIT(f) (1u << (f))

const char *imp_pixel_format_to_string(enum imp_pixel_format f);
/* Returns the format or -EINVAL. */
int imp_pixel_format_from_string(const char *s);
/* Bytes per pixel in memory (1 or 2), 0 for IMP_PIXEL_NONE. */
unsigned imp_pixel_format_bytes(enum imp_pixel_format f);

struct imp_camera_info {
        char vendor[64];
        char model[64];
        char serial[64];
        unsigned sensor_width, sensor_height;   /* pixels */
        unsigned offset_x, offset_y;            /* current ROI, pixels */
        unsigned width, height;
        enum imp_pixel_format pixel_format;     /* current */
        uint32_t pixel_formats;                 /* IMP_PIXEL_BIT() set of the supported ones */
        double exposure_us;                     /* current */
        double gain_db;                         /* current (raw units where the camera has no dB gain) */
};

/* Per-frame metadata; the counters are cumulative since imp_camera_start(). */
struct imp_frame_meta {
        uint64_t timestamp_ns;          /* camera clock */
        uint64_t system_timestamp_ns;   /* host clock (CLOCK_REALTIME) when received */
        uint64_t frame_id;              /* as the camera numbers them */
        uint64_t n_missing_packets;
        uint64_t n_resent_packets;
        uint64_t n_underruns;           /* frames lost for want of a free buffer */
        uint64_t n_failures;            /* incomplete or corrupt frames */
};

struct imp_frame {
        const void *data;               /* owned by the camera; valid until the next grab/stop/close */
        size_t size;                    /* bytes: height × stride_bytes */
        unsigned width, height, stride_bytes;
        enum imp_pixel_format pixel_format;
        struct imp_frame_meta meta;
};

struct imp_camera_acq {
        unsigned n_buffers;             /* stream buffer pool size; 0 means 4 */
        bool software_trigger;          /* frames only on imp_camera_trigger_software() */
};

/* One table per backend. Every slot but name/open/close may be NULL (not supported). */
struct imp_camera_ops {
        /* Name used in rig configs ("aravis"). */
        const char *name;
        /* Connect to the camera at address (backend syntax, e.g. "127.0.0.1" or a device id)
         * within timeout_ms; on success *ret_state is the backend's state. */
        int (*open)(const char *address, unsigned timeout_ms, void **ret_state);
        /* Stop any acquisition and free the state. */
        void (*close)(void *state);
        /* Identity, geometry and current settings. */
        int (*get_info)(void *state, struct imp_camera_info *ret_info);
        /* Exposure time in microseconds; the camera may round it (read back with get_info). */
        int (*set_exposure_us)(void *state, double exposure_us);
        /* Analog gain in dB (raw units on cameras without a dB gain). */
        int (*set_gain_db)(void *state, double gain_db);
        /* Pixel format; -EOPNOTSUPP when the camera does not offer it. */
        int (*set_pixel_format)(void *state, enum imp_pixel_format format);
        /* Region of interest in sensor pixels; -EINVAL when outside the sensor. */
        int (*set_roi)(void *state, unsigned x, unsigned y, unsigned width, unsigned height);
        /* Allocate the stream's buffer pool and start acquiring. */
        int (*start)(void *state, const struct imp_camera_acq *acq);
        /* Stop acquiring and release the stream. */
        int (*stop)(void *state);
        /* Fire one software trigger (acquisition started with software_trigger). */
        int (*trigger_software)(void *state);
        /* While acquiring with software_trigger: on, the camera runs free (exposes frame
         * after frame at its own frame rate, e.g. GenICam TriggerMode Off at its
         * AcquisitionFrameRate) until off; off, it waits for triggers again, and no frame
         * it exposed before off returned is ever returned by a later grab (the backend
         * discards frames still in flight). */
        int (*set_free_run)(void *state, bool on);
        /* Wait up to timeout_ms for the next complete frame, copy its pixels to dst
         * (dst_size bytes) and fill ret_frame (all but data). -ETIMEDOUT when none came,
         * -EIO for an incomplete frame (its buffer is recycled), -EMSGSIZE if dst is short. */
        int (*grab)(void *state, unsigned timeout_ms, void *dst, size_t dst_size,
                    struct imp_frame *ret_frame);
        /* Human detail of the last failure ("/dev/video0: VIDIOC_DQBUF: ..."), or NULL. */
        const char *(*last_error)(void *state);
};

struct imp_camera;

/* The backend table for a name, or NULL. */
const struct imp_camera_ops *imp_camera_backend(const char *name);

/* Open a camera. Caller frees with imp_camera_close(). -ENOENT: no backend by that name. */
int imp_camera_open(const char *backend, const char *address, unsigned timeout_ms,
                    struct imp_camera **ret_camera);
void imp_camera_close(struct imp_camera *camera);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_camera *, imp_camera_close);

const char *imp_camera_backend_name(const struct imp_camera *camera);
int imp_camera_get_info(struct imp_camera *camera, struct imp_camera_info *ret_info);
int imp_camera_set_exposure_us(struct imp_camera *camera, double exposure_us);
int imp_camera_set_gain_db(struct imp_camera *camera, double gain_db);
/* Format and ROI change the frame size: -EBUSY while acquiring. */
int imp_camera_set_pixel_format(struct imp_camera *camera, enum imp_pixel_format format);
int imp_camera_set_roi(struct imp_camera *camera, unsigned x, unsigned y,
                       unsigned width, unsigned height);
/* Sizes the frame buffer from the current ROI and format (the only allocation), starts. */
int imp_camera_start(struct imp_camera *camera, const struct imp_camera_acq *acq);
int imp_camera_stop(struct imp_camera *camera);
/* Started and not since stopped, by the caller or by the driver after an unplug (-ENODEV). */
bool imp_camera_is_acquiring(const struct imp_camera *camera);
int imp_camera_trigger_software(struct imp_camera *camera);
/* Free running on or off while acquiring (see the ops slot): -ENOTCONN when not acquiring,
 * -EOPNOTSUPP when the backend cannot switch mid-acquisition. */
int imp_camera_set_free_run(struct imp_camera *camera, bool on);
/* Frames a camera numbered between two frames received (prev then id) that never arrived:
 * GigE Vision 1.x block ids are 16-bit and wrap skipping 0; larger ids do not wrap (a
 * smaller one is a restart, not a loss). */
uint64_t imp_camera_frames_skipped(uint64_t prev_id, uint64_t id);
/* Next frame. *ret_frame points into the camera: valid until the next grab, stop or close.
 * -ENODEV: the camera is gone; the camera is then stopped (grab answers -ENOTCONN). */
int imp_camera_grab(struct imp_camera *camera, unsigned timeout_ms,
                    const struct imp_frame **ret_frame);
/* The same into the caller's dst (dst_size bytes; -EMSGSIZE when the frame is larger):
 * ret_frame->data is dst. Saves the copy out of the camera's buffer. */
int imp_camera_grab_into(struct imp_camera *camera, unsigned timeout_ms, void *dst, size_t dst_size,
                         struct imp_frame *ret_frame);
/* The backend's detail of its last failure ("" when it keeps none). Valid until the next call. */
const char *imp_camera_last_error(const struct imp_camera *camera);
/* Backends built before the last_error slot existed test for it. */
#define IMP_CAMERA_HAVE_LAST_ERROR 1
