/* Device emulators that stand behind the real drivers in tests: a GigE Vision camera
 * (Aravis ArvGvFakeCamera on loopback), a Modbus TCP dome controller (libmodbus server
 * thread), and a gpiochip (umockdev ioctl handler). They share one emulated rig state so
 * that a frame shows the lights the dome emulators have switched on. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "macro.h"
#include "pattern.h"

#define IMP_EMU_MAX_LIGHTS 64

/* ---- shared rig state ------------------------------------------------------------- */

struct imp_emu_rig;

/* Caller frees with imp_emu_rig_free(). */
int imp_emu_rig_new(unsigned n_lights, struct imp_emu_rig **ret_rig);
void imp_emu_rig_free(struct imp_emu_rig *rig);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_rig *, imp_emu_rig_free);
unsigned imp_emu_rig_n_lights(const struct imp_emu_rig *rig);
/* Called by the dome emulators. Tracks the most lights ever on at once. */
void imp_emu_rig_set_light(struct imp_emu_rig *rig, unsigned id, unsigned level_permille);
/* Copies levels (n entries), returns how many are on. */
unsigned imp_emu_rig_get_lights(struct imp_emu_rig *rig, uint16_t *levels, unsigned n);
/* The lit light if exactly one is on, -1 if none, -2 if several. */
int imp_emu_rig_lit_light(struct imp_emu_rig *rig);
unsigned imp_emu_rig_max_lights_on(struct imp_emu_rig *rig);
void imp_emu_rig_reset_max_lights_on(struct imp_emu_rig *rig);
/* Projector pattern index shown now (-1: projector dark). */
void imp_emu_rig_set_pattern(struct imp_emu_rig *rig, int pattern);
int imp_emu_rig_get_pattern(struct imp_emu_rig *rig);
/* The pattern shown now as a descriptor (what the renderer needs), with its sequence index:
 * index -1 / kind IMP_PAT_NONE is dark. set_pattern_desc(rig, -1, NULL) blanks; a plain
 * imp_emu_rig_set_pattern() keeps the last descriptor (or NONE for -1). */
void imp_emu_rig_set_pattern_desc(struct imp_emu_rig *rig, int index, const struct imp_pattern *desc);
/* Copies the descriptor (kind NONE when dark) and returns the index (-1 dark). */
int imp_emu_rig_get_pattern_desc(struct imp_emu_rig *rig, struct imp_pattern *ret_desc);

/* ---- camera ------------------------------------------------------------------------ */

/* What the emulated camera knows when it fills a frame. */
struct imp_emu_camera_state {
        uint32_t exposure_us;
        uint32_t gain_raw;
        uint32_t pixel_format;          /* GenICam PFNC value (0x01080001 Mono8, 0x01100007 Mono16) */
        int lit_light;                  /* as imp_emu_rig_lit_light(): id, -1 none, -2 several */
        int pattern;                    /* projector pattern index, -1 dark */
        uint16_t level_permille[IMP_EMU_MAX_LIGHTS];
        unsigned n_lights;
        uint64_t frame_index;           /* frames filled so far by this emulator */
        struct imp_pattern pattern_desc;/* the projected pattern (kind NONE when dark) */
        uint64_t frame_id;              /* the frame's id as the camera sends it (GVSP block id) */
};

/* Fills width × height pixels of bytes_per_pixel (1 or 2, little-endian) into buf.
 * Returns 0 or a negative errno (the frame is then sent as filled so far). */
typedef int (*imp_emu_fill_fn)(void *userdata, const struct imp_emu_camera_state *st, void *buf,
                               int width, int height, int bytes_per_pixel);

/* Default fill: a deterministic image that encodes the lit light, the pattern and the
 * exposure. Pixels 0..7 of row 0 are a header (magic, light+2, pattern+1, exposure_us in
 * 4 × 8-bit or 2 × 16-bit pieces, a check value); every other pixel is
 * (x + 3y + 17·(light+2) + 29·(pattern+1) + exposure_us/8) mod 2^(8·bpp). */
int imp_emu_fill_default(void *userdata, const struct imp_emu_camera_state *st, void *buf,
                         int width, int height, int bytes_per_pixel);
/* Reads the header back; -EBADMSG when the header or any pixel disagrees with the formula. */
int imp_emu_decode_default(const void *buf, int width, int height, int bytes_per_pixel,
                           int *ret_light, int *ret_pattern, uint32_t *ret_exposure_us);

struct imp_emu_gige;

/* A GigE Vision camera on address (GVCP UDP port 3956): -EADDRINUSE when another camera
 * holds the port. rig may be NULL (no lights); fill NULL means imp_emu_fill_default.
 * Caller frees with imp_emu_gige_free(). */
int imp_emu_gige_new(const char *address, const char *serial, struct imp_emu_rig *rig,
                     imp_emu_fill_fn fill, void *userdata, struct imp_emu_gige **ret_gige);
void imp_emu_gige_free(struct imp_emu_gige *gige);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_gige *, imp_emu_gige_free);
uint64_t imp_emu_gige_frames_filled(struct imp_emu_gige *gige);
/* Sensor and default image size (the fake camera's own default is 2048 × 2048, 512 × 512
 * read out). Call before a client connects. -EINVAL for 0 or more than 16384. */
int imp_emu_gige_set_sensor_size(struct imp_emu_gige *gige, unsigned width, unsigned height);
/* Unplug: the fake camera is destroyed, nothing answers GVCP and no GVSP packet is sent;
 * the frame counter and the fill stay. -EALREADY when unplugged already. */
int imp_emu_gige_unplug(struct imp_emu_gige *gige);
/* Plug back in: a new fake camera on the same address with the same serial (and sensor
 * size), in its power-on state: no controlling client, no stream, defaults for every
 * setting. -EALREADY when plugged, -EADDRINUSE when another camera took the port meanwhile. */
int imp_emu_gige_replug(struct imp_emu_gige *gige);
/* True if UDP port 3956 on address can be bound now (no other GVCP device there). */
bool imp_emu_gige_port_free(const char *address);

/* ---- Modbus TCP dome controller (docs/dome-registers.md) -------------------------------- */

struct imp_emu_modbus_config {
        const char *address;            /* default "127.0.0.1" */
        uint16_t port;                  /* required for TCP, use a high port */
        /* Serve Modbus RTU on a pseudo-terminal instead of TCP (address and port unused):
         * clients open imp_emu_modbus_rtu_device() as their serial port. */
        bool rtu;
        unsigned rtu_unit;              /* RTU unit (slave) id answered, 1..247, default 1 */
        unsigned n_lights;              /* default 16 */
        unsigned n_axes;                /* default 2 */
        unsigned speed_mm_per_s;        /* default 50 */
        int32_t travel_um;              /* default 100000 */
        /* Projector sequencer block (docs/dome-registers.md, "Projector sequencer"). */
        unsigned projector_width;       /* native resolution reported, default 1024 */
        unsigned projector_height;      /* default 768 */
        unsigned max_patterns;          /* sequence capacity, default and at most 256 */
};

struct imp_emu_modbus;

/* Starts the server thread, listening when it returns. Caller frees with imp_emu_modbus_free(). */
int imp_emu_modbus_new(const struct imp_emu_modbus_config *cfg, struct imp_emu_rig *rig,
                       struct imp_emu_modbus **ret_emu);
void imp_emu_modbus_free(struct imp_emu_modbus *emu);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_modbus *, imp_emu_modbus_free);
/* The pseudo-terminal an RTU client opens ("/dev/pts/N"), NULL for a TCP emulator. */
const char *imp_emu_modbus_rtu_device(const struct imp_emu_modbus *emu);
/* Fault injection; nth = 1 is the next request. Over RTU a "dropped connection" is a
 * request swallowed without an answer (the line stays up). */
void imp_emu_modbus_fail_nth(struct imp_emu_modbus *emu, unsigned nth, uint8_t exception_code);
void imp_emu_modbus_delay(struct imp_emu_modbus *emu, unsigned n_requests, unsigned delay_ms);
void imp_emu_modbus_drop_nth(struct imp_emu_modbus *emu, unsigned nth);
uint64_t imp_emu_modbus_n_requests(struct imp_emu_modbus *emu);
unsigned imp_emu_modbus_n_connections(struct imp_emu_modbus *emu);
/* Light level as the controller holds it. */
unsigned imp_emu_modbus_light(struct imp_emu_modbus *emu, unsigned id);
/* Latch a projector fault now (code as PROJ_FAULT, e.g. 3 = LED fault): the projector goes
 * dark and refuses show() until the fault is cleared (command 1). */
void imp_emu_modbus_projector_fault(struct imp_emu_modbus *emu, unsigned code);
/* Projector as the controller holds it: shown index (-1 dark), patterns in the sequence,
 * triggers fired so far. */
int imp_emu_modbus_projector_shown(struct imp_emu_modbus *emu);
unsigned imp_emu_modbus_projector_count(struct imp_emu_modbus *emu);
unsigned imp_emu_modbus_projector_triggers(struct imp_emu_modbus *emu);

/* ---- gpiochip through umockdev ---------------------------------------------------------- */

struct imp_emu_gpio_config {
        const char *chip_name;          /* default "gpiochip0" */
        const char *label;              /* default "impasto-dome" */
        unsigned n_lines;               /* default 16, at most 64 */
        unsigned light_line_base;       /* LED of light i is on line base + i */
        unsigned n_lights;              /* lines wired to LEDs; default n_lines - base */
        bool leds_active_low;           /* wiring: LED lit when the line is driven low */
};

struct imp_emu_gpio;

/* Needs the umockdev preload (run under umockdev-wrapper): -ENOTSUP without it. */
int imp_emu_gpio_new(const struct imp_emu_gpio_config *cfg, struct imp_emu_rig *rig,
                     struct imp_emu_gpio **ret_emu);
void imp_emu_gpio_free(struct imp_emu_gpio *emu);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_gpio *, imp_emu_gpio_free);
bool imp_emu_gpio_available(void);
/* Physical level of a line: 0 or 1, -1 when no one drives it. */
int imp_emu_gpio_line_level(struct imp_emu_gpio *emu, unsigned line);
/* Mark a line as held by another consumer (requests answer EBUSY). */
void imp_emu_gpio_set_busy(struct imp_emu_gpio *emu, unsigned line, bool busy);
/* The nth set-values ioctl from now fails with errno err. */
void imp_emu_gpio_fail_set_nth(struct imp_emu_gpio *emu, unsigned nth, int err);
unsigned imp_emu_gpio_n_set_calls(struct imp_emu_gpio *emu);

/* ---- V4L2 capture device through umockdev ------------------------------------------------ */

struct imp_emu_v4l2_config {
        const char *video_name;         /* default "video0" (/dev/video0) */
        const char *card;               /* VIDIOC_QUERYCAP card; default "impasto emulated camera" */
        unsigned width, height;         /* default 320 × 240 */
        bool no_userptr;                /* refuse V4L2_MEMORY_USERPTR too: only read() I/O is left */
        bool no_read;                   /* no V4L2_CAP_READWRITE */
        unsigned frame_interval_us;     /* a frame is due this long after the last; 0 = at once */
};

struct imp_emu_v4l2;

/* A /dev/videoN whose V4L2 ioctls are answered here. Offers GREY and Y16; exposure
 * (V4L2_CID_EXPOSURE_ABSOLUTE, 100 µs units) and gain (V4L2_CID_GAIN, raw 0..255). MMAP
 * buffers can be requested but not mapped (umockdev does not emulate mmap); USERPTR
 * buffers are filled through the caller's pointer at DQBUF; read() returns whole frames.
 * Pixels come from fill (NULL: imp_emu_fill_default), pixel_format in its state is the
 * GenICam value (Mono8/Mono16). Needs the umockdev preload: -ENOTSUP without it.
 * Caller frees with imp_emu_v4l2_free(). */
int imp_emu_v4l2_new(const struct imp_emu_v4l2_config *cfg, struct imp_emu_rig *rig,
                     imp_emu_fill_fn fill, void *userdata, struct imp_emu_v4l2 **ret_emu);
void imp_emu_v4l2_free(struct imp_emu_v4l2 *emu);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_v4l2 *, imp_emu_v4l2_free);
/* Device node, "/dev/video0". */
const char *imp_emu_v4l2_devnode(const struct imp_emu_v4l2 *emu);
uint64_t imp_emu_v4l2_frames_filled(struct imp_emu_v4l2 *emu);
/* Fault injection, nth = 1 is the next frame / DQBUF. A dropped frame consumes a sequence
 * number without reaching a buffer (as when the kernel had no buffer queued). */
void imp_emu_v4l2_drop_nth(struct imp_emu_v4l2 *emu, unsigned nth);
/* The nth VIDIOC_DQBUF from now fails with errno err; the frame stays queued. */
void imp_emu_v4l2_fail_dqbuf_nth(struct imp_emu_v4l2 *emu, unsigned nth, int err);
/* The camera is unplugged: every ioctl and read answers ENODEV from now on. */
void imp_emu_v4l2_disconnect(struct imp_emu_v4l2 *emu);
/* No frame becomes due while paused (DQBUF answers EAGAIN). */
void imp_emu_v4l2_pause(struct imp_emu_v4l2 *emu, bool paused);
/* How the last stream was set up: V4L2_MEMORY_MMAP/USERPTR, or 0 for read() only. */
unsigned imp_emu_v4l2_memory(struct imp_emu_v4l2 *emu);
bool imp_emu_v4l2_streaming(struct imp_emu_v4l2 *emu);

/* ---- USB DLP projector through umockdev (docs/projector-usb.md) ------------------------ */

struct imp_emu_usb_config {
        uint16_t vid, pid;              /* default 1d50:6020 */
        const char *serial;             /* default "EMU0001" */
        const char *model;              /* default "impasto DLP emulator" */
        unsigned busnum, devnum;        /* /dev/bus/usb/BBB/DDD; default 1, 5 */
        int width, height;              /* default 1280 × 800 */
        unsigned max_patterns;          /* default 256 */
};

struct imp_emu_usb;

/* A USB device in a umockdev testbed (sysfs attributes and descriptors, the usbfs node)
 * whose usbdevfs ioctls — URBs included — are answered here, speaking the projector's
 * command set. SHOW sets the rig's pattern (rig may be NULL). Needs the umockdev preload
 * (run under umockdev-wrapper): -ENOTSUP without it. Caller frees with imp_emu_usb_free(). */
int imp_emu_usb_new(const struct imp_emu_usb_config *cfg, struct imp_emu_rig *rig,
                    struct imp_emu_usb **ret_emu);
void imp_emu_usb_free(struct imp_emu_usb *emu);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_usb *, imp_emu_usb_free);
bool imp_emu_usb_available(void);
/* Fault injection: the nth command frame from now (1 = the next) and the times - 1 after
 * it stall the bulk OUT endpoint; each stalled frame is not executed. */
void imp_emu_usb_stall_nth(struct imp_emu_usb *emu, unsigned nth, unsigned times);
/* The replies to the nth command frame from now and the times - 1 after it are lost after
 * the command ran: the host times out, and its re-send (same sequence number) is answered
 * from the reply cache. */
void imp_emu_usb_drop_reply_nth(struct imp_emu_usb *emu, unsigned nth, unsigned times);
/* Unplug: every later ioctl answers ENODEV, URBs in flight end with -ESHUTDOWN, and the
 * device leaves the testbed (a udev "remove" event). */
void imp_emu_usb_disconnect(struct imp_emu_usb *emu);
/* Pattern index on now, -1 dark. */
int imp_emu_usb_shown(struct imp_emu_usb *emu);
/* Pattern i of the uploaded sequence as decoded from the wire; -ENOENT past the end. */
int imp_emu_usb_pattern(struct imp_emu_usb *emu, unsigned i, struct imp_pattern *ret);
unsigned imp_emu_usb_n_commands(struct imp_emu_usb *emu);       /* frames received, stalled too */
unsigned imp_emu_usb_n_clear_halts(struct imp_emu_usb *emu);
unsigned imp_emu_usb_n_triggers(struct imp_emu_usb *emu);
