/* Procedural painting relief: canvas weave, brush strokes, palette-knife ridges with a
 * steep cliff, craquelure, test steps, heightfields from files, tilted planes (calibration
 * targets), mirror spheres; region shapes (incl. a printed chessboard) and value noise for the BRDF map. Deterministic in the layer seeds; no allocation per sample. */
#include <math.h>
#include <string.h>
#include "image.h"
#include "scene.h"

static inline double hash01(uint64_t seed, int64_t a, int64_t b) {
        return imp_u01(imp_mix64(seed ^ imp_mix64((uint64_t) a * 0x9E3779B1ull ^ ((uint64_t) b << 32))));
}

static inline double smooth(double t) { return t * t * (3 - 2 * t); }

double imp_value_noise(uint64_t seed, double x_mm, double y_mm, double scale_mm) {
        double sum = 0, amp = 1, norm = 0;
        for (int oct = 0; oct < 2; oct++) {
                double fx = x_mm / scale_mm, fy = y_mm / scale_mm;
                double x0 = floor(fx), y0 = floor(fy);
                double ax = smooth(fx - x0), ay = smooth(fy - y0);
                int64_t ix = (int64_t) x0, iy = (int64_t) y0;
                uint64_t sd = seed + (uint64_t) oct * 7919;
                double a = hash01(sd, ix, iy), b = hash01(sd, ix + 1, iy);
                double c = hash01(sd, ix, iy + 1), d = hash01(sd, ix + 1, iy + 1);
                double v = (a * (1 - ax) + b * ax) * (1 - ay) + (c * (1 - ax) + d * ax) * ay;
                sum += amp * (2 * v - 1);
                norm += amp;
                amp *= 0.5;
                scale_mm *= 0.5;
        }
        return sum / norm;
}

bool imp_shape_contains(const struct imp_shape *sh, double x, double y) {
        switch (sh->kind) {
        case IMP_SHAPE_ALL:
                return true;
        case IMP_SHAPE_BLOB: {
                double dx = x - sh->centre_mm[0], dy = y - sh->centre_mm[1];
                double r2 = dx * dx + dy * dy;
                double rmax = sh->radius_mm * (1 + fabs(sh->wobble));
                if (r2 > rmax * rmax)
                        return false;
                double th = atan2(dy, dx);
                double p1 = 6.2831853 * imp_u01(imp_mix64(sh->seed + 1));
                double p2 = 6.2831853 * imp_u01(imp_mix64(sh->seed + 2));
                double p3 = 6.2831853 * imp_u01(imp_mix64(sh->seed + 3));
                double r = sh->radius_mm * (1 + sh->wobble * (0.5 * sin(3 * th + p1) + 0.3 * sin(5 * th + p2) +
                                                              0.2 * sin(7 * th + p3)));
                return r2 <= r * r;
        }
        case IMP_SHAPE_STRIPE: {
                double nxv = -sin(sh->angle_rad), nyv = cos(sh->angle_rad);
                double d = (x - sh->centre_mm[0]) * nxv + (y - sh->centre_mm[1]) * nyv;
                return fabs(d) <= 0.5 * sh->width_mm;
        }
        case IMP_SHAPE_DISC: {
                double dx = x - sh->centre_mm[0], dy = y - sh->centre_mm[1];
                return dx * dx + dy * dy <= sh->radius_mm * sh->radius_mm;
        }
        case IMP_SHAPE_RECT:
                return x >= sh->min_mm[0] && x <= sh->max_mm[0] && y >= sh->min_mm[1] && y <= sh->max_mm[1];
        case IMP_SHAPE_CHECKER: {
                const struct imp_checker *ck = &sh->checker;
                double uv[2];
                imp_checker_board_uv(ck, x, y, uv);
                double s = ck->square_mm;
                return uv[0] >= -2 * s && uv[0] <= (ck->cols + 1) * s && uv[1] >= -2 * s &&
                       uv[1] <= (ck->rows + 1) * s;
        }
        }
        return false;
}

/* The plane's orthonormal frame: e1 along x lifted onto the plane, n the normal out of the
 * paint, e2 = n × e1. */
static void checker_frame(const struct imp_checker *ck, double e1[3], double e2[3]) {
        double a = ck->slope[0], b = ck->slope[1];
        double l1 = sqrt(1 + a * a), ln = sqrt(1 + a * a + b * b);
        double n[3] = { -a / ln, -b / ln, 1 / ln };
        e1[0] = 1 / l1; e1[1] = 0; e1[2] = a / l1;
        e2[0] = n[1] * e1[2] - n[2] * e1[1];
        e2[1] = n[2] * e1[0] - n[0] * e1[2];
        e2[2] = n[0] * e1[1] - n[1] * e1[0];
}

void imp_checker_board_uv(const struct imp_checker *ck, double x, double y, double ret_uv[2]) {
        double e1[3], e2[3];
        checker_frame(ck, e1, e2);
        double dx = x - ck->origin_mm[0], dy = y - ck->origin_mm[1];
        double d[3] = { dx, dy, ck->slope[0] * dx + ck->slope[1] * dy };
        double u = d[0] * e1[0] + d[1] * e1[1] + d[2] * e1[2];
        double v = d[0] * e2[0] + d[1] * e2[1] + d[2] * e2[2];
        double c = cos(ck->angle_rad), sn = sin(ck->angle_rad);
        ret_uv[0] = c * u + sn * v;
        ret_uv[1] = -sn * u + c * v;
}

/* Length of [0, t] (signed) covered by even-indexed squares [2k·s, (2k+1)·s). */
static double even_cover(double t, double s) {
        double k = floor(t / (2 * s));
        return k * s + IMP_MIN(t - 2 * k * s, s);
}

/* Parts of [c − h, c + h] ∩ [lo, hi] in even and odd squares, as fractions of 2h. */
static void cover_1d(double c, double h, double s, double lo, double hi, double *ret_even, double *ret_odd) {
        double a = IMP_CLAMP(c - h, lo, hi), b = IMP_CLAMP(c + h, lo, hi);
        double ev = even_cover(b, s) - even_cover(a, s);
        *ret_even = ev / (2 * h);
        *ret_odd = (b - a - ev) / (2 * h);
}

double imp_checker_black_fraction(const struct imp_checker *ck, double u, double v, double box_mm) {
        double s = ck->square_mm, h = 0.5 * box_mm, ex, ox, ey, oy;
        cover_1d(u, h, s, -s, ck->cols * s, &ex, &ox);
        cover_1d(v, h, s, -s, ck->rows * s, &ey, &oy);
        return IMP_CLAMP(ex * ey + ox * oy, 0.0, 1.0);   /* black where i + j is even */
}

/* Where the sampled surface lies on the painting: painting (x, y) = R(θ)·(x, y) + offset,
 * (x, y) where the sample sits (imp_sim_surface_sample_xy), and the canvas in the painting
 * frame. Identity for a scene that samples its whole canvas and for a tile's window on the
 * painting's own lattice (a placed surface); else as `place` says. */
struct grid {
        const struct imp_sim_surface *s;
        double c, sn, t[2];
        double cmin[2], cmax[2];
};

static struct grid grid_of(const struct imp_sim_surface *s, const struct imp_painting_place *pl) {
        if (!pl)
                return (struct grid) { .s = s, .c = 1, .cmin = { s->canvas_min_mm[0], s->canvas_min_mm[1] },
                                       .cmax = { s->canvas_max_mm[0], s->canvas_max_mm[1] } };
        return (struct grid) { .s = s, .c = cos(pl->theta_rad), .sn = sin(pl->theta_rad),
                               .t = { pl->offset_mm[0], pl->offset_mm[1] }, .cmax = { pl->canvas_mm[0], pl->canvas_mm[1] } };
}

/* Index bounds of the samples whose world x (or y) lies in [lo, hi], clamped. */
static void sample_range(const struct imp_sim_surface *s, int axis, double lo, double hi, int *i0, int *i1) {
        int n = axis ? s->ny : s->nx;
        double a = (lo - s->origin_mm[axis]) / s->pitch_mm, b = (hi - s->origin_mm[axis]) / s->pitch_mm;
        *i0 = (int) IMP_CLAMP(floor(a), 0, n - 1);
        *i1 = (int) IMP_CLAMP(ceil(b), 0, n - 1);
}

/* Sample index bounds of the painting-frame box [xlo, xhi] × [ylo, yhi] ∩ canvas: the world
 * box of its corners (exact for the identity). */
static void grid_range(const struct grid *g, double xlo, double xhi, double ylo, double yhi, int ret[4]) {
        double px[2] = { IMP_MAX(xlo, g->cmin[0]), IMP_MIN(xhi, g->cmax[0]) };
        double py[2] = { IMP_MAX(ylo, g->cmin[1]), IMP_MIN(yhi, g->cmax[1]) };
        double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY };
        if (g->sn == 0 && g->c == 1 && g->t[0] == 0 && g->t[1] == 0) {
                lo[0] = px[0], hi[0] = px[1], lo[1] = py[0], hi[1] = py[1];
        } else {
                for (int k = 0; k < 4; k++) {
                        double dx = px[k & 1] - g->t[0], dy = py[k >> 1] - g->t[1];
                        double w[2] = { g->c * dx + g->sn * dy, -g->sn * dx + g->c * dy };
                        for (int a = 0; a < 2; a++) {
                                lo[a] = IMP_MIN(lo[a], w[a]);
                                hi[a] = IMP_MAX(hi[a], w[a]);
                        }
                }
        }
        sample_range(g->s, 0, lo[0], hi[0], &ret[0], &ret[1]);
        sample_range(g->s, 1, lo[1], hi[1], &ret[2], &ret[3]);
}

/* Every canvas sample of the box, with k its index and (x, y) its painting-frame position.
 * Under a placement, samples off the painting's canvas are skipped (they stay flat). */
#define FOR_CANVAS(g, xlo, xhi, ylo, yhi, ...) do { \
        int rg_[4]; \
        grid_range(g, xlo, xhi, ylo, yhi, rg_); \
        const struct imp_sim_surface *s_ = (g)->s; \
        for (int j = rg_[2]; j <= rg_[3]; j++) for (int i = rg_[0]; i <= rg_[1]; i++) { \
                size_t k = (size_t) j * s_->nx + i; \
                if (s_->is_frame[k]) continue; \
                double w_[2]; \
                imp_sim_surface_sample_xy(s_, i, j, w_); \
                double wx_ = w_[0], wy_ = w_[1]; \
                double x = (g)->c * wx_ - (g)->sn * wy_ + (g)->t[0], y = (g)->sn * wx_ + (g)->c * wy_ + (g)->t[1]; \
                if (x < (g)->cmin[0] - 1e-9 || x > (g)->cmax[0] + 1e-9 || y < (g)->cmin[1] - 1e-9 || y > (g)->cmax[1] + 1e-9) continue; \
                (void) x; (void) y; __VA_ARGS__; } } while (0)

static void add_weave(const struct grid *g, float *h, const struct imp_layer *L) {
        double w = 2 * M_PI / L->period_mm;
        FOR_CANVAS(g, -INFINITY, INFINITY, -INFINITY, INFINITY,
                   h[k] += (float) (L->amplitude_mm * 0.5 * (1 + sin(w * x) * sin(w * y))));
}

/* Brush strokes: slightly curved ribbons with a rounded cross-section, bristle grooves
 * along the stroke and tapered ends. */
static void add_strokes(const struct grid *g, float *h, const struct imp_layer *L) {
        double W = g->cmax[0] - g->cmin[0], H = g->cmax[1] - g->cmin[1];
        double main_angle = M_PI * imp_u01(imp_mix64(L->seed));
        for (int n = 0; n < L->count; n++) {
                uint64_t sd = imp_mix64(L->seed ^ imp_mix64((uint64_t) n + 1));
                double r[8];
                for (int q = 0; q < 8; q++)
                        r[q] = imp_u01(imp_mix64(sd + (uint64_t) q));
                double cx = g->cmin[0] + W * r[0], cy = g->cmin[1] + H * r[1];
                double ang = main_angle + (r[2] - 0.5) * 1.2;
                double len = L->length_mm * (0.3 + 0.7 * r[3]), wid = L->width_mm * (0.4 + 0.6 * r[4]);
                double amp = L->amplitude_mm * (0.4 + 0.6 * r[5]);
                double curv = (r[6] - 0.5) * 0.6 / len;        /* lateral offset curv·s² */
                double groove_ph = 2 * M_PI * r[7];
                double ux = cos(ang), uy = sin(ang), nx = -uy, ny = ux;
                double ext = 0.5 * len + wid + fabs(curv) * len * len;
                FOR_CANVAS(g, cx - ext, cx + ext, cy - ext, cy + ext, {
                        double px = x - cx, py = y - cy;
                        double sa = px * ux + py * uy;
                        if (fabs(sa) > 0.5 * len)
                                continue;
                        double d = px * nx + py * ny - curv * sa * sa;
                        double q = 2 * d / wid;
                        if (fabs(q) >= 1)
                                continue;
                        double across = sqrt(1 - q * q);
                        double along = smooth(IMP_MIN(1.0, (0.5 * len - fabs(sa)) / (0.15 * len)));
                        double grooves = 1 + 0.2 * sin(2 * M_PI * d / 0.2 + groove_ph);
                        h[k] += (float) (amp * across * along * grooves);
                });
        }
}

/* Palette-knife impasto ridge: a ramp of width `width_mm` rising to the crest, then a
 * cliff that drops within `cliff_mm` (steep when cliff_mm is about one sample). */
static void add_ridge(const struct grid *g, float *h, const struct imp_layer *L) {
        double dx = L->end_mm[0] - L->start_mm[0], dy = L->end_mm[1] - L->start_mm[1];
        double len = hypot(dx, dy);
        if (len <= 0)
                return;
        double ux = dx / len, uy = dy / len, nx = -uy, ny = ux;
        double ext = L->width_mm + L->cliff_mm;
        double xlo = IMP_MIN(L->start_mm[0], L->end_mm[0]) - ext, xhi = IMP_MAX(L->start_mm[0], L->end_mm[0]) + ext;
        double ylo = IMP_MIN(L->start_mm[1], L->end_mm[1]) - ext, yhi = IMP_MAX(L->start_mm[1], L->end_mm[1]) + ext;
        FOR_CANVAS(g, xlo, xhi, ylo, yhi, {
                double px = x - L->start_mm[0], py = y - L->start_mm[1];
                double sa = px * ux + py * uy, d = px * nx + py * ny;
                if (sa < 0 || sa > len || d < -L->width_mm || d > L->cliff_mm)
                        continue;
                double prof = d <= 0 ? pow(1 + d / L->width_mm, 1.5) : 1 - d / L->cliff_mm;
                double taper = smooth(IMP_MIN(1.0, IMP_MIN(sa, len - sa) / (0.1 * len)));
                double crest = 0.85 + 0.15 * imp_value_noise(L->seed, sa, 0, 3.0);
                h[k] += (float) (L->amplitude_mm * prof * taper * crest);
        });
}

/* Craquelure: narrow V grooves along the edges of a jittered-grid Voronoi diagram. */
static void add_craquelure(const struct grid *g, float *h, const struct imp_layer *L) {
        double P = L->period_mm;
        FOR_CANVAS(g, -INFINITY, INFINITY, -INFINITY, INFINITY, {
                int64_t cx = (int64_t) floor(x / P), cy = (int64_t) floor(y / P);
                double f1 = INFINITY, f2 = INFINITY, p1[2] = { 0, 0 }, p2[2] = { 0, 0 };
                for (int64_t b = cy - 1; b <= cy + 1; b++)
                        for (int64_t a = cx - 1; a <= cx + 1; a++) {
                                double fx = (a + hash01(L->seed, a, b)) * P;
                                double fy = (b + hash01(L->seed + 1, a, b)) * P;
                                double dd = (fx - x) * (fx - x) + (fy - y) * (fy - y);
                                if (dd < f1) {
                                        f2 = f1; p2[0] = p1[0]; p2[1] = p1[1];
                                        f1 = dd; p1[0] = fx; p1[1] = fy;
                                } else if (dd < f2) {
                                        f2 = dd; p2[0] = fx; p2[1] = fy;
                                }
                        }
                double sep = hypot(p2[0] - p1[0], p2[1] - p1[1]);
                double edge = sep > 0 ? (f2 - f1) / (2 * sep) : INFINITY;
                if (edge < 0.5 * L->width_mm)
                        h[k] -= (float) (L->amplitude_mm * (1 - 2 * edge / L->width_mm));
        });
}

static void add_step(const struct grid *g, float *h, const struct imp_layer *L) {
        FOR_CANVAS(g, -INFINITY, INFINITY, -INFINITY, INFINITY, {
                double c = L->axis ? y : x;
                if (c < L->at_mm)
                        h[k] += (float) L->amplitude_mm;
        });
}

static int add_file(const struct grid *g, float *h, const struct imp_layer *L, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_read(L->path, &img, err);
        if (r < 0)
                return r;
        double W = g->cmax[0] - g->cmin[0], H = g->cmax[1] - g->cmin[1];
        double scale = L->amplitude_mm;
        if (img->type == IMP_PIX_U8)
                scale /= 255.0;
        else if (img->type == IMP_PIX_U16)
                scale /= 65535.0;
        FOR_CANVAS(g, -INFINITY, INFINITY, -INFINITY, INFINITY, {
                double fx = (x - g->cmin[0]) / W * (img->width - 1);
                double fy = (y - g->cmin[1]) / H * (img->height - 1);
                fx = IMP_CLAMP(fx, 0, img->width - 1);
                fy = IMP_CLAMP(fy, 0, img->height - 1);
                int x0 = (int) fx, y0 = (int) fy;
                int x1 = IMP_MIN(x0 + 1, img->width - 1), y1 = IMP_MIN(y0 + 1, img->height - 1);
                double ax = fx - x0, ay = fy - y0;
                double v = (imp_image_get(img, x0, y0, 0) * (1 - ax) + imp_image_get(img, x1, y0, 0) * ax) * (1 - ay) +
                           (imp_image_get(img, x0, y1, 0) * (1 - ax) + imp_image_get(img, x1, y1, 0) * ax) * ay;
                if (!isfinite(v))
                        v = 0;   /* a NaN in the file becomes flat canvas, never a NaN height */
                h[k] += (float) (scale * v);
        });
        return 0;
}

static void add_plane(const struct grid *g, float *h, const struct imp_layer *L) {
        FOR_CANVAS(g, -INFINITY, INFINITY, -INFINITY, INFINITY,
                   h[k] += (float) (L->slope[0] * x + L->slope[1] * y + L->offset_mm));
}

/* Mirror spheres for light calibration: the part above the surface of a sphere whose
 * centre lies offset_mm (≤ 0) above it: the upper hemisphere at 0, whose rim meets the
 * surface vertically (the sampled heightfield turns that into a ramp one sample wide), a
 * cap with a slanted rim below. */
static void add_sphere(const struct grid *g, float *h, const struct imp_layer *L) {
        double r = L->radius_mm, cx = L->centre_mm[0], cy = L->centre_mm[1], z0 = L->offset_mm;
        FOR_CANVAS(g, cx - r, cx + r, cy - r, cy + r, {
                double d2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
                if (d2 < r * r && sqrt(r * r - d2) + z0 > 0)
                        h[k] += (float) (sqrt(r * r - d2) + z0);
        });
}

int imp_painting_add_layer_placed(const struct imp_sim_surface *surf, const struct imp_painting_place *place, float *h,
                                  const struct imp_layer *L, struct imp_error *err) {
        struct grid gr = grid_of(surf, place), *g = &gr;
        switch (L->kind) {
        case IMP_LAYER_WEAVE: add_weave(g, h, L); return 0;
        case IMP_LAYER_STROKES: add_strokes(g, h, L); return 0;
        case IMP_LAYER_RIDGE: add_ridge(g, h, L); return 0;
        case IMP_LAYER_CRAQUELURE: add_craquelure(g, h, L); return 0;
        case IMP_LAYER_STEP: add_step(g, h, L); return 0;
        case IMP_LAYER_FILE: return add_file(g, h, L, err);
        case IMP_LAYER_PLANE: add_plane(g, h, L); return 0;
        case IMP_LAYER_SPHERE: add_sphere(g, h, L); return 0;
        case IMP_LAYER_COUNT: break;
        }
        return -EINVAL;
}

int imp_painting_add_layer(const struct imp_sim_surface *surf, float *h, const struct imp_layer *L,
                           struct imp_error *err) {
        return imp_painting_add_layer_placed(surf, NULL, h, L, err);
}
