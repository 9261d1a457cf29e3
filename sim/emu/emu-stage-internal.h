/* What the two stage emulators share (emu-stage.c): the motion model of the axes, the fault
 * injection state, the lock and the server thread's life. Each protocol file adds its
 * server loop and its reaction to injected faults through struct emu_stage_proto. */
#pragma once
#include <pthread.h>
#include <stdbool.h>
#include <stdint.h>
#include "emu-stage.h"

/* Where a motion is. Homing is a straight run to 0 at the homing speed. */
enum emu_phase {
        EMU_PHASE_IDLE,
        EMU_PHASE_MOVING,
        EMU_PHASE_HOMING,
};

/* What an update found. */
enum emu_event {
        EMU_EVENT_NONE,
        EMU_EVENT_ARRIVED,      /* a move reached its target */
        EMU_EVENT_HOMED,        /* homing reached 0 */
        EMU_EVENT_LIMIT,        /* a limit switch closed: every axis stopped there */
};

struct emu_motion {
        enum emu_phase phase;
        double pos_mm[IMP_EMU_STAGE_MAX_AXES], start_mm[IMP_EMU_STAGE_MAX_AXES];
        double target_mm[IMP_EMU_STAGE_MAX_AXES];
        double speed_mm_s;
        uint64_t t0_us;
        bool homed;
        bool in_position;       /* the last move or homing reached its target */
        bool held;              /* the last move was stopped before its target */
        double switch_mm[IMP_EMU_STAGE_MAX_AXES];       /* NAN: no switch */
        unsigned limit_axis;    /* after EMU_EVENT_LIMIT */
};

struct imp_emu_stage;

struct emu_stage_proto {
        void *(*thread)(void *emu);
        /* Called with the lock held. A motion event, from whichever thread advanced the motion. */
        void (*event_locked)(struct imp_emu_stage *e, enum emu_event ev);
        void (*alarm_locked)(struct imp_emu_stage *e, unsigned code);
        void (*lose_position_locked)(struct imp_emu_stage *e);
        /* After the thread stopped: release the protocol's state (e->proto_state). */
        void (*destroy)(struct imp_emu_stage *e);
};

struct imp_emu_stage {
        struct imp_emu_stage_config cfg;
        const struct emu_stage_proto *proto;
        void *proto_state;
        int wake[2];                    /* the thread stops when wake[0] is readable */
        pthread_t thread;
        bool running;

        pthread_mutex_t lock;           /* everything below and the protocol's state */
        struct emu_motion motion;
        bool stall, mute;
        double arrive_short_mm;
        unsigned lose_requests;
        unsigned n_moves, n_resets;
};

#define EMU_STAGE_STALL_FRACTION 0.9
#define EMU_STAGE_TICK_US 5000          /* server loops wake this often to advance motion */

uint64_t emu_stage_now_us(void);
/* Allocates and fills defaults; the caller sets proto/proto_state and calls emu_stage_start. */
int emu_stage_new(const struct imp_emu_stage_config *cfg, struct imp_emu_stage **ret_emu);
int emu_stage_start(struct imp_emu_stage *e);

/* Motion, lock held. update advances to now and hands an event to the protocol's
 * event_locked before returning it; start/home begin at now; halt stops where the axes are. */
enum emu_event emu_motion_update_locked(struct imp_emu_stage *e);
void emu_motion_start_locked(struct imp_emu_stage *e, const double target_mm[IMP_EMU_STAGE_MAX_AXES], double speed_mm_s);
void emu_motion_home_locked(struct imp_emu_stage *e);
void emu_motion_halt_locked(struct imp_emu_stage *e);
/* Limit switches closed now, bit a = axis a. */
unsigned emu_motion_limits_locked(const struct imp_emu_stage *e);
