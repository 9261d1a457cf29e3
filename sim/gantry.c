/* The simulated gantry (gantry.h): stage poses with the `stage_error` effect, the clock of
 * its moves, and the tile-by-tile render of a whole painting. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "gantry.h"
#include "json-util.h"
#include "render.h"

/* A standard normal from two hashed uniforms (Box–Muller), deterministic in (seed, k, what). */
static double gauss(uint64_t seed, size_t k, unsigned what) {
        uint64_t h = imp_mix64(seed ^ imp_mix64(0x5741474eull + (uint64_t) k * 16 + what));
        double u1 = imp_u01(h), u2 = imp_u01(imp_mix64(h + 1));
        return sqrt(-2 * log(1 - u1)) * cos(2 * M_PI * u2);
}

void imp_sim_tile_pose(const struct imp_scene *s, const struct imp_tile_plan *tp, size_t k,
                       struct imp_sim_tile_pose *ret) {
        const struct imp_tile *t = imp_tile_plan_tile(tp, k);
        *ret = (struct imp_sim_tile_pose) { 0 };
        for (int a = 0; a < 3; a++)
                ret->commanded_mm[a] = ret->readback_mm[a] = ret->true_mm[a] = t->stage_mm[a];
        const struct imp_stage_error *e = imp_scene_stage_error(s);
        if (!e)
                return;
        /* The direction of the last move along each axis, + from home (targets lie above 0). */
        double dir[2] = { 1, 1 };
        for (size_t i = 1; i <= k; i++)
                for (int a = 0; a < 2; a++) {
                        double d = imp_tile_plan_tile(tp, i)->stage_mm[a] - imp_tile_plan_tile(tp, i - 1)->stage_mm[a];
                        if (d != 0)
                                dir[a] = d > 0 ? 1 : -1;
                }
        uint64_t seed = imp_scene_seed(s);
        for (int a = 0; a < 2; a++)
                ret->true_mm[a] += -0.5 * e->backlash_mm * dir[a] + e->sigma_mm * gauss(seed, k, (unsigned) a);
        ret->theta_rad = e->sigma_deg * M_PI / 180 * gauss(seed, k, 2);
}

void imp_sim_tile_place(const struct imp_tile_plan *tp, const struct imp_sim_tile_pose *pose,
                        struct imp_painting_place *ret) {
        const struct imp_tile_options *o = imp_tile_plan_options(tp);
        *ret = (struct imp_painting_place) {
                .theta_rad = pose->theta_rad,
                .offset_mm = { pose->true_mm[0] - o->origin_mm[0], pose->true_mm[1] - o->origin_mm[1] },
        };
}

static double axis_move_s(double d, double v, double acc) {
        d = fabs(d);
        if (d == 0)
                return 0;
        return d < v * v / acc ? 2 * sqrt(d / acc) : d / v + v / acc;
}

double imp_sim_move_s(const struct imp_scene_gantry *g, const double from_mm[3], const double to_mm[3]) {
        double t = 0;
        for (int a = 0; a < 3; a++)
                t = fmax(t, axis_move_s(to_mm[a] - from_mm[a], g->speed_mm_s, g->accel_mm_s2));
        return t > 0 ? t + g->settle_s : 0;
}

void imp_sim_stamp(struct imp_frame_record *rec, const struct imp_frame_record *prev, const struct imp_rig *rig,
                   long long *t_ns) {
        double readout_us = 0;
        for (int i = 0; i < rig->n_cameras; i++)
                if (!strcmp(rig->cameras[i].name, rec->camera))
                        readout_us = rig->cameras[i].sensor.readout_us;
        if (!prev || prev->light != rec->light || prev->pattern.kind != rec->pattern.kind ||
            prev->pattern.bit != rec->pattern.bit || prev->pattern.step != rec->pattern.step ||
            prev->pattern.inverse != rec->pattern.inverse || prev->pattern.axis != rec->pattern.axis)
                *t_ns += (long long) (rig->settle_us * 1e3);
        rec->t_light_on_ns = *t_ns;
        *t_ns += (long long) (rig->settle_us * 1e3);
        rec->t_trigger_ns = *t_ns;
        *t_ns += (long long) ((rec->exposure_us + readout_us) * 1e3);
        rec->t_frame_ns = *t_ns;
}

/* ---- rendering a whole painting ------------------------------------------------------------ */

struct painting_run {
        struct imp_scene *scene;
        const struct imp_plan *plan;
        const char *plan_path, *out;
        const struct imp_tile_plan *tp;
        long long t_ns;
        const struct imp_frame_record *prev;
        struct imp_sim_painting_result res;
};

/* Tile k's capture set: the plan's frames rendered with the painting placed at the pose. */
static int render_tile(struct painting_run *run, size_t k, const struct imp_sim_tile_pose *pose,
                       struct imp_error *err) {
        struct imp_painting_place pl;
        imp_sim_tile_place(run->tp, pose, &pl);
        int r = imp_scene_place(run->scene, &pl, err);
        if (r < 0)
                return r;
        _cleanup_(imp_render_freep) struct imp_render *rd = NULL;
        if ((r = imp_render_new(run->scene, &rd, err)) < 0)
                return r;
        char dir[1024];
        if (snprintf(dir, sizeof dir, "%s/tiles/%04zu", run->out, k) >= (int) sizeof dir)
                return imp_error_set(err, -ENAMETOOLONG, "%s: path too long", run->out);
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        if ((r = imp_captureset_create(dir, imp_render_rig(rd), run->plan_path, &cs, err)) < 0)
                return r;
        for (size_t i = 0; i < imp_plan_count(run->plan); i++) {
                struct imp_frame_record rec = *imp_plan_frame(run->plan, i);
                imp_sim_stamp(&rec, run->prev, imp_render_rig(rd), &run->t_ns);
                run->prev = imp_plan_frame(run->plan, i);
                _cleanup_image_ struct imp_image *frame = NULL;
                imp_error_clear(err);
                r = imp_render_frame(rd, &rec, &frame, err);
                if (r == -EAGAIN) {
                        run->res.dropped++;
                        continue;
                }
                if (r < 0 || (r = imp_captureset_add_frame(cs, &rec, frame, err)) < 0)
                        return imp_error_prefix(err, "tile %zu, frame %zu: ", k, i);
                run->res.frames++;
        }
        return imp_sim_write_truth(run->scene, rd, dir, err);
}

static json_t *pose_json(size_t k, const struct imp_tile *t, const struct imp_sim_tile_pose *p,
                         const struct imp_tile_options *o) {
        return json_pack("{s:I,s:I,s:I,s:[f,f],s:f,s:[f,f],s:[f,f,f]}", "index", (json_int_t) k, "col",
                         (json_int_t) t->col, "row", (json_int_t) t->row, "offset_mm", p->true_mm[0] - o->origin_mm[0],
                         p->true_mm[1] - o->origin_mm[1], "theta_deg", p->theta_rad * 180 / M_PI, "nominal_offset_mm",
                         p->readback_mm[0] - o->origin_mm[0], p->readback_mm[1] - o->origin_mm[1], "true_stage_mm",
                         p->true_mm[0], p->true_mm[1], p->true_mm[2]);
}

static int save_json(const char *dir, const char *name, const json_t *j, struct imp_error *err) {
        char path[1100];
        if (!j)
                return imp_error_set(err, -ENOMEM, "%s/%s: out of memory", dir, name);
        if (snprintf(path, sizeof path, "%s/%s", dir, name) >= (int) sizeof path)
                return imp_error_set(err, -ENAMETOOLONG, "%s/%s: path too long", dir, name);
        return imp_json_save_atomic(path, j, err);
}

/* OUT/truth/: the whole painting at the truth pitch and every tile's true pose. */
static int write_painting_truth(struct painting_run *run, json_t *poses, struct imp_error *err) {
        const struct imp_scene_gantry *g = imp_scene_gantry(run->scene);
        int r = imp_scene_place_whole(run->scene, g->truth_pitch_mm, err);
        if (r < 0 || (r = imp_sim_write_painting_truth(run->scene, run->out, err)) < 0)
                return r;
        char tdir[1024];
        snprintf(tdir, sizeof tdir, "%s/truth", run->out);
        _cleanup_json_ json_t *j = json_pack("{s:s,s:O}", "frame", "painting_xy = R(theta) * world_xy + offset_mm",
                                             "tiles", poses);
        return save_json(tdir, "tile-poses.json", j, err);
}

static int check_gantry(const struct imp_scene *scene, const struct imp_tile_plan *tp, struct imp_error *err) {
        if (!tp)
                return imp_error_set(err, -EINVAL, "sim: the plan has no painting group (docs/painting.md)");
        if (!imp_scene_is_gantry(scene))
                return imp_error_set(err, -EINVAL, "sim: scene %s has no gantry group: it samples one field of "
                                     "view, not a painting scanned by tiles (docs/painting.md)", imp_scene_name(scene));
        double canvas[2];
        imp_scene_canvas_size(scene, canvas);
        const struct imp_tile_options *o = imp_tile_plan_options(tp);
        for (int a = 0; a < 2; a++)
                if (o->extent_mm[a] > canvas[a] + 1e-6)
                        return imp_error_set(err, -EINVAL, "sim: the plan's painting.extent_mm %c %.1f mm passes the "
                                             "scene's canvas (%.1f mm)", "xy"[a], o->extent_mm[a], canvas[a]);
        return 0;
}

double imp_sim_painting_clock_s(const struct imp_scene *scene, const struct imp_plan *plan, double *ret_move_s) {
        const struct imp_tile_plan *tp = imp_plan_tiles(plan);
        const struct imp_scene_gantry *g = imp_scene_gantry(scene);
        long long t_ns = 0;
        double move_s = 0;
        const struct imp_frame_record *prev = NULL;
        for (size_t k = 0; tp && g && k < imp_tile_plan_count(tp); k++) {
                if (k > 0) {
                        double m = imp_sim_move_s(g, imp_tile_plan_tile(tp, k - 1)->stage_mm, imp_tile_plan_tile(tp, k)->stage_mm);
                        move_s += m;
                        t_ns += (long long) (m * 1e9);
                }
                for (size_t i = 0; i < imp_plan_count(plan); i++) {
                        struct imp_frame_record rec = *imp_plan_frame(plan, i);
                        imp_sim_stamp(&rec, prev, imp_scene_rig(scene), &t_ns);
                        prev = imp_plan_frame(plan, i);
                }
        }
        if (ret_move_s)
                *ret_move_s = move_s;
        return t_ns * 1e-9;
}

int imp_sim_write_painting_truth_plan(struct imp_scene *scene, const struct imp_plan *plan, const char *out,
                                      struct imp_error *err) {
        const struct imp_tile_plan *tp = imp_plan_tiles(plan);
        int r = check_gantry(scene, tp, err);
        if (r < 0)
                return r;
        struct painting_run run = { .scene = scene, .plan = plan, .out = out, .tp = tp };
        _cleanup_json_ json_t *poses = json_array();
        if (!poses)
                return imp_error_set(err, -ENOMEM, "sim: out of memory");
        for (size_t k = 0; k < imp_tile_plan_count(tp); k++) {
                struct imp_sim_tile_pose pose;
                imp_sim_tile_pose(scene, tp, k, &pose);
                json_array_append_new(poses, pose_json(k, imp_tile_plan_tile(tp, k), &pose, imp_tile_plan_options(tp)));
        }
        return write_painting_truth(&run, poses, err);
}

int imp_sim_render_painting(struct imp_scene *scene, const struct imp_plan *plan, const char *plan_path,
                            const char *out, imp_sim_progress_fn progress, void *userdata,
                            struct imp_sim_painting_result *ret, struct imp_error *err) {
        const struct imp_tile_plan *tp = imp_plan_tiles(plan);
        int r = check_gantry(scene, tp, err);
        if (r < 0)
                return r;
        struct painting_run run = { .scene = scene, .plan = plan, .plan_path = plan_path, .out = out, .tp = tp };
        const struct imp_stage_error *se = imp_scene_stage_error(scene);
        _cleanup_json_ json_t *painting = imp_tile_plan_painting_json(tp, se ? se->sigma_mm : 0, se ? se->sigma_deg : 0);
        _cleanup_json_ json_t *poses = json_array();
        if (!painting || !poses)
                return imp_error_set(err, -ENOMEM, "sim: out of memory");
        if ((r = imp_mkdir_p(out, 0755)) < 0)
                return imp_error_set(err, r, "%s: cannot create: %s", out, strerror(-r));
        size_t n = imp_tile_plan_count(tp);
        for (size_t k = 0; k < n; k++) {
                struct imp_sim_tile_pose pose;
                imp_sim_tile_pose(scene, tp, k, &pose);
                if (k > 0) {
                        double m = imp_sim_move_s(imp_scene_gantry(scene), imp_tile_plan_tile(tp, k - 1)->stage_mm,
                                                  pose.commanded_mm);
                        run.res.move_s += m;
                        run.t_ns += (long long) (m * 1e9);
                }
                if ((r = render_tile(&run, k, &pose, err)) < 0)
                        return r;
                imp_painting_json_set_readback(painting, k, pose.readback_mm);
                json_array_append_new(poses, pose_json(k, imp_tile_plan_tile(tp, k), &pose, imp_tile_plan_options(tp)));
                if (progress)
                        progress(userdata, k, n, run.res.frames);
        }
        run.res.tiles = n;
        run.res.clock_s = run.t_ns * 1e-9;
        if ((r = write_painting_truth(&run, poses, err)) < 0 || (r = save_json(out, "painting.json", painting, err)) < 0)
                return r;
        if (ret)
                *ret = run.res;
        return 0;
}
