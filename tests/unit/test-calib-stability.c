/* Hard cases for the calibration (STYLE rule 9): boards that all face the camera
 * (focal length unobservable: f/Z scale ambiguity), a board seen once, NaN input. The
 * answer must be an error or a flagged, finite result with inflated uncertainty, never a
 * confident value. A well-posed set must not be flagged (no false alarms). */
#include <errno.h>
#include <math.h>
#include "calib.h"
#include "cv-calib.h"
#include "test.h"

#define W 1280
#define H 1024
#define COLS 9
#define ROWS 7
#define NP (COLS * ROWS)
#define SQ 75.0
#define MAXV 8

static const double FX = 3000, FY = 3000, CX = 640, CY = 512;
static double obj[MAXV][3 * NP], img[MAXV][2 * NP];
static struct imp_calib_view views[MAXV];

static uint64_t rng = 12345;
static double gauss(void) {
        double u[2];
        for (int i = 0; i < 2; i++) {
                rng = rng * 6364136223846793005ull + 1442695040888963407ull;
                u[i] = ((rng >> 11) + 0.5) / 9007199254740992.0;
        }
        return sqrt(-2 * log(u[0])) * cos(2 * M_PI * u[1]);
}

/* View v: board rotated by ax about x, ay about y, az about z, centred at (ox, oy, z). */
static void make_view(int v, double ax, double ay, double az, double ox, double oy, double z,
                      double noise_px) {
        double cx = cos(ax), sx = sin(ax), cy = cos(ay), sy = sin(ay), cz = cos(az), sz = sin(az);
        for (int i = 0; i < NP; i++) {
                double bx = SQ * (i % COLS) - 4 * SQ, by = SQ * (i / COLS) - 3 * SQ;
                double x = cz * bx - sz * by, y = sz * bx + cz * by, zz = 0;
                double x2 = cy * x + sy * zz, z2 = -sy * x + cy * zz;             /* about y */
                double y3 = cx * y - sx * z2, z3 = sx * y + cx * z2;              /* about x */
                double X = x2 + ox, Y = y3 + oy, Z = z3 + z;
                obj[v][3 * i] = SQ * (i % COLS);
                obj[v][3 * i + 1] = SQ * (i / COLS);
                obj[v][3 * i + 2] = 0;
                img[v][2 * i] = FX * X / Z + CX + noise_px * gauss();
                img[v][2 * i + 1] = FY * Y / Z + CY + noise_px * gauss();
        }
        views[v] = (struct imp_calib_view) { NP, obj[v], img[v] };
}

static void check_finite(const struct imp_calib_intrinsics *in) {
        CHECK_FINITE(in->fx);
        CHECK_FINITE(in->fy);
        CHECK_FINITE(in->cx);
        CHECK_FINITE(in->cy);
        CHECK_FINITE(in->rms_px);
        CHECK_FINITE(in->proj_unc_centre_px);
        CHECK_FINITE(in->proj_unc_corner_px);
        for (int i = 0; i < 5; i++)
                CHECK_FINITE(in->dist[i]);
        for (int i = 0; i < IMP_CALIB_N_INTR; i++)
                CHECK_FINITE(in->std[i]);
        for (int i = 0; i < IMP_CALIB_N_INTR * IMP_CALIB_N_INTR; i++)
                CHECK_FINITE(in->cov[i]);
}

static void report(const char *what, int r, const struct imp_calib_intrinsics *in,
                   const struct imp_error *err) {
        if (r < 0) {
                fprintf(stderr, "%s: error %d: %s\n", what, r, err->msg);
                return;
        }
        char buf[1024];
        imp_calib_flags_describe(in, what, buf, sizeof buf);
        fprintf(stderr, "%s: fx %.1f ± %.3g, cx %.1f ± %.3g, rms %.3f, proj. unc. %.3g px, "
                        "flags %#x\n%s", what, in->fx, in->std[0], in->cx, in->std[2], in->rms_px,
                in->proj_unc_centre_px, in->flags, buf);
}

int main(void) {
        struct imp_error err = {};
        struct imp_calib_intrinsics in;
        int r;

        /* Well posed: tilted views → confident, unflagged, near the truth. */
        static const double tilt[6][3] = { { 0.4, 0, 0 }, { -0.4, 0.1, 0.3 }, { 0, 0.45, -0.2 },
                                           { 0.1, -0.45, 0.1 }, { 0.3, 0.3, 0.5 }, { -0.3, -0.3, -0.4 } };
        for (int v = 0; v < 6; v++)
                make_view(v, tilt[v][0], tilt[v][1], tilt[v][2], 40.0 * (v % 3 - 1), 30.0 * (v % 2),
                          3500 + 100 * v, 0.2);
        r = imp_cv_calib_intrinsics(views, 6, W, H, &in, NULL, NULL, &err);
        report("tilted", r, &in, &err);
        CHECK_OK(r);
        if (r == 0) {
                CHECK_INT_EQ(in.flags, 0);
                CHECK_NEAR(in.fx / FX, 1.0, 0.01);
                check_finite(&in);
        }

        /* Fronto-parallel: same boards, no tilt, other distances and in-plane angles. */
        for (int v = 0; v < 6; v++)
                make_view(v, 0, 0, 0.3 * v, 60.0 * (v % 3 - 1), 40.0 * (v % 2), 3000 + 250 * v, 0.2);
        memset(&in, 0, sizeof in);
        r = imp_cv_calib_intrinsics(views, 6, W, H, &in, NULL, NULL, &err);
        report("fronto-parallel", r, &in, &err);
        CHECK_MSG(r == 0 || r == -EDOM, "fronto-parallel: %d %s", r, err.msg);
        if (r == 0) {
                CHECK(in.flags & IMP_CALIB_FOCAL_UNDETERMINED);
                CHECK_GE(in.std[0] / in.fx, IMP_CALIB_FOCAL_REL_STD_MAX);   /* inflated */
                check_finite(&in);
        }

        /* Nearly fronto-parallel (±1°): still not a confident focal length. */
        for (int v = 0; v < 6; v++)
                make_view(v, 0.017 * (v % 2 ? 1 : -1), 0.017 * (v % 3 - 1), 0.3 * v, 60.0 * (v % 3 - 1),
                          40.0 * (v % 2), 3000 + 250 * v, 0.2);
        r = imp_cv_calib_intrinsics(views, 6, W, H, &in, NULL, NULL, &err);
        report("near fronto-parallel", r, &in, &err);
        CHECK_MSG(r == 0 || r == -EDOM, "near fronto-parallel: %d %s", r, err.msg);
        if (r == 0) {
                CHECK(in.flags & IMP_CALIB_FOCAL_UNDETERMINED);
                check_finite(&in);
        }

        /* A single (tilted) view: error or flagged, never confident. */
        make_view(0, 0.4, 0.3, 0.2, 0, 0, 3500, 0.2);
        r = imp_cv_calib_intrinsics(views, 1, W, H, &in, NULL, NULL, &err);
        report("one view", r, &in, &err);
        CHECK_MSG(r == 0 || r == -EDOM, "one view: %d %s", r, err.msg);
        if (r == 0) {
                CHECK(in.flags & IMP_CALIB_FEW_VIEWS);
                check_finite(&in);
        }

        /* Two views: FEW_VIEWS as well. */
        make_view(1, -0.4, 0.2, -0.3, 50, 0, 3800, 0.2);
        r = imp_cv_calib_intrinsics(views, 2, W, H, &in, NULL, NULL, &err);
        report("two views", r, &in, &err);
        if (r == 0) {
                CHECK(in.flags & IMP_CALIB_FEW_VIEWS);
                check_finite(&in);
        }

        /* NaN in the input is refused, naming the point; the output is untouched. */
        img[1][7] = NAN;
        struct imp_calib_intrinsics keep = { .fx = 42 };
        CHECK_ERR(imp_cv_calib_intrinsics(views, 2, W, H, &keep, NULL, NULL, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "view 1: image point 3 is not finite");
        CHECK_NEAR(keep.fx, 42, 0);

        /* Too few points in a view; bad sizes. */
        struct imp_calib_view tiny = { 3, obj[0], img[0] };
        CHECK_ERR(imp_cv_calib_intrinsics(&tiny, 1, W, H, &in, NULL, NULL, &err), -EINVAL);
        CHECK_ERR(imp_cv_calib_intrinsics(views, 1, 0, H, &in, NULL, NULL, &err), -EINVAL);
        return TEST_DONE();
}
