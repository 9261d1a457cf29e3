/* Calibration on rendered chessboards seen by a known camera: the pinhole intrinsics must
 * come back (fx, fy within 0.1 %, principal point within 0.5 px). The board images are
 * rendered here in C (3×3 supersampled box filter = blur, Gaussian noise σ 2 DN), the
 * corners found and refined by the shim, the camera calibrated with 5 distortion terms
 * free although the truth has none. */
#include <math.h>
#include "calib.h"
#include "cv-calib.h"
#include "test.h"

#define W 1024
#define H 768
#define COLS 9
#define ROWS 7
#define SQ 30.0                 /* mm */
#define N_VIEWS 12
#define NOISE_DN 2.0
#define SS 3                    /* supersampling per axis */

static const double FX = 1200, FY = 1196, CX = 517.3, CY = 380.6;

static uint64_t rng = 0x9e3779b97f4a7c15ull;
static double uniform(void) {
        rng = rng * 6364136223846793005ull + 1442695040888963407ull;
        return ((rng >> 11) + 0.5) / 9007199254740992.0;
}
static double gauss(void) {
        return sqrt(-2 * log(uniform())) * cos(2 * M_PI * uniform());
}

static void rot(double ax, double ay, double az, double R[9]) {
        double cx = cos(ax), sx = sin(ax), cy = cos(ay), sy = sin(ay), cz = cos(az), sz = sin(az);
        double Rx[9] = { 1, 0, 0, 0, cx, -sx, 0, sx, cx }, Ry[9] = { cy, 0, sy, 0, 1, 0, -sy, 0, cy };
        double Rz[9] = { cz, -sz, 0, sz, cz, 0, 0, 0, 1 }, T[9];
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        T[3 * i + j] = 0;
                        for (int k = 0; k < 3; k++)
                                T[3 * i + j] += Rx[3 * i + k] * Ry[3 * k + j];
                }
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        R[3 * i + j] = 0;
                        for (int k = 0; k < 3; k++)
                                R[3 * i + j] += T[3 * i + k] * Rz[3 * k + j];
                }
}

/* Board frame: inner corner (0,0) at the origin, squares from −SQ to 9 SQ × −SQ to 7 SQ,
 * a white margin of one square, grey background. X_cam = R X_board + t. */
static double shade(double bx, double by) {
        if (bx < -2 * SQ || bx > (COLS + 1) * SQ || by < -2 * SQ || by > (ROWS + 1) * SQ)
                return 120;
        if (bx < -SQ || bx > COLS * SQ || by < -SQ || by > ROWS * SQ)
                return 220;
        return ((int) floor(bx / SQ) + (int) floor(by / SQ)) % 2 == 0 ? 25 : 220;
}

static void render(const double R[9], const double t[3], struct imp_image *im) {
        double n[3] = { R[2], R[5], R[8] }, nt = n[0] * t[0] + n[1] * t[1] + n[2] * t[2];
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++) {
                        double acc = 0;
                        for (int sy = 0; sy < SS; sy++)
                                for (int sx = 0; sx < SS; sx++) {
                                        double u = x - 0.5 + (sx + 0.5) / SS, v = y - 0.5 + (sy + 0.5) / SS;
                                        double d[3] = { (u - CX) / FX, (v - CY) / FY, 1 };
                                        double s = nt / (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]);
                                        double X[3] = { s * d[0] - t[0], s * d[1] - t[1], s * d[2] - t[2] };
                                        double bx = R[0] * X[0] + R[3] * X[1] + R[6] * X[2];
                                        double by = R[1] * X[0] + R[4] * X[1] + R[7] * X[2];
                                        acc += s > 0 ? shade(bx, by) : 120;
                                }
                        double v = acc / (SS * SS) + NOISE_DN * gauss();
                        *imp_image_u8(im, x, y) = (uint8_t) IMP_CLAMP(lround(v), 0, 255);
                }
}

int main(void) {
        static const double ang[N_VIEWS][3] = {
                { 0.45, 0, 0.05 }, { -0.45, 0, -0.1 }, { 0, 0.5, 0.1 }, { 0, -0.5, 0 },
                { 0.3, 0.3, 0.2 }, { -0.3, 0.35, -0.15 }, { 0.35, -0.3, 0.3 }, { -0.3, -0.3, 0 },
                { 0.6, 0.1, -0.2 }, { -0.1, 0.6, 0.25 }, { 0.15, -0.6, -0.3 }, { -0.6, -0.15, 0.1 } };
        static double obj[N_VIEWS][3 * COLS * ROWS], img[N_VIEWS][2 * COLS * ROWS];
        struct imp_calib_view views[N_VIEWS];
        struct imp_image *im = NULL;
        struct imp_error err = {};
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U8, &im));
        if (!im)
                return TEST_DONE();
        int n_views = 0;
        for (int v = 0; v < N_VIEWS; v++) {
                double R[9], t[3], c[3] = { 4 * SQ, 3 * SQ, 0 };
                rot(ang[v][0], ang[v][1], ang[v][2], R);
                double C[3] = { 40.0 * ((v % 3) - 1), 30.0 * ((v % 2) ? 1 : -1), 520 + 25 * v };
                for (int i = 0; i < 3; i++)
                        t[i] = C[i] - (R[3 * i] * c[0] + R[3 * i + 1] * c[1] + R[3 * i + 2] * c[2]);
                render(R, t, im);
                int r = imp_cv_calib_find_corners(im, COLS, ROWS, img[n_views], &err);
                CHECK_MSG(r == 0, "view %d: %s", v, err.msg);
                if (r < 0)
                        continue;
                /* The detector may start from any end of the board: the object points
                 * follow its order, which a planar target allows (any rigid relabelling). */
                for (int i = 0; i < COLS * ROWS; i++) {
                        obj[n_views][3 * i] = SQ * (i % COLS);
                        obj[n_views][3 * i + 1] = SQ * (i / COLS);
                        obj[n_views][3 * i + 2] = 0;
                }
                views[n_views] = (struct imp_calib_view) { COLS * ROWS, obj[n_views], img[n_views] };
                n_views++;
        }
        imp_image_free(im);
        CHECK_INT_EQ(n_views, N_VIEWS);
        struct imp_calib_intrinsics in;
        int r = imp_cv_calib_intrinsics(views, n_views, W, H, &in, NULL, NULL, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        if (r < 0)
                return TEST_DONE();
        fprintf(stderr, "synthetic: fx %.3f (truth %.1f, %+.4f %%)  fy %.3f (truth %.1f, %+.4f %%)\n"
                        "           cx %.3f (truth %.1f, %+.3f px)  cy %.3f (truth %.1f, %+.3f px)\n"
                        "           rms %.4f px, worst %.4f px, std fx %.3f fy %.3f cx %.3f cy %.3f, "
                        "proj. unc. %.3f / %.3f px, flags %#x\n",
                in.fx, FX, 100 * (in.fx / FX - 1), in.fy, FY, 100 * (in.fy / FY - 1), in.cx, CX,
                in.cx - CX, in.cy, CY, in.cy - CY, in.rms_px, in.worst_px, in.std[0], in.std[1],
                in.std[2], in.std[3], in.proj_unc_centre_px, in.proj_unc_corner_px, in.flags);
        CHECK_NEAR(in.fx / FX, 1.0, 1e-3);
        CHECK_NEAR(in.fy / FY, 1.0, 1e-3);
        CHECK_NEAR(in.cx, CX, 0.5);
        CHECK_NEAR(in.cy, CY, 0.5);
        CHECK_LE(in.rms_px, 0.2);
        CHECK_INT_EQ(in.flags, 0);
        /* The truth must lie within a few σ of the estimate (the σ are not absurdly small). */
        CHECK_LE(fabs(in.fx - FX), 5 * in.std[0] + 0.05);
        CHECK_LE(fabs(in.cx - CX), 5 * in.std[2] + 0.05);
        return TEST_DONE();
}
