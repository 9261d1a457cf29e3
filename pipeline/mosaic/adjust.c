/* Global least-squares adjustment of the tile poses (mosaic.h): a linear pose graph.
 * Unknowns: each tile's correction ε = (δt_x, δt_y, δθ, δdz) to its current pose. A tile's
 * painting map moves by δt + δθ·J(P − o) (J the 90° rotation, o the tile's centre), exact to
 * first order in δθ (θ is a fraction of a degree: the second order is below 0.1 µm over a
 * field). A pair measured b relative to a as (d, dθ, dz) about the overlap centre c:
 *     δt_b + δθ_b·J(c − o_b) − δt_a − δθ_a·J(c − o_a) = d,  δθ_b − δθ_a = dθ,  δdz_b − δdz_a = dz,
 * weighted by the pair's information; every tile's stage prior pulls its pose to 0 with its σ
 * and so fixes the gauge. Normal equations solved by a dense Cholesky (4N unknowns: a few
 * hundred tiles is a few MB). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "macro.h"
#include "mosaic.h"
#include "numerics.h"

/* The pair's 4×8 design matrix over (ε_a, ε_b). */
static void design(const struct imp_painting *p, const struct imp_mosaic_pair *pr, double A[4][8]) {
        const struct imp_mosaic_tile *ta = &p->tiles[pr->a], *tb = &p->tiles[pr->b];
        double oa[2] = { ta->nominal_mm[0] + ta->pose[0], ta->nominal_mm[1] + ta->pose[1] };
        double ob[2] = { tb->nominal_mm[0] + tb->pose[0], tb->nominal_mm[1] + tb->pose[1] };
        memset(A, 0, sizeof(double[4][8]));
        A[0][0] = -1, A[0][2] = pr->c_mm[1] - oa[1], A[0][4] = 1, A[0][6] = -(pr->c_mm[1] - ob[1]);
        A[1][1] = -1, A[1][2] = -(pr->c_mm[0] - oa[0]), A[1][5] = 1, A[1][6] = pr->c_mm[0] - ob[0];
        A[2][2] = -1, A[2][6] = 1;
        A[3][3] = -1, A[3][7] = 1;
}

static void add_pair(const struct imp_painting *p, const struct imp_mosaic_pair *pr, size_t n, double *H, double *g) {
        double A[4][8], IA[4][8];
        design(p, pr, A);
        for (int r = 0; r < 4; r++)
                for (int c = 0; c < 8; c++) {
                        IA[r][c] = 0;
                        for (int k = 0; k < 4; k++)
                                IA[r][c] += pr->info[r * 4 + k] * A[k][c];
                }
        size_t idx[8];
        for (int c = 0; c < 8; c++)
                idx[c] = 4 * (c < 4 ? pr->a : pr->b) + c % 4;
        for (int c = 0; c < 8; c++) {
                for (int r = 0; r < 4; r++)
                        g[idx[c]] += IA[r][c] * pr->meas[r];
                for (int d = 0; d < 8; d++) {
                        double s = 0;
                        for (int r = 0; r < 4; r++)
                                s += A[r][c] * IA[r][d];
                        H[idx[c] * n + idx[d]] += s;
                }
        }
}

static void stats(const struct imp_painting *p, const struct imp_mosaic_pair *pairs, size_t n_pairs,
                  const double *eps, struct imp_mosaic_adjust_stats *st) {
        double ss = 0, mx = 0, th = 0;
        size_t cnt = 0;
        for (size_t k = 0; k < p->n_tiles; k++) {
                struct imp_mosaic_tile t = p->tiles[k];
                for (int c = 0; c < 4; c++) {
                        double a[2], b[2], fi = (c & 1) ? t.nx - 1 : 0, fj = (c & 2) ? t.ny - 1 : 0;
                        imp_mosaic_tile_to_painting(&p->tiles[k], fi, fj, a);
                        memset(t.pose, 0, sizeof t.pose);
                        imp_mosaic_tile_to_painting(&t, fi, fj, b);
                        double d = hypot(a[0] - b[0], a[1] - b[1]) * 1e3;
                        ss += d * d, mx = fmax(mx, d), cnt++;
                }
                th += p->tiles[k].pose[2] * p->tiles[k].pose[2];
                for (int d = 0; d < 4; d++) {
                        double r = p->tiles[k].pose[d] / p->tiles[k].prior_sd[d];
                        st->chi2_priors += r * r;
                }
        }
        st->change_rms_um = sqrt(ss / cnt), st->change_max_um = mx;
        st->theta_change_rms_deg = sqrt(th / p->n_tiles) * 180 / M_PI;
        double rr = 0;
        for (size_t i = 0; i < n_pairs; i++) {
                if (!pairs[i].ok)
                        continue;
                double A[4][8], res[4];
                design(p, &pairs[i], A);
                for (int r = 0; r < 4; r++) {
                        res[r] = -pairs[i].meas[r];
                        for (int c = 0; c < 8; c++)
                                res[r] += A[r][c] * eps[4 * (c < 4 ? pairs[i].a : pairs[i].b) + c % 4];
                }
                rr += res[0] * res[0] + res[1] * res[1];
                for (int r = 0; r < 4; r++)
                        for (int c = 0; c < 4; c++)
                                st->chi2_pairs += res[r] * pairs[i].info[r * 4 + c] * res[c];
        }
        st->pair_resid_rms_um = st->n_pairs_used ? 1e3 * sqrt(rr / st->n_pairs_used) : 0;
}

/* One solve with the pairs' information scaled by w: eps (n) the corrections. */
static int solve(const struct imp_painting *p, const struct imp_mosaic_pair *pairs, size_t n_pairs, double w,
                 double *eps, size_t *ret_used, struct imp_error *err) {
        size_t n = 4 * p->n_tiles;
        _cleanup_free_ double *H = calloc(n * n, sizeof *H);
        if (!H)
                return imp_error_set(err, -ENOMEM, "out of memory for the adjustment of %zu tiles", p->n_tiles);
        memset(eps, 0, n * sizeof *eps);
        for (size_t k = 0; k < p->n_tiles; k++)
                for (int d = 0; d < 4; d++) {
                        double wp = 1 / (p->tiles[k].prior_sd[d] * p->tiles[k].prior_sd[d]);
                        H[(4 * k + d) * n + 4 * k + d] += wp;
                        eps[4 * k + d] -= wp * p->tiles[k].pose[d];
                }
        /* The design is taken at the poses the pairs were measured at: the current ones. */
        *ret_used = 0;
        for (size_t i = 0; i < n_pairs; i++)
                if (pairs[i].ok) {
                        struct imp_mosaic_pair q = pairs[i];
                        for (int k = 0; k < 16; k++)
                                q.info[k] *= w;
                        add_pair(p, &q, n, H, eps), (*ret_used)++;
                }
        if (!imp_cholesky_factor((int) n, H))
                return imp_error_set(err, -EDOM, "mosaic: the pose graph's normal equations are not positive definite "
                                     "(a pair's information is not finite?)");
        imp_cholesky_solve((int) n, H, eps);
        for (size_t k = 0; k < n; k++)
                if (!isfinite(eps[k]))
                        return imp_error_set(err, -EDOM, "mosaic: the adjustment gave a non-finite pose");
        return 0;
}

int imp_mosaic_adjust(struct imp_painting *p, const struct imp_mosaic_pair *pairs, size_t n_pairs,
                      struct imp_mosaic_adjust_stats *st, struct imp_error *err) {
        size_t n = 4 * p->n_tiles;
        memset(st, 0, sizeof *st);
        if (n > 4 * 4000)
                return imp_error_set(err, -E2BIG, "mosaic: %zu tiles: the dense adjustment stops at 4000", p->n_tiles);
        _cleanup_free_ double *eps = malloc(n * sizeof *eps);
        if (!eps)
                return imp_error_set(err, -ENOMEM, "out of memory");
        /* The pairs' variance factor a posteriori: their information comes from residuals
           taken as independent, but a tile's relief errors are correlated over many texels,
           so on a rendered painting the pairs claimed several times their real precision
           (χ² of the pairs 12× their count of measurements on painting-small). Scaled until
           their χ² per measurement is 1 (at most 1: a consistent set keeps its weight). */
        double w = 1;
        struct imp_mosaic_adjust_stats tmp = *st;
        for (int it = 0; it < 8; it++) {
                int r = solve(p, pairs, n_pairs, w, eps, &st->n_pairs_used, err);
                if (r < 0)
                        return r;
                tmp = *st;
                stats(p, pairs, n_pairs, eps, &tmp);        /* pair misfit: design at the measured poses */
                double k = st->n_pairs_used ? w * tmp.chi2_pairs / (4.0 * st->n_pairs_used) : 1;
                if (k <= 1.05)
                        break;
                w /= k;
        }
        st->variance_factor = 1 / w;
        for (size_t k = 0; k < p->n_tiles; k++)
                for (int d = 0; d < 4; d++)
                        p->tiles[k].pose[d] += eps[4 * k + d];
        double chi2_pairs = tmp.chi2_pairs, pr = tmp.pair_resid_rms_um;
        stats(p, NULL, 0, eps, st);            /* changes and the priors' χ² after */
        st->chi2_pairs = chi2_pairs, st->pair_resid_rms_um = pr;
        imp_painting_update_bboxes(p);
        return 0;
}
