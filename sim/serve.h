/* The simulated rig as devices: a scene served through the real protocols, so impastod and
 * the drivers talk to it exactly as to the hardware.
 *   - one GigE Vision camera (Aravis fake camera, sim/emu) per scene camera, the first on
 *     cfg.address, the next ones on the following addresses (127.0.0.1, 127.0.0.2, …);
 *     its sensor is the scene camera's size; each frame is RENDERED (sim/render.h) for the
 *     rig state at fill time: the lit dome light, the projector's current pattern
 *     descriptor, the exposure and gain the client set;
 *   - the Modbus TCP controller (dome lights, actuators, projector sequencer;
 *     docs/dome-registers.md) on cfg.address:cfg.modbus_port.
 * Frame contents (a record as the renderer sees it):
 *   seq = the frame's GigE id (struct imp_frame_meta.frame_id on the client), so a client
 *   can re-render any frame it received bit for bit; camera = scene camera name; light = id
 *   of the scene light wired to dome register i (lights in scene order); pattern = the
 *   shown descriptor (kind NONE when dark); exposure_us = ExposureTime; gain_db = GainRaw
 *   (the fake camera's gain is an integer 0..10; 1 raw step = 1 dB); step "structured-light"
 *   when a pattern is on, else "dome".
 *   Mono16 carries the sensor's DN as rendered (12-bit values in 16-bit words); Mono8 the
 *   DN shifted down to 8 bits.
 * What the renderer cannot form is delivered as an all-zero frame (0 DN is below every
 * black level, so a client sees it is not a picture) and counted: several lights on at
 * once, a light dimmed below full (the renderer has one light at full intensity), a frame
 * the scene's dropped_frame effect drops, and the injected drop-frame fault (the fake
 * camera always sends the frame it filled; it cannot lose one on the wire). */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "error.h"
#include "macro.h"
#include "rig.h"
#include "scene.h"
#include "tiles.h"

struct imp_serve_config {
        const char *address;            /* first camera and the Modbus controller; "127.0.0.1" */
        uint16_t modbus_port;           /* default 15020 */
        /* A gantry scene (required then): the plan's painting group. The rig gets a GRBL 1.1
         * controller on a pseudo-terminal (imp_serve_stage_device) and every frame is
         * rendered for where its carriage stands: at a tile's target with the pose `sim
         * render` gives that tile (stage_error included), elsewhere at the read-back. The
         * tile plan must outlive the rig. */
        const struct imp_tile_plan *tiles;
};

struct imp_serve;
struct imp_emu_rig;
struct imp_emu_modbus;

/* Builds the renderer (view maps) and starts the devices; the scene must outlive the rig.
 * -EADDRINUSE when the first camera's GVCP port or the Modbus port is taken, -EOPNOTSUPP
 * when impasto was built without Aravis or libmodbus, or the scene has a colour camera
 * (the GigE emulator serves Mono only). Extra cameras whose address cannot be bound are
 * skipped; imp_serve_describe() names them. Caller frees with imp_serve_free(). */
int imp_serve_new(const struct imp_scene *scene, const struct imp_serve_config *cfg, struct imp_serve **ret,
                  struct imp_error *err);
void imp_serve_free(struct imp_serve *s);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_serve *, imp_serve_free);

/* Fault injection from a spec (also `impasto sim serve --fault`):
 *   drop-frame=N           camera frame N (0-based, per camera) is delivered all zero
 *   modbus-exception=N[:C] the Nth Modbus request from now is answered with exception C
 *                          (default 4, server failure)
 *   modbus-delay=N:MS      the next N Modbus requests are answered MS ms late
 *   modbus-disconnect=N    the Nth Modbus request from now drops the connection
 *   frame-delay=MS         every frame is filled MS ms late (a slow camera)
 *   projector-fault=C      latch projector fault C now (3 = LED fault)
 * -EINVAL with a message naming the spec and what was expected. */
int imp_serve_fault(struct imp_serve *s, const char *spec, struct imp_error *err);

/* The calibration the frames obey (imp_render_rig): what `--rig-out` writes. */
const struct imp_rig *imp_serve_rig(const struct imp_serve *s);
/* Cameras actually served, and camera i's address ("127.0.0.1") or NULL when skipped. */
int imp_serve_n_cameras(const struct imp_serve *s);
const char *imp_serve_camera_address(const struct imp_serve *s, int cam);
/* Frames filled by camera i, and of those the all-zero ones (see above). */
uint64_t imp_serve_frames(const struct imp_serve *s, int cam);
uint64_t imp_serve_blank_frames(const struct imp_serve *s, int cam);
/* The emulators, for tests: rig state (lights, pattern) and the Modbus controller. */
struct imp_emu_rig *imp_serve_emu_rig(struct imp_serve *s);
struct imp_emu_modbus *imp_serve_modbus(struct imp_serve *s);
/* A gantry scene's GRBL controller and the pseudo-terminal a client opens, else NULL. */
struct imp_emu_stage;
struct imp_emu_stage *imp_serve_stage(struct imp_serve *s);
const char *imp_serve_stage_device(const struct imp_serve *s);
/* A printable summary: cameras and addresses (and any skipped), Modbus endpoint, lights,
 * projector size. malloc'd. */
char *imp_serve_describe(const struct imp_serve *s);
