/* Hard cases for the joint projector–camera refinement (ceres-procam.h, STYLE rule 9): every
 * board fronto-parallel to both devices (focal length unobservable: f/Z scale ambiguity) and a
 * board seen once. The answer must be an error or a flagged, finite result whose σ covers the
 * truth — never a confident wrong value. The well-posed rig of test-calib-ceres is the
 * no-false-alarm case. Skipped without Ceres. */
#include <errno.h>
#include <math.h>
#include "calib.h"
#include "ceres-calib.h"
#include "ceres-procam.h"
#include "cv-calib.h"
#include "procam-synth.h"
#include "test.h"

#define NOISE_PX 0.1
#define N_FRONTO 6
/* Projector nearly parallel to the camera (1.7°), 100 mm to the side: boards square to the
 * camera are square to the projector too. */
static const double PAR_R[3] = { 0, 0.03, 0 }, PAR_T[3] = { -100, 0, 0 };

static void check_finite(const struct imp_calib_intrinsics *in) {
        CHECK_FINITE(in->fx);
        CHECK_FINITE(in->cx);
        CHECK_FINITE(in->rms_px);
        CHECK_FINITE(in->proj_unc_centre_px);
        CHECK_FINITE(in->proj_unc_corner_px);
        for (int i = 0; i < IMP_CALIB_N_INTR; i++)
                CHECK_FINITE(in->std[i]);
        for (int i = 0; i < IMP_CALIB_N_INTR * IMP_CALIB_N_INTR; i++)
                CHECK_FINITE(in->cov[i]);
}

/* The start: the truth, focal lengths 3 % long, principal points 15 px off, true poses
 * (calibrateCamera cannot be trusted to give one on these views). */
static void start(const struct ps_rig *g, struct imp_calib_intrinsics *c, struct imp_calib_intrinsics *p,
                  struct imp_calib_stereo *st, double *rv, double *tv) {
        const double *k[2] = { PS_CAM, PS_PROJ };
        struct imp_calib_intrinsics *in[2] = { c, p };
        for (int d = 0; d < 2; d++) {
                *in[d] = (struct imp_calib_intrinsics) { .width = d ? PS_PW : PS_W, .height = d ? PS_PH : PS_H,
                        .fx = 1.03 * k[d][0], .fy = 1.03 * k[d][1], .cx = k[d][2] + 15, .cy = k[d][3] - 15,
                        .k3_fixed = true };
                for (int i = 0; i < 5; i++)
                        in[d]->dist[i] = k[d][4 + i];
        }
        *st = (struct imp_calib_stereo) { 0 };
        ps_rotation(g->ext_r, st->R);
        for (int i = 0; i < 3; i++)
                st->t[i] = g->ext_t[i];
        for (int v = 0; v < g->n_views; v++)
                for (int i = 0; i < 3; i++) {
                        rv[3 * v + i] = g->rv[v][i];
                        tv[3 * v + i] = g->tv[v][i];
                }
}

/* Runs the joint fit from start(); prints what it says. Returns its return value. */
static int joint(const char *what, const struct ps_rig *g, struct imp_calib_intrinsics *c,
                 struct imp_calib_intrinsics *p, struct imp_calib_stereo *st) {
        struct imp_ceres_calib_opts co;
        imp_ceres_calib_opts_default(&co);
        double rv[3 * PS_MAXV], tv[3 * PS_MAXV];
        start(g, c, p, st, rv, tv);
        struct imp_error err = { 0 };
        struct imp_ceres_procam_report rep = { 0 };
        int r = imp_ceres_procam_refine(g->vc, g->vp, g->n_views, &co, c, p, st, rv, tv, &rep, &err);
        if (r < 0) {
                fprintf(stderr, "%s: error %d: %s\n", what, r, err.msg);
                return r;
        }
        char buf[2048];
        int n = imp_calib_flags_describe(c, "camera", buf, sizeof buf);
        n += imp_calib_flags_describe(p, "projector", buf + strlen(buf), sizeof buf - strlen(buf));
        fprintf(stderr, "%s: camera fx %.1f ± %.3g (true %.0f), cx %.1f ± %.3g; projector fx %.1f ± %.3g (true "
                "%.0f); tilt %.1f° / %.1f°; pose t (%.2f %.2f %.2f) ± (%.3g %.3g %.3g), true (%.0f %.0f %.0f); "
                "%s; %d warning%s:\n%s", what, c->fx, c->std[0], PS_CAM[0], c->cx, c->std[2], p->fx, p->std[0],
                PS_PROJ[0], c->max_tilt_deg, p->max_tilt_deg, st->t[0], st->t[1], st->t[2], st->t_std[0],
                st->t_std[1], st->t_std[2], g->ext_t[0], g->ext_t[1], g->ext_t[2],
                rep.rank_deficient ? "rank deficient" : "full rank", n, n == 1 ? "" : "s", buf);
        return r;
}

/* Flagged, finite, and every estimate within 3σ of the truth (σ inflated where needed). */
static void check_honest(const struct ps_rig *g, const struct imp_calib_intrinsics *c,
                         const struct imp_calib_intrinsics *p, const struct imp_calib_stereo *st) {
        check_finite(c);
        check_finite(p);
        const struct imp_calib_intrinsics *in[2] = { c, p };
        const double *k[2] = { PS_CAM, PS_PROJ };
        for (int d = 0; d < 2; d++) {
                CHECK(in[d]->flags != 0);
                for (int i = 0; i < 4; i++)
                        CHECK_MSG(fabs((&in[d]->fx)[i] - k[d][i]) <= 3 * in[d]->std[i],
                                  "%s parameter %d: %.3f, true %.3f, 1σ %.3g: a confident wrong value",
                                  d ? "projector" : "camera", i, (&in[d]->fx)[i], k[d][i], in[d]->std[i]);
        }
        CHECK(st->have_std);
        for (int i = 0; i < 3; i++) {
                CHECK_FINITE(st->t_std[i]);
                CHECK_MSG(fabs(st->t[i] - g->ext_t[i]) <= 3 * st->t_std[i],
                          "pose t[%d]: %.3f, true %.3f, 1σ %.3g: a confident wrong value", i, st->t[i],
                          g->ext_t[i], st->t_std[i]);
        }
}

int main(void) {
        if (!imp_ceres_calib_available())
                TEST_SKIP("built without Ceres (IMPASTO_WITH_CERES off)");
        static struct ps_rig g;
        struct imp_calib_intrinsics c, p;
        struct imp_calib_stereo st;
        uint64_t seed = 4242;

        /* Fronto-parallel to both devices: in-plane turns, other distances and offsets. */
        memcpy(g.ext_r, PAR_R, sizeof g.ext_r);
        memcpy(g.ext_t, PAR_T, sizeof g.ext_t);
        g.n_views = N_FRONTO;
        for (int v = 0; v < N_FRONTO; v++) {
                double r[3] = { 0, 0, 0.3 * v }, t[3] = { -60 + 20.0 * (v % 3), -50 + 15.0 * (v % 2), 650 + 40 * v };
                ps_view(&g, v, r, t, NOISE_PX, NOISE_PX, &seed);
        }
        int r = joint("fronto-parallel", &g, &c, &p, &st);
        CHECK_MSG(r == 0 || r == -EDOM, "fronto-parallel: %d", r);
        if (r == 0) {
                CHECK(c.flags & IMP_CALIB_FOCAL_UNDETERMINED);
                CHECK(p.flags & IMP_CALIB_FOCAL_UNDETERMINED);
                CHECK_LE(c.max_tilt_deg, IMP_CALIB_MIN_TILT_DEG);
                CHECK_GE(c.std[0] / c.fx, 0.99);        /* inflated to 100 % */
                CHECK_GE(p.std[0] / p.fx, 0.99);
                check_honest(&g, &c, &p, &st);
        }

        /* One tilted board, seen by both devices. */
        static const double ER[3] = { 0.02, -0.25, 0.01 }, ET[3] = { 160, -15, 20 };
        ps_tilted(&g, 1, ER, ET, NOISE_PX, NOISE_PX, 99);
        r = joint("one view", &g, &c, &p, &st);
        CHECK_MSG(r == 0 || r == -EDOM, "one view: %d", r);
        if (r == 0) {
                CHECK(c.flags & IMP_CALIB_FEW_VIEWS);
                CHECK(p.flags & IMP_CALIB_FEW_VIEWS);
                check_honest(&g, &c, &p, &st);
        }

        /* Two views: still too few to be trusted. */
        ps_tilted(&g, 2, ER, ET, NOISE_PX, NOISE_PX, 7);
        r = joint("two views", &g, &c, &p, &st);
        if (r == 0) {
                CHECK(c.flags & IMP_CALIB_FEW_VIEWS);
                check_honest(&g, &c, &p, &st);
        }
        return TEST_DONE();
}
