/* Device emulators that stand behind the real drivers in tests: a GigE Vision camera
 * (Aravis ArvGvFakeCamera on loopback), a Modbus TCP dome controller (libmodbus server
 * thread), and a gpiochip (umockdev ioctl handler). They share one emulated rig state so
 * that a frame shows the lights the dome emulators have switched on. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "macro.h"

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
/* True if UDP port 3956 on address can be bound now (no other GVCP device there). */
bool imp_emu_gige_port_free(const char *address);

/* ---- Modbus TCP dome controller (docs/dome-registers.md) -------------------------------- */

struct imp_emu_modbus_config {
        const char *address;            /* default "127.0.0.1" */
        uint16_t port;                  /* required, use a high port */
        unsigned n_lights;              /* default 16 */
        unsigned n_axes;                /* default 2 */
        unsigned speed_mm_per_s;        /* default 50 */
        int32_t travel_um;              /* default 100000 */
};

struct imp_emu_modbus;

/* Starts the server thread, listening when it returns. Caller frees with imp_emu_modbus_free(). */
int imp_emu_modbus_new(const struct imp_emu_modbus_config *cfg, struct imp_emu_rig *rig,
                       struct imp_emu_modbus **ret_emu);
void imp_emu_modbus_free(struct imp_emu_modbus *emu);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_modbus *, imp_emu_modbus_free);
/* Fault injection; nth = 1 is the next request. */
void imp_emu_modbus_fail_nth(struct imp_emu_modbus *emu, unsigned nth, uint8_t exception_code);
void imp_emu_modbus_delay(struct imp_emu_modbus *emu, unsigned n_requests, unsigned delay_ms);
void imp_emu_modbus_drop_nth(struct imp_emu_modbus *emu, unsigned nth);
uint64_t imp_emu_modbus_n_requests(struct imp_emu_modbus *emu);
unsigned imp_emu_modbus_n_connections(struct imp_emu_modbus *emu);
/* Light level as the controller holds it. */
unsigned imp_emu_modbus_light(struct imp_emu_modbus *emu, unsigned id);

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
