/* Tile plans (pipeline/model/tiles.h): counts and spacing with the asked overlap, coverage
 * of the whole area, serpentine order, stage targets and height offsets, the plan-file
 * group and its errors. Tolerances: 1e-9 mm for arithmetic that is exact up to rounding. */
#include <fcntl.h>
#include <math.h>
#include <sys/stat.h>
#include <unistd.h>
#include "json-util.h"
#include "tiles.h"
#include "unit/test.h"

#define EPS 1e-9

static struct imp_tile_plan *make(double ex, double ey, double fx, double fy, double overlap, enum imp_tile_order order) {
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        o.extent_mm[0] = ex;
        o.extent_mm[1] = ey;
        o.fov_mm[0] = fx;
        o.fov_mm[1] = fy;
        o.overlap = overlap;
        o.order = order;
        struct imp_tile_plan *p = NULL;
        struct imp_error err = {};
        int r = imp_tile_plan_new(&o, &p, &err);
        CHECK_MSG(r == 0, "plan %gx%g fov %gx%g: %s", ex, ey, fx, fy, err.msg);
        return p;
}

static void test_defaults(void) {
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        CHECK_NEAR(o.overlap, 0.20, EPS);
        CHECK_INT_EQ(o.order, IMP_TILE_ORDER_ROWS);
}

/* 300 × 200 mm with a 60 × 40 mm field at 20 %: steps of 48 × 32 mm fit exactly, 6 × 6. */
static void test_exact_fit(void) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = make(300, 200, 60, 40, 0.2, IMP_TILE_ORDER_ROWS);
        if (!p)
                return;
        unsigned cols, rows;
        imp_tile_plan_grid(p, &cols, &rows);
        CHECK_INT_EQ(cols, 6);
        CHECK_INT_EQ(rows, 6);
        CHECK_INT_EQ(imp_tile_plan_count(p), 36);
        double step[2], ov[2];
        imp_tile_plan_spacing(p, step, ov);
        CHECK_NEAR(step[0], 48, EPS);
        CHECK_NEAR(step[1], 32, EPS);
        CHECK_NEAR(ov[0], 0.2, EPS);
        CHECK_NEAR(ov[1], 0.2, EPS);
        const struct imp_tile *first = imp_tile_plan_tile(p, 0), *last = imp_tile_plan_at(p, 5, 5);
        CHECK_NEAR(first->rect_mm[0], 0, EPS);
        CHECK_NEAR(first->rect_mm[1], 0, EPS);
        CHECK_NEAR(last->rect_mm[2], 300, EPS);
        CHECK_NEAR(last->rect_mm[3], 200, EPS);
        CHECK(imp_tile_plan_tile(p, 36) == NULL);
        /* 108 mm at a 45 mm field and 30 %: (108 − 45) / 31.5 is 2 exactly, in floating point
         * 2.0000000000000004: still 3 tiles, not 4. */
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *q = make(108, 45, 45, 45, 0.3, IMP_TILE_ORDER_ROWS);
        if (!q)
                return;
        imp_tile_plan_grid(q, &cols, &rows);
        CHECK_INT_EQ(cols, 3);
        CHECK_INT_EQ(rows, 1);
        CHECK(imp_tile_plan_at(p, 6, 0) == NULL);
}

/* Every point of the area grown by the edge margin m under at least one tile, every tile
 * inside that, and each neighbour pair sharing at least the asked overlap. Sampled every
 * 0.5 mm from −m (and at the far edge + m). */
static void check_cover(const struct imp_tile_plan *p, double ex, double ey, double overlap) {
        size_t n = imp_tile_plan_count(p);
        unsigned uncovered = 0;
        const double m = imp_tile_plan_options(p)->edge_margin_mm;
        for (double ys = -m; ys <= ey + m + 0.5; ys += 0.5)
                for (double xs = -m; xs <= ex + m + 0.5; xs += 0.5) {
                        double x = fmin(xs, ex + m), y = fmin(ys, ey + m);
                        bool in = false;
                        for (size_t i = 0; i < n && !in; i++) {
                                const double *r = imp_tile_plan_tile(p, i)->rect_mm;
                                in = x >= r[0] - EPS && x <= r[2] + EPS && y >= r[1] - EPS && y <= r[3] + EPS;
                        }
                        uncovered += !in;
                }
        CHECK_INT_EQ(uncovered, 0);
        double step[2], ov[2];
        imp_tile_plan_spacing(p, step, ov);
        const struct imp_tile_options *o = imp_tile_plan_options(p);
        unsigned grid[2];
        imp_tile_plan_grid(p, &grid[0], &grid[1]);
        for (int a = 0; a < 2; a++) {
                if (o->extent_mm[a] <= o->fov_mm[a])
                        continue;
                CHECK_GE(ov[a], overlap - EPS);
                /* As few tiles as that takes: one fewer would overlap less than asked. */
                if (grid[a] > 2)
                        CHECK(1 - (o->extent_mm[a] + 2 * m - o->fov_mm[a]) / (grid[a] - 2) / o->fov_mm[a] < overlap);
        }
        for (size_t i = 0; i < n; i++) {
                const double *r = imp_tile_plan_tile(p, i)->rect_mm;
                if (o->extent_mm[0] + 2 * m >= o->fov_mm[0])
                        CHECK(r[0] >= -m - EPS && r[2] <= ex + m + EPS);
                if (o->extent_mm[1] + 2 * m >= o->fov_mm[1])
                        CHECK(r[1] >= -m - EPS && r[3] <= ey + m + EPS);
        }
}

/* 310 mm does not fit 48 mm steps: 7 columns, spread evenly, overlap above 20 %. */
static void test_uneven(void) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = make(310, 205, 60, 40, 0.2, IMP_TILE_ORDER_ROWS);
        if (!p)
                return;
        unsigned cols, rows;
        imp_tile_plan_grid(p, &cols, &rows);
        CHECK_INT_EQ(cols, 7);                  /* 1 + ceil(250 / 48) */
        CHECK_INT_EQ(rows, 7);                  /* 1 + ceil(165 / 32) */
        double step[2], ov[2];
        imp_tile_plan_spacing(p, step, ov);
        CHECK_NEAR(step[0], 250.0 / 6, EPS);
        CHECK_NEAR(ov[0], 1 - 250.0 / 6 / 60, EPS);
        check_cover(p, 310, 205, 0.2);
}

static void test_small_area(void) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = make(30, 100, 60, 40, 0.2, IMP_TILE_ORDER_ROWS);
        if (!p)
                return;
        unsigned cols, rows;
        imp_tile_plan_grid(p, &cols, &rows);
        CHECK_INT_EQ(cols, 1);
        CHECK_INT_EQ(rows, 3);                  /* 1 + ceil(60 / 32) */
        CHECK_NEAR(imp_tile_plan_tile(p, 0)->center_mm[0], 15, EPS);   /* centred on the narrow axis */
        check_cover(p, 30, 100, 0.2);
}

/* Serpentine: each tile is a grid neighbour of the one before; every cell once. */
static void check_serpentine(const struct imp_tile_plan *p, enum imp_tile_order order) {
        unsigned cols, rows;
        imp_tile_plan_grid(p, &cols, &rows);
        size_t n = imp_tile_plan_count(p);
        unsigned seen[64] = { 0 };
        for (size_t i = 0; i < n; i++) {
                const struct imp_tile *t = imp_tile_plan_tile(p, i);
                CHECK_INT_EQ(t->index, i);
                CHECK(imp_tile_plan_at(p, t->col, t->row) == t);
                seen[t->row * cols + t->col]++;
                if (i == 0)
                        continue;
                const struct imp_tile *u = imp_tile_plan_tile(p, i - 1);
                CHECK_INT_EQ(abs((int) t->col - (int) u->col) + abs((int) t->row - (int) u->row), 1);
        }
        for (size_t i = 0; i < n; i++)
                CHECK_INT_EQ(seen[i], 1);
        /* The fast axis runs forward, then back. */
        const struct imp_tile *a = imp_tile_plan_tile(p, 0), *b = imp_tile_plan_tile(p, 1);
        unsigned fast_n = order == IMP_TILE_ORDER_ROWS ? cols : rows;
        const struct imp_tile *c = imp_tile_plan_tile(p, fast_n), *d = imp_tile_plan_tile(p, fast_n + 1);
        if (order == IMP_TILE_ORDER_ROWS) {
                CHECK(b->col == 1 && b->row == 0);
                CHECK(c->col == cols - 1 && c->row == 1);
                CHECK(d->col == cols - 2 && d->row == 1);
        } else {
                CHECK(b->col == 0 && b->row == 1);
                CHECK(c->col == 1 && c->row == rows - 1);
                CHECK(d->col == 1 && d->row == rows - 2);
        }
        CHECK(a->col == 0 && a->row == 0);
}

static void test_exact_cover(void) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = make(300, 200, 60, 40, 0.2, IMP_TILE_ORDER_ROWS);
        if (p)
                check_cover(p, 300, 200, 0.2);
}

/* An edge margin: the outer fields pass the extent by m on every side, the overlap stays at
 * least the asked one, the extra tiles are counted (300 × 200 mm: 6 × 6 fits exactly, so any
 * margin takes 7 × 7), the stage targets move with the tiles, and the estimate's path and
 * tile count are the new layout's. */
static void test_edge_margin(void) {
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        o.extent_mm[0] = 300, o.extent_mm[1] = 200, o.fov_mm[0] = 60, o.fov_mm[1] = 40;
        o.origin_mm[0] = 20, o.origin_mm[1] = 20;
        o.edge_margin_mm = 1;
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_tile_plan_new(&o, &p, &err));
        if (!p)
                return;
        unsigned cols, rows;
        imp_tile_plan_grid(p, &cols, &rows);
        CHECK_INT_EQ(cols, 7);                  /* 1 + ceil(242 / 48) */
        CHECK_INT_EQ(rows, 7);                  /* 1 + ceil(162 / 32) */
        double step[2], ov[2];
        imp_tile_plan_spacing(p, step, ov);
        CHECK_NEAR(step[0], 242.0 / 6, EPS);
        CHECK_NEAR(step[1], 162.0 / 6, EPS);
        const struct imp_tile *first = imp_tile_plan_tile(p, 0), *last = imp_tile_plan_at(p, 6, 6);
        CHECK_NEAR(first->rect_mm[0], -1, EPS);
        CHECK_NEAR(first->rect_mm[1], -1, EPS);
        CHECK_NEAR(last->rect_mm[2], 301, EPS);
        CHECK_NEAR(last->rect_mm[3], 201, EPS);
        CHECK_NEAR(first->stage_mm[0], 20 + 29, EPS);
        CHECK_NEAR(first->stage_mm[1], 20 + 19, EPS);
        check_cover(p, 300, 200, 0.2);
        struct imp_tile_cost c = { .frames = 120, .bytes = 2e9, .capture_s = 60, .process_s = 30, .workers = 1,
                                   .speed_mm_s = 50, .settle_s = 1 };
        struct imp_tile_estimate e;
        CHECK_OK(imp_tile_plan_estimate(p, &c, &e));
        CHECK_INT_EQ(e.tiles, 49);
        CHECK_INT_EQ(e.frames, 49 * 120);
        CHECK_NEAR(e.move_s, (7 * 242.0 + 6 * 27.0) / 50 + 48, 1e-6);
        CHECK_NEAR(e.capture_s, 49 * 60 + e.move_s, 1e-6);
        /* painting.json says it */
        _cleanup_json_ json_t *j = imp_tile_plan_painting_json(p, 0.05, 0.05);
        CHECK(j && json_real_value(json_object_get(j, "edge_margin_mm")) == 1.0);
        CHECK(j && imp_painting_json_check(j, "painting.json", &err) == 0);
        /* painting-small's plan: 100 × 54 mm at 40 × 30 mm, 24 mm steps fit y exactly: 3 × 3 */
        o.extent_mm[0] = 100, o.extent_mm[1] = 54, o.fov_mm[0] = 40, o.fov_mm[1] = 30;
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *q = NULL;
        CHECK_OK(imp_tile_plan_new(&o, &q, &err));
        if (!q)
                return;
        imp_tile_plan_grid(q, &cols, &rows);
        CHECK_INT_EQ(cols, 3);
        CHECK_INT_EQ(rows, 3);
        check_cover(q, 100, 54, 0.2);
        /* a negative margin is refused */
        o.edge_margin_mm = -0.5;
        struct imp_tile_plan *bad = NULL;
        CHECK_ERR(imp_tile_plan_new(&o, &bad, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "edge_margin_mm");
        CHECK(bad == NULL);
}

static void test_order(void) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *r = make(300, 200, 60, 40, 0.2, IMP_TILE_ORDER_ROWS);
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *c = make(300, 150, 60, 40, 0.2, IMP_TILE_ORDER_COLUMNS);
        if (!r || !c)
                return;
        check_serpentine(r, IMP_TILE_ORDER_ROWS);
        check_serpentine(c, IMP_TILE_ORDER_COLUMNS);
        /* Path: 6 rows of 5 steps of 48 mm, and 5 steps of 32 mm between rows; no return runs. */
        CHECK_NEAR(imp_tile_plan_path_mm(r), 6 * 5 * 48.0 + 5 * 32.0, 1e-6);
        CHECK_NEAR(imp_tile_plan_move_s(r, 100, 0.5), (6 * 5 * 48.0 + 5 * 32.0) / 100 + 35 * 0.5, 1e-6);
}

/* Stage targets: origin + centre; z: base + the corners' bilinear surface + corrections. */
static void test_targets(void) {
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        o.extent_mm[0] = 300;
        o.extent_mm[1] = 200;
        o.fov_mm[0] = 60;
        o.fov_mm[1] = 40;
        o.origin_mm[0] = 12.5;
        o.origin_mm[1] = 7;
        o.z_mm = 20;
        const double cz[4] = { 0.0, 0.6, -0.4, 0.2 };
        memcpy(o.corner_z_mm, cz, sizeof cz);
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_tile_plan_new(&o, &p, &err));
        if (!p)
                return;
        const struct imp_tile *t = imp_tile_plan_at(p, 2, 3);
        double cx = 30 + 2 * 48, cy = 20 + 3 * 32, u = cx / 300, v = cy / 200;
        double z = (1 - u) * (1 - v) * cz[0] + u * (1 - v) * cz[1] + (1 - u) * v * cz[2] + u * v * cz[3];
        CHECK_NEAR(t->center_mm[0], cx, EPS);
        CHECK_NEAR(t->center_mm[1], cy, EPS);
        CHECK_NEAR(t->stage_mm[0], 12.5 + cx, EPS);
        CHECK_NEAR(t->stage_mm[1], 7 + cy, EPS);
        CHECK_NEAR(t->z_offset_mm, z, EPS);
        CHECK_NEAR(t->stage_mm[2], 20 + z, EPS);
        CHECK_OK(imp_tile_plan_set_z_correction(p, 2, 3, 0.25));
        CHECK_NEAR(t->stage_mm[2], 20 + z + 0.25, EPS);
        CHECK_NEAR(imp_tile_plan_at(p, 3, 3)->z_offset_mm,
                   (1 - (30 + 3 * 48) / 300.0) * (1 - v) * cz[0] + (30 + 3 * 48) / 300.0 * (1 - v) * cz[1] +
                   (1 - (30 + 3 * 48) / 300.0) * v * cz[2] + (30 + 3 * 48) / 300.0 * v * cz[3], EPS);
        CHECK_ERR(imp_tile_plan_set_z_correction(p, 6, 0, 0.1), -ERANGE);
        CHECK_ERR(imp_tile_plan_set_z_correction(p, 0, 0, NAN), -EINVAL);

        /* Limits: the far corner tile sits at x 12.5 + 270 = 282.5 mm. */
        double lo[3] = { 0, 0, 0 }, hi[3] = { 400, 300, 50 };
        CHECK_OK(imp_tile_plan_check_limits(p, lo, hi, &err));
        hi[0] = 280;
        CHECK_ERR(imp_tile_plan_check_limits(p, lo, hi, &err), -ERANGE);
        CHECK_STR_CONTAINS(err.msg, "tile 5 (col 5, row 0): stage x 282.500 mm outside [0.000, 280.000] mm");
}

static void test_bad_options(void) {
        struct imp_tile_options o;
        imp_tile_options_default(&o);
        o.extent_mm[0] = 300;
        o.extent_mm[1] = 200;
        o.fov_mm[0] = 60;
        struct imp_error err = {};
        struct imp_tile_plan *p = NULL;
        CHECK_ERR(imp_tile_plan_new(&o, &p, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "fov_mm y: expected a number in (0, 100000] mm, got 0");
        o.fov_mm[1] = 40;
        o.overlap = 0.95;
        CHECK_ERR(imp_tile_plan_new(&o, &p, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "overlap: expected 0..0.8");
        o.overlap = 0.2;
        o.corner_z_mm[2] = NAN;
        CHECK_ERR(imp_tile_plan_new(&o, &p, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "corner_z_mm[2]");
        o.corner_z_mm[2] = 0;
        o.extent_mm[0] = 1e5;
        o.fov_mm[0] = 0.01;
        CHECK_ERR(imp_tile_plan_new(&o, &p, &err), -E2BIG);
        CHECK(p == NULL);
}

static void test_conf(void) {
        static const char text[] =
                "painting = {\n"
                "  extent_mm = [300.0, 200.0];\n"
                "  fov_mm = [60.0, 40.0];\n"
                "  order = \"columns\";\n"
                "  origin_mm = [10.0, 5.0];\n"
                "  z_mm = 20.0;\n"
                "  z_corrections = ( { tile = [2, 1]; z_mm = 0.3; } );\n"
                "};\n";
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_conf_load_string(text, "plan.cfg", &c, &err));
        if (!c)
                return;
        config_setting_t *g = config_setting_get_member(imp_conf_root(c), "painting");
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = NULL;
        CHECK_OK(imp_tile_plan_from_conf(c, g, &p, &err));
        if (!p)
                return;
        CHECK_NEAR(imp_tile_plan_options(p)->overlap, 0.2, EPS);        /* the default */
        CHECK_INT_EQ(imp_tile_plan_options(p)->order, IMP_TILE_ORDER_COLUMNS);
        CHECK_NEAR(imp_tile_plan_at(p, 2, 1)->stage_mm[2], 20.3, EPS);
        CHECK_NEAR(imp_tile_plan_at(p, 1, 1)->stage_mm[2], 20.0, EPS);
        CHECK_NEAR(imp_tile_plan_tile(p, 0)->stage_mm[0], 40.0, EPS);
        CHECK_NEAR(imp_tile_plan_options(p)->edge_margin_mm, 0, EPS);   /* the default */

        static const char *const bad[][2] = {
                { "painting = { extent_mm = [300.0, 200.0]; fov_mm = [60.0, 40.0]; overlap = 0.9; };", "plan.cfg:1: painting.overlap" },
                { "painting = { extent_mm = [300.0, 200.0]; fov = [60.0, 40.0]; };", "unknown field fov" },
                { "painting = { extent_mm = [300.0, 200.0];\n fov_mm = [60.0, 40.0];\n z_corrections = ( { tile = [6, 0]; z_mm = 0.1; } ); };",
                  "plan.cfg:3: painting.z_corrections.[0].tile: expected [col, row] inside the 6 × 6 grid, got [6, 0]" },
                { "painting = { extent_mm = [300.0, -2.0]; fov_mm = [60.0, 40.0]; };", "plan.cfg:1: painting: tiles: extent_mm y" },
                { "painting = { extent_mm = [300.0, 200.0]; fov_mm = [60.0, 40.0]; edge_margin_mm = -1.0; };",
                  "plan.cfg:1: painting.edge_margin_mm" },
        };
        for (size_t i = 0; i < ARRAY_SIZE(bad); i++) {
                _cleanup_(imp_conf_freep) struct imp_conf *b = NULL;
                CHECK_OK(imp_conf_load_string(bad[i][0], "plan.cfg", &b, &err));
                if (!b)
                        continue;
                struct imp_tile_plan *q = NULL;
                CHECK_ERR(imp_tile_plan_from_conf(b, config_setting_get_member(imp_conf_root(b), "painting"), &q, &err),
                          -EINVAL);
                CHECK_STR_CONTAINS(err.msg, bad[i][1]);
                CHECK(q == NULL);
        }
}

/* Hostile painting groups of a plan file: each refused with a message naming
 * the file, line and field, none laid out (a huge extent used to give stage targets of 5e299
 * mm; 10^7 tiles must be refused before anything is allocated for them). */
static void test_hostile_groups(void) {
        static const char *const bad[][2] = {
                { "painting = { extent_mm = [-300.0, 200.0]; fov_mm = [60.0, 40.0]; };", "painting: tiles: extent_mm x: expected a number in (0, 100000] mm, got -300" },
                { "painting = { extent_mm = [1e300, 1e300]; fov_mm = [1e300, 1e300]; };", "extent_mm x: expected a number in (0, 100000] mm, got 1e+300" },
                { "painting = { extent_mm = [300.0, 200.0]; fov_mm = [0.0, 40.0]; };", "fov_mm x: expected a number in (0, 100000] mm, got 0" },
                { "painting = { extent_mm = [300.0, 200.0]; fov_mm = [60.0, 40.0]; overlap = 1.0; };", "painting.overlap" },
                { "painting = { extent_mm = [300.0, 200.0]; fov_mm = [60.0, 40.0]; origin_mm = [1e300, 0.0]; };", "origin_mm x: expected a finite number within" },
                { "painting = { extent_mm = [100000.0, 100000.0]; fov_mm = [0.01, 0.01]; };", "more than 100000" },
                { "painting = { extent_mm = [300.0]; fov_mm = [60.0, 40.0]; };", "painting.extent_mm" },
                { "painting = { extent_mm = \"big\"; fov_mm = [60.0, 40.0]; };", "painting.extent_mm" },
        };
        for (size_t i = 0; i < ARRAY_SIZE(bad); i++) {
                _cleanup_(imp_conf_freep) struct imp_conf *b = NULL;
                struct imp_error err = {};
                CHECK_OK(imp_conf_load_string(bad[i][0], "plan.cfg", &b, &err));
                if (!b)
                        continue;
                config_setting_t *g = config_setting_get_member(imp_conf_root(b), "painting");
                struct imp_tile_plan *q = NULL;
                int r = imp_tile_plan_from_conf(b, g, &q, &err);
                CHECK_MSG(r < 0, "%s: accepted", bad[i][0]);
                CHECK_MSG(strstr(err.msg, bad[i][1]) && strstr(err.msg, "plan.cfg:"), "%s: %s", bad[i][0], err.msg);
                CHECK(q == NULL);
                imp_tile_plan_free(q);
        }
}

#define GOOD_PAINTING \
        "{\"format\": \"impasto-painting\", \"version\": 1, \"extent_mm\": [100, 54], \"fov_mm\": [40, 30], " \
        "\"overlap\": 0.2, \"origin_mm\": [20, 20], \"stage_sigma_mm\": 0.02, \"cols\": 2, \"rows\": 1, \"tiles\": [" \
        "{\"index\": 0, \"col\": 0, \"row\": 0, \"center_mm\": [20, 15], \"commanded_mm\": [40, 35, 10], " \
        "\"readback_mm\": [40, 35, 10], \"capture\": \"tiles/0000\", \"copy\": \"copies/0000\", \"done\": true}, " \
        "{\"index\": 1, \"col\": 1, \"row\": 0, \"center_mm\": [60, 15], \"readback_mm\": [80, 35, 10], " \
        "\"capture\": \"/abs/tiles/0001\", \"copy\": \"copies/0001\"}]}"

/* painting.json as `impasto process`, `impasto mosaic` and impastod's resume read it: a good
 * one passes; each damage is refused (-EBADMSG) naming the file and the field. */
static void test_painting_json(void) {
        struct imp_error err = {};
        json_error_t je;
        _cleanup_json_ json_t *good = json_loads(GOOD_PAINTING, 0, &je);
        CHECK_MSG(good, "%s", je.text);
        if (!good)
                return;
        CHECK_OK(imp_painting_json_check(good, "P", &err));
        static const char *const bad[][3] = {
                /* path in tiles[1] or the header, key, its new JSON value, expected message */
                { "1", "capture", "\"../../etc\"" }, { "1", "copy", "\"copies/../../../x\"" },
                { "1", "copy", "\"..\"" }, { "0", "index", "7" }, { "1", "index", "0" },
                { "1", "col", "2" }, { "0", "row", "-1" }, { "0", "center_mm", "[1e300, 0]" },
                { "0", "readback_mm", "[1, 2]" }, { "0", "done", "\"yes\"" }, { "0", "copy", "17" },
                { "H", "format", "\"other\"" }, { "H", "version", "2" }, { "H", "extent_mm", "[1e9, 5]" },
                { "H", "fov_mm", "[0, 5]" }, { "H", "overlap", "1.0" }, { "H", "stage_sigma_mm", "-1" },
                { "H", "pitch_mm", "0" }, { "H", "tiles", "[]" }, { "H", "tiles", "{}" }, { "H", "cols", "0" },
                { "H", "rows", "1.5" },
        };
        static const char *const want[] = {
                "P: tiles[1].capture: \"../../etc\" leaves the painting's directory",
                "P: tiles[1].copy: \"copies/../../../x\" leaves", "P: tiles[1].copy: \"..\" leaves",
                "P: tiles[0].index: expected 0..1, got 7", "P: tiles[1].index: 0: another tile has it already",
                "P: tiles[1].col: expected 0..1, got 2", "P: tiles[0].row: expected 0..0, got -1",
                "P: tiles[0].center_mm[0]: expected a finite number", "P: tiles[0].readback_mm: expected 3 numbers",
                "P: tiles[0].done: expected a boolean", "P: tiles[0].copy: expected a string",
                "P: format: expected \"impasto-painting\"", "P: version: expected 1..1, got 2",
                "P: extent_mm[0]: expected a size in (0, 100000] mm", "P: fov_mm[0]: expected a size",
                "P: overlap: expected a number in [0, 0.999]", "P: stage_sigma_mm: expected a number in [0",
                "P: pitch_mm: expected a number in [0.001, 1000]", "P: tiles: expected an array of 1..100000 tiles",
                "P: tiles: expected an array", "P: cols: expected 1..100000, got 0", "P: rows: expected an integer",
        };
        for (size_t i = 0; i < ARRAY_SIZE(bad); i++) {
                _cleanup_json_ json_t *j = json_deep_copy(good);
                json_t *v = json_loads(bad[i][2], JSON_DECODE_ANY, &je);
                json_t *o = bad[i][0][0] == 'H' ? j : json_array_get(json_object_get(j, "tiles"), (size_t) atoi(bad[i][0]));
                json_object_set_new(o, bad[i][1], v);
                err.msg[0] = 0;
                CHECK_INT_EQ(imp_painting_json_check(j, "P", &err), -EBADMSG);
                CHECK_MSG(strstr(err.msg, want[i]), "%s = %s: got \"%s\", want \"%s\"", bad[i][1], bad[i][2], err.msg,
                          want[i]);
        }
}

/* imp_painting_json_load: bounded in size (a 65 MiB file is refused without being parsed),
 * a FIFO refused without blocking, unparsable JSON named with line and column. */
static void test_painting_json_load(void) {
        char dir[] = "/tmp/test-tiles-XXXXXX", path[100];
        CHECK(mkdtemp(dir));
        struct imp_error err = {};
        json_t *j = NULL;
        snprintf(path, sizeof path, "%s/painting.json", dir);
        int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        CHECK(fd >= 0 && write(fd, GOOD_PAINTING, strlen(GOOD_PAINTING)) == (ssize_t) strlen(GOOD_PAINTING));
        CHECK_OK(imp_painting_json_load(path, &j, &err));
        CHECK_INT_EQ(json_array_size(json_object_get(j, "tiles")), 2);
        json_decref(j);
        j = NULL;
        CHECK(ftruncate(fd, 10) == 0);
        CHECK_INT_EQ(imp_painting_json_load(path, &j, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "/painting.json:1:");
        CHECK(ftruncate(fd, (off_t) IMP_PAINTING_JSON_MAX_BYTES + 1) == 0);    /* sparse: zeros */
        CHECK_INT_EQ(imp_painting_json_load(path, &j, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "expected a regular file of at most 64 MiB");
        CHECK_STR_CONTAINS(err.msg, "got 67108865 bytes");
        close(fd);
        CHECK(unlink(path) == 0 && mkfifo(path, 0600) == 0);
        CHECK_INT_EQ(imp_painting_json_load(path, &j, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "a special file");
        CHECK(j == NULL);
        CHECK_INT_EQ(imp_painting_json_load("/nonexistent/painting.json", &j, &err), -ENOENT);
        unlink(path);

        /* 4.2 million values in 8.4 MB: refused before the parse (it would take ~250 MB) */
        fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
        const char *head = "{\"format\": \"impasto-painting\", \"x\": [0";
        CHECK(fd >= 0 && write(fd, head, strlen(head)) == (ssize_t) strlen(head));
        static char zeros[2 * 100000];
        for (size_t i = 0; i < sizeof zeros; i += 2)
                zeros[i] = ',', zeros[i + 1] = '0';
        for (int k = 0; k < 42 && fd >= 0; k++)
                CHECK(write(fd, zeros, sizeof zeros) == (ssize_t) sizeof zeros);
        CHECK(fd >= 0 && write(fd, "]}", 2) == 2);
        if (fd >= 0)
                close(fd);
        CHECK_INT_EQ(imp_painting_json_load(path, &j, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "4200006 JSON values, expected at most 4000000");
        unlink(path);
        rmdir(dir);

        /* the daemon's own painting.json (indented, every tile done) of IMP_TILES_MAX tiles fits
         * both bounds: measured per tile on 3 × 2 tiles */
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = make(100, 54, 40, 30, 0.2, IMP_TILE_ORDER_ROWS);
        _cleanup_json_ json_t *pj = p ? imp_tile_plan_painting_json(p, 0.05, 0.05) : NULL;
        size_t n = imp_tile_plan_count(p), k;
        json_t *t;
        json_array_foreach(json_object_get(pj, "tiles"), k, t)
                json_object_set_new(t, "done", json_true());
        _cleanup_free_ char *text = pj ? json_dumps(pj, JSON_INDENT(2) | JSON_REAL_PRECISION(17)) : NULL;
        size_t values = 1;
        for (const char *c = text; c && *c; c++)
                values += *c == ',' || *c == ':' || *c == '[' || *c == '{';
        CHECK(text && n == 6);
        if (text && n == 6) {
                double bytes_per_tile = (double) strlen(text) / (double) n, values_per_tile = (double) values / (double) n;
                fprintf(stderr, "painting.json: %.0f bytes and %.1f values a tile\n", bytes_per_tile, values_per_tile);
                CHECK(bytes_per_tile * IMP_TILES_MAX < IMP_PAINTING_JSON_MAX_BYTES);
                CHECK(values_per_tile * IMP_TILES_MAX < IMP_PAINTING_JSON_MAX_VALUES);
        }
}

/* Capture and processing overlap: the wall time is the capture plus the last tile's
 * processing when a worker keeps up, and grows with the processing when it does not. */
static void test_estimate(void) {
        _cleanup_(imp_tile_plan_freep) struct imp_tile_plan *p = make(300, 200, 60, 40, 0.2, IMP_TILE_ORDER_ROWS);
        if (!p)
                return;
        double path = 6 * 5 * 48.0 + 5 * 32.0;
        struct imp_tile_cost c = { .frames = 120, .bytes = 2e9, .capture_s = 60, .process_s = 30, .workers = 1,
                                   .speed_mm_s = 50, .settle_s = 1 };
        struct imp_tile_estimate e;
        CHECK_OK(imp_tile_plan_estimate(p, &c, &e));
        CHECK_INT_EQ(e.tiles, 36);
        CHECK_INT_EQ(e.frames, 36 * 120);
        CHECK_NEAR(e.bytes, 72e9, 1);
        CHECK_NEAR(e.move_s, path / 50 + 35, 1e-6);
        CHECK_NEAR(e.capture_s, 36 * 60 + path / 50 + 35, 1e-6);
        CHECK_NEAR(e.process_s, 36 * 30, 1e-6);
        CHECK_NEAR(e.wall_s, e.capture_s + 30, 1e-6);   /* the worker keeps up */
        /* Processing slower than capture: the worker is the bottleneck from the first tile. */
        c.process_s = 100;
        CHECK_OK(imp_tile_plan_estimate(p, &c, &e));
        CHECK_NEAR(e.wall_s, 60 + 36 * 100, 1e-6);
        /* Two workers keep up again (each has 2 tiles' capture time, > 100 s, per tile). */
        c.workers = 2;
        CHECK_OK(imp_tile_plan_estimate(p, &c, &e));
        CHECK_NEAR(e.wall_s, e.capture_s + 100, 1e-6);
        c.workers = 0;
        CHECK_ERR(imp_tile_plan_estimate(p, &c, &e), -EINVAL);
        c.workers = 1;
        c.capture_s = NAN;
        CHECK_ERR(imp_tile_plan_estimate(p, &c, &e), -EINVAL);
}

int main(void) {
        test_defaults();
        test_exact_fit();
        test_uneven();
        test_small_area();
        test_exact_cover();
        test_edge_margin();
        test_order();
        test_targets();
        test_bad_options();
        test_conf();
        test_hostile_groups();
        test_painting_json();
        test_painting_json_load();
        test_estimate();
        return TEST_DONE();
}
