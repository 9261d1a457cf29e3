/* Whole paintings in the simulator and the plan (sim/gantry.h, scene gantry groups, the plan's
 * painting group): the plan lays the tiles out and keeps one tile's frames; a tile's window
 * of the painting is the painting seen through its placement; stage_error lands tiles off
 * their read-back with the stated statistics and costs nothing when not listed; a rendered
 * painting has painting.json, a capture set per tile, truth in the painting frame, and a
 * simulated clock that the plan's estimate matches within 10 %.
 * Tolerances are stated at each check. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "gantry.h"
#include "json-util.h"
#include "render.h"
#include "serve.h"
#include "unit/test.h"

#define SCENE IMPASTO_SOURCE_DIR "/config/scenes/painting-small.cfg"

static const char plan_text[] =
        "dome = { lights = [0, 6]; exposures_us = [10000.0]; };\n"
        "painting = { extent_mm = [100.0, 54.0]; fov_mm = [40.0, 30.0]; origin_mm = [20.0, 20.0]; };\n";

static struct imp_scene *load_scene(bool stage_error) {
        struct imp_scene *s = NULL;
        struct imp_error err = {};
        int r = imp_scene_load(SCENE, &s, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        if (s && !stage_error)
                imp_scene_set_effect(s, IMP_FX_STAGE_ERROR, false);
        return s;
}

static struct imp_plan *load_plan(const struct imp_scene *s, const char *text) {
        struct imp_plan *p = NULL;
        struct imp_error err = {};
        int r = imp_plan_load_string(text, "plan.cfg", imp_scene_rig(s), &p, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        return p;
}

/* The painting group gives the tile layout; frames are one tile's, all tile 0; `tiles` beside
 * it is refused naming the field. */
static void test_plan_group(void) {
        _cleanup_(imp_scene_freep) struct imp_scene *s = load_scene(false);
        if (!s)
                return;
        _cleanup_(imp_plan_freep) struct imp_plan *p = load_plan(s, plan_text);
        if (!p)
                return;
        CHECK(imp_plan_tiles(p) != NULL);
        CHECK_INT_EQ(imp_tile_plan_count(imp_plan_tiles(p)), 6);
        CHECK_INT_EQ(imp_plan_count(p), 2);
        for (size_t i = 0; i < imp_plan_count(p); i++)
                CHECK_INT_EQ(imp_plan_frame(p, i)->tile, 0);
        struct imp_plan *bad = NULL;
        struct imp_error err = {};
        char text[512];
        snprintf(text, sizeof text, "tiles = 3;\n%s", plan_text);
        CHECK_ERR(imp_plan_load_string(text, "plan.cfg", imp_scene_rig(s), &bad, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "plan.cfg:1: tiles");
        imp_plan_free(bad);
        _cleanup_(imp_plan_freep) struct imp_plan *one = load_plan(s, "dome = { lights = [0]; exposures_us = [1000.0]; };");
        CHECK(one && imp_plan_tiles(one) == NULL);
}

/* Without stage_error the carriage is where it was told, no rotation; with it, over many
 * tiles the landing error minus the backlash has mean ~0 and σ within 15 % of the stated one
 * (n ≈ 1000: the σ of a σ estimate is ~2 %), the backlash follows the direction of travel,
 * and θ has the stated σ within 15 %. */
static void test_stage_error(void) {
        _cleanup_(imp_scene_freep) struct imp_scene *s = load_scene(true);
        if (!s)
                return;
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        o.extent_mm[0] = 1000, o.extent_mm[1] = 1000, o.fov_mm[0] = 30, o.fov_mm[1] = 30;
        o.origin_mm[0] = o.origin_mm[1] = 10;
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *tp = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_tile_plan_new(&o, &tp, &err));
        const struct imp_stage_error *se = imp_scene_stage_error(s);
        CHECK(se != NULL);
        if (!tp || !se)
                return;
        size_t n = imp_tile_plan_count(tp);
        double sum = 0, sum2 = 0, th2 = 0, back_fwd = 0, back_rev = 0;
        size_t nf = 0, nr = 0;
        for (size_t k = 0; k < n; k++) {
                struct imp_sim_tile_pose p;
                imp_sim_tile_pose(s, tp, k, &p);
                const struct imp_tile *t = imp_tile_plan_tile(tp, k);
                double ex = p.true_mm[0] - p.commanded_mm[0];
                bool forward = t->row % 2 == 0;     /* serpentine: even rows run +x */
                if (t->col > 0 && t->col + 1 < 34) {
                        if (forward)
                                back_fwd += ex, nf++;
                        else
                                back_rev += ex, nr++;
                }
                double ey = p.true_mm[1] - p.commanded_mm[1] + 0.5 * se->backlash_mm;   /* y only rises */
                sum += ey;
                sum2 += ey * ey;
                th2 += p.theta_rad * p.theta_rad;
                CHECK_NEAR(p.readback_mm[0], p.commanded_mm[0], 0);
        }
        double mean = sum / n, sd = sqrt(sum2 / n - mean * mean), th = sqrt(th2 / n) * 180 / M_PI;
        CHECK_NEAR(mean, 0, 0.15 * se->sigma_mm);
        CHECK_NEAR(sd, se->sigma_mm, 0.15 * se->sigma_mm);
        CHECK_NEAR(th, se->sigma_deg, 0.15 * se->sigma_deg);
        /* moving +x the carriage trails by backlash/2, moving −x it leads by as much */
        CHECK_NEAR(back_fwd / nf, -0.5 * se->backlash_mm, 0.3 * se->backlash_mm);
        CHECK_NEAR(back_rev / nr, 0.5 * se->backlash_mm, 0.3 * se->backlash_mm);

        imp_scene_set_effect(s, IMP_FX_STAGE_ERROR, false);
        for (size_t k = 0; k < n; k += 37) {
                struct imp_sim_tile_pose p;
                imp_sim_tile_pose(s, tp, k, &p);
                for (int a = 0; a < 3; a++)
                        CHECK_NEAR(p.true_mm[a], p.commanded_mm[a], 0);
                CHECK_NEAR(p.theta_rad, 0, 0);
        }
}

/* Height of the whole-painting surface at painting point (x, y). */
static double whole_height(const struct imp_sim_surface *w, double x, double y) {
        return imp_sim_surface_height(w, x, y);
}

/* A tile's window is the painting's own lattice seen through the placement: every window
 * sample sits on a painting lattice point and equals the whole painting's sample there, and
 * the height under a world point w is the whole painting's at R·w + t, for an unrotated and
 * a 0.2° placement alike (1e-6 mm, float rounding), while the same comparison 0.3 mm off
 * gives more than 20 µm. The window holds far fewer samples than the painting (< 1/3 here,
 * where the painting is only 2.5 × 1.8 fields). */
static void test_window(void) {
        _cleanup_(imp_scene_freep) struct imp_scene *s = load_scene(false);
        if (!s)
                return;
        struct imp_error err = {};
        const double pitch = imp_scene_surface(s)->pitch_mm;
        double canvas[2];
        imp_scene_canvas_size(s, canvas);
        /* the whole painting, kept */
        CHECK_OK(imp_scene_place_whole(s, pitch, &err));
        struct imp_sim_surface whole = *imp_scene_surface(s);
        size_t nw = (size_t) whole.nx * whole.ny;
        float *hw = malloc(nw * sizeof *hw);
        if (!hw)
                return;
        memcpy(hw, whole.height_mm, nw * sizeof *hw);
        whole.height_mm = hw;
        for (int rot = 0; rot < 2; rot++) {
                struct imp_painting_place pl = { .theta_rad = rot ? 0.2 * M_PI / 180 : 0, .offset_mm = { 50.0, 24.0 } };
                CHECK_OK(imp_scene_place(s, &pl, &err));
                const struct imp_sim_surface *w = imp_scene_surface(s);
                CHECK(w->placed);
                CHECK_LE((double) w->nx * w->ny, nw / 3.0);
                double c = cos(pl.theta_rad), sn = sin(pl.theta_rad), emax = 0, ewmax = 0, off2 = 0;
                size_t m = 0;
                for (int j = 3; j < w->ny - 3; j += 3)      /* inside the window */
                        for (int i = 3; i < w->nx - 3; i += 3) {
                                double xy[2];
                                imp_sim_surface_sample_xy(w, i, j, xy);
                                double x = xy[0], y = xy[1];
                                if (x < 0.5 || y < 0.5 || x > canvas[0] - 0.5 || y > canvas[1] - 0.5)
                                        continue;
                                CHECK_NEAR(x / pitch, round(x / pitch), 1e-9);
                                double h = w->height_mm[(size_t) j * w->nx + i];
                                double e = h - whole_height(&whole, x, y), eo = h - whole_height(&whole, x + 0.3, y);
                                /* a world point between samples: painting point R·w + t */
                                double wx = c * (x - pl.offset_mm[0]) + sn * (y - pl.offset_mm[1]) + 0.37 * pitch;
                                double wy = -sn * (x - pl.offset_mm[0]) + c * (y - pl.offset_mm[1]) + 0.61 * pitch;
                                double ew = imp_sim_surface_height_world(w, wx, wy) -
                                            whole_height(&whole, c * wx - sn * wy + pl.offset_mm[0],
                                                         sn * wx + c * wy + pl.offset_mm[1]);
                                off2 += eo * eo;
                                emax = fmax(emax, fabs(e));
                                ewmax = fmax(ewmax, fabs(ew));
                                m++;
                        }
                CHECK_INT_GE(m, 1000);
                CHECK_GE(sqrt(off2 / m), 0.020);
                CHECK_LE(emax, 1e-6);
                CHECK_LE(ewmax, 1e-6);
        }
        free(hw);
}

/* Renders the painting with a two-light plan: painting.json, six capture sets of two frames,
 * tile poses as imp_sim_tile_pose says, the whole-painting truth at the truth pitch, and a
 * simulated clock the tile estimate (gantry speed, settle) matches within 10 %. */
static void test_render(void) {
        _cleanup_(imp_scene_freep) struct imp_scene *s = load_scene(true);
        if (!s)
                return;
        _cleanup_(imp_plan_freep) struct imp_plan *p = load_plan(s, plan_text);
        if (!p)
                return;
        char out[512], path[600];
        snprintf(out, sizeof out, "%s/painting", test_tmpdir());
        snprintf(path, sizeof path, "%s/plan.cfg", test_tmpdir());
        FILE *f = fopen(path, "w");
        if (!f)
                return;
        fputs(plan_text, f);
        fclose(f);
        struct imp_error err = {};
        struct imp_sim_painting_result res;
        int r = imp_sim_render_painting(s, p, path, out, NULL, NULL, &res, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        if (r < 0)
                return;
        CHECK_INT_EQ(res.tiles, 6);
        double move_s;
        CHECK_NEAR(imp_sim_painting_clock_s(s, p, &move_s), res.clock_s, 1e-9);
        CHECK_NEAR(move_s, res.move_s, 1e-9);
        CHECK_INT_EQ(res.frames, 12);
        snprintf(path, sizeof path, "%s/painting.json", out);
        _cleanup_json_ json_t *pj = NULL;
        CHECK_OK(imp_json_load(path, &pj, &err));
        CHECK_STR_EQ(json_string_value(json_object_get(pj, "format")), "impasto-painting");
        CHECK_INT_EQ(json_array_size(json_object_get(pj, "tiles")), 6);
        snprintf(path, sizeof path, "%s/truth/tile-poses.json", out);
        _cleanup_json_ json_t *tj = NULL;
        CHECK_OK(imp_json_load(path, &tj, &err));
        const struct imp_tile_plan *tp = imp_plan_tiles(p);
        for (size_t k = 0; k < 6; k++) {
                struct imp_sim_tile_pose pose;
                imp_sim_tile_pose(s, tp, k, &pose);
                json_t *e = json_array_get(json_object_get(tj, "tiles"), k);
                double off[2] = { 0 }, th = 0;
                imp_json_get_doubles(e, "offset_mm", true, 2, off, "tile-poses.json", &err);
                imp_json_get_double(e, "theta_deg", true, &th, "tile-poses.json", &err);
                CHECK_NEAR(off[0], pose.true_mm[0] - 20.0, 1e-9);
                CHECK_NEAR(off[1], pose.true_mm[1] - 20.0, 1e-9);
                CHECK_NEAR(th, pose.theta_rad * 180 / M_PI, 1e-9);
                snprintf(path, sizeof path, "%s/tiles/%04zu", out, k);
                _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
                CHECK_OK(imp_captureset_open(path, &cs, &err));
                CHECK(cs && imp_captureset_count(cs) == 2);
        }
        snprintf(path, sizeof path, "%s/truth/heightfield.exr", out);
        _cleanup_image_ struct imp_image *hf = NULL;
        CHECK_OK(imp_image_read(path, &hf, &err));
        CHECK(hf && hf->width == 501 && hf->height == 271);   /* 100 × 54 mm at 0.2 mm */
        const struct imp_scene_gantry *g = imp_scene_gantry(s);
        struct imp_tile_cost cost = { .frames = 2, .capture_s = imp_plan_estimate_s(p, imp_scene_rig(s)), .workers = 1,
                                      .speed_mm_s = g->speed_mm_s,
                                      /* tiles.h: acceleration folded into the settle time */
                                      .settle_s = g->settle_s + g->speed_mm_s / g->accel_mm_s2 };
        struct imp_tile_estimate est;
        CHECK_OK(imp_tile_plan_estimate(tp, &cost, &est));
        fprintf(stderr, "painting: estimate %.2f s, simulated clock %.2f s\n", est.capture_s, res.clock_s);
        CHECK_NEAR(est.capture_s, res.clock_s, 0.10 * res.clock_s);
}

/* Rendering a painting needs a gantry scene and a painting plan: clear errors. */
static void test_refusals(void) {
        struct imp_error err = {};
        _cleanup_(imp_scene_freep) struct imp_scene *s = load_scene(false);
        _cleanup_(imp_scene_freep) struct imp_scene *fov = NULL;
        CHECK_OK(imp_scene_load(IMPASTO_SOURCE_DIR "/config/scenes/small.cfg", &fov, &err));
        if (!s || !fov)
                return;
        _cleanup_(imp_plan_freep) struct imp_plan *p = load_plan(s, plan_text);
        _cleanup_(imp_plan_freep) struct imp_plan *one = load_plan(s, "dome = { lights = [0]; exposures_us = [1000.0]; };");
        char out[512];
        snprintf(out, sizeof out, "%s/refused", test_tmpdir());
        CHECK_ERR(imp_sim_render_painting(s, one, NULL, out, NULL, NULL, NULL, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "no painting group");
        CHECK_ERR(imp_sim_render_painting(fov, p, NULL, out, NULL, NULL, NULL, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "no gantry group");
        struct imp_painting_place pl = { 0 };
        CHECK_ERR(imp_scene_place(fov, &pl, &err), -EINVAL);
        struct imp_serve *sv = NULL;
        int r = imp_serve_new(s, NULL, &sv, &err);   /* a gantry scene is served with its plan only */
        CHECK(r == -EINVAL || r == -EOPNOTSUPP);
        if (!strstr(err.msg, "built without"))       /* a build without the emulators refuses anyway */
                CHECK_STR_CONTAINS(err.msg, "painting on a gantry: give the plan");
        imp_serve_free(sv);
}

/* A 2 × 2 m painting at 0.1 mm (4e8 samples, refused for a one-field scene) loads as a
 * gantry scene, and its window is exactly as large as the small painting's: the memory of a
 * tile does not grow with the painting. */
static void test_large_painting(void) {
        FILE *f = fopen(SCENE, "r");
        if (!f)
                return;
        static char text[16384];
        size_t n = fread(text, 1, sizeof text - 1, f);
        fclose(f);
        text[n] = 0;
        char *w = strstr(text, "width_mm = 100.0;"), *h = strstr(text, "height_mm = 54.0;");
        CHECK(w && h);
        if (!w || !h)
                return;
        memcpy(w, "width_mm = 2.0e3;", 17);
        memcpy(h, "height_mm = 2e3 ;", 17);
        struct imp_error err = {};
        _cleanup_(imp_scene_freep) struct imp_scene *big = NULL;
        _cleanup_(imp_scene_freep) struct imp_scene *small = load_scene(false);
        int r = imp_scene_load_string(text, "big.cfg", &big, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        if (!big || !small)
                return;
        double canvas[2];
        imp_scene_canvas_size(big, canvas);
        CHECK_NEAR(canvas[0], 2000, 0);
        CHECK_INT_EQ(imp_scene_surface(big)->nx, imp_scene_surface(small)->nx);
        CHECK_INT_EQ(imp_scene_surface(big)->ny, imp_scene_surface(small)->ny);
}

int main(void) {
        test_plan_group();
        test_stage_error();
        test_window();
        test_render();
        test_refusals();
        test_large_painting();
        return TEST_DONE();
}
