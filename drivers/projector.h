/* Projector device class: a structured-light projector behind one constant table of
 * operations per backend, chosen by name from the rig config:
 *   "usb-dlp"  a DLP controller on USB (libusb; command set in docs/projector-usb.md)
 *   "modbus"   a pattern sequencer on the rig's Modbus controller (docs/dome-registers.md)
 * A sequence of patterns is uploaded once per scan; show(i) displays pattern i; dark()
 * blanks the output. Drivers do not log; every failure returns a negative errno and
 * leaves the projector dark where the device still answers. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "macro.h"
#include "pattern.h"

#define IMP_PROJECTOR_MAX_PATTERNS 256

struct imp_projector_info {
        char model[64];
        char serial[64];
        int width, height;              /* native resolution, pixels */
        unsigned max_patterns;          /* sequence capacity */
};

struct imp_projector_status {
        int shown;                      /* index shown now, -1 dark */
        unsigned n_uploaded;            /* patterns in the current sequence */
        bool fault;                     /* lamp/LED or sequencer fault latched */
        unsigned fault_code;            /* backend's code, 0 = none */
        uint64_t shown_at_ns;           /* device timestamp of the last show() (CLOCK_MONOTONIC
                                           of the host when the device has none) */
};

/* One table per backend. name/open/close are required, other slots may be NULL
 * (the wrapper answers -EOPNOTSUPP). */
struct imp_projector_ops {
        /* Name used in rig configs. */
        const char *name;
        /* Connect; the address syntax is the backend's ("1d50:6020", "127.0.0.1:1502"). */
        int (*open)(const char *address, unsigned timeout_ms, void **ret_state);
        /* Release the device (the wrapper has blanked it). */
        void (*close)(void *state);
        /* Model, serial, resolution, capacity. */
        int (*get_info)(void *state, struct imp_projector_info *ret_info);
        /* Replace the sequence with n patterns (n <= max_patterns). */
        int (*upload)(void *state, const struct imp_pattern *patterns, unsigned n);
        /* Display pattern i of the sequence and return once it is on. */
        int (*show)(void *state, unsigned index);
        /* Blank the output. */
        int (*dark)(void *state);
        /* Fire the trigger output (cameras in hardware-trigger mode). */
        int (*trigger)(void *state);
        /* Shown index, counts, faults. */
        int (*get_status)(void *state, struct imp_projector_status *ret_status);
        /* Human detail of the last failure, or NULL. */
        const char *(*last_error)(void *state);
};

struct imp_projector;

const struct imp_projector_ops *imp_projector_backend(const char *name);
/* Opens a projector and blanks it. Caller frees with imp_projector_close() (which blanks it
 * again). -ENOENT: no backend by that name. */
int imp_projector_open(const char *backend, const char *address, unsigned timeout_ms,
                       struct imp_projector **ret);
/* The same with an explicit backend table (tests; backends outside the built-in list). */
int imp_projector_open_ops(const struct imp_projector_ops *ops, const char *address, unsigned timeout_ms,
                           struct imp_projector **ret);
void imp_projector_close(struct imp_projector *p);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_projector *, imp_projector_close);
int imp_projector_get_info(struct imp_projector *p, struct imp_projector_info *ret_info);
int imp_projector_upload(struct imp_projector *p, const struct imp_pattern *patterns, unsigned n);
int imp_projector_show(struct imp_projector *p, unsigned index);
int imp_projector_dark(struct imp_projector *p);
int imp_projector_trigger(struct imp_projector *p);
int imp_projector_get_status(struct imp_projector *p, struct imp_projector_status *ret_status);
/* What the last failing call did and why; "" after success. */
const char *imp_projector_last_error(const struct imp_projector *p);
