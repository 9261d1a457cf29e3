/* Copy-versus-truth figures (see compare.h). */
#include <math.h>
#include <string.h>
#include "compare.h"
#include "image.h"
#include "json-util.h"
#include "numerics.h"
#include "quality.h"
#include "rig.h"

#define CMP_FIXED_POINT_ITER 4
#define CMP_CONVERGED_MM     1e-5  /* the fixed point has met the truth surface */
#define CMP_SEARCH_MM        3.0   /* farthest crossing searched along the copy's normal */
#define CMP_MIN_NORMAL_Z     0.1   /* copy normal this close to the world x–y plane: skip */
/* Band limit of the truth for normal_err_deg_mean_bandlimited: a Gaussian of σ = this ×
 * the copy pitch p, whose response exp(−2π²σ²f²) is ½ at the copy's Nyquist frequency
 * 1/(2p) (σ = p·√(2 ln 2)/π). It was σ = p, response 0.29 already at 1/(4p): that
 * removed detail a grid of pitch p holds (the demo's 0.2 mm grooves at 4 texels per
 * period) and so penalised a copy that resolves it (docs/geometry.md). */
#define CMP_BANDLIMIT_SIGMA_PITCH 0.375

struct truth {
        double pitch, origin[2];
        int nx, ny;
        struct imp_image *img;
        int c_h, c_nx, c_ny, c_nz, c_m;
};

static double truth_at(const struct truth *t, int i, int j, int c) {
        return *(imp_image_f32(t->img, i, j) + c);
}

/* Bilinear truth height at world (x, y); false outside the grid or when a corner of the
 * cell is not canvas (no interpolation across the frame step). */
static bool truth_height(const struct truth *t, double x, double y, double *ret) {
        double fx = (x - t->origin[0]) / t->pitch, fy = (y - t->origin[1]) / t->pitch;
        if (!(fx >= 0 && fy >= 0 && fx <= t->nx - 1 && fy <= t->ny - 1))
                return false;
        int x0 = IMP_MIN((int) fx, t->nx - 2 < 0 ? 0 : t->nx - 2), y0 = IMP_MIN((int) fy, t->ny - 2 < 0 ? 0 : t->ny - 2);
        int x1 = IMP_MIN(x0 + 1, t->nx - 1), y1 = IMP_MIN(y0 + 1, t->ny - 1);
        double ax = fx - x0, ay = fy - y0;
        if (truth_at(t, x0, y0, t->c_m) < 0.5 || truth_at(t, x1, y0, t->c_m) < 0.5 ||
            truth_at(t, x0, y1, t->c_m) < 0.5 || truth_at(t, x1, y1, t->c_m) < 0.5)
                return false;
        double a = truth_at(t, x0, y0, t->c_h), b = truth_at(t, x1, y0, t->c_h);
        double c = truth_at(t, x0, y1, t->c_h), d = truth_at(t, x1, y1, t->c_h);
        *ret = (a * (1 - ax) + b * ax) * (1 - ay) + (c * (1 - ax) + d * ax) * ay;
        return isfinite(*ret);
}

/* f(s) = truth height − height of P + s·ez: where the line along the copy's canvas
 * normal through P meets the truth surface. */
static bool along_normal_gap(const struct truth *t, const double P[3], const double ez[3], double s, double *ret) {
        double zt;
        if (!truth_height(t, P[0] + s * ez[0], P[1] + s * ez[1], &zt))
                return false;
        *ret = zt - (P[2] + s * ez[2]);
        return true;
}

/* The offset s along ez from the copy point P to the truth surface. The fixed point
 * s ← (z(P + s·ez) − P_z)/ez_z is exact in one step when ez is vertical, but converges only
 * where the truth's slope along ez's tilt times tan(tilt) is below 1 and slowly near it: on
 * a canvas tilted 25° the ramp of a ridge left 45 µm after 4 steps, and across a cliff it
 * oscillates. When it has not converged, the crossing nearest P is bracketed by a scan in
 * steps of half a truth sample and bisected. False outside the truth canvas. */
static bool truth_along_normal(const struct truth *t, const double P[3], const double ez[3], double *ret) {
        double s = 0, zt, f0, fa, fb;
        bool ok = true;
        for (int it = 0; it < CMP_FIXED_POINT_ITER && ok; it++) {
                ok = truth_height(t, P[0] + s * ez[0], P[1] + s * ez[1], &zt);
                s = (zt - P[2]) / ez[2];
        }
        if (!ok || !along_normal_gap(t, P, ez, s, &f0))
                return false;
        if (fabs(f0) <= CMP_CONVERGED_MM) {
                *ret = s;
                return true;
        }
        if (!along_normal_gap(t, P, ez, 0, &fa))
                return false;
        double step = 0.5 * t->pitch, a = 0, b = 0;
        bool found = false;
        for (int k = 1; k * step <= CMP_SEARCH_MM && !found; k++)
                for (int sign = -1; sign <= 1 && !found; sign += 2) {
                        double lo = sign * (k - 1) * step, hi = sign * k * step, flo;
                        if (!along_normal_gap(t, P, ez, lo, &flo) || !along_normal_gap(t, P, ez, hi, &fb))
                                continue;
                        if ((flo <= 0) != (fb <= 0))
                                a = lo, b = hi, fa = flo, found = true;
                }
        if (!found)
                return false;
        for (int it = 0; it < 50 && fabs(b - a) > 1e-9; it++) {
                double m = 0.5 * (a + b), fm;
                if (!along_normal_gap(t, P, ez, m, &fm))
                        return false;
                if ((fm <= 0) == (fa <= 0))
                        a = m, fa = fm;
                else
                        b = m;
        }
        *ret = 0.5 * (a + b);
        return true;
}

/* Truth normal at sample (i, j): the stored one (hs NULL), or central differences of the
 * smoothed heights hs. Not normalised. */
static void truth_normal_sample(const struct truth *t, const float *hs, int i, int j, double ret[3]) {
        if (!hs) {
                ret[0] = truth_at(t, i, j, t->c_nx), ret[1] = truth_at(t, i, j, t->c_ny), ret[2] = truth_at(t, i, j, t->c_nz);
                return;
        }
        int i0 = IMP_MAX(i - 1, 0), i1 = IMP_MIN(i + 1, t->nx - 1), j0 = IMP_MAX(j - 1, 0), j1 = IMP_MIN(j + 1, t->ny - 1);
        double gx = i1 > i0 ? (hs[(size_t) j * t->nx + i1] - hs[(size_t) j * t->nx + i0]) / ((i1 - i0) * t->pitch) : 0;
        double gy = j1 > j0 ? (hs[(size_t) j1 * t->nx + i] - hs[(size_t) j0 * t->nx + i]) / ((j1 - j0) * t->pitch) : 0;
        double l = sqrt(gx * gx + gy * gy + 1);
        ret[0] = -gx / l, ret[1] = -gy / l, ret[2] = 1 / l;
}

/* Unit truth normal at world (x, y): the bilinear blend of the four surrounding samples'
 * normals, normalised, which is the normal the simulator shades the point with
 * (sim/render.c), so the copy is compared with the surface it was measured on. The
 * nearest sample instead (before) is up to half a truth sample (25 µm) away: on the
 * demo's 0.2 mm bristle grooves that alone added 4° to the mean (docs/geometry.md). */
static void truth_normal_at(const struct truth *t, const float *hs, double x, double y, double ret[3]) {
        double fx = (x - t->origin[0]) / t->pitch, fy = (y - t->origin[1]) / t->pitch;
        int x0 = IMP_CLAMP((int) floor(fx), 0, IMP_MAX(t->nx - 2, 0)), y0 = IMP_CLAMP((int) floor(fy), 0, IMP_MAX(t->ny - 2, 0));
        int x1 = IMP_MIN(x0 + 1, t->nx - 1), y1 = IMP_MIN(y0 + 1, t->ny - 1);
        double ax = IMP_CLAMP(fx - x0, 0.0, 1.0), ay = IMP_CLAMP(fy - y0, 0.0, 1.0), n[4][3], l = 0;
        truth_normal_sample(t, hs, x0, y0, n[0]);
        truth_normal_sample(t, hs, x1, y0, n[1]);
        truth_normal_sample(t, hs, x0, y1, n[2]);
        truth_normal_sample(t, hs, x1, y1, n[3]);
        for (int c = 0; c < 3; c++) {
                ret[c] = (n[0][c] * (1 - ax) + n[1][c] * ax) * (1 - ay) + (n[2][c] * (1 - ax) + n[3][c] * ax) * ay;
                l += ret[c] * ret[c];
        }
        l = sqrt(l);
        for (int c = 0; c < 3; c++)
                ret[c] = l > 0 ? ret[c] / l : (c == 2);
}

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

static int load_exr(const char *dir, const char *what, struct imp_image **ret_img, char ***ret_names,
                    struct imp_error *err) {
        char path[4096];
        snprintf(path, sizeof path, "%s/heightfield.exr", dir);
        int r = imp_exr_read(path, ret_img, ret_names, err);
        if (r < 0)
                imp_error_prefix(err, "%s: ", what);
        return r;
}

static int channel(char **names, const char *name, const char *path, struct imp_error *err) {
        int c = imp_image_channel_index(names, name);
        if (c < 0)
                return imp_error_set(err, -EBADMSG, "%s/heightfield.exr: channel \"%s\" missing", path, name);
        return c;
}

/* Observable truth canvas: per truth sample, 1 when camera 0 of the true rig sees it (the
 * depth its pixel sees is this sample's height) and the projector lights it there. Returns
 * NULL (no error) when the truth has no rig.json or correspondence map. */
#define CMP_SEEN_DEPTH_TOL_MM 0.05
static uint8_t *observable_mask(const char *truth_dir, const struct truth *t) {
        char path[4096];
        struct imp_rig rig = {};
        snprintf(path, sizeof path, "%s/rig.json", truth_dir);
        if (imp_rig_load(path, &rig, NULL) < 0)
                return NULL;
        uint8_t *obs = NULL;
        struct imp_image *corr = NULL;
        char **names = NULL;
        if (rig.n_cameras < 1)
                goto out;
        snprintf(path, sizeof path, "%s/correspondence-%s.exr", truth_dir, rig.cameras[0].name);
        if (imp_exr_read(path, &corr, &names, NULL) < 0)
                goto out;
        int cv = imp_image_channel_index(names, "valid"), cd = imp_image_channel_index(names, "depth_mm");
        if (cv < 0 || cd < 0 || !(obs = calloc((size_t) t->nx * t->ny, 1)))
                goto out;
        for (int j = 0; j < t->ny; j++)
                for (int i = 0; i < t->nx; i++) {
                        double h = truth_at(t, i, j, t->c_h);
                        double X[3] = { t->origin[0] + i * t->pitch, t->origin[1] + j * t->pitch, h }, px[2];
                        if (!imp_pinhole_project(&rig.cameras[0].model, X, px))
                                continue;
                        long u = lround(px[0]), v = lround(px[1]);
                        if (u < 0 || v < 0 || u >= corr->width || v >= corr->height)
                                continue;
                        const float *c = imp_image_f32(corr, (int) u, (int) v);
                        obs[(size_t) j * t->nx + i] = c[cv] >= 0.5 && fabs(c[cd] - h) <= CMP_SEEN_DEPTH_TOL_MM;
                }
out:
        imp_strv_free(names);
        imp_image_free(corr);
        imp_rig_free(&rig);
        return obs;
}

/* Truth canvas heights smoothed by a normalised Gaussian (σ in truth samples) over canvas
 * samples only, so the frame does not bleed in. Caller frees. NULL when out of memory. */
static float *smooth_truth(const struct truth *t, double sigma) {
        int rad = (int) ceil(3 * sigma);
        size_t n = (size_t) t->nx * t->ny;
        float *tmp = malloc(n * sizeof(float) * 2), *out;
        double *w = malloc((2 * rad + 1) * sizeof(double));
        if (!tmp || !w) {
                free(tmp);
                free(w);
                return NULL;
        }
        out = tmp + n;
        for (int k = -rad; k <= rad; k++)
                w[k + rad] = sigma > 0 ? exp(-0.5 * k * k / (sigma * sigma)) : (k == 0);
        for (int pass = 0; pass < 2; pass++)
                for (int j = 0; j < t->ny; j++)
                        for (int i = 0; i < t->nx; i++) {
                                double sw = 0, sh = 0;
                                for (int k = -rad; k <= rad; k++) {
                                        int ii = pass ? i : i + k, jj = pass ? j + k : j;
                                        if (ii < 0 || jj < 0 || ii >= t->nx || jj >= t->ny ||
                                            truth_at(t, ii, jj, t->c_m) < 0.5)
                                                continue;
                                        double h = pass ? tmp[(size_t) jj * t->nx + ii] : truth_at(t, ii, jj, t->c_h);
                                        sw += w[k + rad];
                                        sh += w[k + rad] * h;
                                }
                                float v = sw > 0 ? (float) (sh / sw) : (float) truth_at(t, i, j, t->c_h);
                                (pass ? out : tmp)[(size_t) j * t->nx + i] = v;
                        }
        memmove(tmp, out, n * sizeof(float));
        free(w);
        return realloc(tmp, n * sizeof(float)) ?: tmp;
}

int imp_compare_load_grids(const char *copy_dir, const char *truth_dir, json_t **ret_copy_json,
                           struct imp_compare_grids *ret, struct imp_error *err) {
        if (!copy_dir || !truth_dir || !ret)
                return imp_error_set(err, -EINVAL, "compare: bad arguments");
        char path[4096];
        int r;
        _cleanup_json_ json_t *cj = NULL, *tj = NULL;
        struct imp_compare_grids g = {};
        snprintf(path, sizeof path, "%s/copy.json", copy_dir);
        if ((r = imp_json_load(path, &cj, err)) < 0)
                return r;
        if ((r = imp_json_get_doubles(cj, "canvas_to_world", true, 16, g.canvas_to_world, path, err)) < 0 ||
            (r = imp_json_get_double(cj, "pitch_mm", true, &g.copy_pitch, path, err)) < 0 ||
            (r = imp_json_get_int(cj, "nx", true, &g.copy_nx, path, err)) < 0 ||
            (r = imp_json_get_int(cj, "ny", true, &g.copy_ny, path, err)) < 0)
                return r;
        if (!(g.copy_pitch > 0))
                return imp_error_set(err, -EBADMSG, "%s: pitch_mm must be > 0", path);
        snprintf(path, sizeof path, "%s/truth.json", truth_dir);
        if ((r = imp_json_load(path, &tj, err)) < 0)
                return r;
        if ((r = imp_json_get_double(tj, "pitch_mm", true, &g.truth_pitch, path, err)) < 0 ||
            (r = imp_json_get_doubles(tj, "origin_mm", true, 2, g.truth_origin, path, err)) < 0 ||
            (r = imp_json_get_int(tj, "nx", true, &g.truth_nx, path, err)) < 0 ||
            (r = imp_json_get_int(tj, "ny", true, &g.truth_ny, path, err)) < 0)
                return r;
        if (!(g.truth_pitch > 0))
                return imp_error_set(err, -EBADMSG, "%s: pitch_mm must be > 0", path);
        *ret = g;
        if (ret_copy_json)
                *ret_copy_json = TAKE_PTR(cj);
        return 0;
}

/* Angle between the copy's canvas normal ez and the truth canvas's base plane: the plane
 * of the truth's median slope, (median n_x/n_z, median n_y/n_z, 1) over the canvas samples
 * (n_z > 0). The mean of the unit normals is not that plane: it weights a sample by its
 * projected area, so a ridge's gentle flank outweighs its cliff and the hard suite's
 * untilted canvas came out 1.4° off; the mean slope is the plane for relief that returns
 * to the base, but a few samples at the canvas's border (normals taken across the frame
 * step) dominate it. -1 when no canvas sample; -2 out of memory. */
static double placement_deg(const struct truth *t, const double ez[3]) {
        size_t n = (size_t) t->nx * t->ny, k = 0;
        _cleanup_free_ float *sx = malloc((n ? n : 1) * sizeof(float)), *sy = malloc((n ? n : 1) * sizeof(float));
        if (!sx || !sy)
                return -2;
        for (int j = 0; j < t->ny; j++)
                for (int i = 0; i < t->nx; i++) {
                        double nz = truth_at(t, i, j, t->c_nz);
                        if (truth_at(t, i, j, t->c_m) >= 0.5 && nz > 0) {
                                sx[k] = (float) (truth_at(t, i, j, t->c_nx) / nz);
                                sy[k++] = (float) (truth_at(t, i, j, t->c_ny) / nz);
                        }
                }
        if (k == 0)
                return -1;
        double m[3] = { imp_select_kth_float(sx, k, k / 2), imp_select_kth_float(sy, k, k / 2), 1 };
        double l = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
        return acos(IMP_CLAMP((m[0] * ez[0] + m[1] * ez[1] + m[2] * ez[2]) / l, -1.0, 1.0)) * 180 / M_PI;
}

/* Copy mask texels whose world point (x, y) is on the truth frame, over those inside the
 * truth grid. */
static double frame_texels(const struct imp_image *cimg, int cm, const struct truth *t, const double *M,
                           double cpitch) {
        size_t on_frame = 0, inside = 0;
        for (int j = 0; j < cimg->height; j++)
                for (int i = 0; i < cimg->width; i++) {
                        if (!(*(imp_image_f32(cimg, i, j) + cm) >= 0.5))
                                continue;
                        double x = M[3] + i * cpitch * M[0] + j * cpitch * M[1];
                        double y = M[7] + i * cpitch * M[4] + j * cpitch * M[5];
                        long ti = lround((x - t->origin[0]) / t->pitch), tj = lround((y - t->origin[1]) / t->pitch);
                        if (ti < 0 || tj < 0 || ti >= t->nx || tj >= t->ny)
                                continue;
                        inside++;
                        on_frame += truth_at(t, (int) ti, (int) tj, t->c_m) < 0.5;
                }
        return inside ? (double) on_frame / inside : 0;
}

/* The honesty figures over the compared texels: d the height differences, sg per texel
 * (σ_h or −1 when flagged, σ_n or −1 when unknown, normal error in degrees, σ_h or −1
 * when a height flag excuses it: HEIGHT_FLAGS). */
#define CMP_NORMAL_BAD_DEG 10.0
/* The flags that excuse a texel's height from its σ_h (docs/copy-quality.md): the others
 * (normal_uncertain, photometric_rejected, fit_failed, ...) speak of its normal or its
 * appearance, and its height must still lie within 3σ_h. */
#define HEIGHT_FLAGS (IMP_TEXEL_SATURATED | IMP_TEXEL_FILLED | IMP_TEXEL_FRAME_ADJACENT | IMP_TEXEL_PHASE_REJECTED)
static void honesty(struct imp_compare_result *res, const double *d, const float *sg, size_t n, double med,
                    bool has_sigma_n) {
        size_t nu = 0, bh = 0, bn = 0, over = 0, sn_known = 0, nh = 0, bhh = 0, na = 0, bna = 0;
        double mx = 0;
        for (size_t k = 0; k < n; k++) {
                const float *q = sg + 4 * k;
                if (q[1] >= 0) {
                        na++;
                        bna += q[2] > 3 * q[1];
                }
                if (q[3] >= 0) {
                        nh++;
                        bhh += fabs(d[k] - med) > 3 * q[3];
                }
                if (q[0] < 0)
                        continue;
                nu++;
                bh += fabs(d[k] - med) > 3 * q[0];
                if (q[1] >= 0) {
                        sn_known++;
                        bn += q[2] > 3 * q[1];
                }
                over += q[2] > CMP_NORMAL_BAD_DEG;
                mx = fmax(mx, q[2]);
        }
        res->n_unflagged = nu;
        res->flagged_fraction = n ? (double) (n - nu) / n : 0;
        res->beyond_3sigma_height = nu ? (double) bh / nu : 0;
        res->beyond_3sigma_normal = sn_known ? (double) bn / sn_known : has_sigma_n ? 0 : -1;
        res->unflagged_normal_err_deg_max = mx;
        res->unflagged_normal_over_10deg = over;
        res->n_height_promised = nh;
        res->beyond_3sigma_height_promised = nh ? (double) bhh / nh : 0;
        res->beyond_3sigma_normal_all = na ? (double) bna / na : -1;
}

/* Height RMSE about the median offset, split by mask value, and the mean normal errors;
 * diff holds the sorted-in-place differences, diff + n_tex the same unsorted. */
static void height_figures(struct imp_compare_result *res, double *diff, const uint8_t *filled, size_t n,
                           size_t n_tex, double sum_ang, double sum_ang_f, double sum_ang_bl) {
        res->normal_err_deg_mean = sum_ang / n;
        res->normal_err_deg_mean_bandlimited = sum_ang_bl / n;
        qsort(diff, n, sizeof(double), cmp_double);
        double med = n % 2 ? diff[n / 2] : 0.5 * (diff[n / 2 - 1] + diff[n / 2]);
        double ss = 0, mx = 0;
        for (size_t k = 0; k < n; k++) {
                double d = diff[k] - med;
                ss += d * d;
                mx = fmax(mx, fabs(d));
        }
        double ss_k[2] = { 0, 0 };
        for (size_t k = 0; k < n; k++) {
                double d = diff[n_tex + k] - med;
                ss_k[filled[k]] += d * d;
                res->n_filled += filled[k];
        }
        size_t n_meas = n - res->n_filled;
        if (res->n_filled) {
                res->height_rmse_um_filled = sqrt(ss_k[1] / res->n_filled) * 1000.0;
                res->normal_err_deg_mean_filled = sum_ang_f / res->n_filled;
        }
        if (n_meas) {
                res->height_rmse_um_measured = sqrt(ss_k[0] / n_meas) * 1000.0;
                res->normal_err_deg_mean_measured = (sum_ang - sum_ang_f) / n_meas;
        }
        res->height_offset_mm = med;
        res->height_rmse_um = sqrt(ss / n) * 1000.0;
        res->height_max_abs_um = mx * 1000.0;
}

/* Canvas-mask IoU over the truth grid (compare.h), and over the observable canvas. */
static void mask_iou(const char *truth_dir, const struct truth *tt, const struct imp_image *cimg, int cm,
                     const double *M, double cpitch, struct imp_compare_result *res) {
        const struct truth t = *tt;
        double ex[3] = { M[0], M[4], M[8] }, ey[3] = { M[1], M[5], M[9] }, o[3] = { M[3], M[7], M[11] };
        _cleanup_free_ uint8_t *obs = observable_mask(truth_dir, &t);
        size_t inter = 0, uni = 0, inter_o = 0, uni_o = 0;
        for (int j = 0; j < t.ny; j++)
                for (int i = 0; i < t.nx; i++) {
                        bool a = truth_at(&t, i, j, t.c_m) >= 0.5;
                        double X[3] = { t.origin[0] + i * t.pitch - o[0], t.origin[1] + j * t.pitch - o[1],
                                        truth_at(&t, i, j, t.c_h) - o[2] };
                        double u = (X[0] * ex[0] + X[1] * ex[1] + X[2] * ex[2]) / cpitch;
                        double v = (X[0] * ey[0] + X[1] * ey[1] + X[2] * ey[2]) / cpitch;
                        long ci = lround(u), cj = lround(v);
                        bool b = isfinite(u) && isfinite(v) && ci >= 0 && cj >= 0 && ci < cimg->width &&
                                 cj < cimg->height && *(imp_image_f32(cimg, (int) ci, (int) cj) + cm) >= 0.5;
                        inter += a && b;
                        uni += a || b;
                        if (obs) {
                                bool ao = a && obs[(size_t) j * t.nx + i];
                                inter_o += ao && b;
                                uni_o += ao || b;
                        }
                }
        res->mask_iou = uni ? (double) inter / uni : 0;
        res->mask_iou_observable = !obs ? -1 : uni_o ? (double) inter_o / uni_o : 0;
}

int imp_compare_dirs(const char *copy_dir, const char *truth_dir, struct imp_compare_result *ret,
                     struct imp_error *err) {
        if (!copy_dir || !truth_dir || !ret)
                return imp_error_set(err, -EINVAL, "compare: bad arguments");
        struct imp_compare_grids g;
        int r = imp_compare_load_grids(copy_dir, truth_dir, NULL, &g, err);
        if (r < 0)
                return r;
        const double *M = g.canvas_to_world;
        const double cpitch = g.copy_pitch;
        const long long cnx = g.copy_nx, cny = g.copy_ny, tnx = g.truth_nx, tny = g.truth_ny;
        struct truth t = { .pitch = g.truth_pitch, .origin = { g.truth_origin[0], g.truth_origin[1] } };

        _cleanup_image_ struct imp_image *cimg = NULL, *timg = NULL;
        char **cnames = NULL, **tnames = NULL;
        if ((r = load_exr(copy_dir, "copy", &cimg, &cnames, err)) < 0)
                return r;
        if ((r = load_exr(truth_dir, "truth", &timg, &tnames, err)) < 0) {
                imp_strv_free(cnames);
                return r;
        }
        int ch = channel(cnames, "height", copy_dir, err), cnxc = channel(cnames, "nx", copy_dir, err),
            cnyc = channel(cnames, "ny", copy_dir, err), cm = channel(cnames, "mask", copy_dir, err);
        int csig = imp_image_channel_index(cnames, "sigma"), cfl = imp_image_channel_index(cnames, "flags");
        int csn = imp_image_channel_index(cnames, "sigma_n_deg");
        t.c_h = channel(tnames, "height", truth_dir, err), t.c_nx = channel(tnames, "nx", truth_dir, err);
        t.c_ny = channel(tnames, "ny", truth_dir, err), t.c_nz = channel(tnames, "nz", truth_dir, err);
        t.c_m = channel(tnames, "mask", truth_dir, err);
        imp_strv_free(cnames);
        imp_strv_free(tnames);
        if (ch < 0 || cnxc < 0 || cnyc < 0 || cm < 0 || t.c_h < 0 || t.c_nx < 0 || t.c_ny < 0 || t.c_nz < 0 || t.c_m < 0)
                return -EBADMSG;
        if (cimg->width != cnx || cimg->height != cny)
                return imp_error_set(err, -EBADMSG, "%s: heightfield.exr is %dx%d, copy.json says %lldx%lld",
                                     copy_dir, cimg->width, cimg->height, cnx, cny);
        if (timg->width != tnx || timg->height != tny)
                return imp_error_set(err, -EBADMSG, "%s: heightfield.exr is %dx%d, truth.json says %lldx%lld",
                                     truth_dir, timg->width, timg->height, tnx, tny);
        t.nx = timg->width, t.ny = timg->height, t.img = timg;

        struct imp_compare_result res = {};
        for (int j = 0; j < cimg->height; j++)
                for (int i = 0; i < cimg->width; i++)
                        for (int c = 0; c < cimg->channels; c++)
                                res.nan_count += !isfinite(*(imp_image_f32(cimg, i, j) + c));

        double ex[3] = { M[0], M[4], M[8] }, ey[3] = { M[1], M[5], M[9] }, ez[3] = { M[2], M[6], M[10] };
        double o[3] = { M[3], M[7], M[11] };
        size_t n_tex = (size_t) cimg->width * cimg->height;
        _cleanup_free_ double *diff = malloc((n_tex ? n_tex : 1) * sizeof(double) * 2);
        _cleanup_free_ uint8_t *filled = malloc(n_tex ? n_tex : 1);
        _cleanup_free_ float *tex_sig = malloc((n_tex ? n_tex : 1) * sizeof(float) * 4);
        double sum_ang_f = 0;
        if (!diff || !filled || !tex_sig)
                return imp_error_set(err, -ENOMEM, "compare: out of memory");
        double sum_ang = 0, sum_ang_bl = 0;
        size_t n = 0;
        _cleanup_free_ float *hs = smooth_truth(&t, CMP_BANDLIMIT_SIGMA_PITCH * cpitch / t.pitch);
        if (!hs)
                return imp_error_set(err, -ENOMEM, "compare: out of memory");
        for (int j = 0; j < cimg->height && fabs(ez[2]) >= CMP_MIN_NORMAL_Z; j++)
                for (int i = 0; i < cimg->width; i++) {
                        const float *p = imp_image_f32(cimg, i, j);
                        if (!(p[cm] >= 0.5) || !isfinite(p[ch]))
                                continue;
                        double P[3];
                        for (int q = 0; q < 3; q++)
                                P[q] = o[q] + i * cpitch * ex[q] + j * cpitch * ey[q] + p[ch] * ez[q];
                        double s;
                        if (!truth_along_normal(&t, P, ez, &s))
                                continue;
                        filled[n] = p[cm] >= 1.5;
                        diff[n_tex + n] = -s;   /* unsorted copy for the split figures */
                        diff[n++] = -s;
                        double nxv = isfinite(p[cnxc]) ? p[cnxc] : 0, nyv = isfinite(p[cnyc]) ? p[cnyc] : 0;
                        double nz = sqrt(fmax(0.0, 1 - nxv * nxv - nyv * nyv)), nw[3];
                        for (int q = 0; q < 3; q++)
                                nw[q] = nxv * ex[q] + nyv * ey[q] + nz * ez[q];
                        double tn[3], tb[3];
                        truth_normal_at(&t, NULL, P[0] + s * ez[0], P[1] + s * ez[1], tn);
                        truth_normal_at(&t, hs, P[0] + s * ez[0], P[1] + s * ez[1], tb);
                        double ang = acos(IMP_CLAMP(nw[0] * tn[0] + nw[1] * tn[1] + nw[2] * tn[2], -1.0, 1.0)) * 180.0 / M_PI;
                        sum_ang += ang;
                        sum_ang_f += filled[n - 1] ? ang : 0;
                        /* σ_h, σ_n, angle, σ_h promised; a flagged texel gets σ_h = −1, one
                         * with a height flag or filled σ_h promised = −1 */
                        bool flagged = cfl >= 0 && p[cfl] != 0;
                        bool h_excused = filled[n - 1] || (cfl >= 0 && ((unsigned) p[cfl] & HEIGHT_FLAGS));
                        float sh = csig >= 0 ? p[csig] : 0.0f;
                        tex_sig[4 * (n - 1)] = flagged ? -1.0f : sh;
                        tex_sig[4 * (n - 1) + 1] = csn >= 0 ? p[csn] : -1.0f;
                        tex_sig[4 * (n - 1) + 2] = (float) ang;
                        tex_sig[4 * (n - 1) + 3] = h_excused ? -1.0f : sh;
                        sum_ang_bl += acos(IMP_CLAMP(nw[0] * tb[0] + nw[1] * tb[1] + nw[2] * tb[2], -1.0, 1.0)) * 180.0 / M_PI;
                }
        res.n_compared = n;

        mask_iou(truth_dir, &t, cimg, cm, M, cpitch, &res);
        res.placement_deg = placement_deg(&t, ez);
        res.frame_texel_fraction = frame_texels(cimg, cm, &t, M, cpitch);

        if (n == 0) {   /* what could be computed is still reported */
                *ret = res;
                return imp_error_set(err, -ENODATA, "compare %s vs %s: no copy texel over the truth canvas: "
                                     "heights and normals not compared", copy_dir, truth_dir);
        }
        height_figures(&res, diff, filled, n, n_tex, sum_ang, sum_ang_f, sum_ang_bl);
        honesty(&res, diff + n_tex, tex_sig, n, res.height_offset_mm, csn >= 0);
        *ret = res;
        return 0;
}

/* A figure over n texels: null when there were none (not a 0 that reads as perfect). */
static json_t *figure_over(double v, size_t n) {
        return n ? json_real(v) : json_null();
}

json_t *imp_compare_result_to_json(const struct imp_compare_result *r) {
        /* mask_iou_observable and beyond_3sigma_normal are -1 when not measurable: null; the
         * figures of the filled and of the unflagged texels are null when there are none */
        return json_pack("{s:f,s:f,s:f,s:f,s:f,s:f,s:o,s:I,s:I,s:I,s:o,s:o,s:f,s:f,s:f,s:f,s:I,s:o,s:o,s:o,s:I,s:f,s:I,s:o,s:o}",
                         "height_rmse_um", r->height_rmse_um,
                         "height_offset_mm", r->height_offset_mm,
                         "height_max_abs_um", r->height_max_abs_um,
                         "normal_err_deg_mean", r->normal_err_deg_mean,
                         "normal_err_deg_mean_bandlimited", r->normal_err_deg_mean_bandlimited,
                         "mask_iou", r->mask_iou,
                         "mask_iou_observable", imp_json_figure(r->mask_iou_observable),
                         "nan_count", (json_int_t) r->nan_count,
                         "n_compared", (json_int_t) r->n_compared,
                         "n_filled", (json_int_t) r->n_filled,
                         "height_rmse_um_filled", figure_over(r->height_rmse_um_filled, r->n_filled),
                         "normal_err_deg_mean_filled", figure_over(r->normal_err_deg_mean_filled, r->n_filled),
                         "height_rmse_um_measured", r->height_rmse_um_measured,
                         "normal_err_deg_mean_measured", r->normal_err_deg_mean_measured,
                         "placement_deg", r->placement_deg, "frame_texel_fraction", r->frame_texel_fraction,
                         "n_unflagged", (json_int_t) r->n_unflagged,
                         "beyond_3sigma_height", figure_over(r->beyond_3sigma_height, r->n_unflagged),
                         "beyond_3sigma_normal", r->n_unflagged ? imp_json_figure(r->beyond_3sigma_normal) : json_null(),
                         "unflagged_normal_err_deg_max", figure_over(r->unflagged_normal_err_deg_max, r->n_unflagged),
                         "unflagged_normal_over_10deg", (json_int_t) r->unflagged_normal_over_10deg,
                         "flagged_fraction", r->flagged_fraction,
                         "n_height_promised", (json_int_t) r->n_height_promised,
                         "beyond_3sigma_height_promised",
                         figure_over(r->beyond_3sigma_height_promised, r->n_height_promised),
                         "beyond_3sigma_normal_all", imp_json_figure(r->beyond_3sigma_normal_all));
}
