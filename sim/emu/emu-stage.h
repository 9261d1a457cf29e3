/* Motion stage emulators that stand behind the real stage drivers in tests: a Modbus TCP
 * stepper/servo controller (docs/stage-registers.md, a libmodbus server thread on
 * loopback) and a GRBL 1.1 gantry controller on a pseudo-terminal. Both move in real time
 * at the commanded speed and take the same faults on demand. */
#pragma once
#include <stdbool.h>
#include <stdint.h>
#include "macro.h"

#define IMP_EMU_STAGE_MAX_AXES 3

struct imp_emu_stage_config {
        const char *address;            /* Modbus: listen address, default "127.0.0.1" */
        uint16_t port;                  /* Modbus: TCP port, required; unused by GRBL */
        unsigned n_axes;                /* 2 or 3, default 3 */
        double travel_mm[IMP_EMU_STAGE_MAX_AXES];      /* default 400 × 300 × 50 mm */
        double home_speed_mm_s;         /* homing runs to 0 at this speed, default 400 */
        double rapid_speed_mm_s;        /* GRBL G0 rate ($110), default 500 */
        /* GRBL as built by default (no HOMING_FORCE_SET_ORIGIN): machine coordinates run
         * −travel..0; homing (toward the minimum here) ends at MPos −travel. */
        bool grbl_negative_space;
};

struct imp_emu_stage;

/* A Modbus TCP stage controller listening on cfg->address:cfg->port when it returns.
 * -EADDRINUSE when the port is taken. Caller frees with imp_emu_stage_free(). */
int imp_emu_stage_modbus_new(const struct imp_emu_stage_config *cfg, struct imp_emu_stage **ret_emu);
/* A GRBL 1.1 controller on a pseudo-terminal: clients open imp_emu_stage_device() as their
 * serial port. Machine coordinates 0..travel after homing (GRBL built with
 * HOMING_FORCE_SET_ORIGIN) unless cfg->grbl_negative_space; homing enabled, so it powers
 * up locked in Alarm.
 * Caller frees with imp_emu_stage_free(). */
int imp_emu_stage_grbl_new(const struct imp_emu_stage_config *cfg, struct imp_emu_stage **ret_emu);
void imp_emu_stage_free(struct imp_emu_stage *emu);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_emu_stage *, imp_emu_stage_free);
/* The pseudo-terminal a GRBL client opens ("/dev/pts/N"), NULL for the Modbus emulator. */
const char *imp_emu_stage_device(const struct imp_emu_stage *emu);

/* ---- faults, effective at once -------------------------------------------------------- */

/* A hard limit switch on axis that closes when the axis reaches pos_mm moving up (an
 * obstacle, a misplaced switch). NAN removes it. The controller stops every axis at the
 * switch and loses its position: Modbus fault 1, GRBL ALARM:1 (locked until a reset). */
void imp_emu_stage_limit_switch_at(struct imp_emu_stage *emu, unsigned axis, double pos_mm);
/* The controller raises an alarm and stops: Modbus latches FAULT = code (3 drive alarm,
 * 2 lost position, ...); GRBL sends ALARM:code (1 and 2 lock it until a reset; 1, 3, 6..9
 * lose the position). */
void imp_emu_stage_alarm(struct imp_emu_stage *emu, unsigned code);
/* The controller loses its position by itself: Modbus fault 2 (following error); GRBL
 * restarts (a brown-out): the banner, position counted from 0 again, locked in Alarm. */
void imp_emu_stage_lose_position(struct imp_emu_stage *emu);
/* While on, a move stops at 90 % of its way and stays "moving" (a stalled or hunting axis):
 * it never settles. Homing is not affected. */
void imp_emu_stage_stall(struct imp_emu_stage *emu, bool stall);
/* Moves end short_mm before their target on each moving axis and report "in position"
 * all the same (a servo with a loose in-position window, backlash); 0 turns it off. */
void imp_emu_stage_arrive_short(struct imp_emu_stage *emu, double short_mm);
/* The next n requests (Modbus) or command lines (GRBL; real-time characters still act) are
 * lost on the way: neither run nor answered. */
void imp_emu_stage_lose_requests(struct imp_emu_stage *emu, unsigned n);
/* While on, the controller reads requests and answers none (hung firmware). */
void imp_emu_stage_mute(struct imp_emu_stage *emu, bool mute);

/* ---- what the controller holds ---------------------------------------------------------- */

/* The axes' positions now, mm. */
void imp_emu_stage_position(struct imp_emu_stage *emu, double ret_mm[IMP_EMU_STAGE_MAX_AXES]);
bool imp_emu_stage_homed(struct imp_emu_stage *emu);
/* A move or homing is running (a stalled move stays running until it is stopped). */
bool imp_emu_stage_moving(struct imp_emu_stage *emu);
/* Moves started (homing excluded) and, for GRBL, resets (Ctrl-X) received. */
unsigned imp_emu_stage_n_moves(struct imp_emu_stage *emu);
unsigned imp_emu_stage_n_resets(struct imp_emu_stage *emu);
