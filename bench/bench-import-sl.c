/* Real-data accuracy of the structured-light import (docs/import.md): for each capture of
 * ../shared/data/procam-graycode (a flat printed chessboard under OpenCV's Gray-code
 * sequence), `import sl` + the range image (process-range.h), then the RMS distance of the
 * triangulated points on the board (inside the quadrilateral of its outer inner corners,
 * both projector axes decoded) to their least-squares plane — impasto's triangulation and
 * OpenCV's cv::triangulatePoints on the same correspondences side by side.
 *   bench-import-sl --data DIR --calib RIG.json --work DIR [--board 9x7]
 * RIG.json: `impasto calibrate procam --captures DIR/capture_0 … --projector 1024x768
 * --board 9x7 --square 75 --out RIG.json` (units: the board's square = 75). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "captureset.h"
#include "numerics.h"
#include "cv-calib.h"
#include "cv-triangulate.h"
#include "heightfield.h"
#include "import-sl.h"
#include "process-range.h"

#define PLANE_INLIER_K 3.0            /* inliers: |d| ≤ this × 1.4826 × MAD of the distances */

struct plane_fit {
        long n, n_inliers;
        double rms_all, rms_inliers;
        double normal[3];
        double quant_rms;             /* expected from the Gray code's 1-pixel steps alone */
};

/* Least-squares plane through xyz[keep] (PCA: smallest eigenvector of the scatter). */
static double plane_rms(const double *xyz, const uint8_t *keep, size_t n, double *dist, double ret_normal[3]) {
        double c[3] = {}, A[9] = {}, lam[3], vec[9];
        long m = 0;
        for (size_t i = 0; i < n; i++)
                if (keep[i]) {
                        for (int k = 0; k < 3; k++)
                                c[k] += xyz[3 * i + k];
                        m++;
                }
        if (m < 3)
                return NAN;
        for (int k = 0; k < 3; k++)
                c[k] /= m;
        for (size_t i = 0; i < n; i++)
                if (keep[i])
                        for (int j = 0; j < 3; j++)
                                for (int k = 0; k < 3; k++)
                                        A[3 * j + k] += (xyz[3 * i + j] - c[j]) * (xyz[3 * i + k] - c[k]);
        imp_eigen_sym3(A, lam, vec);   /* ascending: vec[0..2] the smallest */
        for (int k = 0; k < 3; k++)
                ret_normal[k] = vec[k];
        double ss = 0;
        for (size_t i = 0; i < n; i++) {
                dist[i] = (xyz[3 * i] - c[0]) * vec[0] + (xyz[3 * i + 1] - c[1]) * vec[1] + (xyz[3 * i + 2] - c[2]) * vec[2];
                if (keep[i])
                        ss += dist[i] * dist[i];
        }
        return sqrt(ss / m);
}

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

/* Plane RMS over all points, then over the inliers of a robust refit. */
static int fit(const double *xyz, size_t n, struct plane_fit *ret) {
        uint8_t *keep = malloc(n ? n : 1);
        double *dist = malloc((n ? n : 1) * sizeof *dist), *ad = malloc((n ? n : 1) * sizeof *ad);
        if (!keep || !dist || !ad) {
                free(keep), free(dist), free(ad);
                return -ENOMEM;
        }
        memset(keep, 1, n);
        ret->n = (long) n;
        ret->rms_all = plane_rms(xyz, keep, n, dist, ret->normal);
        for (size_t i = 0; i < n; i++)
                ad[i] = fabs(dist[i]);
        qsort(ad, n, sizeof *ad, cmp_double);
        double lim = PLANE_INLIER_K * 1.4826 * ad[n / 2];
        ret->n_inliers = 0;
        for (size_t i = 0; i < n; i++)
                ret->n_inliers += keep[i] = fabs(dist[i]) <= lim;
        ret->rms_inliers = plane_rms(xyz, keep, n, dist, ret->normal);
        free(keep), free(dist), free(ad);
        return 0;
}

/* Inside the convex quadrilateral q (4 points in order)? */
static bool in_quad(const double q[8], double x, double y) {
        int sign = 0;
        for (int k = 0; k < 4; k++) {
                const double *a = &q[2 * k], *b = &q[2 * ((k + 1) % 4)];
                double cr = (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]);
                int s = cr > 0 ? 1 : cr < 0 ? -1 : 0;
                if (s && sign && s != sign)
                        return false;
                if (s)
                        sign = s;
        }
        return true;
}

/* The board quadrilateral from the white frame's corners. */
static int board_quad(const char *frames_dir, int white_index, int cols, int rows, double q[8], struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%.4000s/graycode_%02d.png", frames_dir, white_index);
        _cleanup_image_ struct imp_image *w = NULL;
        int r = imp_png_read(path, &w, err);
        if (r < 0)
                return r;
        double *px = malloc(2 * (size_t) cols * rows * sizeof *px);
        if (!px)
                return -ENOMEM;
        if ((r = imp_cv_calib_find_corners(w, cols, rows, px, err)) >= 0) {
                int idx[4] = { 0, cols - 1, rows * cols - 1, (rows - 1) * cols };
                for (int k = 0; k < 4; k++)
                        q[2 * k] = px[2 * idx[k]], q[2 * k + 1] = px[2 * idx[k] + 1];
        }
        free(px);
        return r;
}

/* The plane RMS the Gray code's quantisation alone gives: the decoded coordinate is a
 * pixel centre, uniform within ±0.5 px of the truth on each axis (σ = 1/√12); the
 * displacement along the plane normal per projector pixel comes from re-triangulating
 * with each axis moved by one pixel (first order). */
static int quantisation(const struct imp_rig *rig, const double *a, double *b, const double *x0, size_t n,
                        struct plane_fit *io) {
        double *x1 = malloc(n * 3 * sizeof *x1), ss = 0;
        if (!x1)
                return -ENOMEM;
        int r = 0;
        for (int axis = 0; axis < 2 && r >= 0; axis++) {
                for (size_t i = 0; i < n; i++)
                        b[2 * i + axis] += 1;
                r = imp_cv_triangulate(&rig->cameras[0].model, &rig->projector.model, a, b, n, x1, NULL);
                for (size_t i = 0; i < n; i++) {
                        b[2 * i + axis] -= 1;
                        double d = 0;
                        for (int k = 0; k < 3; k++)
                                d += (x1[3 * i + k] - x0[3 * i + k]) * io->normal[k];
                        ss += d * d / 12;
                }
        }
        free(x1);
        io->quant_rms = sqrt(ss / n);
        return r;
}

static int one_capture(const char *frames_dir, const char *calib, const char *set, int cols, int rows,
                       struct plane_fit *ours, struct plane_fit *cv, struct imp_error *err) {
        struct imp_import_sl_options o = { frames_dir, IMP_SL_ORDER_OPENCV_GRAYCODE, 1024, 768, calib };
        int r = imp_import_sl(&o, set, err), white = imp_import_sl_frame_count(o.order, 1024, 768) - 2;
        double q[8];
        if (r < 0 || (r = board_quad(frames_dir, white, cols, rows, q, err)) < 0)
                return r;
        struct imp_range_image rg = {};
        struct imp_sl_result *sl = NULL;
        if ((r = imp_range_from_set(set, &rg, &sl, err)) < 0)
                return r;
        size_t cap = (size_t) rg.width * rg.height, n = 0;
        double *a = malloc(cap * 2 * sizeof *a), *b = malloc(cap * 2 * sizeof *b);
        double *xo = malloc(cap * 3 * sizeof *xo), *xc = malloc(cap * 3 * sizeof *xc);
        struct imp_rig rig = {};
        if (!a || !b || !xo || !xc || (r = imp_rig_load(calib, &rig, err)) < 0) {
                r = r < 0 ? r : -ENOMEM;
                goto out;
        }
        for (int y = 0; y < rg.height; y++)
                for (int x = 0; x < rg.width; x++) {
                        size_t t = (size_t) y * rg.width + x;
                        if (rg.valid[t] != IMP_RANGE_BOTH || !in_quad(q, x, y))
                                continue;
                        a[2 * n] = x, a[2 * n + 1] = y;
                        /* decoder coordinates: projector pixel i spans [i, i + 1) */
                        b[2 * n] = sl->proj_x[t] - 0.5, b[2 * n + 1] = sl->proj_y[t] - 0.5;
                        for (int k = 0; k < 3; k++)
                                xo[3 * n + k] = rg.xyz[3 * t + k];
                        n++;
                }
        if (n < 3) {
                r = imp_error_set(err, -ENODATA, "%s: %zu decoded points on the board", frames_dir, n);
                goto out;
        }
        if ((r = imp_cv_triangulate(&rig.cameras[0].model, &rig.projector.model, a, b, n, xc, err)) >= 0 &&
            (r = fit(xo, n, ours)) >= 0 && (r = fit(xc, n, cv)) >= 0)
                r = quantisation(&rig, a, b, xc, n, cv);
out:
        imp_rig_free(&rig);
        free(a), free(b), free(xo), free(xc);
        imp_range_image_done(&rg);
        imp_sl_result_free(sl);
        return r;
}

int main(int argc, char **argv) {
        const char *data = NULL, *calib = NULL, *work = NULL;
        int cols = 9, rows = 7;
        for (int i = 1; i + 1 < argc; i += 2) {
                if (!strcmp(argv[i], "--data")) data = argv[i + 1];
                else if (!strcmp(argv[i], "--calib")) calib = argv[i + 1];
                else if (!strcmp(argv[i], "--work")) work = argv[i + 1];
                else if (!strcmp(argv[i], "--board") && sscanf(argv[i + 1], "%dx%d", &cols, &rows) != 2) return 2;
        }
        if (!data || !calib || !work) {
                fprintf(stderr, "usage: bench-import-sl --data DIR --calib RIG.json --work DIR [--board 9x7]\n");
                return 2;
        }
        printf("%-10s %8s %12s %12s %9s %12s %12s %12s\n", "capture", "points", "impasto_rms", "opencv_rms", "inliers",
               "impasto_in", "opencv_in", "gray_quant");
        for (int c = 0; c < 5; c++) {
                char frames[2048], set[2048];
                snprintf(frames, sizeof frames, "%s/capture_%d", data, c);
                snprintf(set, sizeof set, "%s/capture_%d", work, c);
                struct plane_fit ours = {}, cv = {};
                struct imp_error err = {};
                int r = one_capture(frames, calib, set, cols, rows, &ours, &cv, &err);
                if (r < 0) {
                        printf("capture_%d  failed: %s\n", c, err.msg[0] ? err.msg : strerror(-r));
                        continue;
                }
                printf("capture_%d  %8ld %12.4f %12.4f %9ld %12.4f %12.4f %12.4f\n", c, ours.n, ours.rms_all,
                       cv.rms_all, ours.n_inliers, ours.rms_inliers, cv.rms_inliers, cv.quant_rms);
        }
        printf("(RMS distance to the least-squares plane, calibration units: a board square is 75; inliers:\n"
               " |d| <= %.0f x 1.4826 x MAD after the first fit, counts and RMS of impasto's, OpenCV's on its own;\n"
               " gray_quant: the RMS the Gray code's 1-pixel steps alone would give, sqrt(sum over axes of\n"
               " (plane-normal displacement per projector pixel)^2 / 12), from OpenCV's triangulation)\n",
               PLANE_INLIER_K);
        return 0;
}
