/* Dome device class: the hemispherical LED dome's lights and its actuators behind one
 * constant table of operations per backend ("modbus", "gpiod"), chosen by name. The
 * wrapper keeps the invariants the capture needs: never two lights on unless asked, and
 * every failure leaves the lights off (best effort, reported by imp_dome_lights_known()). */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "macro.h"

#define IMP_DOME_MAX_LIGHTS 64
#define IMP_DOME_MAX_AXES 8
#define IMP_DOME_LEVEL_FULL_PERMILLE 1000

struct imp_dome_info {
        char model[64];
        unsigned n_lights;
        unsigned n_axes;                /* 0 for a lights-only backend */
        bool dimmable;                  /* false: any level > 0 is full on */
};

struct imp_dome_state {
        unsigned n_lights;
        uint16_t level_permille[IMP_DOME_MAX_LIGHTS];   /* 0..1000 */
        unsigned n_on;
};

enum imp_axis_flag {
        IMP_AXIS_MOVING      = 1u << 0,
        IMP_AXIS_HOMED       = 1u << 1,
        IMP_AXIS_FAULT       = 1u << 2,
        IMP_AXIS_IN_POSITION = 1u << 3,
};

struct imp_axis_status {
        int32_t position_um;
        int32_t target_um;
        unsigned flags;                 /* enum imp_axis_flag */
        unsigned fault_code;            /* backend's code, 0 = none; see docs/dome-registers.md */
};

/* One table per backend. name/open/close are required, every other slot may be NULL. */
struct imp_dome_ops {
        /* Name used in rig configs ("modbus", "gpiod"). */
        const char *name;
        /* Connect; address syntax is the backend's ("127.0.0.1:1502;timeout_ms=200"). */
        int (*open)(const char *address, unsigned timeout_ms, void **ret_state);
        /* Release the device (the backend does not switch lights; the wrapper did). */
        void (*close)(void *state);
        /* Light and axis counts. */
        int (*get_info)(void *state, struct imp_dome_info *ret_info);
        /* Set one light's level, 0..1000 permille. Touches no other light. */
        int (*set_light)(void *state, unsigned id, unsigned level_permille);
        /* Switch every light off in one step where the device allows it. */
        int (*all_off)(void *state);
        /* Light levels as the device reports them. */
        int (*get_state)(void *state, struct imp_dome_state *ret_state);
        /* Start a move of axis to pos_um and return; completion is polled with get_axis_status. */
        int (*move_to)(void *state, unsigned axis, int32_t pos_um);
        /* Start homing axis. */
        int (*home)(void *state, unsigned axis);
        /* Stop axis motion now. */
        int (*stop_axis)(void *state, unsigned axis);
        /* Clear a latched axis fault. */
        int (*clear_fault)(void *state, unsigned axis);
        /* Position, target, flags and fault code of one axis. */
        int (*get_axis_status)(void *state, unsigned axis, struct imp_axis_status *ret_status);
        /* Human detail of the last failure ("write register 0x0103: exception 4 ..."), or NULL. */
        const char *(*last_error)(void *state);
};

enum imp_dome_light_flag {
        IMP_DOME_LIGHT_MULTI = 1u << 0, /* keep the other lights as they are */
};

struct imp_dome;

const struct imp_dome_ops *imp_dome_backend(const char *name);

/* Open a dome and switch all lights off. Caller frees with imp_dome_close() (which switches
 * them off again). -ENOENT: no backend by that name. */
int imp_dome_open(const char *backend, const char *address, unsigned timeout_ms,
                  struct imp_dome **ret_dome);
void imp_dome_close(struct imp_dome *dome);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_dome *, imp_dome_close);

const char *imp_dome_backend_name(const struct imp_dome *dome);
int imp_dome_get_info(struct imp_dome *dome, struct imp_dome_info *ret_info);
/* Light id at level_permille. Without IMP_DOME_LIGHT_MULTI every other lit light is switched
 * off first, so two lights are never on at once. On failure all lights are switched off. */
int imp_dome_set_light(struct imp_dome *dome, unsigned id, unsigned level_permille, unsigned flags);
int imp_dome_all_off(struct imp_dome *dome);
int imp_dome_get_state(struct imp_dome *dome, struct imp_dome_state *ret_state);
/* Move and wait until in position (polled every few ms) or timeout_ms: -ETIMEDOUT (the axis
 * is stopped), -EIO when the axis reports a fault (details in imp_dome_last_error()). */
int imp_dome_move_to(struct imp_dome *dome, unsigned axis, int32_t pos_um, unsigned timeout_ms);
int imp_dome_home(struct imp_dome *dome, unsigned axis, unsigned timeout_ms);
int imp_dome_clear_fault(struct imp_dome *dome, unsigned axis);
int imp_dome_get_axis_status(struct imp_dome *dome, unsigned axis, struct imp_axis_status *ret_status);
/* What the last failing call did and why ("set light 3 to 1000‰: ..."); "" after success. */
const char *imp_dome_last_error(const struct imp_dome *dome);
/* False when a failure could not even switch the lights off: their state is unknown. */
bool imp_dome_lights_known(const struct imp_dome *dome);
