/* Canvas extraction and heightfield resampling (seed §4.2, §5; see heightfield.h). Works
 * on the range-image grid first (PCA, Sobel, seed fill, erosion, PCA again, vertex
 * normals), then rasterises the range-image mesh into the canvas-frame grid. */
#include <limits.h>
#include <math.h>
#include <omp.h>
#include <string.h>
#include <sys/stat.h>
#include "heightfield.h"
#include "frame-edge.h"
#include "numerics.h"
#include "image.h"
#include "json-util.h"
#include "quality.h"

#define HF_DEFAULT_GRADIENT_REL   0.25
#define HF_DEFAULT_GRADIENT_FLOOR 1e-3
#define HF_DEFAULT_ERODE_PX       1
#define HF_DEFAULT_MAX_EDGE       4.0
#define HF_DEFAULT_SLOPE_MAX      3.0
#define HF_DEFAULT_STEP_MIN       0.1
#define HF_DEFAULT_NORMAL_RADIUS  0
#define HF_MAX_NORMAL_RADIUS      64
#define HF_MAX_TEXELS             ((size_t) 1 << 28)
#define HF_PLANE_WEAK_RATIO       0.99
#define HF_MIN_FILL_FRAC          0.05   /* a seed fill over fewer valid points is retried */
#define HF_DEFAULT_MAX_TILT_DEG   40.0   /* a frame wall's plane is ~90° off */
#define HF_DEFAULT_MAX_VIEW_DEG   75.0
#define HF_DEFAULT_PLANE_TOL      0.5    /* mm: most of a painting's area lies this close */
#define HF_DEFAULT_RELIEF_MAX     3.0    /* mm: impasto rarely stands higher */
#define HF_DEFAULT_MIN_CANVAS_FRAC 0.02
#define HF_DEFAULT_MIN_CANVAS_PTS 200

void imp_heightfield_options_default(struct imp_heightfield_options *opt) {
        *opt = (struct imp_heightfield_options) {
                .gradient_rel = HF_DEFAULT_GRADIENT_REL,
                .gradient_floor_mm = HF_DEFAULT_GRADIENT_FLOOR,
                .erode_px = HF_DEFAULT_ERODE_PX,
                .max_edge_factor = HF_DEFAULT_MAX_EDGE,
                .slope_max = HF_DEFAULT_SLOPE_MAX,
                .step_min_mm = HF_DEFAULT_STEP_MIN,
                .normal_radius = HF_DEFAULT_NORMAL_RADIUS,
                .expected_normal = { 0, 0, 1 },
                .max_tilt_deg = HF_DEFAULT_MAX_TILT_DEG,
                .max_view_deg = HF_DEFAULT_MAX_VIEW_DEG,
                .plane_tol_mm = HF_DEFAULT_PLANE_TOL,
                .relief_max_mm = HF_DEFAULT_RELIEF_MAX,
                .min_canvas_frac = HF_DEFAULT_MIN_CANVAS_FRAC,
                .min_canvas_points = HF_DEFAULT_MIN_CANVAS_PTS,
        };
}

void imp_heightfield_done(struct imp_heightfield *hf) {
        if (!hf)
                return;
        free(hf->height_mm);
        free(hf->nx_);
        free(hf->ny_);
        free(hf->sigma_mm);
        free(hf->mask);
        free(hf->texel_flags);
        free(hf->sigma_n_deg);
        *hf = (struct imp_heightfield) {};
}

/* Half of pca_plane()'s sums over the points with use[i] set, each one chain of additions
 * in point order as one loop would form it. Without m (the centroid's pass): half 0 the sums
 * of x and y, half 1 of z and the count (in s[2]); with m: half 0 the moments xx, xy, xz,
 * half 1 yy, yz, zz, about m. */
static void pca_half(const struct imp_range_image *r, const uint8_t *use, const double *m, int half, double s[3]) {
        size_t N = (size_t) r->width * r->height;
        const float *X = r->xyz;
        double s0 = 0, s1 = 0, s2 = 0;
        if (!m && half == 0) {
                for (size_t i = 0; i < N; i++)
                        if (use[i])
                                s0 += X[3 * i], s1 += X[3 * i + 1];
        } else if (!m) {
                size_t k = 0;
                for (size_t i = 0; i < N; i++)
                        if (use[i])
                                s0 += X[3 * i + 2], k++;
                s2 = (double) k;
        } else {
                int a = half ? 1 : 0;
                for (size_t i = 0; i < N; i++)
                        if (use[i]) {
                                double d[3] = { X[3 * i] - m[0], X[3 * i + 1] - m[1], X[3 * i + 2] - m[2] };
                                s0 += d[a] * d[a], s1 += d[a] * d[a + 1], s2 += d[a + half] * d[2];
                        }
        }
        s[0] = s0, s[1] = s1, s[2] = s2;
}

/* PCA of the points selected by sel (or all valid): centroid and normal (smallest axis,
 * turned towards the camera). Returns the point count. The sums in two halves side by
 * side (pca_half()): the same sums as one thread. */
static size_t pca_plane(const struct imp_range_image *r, const uint8_t *sel, double ret_m[3],
                        double ret_n[3], bool *ret_weak) {
        const uint8_t *use = sel ? sel : r->valid;
        double h[2][3];
        #pragma omp parallel for schedule(static, 1)
        for (int k = 0; k < 2; k++)
                pca_half(r, use, NULL, k, h[k]);
        size_t cnt = (size_t) h[1][2];
        if (cnt == 0)
                return 0;
        double m[3] = { h[0][0], h[0][1], h[1][0] };
        for (int c = 0; c < 3; c++)
                m[c] /= cnt;
        #pragma omp parallel for schedule(static, 1)
        for (int k = 0; k < 2; k++)
                pca_half(r, use, m, k, h[k]);
        double A[9] = { h[0][0], h[0][1], h[0][2], 0, h[1][0], h[1][1], 0, 0, h[1][2] };
        A[3] = A[1], A[6] = A[2], A[7] = A[5];
        double val[3], vec[9];
        imp_eigen_sym3(A, val, vec);
        double n[3] = { vec[0], vec[1], vec[2] };
        double toc[3] = { r->camera_centre_mm[0] - m[0], r->camera_centre_mm[1] - m[1], r->camera_centre_mm[2] - m[2] };
        if (imp_dot3(n, toc) < 0)
                n[0] = -n[0], n[1] = -n[1], n[2] = -n[2];
        if (!imp_normalize3(n))
                n[0] = 0, n[1] = 0, n[2] = 1;
        memcpy(ret_m, m, sizeof m);
        memcpy(ret_n, n, sizeof n);
        *ret_weak = val[0] >= HF_PLANE_WEAK_RATIO * val[1];
        return cnt;
}

/* Percentiles p_lo ≤ p_hi (0..100) of the n values v (reordered: every caller's own
 * scratch), nearest rank: the order statistics, whatever the order of v. The second select
 * runs above the first's rank only (quickselect leaves v[k] with no larger value below it
 * and no smaller one above). */
static int percentiles(float *v, size_t n, double p_lo, double p_hi, float *ret_lo, float *ret_hi) {
        if (n == 0)
                return -ENODATA;
        size_t k_lo = (size_t) llround(p_lo / 100.0 * (double) (n - 1));
        size_t k_hi = (size_t) llround(p_hi / 100.0 * (double) (n - 1));
        *ret_lo = imp_select_kth_float(v, n, k_lo);
        if (ret_hi)
                *ret_hi = k_hi > k_lo ? imp_select_kth_float(v + k_lo + 1, n - k_lo - 1, k_hi - k_lo - 1) : *ret_lo;
        return 0;
}

static int percentile(float *v, size_t n, double p, float *ret) {
        return percentiles(v, n, p, p, ret, NULL);
}

/* Sobel magnitude of h on the valid pixels (normalised by 1/8: height change per pixel);
 * invalid neighbours take the centre value, image borders are clamped. */
static void sobel(const float *h, const uint8_t *valid, int w, int hh, float *g) {
        #pragma omp parallel for schedule(static)
        for (int y = 0; y < hh; y++)
                for (int x = 0; x < w; x++) {
                        size_t i = (size_t) y * w + x;
                        if (!valid[i]) {
                                g[i] = INFINITY;
                                continue;
                        }
                        float n[3][3];
                        for (int dy = -1; dy <= 1; dy++)
                                for (int dx = -1; dx <= 1; dx++) {
                                        int xx = IMP_CLAMP(x + dx, 0, w - 1), yy = IMP_CLAMP(y + dy, 0, hh - 1);
                                        size_t j = (size_t) yy * w + xx;
                                        n[dy + 1][dx + 1] = valid[j] ? h[j] : h[i];
                                }
                        float gx = (n[0][2] + 2 * n[1][2] + n[2][2]) - (n[0][0] + 2 * n[1][0] + n[2][0]);
                        float gy = (n[2][0] + 2 * n[2][1] + n[2][2]) - (n[0][0] + 2 * n[0][1] + n[0][2]);
                        g[i] = sqrtf(gx * gx + gy * gy) / 8.0f;
                }
}

/* What stops the seed fill besides the Sobel threshold: a near-vertical step between two
 * neighbouring range points (first-PCA height h1 with normal n1). */
struct fill_barrier {
        const float *xyz, *h1;
        double n1[3];
        double slope_max, step_min;   /* slope_max <= 0: no slope barrier */
};

static bool fill_crossable(const struct fill_barrier *b, size_t i, size_t j) {
        if (!(b->slope_max > 0))
                return true;
        double dh = fabs((double) b->h1[j] - b->h1[i]);
        if (dh <= b->step_min)
                return true;
        double d2 = 0;
        for (int q = 0; q < 3; q++) {
                double d = (double) b->xyz[3 * j + q] - b->xyz[3 * i + q];
                d2 += d * d;
        }
        double plane2 = fmax(d2 - dh * dh, 0.0);
        return dh <= b->slope_max * sqrt(plane2);
}

static size_t count_set(const uint8_t *v, size_t n) {
        size_t c = 0;
        for (size_t i = 0; i < n; i++)
                c += v[i] != 0;
        return c;
}

/* 4-connected fill from seed over the unmarked pixels with g <= T (g is +inf on invalid
 * pixels, so they stop it) and, with allow, allow set, not across barrier steps: marks
 * them in mark and lists them in queue (N entries), first the seed. Returns their count. */
static size_t flood(const float *g, int w, int h, size_t seed, float T, const struct fill_barrier *b,
                    const uint8_t *allow, uint8_t *mark, uint32_t *queue) {
        size_t head = 0, tail = 0;
        mark[seed] = 1;
        queue[tail++] = (uint32_t) seed;
        while (head < tail) {
                size_t i = queue[head++];
                int x = (int) (i % w), y = (int) (i / w);
                const int dx[4] = { 1, -1, 0, 0 }, dy[4] = { 0, 0, 1, -1 };
                for (int k = 0; k < 4; k++) {
                        int xx = x + dx[k], yy = y + dy[k];
                        if (xx < 0 || yy < 0 || xx >= w || yy >= h)
                                continue;
                        size_t j = (size_t) yy * w + xx;
                        if (!mark[j] && g[j] <= T && (!allow || allow[j]) && fill_crossable(b, i, j)) {
                                mark[j] = 1;
                                queue[tail++] = (uint32_t) j;
                        }
                }
        }
        return tail;
}

static int seed_fill(const float *g, int w, int h, size_t seed, float T, const struct fill_barrier *b,
                     uint8_t *mask) {
        size_t N = (size_t) w * h;
        _cleanup_free_ uint32_t *queue = malloc(N * sizeof(uint32_t));
        if (!queue)
                return -ENOMEM;
        memset(mask, 0, N);
        flood(g, w, h, seed, T, b, NULL, mask, queue);
        return 0;
}

/* Sets the pixels outside mask that are not 8-connected to the image border (holes
 * enclosed by the mask) in ret_filled (a copy of mask otherwise). */
static int fill_holes(const uint8_t *mask, int w, int h, uint8_t *ret_filled) {
        size_t N = (size_t) w * h, top = 0;
        _cleanup_free_ uint32_t *stack = malloc(N * sizeof(uint32_t));
        _cleanup_free_ uint8_t *outside = calloc(N, 1);
        if (!stack || !outside)
                return -ENOMEM;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t i = (size_t) y * w + x;
                        if ((x == 0 || y == 0 || x == w - 1 || y == h - 1) && !mask[i] && !outside[i]) {
                                outside[i] = 1;
                                stack[top++] = (uint32_t) i;
                        }
                }
        while (top > 0) {
                size_t i = stack[--top];
                int x = (int) (i % w), y = (int) (i / w);
                for (int dy = -1; dy <= 1; dy++)
                        for (int dx = -1; dx <= 1; dx++) {
                                int xx = x + dx, yy = y + dy;
                                if (xx < 0 || yy < 0 || xx >= w || yy >= h)
                                        continue;
                                size_t j = (size_t) yy * w + xx;
                                if (!mask[j] && !outside[j]) {
                                        outside[j] = 1;
                                        stack[top++] = (uint32_t) j;
                                }
                        }
        }
        for (size_t i = 0; i < N; i++)
                ret_filled[i] = mask[i] || !outside[i];
        return 0;
}

/* k steps of 8-neighbour erosion; outside the image counts as outside the mask. */
static int erode(uint8_t *mask, int w, int h, int k) {
        size_t N = (size_t) w * h;
        _cleanup_free_ uint8_t *tmp = malloc(N);
        if (!tmp)
                return -ENOMEM;
        for (int step = 0; step < k; step++) {
                memcpy(tmp, mask, N);
                #pragma omp parallel for schedule(static)
                for (int y = 0; y < h; y++)
                        for (int x = 0; x < w; x++) {
                                size_t i = (size_t) y * w + x;
                                if (!tmp[i])
                                        continue;
                                bool keep = x > 0 && y > 0 && x < w - 1 && y < h - 1;
                                for (int dy = -1; keep && dy <= 1; dy++)
                                        for (int dx = -1; keep && dx <= 1; dx++)
                                                keep = tmp[i + (ptrdiff_t) dy * w + dx];
                                mask[i] = keep;
                        }
        }
        return 0;
}

/* Nearest pixel to the centre (ring by ring) that is valid with g <= T. */
static bool find_seed(const float *g, int w, int h, float T, size_t *ret) {
        int cx = w / 2, cy = h / 2, rmax = IMP_MAX(w, h);
        for (int r = 0; r <= rmax; r++)
                for (int y = cy - r; y <= cy + r; y++) {
                        if (y < 0 || y >= h)
                                continue;
                        int step = (y == cy - r || y == cy + r) ? 1 : 2 * r;
                        for (int x = cx - r; x <= cx + r; x += step ? step : 1) {
                                if (x >= 0 && x < w && g[(size_t) y * w + x] <= T) {
                                        *ret = (size_t) y * w + x;
                                        return true;
                                }
                        }
                }
        return false;
}

/* Per-pixel data in the canvas frame: (u, v, h) and the vertex normal, σ_h, σ_n. */
struct hf_ctx {
        const struct imp_range_image *r;
        const uint8_t *canvas;
        float *uvh;          /* 3 per pixel */
        float *nrm;          /* 3 per pixel */
        float *sig;
        float *sig_n_deg;    /* vertex normal σ, degrees */
        double footprint;    /* mm */
        double max_edge2;
};

#define HF_FEW_SAMPLES_EDGE 2.0       /* a triangle with an edge longer than this × the
                                         footprint spans missing range points */

static bool edge_ok(const struct hf_ctx *c, size_t a, size_t b) {
        double s = 0;
        for (int k = 0; k < 3; k++) {
                double d = c->uvh[3 * a + k] - c->uvh[3 * b + k];
                s += d * d;
        }
        return s <= c->max_edge2;
}

/* Vertex normal σ (rms angle, degrees), from the data around the vertex: the
 * least-squares plane h = a + b·u + c·v through the canvas points of its 3×3
 * neighbourhood has residual rms s (n − 3 degrees of freedom), which holds the range noise
 * and the relief the footprint does not resolve; var(b) = s²/Σ(u − ū)², var(c) likewise,
 * and the normal's rms angle is atan √(var b + var c). With fewer than 5 points, the range
 * σ_h through the same fit on a full 3×3 grid: atan(σ_h / (√3·d)), d the footprint. The
 * standard error of the mean of the surrounding triangle normals (their rms angle to it
 * over √n) is added in quadrature for what the plane does not see. */
static float vertex_sigma_deg(const struct hf_ctx *c, int x, int y, double sig_h, const double tri[][3], int n_tri,
                              const double mean[3]) {
        int w = c->r->width, h = c->r->height;
        size_t i = (size_t) y * w + x;
        double S = 0, Su = 0, Sv = 0, Suu = 0, Svv = 0, Suv = 0, Sh = 0, Suh = 0, Svh = 0, Shh = 0;
        for (int dy = -1; dy <= 1; dy++)
                for (int dx = -1; dx <= 1; dx++) {
                        int xx = x + dx, yy = y + dy;
                        if (xx < 0 || yy < 0 || xx >= w || yy >= h)
                                continue;
                        size_t j = (size_t) yy * w + xx;
                        if (!c->canvas[j] || !edge_ok(c, i, j))
                                continue;
                        double u = c->uvh[3 * j] - c->uvh[3 * i], v = c->uvh[3 * j + 1] - c->uvh[3 * i + 1];
                        double hh = c->uvh[3 * j + 2] - c->uvh[3 * i + 2];
                        S += 1, Su += u, Sv += v, Suu += u * u, Svv += v * v, Suv += u * v;
                        Sh += hh, Suh += u * hh, Svh += v * hh, Shh += hh * hh;
                }
        double noise = c->footprint > 0 ? atan(sig_h / (sqrt(3.0) * c->footprint)) : 0;
        if (S >= 5) {
                double cuu = Suu - Su * Su / S, cvv = Svv - Sv * Sv / S, cuv = Suv - Su * Sv / S;
                double cuh = Suh - Su * Sh / S, cvh = Svh - Sv * Sh / S, chh = Shh - Sh * Sh / S;
                double det = cuu * cvv - cuv * cuv;
                if (det > 1e-12 * (cuu * cvv + 1e-300)) {
                        double b = (cvv * cuh - cuv * cvh) / det, cc = (cuu * cvh - cuv * cuh) / det;
                        double s2 = fmax(chh - b * cuh - cc * cvh, 0.0) / (S - 3);
                        noise = atan(sqrt(s2 * (cvv + cuu) / det));   /* var b = s²·cvv/det, var c = s²·cuu/det */
                }
        }
        double ss = 0;
        for (int k = 0; k < n_tri; k++)
                ss += pow(acos(IMP_CLAMP(imp_dot3(tri[k], mean), -1.0, 1.0)), 2);
        double spread2 = n_tri ? ss / ((double) n_tri * n_tri) : 0;   /* of their mean */
        return (float) (sqrt(noise * noise + spread2) * 180 / M_PI);
}

static void vertex_normals(struct hf_ctx *c) {
        int w = c->r->width, h = c->r->height;
        static const int ox[8] = { 1, 1, 0, -1, -1, -1, 0, 1 }, oy[8] = { 0, 1, 1, 1, 0, -1, -1, -1 };
        #pragma omp parallel for schedule(static)
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t i = (size_t) y * w + x;
                        if (!c->canvas[i])
                                continue;
                        double sum[3] = { 0, 0, 0 }, tri[8][3];
                        int n_tri = 0;
                        for (int k = 0; k < 8; k++) {
                                int x1 = x + ox[k], y1 = y + oy[k], x2 = x + ox[(k + 1) % 8], y2 = y + oy[(k + 1) % 8];
                                if (x1 < 0 || y1 < 0 || x1 >= w || y1 >= h || x2 < 0 || y2 < 0 || x2 >= w || y2 >= h)
                                        continue;
                                size_t a = (size_t) y1 * w + x1, b = (size_t) y2 * w + x2;
                                if (!c->canvas[a] || !c->canvas[b] || !edge_ok(c, i, a) || !edge_ok(c, i, b))
                                        continue;
                                double e1[3], e2[3], n[3];
                                for (int q = 0; q < 3; q++) {
                                        e1[q] = c->uvh[3 * a + q] - c->uvh[3 * i + q];
                                        e2[q] = c->uvh[3 * b + q] - c->uvh[3 * i + q];
                                }
                                imp_cross3(e1, e2, n);
                                if (n[2] < 0)   /* orient by the (u, v) winding: towards +h */
                                        n[0] = -n[0], n[1] = -n[1], n[2] = -n[2];
                                if (!imp_normalize3(n))
                                        continue;
                                for (int q = 0; q < 3; q++)
                                        sum[q] += tri[n_tri][q] = n[q];
                                n_tri++;
                        }
                        if (!imp_normalize3(sum))
                                sum[0] = 0, sum[1] = 0, sum[2] = 1;
                        for (int q = 0; q < 3; q++)
                                c->nrm[3 * i + q] = (float) sum[q];
                        c->sig_n_deg[i] = vertex_sigma_deg(c, x, y, c->sig[i], tri, n_tri, sum);
                }
}

/* σ_n pooled over the 3×3 vertex neighbourhood: the larger of a vertex's own σ and the
 * rms of its canvas neighbours'. One 3×3 fit has 6 degrees of freedom, so its residual
 * alone understates the noise at one vertex in a hundred by a factor of 2.6 or more (χ²₆
 * 1 % quantile 0.87 vs 6); pooling nine overlapping fits narrows that, and a texel next to
 * steep relief inherits its neighbours' doubt. */
static int pool_sigma_n(struct hf_ctx *c) {
        int w = c->r->width, h = c->r->height;
        size_t N = (size_t) w * h;
        _cleanup_free_ float *own = malloc(N * sizeof(float));
        if (!own)
                return -ENOMEM;
        memcpy(own, c->sig_n_deg, N * sizeof(float));
        #pragma omp parallel for schedule(static)
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t i = (size_t) y * w + x;
                        if (!c->canvas[i])
                                continue;
                        double ss = 0;
                        int n = 0;
                        for (int dy = -1; dy <= 1; dy++)
                                for (int dx = -1; dx <= 1; dx++) {
                                        int xx = x + dx, yy = y + dy;
                                        size_t j = (size_t) yy * w + xx;
                                        if (xx < 0 || yy < 0 || xx >= w || yy >= h || !c->canvas[j])
                                                continue;
                                        ss += (double) own[j] * own[j];
                                        n++;
                                }
                        c->sig_n_deg[i] = (float) fmax(own[i], sqrt(ss / n));
                }
        return 0;
}

/* Rasterise triangle (a, b, c) of range pixels into the grid rows [band0, band1). */
static void raster_tri(const struct hf_ctx *c, size_t a, size_t b, size_t d, struct imp_heightfield *hf,
                       double umin, double vmin, int band0, int band1) {
        double p = hf->pitch_mm;
        double X[3], Y[3], e2max = 0;
        size_t id[3] = { a, b, d };
        for (int k = 0; k < 3; k++) {
                X[k] = (c->uvh[3 * id[k]] - umin) / p;
                Y[k] = (c->uvh[3 * id[k] + 1] - vmin) / p;
        }
        for (int k = 0; k < 3; k++) {
                double e2 = 0;
                for (int q = 0; q < 3; q++)
                        e2 += pow(c->uvh[3 * id[k] + q] - c->uvh[3 * id[(k + 1) % 3] + q], 2);
                e2max = fmax(e2max, e2);
        }
        uint16_t tri_flags = sqrt(e2max) > HF_FEW_SAMPLES_EDGE * c->footprint ? IMP_TEXEL_FEW_SAMPLES : 0;
        /* the decoder's doubts about a vertex (clipped frames, phase rejected) are the texel's */
        for (int k = 0; k < 3 && c->r->flags; k++)
                tri_flags |= c->r->flags[id[k]] & (IMP_TEXEL_SATURATED | IMP_TEXEL_PHASE_REJECTED);
        double area = (X[1] - X[0]) * (Y[2] - Y[0]) - (X[2] - X[0]) * (Y[1] - Y[0]);
        if (fabs(area) < 1e-12)
                return;
        int i0 = (int) ceil(fmin(X[0], fmin(X[1], X[2])) - 1e-9), i1 = (int) floor(fmax(X[0], fmax(X[1], X[2])) + 1e-9);
        int j0 = (int) ceil(fmin(Y[0], fmin(Y[1], Y[2])) - 1e-9), j1 = (int) floor(fmax(Y[0], fmax(Y[1], Y[2])) + 1e-9);
        i0 = IMP_MAX(i0, 0), j0 = IMP_MAX(j0, band0), i1 = IMP_MIN(i1, hf->nx - 1), j1 = IMP_MIN(j1, band1 - 1);
        const double eps = -1e-9;
        for (int j = j0; j <= j1; j++)
                for (int i = i0; i <= i1; i++) {
                        double l1 = ((X[2] - X[0]) * (j - Y[0]) - (i - X[0]) * (Y[2] - Y[0])) / -area;
                        double l2 = ((X[1] - X[0]) * (j - Y[0]) - (i - X[0]) * (Y[1] - Y[0])) / area;
                        double l0 = 1 - l1 - l2;
                        if (l0 < eps || l1 < eps || l2 < eps)
                                continue;
                        double L[3] = { l0, l1, l2 }, hh = 0, s = 0, sn = 0, n[3] = { 0, 0, 0 };
                        for (int k = 0; k < 3; k++) {
                                hh += L[k] * c->uvh[3 * id[k] + 2];
                                s += L[k] * c->sig[id[k]];
                                sn += L[k] * c->sig_n_deg[id[k]];
                                for (int q = 0; q < 3; q++)
                                        n[q] += L[k] * c->nrm[3 * id[k] + q];
                        }
                        if (!imp_normalize3(n))
                                n[0] = 0, n[1] = 0, n[2] = 1;
                        size_t t = (size_t) j * hf->nx + i;
                        hf->height_mm[t] = (float) hh;
                        hf->sigma_mm[t] = (float) s;
                        hf->sigma_n_deg[t] = (float) sn;
                        hf->nx_[t] = (float) n[0];
                        hf->ny_[t] = (float) n[1];
                        hf->texel_flags[t] = tri_flags;
                        hf->mask[t] = 1;
                }
}

/* Grid rows that the triangles of range row y (its points and row y + 1's) can reach, one
 * more each side: [ret_lo[y], ret_hi[y]]; empty (lo > hi) without canvas points. */
static void row_reach(const struct hf_ctx *c, double vmin, double p, int *ret_lo, int *ret_hi) {
        int w = c->r->width, h = c->r->height;
        #pragma omp parallel for schedule(static)
        for (int y = 0; y < h - 1; y++) {
                double lo = INFINITY, hi = -INFINITY;
                for (size_t i = (size_t) y * w; i < (size_t) (y + 2) * w; i++)
                        if (c->canvas[i]) {
                                double Y = (c->uvh[3 * i + 1] - vmin) / p;   /* as raster_tri() */
                                lo = fmin(lo, Y), hi = fmax(hi, Y);
                        }
                ret_lo[y] = lo <= hi ? (int) ceil(lo - 1e-9) - 1 : INT_MAX;
                ret_hi[y] = lo <= hi ? (int) floor(hi + 1e-9) + 1 : INT_MIN;
        }
}

/* The range mesh (two triangles a pixel quad, edges checked) rasterised into the grid in
 * bands of grid rows, one a thread: each thread takes every triangle that reaches its band,
 * in the serial order, and writes only its rows, so a texel two triangles cover keeps the
 * later one's values as in one pass (test-heightfield-bands). */
static int raster_mesh(const struct hf_ctx *c, double umin, double vmin, struct imp_heightfield *hf) {
        int w = c->r->width, h = c->r->height;
        const uint8_t *canvas = c->canvas;
        size_t nh = (size_t) IMP_MAX(h, 1);
        _cleanup_free_ int *lo = malloc(nh * sizeof(int)), *hi = malloc(nh * sizeof(int));
        if (!lo || !hi)
                return -ENOMEM;
        row_reach(c, vmin, hf->pitch_mm, lo, hi);
        #pragma omp parallel
        {
                int nt = omp_get_num_threads(), t = omp_get_thread_num();
                int band0 = (int) ((long) hf->ny * t / nt), band1 = (int) ((long) hf->ny * (t + 1) / nt);
                for (int y = 0; y + 1 < h; y++) {
                        if (hi[y] < band0 || lo[y] >= band1)
                                continue;
                        for (int x = 0; x + 1 < w; x++) {
                                size_t a = (size_t) y * w + x, b = a + 1, d = a + w, e = d + 1;
                                if (canvas[a] && canvas[b] && canvas[d] && edge_ok(c, a, b) && edge_ok(c, a, d) &&
                                    edge_ok(c, b, d))
                                        raster_tri(c, a, b, d, hf, umin, vmin, band0, band1);
                                if (canvas[b] && canvas[e] && canvas[d] && edge_ok(c, b, e) && edge_ok(c, e, d) &&
                                    edge_ok(c, b, d))
                                        raster_tri(c, b, e, d, hf, umin, vmin, band0, band1);
                        }
                }
        }
        return 0;
}

/* Replaces the texel normals by the normal of the least-squares plane h = a + b·u + c·v
 * through the masked texels of the (2r+1)² window. Texels whose window does not determine
 * a plane (fewer than 3 texels, or all on a line) keep the interpolated vertex normal. */
static int plane_normals(struct imp_heightfield *hf, int rad) {
        int nx = hf->nx, ny = hf->ny;
        size_t n_tex = (size_t) nx * ny;
        _cleanup_free_ float *onx = malloc(n_tex * sizeof(float)), *ony = malloc(n_tex * sizeof(float));
        if (!onx || !ony)
                return -ENOMEM;
        memcpy(onx, hf->nx_, n_tex * sizeof(float));
        memcpy(ony, hf->ny_, n_tex * sizeof(float));
        double p = hf->pitch_mm;
        #pragma omp parallel for schedule(dynamic, 16)
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t t = (size_t) j * nx + i;
                        if (!hf->mask[t])
                                continue;
                        /* Moments about the window centre in texel units. */
                        double S = 0, Su = 0, Sv = 0, Suu = 0, Svv = 0, Suv = 0, Sh = 0, Suh = 0, Svh = 0;
                        double h0 = hf->height_mm[t];
                        for (int dv = -rad; dv <= rad; dv++) {
                                int jj = j + dv;
                                if (jj < 0 || jj >= ny)
                                        continue;
                                for (int du = -rad; du <= rad; du++) {
                                        int ii = i + du;
                                        if (ii < 0 || ii >= nx)
                                                continue;
                                        size_t q = (size_t) jj * nx + ii;
                                        if (!hf->mask[q])
                                                continue;
                                        double hh = hf->height_mm[q] - h0;
                                        S += 1, Su += du, Sv += dv, Suu += du * du, Svv += dv * dv, Suv += du * dv;
                                        Sh += hh, Suh += du * hh, Svh += dv * hh;
                                }
                        }
                        if (S < 3)
                                continue;
                        /* Centre the moments, solve the 2×2 normal equations for b, c. */
                        double cuu = Suu - Su * Su / S, cvv = Svv - Sv * Sv / S, cuv = Suv - Su * Sv / S;
                        double cuh = Suh - Su * Sh / S, cvh = Svh - Sv * Sh / S;
                        double det = cuu * cvv - cuv * cuv;
                        if (!(det > 1e-9 * (cuu * cvv + 1e-300)) || !(det > 0))
                                continue;
                        double b = (cvv * cuh - cuv * cvh) / det / p, c = (cuu * cvh - cuv * cuh) / det / p;
                        double n[3] = { -b, -c, 1 };
                        if (!imp_normalize3(n))
                                continue;
                        onx[t] = (float) n[0];
                        ony[t] = (float) n[1];
                }
        memcpy(hf->nx_, onx, n_tex * sizeof(float));
        memcpy(hf->ny_, ony, n_tex * sizeof(float));
        return 0;
}

/* Shadow fill (heightfield.h, shadow_fill_px). */
#define HF_FILL_SLOPE_SIGMA 0.035     /* tan 2°: slope uncertainty integrated over the fill */

struct fill_frame {                   /* canvas frame: origin m, axes ex, ey, ez; grid origin */
        const double *m, *ex, *ey, *ez;
        double umin, vmin, h_frame;
};

/* Frame texels: non-canvas points above h_frame splatted onto the grid, dilated by one
 * texel (8-neighbours). */
static void frame_texels(const struct imp_heightfield *hf, const struct imp_range_image *range,
                         const uint8_t *canvas, const struct fill_frame *f, uint8_t *splat, uint8_t *ret) {
        int nx = hf->nx, ny = hf->ny;
        size_t N = (size_t) range->width * range->height;
        memset(splat, 0, (size_t) nx * ny);
        for (size_t i = 0; i < N; i++) {
                if (!range->valid[i] || canvas[i])
                        continue;
                const float *X = range->xyz + 3 * i;
                double d[3] = { X[0] - f->m[0], X[1] - f->m[1], X[2] - f->m[2] };
                if (!(imp_dot3(d, f->ez) > f->h_frame))
                        continue;
                long ti = lround((imp_dot3(d, f->ex) - f->umin) / hf->pitch_mm);
                long tj = lround((imp_dot3(d, f->ey) - f->vmin) / hf->pitch_mm);
                if (ti >= 0 && tj >= 0 && ti < nx && tj < ny)
                        splat[(size_t) tj * nx + ti] = 1;
        }
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        bool on = false;
                        for (int dy = -1; dy <= 1 && !on; dy++)
                                for (int dx = -1; dx <= 1 && !on; dx++) {
                                        int ii = i + dx, jj = j + dy;
                                        on = ii >= 0 && jj >= 0 && ii < nx && jj < ny && splat[(size_t) jj * nx + ii];
                                }
                        ret[(size_t) j * nx + i] = on;
                }
}

/* k-th 4-neighbour (0..3) of texel t on an nx × ny grid; false when off the grid. */
static bool neighbour4(int nx, int ny, size_t t, int k, size_t *ret_u) {
        static const int ox[4] = { 1, -1, 0, 0 }, oy[4] = { 0, 0, 1, -1 };
        int ii = (int) (t % nx) + ox[k], jj = (int) (t / nx) + oy[k];
        if (ii < 0 || jj < 0 || ii >= nx || jj >= ny)
                return false;
        *ret_u = (size_t) jj * nx + ii;
        return true;
}

/* Fills the uncovered texels between the measured canvas and the frame (see
 * heightfield.h). Returns the number filled or -ENOMEM. */
static long shadow_fill(struct imp_heightfield *hf, const struct imp_range_image *range, const uint8_t *canvas,
                        const struct fill_frame *f, int max_px) {
        int nx = hf->nx, ny = hf->ny;
        size_t n = (size_t) nx * ny;
        _cleanup_free_ uint8_t *frame = malloc(n), *state = calloc(n, 1);
        _cleanup_free_ uint32_t *stack = malloc(n * sizeof(uint32_t)), *src = malloc(n * sizeof(uint32_t));
        _cleanup_free_ uint16_t *dist = malloc(n * sizeof(uint16_t));
        if (!frame || !state || !stack || !src || !dist)
                return -ENOMEM;
        frame_texels(hf, range, canvas, f, state, frame);
        /* Enclosed by the canvas and the frame = not reached from the padded grid's border
         * (8-connected): fill_holes. state: 0 candidate, 1 not enclosed, 2 canvas or frame. */
        for (size_t t = 0; t < n; t++)
                state[t] = hf->mask[t] || frame[t];
        _cleanup_free_ uint8_t *enclosed = malloc(n);
        if (!enclosed)
                return -ENOMEM;
        int r = fill_holes(state, nx, ny, enclosed);
        if (r < 0)
                return r;
        for (size_t t = 0; t < n; t++)
                state[t] = state[t] ? 2 : enclosed[t] ? 0 : 1;
        /* Enclosed components (4-connected): accepted (3) when they touch the frame. */
        for (size_t t0 = 0; t0 < n; t0++) {
                if (state[t0] != 0)
                        continue;
                size_t first = 0, end = 0;
                bool touches = false;
                state[t0] = 4;
                src[end++] = (uint32_t) t0;   /* src as the component's list */
                while (first < end) {
                        size_t t = src[first++], u;
                        for (int k = 0; k < 4; k++) {
                                if (!neighbour4(nx, ny, t, k, &u))
                                        continue;
                                touches |= frame[u] != 0;
                                if (state[u] == 0) {
                                        state[u] = 4;
                                        src[end++] = (uint32_t) u;
                                }
                        }
                }
                for (size_t k = 0; k < end; k++)
                        state[src[k]] = touches ? 3 : 5;
        }
        /* Breadth-first from the measured texels into accepted ones, up to max_px steps:
         * nearest measured texel (src) and the distance. */
        size_t head = 0, tail = 0;
        for (size_t t = 0; t < n; t++)
                if (hf->mask[t]) {
                        src[t] = (uint32_t) t, dist[t] = 0;
                        stack[tail++] = (uint32_t) t;
                }
        long filled = 0;
        while (head < tail) {
                size_t t = stack[head++], u;
                if (dist[t] >= max_px)
                        continue;
                for (int k = 0; k < 4; k++) {
                        if (!neighbour4(nx, ny, t, k, &u) || state[u] != 3)
                                continue;
                        state[u] = 6;
                        src[u] = src[t], dist[u] = (uint16_t) (dist[t] + 1);
                        size_t s = src[u];
                        double ds = dist[u] * hf->pitch_mm * HF_FILL_SLOPE_SIGMA;
                        hf->mask[u] = IMP_HF_MASK_FILLED;
                        hf->height_mm[u] = hf->height_mm[s];
                        hf->nx_[u] = 0, hf->ny_[u] = 0;
                        hf->sigma_mm[u] = (float) hypot(hf->sigma_mm[s], ds);
                        hf->sigma_n_deg[u] = 90;   /* unknown until normals come */
                        hf->texel_flags[u] = IMP_TEXEL_FILLED;
                        stack[tail++] = (uint32_t) u;
                        filled++;
                }
        }
        return filled;
}

/* Crops the grid to the mask's bounding box; moves the grid origin (umin, vmin). */
static int crop_to_mask(struct imp_heightfield *hf, double *umin, double *vmin) {
        int i0 = hf->nx, i1 = -1, j0 = hf->ny, j1 = -1;
        for (int j = 0; j < hf->ny; j++)
                for (int i = 0; i < hf->nx; i++)
                        if (hf->mask[(size_t) j * hf->nx + i]) {
                                i0 = IMP_MIN(i0, i), i1 = IMP_MAX(i1, i);
                                j0 = IMP_MIN(j0, j), j1 = IMP_MAX(j1, j);
                        }
        if (i1 < 0 || (i0 == 0 && j0 == 0 && i1 == hf->nx - 1 && j1 == hf->ny - 1))
                return 0;
        int w = i1 - i0 + 1, h = j1 - j0 + 1;
        float **f[4] = { &hf->height_mm, &hf->nx_, &hf->ny_, &hf->sigma_mm };
        for (int k = 0; k < 4; k++) {
                float *o = malloc((size_t) w * h * sizeof(float));
                if (!o)
                        return -ENOMEM;
                for (int j = 0; j < h; j++)
                        memcpy(o + (size_t) j * w, *f[k] + (size_t) (j + j0) * hf->nx + i0, w * sizeof(float));
                free(*f[k]);
                *f[k] = o;
        }
        uint8_t *o = malloc((size_t) w * h);
        uint16_t *of = malloc((size_t) w * h * sizeof *of);
        float *osn = malloc((size_t) w * h * sizeof *osn);
        if (!o || !of || !osn) {
                free(o), free(of), free(osn);
                return -ENOMEM;
        }
        for (int j = 0; j < h; j++) {
                size_t src = (size_t) (j + j0) * hf->nx + i0;
                memcpy(o + (size_t) j * w, hf->mask + src, w);
                memcpy(of + (size_t) j * w, hf->texel_flags + src, w * sizeof *of);
                memcpy(osn + (size_t) j * w, hf->sigma_n_deg + src, w * sizeof *osn);
        }
        free(hf->mask);
        free(hf->texel_flags);
        free(hf->sigma_n_deg);
        hf->mask = o;
        hf->texel_flags = of;
        hf->sigma_n_deg = osn;
        hf->nx = w, hf->ny = h;
        *umin += i0 * hf->pitch_mm, *vmin += j0 * hf->pitch_mm;
        return 0;
}

void imp_heightfield_drop_filled(struct imp_heightfield *hf, const uint8_t *drop) {
        if (!hf || !hf->mask)
                return;
        int nx = hf->nx, ny = hf->ny;
        size_t n = (size_t) nx * ny;
        for (size_t t = 0; t < n; t++)
                if (hf->mask[t] == IMP_HF_MASK_FILLED && (!drop || drop[t]))
                        hf->mask[t] = 0;
        /* Filled texels cut off from the measured canvas go too: mark the connected ones
         * (value 3 temporarily) from every measured texel. */
        _cleanup_free_ uint32_t *stack = malloc((n ? n : 1) * sizeof(uint32_t));
        size_t top = 0;
        if (stack) {
                for (size_t t = 0; t < n; t++)
                        if (hf->mask[t] == IMP_HF_MASK_MEASURED)
                                stack[top++] = (uint32_t) t;
                while (top > 0) {
                        size_t t = stack[--top], u;
                        for (int k = 0; k < 4; k++) {
                                if (neighbour4(nx, ny, t, k, &u) && hf->mask[u] == IMP_HF_MASK_FILLED) {
                                        hf->mask[u] = 3;
                                        stack[top++] = (uint32_t) u;
                                }
                        }
                }
        }
        hf->n_mask_texels = hf->n_filled_texels = 0;
        for (size_t t = 0; t < n; t++) {
                if (hf->mask[t] == 3 || (!stack && hf->mask[t] == IMP_HF_MASK_FILLED))
                        hf->mask[t] = IMP_HF_MASK_FILLED;
                else if (hf->mask[t] != IMP_HF_MASK_MEASURED) {
                        hf->mask[t] = 0;
                        hf->height_mm[t] = hf->nx_[t] = hf->ny_[t] = hf->sigma_mm[t] = 0;
                        if (hf->sigma_n_deg)
                                hf->sigma_n_deg[t] = 0;
                        if (hf->texel_flags)
                                hf->texel_flags[t] = 0;
                }
                hf->n_mask_texels += hf->mask[t] != 0;
                hf->n_filled_texels += hf->mask[t] == IMP_HF_MASK_FILLED;
        }
}

/* ---- robust canvas plane (placement) ---- */

#define HF_RANSAC_ITER       400
#define HF_RANSAC_MAX_SCORE  20000    /* points scored per hypothesis (strided subsample) */
#define HF_RANSAC_REFINE     3        /* PCA passes on the inliers */

static double angle_deg(const double a[3], const double b[3]) {
        return acos(IMP_CLAMP(imp_dot3(a, b), -1.0, 1.0)) * 180 / M_PI;
}

/* Plane through points a, b, c, turned towards the camera; false when degenerate. */
static bool plane3(const float *a, const float *b, const float *c, const double C[3], double ret_n[3]) {
        double e1[3], e2[3], toc[3];
        for (int q = 0; q < 3; q++) {
                e1[q] = (double) b[q] - a[q];
                e2[q] = (double) c[q] - a[q];
                toc[q] = C[q] - a[q];
        }
        imp_cross3(e1, e2, ret_n);
        double l = sqrt(imp_dot3(ret_n, ret_n));
        if (!(l > 1e-3 * imp_dot3(e1, e1) && l > 1e-3 * imp_dot3(e2, e2)))   /* sin(angle) > 1e-3 */
                return false;
        imp_normalize3(ret_n);
        if (imp_dot3(ret_n, toc) < 0)
                ret_n[0] = -ret_n[0], ret_n[1] = -ret_n[1], ret_n[2] = -ret_n[2];
        return true;
}

/* Signed distance of point i in front of the plane (p, n), towards the camera. */
static double plane_dist(const struct imp_range_image *r, size_t i, const double p[3], const double n[3]) {
        const float *X = r->xyz + 3 * i;
        double d[3] = { X[0] - p[0], X[1] - p[1], X[2] - p[2] };
        return imp_dot3(d, n);
}

/* Points RANSAC may use: valid and, with a previous plane (behind_n not NULL), more than
 * 2·plane_tol_mm behind it. */
struct ransac_set {
        const double *behind_p, *behind_n;
        double tol;
};
static bool ransac_use(const struct imp_range_image *r, const struct ransac_set *set, size_t i) {
        return r->valid[i] && (!set->behind_n || plane_dist(r, i, set->behind_p, set->behind_n) < -2 * set->tol);
}

/* One RANSAC search: hypotheses from three usable points of the image's central half (the
 * canvas is centred in the shot, seed §4.2); score = usable points within plane_tol_mm (a
 * strided subsample). Any orientation is considered: were only planes near the rig's pose
 * allowed, a canvas tilted far off it would leave its frame's walls as the best plane;
 * the tilt is checked on the result (canvas_frame) and refused there. Deterministic
 * (fixed xorshift seed). Returns the best score (0: every hypothesis degenerate). */
static size_t ransac_search(const struct imp_range_image *r, const struct imp_heightfield_options *opt,
                            const struct ransac_set *set, uint32_t *central, double ret_p[3], double ret_n[3]) {
        int w = r->width, h = r->height;
        size_t N = (size_t) w * h, n_use = 0, n_central = 0, best = 0;
        for (size_t i = 0; i < N; i++)
                n_use += ransac_use(r, set, i);
        for (int y = h / 4; y < h - h / 4; y++)
                for (int x = w / 4; x < w - w / 4; x++)
                        if (ransac_use(r, set, (size_t) y * w + x))
                                central[n_central++] = (uint32_t) ((size_t) y * w + x);
        if (n_central < 3)
                return 0;
        size_t stride = n_use > HF_RANSAC_MAX_SCORE ? n_use / HF_RANSAC_MAX_SCORE : 1;
        uint64_t st = 0x9e3779b97f4a7c15ull;
        for (int it = 0; it < HF_RANSAC_ITER; it++) {
                size_t id[3];
                for (int k = 0; k < 3; k++) {
                        st ^= st << 13, st ^= st >> 7, st ^= st << 17;
                        id[k] = central[st % n_central];
                }
                const float *a = r->xyz + 3 * id[0];
                double n[3], p[3] = { a[0], a[1], a[2] };
                if (!plane3(a, r->xyz + 3 * id[1], r->xyz + 3 * id[2], r->camera_centre_mm, n))
                        continue;
                size_t score = 0;
                for (size_t i = 0; i < N; i += stride)
                        score += ransac_use(r, set, i) && fabs(plane_dist(r, i, p, n)) <= opt->plane_tol_mm;
                if (score > best) {
                        best = score;
                        memcpy(ret_n, n, 3 * sizeof *n);
                        memcpy(ret_p, p, 3 * sizeof *p);
                }
        }
        return best;
}

/* The canvas plane, robustly (seed §4.2 takes the PCA of every point; a deep or oblique
 * frame's walls and tops, or wild decode points, pull that off the canvas). RANSAC
 * (ransac_search); then, since a frame stands in front of its canvas, a plane parallel to
 * it (within 10°) behind it with at least a fifth of its support replaces it, as long as
 * there is one; then PCA on the inliers, HF_RANSAC_REFINE times. Returns false when every
 * hypothesis was degenerate. */
#define HF_BEHIND_MIN_SUPPORT 0.2
#define HF_BEHIND_MAX_DEG     10.0
static bool ransac_plane(const struct imp_range_image *r, const struct imp_heightfield_options *opt,
                         uint8_t *scratch, double ret_m[3], double ret_n[3], double *ret_frac) {
        size_t N = (size_t) r->width * r->height, n_valid = 0;
        for (size_t i = 0; i < N; i++)
                n_valid += r->valid[i] != 0;
        _cleanup_free_ uint32_t *central = malloc((N ? N : 1) * sizeof(uint32_t));
        if (!central || n_valid < 3)
                return false;
        struct ransac_set set = { .tol = opt->plane_tol_mm };
        double bp[3], bn[3], p[3], n[3];
        size_t best = ransac_search(r, opt, &set, central, bp, bn);
        if (best == 0)
                return false;
        for (int k = 0; k < 3; k++) {
                double pp[3] = { bp[0], bp[1], bp[2] }, pn[3] = { bn[0], bn[1], bn[2] };
                set.behind_p = pp, set.behind_n = pn;
                size_t sc = ransac_search(r, opt, &set, central, p, n);
                if (sc < HF_BEHIND_MIN_SUPPORT * best ||
                    (angle_deg(n, pn) > HF_BEHIND_MAX_DEG &&
                     !(angle_deg(n, opt->expected_normal) < angle_deg(pn, opt->expected_normal) - HF_BEHIND_MAX_DEG)))
                        break;
                memcpy(bp, p, sizeof bp);
                memcpy(bn, n, sizeof bn);
                best = sc;
        }
        size_t n_in = 0;
        for (int pass = 0; pass < HF_RANSAC_REFINE; pass++) {
                n_in = 0;
                for (size_t i = 0; i < N; i++)
                        n_in += scratch[i] = r->valid[i] && fabs(plane_dist(r, i, bp, bn)) <= opt->plane_tol_mm;
                bool weak;
                double m[3];
                if (n_in < 3 || pca_plane(r, scratch, m, n, &weak) < 3)
                        break;
                memcpy(bp, m, sizeof bp);
                memcpy(bn, n, sizeof bn);
        }
        memcpy(ret_m, bp, sizeof bp);
        memcpy(ret_n, bn, sizeof bn);
        *ret_frac = (double) n_in / n_valid;
        return true;
}

/* Median distance between horizontally adjacent canvas points (vertically when no row
 * holds two): *ret_3d between the 3-D points (what the mesh's edges are measured against:
 * it grows with range noise), *ret_plane between the points where their viewing rays meet
 * the canvas plane (m, n): the camera footprint on the canvas, which range noise along the
 * ray does not change (the ray's direction is (X − C)/|X − C| whatever the noise). 0 when
 * no pair exists. */
static bool ray_on_plane(const struct imp_range_image *r, size_t i, const double m[3], const double n[3],
                         double ret[3]) {
        const double *C = r->camera_centre_mm;
        double d[3], mc[3];
        for (int q = 0; q < 3; q++)
                d[q] = r->xyz[3 * i + q] - C[q], mc[q] = m[q] - C[q];
        double dn = imp_dot3(d, n);
        if (!(fabs(dn) > 1e-9 * sqrt(imp_dot3(d, d))))
                return false;
        double s = imp_dot3(mc, n) / dn;
        for (int q = 0; q < 3; q++)
                ret[q] = C[q] + s * d[q];
        return true;
}

/* The pairs of row y (dir 0: (x, x + 1); dir 1: (x, x + w)) into dist and dp from their
 * start; returns their counts in ret_nd, ret_np. */
static void footprint_row(const struct imp_range_image *range, const uint8_t *canvas, const double m[3],
                          const double n[3], int dir, int y, float *dist, float *dp, size_t *ret_nd, size_t *ret_np) {
        int w = range->width;
        size_t nd = 0, np = 0;
        for (int x = 0; x + 1 - dir < w; x++) {
                size_t i = (size_t) y * w + x, j = dir ? i + w : i + 1;
                if (!canvas[i] || !canvas[j])
                        continue;
                double s2 = 0, pi[3], pj[3];
                for (int q = 0; q < 3; q++) {
                        double dd = range->xyz[3 * i + q] - range->xyz[3 * j + q];
                        s2 += dd * dd;
                }
                dist[nd++] = (float) sqrt(s2);
                if (ray_on_plane(range, i, m, n, pi) && ray_on_plane(range, j, m, n, pj))
                        dp[np++] = (float) sqrt(pow(pi[0] - pj[0], 2) + pow(pi[1] - pj[1], 2) + pow(pi[2] - pj[2], 2));
        }
        *ret_nd = nd, *ret_np = np;
}

/* Rows in parallel, each into its own w slots, then packed: the medians are order
 * statistics, the same in any order. */
static int footprint_mm(const struct imp_range_image *range, const uint8_t *canvas, const double m[3],
                        const double n[3], double *ret_3d, double *ret_plane) {
        int w = range->width, h = range->height;
        size_t N = (size_t) w * h;
        _cleanup_free_ float *dist = malloc(N * sizeof(float)), *dp = malloc(N * sizeof(float));
        _cleanup_free_ size_t *cnt = malloc((size_t) IMP_MAX(h, 1) * 2 * sizeof(size_t));
        if (!dist || !dp || !cnt)
                return -ENOMEM;
        size_t nd = 0, np = 0;
        for (int dir = 0; dir < 2 && nd == 0; dir++) {
                #pragma omp parallel for schedule(static)
                for (int y = 0; y < h - dir; y++)
                        footprint_row(range, canvas, m, n, dir, y, dist + (size_t) y * w, dp + (size_t) y * w,
                                      &cnt[2 * y], &cnt[2 * y + 1]);
                for (int y = 0; y < h - dir; y++) {
                        memmove(dist + nd, dist + (size_t) y * w, cnt[2 * y] * sizeof(float));
                        memmove(dp + np, dp + (size_t) y * w, cnt[2 * y + 1] * sizeof(float));
                        nd += cnt[2 * y], np += cnt[2 * y + 1];
                }
        }
        float med = 0, medp = 0;
        int r = 0, rp = 0;
        #pragma omp parallel sections
        {
                #pragma omp section
                r = nd ? percentile(dist, nd, 50, &med) : 0;
                #pragma omp section
                rp = np ? percentile(dp, np, 50, &medp) : 0;
        }
        *ret_3d = med;
        *ret_plane = np ? medp : med;
        return r < 0 ? r : rp;
}

/* A flush frame cut off the seed fill by its albedo step (frame-edge.h); bins of two
 * camera footprints on the robust plane. */
static int trim_flush_frame(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                            const double m1[3], const double n1[3], struct imp_heightfield *hf, uint8_t *canvas) {
        double d3, dp;
        int r = footprint_mm(range, canvas, m1, n1, &d3, &dp);
        if (r < 0 || !(dp > 0))
                return r;
        struct imp_frame_edge fe;
        if ((r = imp_frame_edge_trim(range, opt->albedo, m1, n1, 2 * dp, canvas, &fe)) < 0)
                return r;
        hf->n_frame_trimmed = fe.n_trimmed;
        memcpy(hf->frame_trim_mm, fe.trim_mm, sizeof fe.trim_mm);
        if (fe.sides_trimmed)
                hf->flags |= IMP_HF_FRAME_TRIMMED;
        return 0;
}

/* ---- high relief: the canvas between the paint's walls ---- */

#define HF_POCKET_MIN_FRAC 0.002   /* of the valid points: a smaller component is no pocket */
#define HF_POCKET_MIN_PX   20
#define HF_POCKET_LEVEL_P  10.0    /* a pocket's ground level: this percentile of its heights */
#define HF_RELIEF_MIN_PX   9       /* a smaller component inside the hull is noise */
#define HF_IMPASTO_MM      1.0     /* paint this high over the ground ... */
#define HF_IMPASTO_FRAC    0.05    /* ... on this fraction of the hull's valid points: high relief */

/* Per image row the x interval of the convex hull of the set pixels of sel (Andrew's
 * monotone chain over each row's outermost set pixels); xl > xr on rows it misses. */
struct hull_pt {
        double x, y;
};

static int cmp_hull_pt(const void *a, const void *b) {
        const struct hull_pt *p = a, *q = b;
        return p->x < q->x ? -1 : p->x > q->x ? 1 : p->y < q->y ? -1 : p->y > q->y;
}

static double hull_turn(const struct hull_pt *o, const struct hull_pt *a, const struct hull_pt *b) {
        return (a->x - o->x) * (b->y - o->y) - (a->y - o->y) * (b->x - o->x);
}

static int hull_rows(const uint8_t *sel, int w, int h, double *xl, double *xr) {
        _cleanup_free_ struct hull_pt *pt = malloc((size_t) 2 * h * sizeof *pt);
        _cleanup_free_ struct hull_pt *H = malloc(((size_t) 4 * h + 2) * sizeof *H);
        if (!pt || !H)
                return -ENOMEM;
        size_t n = 0, k = 0;
        for (int y = 0; y < h; y++) {
                int lo = -1, hi = -1;
                for (int x = 0; x < w; x++)
                        if (sel[(size_t) y * w + x]) {
                                lo = lo < 0 ? x : lo;
                                hi = x;
                        }
                if (lo >= 0) {
                        pt[n++] = (struct hull_pt) { lo, y };
                        if (hi != lo)
                                pt[n++] = (struct hull_pt) { hi, y };
                }
                xl[y] = INFINITY, xr[y] = -INFINITY;
        }
        qsort(pt, n, sizeof *pt, cmp_hull_pt);
        for (size_t i = 0; i < n; i++) {   /* lower chain */
                while (k >= 2 && hull_turn(&H[k - 2], &H[k - 1], &pt[i]) <= 0)
                        k--;
                H[k++] = pt[i];
        }
        for (size_t i = n - 1, t = k + 1; n > 1 && i-- > 0;) {   /* upper chain */
                while (k >= t && hull_turn(&H[k - 2], &H[k - 1], &pt[i]) <= 0)
                        k--;
                H[k++] = pt[i];
        }
        for (size_t e = 0; e < k; e++) {
                const struct hull_pt *a = &H[e], *b = &H[(e + 1) % k];
                int y0 = (int) ceil(fmin(a->y, b->y)), y1 = (int) floor(fmax(a->y, b->y));
                for (int y = IMP_MAX(y0, 0); y <= IMP_MIN(y1, h - 1); y++) {
                        double x = a->y == b->y ? a->x : a->x + (y - a->y) * (b->x - a->x) / (b->y - a->y);
                        double x2 = a->y == b->y ? b->x : x;
                        xl[y] = fmin(xl[y], fmin(x, x2)), xr[y] = fmax(xr[y], fmax(x, x2));
                }
        }
        return 0;
}

/* The components of the fill's graph met in pixel order that are not marked yet and hold
 * at least min_px pixels (flood over g, within allow when set): keep(ctx, list, n) says
 * whether one joins add (and counts it). */
struct relief_ctx {
        const float *h1, *g;
        float T, ref_level, level_tol;
        const struct fill_barrier *b;
        float *hv;                    /* scratch, N */
};

static bool pocket_at_ground(const struct relief_ctx *c, const uint32_t *list, size_t n) {
        for (size_t q = 0; q < n; q++)
                c->hv[q] = c->h1[list[q]];
        float level;
        return percentile(c->hv, n, HF_POCKET_LEVEL_P, &level) == 0 && fabsf(level - c->ref_level) <= c->level_tol;
}

static size_t add_components(const struct relief_ctx *c, int w, int h, const uint8_t *allow, size_t min_px,
                             bool ground_only, uint8_t *mark, uint32_t *queue, uint8_t *add) {
        size_t N = (size_t) w * h, added = 0;
        for (size_t i = 0; i < N; i++) {
                if (mark[i] || !(c->g[i] <= c->T) || (allow && !allow[i]))
                        continue;
                size_t n = flood(c->g, w, h, i, c->T, c->b, allow, mark, queue);
                if (n < min_px || (ground_only && !pocket_at_ground(c, queue, n)))
                        continue;
                for (size_t q = 0; q < n; q++)
                        add[queue[q]] = 1;
                added += n;
        }
        return added;
}

/* Heavy impasto (strokes several millimetres high, their walls near vertical, the
 * projector's shadows beside them) cuts the ground into pockets the seed fill cannot
 * leave (seed §4.2 takes the frame's step for the only large one), and lifts the paint's
 * tops past relief_max_mm. Paint may stand as high as a frame; what tells them apart is
 * where they lie: the frame around the canvas, the paint on it. So: the other pockets at
 * the seed region's ground level (components of the fill's graph holding at least
 * HF_POCKET_MIN_FRAC of the valid points whose HF_POCKET_LEVEL_P-th height percentile
 * lies within step_min_mm of the seed region's, or of the plane when the seed region
 * stands on it, paint; none when it lies behind the plane, which is then no ground: a
 * frame's top larger than the canvas seen)
 * join the canvas, and so does every component of the fill's graph, at any height, inside
 * the convex hull of them all in the image (the canvas seen through its frame is convex;
 * the frame and its walls lie outside it) — when paint stands HF_IMPASTO_MM over the
 * ground on HF_IMPASTO_FRAC of the valid points in that hull: range broken up by dark
 * paint or ambient light, on a canvas with no high relief, is no relief's doing, and its
 * refusal names the cause (hard-ambient-dark). A frame standing step_min_mm off the canvas is
 * no pocket; a flush one is in the seed fill already (the albedo trim cuts it). graw: the
 * Sobel magnitude (+inf on invalid pixels) without the relief_max_mm exclusion; inside (N)
 * is set to the hull when anything joined, cleared otherwise. */
static int relief_pockets(int w, int h, const float *h1, const float *g, const float *graw, float T,
                          const struct imp_heightfield_options *opt, const struct fill_barrier *b,
                          size_t n_valid, struct imp_heightfield *hf, uint8_t *canvas, uint8_t *inside) {
        size_t N = (size_t) w * h, nr = 0;
        _cleanup_free_ float *hv = malloc(N * sizeof(float));
        _cleanup_free_ uint32_t *queue = malloc(N * sizeof(uint32_t));
        _cleanup_free_ uint8_t *mark = malloc(N), *sel = malloc(N);
        _cleanup_free_ double *xl = malloc(h * sizeof(double)), *xr = malloc(h * sizeof(double));
        if (!hv || !queue || !mark || !sel || !xl || !xr)
                return -ENOMEM;
        for (size_t i = 0; i < N; i++)
                if (canvas[i])
                        hv[nr++] = h1[i];
        float ref = 0;
        memset(inside, 0, N);
        if (nr == 0 || percentile(hv, nr, HF_POCKET_LEVEL_P, &ref) < 0)
                return 0;
        if (ref < -opt->plane_tol_mm)   /* the plane lies in front of the seed's ground: no ground */
                return 0;
        if (ref > opt->plane_tol_mm)    /* the seed on paint: the plane's level is the ground's */
                ref = 0;
        struct relief_ctx c = { .h1 = h1, .g = g, .T = T, .ref_level = ref, .level_tol = (float) b->step_min,
                                .b = b, .hv = hv };
        size_t min_px = (size_t) fmax(HF_POCKET_MIN_PX, HF_POCKET_MIN_FRAC * (double) n_valid);
        memcpy(mark, canvas, N);
        memcpy(sel, canvas, N);
        size_t added = add_components(&c, w, h, NULL, min_px, true, mark, queue, sel);
        int r = hull_rows(sel, w, h, xl, xr);
        if (r < 0)
                return r;
        size_t n_in = 0, n_high = 0;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t i = (size_t) y * w + x;
                        inside[i] = x >= xl[y] - 1e-9 && x <= xr[y] + 1e-9;
                        n_in += inside[i] && isfinite(graw[i]);
                        n_high += inside[i] && isfinite(graw[i]) && h1[i] - ref > HF_IMPASTO_MM;
                }
        if (added == 0 || n_high < HF_IMPASTO_FRAC * n_in) {   /* not the relief's pockets: as before */
                memset(inside, 0, N);
                return 0;
        }
        memcpy(canvas, sel, N);
        c.g = graw;
        memcpy(mark, canvas, N);
        added += add_components(&c, w, h, inside, HF_RELIEF_MIN_PX, false, mark, queue, canvas);
        hf->n_relief_points = added;
        return 0;
}

/* The canvas on the range grid (seed §4.2 with a robust plane): heights h1 over the robust
 * plane (m1, n1), points beyond relief_max_mm excluded, Sobel, seed fill from the centre
 * stopped at high gradient and near-vertical steps, erosion. */
static int canvas_mask(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                       const double m1[3], const double n1[3], struct imp_heightfield *hf, uint8_t *canvas) {
        int w = range->width, h = range->height, r;
        size_t N = (size_t) w * h, k = 0;
        _cleanup_free_ float *h1 = malloc(N * sizeof(float)), *g = malloc(N * sizeof(float));
        _cleanup_free_ float *hv = malloc(hf->n_range_points * sizeof(float)), *graw = malloc(N * sizeof(float));
        if (!h1 || !g || !hv || !graw)
                return -ENOMEM;
        for (size_t i = 0; i < N; i++) {
                if (!range->valid[i]) {
                        h1[i] = 0;
                        continue;
                }
                double d[3] = { range->xyz[3 * i] - m1[0], range->xyz[3 * i + 1] - m1[1], range->xyz[3 * i + 2] - m1[2] };
                h1[i] = hv[k++] = (float) imp_dot3(d, n1);
        }
        float p1, p99;
        if ((r = percentiles(hv, k, 1, 99, &p1, &p99)) < 0)
                return r;
        float T = (float) fmax(opt->gradient_rel * (p99 - p1), opt->gradient_floor_mm);
        hf->gradient_threshold_mm = T;
        sobel(h1, range->valid, w, h, g);
        memcpy(graw, g, N * sizeof(float));
        for (size_t i = 0; i < N; i++)   /* the frame by geometry: far off the canvas plane */
                if (range->valid[i] && fabs(h1[i]) > opt->relief_max_mm) {
                        g[i] = INFINITY;
                        hf->n_excluded_points++;
                }
        size_t seed, centre = (size_t) (h / 2) * w + w / 2;
        if (!find_seed(g, w, h, T, &seed))
                return -ENODATA;
        if (seed != centre)
                hf->flags |= IMP_HF_SEED_MOVED;
        struct fill_barrier b = { .xyz = range->xyz, .h1 = h1, .n1 = { n1[0], n1[1], n1[2] },
                                  .slope_max = opt->slope_max, .step_min = opt->step_min_mm };
        if ((r = seed_fill(g, w, h, seed, T, &b, canvas)) < 0)
                return r;
        /* A fill that stops almost at once is a staircase, not a frame: a Gray-only
         * decode with a camera finer than the projector gives terraces one projector
         * column wide whose risers pass for near-vertical steps. Raise step_min (doubling)
         * until the fill spreads; with no level below the relief span that does, drop
         * the slope barrier. */
        while (b.slope_max > 0 && count_set(canvas, N) < HF_MIN_FILL_FRAC * hf->n_range_points) {
                b.step_min = fmax(2 * b.step_min, 0.05);
                if (b.step_min > 0.5 * (p99 - p1))
                        b.slope_max = 0;
                hf->flags |= IMP_HF_STEP_RAISED;
                if ((r = seed_fill(g, w, h, seed, T, &b, canvas)) < 0)
                        return r;
        }
        hf->step_min_used_mm = b.slope_max > 0 ? b.step_min : INFINITY;
        _cleanup_free_ uint8_t *hull = malloc(N);
        if (!hull)
                return -ENOMEM;
        if ((r = relief_pockets(w, h, h1, g, graw, T, opt, &b, hf->n_range_points, hf, canvas, hull)) < 0)
                return r;
        for (size_t i = 0; i < N; i++)   /* what the albedo trim cuts off is rim again */
                hull[i] = hull[i] && !canvas[i];
        if (opt->albedo && (r = trim_flush_frame(range, opt, m1, n1, hf, canvas)) < 0)
                return r;
        if (opt->keep_holes)
                return erode(canvas, w, h, opt->erode_px);
        /* Erode the hole-filled mask, then keep only filled pixels: holes do not grow, the
         * outer rim shrinks by erode_px. Inside the hull of the canvas's pockets there is no
         * outer rim: the shadows and unmeasured walls of the paint are holes too. */
        _cleanup_free_ uint8_t *solid = malloc(N);
        if (!solid)
                return -ENOMEM;
        if ((r = fill_holes(canvas, w, h, solid)) < 0)
                return r;
        for (size_t i = 0; i < N; i++)
                solid[i] |= hull[i];
        if ((r = erode(solid, w, h, opt->erode_px)) < 0)
                return r;
        for (size_t i = 0; i < N; i++)
                canvas[i] = canvas[i] && solid[i];
        return 0;
}

/* A painting's tile: every valid point within relief_max_mm of the robust plane. */
static void whole_field_mask(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                             const double m1[3], const double n1[3], struct imp_heightfield *hf, uint8_t *canvas) {
        size_t N = (size_t) range->width * range->height;
        for (size_t i = 0; i < N; i++) {
                canvas[i] = 0;
                if (!range->valid[i])
                        continue;
                const float *X = range->xyz + 3 * i;
                double d[3] = { X[0] - m1[0], X[1] - m1[1], X[2] - m1[2] };
                if (fabs(imp_dot3(d, n1)) > opt->relief_max_mm)
                        hf->n_excluded_points++;
                else
                        canvas[i] = 1;
        }
        hf->step_min_used_mm = INFINITY;   /* no slope barrier */
}

/* The canvas's base plane: the PCA plane of the canvas points at or below the median
 * height over the current plane, HF_BASE_PASSES times. Relief (a ridge, strokes) stands
 * on the base; in a least-squares plane through every point it tilts the plane towards
 * where it lies, the more so the less canvas is seen. The normal ez is replaced; the
 * origin m stays the centroid of every canvas point. */
#define HF_BASE_PASSES 2
static int base_plane(const struct imp_range_image *range, const uint8_t *canvas, const double m[3], double ez[3]) {
        size_t N = (size_t) range->width * range->height, k = 0;
        _cleanup_free_ float *hv = malloc((N ? N : 1) * sizeof(float));
        _cleanup_free_ uint8_t *low = malloc(N ? N : 1);
        if (!hv || !low)
                return -ENOMEM;
        for (int pass = 0; pass < HF_BASE_PASSES; pass++) {
                k = 0;
                for (size_t i = 0; i < N; i++)
                        if (canvas[i])
                                hv[k++] = (float) plane_dist(range, i, m, ez);
                float med;
                int r = percentile(hv, k, 50, &med);
                if (r < 0)
                        return r;
                for (size_t i = 0; i < N; i++)
                        low[i] = canvas[i] && plane_dist(range, i, m, ez) <= med;
                double mm[3], n[3];
                bool weak;
                if (pca_plane(range, low, mm, n, &weak) < 3 || weak)
                        return 0;
                memcpy(ez, n, sizeof n);
        }
        return 0;
}

/* The canvas frame from the canvas points (second PCA, seed §4.2) and the placement checks
 * against the rig: tilt from the expected normal, viewing angle, amount of canvas. */
static int canvas_frame(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                        const uint8_t *canvas, struct imp_heightfield *hf, double m[3], double ex[3],
                        double ey[3], double ez[3], struct imp_error *err) {
        bool weak;
        hf->n_canvas_points = pca_plane(range, canvas, m, ez, &weak);
        if (hf->n_canvas_points < 3)
                return imp_error_set(err, -ENODATA, "no canvas: %zu of %zu valid range points left after the "
                                     "seed fill", hf->n_canvas_points, hf->n_range_points);
        if (!opt->skip_extraction) {
                int r = base_plane(range, canvas, m, ez);
                if (r < 0)
                        return r;
        }
        if (weak)
                hf->flags |= IMP_HF_PLANE_WEAK;
        double toc[3] = { range->camera_centre_mm[0] - m[0], range->camera_centre_mm[1] - m[1],
                          range->camera_centre_mm[2] - m[2] };
        imp_normalize3(toc);
        hf->plane_tilt_deg = angle_deg(ez, opt->expected_normal);
        hf->plane_view_deg = angle_deg(ez, toc);
        if (!opt->skip_extraction) {
                size_t min_pts = (size_t) fmax((double) opt->min_canvas_points,
                                               opt->min_canvas_frac * (double) hf->n_range_points);
                if (hf->plane_tilt_deg > opt->max_tilt_deg)
                        return imp_error_set(err, -ENODATA, "no plausible canvas: its plane is %.0f° off the "
                                             "rig's canvas normal (at most %.0f° expected)",
                                             hf->plane_tilt_deg, opt->max_tilt_deg);
                if (hf->plane_view_deg > opt->max_view_deg)
                        return imp_error_set(err, -ENODATA, "no plausible canvas: seen %.0f° off its normal "
                                             "(at most %.0f°)", hf->plane_view_deg, opt->max_view_deg);
                if (hf->n_canvas_points < min_pts)
                        return imp_error_set(err, -ENODATA, "too little canvas: %zu of %zu valid range points "
                                             "(at least %zu needed)", hf->n_canvas_points,
                                             hf->n_range_points, min_pts);
        }
        imp_canvas_axes(ez, ex, ey);
        return 0;
}

/* Canvas points in the canvas frame (uvh), their σ_h (range σ projected on the normal),
 * their bounding box, the plane rms and the shadow fill's frame threshold. */
struct frame_pts {
        double m[3], ex[3], ey[3], ez[3];
        double umin, vmin, umax, vmax;
};

static int project_canvas(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                          const uint8_t *canvas, struct frame_pts *f, float *uvh, float *sig,
                          struct imp_heightfield *hf) {
        size_t N = (size_t) range->width * range->height, k = 0;
        double ss = 0;
        _cleanup_free_ float *hv = malloc(hf->n_canvas_points * sizeof(float));
        if (!hv)
                return -ENOMEM;
        double umin = INFINITY, vmin = INFINITY, umax = -INFINITY, vmax = -INFINITY;
        #pragma omp parallel for schedule(static) reduction(min: umin, vmin) reduction(max: umax, vmax)
        for (size_t i = 0; i < N; i++) {
                if (!canvas[i])
                        continue;
                const float *X = range->xyz + 3 * i;
                double d[3] = { X[0] - f->m[0], X[1] - f->m[1], X[2] - f->m[2] };
                double u = imp_dot3(d, f->ex), v = imp_dot3(d, f->ey), hh = imp_dot3(d, f->ez);
                uvh[3 * i] = (float) u, uvh[3 * i + 1] = (float) v, uvh[3 * i + 2] = (float) hh;
                double ray[3] = { X[0] - range->camera_centre_mm[0], X[1] - range->camera_centre_mm[1],
                                  X[2] - range->camera_centre_mm[2] };
                double cosr = imp_normalize3(ray) ? fabs(imp_dot3(ray, f->ez)) : 1.0;
                sig[i] = range->sigma_mm ? (float) (range->sigma_mm[i] * cosr) : 0.0f;
                umin = fmin(umin, u), umax = fmax(umax, u);
                vmin = fmin(vmin, v), vmax = fmax(vmax, v);
        }
        f->umin = umin, f->vmin = vmin, f->umax = umax, f->vmax = vmax;
        for (size_t i = 0; i < N; i++) {   /* the sum in one order: the rms the same every run */
                if (!canvas[i])
                        continue;
                const float *X = range->xyz + 3 * i;
                double d[3] = { X[0] - f->m[0], X[1] - f->m[1], X[2] - f->m[2] };
                double hh = imp_dot3(d, f->ez);
                hv[k++] = (float) hh;
                ss += hh * hh;
        }
        hf->plane_rms_mm = sqrt(ss / hf->n_canvas_points);
        if (opt->shadow_fill_px > 0 && !opt->skip_extraction && !opt->whole_field) {   /* frame threshold: h99 + (h99 − h1) */
                float c1, c99;
                int r;
                if ((r = percentiles(hv, k, 1, 99, &c1, &c99)) < 0)
                        return r;
                hf->frame_height_mm = c99 + fmax((double) c99 - c1, opt->step_min_mm);
        }
        return 0;
}

static int alloc_grid(struct imp_heightfield *hf) {
        size_t n_tex = (size_t) hf->nx * hf->ny;
        hf->height_mm = calloc(n_tex, sizeof(float));
        hf->nx_ = calloc(n_tex, sizeof(float));
        hf->ny_ = calloc(n_tex, sizeof(float));
        hf->sigma_mm = calloc(n_tex, sizeof(float));
        hf->sigma_n_deg = calloc(n_tex, sizeof(float));
        hf->texel_flags = calloc(n_tex, sizeof(uint16_t));
        hf->mask = calloc(n_tex, 1);
        return hf->height_mm && hf->nx_ && hf->ny_ && hf->sigma_mm && hf->sigma_n_deg && hf->texel_flags && hf->mask
               ? 0 : -ENOMEM;
}

/* The range mesh rasterised into the canvas-frame grid, then the shadow fill (the grid is
 * padded for it and cropped to the mask again). */
static int rasterise(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                     const uint8_t *canvas, struct frame_pts *f, struct hf_ctx *c, struct imp_heightfield *hf) {
        int r;
        bool fill = opt->shadow_fill_px > 0 && !opt->skip_extraction && !opt->whole_field;   /* no frame */
        if (fill) {   /* room for the fill; cropped again below */
                double pad = opt->shadow_fill_px * hf->pitch_mm;
                f->umin -= pad, f->vmin -= pad, f->umax += pad, f->vmax += pad;
        }
        double gx = floor((f->umax - f->umin) / hf->pitch_mm + 1e-9) + 1;
        double gy = floor((f->vmax - f->vmin) / hf->pitch_mm + 1e-9) + 1;
        if (!(gx * gy <= (double) HF_MAX_TEXELS))
                return -E2BIG;
        hf->nx = (int) gx, hf->ny = (int) gy;
        if ((r = alloc_grid(hf)) < 0)
                return r;
        vertex_normals(c);
        if ((r = pool_sigma_n(c)) < 0)
                return r;
        if ((r = raster_mesh(c, f->umin, f->vmin, hf)) < 0)
                return r;
        if (opt->normal_radius > 0 && (r = plane_normals(hf, opt->normal_radius)) < 0)
                return r;
        if (fill) {
                struct fill_frame ff = { f->m, f->ex, f->ey, f->ez, f->umin, f->vmin, hf->frame_height_mm };
                long nf = shadow_fill(hf, range, canvas, &ff, opt->shadow_fill_px);
                if (nf < 0)
                        return (int) nf;
                if ((r = crop_to_mask(hf, &f->umin, &f->vmin)) < 0)
                        return r;
                hf->n_filled_texels = (size_t) nf;
        }
        return 0;
}

void imp_heightfield_sigma_moved(struct imp_heightfield *hf, const float *measured_mm) {
        size_t n = (size_t) hf->nx * hf->ny;
        for (size_t t = 0; t < n && measured_mm; t++)
                if (hf->mask[t] == IMP_HF_MASK_MEASURED && isfinite(hf->height_mm[t]) && isfinite(measured_mm[t]))
                        hf->sigma_mm[t] = (float) hypot(hf->sigma_mm[t], hf->height_mm[t] - measured_mm[t]);
}

int imp_heightfield_flag_edges(struct imp_heightfield *hf, int px) {
        size_t n = (size_t) hf->nx * hf->ny;
        _cleanup_free_ uint8_t *solid = malloc(n ? n : 1);
        if (!solid)
                return -ENOMEM;
        int r = fill_holes(hf->mask, hf->nx, hf->ny, solid);
        if (r < 0 || (r = erode(solid, hf->nx, hf->ny, px)) < 0)
                return r;
        for (size_t t = 0; t < n; t++) {
                if (!hf->mask[t]) {
                        hf->texel_flags[t] = 0;
                        continue;
                }
                hf->texel_flags[t] &= (uint16_t) ~(IMP_TEXEL_FRAME_ADJACENT | IMP_TEXEL_FILLED |
                                                   IMP_TEXEL_NORMAL_UNCERTAIN);
                if (!solid[t])
                        hf->texel_flags[t] |= IMP_TEXEL_FRAME_ADJACENT;
                if (!(hf->sigma_n_deg[t] <= IMP_TEXEL_NORMAL_SIGMA_MAX_DEG))
                        hf->texel_flags[t] |= IMP_TEXEL_NORMAL_UNCERTAIN;
                if (hf->mask[t] == IMP_HF_MASK_FILLED)
                        hf->texel_flags[t] |= IMP_TEXEL_FILLED;
        }
        return 0;
}


static bool options_ok(const struct imp_heightfield_options *opt) {
        return opt->erode_px >= 0 && opt->gradient_rel > 0 && opt->max_edge_factor > 0 && opt->normal_radius >= 0 &&
               opt->normal_radius <= HF_MAX_NORMAL_RADIUS && !isnan(opt->slope_max) && opt->step_min_mm >= 0 &&
               opt->shadow_fill_px >= 0 && opt->shadow_fill_px <= UINT16_MAX - 1 && opt->max_tilt_deg > 0 &&
               opt->max_tilt_deg <= 90 && opt->max_view_deg > 0 && opt->max_view_deg <= 90 && opt->plane_tol_mm > 0 &&
               opt->relief_max_mm > 0 && opt->min_canvas_frac >= 0 && opt->min_canvas_frac < 1 &&
               fabs(sqrt(imp_dot3(opt->expected_normal, opt->expected_normal)) - 1) < 1e-6;
}

/* The canvas plane to extract against: robust (RANSAC) or, when no plane fits the rig's
 * pose, the PCA of every point (flagged; the placement checks then decide). */
static int first_plane(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                       uint8_t *scratch, struct imp_heightfield *hf, double m1[3], double n1[3]) {
        bool weak;
        hf->n_range_points = pca_plane(range, NULL, m1, n1, &weak);
        if (hf->n_range_points < 3)
                return -ENODATA;
        if (!ransac_plane(range, opt, scratch, m1, n1, &hf->ransac_inlier_frac))
                hf->flags |= IMP_HF_PLANE_NO_CONSENSUS;
        return 0;
}

/* The texels inside the convex hull of the mask (the canvas's outline as measured): the
 * holes of a canvas whose relief hides or shadows much of it lie within it. */
static int outline_texels(struct imp_heightfield *hf) {
        _cleanup_free_ double *xl = malloc(hf->ny * sizeof(double)), *xr = malloc(hf->ny * sizeof(double));
        if (!xl || !xr)
                return -ENOMEM;
        int r = hull_rows(hf->mask, hf->nx, hf->ny, xl, xr);
        if (r < 0)
                return r;
        hf->n_outline_texels = 0;
        for (int y = 0; y < hf->ny; y++)
                if (xr[y] >= xl[y])
                        hf->n_outline_texels += (size_t) (IMP_MIN(floor(xr[y] + 1e-9), hf->nx - 1.0) -
                                                          IMP_MAX(ceil(xl[y] - 1e-9), 0.0) + 1);
        return 0;
}

int imp_heightfield_extract(const struct imp_range_image *range, const struct imp_heightfield_options *opt,
                            struct imp_heightfield *ret, struct imp_error *err) {
        struct imp_heightfield_options defaults;
        if (!range || !ret || range->width <= 0 || range->height <= 0 || !range->xyz || !range->valid)
                return -EINVAL;
        if (!opt) {
                imp_heightfield_options_default(&defaults);
                opt = &defaults;
        }
        if (!options_ok(opt))
                return -EINVAL;
        size_t N = (size_t) range->width * range->height;
        if (N > UINT32_MAX)
                return -E2BIG;
        _cleanup_(imp_heightfield_done) struct imp_heightfield hf = {};
        struct frame_pts f;
        double n1[3];
        _cleanup_free_ uint8_t *canvas = malloc(N);
        if (!canvas)
                return -ENOMEM;
        int r = first_plane(range, opt, canvas, &hf, f.m, n1);
        if (r < 0)
                return imp_error_set(err, r, "no canvas: fewer than 3 valid range points");
        if (opt->skip_extraction) {
                for (size_t i = 0; i < N; i++)
                        canvas[i] = range->valid[i] != 0;
        } else if (opt->whole_field) {
                whole_field_mask(range, opt, f.m, n1, &hf, canvas);
        } else if ((r = canvas_mask(range, opt, f.m, n1, &hf, canvas)) < 0)
                return r == -ENODATA ? imp_error_set(err, r, "no canvas: no seed point of low gradient near "
                                                     "the image centre") : r;
        if ((r = canvas_frame(range, opt, canvas, &hf, f.m, f.ex, f.ey, f.ez, err)) < 0)
                return r;
        _cleanup_free_ float *uvh = malloc(N * 3 * sizeof(float)), *nrm = malloc(N * 3 * sizeof(float));
        _cleanup_free_ float *sig = malloc(N * sizeof(float)), *sig_n = malloc(N * sizeof(float));
        if (!uvh || !nrm || !sig || !sig_n)
                return -ENOMEM;
        if ((r = project_canvas(range, opt, canvas, &f, uvh, sig, &hf)) < 0)
                return r;
        if ((r = footprint_mm(range, canvas, f.m, f.ez, &hf.neighbour_mm, &hf.footprint_mm)) < 0)
                return r;
        if (!(hf.footprint_mm > 0 && hf.neighbour_mm > 0))
                return imp_error_set(err, -ENODATA, "no canvas: no two neighbouring canvas points");
        /* The 3-D neighbour distance (what the copy's pitch always was: on a clean scan a
         * hair above the footprint, by the relief's slope) capped by the footprint on the
         * plane, which range noise does not grow. (At the footprint itself the demo
         * measured worse: 3.65 µm and 2.26° against 3.13 µm and 1.72° at 1.009 × it.) */
        hf.pitch_mm = opt->pitch_mm > 0 ? opt->pitch_mm : fmin(hf.neighbour_mm, IMP_HF_PITCH_NOISE_CAP * hf.footprint_mm);
        /* Mesh edges are 3-D distances: measured against the 3-D neighbour distance. */
        double max_edge = opt->max_edge_factor * fmax(hf.neighbour_mm, hf.pitch_mm);
        struct hf_ctx c = { .r = range, .canvas = canvas, .uvh = uvh, .nrm = nrm, .sig = sig, .sig_n_deg = sig_n,
                            .footprint = hf.neighbour_mm, .max_edge2 = max_edge * max_edge };
        if ((r = rasterise(range, opt, canvas, &f, &c, &hf)) < 0)
                return r;
        if ((r = imp_heightfield_flag_edges(&hf, IMP_HF_FRAME_ADJACENT_PX)) < 0)
                return r;
        size_t n_tex = (size_t) hf.nx * hf.ny;
        for (size_t t = 0; t < n_tex; t++)
                hf.n_mask_texels += hf.mask[t] != 0;
        if (hf.n_mask_texels == 0)
                return imp_error_set(err, -ENODATA, "no canvas: no texel covered by the range mesh");
        if ((r = outline_texels(&hf)) < 0)
                return r;
        double *M = hf.canvas_to_world;
        for (int q = 0; q < 3; q++) {
                M[4 * q + 0] = f.ex[q];
                M[4 * q + 1] = f.ey[q];
                M[4 * q + 2] = f.ez[q];
                M[4 * q + 3] = f.m[q] + f.umin * f.ex[q] + f.vmin * f.ey[q];
        }
        M[12] = M[13] = M[14] = 0, M[15] = 1;
        *ret = hf;
        hf = (struct imp_heightfield) {};
        return 0;
}

int imp_heightfield_from_range(const struct imp_range_image *range,
                               const struct imp_heightfield_options *opt, struct imp_heightfield *ret) {
        return imp_heightfield_extract(range, opt, ret, NULL);
}

json_t *imp_heightfield_stage_json(const struct imp_heightfield *hf) {
        return json_pack("{s:I,s:I,s:I,s:I,s:f,s:f,s:f,s:f,s:f,s:f,s:b,s:b,s:b,s:f,s:f,s:f,s:f,s:I,s:b,s:I,s:I,s:I,s:b}",
                         "range_points", (json_int_t) hf->n_range_points,
                         "canvas_points", (json_int_t) hf->n_canvas_points,
                         "mask_texels", (json_int_t) hf->n_mask_texels,
                         "shadow_filled_texels", (json_int_t) hf->n_filled_texels,
                         "frame_height_mm", hf->frame_height_mm,
                         "plane_rms_mm", hf->plane_rms_mm,
                         "gradient_threshold_mm", hf->gradient_threshold_mm,
                         "footprint_mm", hf->footprint_mm, "neighbour_mm", hf->neighbour_mm,
                         "pitch_mm", hf->pitch_mm,
                         "seed_moved", (hf->flags & IMP_HF_SEED_MOVED) != 0,
                         "plane_weak", (hf->flags & IMP_HF_PLANE_WEAK) != 0,
                         "step_raised", (hf->flags & IMP_HF_STEP_RAISED) != 0,
                         /* −1: the slope barrier had to go */
                         "step_min_mm", isfinite(hf->step_min_used_mm) ? hf->step_min_used_mm : -1.0,
                         "plane_tilt_deg", hf->plane_tilt_deg, "plane_view_deg", hf->plane_view_deg,
                         "ransac_inlier_frac", hf->ransac_inlier_frac,
                         "excluded_points", (json_int_t) hf->n_excluded_points,
                         "plane_no_consensus", (hf->flags & IMP_HF_PLANE_NO_CONSENSUS) != 0,
                         "frame_trimmed_points", (json_int_t) hf->n_frame_trimmed,
                         "relief_points", (json_int_t) hf->n_relief_points,
                         "outline_texels", (json_int_t) hf->n_outline_texels,
                         "frame_trimmed", (hf->flags & IMP_HF_FRAME_TRIMMED) != 0);
}

int imp_heightfield_write_exr(const struct imp_heightfield *hf, const char *copy_dir, struct imp_error *err) {
        if (!hf || !copy_dir || hf->nx <= 0 || hf->ny <= 0)
                return imp_error_set(err, -EINVAL, "heightfield save: bad arguments");
        int r = imp_mkdir_p(copy_dir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create directory: %s", copy_dir, strerror(-r));
        _cleanup_image_ struct imp_image *img = NULL;
        if ((r = imp_image_new(hf->nx, hf->ny, 7, IMP_PIX_F32, &img)) < 0)
                return imp_error_set(err, r, "heightfield %dx%d: cannot allocate: %s", hf->nx, hf->ny, strerror(-r));
        for (int j = 0; j < hf->ny; j++)
                for (int i = 0; i < hf->nx; i++) {
                        size_t t = (size_t) j * hf->nx + i;
                        float *p = imp_image_f32(img, i, j);
                        p[0] = hf->height_mm[t];
                        p[1] = hf->nx_[t];
                        p[2] = hf->ny_[t];
                        p[3] = hf->sigma_mm[t];
                        p[4] = hf->mask[t];
                        p[5] = hf->texel_flags ? hf->texel_flags[t] : 0;
                        p[6] = hf->sigma_n_deg ? hf->sigma_n_deg[t] : 0;
                }
        static const char *const names[] = { "height", "nx", "ny", "sigma", "mask", "flags", "sigma_n_deg" };
        char path[4096];
        snprintf(path, sizeof path, "%s/heightfield.exr", copy_dir);
        return imp_exr_write(path, img, names, false, err);
}

int imp_heightfield_save(const struct imp_heightfield *hf, const char *copy_dir, struct imp_error *err) {
        int r = imp_heightfield_write_exr(hf, copy_dir, err);
        if (r < 0)
                return r;
        char path[4096];
        snprintf(path, sizeof path, "%s/copy.json", copy_dir);
        _cleanup_json_ json_t *j = NULL;
        struct stat st;
        if (stat(path, &st) == 0) {
                if ((r = imp_json_load(path, &j, err)) < 0)
                        return r;
                if (!json_is_object(j))
                        return imp_error_set(err, -EBADMSG, "%s: expected a JSON object", path);
        } else
                j = json_object();
        json_t *m = json_array();
        for (int k = 0; k < 16; k++)
                json_array_append_new(m, json_real(hf->canvas_to_world[k]));
        json_object_set_new(j, "units", json_string("mm"));
        json_object_set_new(j, "pitch_mm", json_real(hf->pitch_mm));
        json_object_set_new(j, "nx", json_integer(hf->nx));
        json_object_set_new(j, "ny", json_integer(hf->ny));
        json_object_set_new(j, "canvas_to_world", m);
        if (!json_is_object(json_object_get(j, "provenance")))
                json_object_set_new(j, "provenance", json_object());
        json_t *stages = json_object_get(j, "stages");
        if (!json_is_object(stages)) {
                stages = json_object();
                json_object_set_new(j, "stages", stages);
        }
        json_object_set_new(stages, "heightfield", imp_heightfield_stage_json(hf));
        return imp_json_save_atomic(path, j, err);
}
