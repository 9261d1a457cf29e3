/* Motion stage device class: the gantry that carries camera, projector and dome over a
 * painting, behind one constant table of operations per backend ("modbus", "grbl"),
 * chosen by name. The wrapper keeps the invariants a tiled scan needs: no move outside the
 * soft limits, no move while a fault is latched, no move while the position is not known
 * (never homed, or lost), and a move that does not settle in time is stopped. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "macro.h"

#define IMP_STAGE_MAX_AXES 3            /* x, y and an optional z (focus / height) */
#define IMP_STAGE_DEFAULT_SPEED_MM_S 50.0
#define IMP_STAGE_DEFAULT_TOLERANCE_MM 0.010    /* read-back within 10 µm counts as there */

enum imp_stage_axis_mask {
        IMP_STAGE_X = 1u << 0,
        IMP_STAGE_Y = 1u << 1,
        IMP_STAGE_Z = 1u << 2,
        IMP_STAGE_XY = IMP_STAGE_X | IMP_STAGE_Y,
        IMP_STAGE_XYZ = IMP_STAGE_XY | IMP_STAGE_Z,
};

struct imp_stage_info {
        char model[96];
        unsigned n_axes;                        /* 2 (x, y) or 3 (x, y, z) */
        double travel_mm[IMP_STAGE_MAX_AXES];   /* machine travel: positions 0..travel after homing */
};

enum imp_stage_flag {
        IMP_STAGE_MOVING      = 1u << 0,        /* a move is running (feed hold counts as moving) */
        IMP_STAGE_HOMING      = 1u << 1,        /* a homing cycle is running */
        IMP_STAGE_HOMED       = 1u << 2,        /* position known: homed, and not lost since */
        IMP_STAGE_IN_POSITION = 1u << 3,        /* the last move or home ended at its target */
        IMP_STAGE_HELD        = 1u << 4,        /* stopped by soft-stop before its target */
};

/* Why the stage refuses to move. The controller's own code is in fault_code. */
enum imp_stage_fault {
        IMP_STAGE_FAULT_NONE = 0,
        IMP_STAGE_FAULT_LIMIT,          /* a hard limit switch was hit: the position is lost */
        IMP_STAGE_FAULT_LOST_POSITION,  /* steps lost, controller reset or reset in motion */
        IMP_STAGE_FAULT_ALARM,          /* a drive or controller alarm (over-current, e-stop, ...) */
        IMP_STAGE_FAULT_HOMING,         /* the homing cycle failed */
        IMP_STAGE_FAULT_TRAVEL,         /* the controller refused a target outside its travel */
        _IMP_STAGE_FAULT_MAX,
};

struct imp_stage_status {
        double position_mm[IMP_STAGE_MAX_AXES]; /* read back, machine coordinates */
        unsigned flags;                         /* enum imp_stage_flag */
        enum imp_stage_fault fault;             /* latched until imp_stage_clear_fault() */
        unsigned fault_code;                    /* the controller's: GRBL ALARM:N, Modbus FAULT */
        unsigned limit_mask;                    /* hard limit switches pressed now, enum imp_stage_axis_mask */
};

/* Where and how the wrapper lets the stage go. Soft limits come from the rig config and
 * must lie inside the controller's travel. */
struct imp_stage_config {
        double min_mm[IMP_STAGE_MAX_AXES];
        double max_mm[IMP_STAGE_MAX_AXES];
        double speed_mm_s;                      /* feed of every move, > 0 */
        double tolerance_mm;                    /* read-back vs target for "settled", > 0 */
};

/* One table per backend. name/open/close/get_info/get_status are required, every other
 * slot may be NULL (the wrapper answers -EOPNOTSUPP). Operations start and return; the
 * wrapper polls get_status for completion. */
struct imp_stage_ops {
        /* Name used in rig configs ("modbus", "grbl"). */
        const char *name;
        /* Connect; address syntax is the backend's ("127.0.0.1:1502;timeout_ms=200"). */
        int (*open)(const char *address, unsigned timeout_ms, void **ret_state);
        /* Release the device; it does not stop a running move (the wrapper did). */
        void (*close)(void *state);
        /* Axis count and travel as the controller reports them. */
        int (*get_info)(void *state, struct imp_stage_info *ret_info);
        /* Start a move of the axes in mask to target_mm (absolute) at speed_mm_s. */
        int (*move_to)(void *state, const double target_mm[IMP_STAGE_MAX_AXES], unsigned mask,
                       double speed_mm_s);
        /* Start the homing cycle of every axis; on success the position is known (0 where
         * the controller sets its origin at home). */
        int (*home)(void *state);
        /* Position, flags, latched fault and limit switches. */
        int (*get_status)(void *state, struct imp_stage_status *ret_status);
        /* Decelerate to a stop and drop the rest of the move, keeping the position. */
        int (*soft_stop)(void *state);
        /* Clear a latched fault or alarm. Does not make a lost position known again. */
        int (*clear_fault)(void *state);
        /* Human detail of the last failure ("read 16 registers at 0x0008 ..."), or NULL. */
        const char *(*last_error)(void *state);
};

struct imp_stage;

const struct imp_stage_ops *imp_stage_backend(const char *name);
/* "hard limit switch hit", "position lost", ...; "unknown fault" out of range. */
const char *imp_stage_fault_name(enum imp_stage_fault fault);

/* Open a stage. The config starts as imp_stage_default_config() of the controller's
 * travel. Caller frees with imp_stage_close() (which soft-stops a running move).
 * -ENOENT: no backend by that name. */
int imp_stage_open(const char *backend, const char *address, unsigned timeout_ms,
                   struct imp_stage **ret_stage);
void imp_stage_close(struct imp_stage *stage);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_stage *, imp_stage_close);

/* Soft limits = the whole travel, speed and tolerance the defaults above. */
void imp_stage_default_config(const struct imp_stage_info *info, struct imp_stage_config *ret_config);
/* -ERANGE when a soft limit lies outside the travel or min > max on an axis in use,
 * -EINVAL for a speed or tolerance that is not a positive finite number. */
int imp_stage_configure(struct imp_stage *stage, const struct imp_stage_config *config);
int imp_stage_get_config(struct imp_stage *stage, struct imp_stage_config *ret_config);

const char *imp_stage_backend_name(const struct imp_stage *stage);
int imp_stage_get_info(struct imp_stage *stage, struct imp_stage_info *ret_info);

/* Start the homing cycle. -EIO when a fault is latched (clear it first). */
int imp_stage_home(struct imp_stage *stage);
/* Start an absolute move of the axes in mask (z only on a 3-axis stage). Nothing is sent
 * when it is refused: -EINVAL (not finite, bad mask), -ERANGE (outside the soft limits),
 * -EIO (a fault is latched: imp_stage_clear_fault()), -ESTALE (position not known:
 * imp_stage_home()), -EBUSY (a move or homing is running). */
int imp_stage_move_to(struct imp_stage *stage, const double target_mm[IMP_STAGE_MAX_AXES], unsigned mask);
/* Wait until the last move or home has settled: not moving, in position, and every axis of
 * the move read back within the tolerance of its target. Polled every few ms.
 * -ETIMEDOUT after timeout_ms (the stage is then soft-stopped), -EIO when a fault is
 * latched meanwhile, or the controller's own error. ret_status (may be NULL) gets the last
 * status read, on failure too. */
int imp_stage_wait_settled(struct imp_stage *stage, unsigned timeout_ms, struct imp_stage_status *ret_status);
/* The same, one status read at a time, for a caller with its own event loop (impastod): 0
 * settled, -EAGAIN not yet (poll again in IMP_STAGE_POLL_INTERVAL_MS or so), otherwise what
 * imp_stage_wait_settled() returns once deadline_us (imp_stage_deadline_us()) has passed
 * (the stage soft-stopped; timeout_ms only names it in the message). One call blocks at most
 * for the controller's answer to a status query. */
#define IMP_STAGE_POLL_INTERVAL_MS 10
uint64_t imp_stage_deadline_us(unsigned timeout_ms);
int imp_stage_poll_settled(struct imp_stage *stage, uint64_t deadline_us, unsigned timeout_ms,
                           struct imp_stage_status *ret_status);
int imp_stage_get_status(struct imp_stage *stage, struct imp_stage_status *ret_status);
/* Decelerate to a stop and forget the rest of the move; the position stays known. */
int imp_stage_soft_stop(struct imp_stage *stage);
int imp_stage_clear_fault(struct imp_stage *stage);
/* What the last failing call did and why ("move to (10.000, 20.000) mm: ..."); "" after success. */
const char *imp_stage_last_error(const struct imp_stage *stage);
