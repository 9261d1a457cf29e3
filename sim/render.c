/* Image formation: per-camera view maps by heightfield ray marching, then per frame one
 * fused shading pass (dome light with optional shadow rays, projector pattern, ambient,
 * indirect), vignetting, defocus and the sensor model. See render.h for conventions. */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "indirect.h"
#include "render.h"

#define MISS UINT32_MAX
#define BLOCK 16                  /* samples per side of a max-height block (shadow skipping) */
#define SUPER 8                   /* blocks per side of a superblock (second skipping level) */
#define LINEAR_MIN_STEPS 8        /* linear search steps for a ray crossing the relief vertically */
#define BISECTIONS 24             /* binary refinement after the linear search (seed §5.2) */
#define SHADOW_BIAS_MM 1e-3       /* occluder must rise this much above the shadow ray */
#define POISSON_GAUSS_E 20.0      /* Poisson by inversion below this mean, Gaussian above */
#define PATTERN_SUB 4             /* samples per projector pixel of a defocused pattern profile */
#define HOT_SALT 0x686f74706978ull
#define PRNU_SALT 0x70726e75ull

static const double LUMA[3] = { 0.2126, 0.7152, 0.0722 };   /* Rec. 709 */

struct view_px {
        float p[3], n[3], t[3];      /* hit point, unit normal, tangent (world) */
        float vloc[3];               /* direction to the camera in the local frame (t, n×t, n) */
        float vig;                   /* cos⁴ vignetting factor; 1 without the effect */
        uint32_t texel;              /* lower-left sample (i0, j0) of the hit, MISS when the ray misses */
        float tw[2];                 /* bilinear weights of samples i0 + 1, j0 + 1 (0 at the edge) */
        uint8_t tdi, tdj;            /* 1 when sample i0 + 1 / j0 + 1 exists */
};

/* The BRDF at a hit point: the bilinear blend of the four surrounding samples' BRDFs. Samples
 * of one region differ only in ρd (the tint), so they blend into one Lafortune lobe with the
 * weighted ρd; only where regions meet is the result a mixture of up to four lobes. */
struct brdf_mix {
        int n;
        float w[4];
        struct imp_lafortune b[4];
        float rho_d[3];              /* Σ w ρd, for the ambient and indirect terms */
};

struct proj_px {
        float x[2];                  /* projector pixel coordinates */
        float g[3];                  /* radiance of a fully lit projector pixel, 0 if unlit */
};

struct cam_state {
        int w, h, nch;               /* nch: 3 for colour/bayer radiance, else 1 */
        double C[3];
        struct view_px *view;
        struct proj_px *proj;        /* lazily, on the first projector frame */
        float *prnu;                 /* per-pixel relative gain error (noise) */
        uint8_t *hot;                /* hot pixel map (hot_pixels) */
        float *rad, *tmp;            /* radiance buffer and blur scratch */
};

struct imp_render {
        const struct imp_scene *scene;
        bool fx[IMP_FX_COUNT];
        struct imp_rig rig;          /* shallow copy (lights not owned), distortion per effect */
        const struct imp_sim_surface *surf;
        const float *normals;
        const uint8_t *region;
        const float *tint;
        struct imp_lafortune brdf[IMP_SCENE_MAX_REGIONS];
        double hmin, hmax;
        float *bmax;                 /* BLOCK×BLOCK max heights */
        int bnx, bny;
        float *smax;                 /* SUPER×SUPER blocks max heights */
        int snx, sny;
        struct cam_state cam[4];
        struct imp_indirect *ind;
        int ind_light;
        float *profile;              /* defocused pattern profile scratch */
        size_t profile_cap;
        struct imp_sim_counters cnt;
        bool key_valid;              /* radiance cache: the last frame's light situation */
        int key_cam, key_light;
        bool key_dark;
        struct imp_pattern key_pat;
};

static void add_counters(struct imp_sim_counters *dst, const struct imp_sim_counters *src) {
        uint64_t *d = (uint64_t *) dst;
        const uint64_t *s = (const uint64_t *) src;
        for (size_t i = 0; i < sizeof *dst / sizeof(uint64_t); i++) {
#pragma omp atomic
                d[i] += s[i];
        }
}

/* ---- random numbers: a hash of (seed, seq, camera, pixel) and a draw index ---- */
static inline uint64_t rng_key(uint64_t seed, uint64_t seq, uint64_t cam, uint64_t pix) {
        return imp_mix64(seed ^ imp_mix64(seq ^ imp_mix64((cam << 40) ^ pix)));
}
static inline double rng_u(uint64_t key, unsigned *k) {
        return imp_u01(imp_mix64(key + 0xD1B54A32D192ED03ull * ++*k));
}
static inline double rng_normal(uint64_t key, unsigned *k) {
        double u1 = 1.0 - rng_u(key, k), u2 = rng_u(key, k);
        return sqrt(-2.0 * log(u1)) * cos(2 * M_PI * u2);
}
static inline double rng_poisson(uint64_t key, unsigned *k, double mean) {
        if (mean <= 0)
                return 0;
        if (mean >= POISSON_GAUSS_E) {
                double v = mean + sqrt(mean) * rng_normal(key, k);
                return v > 0 ? floor(v + 0.5) : 0;
        }
        double u = rng_u(key, k), p = exp(-mean), F = p;
        int n = 0;
        while (u > F && n < 200) {
                n++;
                p *= mean / n;
                F += p;
        }
        return n;
}

/* ---- heightfield marching ---- */
static inline double height_at(const struct imp_sim_surface *s, double x, double y) {
        return imp_sim_surface_height(s, x, y);
}

static bool inside_grid(const struct imp_sim_surface *s, double x, double y) {
        double fx = (x - s->origin_mm[0]) / s->pitch_mm, fy = (y - s->origin_mm[1]) / s->pitch_mm;
        return fx >= 0 && fy >= 0 && fx <= s->nx - 1 && fy <= s->ny - 1;
}

/* A world ray in the frame of the samples (the painting's, for a placed surface). */
static void ray_to_lattice(const struct imp_sim_surface *s, const double O[3], const double D[3], double ret_o[3],
                           double ret_d[3]) {
        imp_sim_surface_to_lattice(s, O, ret_o);
        imp_sim_surface_dir_to_lattice(s, D, ret_d);
        ret_o[2] = O[2];
        ret_d[2] = D[2];
}

/* First intersection of O + t·D with the heightfield: linear search with steps of at most
 * half a sample horizontally, then bisection. False when the ray misses the sampled area. */
static bool march_view(const struct imp_render *r, const double O[3], const double D[3], double ret_p[3]) {
        const struct imp_sim_surface *s = r->surf;
        if (!(D[2] < -1e-9))
                return false;
        double zmax = r->hmax + 1e-3, zmin = r->hmin - 1e-3;
        double t0 = IMP_MAX(0.0, (O[2] - zmax) / -D[2]), t1 = (O[2] - zmin) / -D[2];
        if (!(t1 > t0))
                return false;
        double dxy = hypot(D[0], D[1]);
        double dt = (t1 - t0) / LINEAR_MIN_STEPS;
        if (dxy > 1e-12)
                dt = IMP_MIN(dt, 0.5 * s->pitch_mm / dxy);
        double ta = t0, tb = t1;
        for (double t = t0 + dt;; t += dt) {
                if (t > t1)
                        t = t1;
                double f = O[2] + t * D[2] - height_at(s, O[0] + t * D[0], O[1] + t * D[1]);
                if (f <= 0) {
                        tb = t;
                        break;
                }
                ta = t;
                if (t >= t1)
                        return false;
        }
        for (int i = 0; i < BISECTIONS; i++) {
                double tm = 0.5 * (ta + tb);
                double f = O[2] + tm * D[2] - height_at(s, O[0] + tm * D[0], O[1] + tm * D[1]);
                if (f > 0)
                        ta = tm;
                else
                        tb = tm;
        }
        double t = 0.5 * (ta + tb);
        for (int i = 0; i < 3; i++)
                ret_p[i] = O[i] + t * D[i];
        return inside_grid(s, ret_p[0], ret_p[1]);
}

/* Is the segment from surface point p towards `target` blocked by the relief? Steps of half
 * a sample, whole blocks skipped while the ray is above their maximum. */
static bool occluded(const struct imp_render *r, const float pf[3], const double target_w[3], uint64_t *steps) {
        const struct imp_sim_surface *s = r->surf;
        double p[3] = { pf[0], pf[1], pf[2] }, target[3] = { target_w[0], target_w[1], target_w[2] };
        if (s->placed) {        /* the segment in the frame of the samples */
                imp_sim_surface_to_lattice(s, target_w, target);
                double w[2] = { p[0], p[1] };
                imp_sim_surface_to_lattice(s, w, p);
        }
        double d[3] = { target[0] - p[0], target[1] - p[1], target[2] - p[2] };
        double dist = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        if (!(dist > 0))
                return false;
        for (int i = 0; i < 3; i++)
                d[i] /= dist;
        double t_end = dist;
        if (d[2] > 1e-12)
                t_end = IMP_MIN(t_end, (r->hmax + SHADOW_BIAS_MM - p[2]) / d[2]);
        double xmin = s->origin_mm[0], xmax = xmin + (s->nx - 1) * s->pitch_mm;
        double ymin = s->origin_mm[1], ymax = ymin + (s->ny - 1) * s->pitch_mm;
        if (d[0] > 1e-12) t_end = IMP_MIN(t_end, (xmax - p[0]) / d[0]);
        if (d[0] < -1e-12) t_end = IMP_MIN(t_end, (xmin - p[0]) / d[0]);
        if (d[1] > 1e-12) t_end = IMP_MIN(t_end, (ymax - p[1]) / d[1]);
        if (d[1] < -1e-12) t_end = IMP_MIN(t_end, (ymin - p[1]) / d[1]);
        if (!(t_end > 0))
                return false;
        double dxy = hypot(d[0], d[1]);
        double dt = dxy > 1e-12 ? 0.5 * s->pitch_mm / dxy : t_end;
        dt = IMP_MIN(dt, t_end / 4);
        double bsize = BLOCK * s->pitch_mm;
        uint64_t n = 0;
        bool rising = d[2] > 1e-12, hit = false;
        for (double t = dt; t < t_end;) {
                double x = p[0] + t * d[0], y = p[1] + t * d[1], z = p[2] + t * d[2];
                if (rising) {
                        /* skip a superblock, else a block, while the rising ray is above it */
                        double tskip = -1;
                        for (int lv = 1; lv >= 0 && tskip < 0; lv--) {
                                double sz = lv ? bsize * SUPER : bsize;
                                int gnx = lv ? r->snx : r->bnx, gny = lv ? r->sny : r->bny;
                                const float *mx = lv ? r->smax : r->bmax;
                                int bi = (int) IMP_CLAMP((x - xmin) / sz, 0, gnx - 1);
                                int bj = (int) IMP_CLAMP((y - ymin) / sz, 0, gny - 1);
                                if (!(z > mx[(size_t) bj * gnx + bi] + SHADOW_BIAS_MM))
                                        continue;
                                double bx0 = xmin + bi * sz, by0 = ymin + bj * sz, tx = INFINITY, ty = INFINITY;
                                if (d[0] > 1e-12) tx = (bx0 + sz - p[0]) / d[0];
                                if (d[0] < -1e-12) tx = (bx0 - p[0]) / d[0];
                                if (d[1] > 1e-12) ty = (by0 + sz - p[1]) / d[1];
                                if (d[1] < -1e-12) ty = (by0 - p[1]) / d[1];
                                tskip = IMP_MAX(t, IMP_MIN(tx, ty)) + 1e-6;
                        }
                        if (tskip >= 0) {
                                t = tskip;
                                continue;
                        }
                }
                n++;
                if (height_at(s, x, y) > z + SHADOW_BIAS_MM) {
                        hit = true;
                        break;
                }
                t += dt;
        }
        *steps += n;
        return hit;
}

/* ---- setup ---- */
static int build_blocks(struct imp_render *r) {
        const struct imp_sim_surface *s = r->surf;
        r->bnx = (s->nx - 1 + BLOCK - 1) / BLOCK;
        r->bny = (s->ny - 1 + BLOCK - 1) / BLOCK;
        r->bnx = IMP_MAX(r->bnx, 1);
        r->bny = IMP_MAX(r->bny, 1);
        r->bmax = malloc((size_t) r->bnx * r->bny * sizeof(float));
        if (!r->bmax)
                return -ENOMEM;
        for (int bj = 0; bj < r->bny; bj++)
                for (int bi = 0; bi < r->bnx; bi++) {
                        float m = -INFINITY;
                        for (int j = bj * BLOCK; j <= IMP_MIN((bj + 1) * BLOCK, s->ny - 1); j++)
                                for (int i = bi * BLOCK; i <= IMP_MIN((bi + 1) * BLOCK, s->nx - 1); i++)
                                        m = IMP_MAX(m, s->height_mm[(size_t) j * s->nx + i]);
                        r->bmax[(size_t) bj * r->bnx + bi] = m;
                }
        r->snx = (r->bnx + SUPER - 1) / SUPER;
        r->sny = (r->bny + SUPER - 1) / SUPER;
        if (!(r->smax = malloc((size_t) r->snx * r->sny * sizeof(float))))
                return -ENOMEM;
        for (int sj = 0; sj < r->sny; sj++)
                for (int si = 0; si < r->snx; si++) {
                        float m = -INFINITY;
                        for (int bj = sj * SUPER; bj < IMP_MIN((sj + 1) * SUPER, r->bny); bj++)
                                for (int bi = si * SUPER; bi < IMP_MIN((si + 1) * SUPER, r->bnx); bi++)
                                        m = IMP_MAX(m, r->bmax[(size_t) bj * r->bnx + bi]);
                        r->smax[(size_t) sj * r->snx + si] = m;
                }
        return 0;
}

static void build_view(struct imp_render *r, int ci) {
        struct cam_state *cs = &r->cam[ci];
        const struct imp_pinhole *m = &r->rig.cameras[ci].model;
        const struct imp_sim_surface *s = r->surf;
        const double axis[3] = { m->R[6], m->R[7], m->R[8] };
        bool distort = r->fx[IMP_FX_DISTORTION], vignette = r->fx[IMP_FX_VIGNETTING];
        uint64_t dist_evals = 0;
#pragma omp parallel for schedule(dynamic, 4) reduction(+ : dist_evals)
        for (int y = 0; y < cs->h; y++)
                for (int x = 0; x < cs->w; x++) {
                        struct view_px *v = &cs->view[(size_t) y * cs->w + x];
                        double px[2] = { x, y }, O[3], D[3], p[3];
                        imp_pinhole_ray_world(m, px, O, D);
                        if (distort)
                                dist_evals++;
                        v->vig = 1;
                        if (vignette) {
                                double c = IMP_MAX(0.0, D[0] * axis[0] + D[1] * axis[1] + D[2] * axis[2]);
                                v->vig = (float) (c * c * c * c);
                        }
                        double Ol[3], Dl[3];    /* the ray in the frame of the samples */
                        ray_to_lattice(s, O, D, Ol, Dl);
                        if (!march_view(r, Ol, Dl, p)) {
                                v->texel = MISS;
                                continue;
                        }
                        double fx = (p[0] - s->origin_mm[0]) / s->pitch_mm, fy = (p[1] - s->origin_mm[1]) / s->pitch_mm;
                        int i0 = (int) IMP_CLAMP(floor(fx), 0, s->nx - 1), j0 = (int) IMP_CLAMP(floor(fy), 0, s->ny - 1);
                        int i1 = IMP_MIN(i0 + 1, s->nx - 1), j1 = IMP_MIN(j0 + 1, s->ny - 1);
                        double ax = fx - i0, ay = fy - j0, n[3], t[3], b[3], vw[3] = { -D[0], -D[1], -D[2] }, vl[3];
                        const float *N = r->normals;
                        size_t k00 = 3 * ((size_t) j0 * s->nx + i0), k10 = 3 * ((size_t) j0 * s->nx + i1);
                        size_t k01 = 3 * ((size_t) j1 * s->nx + i0), k11 = 3 * ((size_t) j1 * s->nx + i1);
                        double len = 0;
                        for (int c = 0; c < 3; c++) {
                                n[c] = (N[k00 + c] * (1 - ax) + N[k10 + c] * ax) * (1 - ay) +
                                       (N[k01 + c] * (1 - ax) + N[k11 + c] * ax) * ay;
                                len += n[c] * n[c];
                        }
                        len = sqrt(len);
                        for (int c = 0; c < 3; c++)
                                n[c] = len > 0 ? n[c] / len : (c == 2);
                        if (s->placed) {        /* hit point and normal back to world */
                                double l[2] = { p[0], p[1] }, ln[2] = { n[0], n[1] };
                                imp_sim_surface_to_world(s, l, p);
                                imp_sim_surface_dir_to_world(s, ln, n);
                        }
                        imp_local_frame(n, t, b);
                        imp_to_local(t, b, n, vw, vl);
                        for (int c = 0; c < 3; c++) {
                                v->p[c] = (float) p[c];
                                v->n[c] = (float) n[c];
                                v->t[c] = (float) t[c];
                                v->vloc[c] = (float) vl[c];
                        }
                        /* BRDF/albedo: bilinear in the samples around the hit (sample i sits at
                         * origin + i · pitch), not the nearest one, which would snap edges to the
                         * sample grid. */
                        v->texel = (uint32_t) ((size_t) j0 * s->nx + i0);
                        v->tdi = (uint8_t) (i1 > i0);
                        v->tdj = (uint8_t) (j1 > j0);
                        v->tw[0] = v->tdi ? (float) IMP_CLAMP(ax, 0.0, 1.0) : 0.0f;
                        v->tw[1] = v->tdj ? (float) IMP_CLAMP(ay, 0.0, 1.0) : 0.0f;
                }
        r->cnt.distortion_evals += dist_evals;
}

static int init_camera(struct imp_render *r, int ci) {
        struct cam_state *cs = &r->cam[ci];
        const struct imp_rig_camera *cam = &r->rig.cameras[ci];
        const struct imp_scene_camera_opts *o = imp_scene_camera_opts(r->scene, ci);
        cs->w = cam->model.width;
        cs->h = cam->model.height;
        cs->nch = o->colour || r->fx[IMP_FX_BAYER] ? 3 : 1;
        size_t n = (size_t) cs->w * cs->h;
        imp_pinhole_centre(&cam->model, cs->C);
        cs->view = malloc(n * sizeof *cs->view);
        cs->rad = malloc(n * cs->nch * sizeof(float));
        if (!cs->view || !cs->rad)
                return -ENOMEM;
        if (r->fx[IMP_FX_DEFOCUS] && !(cs->tmp = malloc(n * cs->nch * sizeof(float))))
                return -ENOMEM;
        uint64_t seed = imp_scene_seed(r->scene);
        if (r->fx[IMP_FX_NOISE]) {
                if (!(cs->prnu = malloc(n * sizeof(float))))
                        return -ENOMEM;
                double prnu = cam->sensor.prnu;
                for (size_t k = 0; k < n; k++) {
                        unsigned d = 0;
                        cs->prnu[k] = (float) (prnu * rng_normal(rng_key(seed ^ PRNU_SALT, 0, ci, k), &d));
                }
                r->cnt.random_draws += 2 * n;
        }
        if (r->fx[IMP_FX_HOT_PIXELS]) {
                if (!(cs->hot = malloc(n)))
                        return -ENOMEM;
                double frac = imp_scene_hot_pixel_fraction(r->scene);
                for (size_t k = 0; k < n; k++) {
                        unsigned d = 0;
                        cs->hot[k] = rng_u(rng_key(seed ^ HOT_SALT, 0, ci, k), &d) < frac;
                }
                r->cnt.random_draws += n;
        }
        build_view(r, ci);
        return 0;
}

void imp_render_free(struct imp_render *r) {
        if (!r)
                return;
        for (int i = 0; i < 4; i++) {
                free(r->cam[i].view);
                free(r->cam[i].proj);
                free(r->cam[i].prnu);
                free(r->cam[i].hot);
                free(r->cam[i].rad);
                free(r->cam[i].tmp);
        }
        imp_indirect_free(r->ind);
        free(r->bmax);
        free(r->smax);
        free(r->profile);
        free(r);
}

static void zero_distortion(struct imp_pinhole *m) { m->k1 = m->k2 = m->k3 = m->p1 = m->p2 = 0; }

int imp_render_new(const struct imp_scene *scene, struct imp_render **ret, struct imp_error *err) {
        _cleanup_(imp_render_freep) struct imp_render *r = calloc(1, sizeof *r);
        if (!r)
                return -ENOMEM;
        r->scene = scene;
        for (int i = 0; i < IMP_FX_COUNT; i++)
                r->fx[i] = imp_scene_has_effect(scene, i);
        r->rig = *imp_scene_rig(scene);
        if (!r->fx[IMP_FX_DISTORTION]) {
                for (int i = 0; i < r->rig.n_cameras; i++)
                        zero_distortion(&r->rig.cameras[i].model);
                zero_distortion(&r->rig.projector.model);
        }
        r->surf = imp_scene_surface(scene);
        r->normals = imp_scene_normals(scene);
        r->region = imp_scene_region_map(scene);
        r->tint = imp_scene_tint(scene);
        int nreg = 0;
        const struct imp_scene_region *reg = imp_scene_regions(scene, &nreg);
        for (int i = 0; i < nreg; i++)
                r->brdf[i] = reg[i].brdf;
        r->hmin = imp_scene_min_height_mm(scene);
        r->hmax = imp_scene_max_height_mm(scene);
        r->ind_light = -1;
        int q = build_blocks(r);
        if (q < 0)
                return q;
        for (int i = 0; i < r->rig.n_cameras; i++)
                if ((q = init_camera(r, i)) < 0)
                        return imp_error_set(err, q, "camera %s: cannot allocate the view map", r->rig.cameras[i].name);
        *ret = TAKE_PTR(r);
        return 0;
}

const struct imp_rig *imp_render_rig(const struct imp_render *r) { return &r->rig; }
const struct imp_sim_counters *imp_render_counters(const struct imp_render *r) { return &r->cnt; }
void imp_render_reset_counters(struct imp_render *r) { memset(&r->cnt, 0, sizeof r->cnt); }

int imp_render_view_point(const struct imp_render *r, int cam, int x, int y, double ret_p[3], double ret_n[3]) {
        if (cam < 0 || cam >= r->rig.n_cameras || x < 0 || y < 0 || x >= r->cam[cam].w || y >= r->cam[cam].h)
                return -EINVAL;
        const struct view_px *v = &r->cam[cam].view[(size_t) y * r->cam[cam].w + x];
        if (v->texel == MISS)
                return -ENODATA;
        for (int i = 0; i < 3; i++) {
                if (ret_p) ret_p[i] = v->p[i];
                if (ret_n) ret_n[i] = v->n[i];
        }
        return 0;
}

/* ---- shading ---- */
static inline void texel_brdf(const struct imp_render *r, const struct view_px *v, struct brdf_mix *m) {
        size_t nx = (size_t) r->surf->nx, k0 = v->texel;
        size_t k[4] = { k0, k0 + v->tdi, k0 + v->tdj * nx, k0 + v->tdj * nx + v->tdi };
        float ax = v->tw[0], ay = v->tw[1];
        float w[4] = { (1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay };
        uint8_t reg = r->region[k[0]];
        float t0 = r->tint[k[0]];
        bool one = true, flat = true;
        for (int q = 1; q < 4; q++) {
                one = one && r->region[k[q]] == reg;
                flat = flat && r->tint[k[q]] == t0;
        }
        if (one) {              /* one region: one lobe, ρd scaled by the interpolated tint */
                float tint = t0;
                if (!flat)
                        tint = (r->tint[k[0]] * (1 - ax) + r->tint[k[1]] * ax) * (1 - ay) +
                               (r->tint[k[2]] * (1 - ax) + r->tint[k[3]] * ax) * ay;
                m->n = 1;
                m->w[0] = 1;
                m->b[0] = r->brdf[reg];
                for (int c = 0; c < 3; c++)
                        m->rho_d[c] = m->b[0].rho_d[c] *= tint;
                return;
        }
        uint8_t regs[4];
        float wt[4];            /* Σ w · tint per region */
        m->n = 0;
        for (int q = 0; q < 4; q++) {
                if (!(w[q] > 0))
                        continue;
                int e = 0;
                while (e < m->n && regs[e] != r->region[k[q]])
                        e++;
                if (e == m->n) {
                        regs[e] = r->region[k[q]];
                        m->w[e] = 0;
                        wt[e] = 0;
                        m->n++;
                }
                m->w[e] += w[q];
                wt[e] += w[q] * r->tint[k[q]];
        }
        for (int c = 0; c < 3; c++)
                m->rho_d[c] = 0;
        for (int e = 0; e < m->n; e++) {
                m->b[e] = r->brdf[regs[e]];
                for (int c = 0; c < 3; c++) {
                        m->b[e].rho_d[c] *= wt[e] / m->w[e];
                        m->rho_d[c] += m->w[e] * m->b[e].rho_d[c];
                }
        }
}

/* V = E · cos θl · f(v, l) per channel for light from world point `src` with irradiance
 * E (before colour); returns false when the light is below the surface. */
static inline bool shade_point(const struct view_px *v, const struct brdf_mix *b, const double src[3],
                               double *ret_dist, double ret_l[3], double ret_f[3], double *ret_cos) {
        double l[3] = { src[0] - v->p[0], src[1] - v->p[1], src[2] - v->p[2] };
        double d = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
        for (int i = 0; i < 3; i++)
                l[i] /= d;
        double n[3] = { v->n[0], v->n[1], v->n[2] }, t[3] = { v->t[0], v->t[1], v->t[2] };
        double cosl = n[0] * l[0] + n[1] * l[1] + n[2] * l[2];
        if (!(cosl > 0) || v->vloc[2] <= 0)
                return false;
        double bb[3] = { n[1] * t[2] - n[2] * t[1], n[2] * t[0] - n[0] * t[2], n[0] * t[1] - n[1] * t[0] };
        double ll[3], vl[3] = { v->vloc[0], v->vloc[1], v->vloc[2] };
        imp_to_local(t, bb, n, l, ll);
        for (int c = 0; c < 3; c++) {
                ret_f[c] = b->n == 1 ? imp_lafortune_eval(&b->b[0], c, vl, ll) : 0;
                for (int e = 0; b->n > 1 && e < b->n; e++)
                        ret_f[c] += b->w[e] * imp_lafortune_eval(&b->b[e], c, vl, ll);
        }
        *ret_dist = d;
        *ret_cos = cosl;
        memcpy(ret_l, l, sizeof l);
        return true;
}

static int build_projector_map(struct imp_render *r, int ci) {
        struct cam_state *cs = &r->cam[ci];
        size_t n = (size_t) cs->w * cs->h;
        if (!(cs->proj = malloc(n * sizeof *cs->proj)))
                return -ENOMEM;
        const struct imp_rig_projector *pj = &r->rig.projector;
        double Cp[3];
        imp_pinhole_centre(&pj->model, Cp);
        bool shadows = r->fx[IMP_FX_SHADOWS], distort = r->fx[IMP_FX_DISTORTION];
        uint64_t evals = 0, rays = 0, steps = 0, dist = 0;
#pragma omp parallel for schedule(dynamic, 4) reduction(+ : evals, rays, steps, dist)
        for (int y = 0; y < cs->h; y++)
                for (int x = 0; x < cs->w; x++) {
                        size_t k = (size_t) y * cs->w + x;
                        const struct view_px *v = &cs->view[k];
                        struct proj_px *pp = &cs->proj[k];
                        memset(pp, 0, sizeof *pp);
                        if (v->texel == MISS)
                                continue;
                        double X[3] = { v->p[0], v->p[1], v->p[2] }, uv[2];
                        bool front = imp_pinhole_project(&pj->model, X, uv);
                        if (distort)
                                dist++;
                        if (!front || uv[0] < -0.5 || uv[1] < -0.5 || uv[0] >= pj->model.width - 0.5 ||
                            uv[1] >= pj->model.height - 0.5)
                                continue;
                        pp->x[0] = (float) uv[0];
                        pp->x[1] = (float) uv[1];
                        struct brdf_mix b;
                        texel_brdf(r, v, &b);
                        double d, l[3], f[3], cosl;
                        if (!shade_point(v, &b, Cp, &d, l, f, &cosl))
                                continue;
                        if (shadows) {
                                rays++;
                                if (occluded(r, v->p, Cp, &steps))
                                        continue;
                        }
                        evals++;
                        double E = pj->intensity * 1e6 / (d * d);
                        for (int c = 0; c < 3; c++)
                                pp->g[c] = (float) (E * cosl * f[c]);
                }
        r->cnt.shading_evals += evals;
        r->cnt.shadow_rays += rays;
        r->cnt.shadow_steps += steps;
        r->cnt.distortion_evals += dist;
        return 0;
}

static double pattern_value(const struct imp_pattern *pt, double x) {
        switch (pt->kind) {
        case IMP_PAT_WHITE:
                return 1;
        case IMP_PAT_GRAY: {
                long i = (long) floor(x + 0.5);
                long maxi = (1L << pt->nbits) - 1;
                i = IMP_CLAMP(i, 0, maxi);
                long g = i ^ (i >> 1);
                int bit = (int) ((g >> (pt->nbits - 1 - pt->bit)) & 1);
                return pt->inverse ? 1 - bit : bit;
        }
        case IMP_PAT_PHASE:
                /* The decoder's convention (imp_sl_pattern_value): pixel i spans decoder
                 * coordinates [i, i + 1), i.e. u = x + 0.5 for the pinhole coordinate x. */
                return 0.5 + 0.5 * cos(2 * M_PI * (x + 0.5) / pt->period_px +
                                       2 * M_PI * pt->step / pt->steps);
        case IMP_PAT_BLACK:
        case IMP_PAT_NONE:
                break;
        }
        return 0;
}

static inline double emission(const struct imp_rig_projector *pj, const struct imp_pattern *pt, double x) {
        double v = pattern_value(pt, x);
        return pj->black_level + (1 - pj->black_level) * (v > 0 ? pow(v, pj->gamma) : 0);
}

/* With `defocus`: the emitted profile along the pattern axis, blurred by the projector's
 * Gaussian, at PATTERN_SUB samples per pixel starting at x = -0.5. */
static int build_profile(struct imp_render *r, const struct imp_pattern *pt, int *ret_len) {
        const struct imp_rig_projector *pj = &r->rig.projector;
        int size = pt->axis ? pj->model.height : pj->model.width;
        int len = size * PATTERN_SUB + 1;
        size_t need = 2 * (size_t) len;
        if (need > r->profile_cap) {
                float *p = realloc(r->profile, need * sizeof(float));
                if (!p)
                        return -ENOMEM;
                r->profile = p;
                r->profile_cap = need;
        }
        float *raw = r->profile + len, *out = r->profile;
        for (int i = 0; i < len; i++)
                raw[i] = (float) emission(pj, pt, -0.5 + (i + 0.5) / PATTERN_SUB);
        double sigma = pj->defocus_px * PATTERN_SUB;
        int rad = (int) ceil(3 * sigma);
        uint64_t taps = 0;
        for (int i = 0; i < len; i++) {
                double sum = 0, wsum = 0;
                for (int k = -rad; k <= rad; k++) {
                        int j = i + k;
                        double w = sigma > 0 ? exp(-0.5 * k * k / (sigma * sigma)) : 1;
                        wsum += w;
                        if (j >= 0 && j < len)
                                sum += w * raw[j];
                        taps++;
                }
                out[i] = (float) (sum / wsum);
        }
        r->cnt.defocus_taps += taps;
        *ret_len = len;
        return 0;
}

static int ensure_indirect(struct imp_render *r, int li, struct imp_error *err) {
        const struct imp_rig_light *L = &r->rig.lights[li];
        if (r->ind && r->ind_light == L->id)
                return 0;
        imp_indirect_free(r->ind);
        r->ind = NULL;
        struct imp_indirect_params p;
        imp_scene_indirect_params(r->scene, &p);
        struct imp_rig_light Ll = *L;   /* the light in the frame of the samples */
        double ax[3];
        ray_to_lattice(r->surf, L->pos_mm, L->axis, Ll.pos_mm, ax);
        memcpy(Ll.axis, ax, sizeof ax);
        int q = imp_indirect_build(r->surf, &Ll, &p, &r->ind, &r->cnt);
        if (q < 0)
                return imp_error_set(err, q, "light %d: cannot build the interreflection grids", L->id);
        r->ind_light = L->id;
        return 0;
}

static void blur_axis(const float *src, float *dst, int w, int h, int nch, int axis, const double *wts, int rad,
                      uint64_t *taps) {
        uint64_t nt = 0;
#pragma omp parallel for schedule(static) reduction(+ : nt)
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++)
                        for (int c = 0; c < nch; c++) {
                                double sum = 0, wsum = 0;
                                for (int k = -rad; k <= rad; k++) {
                                        int xx = axis ? x : x + k, yy = axis ? y + k : y;
                                        if (xx < 0 || yy < 0 || xx >= w || yy >= h)
                                                continue;
                                        sum += wts[k + rad] * src[((size_t) yy * w + xx) * nch + c];
                                        wsum += wts[k + rad];
                                        nt++;
                                }
                                dst[((size_t) y * w + x) * nch + c] = (float) (sum / wsum);
                        }
        *taps += nt;
}

static void defocus_camera(struct imp_render *r, int ci) {
        struct cam_state *cs = &r->cam[ci];
        double sigma = imp_scene_camera_opts(r->scene, ci)->defocus_px;
        if (!(sigma > 0))
                return;
        int rad = (int) ceil(3 * sigma);
        double wts[2 * 3 * 50 + 2];
        rad = IMP_MIN(rad, 150);
        for (int k = -rad; k <= rad; k++)
                wts[k + rad] = exp(-0.5 * k * k / (sigma * sigma));
        blur_axis(cs->rad, cs->tmp, cs->w, cs->h, cs->nch, 0, wts, rad, &r->cnt.defocus_taps);
        blur_axis(cs->tmp, cs->rad, cs->w, cs->h, cs->nch, 1, wts, rad, &r->cnt.defocus_taps);
}

static bool same_pattern(const struct imp_pattern *a, const struct imp_pattern *b) {
        return a->kind == b->kind && a->axis == b->axis && a->bit == b->bit && a->nbits == b->nbits &&
               a->inverse == b->inverse && a->period_px == b->period_px && a->step == b->step &&
               a->steps == b->steps;
}

/* Adds the direct light of dome light L at view pixel v (BRDF b) to V, with its shadow
 * when `shadows`. Per pixel of the hot loop: allocates nothing. */
static inline void add_direct(const struct imp_render *r, const struct view_px *v, const struct brdf_mix *b,
                              const struct imp_rig_light *L, bool shadows, struct imp_sim_counters *loc, double V[3]) {
        double d, l[3], f[3], cosl;
        bool lit = shade_point(v, b, L->pos_mm, &d, l, f, &cosl);
        if (lit && shadows) {
                loc->shadow_rays++;
                lit = !occluded(r, v->p, L->pos_mm, &loc->shadow_steps);
        }
        if (!lit)
                return;
        loc->shading_evals++;
        double E = L->intensity * 1e6 / (d * d);
        if (L->profile_exp > 0) {
                double ca = -(L->axis[0] * l[0] + L->axis[1] * l[1] + L->axis[2] * l[2]);
                E *= ca > 0 ? (L->profile_exp == 1 ? ca : pow(ca, L->profile_exp)) : 0;
        }
        for (int c = 0; c < 3; c++)
                V[c] += E * L->colour[c] * cosl * f[c];
}

/* Adds the projector's light of pattern pat at a pixel whose projector footprint is pp to
 * V: from the defocused profile (plen samples) when given, else the sharp emission. */
static inline void add_projector(const struct proj_px *pp, const struct imp_rig_projector *pj,
                                 const struct imp_pattern *pat, const float *profile, int plen,
                                 struct imp_sim_counters *loc, double V[3]) {
        if (!(pp->g[0] > 0 || pp->g[1] > 0 || pp->g[2] > 0))
                return;
        double xa = pp->x[pat->axis], e;
        loc->projector_lookups++;
        if (profile) {
                double fi = (xa + 0.5) * PATTERN_SUB - 0.5;
                fi = IMP_CLAMP(fi, 0, plen - 1);
                int i0 = (int) fi, i1 = IMP_MIN(i0 + 1, plen - 1);
                e = profile[i0] + (fi - i0) * (profile[i1] - profile[i0]);
        } else {
                e = emission(pj, pat, xa);
        }
        for (int c = 0; c < 3; c++)
                V[c] += pp->g[c] * e;
}

/* Fills cam[ci].rad for the light situation of `rec` (cached across an exposure stack). */
static int compute_radiance(struct imp_render *r, const struct imp_frame_record *rec, int *ret_ci,
                            struct imp_error *err) {
        int ci = imp_scene_camera_index(r->scene, rec->camera);
        if (ci < 0)
                return imp_error_set(err, -ENOENT, "frame %lld: no camera \"%s\" in the scene", rec->seq, rec->camera);
        int li = -1;
        if (rec->light >= 0 && (li = imp_scene_light_index(r->scene, rec->light)) < 0)
                return imp_error_set(err, -ENOENT, "frame %lld: no dome light %d in the scene", rec->seq, rec->light);
        *ret_ci = ci;
        bool dark = !strcmp(rec->step, "dark");
        struct imp_pattern pat = rec->pattern;
        if (!r->fx[IMP_FX_PROJECTOR] || dark)
                pat.kind = IMP_PAT_NONE;
        if (r->key_valid && r->key_cam == ci && r->key_light == rec->light && r->key_dark == dark &&
            same_pattern(&r->key_pat, &pat))
                return 0;
        r->key_valid = false;

        struct cam_state *cs = &r->cam[ci];
        size_t n = (size_t) cs->w * cs->h;
        memset(cs->rad, 0, n * cs->nch * sizeof(float));
        int q;
        bool use_light = !dark && li >= 0 && r->fx[IMP_FX_DIRECT];
        bool use_ind = !dark && li >= 0 && r->fx[IMP_FX_INDIRECT];
        bool use_proj = pat.kind != IMP_PAT_NONE;
        bool use_amb = !dark && r->fx[IMP_FX_AMBIENT];
        bool shadows = r->fx[IMP_FX_SHADOWS];
        if (use_proj && !cs->proj && (q = build_projector_map(r, ci)) < 0)
                return q;
        if (use_ind && (q = ensure_indirect(r, li, err)) < 0)
                return q;
        int plen = 0;
        bool defocus_pat = use_proj && r->fx[IMP_FX_DEFOCUS] && r->rig.projector.defocus_px > 0;
        if (defocus_pat && (q = build_profile(r, &pat, &plen)) < 0)
                return q;
        const struct imp_rig_light *L = li >= 0 ? &r->rig.lights[li] : NULL;
        const struct imp_rig_projector *pj = &r->rig.projector;
        double ambient = imp_scene_ambient(r->scene);
        const float *profile = r->profile;
        int nch = cs->nch;
        struct imp_sim_counters tot = { 0 };

#pragma omp parallel
        {
                struct imp_sim_counters loc = { 0 };
#pragma omp for schedule(dynamic, 4)
                for (int y = 0; y < cs->h; y++)
                        for (int x = 0; x < cs->w; x++) {
                                size_t k = (size_t) y * cs->w + x;
                                const struct view_px *v = &cs->view[k];
                                if (v->texel == MISS)
                                        continue;
                                double V[3] = { 0, 0, 0 };
                                struct brdf_mix b;
                                texel_brdf(r, v, &b);
                                if (use_light)
                                        add_direct(r, v, &b, L, shadows, &loc, V);
                                if (use_proj)
                                        add_projector(&cs->proj[k], pj, &pat, defocus_pat ? profile : NULL, plen, &loc, V);
                                if (use_ind) {
                                        double Pw[3] = { v->p[0], v->p[1], v->p[2] }, Nw[3] = { v->n[0], v->n[1], v->n[2] };
                                        double P[3], N[3];
                                        float rgb[3];
                                        ray_to_lattice(r->surf, Pw, Nw, P, N);
                                        imp_indirect_eval(r->ind, P, N, rgb, &loc);
                                        for (int c = 0; c < 3; c++)
                                                V[c] += rgb[c] * b.rho_d[c];
                                }
                                if (use_amb)
                                        for (int c = 0; c < 3; c++)
                                                V[c] += ambient * b.rho_d[c];
                                if (r->fx[IMP_FX_VIGNETTING])
                                        for (int c = 0; c < 3; c++)
                                                V[c] *= v->vig;
                                if (nch == 3)
                                        for (int c = 0; c < 3; c++)
                                                cs->rad[3 * k + c] = (float) V[c];
                                else
                                        cs->rad[k] = (float) (LUMA[0] * V[0] + LUMA[1] * V[1] + LUMA[2] * V[2]);
                        }
                add_counters(&tot, &loc);
        }
        add_counters(&r->cnt, &tot);
        if (r->fx[IMP_FX_DEFOCUS] && !dark)
                defocus_camera(r, ci);
        r->key_valid = true;
        r->key_cam = ci;
        r->key_light = rec->light;
        r->key_dark = dark;
        r->key_pat = pat;
        return 0;
}

int imp_render_radiance(struct imp_render *r, const struct imp_frame_record *rec, struct imp_image **ret,
                        struct imp_error *err) {
        int ci = -1;
        int q = compute_radiance(r, rec, &ci, err);
        if (q < 0)
                return q;
        const struct cam_state *cs = &r->cam[ci];
        struct imp_image *img = NULL;
        if ((q = imp_image_new(cs->w, cs->h, cs->nch, IMP_PIX_F32, &img)) < 0)
                return q;
        for (int y = 0; y < cs->h; y++)
                memcpy(imp_image_row(img, y), cs->rad + (size_t) y * cs->w * cs->nch, (size_t) cs->w * cs->nch * sizeof(float));
        *ret = img;
        return 0;
}

int imp_render_frame(struct imp_render *r, const struct imp_frame_record *rec, struct imp_image **ret,
                     struct imp_error *err) {
        if (r->fx[IMP_FX_DROPPED_FRAME] && imp_scene_frame_dropped(r->scene, rec->seq))
                return imp_error_set(err, -EAGAIN, "frame %lld: dropped", rec->seq);
        int ci = -1;
        int q = compute_radiance(r, rec, &ci, err);
        if (q < 0)
                return q;
        const struct cam_state *cs = &r->cam[ci];
        const struct imp_sensor *sn = &r->rig.cameras[ci].sensor;
        bool colour = imp_scene_camera_opts(r->scene, ci)->colour, bayer = r->fx[IMP_FX_BAYER] && !colour;
        int och = colour ? 3 : 1;
        struct imp_image *img = NULL;
        if ((q = imp_image_new(cs->w, cs->h, och, IMP_PIX_U16, &img)) < 0)
                return q;
        double t_s = rec->exposure_us * 1e-6;
        double e_scale = sn->quantum_scale * t_s;
        double e_per_dn = sn->gain_e_per_dn * pow(10.0, -rec->gain_db / 20.0);
        double maxdn = (double) ((1u << sn->bits) - 1);
        double hot_e = imp_scene_hot_pixel_e_per_s(r->scene) * t_s, dark_e = sn->dark_current_e_per_s * t_s;
        bool noise = r->fx[IMP_FX_NOISE];
        uint64_t seed = imp_scene_seed(r->scene), draws = 0;
#pragma omp parallel for schedule(static) reduction(+ : draws)
        for (int y = 0; y < cs->h; y++) {
                uint16_t *row = imp_image_u16(img, 0, y);
                for (int x = 0; x < cs->w; x++) {
                        size_t k = (size_t) y * cs->w + x;
                        uint64_t key = noise ? rng_key(seed, (uint64_t) rec->seq, (uint64_t) ci, k) : 0;
                        unsigned nd = 0;
                        for (int c = 0; c < och; c++) {
                                double V = cs->nch == 1 ? cs->rad[k]
                                         : bayer ? cs->rad[3 * k + ((y & 1) + (x & 1))]
                                                 : cs->rad[3 * k + c];
                                double e = V * e_scale;
                                double g_read = 0;
                                if (noise) {
                                        e = e * (1 + cs->prnu[k]) + dark_e;
                                        /* one Box–Muller pair: shot noise (Gaussian regime) and read noise */
                                        double u1 = 1.0 - rng_u(key, &nd), u2 = rng_u(key, &nd);
                                        double rad = sqrt(-2.0 * log(u1));
                                        double g_shot = rad * cos(2 * M_PI * u2);
                                        g_read = rad * sin(2 * M_PI * u2);
                                        if (e >= POISSON_GAUSS_E) {
                                                e = floor(e + sqrt(e) * g_shot + 0.5);
                                                e = e > 0 ? e : 0;
                                        } else {
                                                e = rng_poisson(key, &nd, e);
                                        }
                                }
                                if (cs->hot && cs->hot[k])
                                        e += hot_e;
                                e = IMP_MIN(e, sn->full_well_e);
                                if (noise)
                                        e += sn->read_noise_e * g_read;
                                double dn = floor(e / e_per_dn + sn->black_level_dn + 0.5);
                                row[x * och + c] = (uint16_t) IMP_CLAMP(dn, 0.0, maxdn);
                        }
                        draws += nd;
                }
        }
        r->cnt.random_draws += draws;
        *ret = img;
        return 0;
}

int imp_render_correspondence(struct imp_render *r, int ci, struct imp_image **ret) {
        if (!r->rig.has_projector)
                return -ENODEV;
        if (ci < 0 || ci >= r->rig.n_cameras)
                return -EINVAL;
        const struct cam_state *cs = &r->cam[ci];
        const struct imp_rig_projector *pj = &r->rig.projector;
        struct imp_image *img = NULL;
        int q = imp_image_new(cs->w, cs->h, 4, IMP_PIX_F32, &img);
        if (q < 0)
                return q;
        double Cp[3];
        imp_pinhole_centre(&pj->model, Cp);
#pragma omp parallel for schedule(dynamic, 4)
        for (int y = 0; y < cs->h; y++)
                for (int x = 0; x < cs->w; x++) {
                        const struct view_px *v = &cs->view[(size_t) y * cs->w + x];
                        float *o = imp_image_f32(img, x, y);
                        o[0] = o[1] = o[2] = o[3] = 0;
                        if (v->texel == MISS)
                                continue;
                        double X[3] = { v->p[0], v->p[1], v->p[2] }, uv[2];
                        uint64_t steps = 0;
                        o[3] = v->p[2];
                        if (!imp_pinhole_project(&pj->model, X, uv) || uv[0] < -0.5 || uv[1] < -0.5 ||
                            uv[0] >= pj->model.width - 0.5 || uv[1] >= pj->model.height - 0.5)
                                continue;
                        double l[3] = { Cp[0] - X[0], Cp[1] - X[1], Cp[2] - X[2] };
                        if (l[0] * v->n[0] + l[1] * v->n[1] + l[2] * v->n[2] <= 0 || occluded(r, v->p, Cp, &steps))
                                continue;
                        o[0] = (float) uv[0];
                        o[1] = (float) uv[1];
                        o[2] = 1;
                }
        *ret = img;
        return 0;
}
