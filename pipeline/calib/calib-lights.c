/* Dome light calibration: sphere silhouettes, highlight centroids, reflected rays, the
 * least-squares light position with its covariance, intensity from a white target, and
 * RTI .lp files. docs/calibration-lights.md explains the choices. */
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "calib-lights.h"
#include "macro.h"
#include "numerics.h"

#define SILHOUETTE_PROFILES 360       /* radial edge profiles per sphere */
#define SILHOUETTE_MIN_EDGES 32
#define PROFILE_STEP_PX 0.25
#define EDGE_LEVEL_OFFSET_PX 4.0      /* local levels sampled this far either side of an edge */
#define FIT_MAX_ITER 50
#define FIT_STEP_TOL_MM 1e-7
#define HIGHLIGHT_DISC_MARGIN_PX 3.0
#define HIGHLIGHT_THRESHOLD 0.2       /* blob threshold: bg + this × (peak − bg) */
#define HIGHLIGHT_MIN_SNR 10.0        /* peak − bg in units of σ_bg */
#define HIGHLIGHT_SAT_SIGMA_PX 0.25
#define HIGHLIGHT_MIN_SIGMA_PX 0.01
#define LIGHT_COND_MAX 1000.0
#define LIGHT_PRIOR_DISTANCE_MM 500.0
#define LIGHT_PRIOR_SIGMA_MM 1000.0
#define LIGHT_MIN_SIGMA_RAD 1e-7
#define RIM_SIGMA_RAD 0.1             /* a perturbed pixel ray misses the sphere: near the rim */
#define COND_CAP 1e30
#define REFERENCE_DISTANCE_MM 1000.0  /* intensity = irradiance at this distance */


static double view_get(const struct imp_frame_view *v, int x, int y, int c) {
        return imp_image_get(v->img, x, y, c);
}

/* Bilinear sample at crop coordinates (pixel centres at integers); NAN outside. */
static double bilinear(const struct imp_image *img, double x, double y) {
        int x0 = (int) floor(x), y0 = (int) floor(y);
        if (x0 < 0 || y0 < 0 || x0 + 1 >= img->width || y0 + 1 >= img->height)
                return NAN;
        double ax = x - x0, ay = y - y0;
        return (imp_image_get(img, x0, y0, 0) * (1 - ax) + imp_image_get(img, x0 + 1, y0, 0) * ax) * (1 - ay) +
               (imp_image_get(img, x0, y0 + 1, 0) * (1 - ax) + imp_image_get(img, x0 + 1, y0 + 1, 0) * ax) * ay;
}

/* ---- 3×3 symmetric helpers ---- */

/* Eigen-decomposition of a symmetric 3×3: ret_l ascending, eigenvector k in column k of
 * ret_v (row-major V[i*3+k]). */
static void eig3(const double A_in[9], double ret_l[3], double ret_v[9]) {
        double A[9];
        memcpy(A, A_in, sizeof A);
        imp_eigen_sym(3, A, ret_l, ret_v);
}

/* Inverse of a symmetric positive definite 3×3 through its eigen-decomposition. */
static void inv_sym3(const double A[9], double ret[9]) {
        double l[3], V[9];
        eig3(A, l, V);
        for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) {
                        double s = 0;
                        for (int k = 0; k < 3; k++)
                                s += V[i * 3 + k] * V[j * 3 + k] / IMP_MAX(l[k], DBL_MIN);
                        ret[i * 3 + j] = s;
                }
}

/* ---- spheres ---- */

struct edge { double px[2]; };

/* Edge crossing along one profile from outside inwards; false when none. */
static bool find_edge(const struct imp_image *img, const double c[2], double ang, double r_lo, double r_hi,
                      double thr, double *ret_r) {
        double ca = cos(ang), sa = sin(ang);
        double prev = NAN, prev_r = 0;
        for (double r = r_hi; r >= r_lo; r -= PROFILE_STEP_PX) {
                double v = bilinear(img, c[0] + r * ca, c[1] + r * sa);
                if (isnan(v)) {
                        prev = NAN;
                        continue;
                }
                if (!isnan(prev) && prev >= thr && v < thr) {
                        *ret_r = r + (prev_r - r) * (thr - v) / (prev - v);
                        return true;
                }
                prev = v;
                prev_r = r;
        }
        return false;
}

/* Edge points (full-frame pixels, image offset x0, y0) along SILHOUETTE_PROFILES radial
 * profiles from c (image coordinates) between 0.5 and 1.5 ρ: the first crossing of `thr`
 * from outside inwards, refined at the local half level (the background and the body
 * EDGE_LEVEL_OFFSET_PX either side). Returns the number found. */
static int profile_edges(const struct imp_image *img, const double c[2], double rho, double thr, int x0, int y0,
                         struct edge *edges) {
        int ne = 0;
        for (int k = 0; k < SILHOUETTE_PROFILES; k++) {
                double ang = 2 * M_PI * k / SILHOUETTE_PROFILES, r;
                if (!find_edge(img, c, ang, 0.5 * rho, 1.5 * rho, thr, &r))
                        continue;
                double ca = cos(ang), sa = sin(ang);
                double vo = bilinear(img, c[0] + (r + EDGE_LEVEL_OFFSET_PX) * ca, c[1] + (r + EDGE_LEVEL_OFFSET_PX) * sa);
                double vi = bilinear(img, c[0] + (r - EDGE_LEVEL_OFFSET_PX) * ca, c[1] + (r - EDGE_LEVEL_OFFSET_PX) * sa);
                if (isnan(vo) || isnan(vi) || !(vo > vi))
                        continue;
                double r2;
                if (!find_edge(img, c, ang, r - EDGE_LEVEL_OFFSET_PX, r + EDGE_LEVEL_OFFSET_PX, 0.5 * (vo + vi), &r2))
                        continue;
                edges[ne].px[0] = x0 + c[0] + r2 * ca;
                edges[ne].px[1] = y0 + c[1] + r2 * sa;
                ne++;
        }
        return ne;
}

static int collect_edges(const struct imp_frame_view *vw, struct edge *edges, double ret_c[2], double *ret_rho) {
        const struct imp_image *img = vw->img;
        size_t n = (size_t) img->width * img->height;
        _cleanup_free_ double *vals = malloc(n * sizeof *vals);
        if (!vals)
                return -ENOMEM;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        vals[(size_t) y * img->width + x] = view_get(vw, x, y, 0);
        qsort(vals, n, sizeof *vals, imp_cmp_double);
        double lo = vals[n / 10], hi = vals[n * 9 / 10];
        if (!(hi - lo > 0) || !isfinite(hi - lo))
                return -ENOENT;
        double thr = 0.5 * (lo + hi), sx = 0, sy = 0, cnt = 0;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++)
                        if (view_get(vw, x, y, 0) < thr) { sx += x; sy += y; cnt++; }
        if (cnt < 16)
                return -ENOENT;
        double c[2] = { sx / cnt, sy / cnt }, rho = sqrt(cnt / M_PI);
        int ne = profile_edges(img, c, rho, thr, vw->x0, vw->y0, edges);
        ret_c[0] = c[0];
        ret_c[1] = c[1];
        *ret_rho = rho;
        return ne;
}

/* Kåsa algebraic circle fit: x² + y² + D x + E y + F = 0. */
static bool circle_fit(const struct edge *e, int n, double ret_c[2], double *ret_r) {
        double M[9] = { 0 }, b[3] = { 0 }, mx = 0, my = 0;
        for (int i = 0; i < n; i++) {
                mx += e[i].px[0] / n;
                my += e[i].px[1] / n;
        }
        for (int i = 0; i < n; i++) {   /* centred coordinates keep the normal matrix well scaled */
                double x = e[i].px[0] - mx, y = e[i].px[1] - my, row[3] = { x, y, 1 }, z = -(x * x + y * y);
                for (int a = 0; a < 3; a++) {
                        b[a] += row[a] * z;
                        for (int c = 0; c < 3; c++)
                                M[a * 3 + c] += row[a] * row[c];
                }
        }
        double Mi[9], s[3];
        inv_sym3(M, Mi);
        for (int a = 0; a < 3; a++)
                s[a] = Mi[a * 3] * b[0] + Mi[a * 3 + 1] * b[1] + Mi[a * 3 + 2] * b[2];
        double a = -s[0] / 2, c = -s[1] / 2, r2 = a * a + c * c - s[2];
        if (!(r2 > 0))
                return false;
        ret_c[0] = a + mx;
        ret_c[1] = c + my;
        *ret_r = sqrt(r2);
        return true;
}

/* ---- sphere detection ---- */

struct component {
        long count;
        int xa, xb, ya, yb;
        bool border;
};

/* 8-connected component of pixels marked 1 in `lab` from seed k (marks them 2). */
static struct component flood(uint8_t *lab, int W, int H, int k, int *stack) {
        struct component c = { .xa = W, .ya = H, .xb = -1, .yb = -1 };
        int ns = 0;
        stack[ns++] = k;
        lab[k] = 2;
        while (ns > 0) {
                int q = stack[--ns], x = q % W, y = q / W;
                c.count++;
                c.xa = IMP_MIN(c.xa, x); c.xb = IMP_MAX(c.xb, x);
                c.ya = IMP_MIN(c.ya, y); c.yb = IMP_MAX(c.yb, y);
                c.border |= x == 0 || y == 0 || x == W - 1 || y == H - 1;
                for (int dy = -1; dy <= 1; dy++)
                        for (int dx = -1; dx <= 1; dx++) {
                                int xn = x + dx, yn = y + dy;
                                if (xn < 0 || yn < 0 || xn >= W || yn >= H || lab[yn * W + xn] != 1)
                                        continue;
                                lab[yn * W + xn] = 2;
                                stack[ns++] = yn * W + xn;
                        }
        }
        return c;
}

/* Robust circle: Kåsa, then passes that drop the points beyond max(3 × 1.4826 MAD, 0.5 px). */
static bool robust_circle(struct edge *e, int n, double *res, struct imp_sphere_circle *ret) {
        double c[2], r;
        for (int pass = 0; pass < 4; pass++) {
                if (n < SILHOUETTE_MIN_EDGES || !circle_fit(e, n, c, &r))
                        return false;
                for (int i = 0; i < n; i++)
                        res[i] = fabs(hypot(e[i].px[0] - c[0], e[i].px[1] - c[1]) - r);
                if (pass == 3)
                        break;
                _cleanup_free_ double *sorted = malloc((size_t) n * sizeof *sorted);
                if (!sorted)
                        return false;
                memcpy(sorted, res, (size_t) n * sizeof *sorted);
                qsort(sorted, (size_t) n, sizeof *sorted, imp_cmp_double);
                double lim = IMP_MAX(3 * 1.4826 * sorted[n / 2], 0.5);
                int m = 0;
                for (int i = 0; i < n; i++)
                        if (res[i] <= lim)
                                e[m++] = e[i];
                n = m;
        }
        double ss = 0;
        for (int i = 0; i < n; i++)
                ss += res[i] * res[i];
        *ret = (struct imp_sphere_circle) { .centre_px = { c[0], c[1] }, .radius_px = r, .rms_px = sqrt(ss / n),
                                            .n_edge = n };
        return true;
}

/* Reading order: rows of `band` pixels, then x (insertion sort, a handful of circles). */
static void sort_circles(struct imp_sphere_circle *c, int n, double band) {
        for (int i = 1; i < n; i++)
                for (int j = i; j > 0; j--) {
                        const struct imp_sphere_circle *p = &c[j - 1], *q = &c[j];
                        double rp = floor(p->centre_px[1] / band), rq = floor(q->centre_px[1] / band);
                        if (rp < rq || (rp == rq && p->centre_px[0] <= q->centre_px[0]))
                                break;
                        struct imp_sphere_circle t = c[j - 1];
                        c[j - 1] = c[j];
                        c[j] = t;
                }
}

int imp_lights_sphere_detect(const struct imp_frame_view *v, double min_radius_px, double max_radius_px,
                             struct imp_sphere_circle *ret, int max) {
        if (!v || !v->img || (max > 0 && !ret) || !(min_radius_px > 2) || !(max_radius_px >= min_radius_px))
                return -EINVAL;
        const struct imp_image *img = v->img;
        int W = img->width, H = img->height;
        size_t n = (size_t) W * H, m = 0;
        if (W < 8 || H < 8)
                return -EINVAL;
        _cleanup_free_ double *vals = malloc((n / 4 + 1) * sizeof *vals);
        _cleanup_free_ uint8_t *lab = calloc(n, 1);
        _cleanup_free_ int *stack = malloc(n * sizeof *stack);
        _cleanup_free_ struct edge *edges = calloc(SILHOUETTE_PROFILES, sizeof *edges);
        _cleanup_free_ double *res = calloc(SILHOUETTE_PROFILES, sizeof *res);
        if (!vals || !lab || !stack || !edges || !res)
                return -ENOMEM;
        for (size_t k = 0; k < n; k += 4) {   /* every 4th pixel is plenty for two percentiles */
                double val = view_get(v, (int) (k % W), (int) (k / W), 0);
                if (isfinite(val))
                        vals[m++] = val;
        }
        if (m < 16)
                return 0;
        qsort(vals, m, sizeof *vals, imp_cmp_double);
        double thr = 0.5 * (vals[m / 20] + vals[m * 19 / 20]);
        if (!(vals[m * 19 / 20] > vals[m / 20]))
                return 0;
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        lab[(size_t) y * W + x] = view_get(v, x, y, 0) < thr;   /* NaN: not dark */
        int found = 0;
        for (size_t k = 0; k < n; k++) {
                if (lab[k] != 1)
                        continue;
                struct component c = flood(lab, W, H, (int) k, stack);
                double rb = 0.25 * (c.xb - c.xa + 1 + c.yb - c.ya + 1);
                /* a disc fills π/4 of its box: a ring, a line or a shadow's sliver does not */
                if (c.border || rb < min_radius_px || rb > max_radius_px || c.count < 0.6 * M_PI * rb * rb)
                        continue;
                double cc[2] = { 0.5 * (c.xa + c.xb), 0.5 * (c.ya + c.yb) };
                int ne = profile_edges(img, cc, rb, thr, v->x0, v->y0, edges);
                struct imp_sphere_circle circ;
                if (ne < 0.7 * SILHOUETTE_PROFILES || !robust_circle(edges, ne, res, &circ) ||
                    circ.n_edge < 0.7 * SILHOUETTE_PROFILES || !(circ.rms_px < 0.1 * circ.radius_px) ||
                    circ.radius_px < min_radius_px || circ.radius_px > max_radius_px)
                        continue;
                if (found < max)
                        ret[found] = circ;
                found++;
        }
        if (ret)
                sort_circles(ret, IMP_MIN(found, max), 0.25 * H);
        return found;
}

/* Residual and Jacobian (in C) of one edge ray (origin O, unit direction d) for a sphere of
 * radius r at C: tangency dist(C, ray) − r, or for a sphere cut at C_z + cut (finite) whose
 * closest ray point lies below the cut, the rim's: |crossing of the cut plane − C|_xy − a. */
static double edge_residual(const double O[3], const double d[3], const double C[3], double r, double cut,
                            double J[3]) {
        double w[3] = { C[0] - O[0], C[1] - O[1], C[2] - O[2] }, s = imp_dot3(w, d), u[3];
        for (int k = 0; k < 3; k++)
                u[k] = w[k] - s * d[k];   /* from the closest ray point to C */
        if (isfinite(cut) && u[2] > -cut && fabs(d[2]) > 1e-12) {
                double t = (w[2] + cut) / d[2], e[2] = { O[0] + t * d[0] - C[0], O[1] + t * d[1] - C[1] };
                double l = hypot(e[0], e[1]);
                if (l > 0) {
                        J[0] = -e[0] / l;
                        J[1] = -e[1] / l;
                        J[2] = (e[0] * d[0] + e[1] * d[1]) / (l * d[2]);
                        return l - sqrt(IMP_MAX(r * r - cut * cut, 0.0));
                }
        }
        double dist = imp_norm3(u);
        for (int k = 0; k < 3; k++)
                J[k] = dist > 0 ? u[k] / dist : 0;
        return dist - r;
}

/* Gauss–Newton on the edge residuals; np = 2 holds C_z. ret_cov: the centre's covariance
 * (JᵀJ)⁻¹ · rms² at the solution (zz = 0 when C_z is held), ret_sigma: its √λmax. */
static int fit_centre(const double (*d)[3], int n, const double O[3], double r, int np, double cut, double C[3],
                      double *ret_rms, double *ret_sigma, double ret_cov[9]) {
        for (int it = 0; it < FIT_MAX_ITER; it++) {
                double JtJ[9] = { 0 }, Jtr[3] = { 0 }, ss = 0;
                for (int i = 0; i < n; i++) {
                        double J[3], res = edge_residual(O, d[i], C, r, cut, J);
                        if (np == 2)
                                J[2] = 0;
                        for (int a = 0; a < 3; a++) {
                                Jtr[a] += J[a] * res;
                                for (int b = 0; b < 3; b++)
                                        JtJ[a * 3 + b] += J[a] * J[b];
                        }
                        ss += res * res;
                }
                if (np == 2)
                        JtJ[8] = 1;
                double Ji[9], step[3], sn = 0;
                inv_sym3(JtJ, Ji);
                for (int a = 0; a < 3; a++) {
                        step[a] = -(Ji[a * 3] * Jtr[0] + Ji[a * 3 + 1] * Jtr[1] + Ji[a * 3 + 2] * Jtr[2]);
                        C[a] += step[a];
                        sn += step[a] * step[a];
                }
                *ret_rms = sqrt(ss / n);
                if (!isfinite(sn))
                        return -EDOM;
                if (sqrt(sn) < FIT_STEP_TOL_MM) {
                        if (np == 2)
                                Ji[8] = 0;
                        double l[3], V[9], s2 = ss / IMP_MAX(n - np, 1);
                        eig3(Ji, l, V);
                        *ret_sigma = sqrt(IMP_MAX(l[2], 0.0) * s2);
                        for (int k = 0; k < 9; k++)
                                ret_cov[k] = Ji[k] * s2;
                        return 0;
                }
        }
        return -EDOM;
}

int imp_lights_sphere_fit(const struct imp_pinhole *cam, const struct imp_frame_view *v, double radius_mm,
                          double centre_z_mm, double cut_mm, struct imp_sphere *ret, struct imp_error *err) {
        if (!cam || !v || !v->img || !ret || !(radius_mm > 0) || v->img->width < 8 || v->img->height < 8)
                return imp_error_set(err, -EINVAL, "sphere fit: bad arguments");
        _cleanup_free_ struct edge *edges = calloc(SILHOUETTE_PROFILES, sizeof *edges);
        _cleanup_free_ double (*dirs)[3] = calloc(SILHOUETTE_PROFILES, sizeof *dirs);
        if (!edges || !dirs)
                return imp_error_set(err, -ENOMEM, "sphere fit: out of memory");
        double c0[2], rho0;
        int ne = collect_edges(v, edges, c0, &rho0);
        if (ne == -ENOENT)
                return imp_error_set(err, -ENOENT, "sphere fit: no dark silhouette in the %dx%d view at (%d, %d)",
                                     v->img->width, v->img->height, v->x0, v->y0);
        if (ne < 0)
                return imp_error_set(err, ne, "sphere fit: out of memory");
        if (ne < SILHOUETTE_MIN_EDGES)
                return imp_error_set(err, -EDOM, "sphere fit: only %d silhouette edge points (need %d)", ne,
                                     SILHOUETTE_MIN_EDGES);
        /* edge points of something else in the view (a neighbour, a dark mark) are outliers */
        _cleanup_free_ double *res = calloc(SILHOUETTE_PROFILES, sizeof *res);
        struct imp_sphere_circle circ;
        if (!res)
                return imp_error_set(err, -ENOMEM, "sphere fit: out of memory");
        if (!robust_circle(edges, ne, res, &circ))
                return imp_error_set(err, -EDOM, "sphere fit: the silhouette edge is not a circle");
        ne = circ.n_edge;
        double cc[2] = { circ.centre_px[0], circ.centre_px[1] }, rho = circ.radius_px;
        double O[3], d0[3];
        for (int i = 0; i < ne; i++)
                imp_pinhole_ray_world(cam, edges[i].px, O, dirs[i]);
        imp_pinhole_ray_world(cam, cc, O, d0);
        double C[3], s;
        bool on_plane = isfinite(centre_z_mm);
        if (on_plane && fabs(d0[2]) > 1e-9)
                s = (centre_z_mm - O[2]) / d0[2];
        else
                s = radius_mm * 0.5 * (cam->fx + cam->fy) / rho;
        for (int k = 0; k < 3; k++)
                C[k] = O[k] + s * d0[k];
        double rms = 0, csig = 0, ccov[9] = { 0 };
        int r = fit_centre((const double (*)[3]) dirs, ne, O, radius_mm, on_plane ? 2 : 3, cut_mm, C, &rms, &csig, ccov);
        if (r < 0 || !isfinite(C[0] + C[1] + C[2]))
                return imp_error_set(err, -EDOM, "sphere fit: the centre fit did not converge");
        struct imp_sphere out = { .radius_mm = radius_mm, .n_edge = ne, .centre_sigma_mm = csig, .cut_mm = cut_mm,
                                  .centre_z_held = on_plane };
        memcpy(out.centre_mm, C, sizeof C);
        memcpy(out.centre_cov_mm2, ccov, sizeof ccov);
        /* a cut sphere's outline is mostly its rim: the image disc is centred on the rim's centre */
        double Cv[3] = { C[0], C[1], C[2] + (isfinite(cut_mm) ? cut_mm : 0) };
        if (!imp_pinhole_project(cam, Cv, out.image_centre_px))
                return imp_error_set(err, -EDOM, "sphere fit: the sphere lies behind the camera");
        double sr = 0, se = 0;
        for (int i = 0; i < ne; i++)
                sr += hypot(edges[i].px[0] - out.image_centre_px[0], edges[i].px[1] - out.image_centre_px[1]);
        out.image_radius_px = sr / ne;
        /* the edge residual in pixels: tangency error (mm) over the mm per pixel at the sphere */
        double mm_per_px = (isfinite(cut_mm) ? sqrt(IMP_MAX(radius_mm * radius_mm - cut_mm * cut_mm, 1e-12)) : radius_mm) /
                           out.image_radius_px;
        se = rms / mm_per_px;
        out.rms_px = se;
        *ret = out;
        return 0;
}

/* ---- highlights ---- */

int imp_lights_highlight(const struct imp_frame_view *v, const struct imp_sphere *s, double saturation,
                         struct imp_highlight *ret) {
        if (!v || !v->img || !s || !ret || !(s->image_radius_px > HIGHLIGHT_DISC_MARGIN_PX + 1))
                return -EINVAL;
        const struct imp_image *img = v->img;
        int W = img->width, H = img->height;
        double cx = s->image_centre_px[0] - v->x0, cy = s->image_centre_px[1] - v->y0;
        double rr = s->image_radius_px - HIGHLIGHT_DISC_MARGIN_PX;
        int xa = IMP_MAX(0, (int) floor(cx - rr)), xb = IMP_MIN(W - 1, (int) ceil(cx + rr));
        int ya = IMP_MAX(0, (int) floor(cy - rr)), yb = IMP_MIN(H - 1, (int) ceil(cy + rr));
        if (xa > xb || ya > yb)
                return -EINVAL;
        size_t cap = (size_t) (xb - xa + 1) * (yb - ya + 1);
        _cleanup_free_ double *vals = malloc(cap * sizeof *vals);
        _cleanup_free_ uint8_t *mask = calloc(cap, 1);     /* 1 in disc, 2 visited */
        _cleanup_free_ int *stack = malloc(cap * sizeof *stack);
        if (!vals || !mask || !stack)
                return -ENOMEM;
        int bw = xb - xa + 1;
        size_t n = 0;
        double peak = -INFINITY;
        int pk = -1;
        for (int y = ya; y <= yb; y++)
                for (int x = xa; x <= xb; x++) {
                        if ((x - cx) * (x - cx) + (y - cy) * (y - cy) > rr * rr)
                                continue;
                        double val = view_get(v, x, y, 0);
                        if (!isfinite(val))
                                continue;
                        int k = (y - ya) * bw + (x - xa);
                        mask[k] = 1;
                        vals[n++] = val;
                        if (val > peak) { peak = val; pk = k; }
                }
        if (n < 16 || pk < 0)
                return -ENOENT;
        qsort(vals, n, sizeof *vals, imp_cmp_double);
        double bg = vals[n / 2];
        for (size_t i = 0; i < n; i++)
                vals[i] = fabs(vals[i] - bg);
        qsort(vals, n, sizeof *vals, imp_cmp_double);
        double sigma_bg = 1.4826 * vals[n / 2];
        double top = IMP_MIN(peak, saturation);
        if (!(top - bg > HIGHLIGHT_MIN_SNR * sigma_bg) || !(top > bg))
                return -ENOENT;
        double thr = bg + HIGHLIGHT_THRESHOLD * (top - bg);
        /* 4-connected flood fill of the blob around the peak */
        double sw = 0, sx = 0, sy = 0;
        int ns = 0, np = 0;
        bool sat = false;
        stack[ns++] = pk;
        mask[pk] = 2;
        while (ns > 0) {
                int k = stack[--ns], x = xa + k % bw, y = ya + k / bw;
                double val = view_get(v, x, y, 0);
                sat |= val >= saturation;
                double w = IMP_MIN(val, saturation) - thr;
                sw += w; sx += w * x; sy += w * y;
                np++;
                const int nb[4][2] = { { 1, 0 }, { -1, 0 }, { 0, 1 }, { 0, -1 } };
                for (int j = 0; j < 4; j++) {
                        int xn = x + nb[j][0], yn = y + nb[j][1];
                        if (xn < xa || xn > xb || yn < ya || yn > yb)
                                continue;
                        int kn = (yn - ya) * bw + (xn - xa);
                        if (mask[kn] != 1 || !(view_get(v, xn, yn, 0) > thr))
                                continue;
                        mask[kn] = 2;
                        stack[ns++] = kn;
                }
        }
        if (!(sw > 0))
                return -ENOENT;
        double mx = sx / sw, my = sy / sw, sig;
        if (sat) {
                sig = IMP_MAX(HIGHLIGHT_SAT_SIGMA_PX, 0.5 / sqrt(np));
        } else {
                /* second pass over the blob pixels (mask 2) for the noise propagation */
                double qx = 0, qy = 0;
                for (int k = 0; k < (int) cap; k++)
                        if (mask[k] == 2) {
                                double x = xa + k % bw, y = ya + k / bw;
                                qx += (x - mx) * (x - mx);
                                qy += (y - my) * (y - my);
                        }
                sig = IMP_MAX(HIGHLIGHT_MIN_SIGMA_PX, sigma_bg * sqrt(IMP_MAX(qx, qy)) / sw);
        }
        *ret = (struct imp_highlight) { .px = { mx + v->x0, my + v->y0 }, .sigma_px = sig, .peak = peak,
                                        .n_pixels = np, .saturated = sat };
        return 0;
}

/* ---- reflection ---- */

bool imp_lights_reflect_ray(const double O[3], const double u[3], const double C[3], double r, double P[3],
                            double d[3]) {
        double w[3] = { O[0] - C[0], O[1] - C[1], O[2] - C[2] };
        double b = imp_dot3(w, u), c = imp_dot3(w, w) - r * r, disc = b * b - c;
        if (!(disc >= 0))
                return false;
        double t = -b - sqrt(disc), n[3];
        for (int k = 0; k < 3; k++) {
                P[k] = O[k] + t * u[k];
                n[k] = (P[k] - C[k]) / r;
        }
        double un = imp_dot3(u, n);
        for (int k = 0; k < 3; k++)
                d[k] = u[k] - 2 * un * n[k];
        double l = imp_norm3(d);
        for (int k = 0; k < 3; k++)
                d[k] /= l;
        return true;
}

static bool reflect_px(const struct imp_pinhole *cam, const struct imp_sphere *s, const double px[2],
                       double P[3], double dr[3]) {
        double O[3], d[3];
        imp_pinhole_ray_world(cam, px, O, d);
        return imp_lights_reflect_ray(O, d, s->centre_mm, s->radius_mm, P, dr);
}

int imp_lights_reflect(const struct imp_pinhole *cam, const struct imp_sphere *s, const double px[2],
                       double sigma_px, double ret_origin[3], double ret_dir[3], double *ret_sigma_rad) {
        if (!cam || !s || !px || !ret_origin || !ret_dir || !(s->radius_mm > 0))
                return -EINVAL;
        double P[3], d[3];
        if (!reflect_px(cam, s, px, P, d))
                return -EDOM;
        if (ret_sigma_rad) {
                double h = sigma_px > 0 ? sigma_px : HIGHLIGHT_MIN_SIGMA_PX, acc = 0;
                for (int a = 0; a < 2; a++) {
                        double q[2] = { px[0] + (a == 0) * h, px[1] + (a == 1) * h }, Pq[3], dq[3];
                        double ang = RIM_SIGMA_RAD;
                        if (reflect_px(cam, s, q, Pq, dq))
                                ang = acos(IMP_CLAMP(imp_dot3(d, dq), -1.0, 1.0));
                        acc += ang * ang;
                }
                double sc = 2 * IMP_MAX(s->centre_sigma_mm, 0.0) / s->radius_mm;
                *ret_sigma_rad = sqrt(acc / 2 + sc * sc);
        }
        memcpy(ret_origin, P, sizeof P);
        memcpy(ret_dir, d, sizeof d);
        return 0;
}

/* ---- triangulation ---- */

int imp_lights_triangulate(int n, const double (*o)[3], const double (*d)[3], const double *sigma_rad,
                           const struct imp_light_fit_opts *opts, struct imp_light_estimate *ret) {
        if (n < 1 || !o || !d || !ret)
                return -EINVAL;
        double cond_max = opts && opts->cond_max > 0 ? opts->cond_max : LIGHT_COND_MAX;
        double pd = opts && opts->prior_distance_mm > 0 ? opts->prior_distance_mm : LIGHT_PRIOR_DISTANCE_MM;
        double ps = opts && opts->prior_sigma_mm > 0 ? opts->prior_sigma_mm : LIGHT_PRIOR_SIGMA_MM;
        _cleanup_free_ double (*u)[3] = calloc(n, sizeof *u);
        _cleanup_free_ double *slat = calloc(n, sizeof *slat);
        if (!u || !slat)
                return -ENOMEM;
        double mo[3] = { 0 }, md[3] = { 0 };
        for (int i = 0; i < n; i++) {
                double l = imp_norm3(d[i]);
                if (!isfinite(l + o[i][0] + o[i][1] + o[i][2]) || !(l > 0))
                        return -EINVAL;
                if (sigma_rad && !isfinite(sigma_rad[i]))
                        return -EINVAL;
                for (int k = 0; k < 3; k++) {
                        u[i][k] = d[i][k] / l;
                        mo[k] += o[i][k] / n;
                        md[k] += u[i][k];
                }
        }
        double ml = imp_norm3(md), Xp[3];
        for (int k = 0; k < 3; k++)
                Xp[k] = mo[k] + (ml > 1e-9 ? pd * md[k] / ml : 0);
        double X[3], A[9], Ap[9], cov[9];
        for (int i = 0; i < n; i++)
                slat[i] = IMP_MAX(sigma_rad ? sigma_rad[i] : 0, LIGHT_MIN_SIGMA_RAD) * pd;
        for (int pass = 0; pass < 3; pass++) {
                double b[3] = { 0 };
                memset(A, 0, sizeof A);
                for (int i = 0; i < n; i++) {
                        double w = 1 / (slat[i] * slat[i]);
                        for (int a = 0; a < 3; a++)
                                for (int c = 0; c < 3; c++) {
                                        double P = (a == c) - u[i][a] * u[i][c];
                                        A[a * 3 + c] += w * P;
                                        b[a] += w * P * o[i][c];
                                }
                }
                memcpy(Ap, A, sizeof A);
                for (int a = 0; a < 3; a++) {
                        Ap[a * 4] += 1 / (ps * ps);
                        b[a] += Xp[a] / (ps * ps);
                }
                inv_sym3(Ap, cov);
                for (int a = 0; a < 3; a++)
                        X[a] = cov[a * 3] * b[0] + cov[a * 3 + 1] * b[1] + cov[a * 3 + 2] * b[2];
                for (int i = 0; i < n; i++) {
                        double w[3] = { X[0] - o[i][0], X[1] - o[i][1], X[2] - o[i][2] };
                        slat[i] = IMP_MAX(sigma_rad ? sigma_rad[i] : 0, LIGHT_MIN_SIGMA_RAD) * IMP_MAX(imp_norm3(w), 1.0);
                }
        }
        unsigned flags = n < 2 ? IMP_LIGHT_FEW_RAYS : 0;
        double chi2 = 0, ss = 0;
        for (int i = 0; i < n; i++) {
                double w[3] = { X[0] - o[i][0], X[1] - o[i][1], X[2] - o[i][2] }, s = imp_dot3(w, u[i]), e2 = 0;
                if (s < 0)
                        flags |= IMP_LIGHT_BEHIND;
                for (int k = 0; k < 3; k++)
                        e2 += (w[k] - s * u[i][k]) * (w[k] - s * u[i][k]);
                ss += e2;
                chi2 += e2 / (slat[i] * slat[i]);
        }
        int dof = 2 * n - 3;
        double scale = dof > 0 ? IMP_MAX(1.0, chi2 / dof) : 1.0;
        for (int k = 0; k < 9; k++)
                cov[k] *= scale;
        double l[3], V[9];
        eig3(A, l, V);
        double cond = l[0] > l[2] / COND_CAP ? l[2] / l[0] : COND_CAP;
        if (cond > cond_max) {
                flags |= IMP_LIGHT_ILL_CONDITIONED;
                /* the data do not pin these directions down: their uncertainty is the prior's */
                for (int k = 0; k < 3; k++)
                        if (!(l[k] * cond_max > l[2]))
                                for (int a = 0; a < 3; a++)
                                        for (int c = 0; c < 3; c++)
                                                cov[a * 3 + c] += ps * ps * V[a * 3 + k] * V[c * 3 + k];
        }
        double cl[3], cV[9];
        eig3(cov, cl, cV);
        struct imp_light_estimate out = { .sigma_mm = sqrt(IMP_MAX(cl[2], 0.0)), .cond = cond,
                                          .rms_mm = sqrt(ss / n), .n_rays = n, .flags = flags };
        memcpy(out.pos_mm, X, sizeof X);
        memcpy(out.cov_mm2, cov, sizeof cov);
        *ret = out;
        return 0;
}

/* ---- intensity ---- */

int imp_lights_intensity(const struct imp_pinhole *cam, const struct imp_frame_view *v, double plane_z_mm,
                         const double pos_mm[3], const double *axis, double profile_exp,
                         struct imp_light_intensity *ret) {
        if (!cam || !v || !v->img || !pos_mm || !ret || !isfinite(plane_z_mm))
                return -EINVAL;
        const struct imp_image *img = v->img;
        int nch = img->channels >= 3 ? 3 : 1;
        double sum[3] = { 0 }, s1 = 0, s2 = 0;
        long cnt = 0;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        double px[2] = { v->x0 + x, v->y0 + y }, O[3], d[3], val[3];
                        bool ok = true;
                        for (int c = 0; c < nch; c++) {
                                val[c] = imp_image_get(img, x, y, c);
                                ok &= isfinite(val[c]) && val[c] > 0;
                        }
                        if (!ok)
                                continue;
                        imp_pinhole_ray_world(cam, px, O, d);
                        if (!(fabs(d[2]) > 1e-12))
                                continue;
                        double t = (plane_z_mm - O[2]) / d[2];
                        if (!(t > 0))
                                continue;
                        double l[3] = { pos_mm[0] - O[0] - t * d[0], pos_mm[1] - O[1] - t * d[1], pos_mm[2] - O[2] - t * d[2] };
                        double dist = imp_norm3(l), cosl = l[2] / dist, f = 1;
                        if (!(cosl > 0))
                                continue;
                        if (axis && profile_exp > 0) {
                                double ca = -imp_dot3(l, axis) / (dist * imp_norm3(axis));
                                if (!(ca > 0))
                                        continue;
                                f = pow(ca, profile_exp);
                        }
                        double k = dist / REFERENCE_DISTANCE_MM, g = k * k / (cosl * f), m = 0;
                        for (int c = 0; c < nch; c++) {
                                sum[c] += val[c] * g;
                                m += val[c] * g / nch;
                        }
                        s1 += m;
                        s2 += m * m;
                        cnt++;
                }
        if (cnt == 0)
                return -ENOENT;
        struct imp_light_intensity out = { .n_pixels = (int) IMP_MIN(cnt, (long) INT32_MAX) };
        double mean = s1 / cnt, var = IMP_MAX(s2 / cnt - mean * mean, 0.0);
        out.intensity = mean;
        out.rel_sigma = mean > 0 ? sqrt(var / cnt) / mean : INFINITY;
        for (int c = 0; c < 3; c++)
                out.colour[c] = nch == 3 && mean > 0 ? sum[c] / cnt / mean : 1.0;
        if (!isfinite(out.rel_sigma))
                out.rel_sigma = 1.0;
        *ret = out;
        return 0;
}

/* ---- .lp files ---- */

#define LP_NEAR_FIELD_TAG "# impasto near-field mm"

int imp_lights_lp_write(const char *path, int n, const struct imp_rig_light *lights, const char *const *names,
                        const double centre_mm[3], bool near_field, struct imp_error *err) {
        if (!path || n < 0 || (n > 0 && !lights))
                return imp_error_set(err, -EINVAL, "lp write: bad arguments");
        char tmp[4096];
        if (snprintf(tmp, sizeof tmp, "%s.tmp", path) >= (int) sizeof tmp)
                return imp_error_set(err, -ENAMETOOLONG, "%s: path too long", path);
        FILE *f = fopen(tmp, "w");
        if (!f)
                return imp_error_set(err, -errno, "%s: cannot write: %s", tmp, strerror(errno));
        fprintf(f, near_field ? "%d " LP_NEAR_FIELD_TAG "\n" : "%d\n", n);
        for (int i = 0; i < n; i++) {
                char def[32];
                snprintf(def, sizeof def, "light_%03d.png", lights[i].id);
                const char *nm = names && names[i] ? names[i] : def;
                double p[3];
                for (int k = 0; k < 3; k++)
                        p[k] = lights[i].pos_mm[k] - (near_field || !centre_mm ? 0 : centre_mm[k]);
                if (!near_field) {
                        double l = imp_norm3(p);
                        for (int k = 0; k < 3; k++)
                                p[k] = l > 0 ? p[k] / l : 0;
                }
                fprintf(f, "%s %.9f %.9f %.9f\n", nm, p[0], p[1], p[2]);
        }
        bool bad = ferror(f);
        if (fclose(f) != 0 || bad) {
                unlink(tmp);
                return imp_error_set(err, -EIO, "%s: write failed", tmp);
        }
        if (rename(tmp, path) < 0) {
                int e = errno;
                unlink(tmp);
                return imp_error_set(err, -e, "%s: cannot rename: %s", path, strerror(e));
        }
        return 0;
}

int imp_lights_lp_read(const char *path, const double centre_mm[3], double radius_mm, int *ret_n,
                       struct imp_rig_light **ret_lights, char ***ret_names, bool *ret_near_field,
                       struct imp_error *err) {
        if (!path || !ret_n || !ret_lights)
                return imp_error_set(err, -EINVAL, "lp read: bad arguments");
        _cleanup_fclose_ FILE *f = fopen(path, "r");
        if (!f)
                return imp_error_set(err, -errno, "%s: cannot open: %s", path, strerror(errno));
        char line[4096];
        int lineno = 1, n;
        if (!fgets(line, sizeof line, f))
                return imp_error_set(err, -EBADMSG, "%s:1: empty file, expected the light count", path);
        char *end;
        long ln = strtol(line, &end, 10);
        if (end == line || ln < 1 || ln > 100000)
                return imp_error_set(err, -EBADMSG, "%s:1: expected a light count (1..100000)", path);
        n = (int) ln;
        bool near = strstr(end, "near-field") != NULL;
        _cleanup_free_ struct imp_rig_light *L = calloc(n, sizeof *L);
        char **names = calloc(n + 1, sizeof *names);
        if (!L || !names) {
                free(names);
                return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        }
        int r = 0;
        for (int i = 0; i < n; i++) {
                lineno++;
                char nm[1024];
                double p[3];
                if (!fgets(line, sizeof line, f)) {
                        r = imp_error_set(err, -EBADMSG, "%s:%d: expected %d lights, the file ends after %d", path,
                                          lineno, n, i);
                        break;
                }
                if (sscanf(line, "%1023s %lf %lf %lf", nm, &p[0], &p[1], &p[2]) != 4 ||
                    !isfinite(p[0] + p[1] + p[2])) {
                        r = imp_error_set(err, -EBADMSG, "%s:%d: expected \"filename x y z\"", path, lineno);
                        break;
                }
                if (!near) {
                        double l = imp_norm3(p);
                        if (!(l > 1e-9)) {
                                r = imp_error_set(err, -EBADMSG, "%s:%d: zero direction", path, lineno);
                                break;
                        }
                        for (int k = 0; k < 3; k++)
                                p[k] = (centre_mm ? centre_mm[k] : 0) + radius_mm * p[k] / l;
                }
                L[i] = (struct imp_rig_light) { .id = i, .pos_mm = { p[0], p[1], p[2] }, .intensity = 1,
                                                .colour = { 1, 1, 1 } };
                if (!(names[i] = strdup(nm))) {
                        r = imp_error_set(err, -ENOMEM, "%s: out of memory", path);
                        break;
                }
        }
        if (r < 0) {
                imp_strv_free(names);
                return r;
        }
        *ret_n = n;
        *ret_lights = TAKE_PTR(L);
        if (ret_names)
                *ret_names = names;
        else
                imp_strv_free(names);
        if (ret_near_field)
                *ret_near_field = near;
        return 0;
}
