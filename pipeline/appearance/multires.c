/* Multi-resolution view-dependent texture (seed 003 §4–7; see multires.h and
 * docs/multires.md): pixels → cells per block of cells, depth-bracketed deposits, fill and
 * filter passes, hat reconstruction, EXR pyramid. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include "json-util.h"
#include "multires.h"

#define MR_DEFAULT_BASE_CELL_MM   25.0
#define MR_DEFAULT_SUPERSAMPLE    2
#define MR_DEFAULT_FEATHER_PX     16.0
#define MR_DEFAULT_HEMI_N         8
#define MR_DEFAULT_HEMI_BUDGET    ((size_t) 16 << 20)
#define MR_DEFAULT_FADE_RADIUS    0.35
#define MR_DEFAULT_EMPTY          0.5f
#define MR_DEFAULT_BLOCK_CELLS    256
#define MR_MAX_SUPERSAMPLE        8
#define MR_DEPTH_SAMPLES          64      /* pixel grid per side for the depth metric */
#define MR_BBOX_GRID              5       /* block points projected to bound its pixels */
#define MR_BBOX_MARGIN_PX         2
#define MR_HOLE_MIN_NEIGHBOURS    4       /* of 8: a hole, not the edge of the data */
#define MR_FORMAT                 "impasto-multires"
#define MR_VERSION                1

struct mr_layer {
        int nx, ny;
        double cell_mm;
        float *rgb;          /* 3 per cell */
        float *cov;          /* coverage (best mask value reaching the cell), 0 = none */
        float *direct;       /* direct weight at this layer, clamped to 1 */
        float *w;            /* blend weight, build only */
        uint8_t *up;         /* build only: data the finer layer may take (own or from above) */
        float *hemi;         /* nx·ny·n²·4 (r, g, b, weight) or NULL */
};

struct imp_multires {
        double width_mm, height_mm, base_cell_mm;
        int n_layers, hemi_n, hemi_layer;
        float empty_value;
        struct mr_layer layers[IMP_MULTIRES_MAX_LAYERS];
        int n_views;
        double *view_depth, *view_fp;     /* NAN-free: fp 0 marks a view that saw nothing */
        size_t nonfinite_px;
};

void imp_multires_options_default(struct imp_multires_options *opt) {
        *opt = (struct imp_multires_options) {
                .base_cell_mm = MR_DEFAULT_BASE_CELL_MM,
                .supersample = MR_DEFAULT_SUPERSAMPLE,
                .feather_px = MR_DEFAULT_FEATHER_PX,
                .hemi_n = MR_DEFAULT_HEMI_N,
                .hemi_layer = -1,
                .hemi_budget_bytes = MR_DEFAULT_HEMI_BUDGET,
                .fade_radius = MR_DEFAULT_FADE_RADIUS,
                .empty_value = MR_DEFAULT_EMPTY,
                .block_cells = MR_DEFAULT_BLOCK_CELLS,
        };
}

static bool options_valid(const struct imp_multires_options *o) {
        return o && isfinite(o->width_mm) && o->width_mm > 0 && isfinite(o->height_mm) &&
               o->height_mm > 0 && isfinite(o->base_cell_mm) && o->base_cell_mm > 0 &&
               o->n_layers >= 0 && o->n_layers <= IMP_MULTIRES_MAX_LAYERS &&
               o->supersample >= 1 && o->supersample <= MR_MAX_SUPERSAMPLE &&
               isfinite(o->feather_px) && o->feather_px >= 0 &&
               o->hemi_n >= 0 && o->hemi_n <= IMP_MULTIRES_MAX_HEMI_N &&
               o->hemi_layer >= -1 && o->hemi_layer < IMP_MULTIRES_MAX_LAYERS &&
               isfinite(o->fade_radius) && o->fade_radius > 0 && isfinite(o->empty_value) &&
               o->block_cells >= 1 && o->block_cells <= 4096;
}

static bool view_valid(const struct imp_multires_view *v) {
        const struct imp_image *im = v->image;
        if (!im || im->type != IMP_PIX_F32 || (im->channels != 1 && im->channels != 3) ||
            im->width < 1 || im->height < 1)
                return false;
        if (v->mask && (v->mask->type != IMP_PIX_F32 || v->mask->channels != 1 ||
                        v->mask->width != im->width || v->mask->height != im->height))
                return false;
        const struct imp_pinhole *c = &v->camera;
        return isfinite(c->fx) && isfinite(c->fy) && c->fx != 0 && c->fy != 0 &&
               isfinite(c->cx) && isfinite(c->cy);
}

/* ---- camera rays onto the canvas plane ---- */

struct mr_cam {
        const struct imp_pinhole *m;
        double C[3];
        bool distorted;
};

static void cam_init(struct mr_cam *c, const struct imp_pinhole *m) {
        c->m = m;
        imp_pinhole_centre(m, c->C);
        c->distorted = m->k1 != 0 || m->k2 != 0 || m->k3 != 0 || m->p1 != 0 || m->p2 != 0;
}

/* Pixel position → point on z = 0 seen from the front; false when the ray misses it. */
static bool cam_hit(const struct mr_cam *c, double u, double v, double ret_xy[2]) {
        double D[3], O[3];
        if (c->distorted) {
                double px[2] = { u, v };
                imp_pinhole_ray_world(c->m, px, O, D);
        } else {
                const double *R = c->m->R;
                double d0 = (u - c->m->cx) / c->m->fx, d1 = (v - c->m->cy) / c->m->fy;
                for (int i = 0; i < 3; i++)
                        D[i] = R[i] * d0 + R[3 + i] * d1 + R[6 + i];
                memcpy(O, c->C, sizeof O);
        }
        if (!(O[2] > 0) || !(D[2] < 0))
                return false;
        double t = -O[2] / D[2];
        ret_xy[0] = O[0] + t * D[0];
        ret_xy[1] = O[1] + t * D[1];
        return isfinite(ret_xy[0]) && isfinite(ret_xy[1]);
}

static bool on_canvas(double W, double H, const double xy[2]) {
        return xy[0] >= 0 && xy[0] < W && xy[1] >= 0 && xy[1] < H;
}

int imp_multires_view_depth(const struct imp_multires_options *opt,
                            const struct imp_multires_view *view, double *ret_depth,
                            double *ret_footprint_mm) {
        if (!options_valid(opt) || !view || !view_valid(view))
                return -EINVAL;
        struct mr_cam cam;
        cam_init(&cam, &view->camera);
        int w = view->image->width, h = view->image->height;
        int sx = IMP_MAX(1, w / MR_DEPTH_SAMPLES), sy = IMP_MAX(1, h / MR_DEPTH_SAMPLES);
        double sum_area = 0;
        size_t n = 0;
        for (int v = sy / 2; v < h; v += sy)
                for (int u = sx / 2; u < w; u += sx) {
                        double X[2], a[2], b[2], c[2], d[2];
                        if (!cam_hit(&cam, u, v, X) || !on_canvas(opt->width_mm, opt->height_mm, X) ||
                            !cam_hit(&cam, u - 0.5, v, a) || !cam_hit(&cam, u + 0.5, v, b) ||
                            !cam_hit(&cam, u, v - 0.5, c) || !cam_hit(&cam, u, v + 0.5, d))
                                continue;
                        double ex = b[0] - a[0], ey = b[1] - a[1];
                        double fx = d[0] - c[0], fy = d[1] - c[1];
                        sum_area += fabs(ex * fy - ey * fx);
                        n++;
                }
        if (n == 0 || !(sum_area > 0) || !isfinite(sum_area))
                return -ENODATA;
        double p = sqrt(sum_area / (double) n);
        if (ret_depth)
                *ret_depth = log2(opt->base_cell_mm / p);
        if (ret_footprint_mm)
                *ret_footprint_mm = p;
        return 0;
}

/* ---- layers ---- */

static size_t layer_cells(const struct mr_layer *l) {
        return (size_t) l->nx * l->ny;
}

static size_t hemi_floats(const struct imp_multires *mr, const struct mr_layer *l) {
        return layer_cells(l) * (size_t) mr->hemi_n * mr->hemi_n * 4;
}

void imp_multires_free(struct imp_multires *mr) {
        if (!mr)
                return;
        for (int L = 0; L < IMP_MULTIRES_MAX_LAYERS; L++) {
                struct mr_layer *l = &mr->layers[L];
                free(l->rgb);
                free(l->cov);
                free(l->direct);
                free(l->w);
                free(l->up);
                free(l->hemi);
        }
        free(mr->view_depth);
        free(mr->view_fp);
        free(mr);
}

/* Allocates the layer arrays (zeroed); hemisphere arrays for layers ≤ hemi_layer. */
static int alloc_layers(struct imp_multires *mr, int nx0, int ny0, bool with_w) {
        for (int L = 0; L < mr->n_layers; L++) {
                struct mr_layer *l = &mr->layers[L];
                l->nx = nx0 << L;
                l->ny = ny0 << L;
                l->cell_mm = mr->base_cell_mm / (double) (1u << L);
                size_t N = layer_cells(l);
                l->rgb = calloc(N * 3, sizeof(float));
                l->cov = calloc(N, sizeof(float));
                l->direct = calloc(N, sizeof(float));
                if (with_w) {
                        l->w = calloc(N, sizeof(float));
                        l->up = calloc(N, 1);
                }
                if (!l->rgb || !l->cov || !l->direct || (with_w && (!l->w || !l->up)))
                        return -ENOMEM;
                if (L <= mr->hemi_layer && !(l->hemi = calloc(hemi_floats(mr, l), sizeof(float))))
                        return -ENOMEM;
        }
        return 0;
}

/* The size limits every layer file must respect (pipeline/core/image.h). */
static bool layer_fits(int nx, int ny, int channels, int scale) {
        if ((long long) nx * scale > IMP_IMAGE_MAX_SIDE || (long long) ny * scale > IMP_IMAGE_MAX_SIDE)
                return false;
        return (double) nx * scale * ny * scale * channels * sizeof(float) <= (double) IMP_IMAGE_MAX_BYTES;
}

/* Depth percentage of a view at depth d for layer L (seed §6.1): the bracketing layers
 * i = floor(d) and i+1 get 1−(d−i) and d−i; depths outside [0, top] are clamped, so a view
 * finer than the finest layer deposits there in full (an area average). */
static double depth_pct(double d, int L, int top) {
        d = IMP_CLAMP(d, 0.0, (double) top);
        int i = (int) floor(d);
        double f = d - i;
        if (L == i)
                return 1 - f;
        if (L == i + 1)
                return f;
        return 0;
}

void imp_multires_dir_to_st(const double omega[3], double ret_st[2]) {
        double x = omega[0], y = omega[1], z = omega[2];
        double n = sqrt(x * x + y * y + z * z);
        if (!(n > 0) || !isfinite(n)) {
                ret_st[0] = ret_st[1] = 0;
                return;
        }
        x /= n, y /= n, z /= n;
        if (z < 0) {   /* behind the paint: the rim point of the same azimuth */
                double r = hypot(x, y);
                if (r > 0)
                        x /= r, y /= r;
                z = 0;
        }
        ret_st[0] = -x / (1 + z);
        ret_st[1] = y / (1 + z);
}

static double elem_centre(int a, int n) {
        return -1 + (a + 0.5) * 2.0 / n;
}

/* ---- deposit: one block of cells of one layer, one view ---- */

struct mr_block {
        int L, i0, j0, bw, bh;           /* cells [i0, i0+bw) × [j0, j0+bh) */
        double *cnt, *msum, *cm;         /* per cell: sub-pixels, Σ mask, Σ mask·colour (3) */
};

static float feather(const struct imp_multires_options *o, int u, int v, int w, int h) {
        if (o->feather_px <= 0)
                return 1;
        double d = IMP_MIN(IMP_MIN(u + 0.5, v + 0.5), IMP_MIN(w - 0.5 - u, h - 0.5 - v));
        double m = IMP_CLAMP(d / o->feather_px, 0.0, 1.0);
        return (float) (m * m * (3 - 2 * m));
}

/* Pixel rectangle that can map into the block: the bounding box of a grid of block points,
 * widened by a margin; the whole image when a point falls behind the camera. */
static bool block_pixels(const struct imp_multires *mr, const struct mr_block *b,
                         const struct imp_multires_view *view, int ret_r[4]) {
        const struct mr_layer *l = &mr->layers[b->L];
        int w = view->image->width, h = view->image->height;
        double x0 = b->i0 * l->cell_mm, y0 = b->j0 * l->cell_mm;
        double x1 = IMP_MIN((b->i0 + b->bw) * l->cell_mm, mr->width_mm);
        double y1 = IMP_MIN((b->j0 + b->bh) * l->cell_mm, mr->height_mm);
        if (x1 <= x0 || y1 <= y0)
                return false;
        double umin = INFINITY, umax = -INFINITY, vmin = INFINITY, vmax = -INFINITY;
        for (int a = 0; a < MR_BBOX_GRID; a++)
                for (int c = 0; c < MR_BBOX_GRID; c++) {
                        double X[3] = { x0 + (x1 - x0) * a / (MR_BBOX_GRID - 1),
                                        y0 + (y1 - y0) * c / (MR_BBOX_GRID - 1), 0 }, px[2];
                        if (!imp_pinhole_project(&view->camera, X, px) || !isfinite(px[0]) ||
                            !isfinite(px[1])) {
                                ret_r[0] = 0, ret_r[1] = 0, ret_r[2] = w, ret_r[3] = h;
                                return true;
                        }
                        umin = fmin(umin, px[0]), umax = fmax(umax, px[0]);
                        vmin = fmin(vmin, px[1]), vmax = fmax(vmax, px[1]);
                }
        ret_r[0] = (int) IMP_CLAMP(floor(umin) - MR_BBOX_MARGIN_PX, 0.0, (double) w);
        ret_r[1] = (int) IMP_CLAMP(floor(vmin) - MR_BBOX_MARGIN_PX, 0.0, (double) h);
        ret_r[2] = (int) IMP_CLAMP(ceil(umax) + MR_BBOX_MARGIN_PX + 1, 0.0, (double) w);
        ret_r[3] = (int) IMP_CLAMP(ceil(vmax) + MR_BBOX_MARGIN_PX + 1, 0.0, (double) h);
        return ret_r[2] > ret_r[0] && ret_r[3] > ret_r[1];
}

/* Seed §4.3: every sub-pixel of the view adds its pixel to the cell it lands in. */
static bool splat_block(const struct imp_multires *mr, const struct imp_multires_options *o,
                        const struct imp_multires_view *view, const struct mr_cam *cam,
                        struct mr_block *b) {
        int r[4];
        if (!block_pixels(mr, b, view, r))
                return false;
        const struct mr_layer *l = &mr->layers[b->L];
        const struct imp_image *im = view->image;
        int k = o->supersample, nb = b->bw * b->bh;
        memset(b->cnt, 0, (size_t) nb * sizeof(double));
        memset(b->msum, 0, (size_t) nb * sizeof(double));
        memset(b->cm, 0, (size_t) nb * 3 * sizeof(double));
        bool any = false;
        for (int v = r[1]; v < r[3]; v++)
                for (int u = r[0]; u < r[2]; u++) {
                        const float *p = imp_image_f32(im, u, v);
                        float c[3];
                        for (int ch = 0; ch < 3; ch++)
                                c[ch] = p[im->channels == 3 ? ch : 0];
                        if (!isfinite(c[0]) || !isfinite(c[1]) || !isfinite(c[2]))
                                continue;
                        float m = feather(o, u, v, im->width, im->height);
                        if (view->mask) {
                                float mm = *imp_image_f32(view->mask, u, v);
                                m *= isfinite(mm) ? IMP_CLAMP(mm, 0.0f, 1.0f) : 0.0f;
                        }
                        for (int sb = 0; sb < k; sb++)
                                for (int sa = 0; sa < k; sa++) {
                                        double xy[2];
                                        if (!cam_hit(cam, u - 0.5 + (sa + 0.5) / k,
                                                     v - 0.5 + (sb + 0.5) / k, xy) ||
                                            !on_canvas(mr->width_mm, mr->height_mm, xy))
                                                continue;
                                        int i = (int) floor(xy[0] / l->cell_mm) - b->i0;
                                        int j = (int) floor(xy[1] / l->cell_mm) - b->j0;
                                        if (i < 0 || j < 0 || i >= b->bw || j >= b->bh)
                                                continue;
                                        size_t q = (size_t) j * b->bw + i;
                                        b->cnt[q] += 1;
                                        b->msum[q] += m;
                                        for (int ch = 0; ch < 3; ch++)
                                                b->cm[3 * q + ch] += (double) m * c[ch];
                                        any = true;
                                }
                }
        return any;
}

/* Seed §6.1: the view's colour and mask per cell, weighted by the depth percentage, into
 * the independent sums; with the fade hat around its direction into the hemisphere sums. */
static void deposit_block(struct imp_multires *mr, const struct imp_multires_options *o,
                          const struct mr_cam *cam, const struct mr_block *b, double pct_i,
                          double pct_h) {
        struct mr_layer *l = &mr->layers[b->L];
        int n = mr->hemi_n;
        for (int j = 0; j < b->bh; j++)
                for (int i = 0; i < b->bw; i++) {
                        size_t q = (size_t) j * b->bw + i;
                        if (!(b->cnt[q] > 0) || !(b->msum[q] > 0))
                                continue;
                        double alpha = b->msum[q] / b->cnt[q], col[3];
                        for (int ch = 0; ch < 3; ch++)
                                col[ch] = b->cm[3 * q + ch] / b->msum[q];
                        int ci = b->i0 + i, cj = b->j0 + j;
                        size_t cell = (size_t) cj * l->nx + ci;
                        if (pct_i > 0) {
                                double wgt = pct_i * alpha;
                                for (int ch = 0; ch < 3; ch++)
                                        l->rgb[3 * cell + ch] += (float) (wgt * col[ch]);
                                l->w[cell] += (float) wgt;
                                l->direct[cell] += (float) alpha;
                                l->cov[cell] = fmaxf(l->cov[cell], (float) alpha);
                        }
                        if (pct_h > 0 && l->hemi) {
                                double P[3] = { IMP_MIN((ci + 0.5) * l->cell_mm, mr->width_mm),
                                                IMP_MIN((cj + 0.5) * l->cell_mm, mr->height_mm), 0 };
                                double om[3] = { cam->C[0] - P[0], cam->C[1] - P[1], cam->C[2] - P[2] }, st[2];
                                imp_multires_dir_to_st(om, st);
                                float *hc = l->hemi + cell * (size_t) n * n * 4;
                                for (int eb = 0; eb < n; eb++)
                                        for (int ea = 0; ea < n; ea++) {
                                                double dist = hypot(elem_centre(ea, n) - st[0],
                                                                    elem_centre(eb, n) - st[1]);
                                                double f = 1 - dist / o->fade_radius;
                                                if (f <= 0)
                                                        continue;
                                                float *e = hc + ((size_t) eb * n + ea) * 4;
                                                double wgt = pct_h * alpha * f;
                                                for (int ch = 0; ch < 3; ch++)
                                                        e[ch] += (float) (wgt * col[ch]);
                                                e[3] += (float) wgt;
                                        }
                        }
                }
}

static int deposit_all(struct imp_multires *mr, const struct imp_multires_options *o,
                       const struct imp_multires_view *views, int n_views) {
        int B = o->block_cells, top = mr->n_layers - 1;
        size_t nb = (size_t) B * B;
        _cleanup_free_ double *cnt = malloc(nb * sizeof(double));
        _cleanup_free_ double *msum = malloc(nb * sizeof(double));
        _cleanup_free_ double *cm = malloc(nb * 3 * sizeof(double));
        if (!cnt || !msum || !cm)
                return -ENOMEM;
        for (int L = 0; L < mr->n_layers; L++) {
                struct mr_layer *l = &mr->layers[L];
                for (int j0 = 0; j0 < l->ny; j0 += B)
                        for (int i0 = 0; i0 < l->nx; i0 += B) {
                                struct mr_block b = { .L = L, .i0 = i0, .j0 = j0,
                                        .bw = IMP_MIN(B, l->nx - i0), .bh = IMP_MIN(B, l->ny - j0),
                                        .cnt = cnt, .msum = msum, .cm = cm };
                                for (int v = 0; v < n_views; v++) {
                                        if (!(mr->view_fp[v] > 0))
                                                continue;
                                        double d = mr->view_depth[v];
                                        double pi = depth_pct(d, L, top);
                                        double ph = L <= mr->hemi_layer
                                                ? depth_pct(IMP_MIN(d, (double) mr->hemi_layer), L, mr->hemi_layer) : 0;
                                        if (pi <= 0 && ph <= 0)
                                                continue;
                                        struct mr_cam cam;
                                        cam_init(&cam, &views[v].camera);
                                        if (splat_block(mr, o, &views[v], &cam, &b))
                                                deposit_block(mr, o, &cam, &b, pi, ph);
                                }
                        }
        }
        return 0;
}

/* ---- fill and filter (seed §6.2) ---- */

/* Seed §6.1: the colour is the depth·mask-weighted mean of the views (normalised); the
 * weight this layer's data has against data filled from other layers is the views' mask
 * sum Σα (clamped), so a view fades out at its feathered edge however small its depth
 * percentage here. During deposits w holds Σ pct·α and direct holds Σα. */
static void normalise_direct(struct mr_layer *l) {
        size_t N = layer_cells(l);
        for (size_t q = 0; q < N; q++) {
                float w = l->w[q];
                if (w > 0) {
                        for (int ch = 0; ch < 3; ch++)
                                l->rgb[3 * q + ch] /= w;
                        l->w[q] = fminf(l->direct[q], 1);
                        l->direct[q] = fminf(w, 1);
                        l->up[q] = 1;
                } else {
                        l->rgb[3 * q] = l->rgb[3 * q + 1] = l->rgb[3 * q + 2] = 0;
                        l->w[q] = l->direct[q] = l->cov[q] = 0;
                }
        }
}

/* Gaps left by the discrete mapping: a cell without data whose 8-neighbourhood mostly has
 * direct data takes their weighted mean (seed: flood fill to the nearest cell). */
static void fill_holes(struct mr_layer *l) {
        for (int j = 0; j < l->ny; j++)
                for (int i = 0; i < l->nx; i++) {
                        size_t q = (size_t) j * l->nx + i;
                        if (l->w[q] > 0)
                                continue;
                        double s[3] = { 0, 0, 0 }, sw = 0;
                        float cov = 0;
                        int cnt = 0;
                        for (int dj = -1; dj <= 1; dj++)
                                for (int di = -1; di <= 1; di++) {
                                        int ii = i + di, jj = j + dj;
                                        if ((!di && !dj) || ii < 0 || jj < 0 || ii >= l->nx || jj >= l->ny)
                                                continue;
                                        size_t p = (size_t) jj * l->nx + ii;
                                        if (!(l->direct[p] > 0))
                                                continue;
                                        cnt++;
                                        sw += l->w[p];
                                        cov = fmaxf(cov, l->cov[p]);
                                        for (int ch = 0; ch < 3; ch++)
                                                s[ch] += l->w[p] * l->rgb[3 * p + ch];
                                }
                        if (cnt < MR_HOLE_MIN_NEIGHBOURS || !(sw > 0))
                                continue;
                        for (int ch = 0; ch < 3; ch++)
                                l->rgb[3 * q + ch] = (float) (s[ch] / sw);
                        l->w[q] = (float) (sw / cnt);
                        l->cov[q] = cov;
                        l->up[q] = 1;
                }
}

/* Own data with weight w, plus (1 − w) of other data c2 of weight w2. */
static void blend_in(float *rgb, float *w, float *cov, const double c2[3], double w2, float cov2) {
        if (*w >= 1 || !(w2 > 0))
                return;
        double a = *w, b = (1 - a) * w2;
        for (int ch = 0; ch < 3; ch++)
                rgb[ch] = (float) ((a * rgb[ch] + b * c2[ch]) / (a + b));
        *w = (float) (a + b);
        *cov = fmaxf(*cov, cov2);
}

/* Missing data from the filtered finer layer: the weighted mean of the four children. */
static void filter_down(struct mr_layer *l, const struct mr_layer *f) {
        for (int j = 0; j < l->ny; j++)
                for (int i = 0; i < l->nx; i++) {
                        size_t q = (size_t) j * l->nx + i;
                        double s[3] = { 0, 0, 0 }, sw = 0;
                        float cov = 0;
                        for (int k = 0; k < 4; k++) {
                                size_t p = (size_t) (2 * j + k / 2) * f->nx + 2 * i + k % 2;
                                sw += f->w[p];
                                cov = fmaxf(cov, f->cov[p]);
                                for (int ch = 0; ch < 3; ch++)
                                        s[ch] += f->w[p] * f->rgb[3 * p + ch];
                        }
                        if (!(sw > 0))
                                continue;
                        double c[3] = { s[0] / sw, s[1] / sw, s[2] / sw };
                        blend_in(l->rgb + 3 * q, &l->w[q], &l->cov[q], c, sw / 4, cov);
                }
}

/* Hat-function weights of the 4 cells around grid coordinate (u, v) (cell centres at
 * integers), clamped at the grid edge. */
static void hat4(int nx, int ny, double u, double v, size_t ret_q[4], double ret_h[4]) {
        u = IMP_CLAMP(u, 0.0, (double) (nx - 1));
        v = IMP_CLAMP(v, 0.0, (double) (ny - 1));
        int i0 = IMP_MIN((int) floor(u), nx - 1), j0 = IMP_MIN((int) floor(v), ny - 1);
        int i1 = IMP_MIN(i0 + 1, nx - 1), j1 = IMP_MIN(j0 + 1, ny - 1);
        double fu = u - i0, fv = v - j0;
        ret_q[0] = (size_t) j0 * nx + i0, ret_h[0] = (1 - fu) * (1 - fv);
        ret_q[1] = (size_t) j0 * nx + i1, ret_h[1] = fu * (1 - fv);
        ret_q[2] = (size_t) j1 * nx + i0, ret_h[2] = (1 - fu) * fv;
        ret_q[3] = (size_t) j1 * nx + i1, ret_h[3] = fu * fv;
}

/* What is still missing from the coarser layer through its hat functions (seed footnote 2:
 * propagating data up the layers). */
static void fill_up(struct mr_layer *l, const struct mr_layer *p) {
        for (int j = 0; j < l->ny; j++)
                for (int i = 0; i < l->nx; i++) {
                        size_t q = (size_t) j * l->nx + i;
                        /* only below a parent that holds data of its own or from above: data
                         * a parent has only from its other children must not spread sideways */
                        if (l->w[q] >= 1 || !p->up[(size_t) (j / 2) * p->nx + i / 2])
                                continue;
                        size_t pq[4];
                        double h[4], s[3] = { 0, 0, 0 }, sw = 0;
                        hat4(p->nx, p->ny, (i + 0.5) / 2 - 0.5, (j + 0.5) / 2 - 0.5, pq, h);
                        float cov = 0;
                        for (int k = 0; k < 4; k++) {
                                double wk = h[k] * p->w[pq[k]];
                                if (!(wk > 0))
                                        continue;
                                sw += wk;
                                cov = fmaxf(cov, p->cov[pq[k]]);
                                for (int ch = 0; ch < 3; ch++)
                                        s[ch] += wk * p->rgb[3 * pq[k] + ch];
                        }
                        if (!(sw > 0))
                                continue;
                        double c[3] = { s[0] / sw, s[1] / sw, s[2] / sw };
                        blend_in(l->rgb + 3 * q, &l->w[q], &l->cov[q], c, sw, cov);
                        l->up[q] = 1;
                }
}

static void finish_independent(struct imp_multires *mr) {
        int top = mr->n_layers - 1;
        for (int L = 0; L <= top; L++) {
                normalise_direct(&mr->layers[L]);
                fill_holes(&mr->layers[L]);
        }
        for (int L = top - 1; L >= 0; L--)
                filter_down(&mr->layers[L], &mr->layers[L + 1]);
        for (int L = 1; L <= top; L++)
                fill_up(&mr->layers[L], &mr->layers[L - 1]);
        for (int L = 0; L <= top; L++) {
                struct mr_layer *l = &mr->layers[L];
                for (size_t q = 0; q < layer_cells(l); q++)
                        if (!(l->w[q] > 0) || !(l->cov[q] > 0)) {
                                l->rgb[3 * q] = l->rgb[3 * q + 1] = l->rgb[3 * q + 2] = mr->empty_value;
                                l->cov[q] = 0;
                        }
        }
}

/* Hemisphere data (seed §6.1–6.2): normalise the direct sums at each layer; where a layer
 * has none, the four children's arrays filtered element by element (only where they hold
 * data, so independent colour is never copied down); then blend in 1 − α of the cell's
 * independent colour. Runs from the finest hemisphere layer down to layer 0. */
static void finish_hemi(struct imp_multires *mr) {
        int n2 = mr->hemi_n * mr->hemi_n;
        for (int L = mr->hemi_layer; L >= 0; L--) {
                struct mr_layer *l = &mr->layers[L];
                const struct mr_layer *f = L < mr->hemi_layer ? &mr->layers[L + 1] : NULL;
                for (int j = 0; j < l->ny; j++)
                        for (int i = 0; i < l->nx; i++) {
                                size_t q = (size_t) j * l->nx + i;
                                for (int e = 0; e < n2; e++) {
                                        float *el = l->hemi + (q * n2 + e) * 4;
                                        if (el[3] > 0) {
                                                for (int ch = 0; ch < 3; ch++)
                                                        el[ch] /= el[3];
                                                continue;
                                        }
                                        if (!f)
                                                continue;
                                        double s[3] = { 0, 0, 0 }, sw = 0;
                                        for (int k = 0; k < 4; k++) {
                                                size_t p = (size_t) (2 * j + k / 2) * f->nx + 2 * i + k % 2;
                                                const float *c = f->hemi + (p * n2 + e) * 4;
                                                double wk = fminf(c[3], 1);
                                                sw += wk;
                                                for (int ch = 0; ch < 3; ch++)
                                                        s[ch] += wk * c[ch];
                                        }
                                        if (sw > 0) {
                                                for (int ch = 0; ch < 3; ch++)
                                                        el[ch] = (float) (s[ch] / sw);
                                                el[3] = (float) (sw / 4);
                                        }
                                }
                        }
                /* The finer layer's data is no longer needed: blend it now. */
                if (f) {
                        struct mr_layer *fl = &mr->layers[L + 1];
                        for (size_t q = 0; q < layer_cells(fl); q++)
                                for (int e = 0; e < n2; e++) {
                                        float *el = fl->hemi + (q * n2 + e) * 4;
                                        float a = fminf(el[3], 1);
                                        for (int ch = 0; ch < 3; ch++)
                                                el[ch] = a * el[ch] + (1 - a) * fl->rgb[3 * q + ch];
                                }
                }
        }
        struct mr_layer *l0 = &mr->layers[0];
        for (size_t q = 0; q < layer_cells(l0); q++)
                for (int e = 0; e < n2; e++) {
                        float *el = l0->hemi + (q * n2 + e) * 4;
                        float a = fminf(el[3], 1);
                        for (int ch = 0; ch < 3; ch++)
                                el[ch] = a * el[ch] + (1 - a) * l0->rgb[3 * q + ch];
                }
}

/* ---- build ---- */

static int choose_layers(struct imp_multires *mr, const struct imp_multires_options *o,
                         int nx0, int ny0) {
        double dmax = 0;
        for (int v = 0; v < mr->n_views; v++)
                if (mr->view_fp[v] > 0)
                        dmax = fmax(dmax, mr->view_depth[v]);
        if (o->n_layers > 0) {
                mr->n_layers = o->n_layers;
                if (!layer_fits(nx0 << (o->n_layers - 1), ny0 << (o->n_layers - 1), 5, 1))
                        return -EINVAL;
        } else {
                int top = (int) IMP_CLAMP(ceil(dmax), 0.0, (double) (IMP_MULTIRES_MAX_LAYERS - 1));
                while (top > 0 && !layer_fits(nx0 << top, ny0 << top, 5, 1))
                        top--;
                mr->n_layers = top + 1;
        }
        mr->hemi_layer = -1;
        if (o->hemi_n == 0)
                return 0;
        int n = o->hemi_n;
        int want = o->hemi_layer >= 0 ? IMP_MIN(o->hemi_layer, mr->n_layers - 1) : mr->n_layers - 1;
        double bytes = 0;
        for (int L = 0; L <= want; L++) {
                double cells = (double) (nx0 << L) * (double) (ny0 << L);
                bytes += cells * n * n * 4 * sizeof(float);
                bool fits = layer_fits(nx0 << L, ny0 << L, 4, n);
                if (o->hemi_layer >= 0 && !fits)
                        return -EINVAL;
                if (!fits || (o->hemi_layer < 0 && bytes > (double) o->hemi_budget_bytes))
                        break;
                mr->hemi_layer = L;
        }
        return 0;
}

int imp_multires_build(const struct imp_multires_options *opt,
                       const struct imp_multires_view *views, int n_views,
                       struct imp_multires **ret) {
        if (!options_valid(opt) || !views || n_views < 1 || !ret)
                return -EINVAL;
        for (int v = 0; v < n_views; v++)
                if (!view_valid(&views[v]))
                        return -EINVAL;
        int nx0 = (int) ceil(opt->width_mm / opt->base_cell_mm - 1e-9);
        int ny0 = (int) ceil(opt->height_mm / opt->base_cell_mm - 1e-9);
        if (nx0 < 1 || ny0 < 1 || !layer_fits(nx0, ny0, 5, 1))
                return -EINVAL;

        _cleanup_multires_ struct imp_multires *mr = calloc(1, sizeof *mr);
        if (!mr)
                return -ENOMEM;
        *mr = (struct imp_multires) { .width_mm = opt->width_mm, .height_mm = opt->height_mm,
                .base_cell_mm = opt->base_cell_mm, .hemi_n = opt->hemi_n,
                .empty_value = opt->empty_value, .n_views = n_views };
        mr->view_depth = calloc((size_t) n_views, sizeof(double));
        mr->view_fp = calloc((size_t) n_views, sizeof(double));
        if (!mr->view_depth || !mr->view_fp)
                return -ENOMEM;
        bool any = false;
        for (int v = 0; v < n_views; v++) {
                const struct imp_image *im = views[v].image;
                for (int y = 0; y < im->height; y++)
                        for (int x = 0; x < im->width; x++)
                                for (int c = 0; c < im->channels; c++)
                                        if (!isfinite(imp_image_f32(im, x, y)[c])) {
                                                mr->nonfinite_px++;
                                                break;
                                        }
                int r = imp_multires_view_depth(opt, &views[v], &mr->view_depth[v], &mr->view_fp[v]);
                if (r == -ENODATA)
                        continue;   /* the view misses the canvas: it contributes nothing */
                if (r < 0)
                        return r;
                any = true;
        }
        if (!any)
                return -ENODATA;
        int r = choose_layers(mr, opt, nx0, ny0);
        if (r < 0)
                return r;
        if ((r = alloc_layers(mr, nx0, ny0, true)) < 0)
                return r;
        if ((r = deposit_all(mr, opt, views, n_views)) < 0)
                return r;
        finish_independent(mr);
        if (mr->hemi_layer >= 0)
                finish_hemi(mr);
        for (int L = 0; L < mr->n_layers; L++) {
                free(mr->layers[L].w);
                free(mr->layers[L].up);
                mr->layers[L].w = NULL;
                mr->layers[L].up = NULL;
        }
        *ret = TAKE_PTR(mr);
        return 0;
}

/* ---- queries ---- */

int imp_multires_n_layers(const struct imp_multires *mr) { return mr ? mr->n_layers : -EINVAL; }
int imp_multires_hemi_n(const struct imp_multires *mr) { return mr ? mr->hemi_n : -EINVAL; }
int imp_multires_hemi_layer(const struct imp_multires *mr) { return mr ? mr->hemi_layer : -1; }
size_t imp_multires_nonfinite_px(const struct imp_multires *mr) { return mr ? mr->nonfinite_px : 0; }

size_t imp_multires_bytes(const struct imp_multires *mr) {
        if (!mr)
                return 0;
        size_t b = sizeof *mr;
        for (int L = 0; L < mr->n_layers; L++) {
                const struct mr_layer *l = &mr->layers[L];
                b += layer_cells(l) * 5 * sizeof(float);
                if (l->hemi)
                        b += hemi_floats(mr, l) * sizeof(float);
        }
        return b;
}

int imp_multires_layer_info(const struct imp_multires *mr, int layer,
                            struct imp_multires_layer_info *ret) {
        if (!mr || !ret || layer < 0 || layer >= mr->n_layers)
                return -EINVAL;
        const struct mr_layer *l = &mr->layers[layer];
        struct imp_multires_layer_info info = { .nx = l->nx, .ny = l->ny, .cell_mm = l->cell_mm,
                                                .has_hemi = l->hemi != NULL };
        for (size_t q = 0; q < layer_cells(l); q++) {
                if (l->direct[q] > 0)
                        info.n_direct++;
                else if (l->cov[q] > 0)
                        info.n_filled++;
                else
                        info.n_empty++;
        }
        *ret = info;
        return 0;
}

int imp_multires_view_stats(const struct imp_multires *mr, int v, double *ret_depth,
                            double *ret_footprint_mm) {
        if (!mr || v < 0 || v >= mr->n_views)
                return -EINVAL;
        if (!(mr->view_fp[v] > 0))
                return -ENODATA;
        if (ret_depth)
                *ret_depth = mr->view_depth[v];
        if (ret_footprint_mm)
                *ret_footprint_mm = mr->view_fp[v];
        return 0;
}

int imp_multires_cell(const struct imp_multires *mr, int layer, int i, int j,
                      float ret_rgb[3], float *ret_coverage, float *ret_direct) {
        if (!mr || layer < 0 || layer >= mr->n_layers)
                return -EINVAL;
        const struct mr_layer *l = &mr->layers[layer];
        if (i < 0 || j < 0 || i >= l->nx || j >= l->ny)
                return -EINVAL;
        size_t q = (size_t) j * l->nx + i;
        if (ret_rgb)
                memcpy(ret_rgb, l->rgb + 3 * q, 3 * sizeof(float));
        if (ret_coverage)
                *ret_coverage = l->cov[q];
        if (ret_direct)
                *ret_direct = l->direct[q];
        return 0;
}

int imp_multires_hemi(const struct imp_multires *mr, int layer, int i, int j, int a, int b,
                      float ret_rgb[3], float *ret_weight) {
        if (!mr || layer < 0 || layer >= mr->n_layers)
                return -EINVAL;
        const struct mr_layer *l = &mr->layers[layer];
        int n = mr->hemi_n;
        if (i < 0 || j < 0 || i >= l->nx || j >= l->ny || a < 0 || b < 0 || a >= n || b >= n)
                return -EINVAL;
        if (!l->hemi)
                return -ENODATA;
        const float *e = l->hemi + (((size_t) j * l->nx + i) * n * n + (size_t) b * n + a) * 4;
        if (ret_rgb)
                memcpy(ret_rgb, e, 3 * sizeof(float));
        if (ret_weight)
                *ret_weight = e[3];
        return 0;
}

/* Hat reconstruction within one cell's hemisphere array at (s, t), clamped to the edge. */
static void hemi_lookup(const struct imp_multires *mr, const struct mr_layer *l, size_t q,
                        const double st[2], double ret[3]) {
        int n = mr->hemi_n;
        size_t e[4];
        double h[4];
        hat4(n, n, (st[0] + 1) * n / 2 - 0.5, (st[1] + 1) * n / 2 - 0.5, e, h);
        const float *base = l->hemi + q * (size_t) n * n * 4;
        ret[0] = ret[1] = ret[2] = 0;
        for (int k = 0; k < 4; k++)
                for (int ch = 0; ch < 3; ch++)
                        ret[ch] += h[k] * base[e[k] * 4 + ch];
}

/* Coverage-weighted hat reconstruction over one layer; *ret_sw = Σ hat·coverage. */
static void layer_sample(const struct imp_multires *mr, int L, double x, double y,
                         const double *st, double ret[3], double *ret_sw, double *ret_cov) {
        const struct mr_layer *l = &mr->layers[L];
        size_t q[4];
        double h[4], s[3] = { 0, 0, 0 }, sw = 0, cov = 0;
        hat4(l->nx, l->ny, x / l->cell_mm - 0.5, y / l->cell_mm - 0.5, q, h);
        for (int k = 0; k < 4; k++) {
                double wk = h[k] * l->cov[q[k]];
                cov += h[k] * l->cov[q[k]];
                if (!(wk > 0))
                        continue;
                double c[3] = { l->rgb[3 * q[k]], l->rgb[3 * q[k] + 1], l->rgb[3 * q[k] + 2] };
                if (st && l->hemi)
                        hemi_lookup(mr, l, q[k], st, c);
                sw += wk;
                for (int ch = 0; ch < 3; ch++)
                        s[ch] += wk * c[ch];
        }
        for (int ch = 0; ch < 3; ch++)
                ret[ch] = sw > 0 ? s[ch] / sw : 0;
        *ret_sw = sw;
        *ret_cov = cov;
}

int imp_multires_sample(const struct imp_multires *mr, double x_mm, double y_mm,
                        const double eye_mm[3], double depth, float ret_rgb[3],
                        float *ret_coverage) {
        if (!mr || !ret_rgb || !isfinite(x_mm) || !isfinite(y_mm) || !isfinite(depth) ||
            (eye_mm && (!isfinite(eye_mm[0]) || !isfinite(eye_mm[1]) || !isfinite(eye_mm[2]))))
                return -EINVAL;
        int top = mr->n_layers - 1;
        double d = IMP_CLAMP(depth, 0.0, (double) top);
        int i = (int) floor(d);
        double f = d - i, st[2], *stp = NULL;
        if (eye_mm && mr->hemi_layer >= 0) {
                double om[3] = { eye_mm[0] - x_mm, eye_mm[1] - y_mm, eye_mm[2] };
                imp_multires_dir_to_st(om, st);
                stp = st;
        }
        double s[3] = { 0, 0, 0 }, sw = 0, cov = 0;
        for (int k = 0; k < 2; k++) {
                double lw = k ? f : 1 - f;
                if (lw <= 0)
                        continue;
                int L = IMP_MIN(i + k, top);
                /* view-dependent colour comes from the finest layer with hemisphere arrays */
                int Ls = stp && L > mr->hemi_layer ? mr->hemi_layer : L;
                double c[3], lsw, lcov;
                layer_sample(mr, Ls, x_mm, y_mm, stp, c, &lsw, &lcov);
                if (Ls != L)   /* coverage still reports the requested layer */
                        layer_sample(mr, L, x_mm, y_mm, NULL, (double[3]) {}, &lsw, &lcov);
                cov += lw * lcov;
                sw += lw * lsw;
                for (int ch = 0; ch < 3; ch++)
                        s[ch] += lw * lsw * c[ch];
        }
        for (int ch = 0; ch < 3; ch++)
                ret_rgb[ch] = sw > 0 ? (float) (s[ch] / sw) : mr->empty_value;
        if (ret_coverage)
                *ret_coverage = (float) cov;
        return 0;
}

/* ---- files ---- */

static const char *const layer_names[] = { "R", "G", "B", "coverage", "direct" };
static const char *const hemi_names[] = { "R", "G", "B", "weight" };

static int save_layer(const struct imp_multires *mr, int L, const char *dir, struct imp_error *err) {
        const struct mr_layer *l = &mr->layers[L];
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_new(l->nx, l->ny, 5, IMP_PIX_F32, &img);
        if (r < 0)
                return imp_error_set(err, r, "multires layer %d: cannot allocate the image", L);
        for (int j = 0; j < l->ny; j++)
                for (int i = 0; i < l->nx; i++) {
                        size_t q = (size_t) j * l->nx + i;
                        float *p = imp_image_f32(img, i, j);
                        p[0] = l->rgb[3 * q], p[1] = l->rgb[3 * q + 1], p[2] = l->rgb[3 * q + 2];
                        p[3] = l->cov[q], p[4] = l->direct[q];
                }
        char path[4096];
        snprintf(path, sizeof path, "%s/layer-%d.exr", dir, L);
        if ((r = imp_exr_write(path, img, layer_names, false, err)) < 0 || !l->hemi)
                return r;
        int n = mr->hemi_n;
        imp_image_free(TAKE_PTR(img));
        if ((r = imp_image_new(l->nx * n, l->ny * n, 4, IMP_PIX_F32, &img)) < 0)
                return imp_error_set(err, r, "multires layer %d: cannot allocate the hemisphere image", L);
        for (int j = 0; j < l->ny; j++)
                for (int i = 0; i < l->nx; i++)
                        for (int b = 0; b < n; b++)
                                for (int a = 0; a < n; a++) {
                                        const float *e = l->hemi + (((size_t) j * l->nx + i) * n * n + (size_t) b * n + a) * 4;
                                        memcpy(imp_image_f32(img, i * n + a, j * n + b), e, 4 * sizeof(float));
                                }
        snprintf(path, sizeof path, "%s/hemi-%d.exr", dir, L);
        return imp_exr_write(path, img, hemi_names, false, err);
}

static json_t *index_json(const struct imp_multires *mr) {
        json_t *layers = json_array(), *views = json_array();
        for (int L = 0; L < mr->n_layers; L++) {
                struct imp_multires_layer_info info;
                char f[64], h[64];
                imp_multires_layer_info(mr, L, &info);
                snprintf(f, sizeof f, "layer-%d.exr", L);
                snprintf(h, sizeof h, "hemi-%d.exr", L);
                json_array_append_new(layers, json_pack("{s:i, s:s, s:o, s:[i,i], s:f, s:I, s:I, s:I}",
                        "layer", L, "file", f, "hemi_file", info.has_hemi ? json_string(h) : json_null(),
                        "cells", info.nx, info.ny, "cell_mm", info.cell_mm,
                        "n_direct", (json_int_t) info.n_direct, "n_filled", (json_int_t) info.n_filled,
                        "n_empty", (json_int_t) info.n_empty));
        }
        for (int v = 0; v < mr->n_views; v++)
                json_array_append_new(views, mr->view_fp[v] > 0
                        ? json_pack("{s:f, s:f}", "depth", mr->view_depth[v], "footprint_mm", mr->view_fp[v])
                        : json_pack("{s:n, s:n}", "depth", "footprint_mm"));
        return json_pack("{s:s, s:i, s:[f,f], s:f, s:i, s:f, s:{s:i, s:i, s:s}, s:o, s:o}",
                "format", MR_FORMAT, "version", MR_VERSION,
                "canvas_mm", mr->width_mm, mr->height_mm, "base_cell_mm", mr->base_cell_mm,
                "n_layers", mr->n_layers, "empty_value", (double) mr->empty_value,
                "hemi", "n", mr->hemi_n, "finest_layer", mr->hemi_layer,
                "parameterisation", "(s,t) = (-wx, wy) / (1 + wz), w towards the viewer",
                "layers", layers, "views", views);
}

int imp_multires_save(const struct imp_multires *mr, const char *dir, struct imp_error *err) {
        if (!mr || !dir)
                return imp_error_set(err, -EINVAL, "multires: bad arguments");
        int r = imp_mkdir_p(dir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create the directory", dir);
        for (int L = 0; L < mr->n_layers; L++)
                if ((r = save_layer(mr, L, dir, err)) < 0)
                        return r;
        _cleanup_json_ json_t *j = index_json(mr);
        if (!j)
                return imp_error_set(err, -ENOMEM, "%s: cannot build index.json", dir);
        char path[4096];
        snprintf(path, sizeof path, "%s/index.json", dir);
        return imp_json_save_atomic(path, j, err);
}

/* Reads one EXR into `dst` (stride `per` floats per pixel) by channel name. */
static int load_exr(const char *path, int w, int h, const char *const *names, int nch,
                    float *dst, int n, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        char **file_names = NULL;
        int r = imp_exr_read(path, &img, &file_names, err);
        if (r < 0)
                return r;
        int idx[8];
        for (int c = 0; c < nch; c++)
                if ((idx[c] = imp_image_channel_index(file_names, names[c])) < 0) {
                        imp_strv_free(file_names);
                        return imp_error_set(err, -EBADMSG, "%s: channel %s missing", path, names[c]);
                }
        imp_strv_free(file_names);
        if (img->width != w * n || img->height != h * n)
                return imp_error_set(err, -EBADMSG, "%s: %dx%d pixels, expected %dx%d", path,
                                     img->width, img->height, w * n, h * n);
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        const float *p = imp_image_f32(img, x, y);
                        /* pixel (i·n + a, j·n + b) → cell (i, j), element (a, b) */
                        size_t cell = (size_t) (y / n) * w + x / n;
                        size_t e = (size_t) (y % n) * n + x % n;
                        float *d = dst + (cell * n * n + e) * nch;
                        for (int c = 0; c < nch; c++) {
                                if (!isfinite(p[idx[c]]))
                                        return imp_error_set(err, -EBADMSG, "%s: non-finite value at (%d, %d)", path, x, y);
                                d[c] = p[idx[c]];
                        }
                }
        return 0;
}

static int load_layers(struct imp_multires *mr, const char *dir, struct imp_error *err) {
        char path[4096];
        for (int L = 0; L < mr->n_layers; L++) {
                struct mr_layer *l = &mr->layers[L];
                size_t N = layer_cells(l);
                _cleanup_free_ float *tmp = malloc(N * 5 * sizeof(float));
                if (!tmp)
                        return -ENOMEM;
                snprintf(path, sizeof path, "%s/layer-%d.exr", dir, L);
                int r = load_exr(path, l->nx, l->ny, layer_names, 5, tmp, 1, err);
                if (r < 0)
                        return r;
                for (size_t q = 0; q < N; q++) {
                        memcpy(l->rgb + 3 * q, tmp + 5 * q, 3 * sizeof(float));
                        l->cov[q] = tmp[5 * q + 3];
                        l->direct[q] = tmp[5 * q + 4];
                }
                if (!l->hemi)
                        continue;
                snprintf(path, sizeof path, "%s/hemi-%d.exr", dir, L);
                if ((r = load_exr(path, l->nx, l->ny, hemi_names, 4, l->hemi, mr->hemi_n, err)) < 0)
                        return r;
        }
        return 0;
}

int imp_multires_load(const char *dir, struct imp_multires **ret, struct imp_error *err) {
        if (!dir || !ret)
                return imp_error_set(err, -EINVAL, "multires: bad arguments");
        char path[4096];
        snprintf(path, sizeof path, "%s/index.json", dir);
        _cleanup_json_ json_t *j = NULL;
        int r = imp_json_load(path, &j, err);
        if (r < 0)
                return r;
        const char *fmt = NULL;
        double cw = 0, ch = 0, c0 = 0, empty = 0;
        json_t *canvas = json_object_get(j, "canvas_mm"), *hemi = json_object_get(j, "hemi");
        json_t *layers = json_object_get(j, "layers"), *views = json_object_get(j, "views");
        long long nl = 0, hn = 0, hl = -1;
        if (imp_json_get_string(j, "format", true, &fmt, "index.json", err) < 0 || strcmp(fmt, MR_FORMAT) ||
            imp_json_get_double(j, "base_cell_mm", true, &c0, "index.json", err) < 0 ||
            imp_json_get_int(j, "n_layers", true, &nl, "index.json", err) < 0 ||
            imp_json_get_double(j, "empty_value", true, &empty, "index.json", err) < 0 ||
            !json_is_array(canvas) || json_array_size(canvas) != 2 || !json_is_object(hemi) ||
            imp_json_get_int(hemi, "n", true, &hn, "index.json: hemi.", err) < 0 ||
            imp_json_get_int(hemi, "finest_layer", true, &hl, "index.json: hemi.", err) < 0 ||
            !json_is_array(layers) || !json_is_array(views))
                return imp_error_set(err, -EBADMSG, "%s: not a multires index", path);
        cw = json_number_value(json_array_get(canvas, 0));
        ch = json_number_value(json_array_get(canvas, 1));
        if (!(cw > 0) || !(ch > 0) || !(c0 > 0) || !isfinite(cw) || !isfinite(ch) || !isfinite(c0) ||
            !isfinite(empty) || nl < 1 || nl > IMP_MULTIRES_MAX_LAYERS ||
            json_array_size(layers) != (size_t) nl || hn < 0 || hn > IMP_MULTIRES_MAX_HEMI_N ||
            hl < -1 || hl >= nl || (hn == 0 && hl >= 0))
                return imp_error_set(err, -EBADMSG, "%s: inconsistent pyramid parameters", path);
        int nx0 = (int) ceil(cw / c0 - 1e-9), ny0 = (int) ceil(ch / c0 - 1e-9);
        if (!layer_fits(nx0 << (nl - 1), ny0 << (nl - 1), 5, 1) ||
            (hl >= 0 && !layer_fits(nx0 << hl, ny0 << hl, 4, (int) hn)))
                return imp_error_set(err, -EBADMSG, "%s: pyramid too large", path);
        for (long long L = 0; L < nl; L++) {
                json_t *cells = json_object_get(json_array_get(layers, L), "cells");
                if (json_integer_value(json_array_get(cells, 0)) != (nx0 << L) ||
                    json_integer_value(json_array_get(cells, 1)) != (ny0 << L))
                        return imp_error_set(err, -EBADMSG, "%s: layers[%lld].cells: expected [%d, %d]",
                                             path, L, nx0 << L, ny0 << L);
        }
        _cleanup_multires_ struct imp_multires *mr = calloc(1, sizeof *mr);
        if (!mr)
                return -ENOMEM;
        *mr = (struct imp_multires) { .width_mm = cw, .height_mm = ch, .base_cell_mm = c0,
                .n_layers = (int) nl, .hemi_n = (int) hn, .hemi_layer = (int) hl,
                .empty_value = (float) empty, .n_views = (int) json_array_size(views) };
        mr->view_depth = calloc((size_t) mr->n_views + 1, sizeof(double));
        mr->view_fp = calloc((size_t) mr->n_views + 1, sizeof(double));
        if (!mr->view_depth || !mr->view_fp)
                return -ENOMEM;
        for (int v = 0; v < mr->n_views; v++) {
                json_t *o = json_array_get(views, v);
                double d = json_number_value(json_object_get(o, "depth"));
                double p = json_number_value(json_object_get(o, "footprint_mm"));
                if (isfinite(d) && isfinite(p) && p > 0)
                        mr->view_depth[v] = d, mr->view_fp[v] = p;
        }
        if ((r = alloc_layers(mr, nx0, ny0, false)) < 0)
                return imp_error_set(err, r, "%s: cannot allocate the pyramid", dir);
        if ((r = load_layers(mr, dir, err)) < 0)
                return r;
        *ret = TAKE_PTR(mr);
        return 0;
}
