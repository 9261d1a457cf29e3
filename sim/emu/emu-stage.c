/* The stage emulators' common part: axes that move in real time along a straight line,
 * homing, limit switches and stalls, the fault injection entry points and the server
 * thread's start and stop. The protocols are in emu-stage-modbus.c and emu-grbl.c. */
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "emu-stage-internal.h"

#define DEFAULT_HOME_SPEED_MM_S 400.0
#define DEFAULT_RAPID_SPEED_MM_S 500.0

static const double default_travel_mm[IMP_EMU_STAGE_MAX_AXES] = { 400, 300, 50 };

uint64_t emu_stage_now_us(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return (uint64_t) ts.tv_sec * 1000000u + (uint64_t) ts.tv_nsec / 1000u;
}

int emu_stage_new(const struct imp_emu_stage_config *cfg, struct imp_emu_stage **ret_emu) {
        if (!cfg || !ret_emu)
                return -EINVAL;
        struct imp_emu_stage *e = calloc(1, sizeof *e);
        if (!e)
                return -ENOMEM;
        e->cfg = *cfg;
        if (!e->cfg.address)
                e->cfg.address = "127.0.0.1";
        if (!e->cfg.n_axes)
                e->cfg.n_axes = IMP_EMU_STAGE_MAX_AXES;
        if (!(e->cfg.home_speed_mm_s > 0))
                e->cfg.home_speed_mm_s = DEFAULT_HOME_SPEED_MM_S;
        if (!(e->cfg.rapid_speed_mm_s > 0))
                e->cfg.rapid_speed_mm_s = DEFAULT_RAPID_SPEED_MM_S;
        for (unsigned a = 0; a < IMP_EMU_STAGE_MAX_AXES; a++) {
                if (!(e->cfg.travel_mm[a] > 0))
                        e->cfg.travel_mm[a] = default_travel_mm[a];
                e->motion.switch_mm[a] = NAN;
        }
        e->wake[0] = e->wake[1] = -1;
        pthread_mutex_init(&e->lock, NULL);
        if (e->cfg.n_axes < 2 || e->cfg.n_axes > IMP_EMU_STAGE_MAX_AXES) {
                imp_emu_stage_free(e);
                return -EINVAL;
        }
        *ret_emu = e;
        return 0;
}

int emu_stage_start(struct imp_emu_stage *e) {
        if (pipe(e->wake) < 0)
                return negative_errno();
        int r = -pthread_create(&e->thread, NULL, e->proto->thread, e);
        if (r < 0)
                return r;
        e->running = true;
        return 0;
}

void imp_emu_stage_free(struct imp_emu_stage *e) {
        if (!e)
                return;
        if (e->running) {
                (void) !write(e->wake[1], "x", 1);
                pthread_join(e->thread, NULL);
        }
        if (e->proto && e->proto->destroy)
                e->proto->destroy(e);
        if (e->wake[0] >= 0) {
                close(e->wake[0]);
                close(e->wake[1]);
        }
        pthread_mutex_destroy(&e->lock);
        free(e);
}

/* Fraction of the way where the first switch closes on the segment start → stop, or > 1. */
static double switch_fraction(const struct imp_emu_stage *e, const double *start, const double *stop,
                              unsigned *ret_axis) {
        double best = 2;
        for (unsigned a = 0; a < e->cfg.n_axes; a++) {
                double sw = e->motion.switch_mm[a];
                if (isnan(sw) || !(start[a] < sw && stop[a] >= sw))
                        continue;
                double f = (sw - start[a]) / (stop[a] - start[a]);
                if (f < best) {
                        best = f;
                        *ret_axis = a;
                }
        }
        return best;
}

static enum emu_event advance_locked(struct imp_emu_stage *e) {
        struct emu_motion *m = &e->motion;
        if (m->phase == EMU_PHASE_IDLE)
                return EMU_EVENT_NONE;
        double dist = 0, now_mm[IMP_EMU_STAGE_MAX_AXES];
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                dist += (m->target_mm[a] - m->start_mm[a]) * (m->target_mm[a] - m->start_mm[a]);
        dist = sqrt(dist);
        double f = dist > 0 ? m->speed_mm_s * (double) (emu_stage_now_us() - m->t0_us) * 1e-6 / dist : 1;
        double f_max = m->phase == EMU_PHASE_MOVING && e->stall ? EMU_STAGE_STALL_FRACTION : 1;
        f = fmin(f, f_max);
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                now_mm[a] = m->start_mm[a] + (m->target_mm[a] - m->start_mm[a]) * f;
        /* From the segment's start: the motion is a line, so the first crossing is the same. */
        double fs = switch_fraction(e, m->start_mm, now_mm, &m->limit_axis);
        if (fs <= 1) {
                for (unsigned a = 0; a < e->cfg.n_axes; a++)
                        m->pos_mm[a] = m->start_mm[a] + (now_mm[a] - m->start_mm[a]) * fs;
                memcpy(m->target_mm, m->pos_mm, sizeof m->pos_mm);
                m->phase = EMU_PHASE_IDLE;
                m->homed = m->in_position = false;
                return EMU_EVENT_LIMIT;
        }
        memcpy(m->pos_mm, now_mm, sizeof now_mm);
        if (f < 1)
                return EMU_EVENT_NONE;
        enum emu_event ev = m->phase == EMU_PHASE_HOMING ? EMU_EVENT_HOMED : EMU_EVENT_ARRIVED;
        if (ev == EMU_EVENT_ARRIVED)
                for (unsigned a = 0; a < e->cfg.n_axes; a++)
                        if (m->target_mm[a] != m->start_mm[a])
                                m->pos_mm[a] -= copysign(e->arrive_short_mm, m->target_mm[a] - m->start_mm[a]);
        if (ev == EMU_EVENT_HOMED)
                m->homed = true;
        m->phase = EMU_PHASE_IDLE;
        m->in_position = true;
        return ev;
}

enum emu_event emu_motion_update_locked(struct imp_emu_stage *e) {
        enum emu_event ev = advance_locked(e);
        if (ev != EMU_EVENT_NONE && e->proto && e->proto->event_locked)
                e->proto->event_locked(e, ev);
        return ev;
}

static void begin_locked(struct imp_emu_stage *e, enum emu_phase phase, const double *target, double speed) {
        struct emu_motion *m = &e->motion;
        memcpy(m->start_mm, m->pos_mm, sizeof m->pos_mm);
        memcpy(m->target_mm, target, sizeof m->target_mm);
        m->speed_mm_s = speed;
        m->t0_us = emu_stage_now_us();
        m->phase = phase;
        m->in_position = m->held = false;
}

void emu_motion_start_locked(struct imp_emu_stage *e, const double target_mm[IMP_EMU_STAGE_MAX_AXES],
                             double speed_mm_s) {
        e->n_moves++;
        begin_locked(e, EMU_PHASE_MOVING, target_mm, speed_mm_s);
}

void emu_motion_home_locked(struct imp_emu_stage *e) {
        static const double zero[IMP_EMU_STAGE_MAX_AXES] = { 0 };
        e->motion.homed = false;
        begin_locked(e, EMU_PHASE_HOMING, zero, e->cfg.home_speed_mm_s);
}

void emu_motion_halt_locked(struct imp_emu_stage *e) {
        struct emu_motion *m = &e->motion;
        (void) emu_motion_update_locked(e);
        if (m->phase == EMU_PHASE_MOVING)
                m->held = true;
        if (m->phase == EMU_PHASE_HOMING)
                m->homed = false;
        m->phase = EMU_PHASE_IDLE;
        memcpy(m->target_mm, m->pos_mm, sizeof m->pos_mm);
}

unsigned emu_motion_limits_locked(const struct imp_emu_stage *e) {
        unsigned mask = 0;
        for (unsigned a = 0; a < e->cfg.n_axes; a++)
                if (!isnan(e->motion.switch_mm[a]) && e->motion.pos_mm[a] >= e->motion.switch_mm[a])
                        mask |= 1u << a;
        return mask;
}

/* ---- fault injection and inspection ------------------------------------------------------ */

void imp_emu_stage_limit_switch_at(struct imp_emu_stage *e, unsigned axis, double pos_mm) {
        if (axis >= e->cfg.n_axes)
                return;
        pthread_mutex_lock(&e->lock);
        (void) emu_motion_update_locked(e);     /* the switch acts from now on, not in the past */
        memcpy(e->motion.start_mm, e->motion.pos_mm, sizeof e->motion.pos_mm);
        e->motion.t0_us = emu_stage_now_us();
        e->motion.switch_mm[axis] = pos_mm;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_alarm(struct imp_emu_stage *e, unsigned code) {
        pthread_mutex_lock(&e->lock);
        e->proto->alarm_locked(e, code);
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_lose_position(struct imp_emu_stage *e) {
        pthread_mutex_lock(&e->lock);
        e->proto->lose_position_locked(e);
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_stall(struct imp_emu_stage *e, bool stall) {
        pthread_mutex_lock(&e->lock);
        e->stall = stall;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_arrive_short(struct imp_emu_stage *e, double short_mm) {
        pthread_mutex_lock(&e->lock);
        e->arrive_short_mm = short_mm;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_lose_requests(struct imp_emu_stage *e, unsigned n) {
        pthread_mutex_lock(&e->lock);
        e->lose_requests = n;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_mute(struct imp_emu_stage *e, bool mute) {
        pthread_mutex_lock(&e->lock);
        e->mute = mute;
        pthread_mutex_unlock(&e->lock);
}

void imp_emu_stage_position(struct imp_emu_stage *e, double ret_mm[IMP_EMU_STAGE_MAX_AXES]) {
        pthread_mutex_lock(&e->lock);
        (void) emu_motion_update_locked(e);
        memcpy(ret_mm, e->motion.pos_mm, sizeof e->motion.pos_mm);
        pthread_mutex_unlock(&e->lock);
}

bool imp_emu_stage_homed(struct imp_emu_stage *e) {
        pthread_mutex_lock(&e->lock);
        bool h = e->motion.homed;
        pthread_mutex_unlock(&e->lock);
        return h;
}

bool imp_emu_stage_moving(struct imp_emu_stage *e) {
        pthread_mutex_lock(&e->lock);
        (void) emu_motion_update_locked(e);
        bool moving = e->motion.phase != EMU_PHASE_IDLE;
        pthread_mutex_unlock(&e->lock);
        return moving;
}

unsigned imp_emu_stage_n_moves(struct imp_emu_stage *e) {
        pthread_mutex_lock(&e->lock);
        unsigned n = e->n_moves;
        pthread_mutex_unlock(&e->lock);
        return n;
}

unsigned imp_emu_stage_n_resets(struct imp_emu_stage *e) {
        pthread_mutex_lock(&e->lock);
        unsigned n = e->n_resets;
        pthread_mutex_unlock(&e->lock);
        return n;
}
