/* Tile plans (pipeline/model/tiles.h): counts and spacing with the asked overlap, coverage
 * of the whole area, serpentine order, stage targets and height offsets, the plan-file
 * group and its errors. Tolerances: 1e-9 mm for arithmetic that is exact up to rounding. */
#include <math.h>
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

/* Every point of the area under at least one tile, every tile inside the area, and each
 * neighbour pair sharing at least the asked overlap. Sampled every 0.5 mm. */
static void check_cover(const struct imp_tile_plan *p, double ex, double ey, double overlap) {
        size_t n = imp_tile_plan_count(p);
        unsigned uncovered = 0;
        for (double y = 0; y <= ey; y += 0.5)
                for (double x = 0; x <= ex; x += 0.5) {
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
                        CHECK(1 - (o->extent_mm[a] - o->fov_mm[a]) / (grid[a] - 2) / o->fov_mm[a] < overlap);
        }
        for (size_t i = 0; i < n; i++) {
                const double *r = imp_tile_plan_tile(p, i)->rect_mm;
                if (o->extent_mm[0] >= o->fov_mm[0])
                        CHECK(r[0] >= -EPS && r[2] <= ex + EPS);
                if (o->extent_mm[1] >= o->fov_mm[1])
                        CHECK(r[1] >= -EPS && r[3] <= ey + EPS);
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
        CHECK_STR_CONTAINS(err.msg, "fov_mm y: expected a number > 0, got 0");
        o.fov_mm[1] = 40;
        o.overlap = 0.95;
        CHECK_ERR(imp_tile_plan_new(&o, &p, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "overlap: expected 0..0.8");
        o.overlap = 0.2;
        o.corner_z_mm[2] = NAN;
        CHECK_ERR(imp_tile_plan_new(&o, &p, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "corner_z_mm[2]");
        o.corner_z_mm[2] = 0;
        o.extent_mm[0] = 1e6;
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

        static const char *const bad[][2] = {
                { "painting = { extent_mm = [300.0, 200.0]; fov_mm = [60.0, 40.0]; overlap = 0.9; };", "plan.cfg:1: painting.overlap" },
                { "painting = { extent_mm = [300.0, 200.0]; fov = [60.0, 40.0]; };", "unknown field fov" },
                { "painting = { extent_mm = [300.0, 200.0];\n fov_mm = [60.0, 40.0];\n z_corrections = ( { tile = [6, 0]; z_mm = 0.1; } ); };",
                  "plan.cfg:3: painting.z_corrections.[0].tile: expected [col, row] inside the 6 × 6 grid, got [6, 0]" },
                { "painting = { extent_mm = [300.0, -2.0]; fov_mm = [60.0, 40.0]; };", "plan.cfg:1: painting: tiles: extent_mm y" },
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
        test_order();
        test_targets();
        test_bad_options();
        test_conf();
        test_estimate();
        return TEST_DONE();
}
