/* In-plane registration error against the truth poses (mosaic.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include "mosaic.h"

/* The 4 corners and the centre of tile t: estimated and true painting positions. */
static void tile_points(const struct imp_mosaic_tile *t, double est[5][2], double tru[5][2]) {
        const double *M = t->c2w;
        for (int q = 0; q < 5; q++) {
                double fi = q == 4 ? 0.5 * (t->nx - 1) : (q & 1) ? t->nx - 1 : 0;
                double fj = q == 4 ? 0.5 * (t->ny - 1) : (q & 2) ? t->ny - 1 : 0;
                imp_mosaic_tile_to_painting(t, fi, fj, est[q]);
                double u = fi * t->pitch_mm, v = fj * t->pitch_mm;
                double wx = M[0] * u + M[1] * v + M[3], wy = M[4] * u + M[5] * v + M[7];
                double c = cos(t->truth[2]), s = sin(t->truth[2]);
                tru[q][0] = t->truth[0] + c * wx - s * wy, tru[q][1] = t->truth[1] + s * wx + c * wy;
        }
}

int imp_mosaic_registration_error(const struct imp_painting *p, struct imp_mosaic_reg_error *ret) {
        if (!p->has_truth)
                return -ENODATA;
        size_t n = 5 * p->n_tiles;
        double (*e)[2] = malloc(n * sizeof *e), (*X)[2] = malloc(n * sizeof *X);
        if (!e || !X)
                return free(e), free(X), -ENOMEM;
        double m[2] = { 0 }, xm[2] = { 0 }, ss = 0;
        for (size_t k = 0; k < p->n_tiles; k++) {
                double est[5][2], tru[5][2];
                tile_points(&p->tiles[k], est, tru);
                for (int q = 0; q < 5; q++) {
                        size_t i = 5 * k + q;
                        e[i][0] = est[q][0] - tru[q][0], e[i][1] = est[q][1] - tru[q][1];
                        X[i][0] = tru[q][0], X[i][1] = tru[q][1];
                        m[0] += e[i][0] / n, m[1] += e[i][1] / n, xm[0] += X[i][0] / n, xm[1] += X[i][1] / n;
                        ss += e[i][0] * e[i][0] + e[i][1] * e[i][1];
                }
        }
        /* The common rigid motion: translation m and rotation φ about the centroid. */
        double num = 0, den = 0;
        for (size_t i = 0; i < n; i++) {
                double jx = -(X[i][1] - xm[1]), jy = X[i][0] - xm[0];
                num += jx * (e[i][0] - m[0]) + jy * (e[i][1] - m[1]), den += jx * jx + jy * jy;
        }
        double phi = den > 0 ? num / den : 0, rs = 0, sum = 0, far = -1, far_d = -1, mx = 0;
        for (size_t i = 0; i < n; i++) {
                double rx = e[i][0] - m[0] + phi * (X[i][1] - xm[1]), ry = e[i][1] - m[1] - phi * (X[i][0] - xm[0]);
                double a = hypot(rx, ry);
                rs += a * a, sum += a, mx = fmax(mx, a);
                double d = hypot(X[i][0] - X[0][0], X[i][1] - X[0][1]);
                if (d > far_d)
                        far_d = d, far = a;
        }
        *ret = (struct imp_mosaic_reg_error) { .abs_rms_um = 1e3 * sqrt(ss / n), .rms_um = 1e3 * sqrt(rs / n),
                                               .mean_um = 1e3 * sum / n, .far_corner_um = 1e3 * far, .max_um = 1e3 * mx };
        free(e), free(X);
        return 0;
}
