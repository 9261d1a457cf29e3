/* Diagnosis of the held-out re-render error: the held-out dome lights of a
 * simulated capture re-rendered through the same sample extraction and shading as
 * `impasto process --holdout N` (pipeline/process.c validate_holdout), with geometry and
 * BRDF taken from either the copy (fitted) or the simulator's truth:
 *
 *   true  geometry + true  BRDF   on the truth grid (not a floor: the canvas has normal
 *                                  detail finer than a pixel, see docs/btf-fit.md §5)
 *   true  geometry + fitted BRDF  the copy's BRDF looked up at the truth texel
 *   fitted geometry + true BRDF   the truth BRDF looked up at the copy texel
 *   fitted geometry + fitted BRDF what process reports
 *   true geometry + BRDF refitted on the true geometry (--refit)
 *   copy positions + truth normals there (+ true BRDF, + BRDF refitted on them) (--true-normals)
 *   copy geometry + BRDF refitted here, timed: the BTF stage's CPU time (--refit-copy)
 *
 * For each: RMSE of V/E (white units) overall and per light (with the light's elevation),
 * the share of the squared error from samples near a shadow edge (a texel within 2 texels
 * has the light blocked), from highlights (true or fitted specular term > 0.02) and from
 * the worst 1 % of samples; the noise floor from the HDR variance. --maps DIR writes the
 * per-texel RMS error of every combination (EXR, one channel per held-out light + all).
 *
 * Usage: diag-rerender CAPTURE COPY TRUTH N [--refit | --true-normals | --refit-copy] [--maps DIR]
 * Environment: DIAG_VERBOSE=1 per-light splits on stderr; DIAG_SKIP_BASE=1 skips the first
 * four combinations. The held-out stacks are every Nth dome light, as `process --holdout N`. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "btf.h"
#include "captureset.h"
#include "hdr.h"
#include "image.h"
#include "json-util.h"

static const double LUMA[3] = { 0.2126, 0.7152, 0.0722 };

struct grid {
        struct imp_btf_heightfield hf;
        float *height, *normal;
        uint8_t *mask;
        struct imp_btf_texel *tex;    /* BRDF on this grid (fitted or true) */
        struct imp_btf_texel *tex_other;  /* the other source's BRDF resampled onto this grid */
};

static void die(const char *what, int r) {
        fprintf(stderr, "diag-rerender: %s: %s\n", what, strerror(r < 0 ? -r : r));
        exit(1);
}

static struct imp_image *load_exr(const char *dir, const char *file, const char *const *ch, int n, int *idx) {
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", dir, file);
        struct imp_image *img = NULL;
        char **names = NULL;
        struct imp_error err = {};
        if (imp_exr_read(path, &img, &names, &err) < 0) {
                fprintf(stderr, "%s\n", err.msg);
                exit(1);
        }
        for (int i = 0; i < n; i++)
                if ((idx[i] = imp_image_channel_index(names, ch[i])) < 0)
                        die(path, -EBADMSG);
        imp_strv_free(names);
        return img;
}

static const char *const RGB[] = { "R", "G", "B" }, *const LOBE[] = { "cx", "cy", "cz", "k" };

/* BRDF maps of DIR into texels (mono: luminance of ρd, ρs when mono). */
static struct imp_btf_texel *load_brdf(const char *dir, int w, int h, bool mono) {
        int ci[3], si[3], li[4];
        struct imp_image *d = load_exr(dir, "rho_d.exr", RGB, 3, ci), *s = load_exr(dir, "rho_s.exr", RGB, 3, si);
        struct imp_image *l = load_exr(dir, "lobe.exr", LOBE, 4, li);
        if (d->width != w || d->height != h)
                die("BRDF map size", -EBADMSG);
        struct imp_btf_texel *t = calloc((size_t) w * h, sizeof *t);
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        struct imp_btf_texel *q = &t[(size_t) y * w + x];
                        const float *pd = imp_image_f32(d, x, y), *ps = imp_image_f32(s, x, y), *pl = imp_image_f32(l, x, y);
                        double md = 0, ms = 0;
                        for (int c = 0; c < 3; c++) {
                                q->rho_d[c] = pd[ci[c]];
                                q->rho_s[c] = ps[si[c]];
                                md += LUMA[c] * pd[ci[c]];
                                ms += LUMA[c] * ps[si[c]];
                        }
                        if (mono)
                                for (int c = 0; c < 3; c++) {
                                        q->rho_d[c] = (float) md;
                                        q->rho_s[c] = (float) ms;
                                }
                        q->cx = pl[li[0]], q->cy = pl[li[1]], q->cz = pl[li[2]], q->k = pl[li[3]];
                }
        imp_image_free(d);
        imp_image_free(s);
        imp_image_free(l);
        return t;
}

/* heightfield.exr of DIR (height, nx, ny, mask) into a btf heightfield. */
static void load_grid(const char *dir, double pitch, const double M[16], struct grid *g) {
        static const char *const HF[] = { "height", "nx", "ny", "mask" };
        int hi[4];
        struct imp_image *img = load_exr(dir, "heightfield.exr", HF, 4, hi);
        int w = img->width, h = img->height;
        size_t n = (size_t) w * h;
        g->height = malloc(n * sizeof *g->height);
        g->normal = malloc(3 * n * sizeof *g->normal);
        g->mask = malloc(n);
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        const float *p = imp_image_f32(img, x, y);
                        size_t i = (size_t) y * w + x;
                        double nx = p[hi[1]], ny = p[hi[2]], s = 1 - nx * nx - ny * ny;
                        g->height[i] = p[hi[0]];
                        g->normal[3 * i] = (float) nx;
                        g->normal[3 * i + 1] = (float) ny;
                        g->normal[3 * i + 2] = (float) sqrt(s > 0 ? s : 0);
                        g->mask[i] = p[hi[3]] >= 0.5f && isfinite(p[hi[0]]);
                }
        imp_image_free(img);
        g->hf = (struct imp_btf_heightfield) { w, h, pitch, g->height, g->normal, g->mask, {} };
        memcpy(g->hf.canvas_to_world, M, sizeof g->hf.canvas_to_world);
}

/* src texels resampled (nearest) onto dst's texels through both canvas_to_world maps;
 * texels that fall outside src or on a masked src texel get MASKED. */
static struct imp_btf_texel *resample(const struct grid *dst, const struct grid *src, const struct imp_btf_texel *st) {
        const double *A = dst->hf.canvas_to_world, *B = src->hf.canvas_to_world;
        struct imp_btf_texel *t = calloc((size_t) dst->hf.width * dst->hf.height, sizeof *t);
        for (int y = 0; y < dst->hf.height; y++)
                for (int x = 0; x < dst->hf.width; x++) {
                        size_t i = (size_t) y * dst->hf.width + x;
                        double P[3] = { x * dst->hf.pitch_mm, y * dst->hf.pitch_mm, dst->height[i] }, W[3], Q[3];
                        for (int r = 0; r < 3; r++)
                                W[r] = A[4 * r] * P[0] + A[4 * r + 1] * P[1] + A[4 * r + 2] * P[2] + A[4 * r + 3];
                        for (int r = 0; r < 3; r++)   /* rigid: Bᵀ (W − t) */
                                Q[r] = B[r] * (W[0] - B[3]) + B[4 + r] * (W[1] - B[7]) + B[8 + r] * (W[2] - B[11]);
                        long u = lround(Q[0] / src->hf.pitch_mm), v = lround(Q[1] / src->hf.pitch_mm);
                        if (u < 0 || v < 0 || u >= src->hf.width || v >= src->hf.height ||
                            !src->mask[(size_t) v * src->hf.width + u]) {
                                t[i].flags = IMP_BTF_MASKED;
                                continue;
                        }
                        t[i] = st[(size_t) v * src->hf.width + u];
                        t[i].flags &= (uint16_t) ~IMP_BTF_MASKED;
                }
        return t;
}

static int cmp_desc(const void *x, const void *y) {
        float p = *(const float *) x, q = *(const float *) y;
        return (p < q) - (p > q);
}

struct acc {
        double ss, ss_edge, ss_hl, n, n_edge, n_hl;
};

/* Where the squared residuals come from: material (by the reference's ρs, k), sign of the
 * model's error, fit flags. */
struct breakdown {
        double mat[3], matn[3], sign[2], flag[9], flagn[9], n;
};

static void add_breakdown(struct breakdown *bd, const struct imp_btf_texel *m, const struct imp_btf_texel *t, double d) {
        int mat = m->rho_s[1] > 0.3f ? 2 : m->k > 6.5f ? 1 : 0;
        bd->mat[mat] += d * d, bd->matn[mat]++;
        bd->sign[d < 0] += d * d;
        for (int f = 0; f < 9; f++)
                if (t->flags & (1u << f))
                        bd->flag[f] += d * d, bd->flagn[f]++;
        bd->n++;
}

static void print_breakdown(const struct breakdown *b) {
        double bss = b->sign[0] + b->sign[1];
        printf("    by material (ref ρs/k): ochre %.1f%% SS (%.1f%% smp, rmse %.4f), blue %.1f%% (%.1f%%, %.4f), glaze %.1f%% (%.1f%%, %.4f);"
               " model too low %.1f%% SS, too high %.1f%%\n    by flag:",
               100 * b->mat[0] / bss, 100 * b->matn[0] / b->n, sqrt(b->mat[0] / fmax(1, b->matn[0])),
               100 * b->mat[1] / bss, 100 * b->matn[1] / b->n, sqrt(b->mat[1] / fmax(1, b->matn[1])),
               100 * b->mat[2] / bss, 100 * b->matn[2] / b->n, sqrt(b->mat[2] / fmax(1, b->matn[2])),
               100 * b->sign[0] / bss, 100 * b->sign[1] / bss);
        static const char *const FN[9] = { "few", "cx=cy", "matte", "sat", "hidden", "filled", "masked", "kbound", "uncertain" };
        for (int f = 0; f < 9; f++)
                if (b->flagn[f] > 0)
                        printf(" %s %.1f%% SS (%.1f%% smp, rmse %.4f)", FN[f], 100 * b->flag[f] / bss, 100 * b->flagn[f] / b->n,
                               sqrt(b->flag[f] / b->flagn[f]));
        printf("\n");
}

/* The last channel of each texel of map (n lights + 1): the RMS over the lights. */
static void map_all_lights(float *map, size_t n_texels, int n) {
        for (size_t i = 0; i < n_texels; i++) {
                double s = 0;
                int c = 0;
                for (int li = 0; li < n; li++)
                        if (isfinite(map[i * (n + 1) + li]))
                                s += (double) map[i * (n + 1) + li] * map[i * (n + 1) + li], c++;
                map[i * (n + 1) + n] = c ? (float) sqrt(s / c) : NAN;
        }
}

/* Whether a texel within 2 of (x, y) has the light blocked (lit[] == 2). */
static bool near_shadow(const uint8_t *lit, int W, int H, int x, int y) {
        for (int dy = -2; dy <= 2; dy++)
                for (int dx = -2; dx <= 2; dx++) {
                        int xx = x + dx, yy = y + dy;
                        if (xx >= 0 && yy >= 0 && xx < W && yy < H && lit[(size_t) yy * W + xx] == 2)
                                return true;
                }
        return false;
}

/* Re-render the held-out lights on grid g with BRDF tex (spec_ref: a second BRDF whose
 * specular term also marks a highlight). Prints one line; fills map (w·h·(n+1)) when not NULL. */
static void rerender(const char *name, const struct grid *g, const struct imp_btf_texel *tex,
                     const struct imp_btf_texel *spec_ref, const struct imp_pinhole *cam,
                     const struct imp_rig_light *lights, struct imp_image **frames, struct imp_image **valid,
                     const double *elev, int n, float *map) {
        enum { TILE = 64 };
        const struct imp_btf_heightfield *bh = &g->hf;
        int W = bh->width, H = bh->height;
        struct imp_btf_samples *smp = NULL;
        struct imp_btf_hf_pyramid *py = NULL;
        int r = imp_btf_samples_new(TILE * TILE, 1, &smp);
        if (r < 0 || (r = imp_btf_hf_pyramid_new(bh, &py)) < 0)
                die("samples", r);
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        uint8_t *lit = malloc((size_t) W * H);            /* 1 lit, 2 shadowed, 0 other */
        float *res = malloc((size_t) W * H * sizeof *res); /* squared residual / NAN */
        float *spec = malloc((size_t) W * H * sizeof *spec);
        struct acc all = {};
        size_t nsamp = 0, cap = (size_t) W * H * n;
        float *allres = malloc(cap * sizeof *allres);
        printf("%-34s", name);
        struct breakdown bd = {};
        double per[64];
        for (int li = 0; li < n; li++) {
                const struct imp_image *fr = frames[li], *va = valid[li];
                struct imp_btf_capture capt = { cam, &lights[li], 1, &fr, &va };
                memset(lit, 0, (size_t) W * H);
                for (size_t i = 0; i < (size_t) W * H; i++)
                        res[i] = NAN;
                for (int y0 = 0; y0 < H; y0 += TILE)
                        for (int x0 = 0; x0 < W; x0 += TILE) {
                                int w = IMP_MIN(TILE, W - x0), h = IMP_MIN(TILE, H - y0);
                                if ((r = imp_btf_samples_extract_pyramid(bh, &capt, &sp, py, x0, y0, w, h, smp)) < 0)
                                        die("extract", r);
                                for (int k = 0; k < w * h; k++) {
                                        size_t ti = (size_t) (y0 + k / w) * W + x0 + k % w;
                                        if (smp->n_shadowed[k])
                                                lit[ti] = 2;
                                        if (smp->count[k] == 0 || (tex[ti].flags & IMP_BTF_MASKED) ||
                                            (smp->flags[k] & IMP_BTF_MASKED))
                                                continue;
                                        lit[ti] = 1;
                                        const struct imp_btf_sample *q = &smp->samples[k];
                                        const struct imp_btf_texel *t = &tex[ti];
                                        struct imp_lafortune b = { .cx = t->cx, .cy = t->cy, .cz = t->cz, .k = t->k };
                                        memcpy(b.rho_d, t->rho_d, sizeof b.rho_d);
                                        memcpy(b.rho_s, t->rho_s, sizeof b.rho_s);
                                        double v[3] = { q->v[0], q->v[1], q->v[2] }, l[3] = { q->l[0], q->l[1], q->l[2] };
                                        double E = q->e_cos / q->l[2];
                                        /* mono frames: the three channels are equal; channel 1 */
                                        double d = (q->value[1] - q->e_cos * imp_lafortune_eval(&b, 1, v, l)) / E;
                                        double sp1 = b.rho_s[1] * imp_lafortune_lobe(&b, v, l);
                                        if (spec_ref) {
                                                const struct imp_btf_texel *u = &spec_ref[ti];
                                                struct imp_lafortune b2 = { .cx = u->cx, .cy = u->cy, .cz = u->cz, .k = u->k };
                                                memcpy(b2.rho_s, u->rho_s, sizeof b2.rho_s);
                                                sp1 = fmax(sp1, b2.rho_s[1] * imp_lafortune_lobe(&b2, v, l));
                                        }
                                        spec[ti] = (float) sp1;
                                        if (isfinite(d)) {
                                                res[ti] = (float) (d * d);
                                                add_breakdown(&bd, spec_ref ? &spec_ref[ti] : t, t, d);
                                        }
                                }
                        }
                struct acc a = {};
                for (int y = 0; y < H; y++)
                        for (int x = 0; x < W; x++) {
                                size_t i = (size_t) y * W + x;
                                if (map)
                                        map[i * (n + 1) + li] = isfinite(res[i]) ? sqrtf(res[i]) : NAN;
                                if (!isfinite(res[i]))
                                        continue;
                                bool edge = near_shadow(lit, W, H, x, y);
                                bool hl = spec[i] > 0.02;
                                a.ss += res[i], a.n++;
                                if (edge)
                                        a.ss_edge += res[i], a.n_edge++;
                                if (hl)
                                        a.ss_hl += res[i], a.n_hl++;
                                if (nsamp < cap)
                                        allres[nsamp++] = res[i];
                        }
                per[li] = a.n ? sqrt(a.ss / a.n) : -1;
                all.ss += a.ss, all.ss_edge += a.ss_edge, all.ss_hl += a.ss_hl;
                all.n += a.n, all.n_edge += a.n_edge, all.n_hl += a.n_hl;
                if (getenv("DIAG_VERBOSE"))
                        fprintf(stderr, "  %s light %d elev %.0f: rmse %.4f, edge %.0f%% of SS (%.1f%% of samples), "
                                "highlight %.0f%% of SS (%.1f%% of samples), rmse without both %.4f\n", name, li,
                                elev[li], per[li], 100 * a.ss_edge / a.ss, 100 * a.n_edge / a.n, 100 * a.ss_hl / a.ss,
                                100 * a.n_hl / a.n, sqrt((a.ss - a.ss_edge - a.ss_hl) / fmax(1, a.n - a.n_edge - a.n_hl)));
        }
        qsort(allres, nsamp, sizeof *allres, cmp_desc);   /* worst first */
        double top = 0;
        for (size_t i = 0; i < nsamp / 100; i++)
                top += allres[i];
        printf(" rmse %.4f | edge %4.1f%% SS (%4.1f%% smp) | hl %4.1f%% SS (%4.1f%% smp) | worst1%% %4.1f%% SS |"
               " w/o edge+hl %.4f |", sqrt(all.ss / all.n), 100 * all.ss_edge / all.ss, 100 * all.n_edge / all.n,
               100 * all.ss_hl / all.ss, 100 * all.n_hl / all.n, 100 * top / all.ss,
               sqrt(fmax(0, all.ss - all.ss_edge - all.ss_hl) / fmax(1, all.n - all.n_edge - all.n_hl)));
        for (int li = 0; li < n; li++)
                printf(" %.0f°:%.4f", elev[li], per[li]);
        printf("\n");
        print_breakdown(&bd);
        fflush(stdout);
        if (map)
                map_all_lights(map, (size_t) W * H, n);
        free(allres);
        free(lit);
        free(res);
        free(spec);
        imp_btf_hf_pyramid_free(py);
        imp_btf_samples_free(smp);
}

static void write_map(const char *dir, const char *name, const struct grid *g, float *map, int n) {
        if (!dir)
                return;
        struct imp_image *img;
        if (imp_image_new(g->hf.width, g->hf.height, n + 1, IMP_PIX_F32, &img) < 0)
                die("map", -ENOMEM);
        memcpy(img->data, map, (size_t) g->hf.width * g->hf.height * (n + 1) * sizeof(float));
        char path[4096], *names[65];
        char buf[65][16];
        for (int i = 0; i <= n; i++) {
                snprintf(buf[i], sizeof buf[i], i < n ? "L%d" : "all", i);
                names[i] = buf[i];
        }
        snprintf(path, sizeof path, "%s/err-%s.exr", dir, name);
        struct imp_error err = {};
        if (imp_exr_write(path, img, (const char *const *) names, false, &err) < 0)
                fprintf(stderr, "%s\n", err.msg);
        imp_image_free(img);
}

/* The BRDF fitted on grid g from the fit lights (default parameters); with `timed`, the
 * stage's wall and CPU time and texels/s are printed. Caller frees. */
static struct imp_btf_texel *fit_on(const struct grid *g, const struct imp_btf_capture *capt, bool timed) {
        struct imp_btf_sample_params sp;
        struct imp_btf_fit_params fp;
        imp_btf_sample_params_default(&sp);
        imp_btf_fit_params_default(&fp);
        long ntx = (long) g->hf.width * g->hf.height;
        struct imp_btf_texel *rt = calloc(ntx, sizeof *rt);
        struct imp_btf_stats bs = {};
        struct timespec w0, w1, c0, c1;
        clock_gettime(CLOCK_MONOTONIC, &w0);
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c0);
        int r = rt ? imp_btf_fit_grid(&g->hf, capt, &sp, &fp, 64, rt, &bs) : -ENOMEM;
        clock_gettime(CLOCK_MONOTONIC, &w1);
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &c1);
        if (r < 0)
                die("refit", r);
        double ws = (w1.tv_sec - w0.tv_sec) + 1e-9 * (w1.tv_nsec - w0.tv_nsec);
        double cs = (c1.tv_sec - c0.tv_sec) + 1e-9 * (c1.tv_nsec - c0.tv_nsec);
        if (timed)
                printf("refit (imp_btf_fit_grid, %d lights): %ld texels (%ld fitted) in %.1f s wall, %.1f s CPU: "
                       "%.0f texels/s wall, %.0f texels per CPU-second; samples %ld, shadowed %ld\n", capt->n_lights,
                       ntx, bs.n_fitted, ws, cs, ntx / ws, ntx / cs, bs.n_samples, bs.n_shadowed);
        return rt;
}

/* The HDR-merged dome stacks of camera 0: the held-out ones (every Nth) and, with `fit`,
 * the others (the fit lights); prints the held-out count and the HDR noise. */
struct stacks {
        int nho, nfit;
        struct imp_image **ho_f, **ho_v, **fi_f, **fi_v;
        struct imp_rig_light *ho_l, *fi_l;
        double elev[64];
};

static void load_stacks(const struct imp_captureset *cs, const struct imp_rig_camera *cam, int N, bool refit,
                        struct stacks *ret) {
        struct imp_error err = {};
        const struct imp_rig *rig = imp_captureset_rig(cs);
        /* dome stacks of camera 0, in manifest order (process.c collect_stacks) */
        size_t nrec = imp_captureset_count(cs), nst = 0;
        size_t (*st)[8] = calloc(nrec, sizeof *st);
        int *stn = calloc(nrec, sizeof *stn);
        for (size_t i = 0; i < nrec; i++) {
                const struct imp_frame_record *r = imp_captureset_record(cs, i);
                if (strcmp(r->step, "dome") || strcmp(r->camera, cam->name) || r->tile != 0)
                        continue;
                size_t k = nst;
                if (nst > 0 && imp_captureset_record(cs, st[nst - 1][0])->light == r->light)
                        k = nst - 1;
                else
                        nst++;
                if (stn[k] < 8)
                        st[k][stn[k]++] = i;
        }
        int nho = 0, nfit = 0;
        struct imp_image **ho_f = calloc(nst, sizeof *ho_f), **ho_v = calloc(nst, sizeof *ho_v);
        struct imp_image **fi_f = calloc(nst, sizeof *fi_f), **fi_v = calloc(nst, sizeof *fi_v);
        struct imp_rig_light *ho_l = calloc(nst, sizeof *ho_l), *fi_l = calloc(nst, sizeof *fi_l);
        double *elev = ret->elev, noise_ss = 0, noise_n = 0;
        for (size_t s = 0; s < nst; s++) {
                bool held = N > 0 && (s + 1) % (size_t) N == 0;
                if (!held && !refit)
                        continue;
                struct imp_image *raw[8] = {};
                struct imp_hdr_exposure ex[8];
                for (int k = 0; k < stn[s]; k++) {
                        if (imp_captureset_load_frame(cs, st[s][k], &raw[k], &err) < 0) {
                                fprintf(stderr, "%s\n", err.msg);
                                exit(1);
                        }
                        const struct imp_frame_record *rec = imp_captureset_record(cs, st[s][k]);
                        ex[k] = (struct imp_hdr_exposure) { raw[k], rec->exposure_us, rec->gain_db };
                }
                struct imp_hdr_options opt;
                imp_hdr_options_default(&opt);
                opt.demosaic = true;
                struct imp_hdr_result h = {};
                int r = imp_hdr_merge(ex, stn[s], &cam->sensor, &opt, &h);
                for (int k = 0; k < stn[s]; k++)
                        imp_image_free(raw[k]);
                if (r < 0)
                        die("hdr merge", r);
                struct imp_image *vimg;
                if ((r = imp_btf_valid_from_hdr(h.flags, &vimg)) < 0)
                        die("validity", r);
                int id = imp_captureset_record(cs, st[s][0])->light;
                const struct imp_rig_light *L = NULL;
                for (int k = 0; k < rig->n_lights; k++)
                        if (rig->lights[k].id == id)
                                L = &rig->lights[k];
                if (held) {
                        /* HDR noise relative to the irradiance at the frame centre */
                        double X[3] = { 30, 20, 0 }, E = imp_btf_light_irradiance(L, X);
                        for (int y = 0; y < h.variance->height; y += 4)
                                for (int x = 0; x < h.variance->width; x += 4) {
                                        double v = *imp_image_f32(h.variance, x, y);
                                        if (isfinite(v))
                                                noise_ss += v / (E * E), noise_n++;
                                }
                        double dz = L->pos_mm[2], dxy = hypot(L->pos_mm[0] - 30, L->pos_mm[1] - 20);
                        elev[nho] = atan2(dz, dxy) * 180 / M_PI;
                        ho_f[nho] = TAKE_PTR(h.value);
                        ho_v[nho] = vimg;
                        ho_l[nho++] = *L;
                } else {
                        fi_f[nfit] = TAKE_PTR(h.value);
                        fi_v[nfit] = vimg;
                        fi_l[nfit++] = *L;
                }
                imp_hdr_result_done(&h);
        }
        printf("held-out lights: %d of %zu; HDR noise (σ of V/E at the centre's E, mean over pixels): %.4f\n", nho,
               nst, sqrt(noise_ss / fmax(1, noise_n)));
        free(st);
        free(stn);
        *ret = (struct stacks) { .nho = nho, .nfit = nfit, .ho_f = ho_f, .ho_v = ho_v, .fi_f = fi_f, .fi_v = fi_v,
                                 .ho_l = ho_l, .fi_l = fi_l };
        memcpy(ret->elev, elev, sizeof ret->elev);
}

/* The copy's texel positions and heights with the truth's normals (bilinear at each
 * texel's world point; smoothed over 2r+1 truth texels, r = 0 and 1), rendered with the
 * truth BRDF and with a BRDF refitted on them. */
static void true_normals_pass(const struct grid *gcp, const struct grid *gtp, double cp, double tp, const double org[2],
                              const struct imp_pinhole *cam_model, const struct imp_btf_capture *capt,
                              const struct stacks *S, float *mc) {
        const struct grid gc = *gcp, gt = *gtp;
        const int nho = S->nho;
        struct imp_rig_light *ho_l = S->ho_l;
        struct imp_image **ho_f = S->ho_f, **ho_v = S->ho_v;
        const double *elev = S->elev;
        size_t nt = (size_t) gc.hf.width * gc.hf.height;
        float *tn = malloc(3 * nt * sizeof *tn);
        const double *A = gc.hf.canvas_to_world;
        for (int rad = 0; rad <= 1; rad++) {
                for (int y = 0; y < gc.hf.height; y++)
                        for (int x = 0; x < gc.hf.width; x++) {
                                size_t i = (size_t) y * gc.hf.width + x;
                                double P[3] = { x * cp, y * cp, gc.height[i] }, W[3], nw[3] = { 0, 0, 0 };
                                for (int r = 0; r < 3; r++)
                                        W[r] = A[4 * r] * P[0] + A[4 * r + 1] * P[1] + A[4 * r + 2] * P[2] + A[4 * r + 3];
                                double fx = (W[0] - org[0]) / tp, fy = (W[1] - org[1]) / tp;
                                int x0 = (int) floor(fx), y0 = (int) floor(fy);
                                double ax = fx - x0, ay = fy - y0;
                                for (int dy = -rad; dy <= rad + 1; dy++)
                                        for (int dx = -rad; dx <= rad + 1; dx++) {
                                                int xx = IMP_CLAMP(x0 + dx, 0, gt.hf.width - 1), yy = IMP_CLAMP(y0 + dy, 0, gt.hf.height - 1);
                                                double wx = dx <= 0 ? (dx == 0 ? 1 - ax : 1) : (dx == rad + 1 ? ax : 1);
                                                double wy = dy <= 0 ? (dy == 0 ? 1 - ay : 1) : (dy == rad + 1 ? ay : 1);
                                                if (rad == 0) {
                                                        wx = dx == 0 ? 1 - ax : ax;
                                                        wy = dy == 0 ? 1 - ay : ay;
                                                }
                                                const float *q = gt.normal + 3 * ((size_t) yy * gt.hf.width + xx);
                                                for (int c = 0; c < 3; c++)
                                                        nw[c] += wx * wy * q[c];
                                        }
                                double len = 0;
                                for (int r = 0; r < 3; r++) {   /* canvas = Aᵀ world (rotation part) */
                                        double v = A[r] * nw[0] + A[4 + r] * nw[1] + A[8 + r] * nw[2];
                                        tn[3 * i + r] = (float) v;
                                        len += v * v;
                                }
                                for (int r = 0; r < 3; r++)
                                        tn[3 * i + r] = (float) (tn[3 * i + r] / sqrt(len));
                        }
                struct grid g3 = gc;
                g3.normal = tn;
                g3.hf.normal = tn;
                char nm[64];
                snprintf(nm, sizeof nm, "copy pos + true n (r%d) + true BRDF", rad);
                rerender(nm, &g3, gc.tex_other, NULL, cam_model, ho_l, ho_f, ho_v, elev, nho, mc);
                struct imp_btf_texel *rt = fit_on(&g3, capt, false);
                snprintf(nm, sizeof nm, "copy pos + true n (r%d) + refit", rad);
                rerender(nm, &g3, rt, gc.tex_other, cam_model, ho_l, ho_f, ho_v, elev, nho, mc);
                free(rt);
        }
        free(tn);
}

int main(int argc, char **argv) {
        if (argc < 5) {
                fprintf(stderr, "usage: diag-rerender CAPTURE COPY TRUTH N [--refit | --true-normals | --refit-copy] "
                        "[--maps DIR]\n");
                return 2;
        }
        const char *capdir = argv[1], *copydir = argv[2], *truthdir = argv[3], *mapdir = NULL;
        int N = atoi(argv[4]);
        bool refit = false, refit_copy = false, true_normals = false;
        for (int i = 5; i < argc; i++) {
                if (!strcmp(argv[i], "--refit"))
                        refit = true;
                else if (!strcmp(argv[i], "--true-normals"))
                        refit = true_normals = true;
                else if (!strcmp(argv[i], "--refit-copy"))
                        refit = refit_copy = true;
                else if (!strcmp(argv[i], "--maps") && i + 1 < argc)
                        mapdir = argv[++i];
        }
        struct imp_error err = {};
        struct imp_captureset *cs;
        if (imp_captureset_open(capdir, &cs, &err) < 0) {
                fprintf(stderr, "%s\n", err.msg);
                return 1;
        }
        const struct imp_rig *rig = imp_captureset_rig(cs);
        const struct imp_rig_camera *cam = &rig->cameras[0];

        struct stacks S;
        load_stacks(cs, cam, N, refit, &S);
        int nho = S.nho, nfit = S.nfit;
        struct imp_image **ho_f = S.ho_f, **ho_v = S.ho_v, **fi_f = S.fi_f, **fi_v = S.fi_v;
        struct imp_rig_light *ho_l = S.ho_l, *fi_l = S.fi_l;
        const double *elev = S.elev;

        /* the copy and the truth */
        _cleanup_json_ json_t *cj = NULL, *tj = NULL;
        char path[4096];
        snprintf(path, sizeof path, "%s/copy.json", copydir);
        double Mc[16], Mt[16] = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 }, cp, tp, org[2];
        if (imp_json_load(path, &cj, &err) < 0 || imp_json_get_doubles(cj, "canvas_to_world", true, 16, Mc, path, &err) < 0 ||
            imp_json_get_double(cj, "pitch_mm", true, &cp, path, &err) < 0) {
                fprintf(stderr, "%s\n", err.msg);
                return 1;
        }
        snprintf(path, sizeof path, "%s/truth.json", truthdir);
        if (imp_json_load(path, &tj, &err) < 0 || imp_json_get_double(tj, "pitch_mm", true, &tp, path, &err) < 0 ||
            imp_json_get_doubles(tj, "origin_mm", true, 2, org, path, &err) < 0) {
                fprintf(stderr, "%s\n", err.msg);
                return 1;
        }
        Mt[3] = org[0], Mt[7] = org[1];
        struct grid gc = {}, gt = {};
        load_grid(copydir, cp, Mc, &gc);
        load_grid(truthdir, tp, Mt, &gt);
        bool mono = cam->sensor.bayer == false && ho_f[0]->channels == 1;
        gc.tex = load_brdf(copydir, gc.hf.width, gc.hf.height, false);
        gt.tex = load_brdf(truthdir, gt.hf.width, gt.hf.height, mono);
        gc.tex_other = resample(&gc, &gt, gt.tex);   /* truth BRDF on the copy grid */
        gt.tex_other = resample(&gt, &gc, gc.tex);   /* copy BRDF on the truth grid */
        /* the copy's MASKED texels stay masked in the comparison on its grid */
        for (size_t i = 0; i < (size_t) gc.hf.width * gc.hf.height; i++)
                if (gc.tex[i].flags & IMP_BTF_MASKED)
                        gc.tex_other[i].flags |= IMP_BTF_MASKED;
        printf("copy %dx%d pitch %.4f, truth %dx%d pitch %.4f, mono %d\n", gc.hf.width, gc.hf.height, cp,
               gt.hf.width, gt.hf.height, tp, mono);

        struct imp_btf_capture capt = { &cam->model, fi_l, nfit, (const struct imp_image *const *) fi_f,
                                        (const struct imp_image *const *) fi_v };
        size_t nc = (size_t) gc.hf.width * gc.hf.height * (nho + 1), ntr = (size_t) gt.hf.width * gt.hf.height * (nho + 1);
        float *mc = calloc(nc, sizeof *mc), *mt = calloc(ntr, sizeof *mt);
        if (!getenv("DIAG_SKIP_BASE")) {
        rerender("true geometry + true BRDF", &gt, gt.tex, NULL, &cam->model, ho_l, ho_f, ho_v, elev, nho, mt);
        write_map(mapdir, "tgeo-tbrdf", &gt, mt, nho);
        rerender("true geometry + fitted BRDF", &gt, gt.tex_other, gt.tex, &cam->model, ho_l, ho_f, ho_v, elev, nho, mt);
        write_map(mapdir, "tgeo-fbrdf", &gt, mt, nho);
        rerender("fitted geometry + true BRDF", &gc, gc.tex_other, NULL, &cam->model, ho_l, ho_f, ho_v, elev, nho, mc);
        write_map(mapdir, "fgeo-tbrdf", &gc, mc, nho);
        rerender("fitted geometry + fitted BRDF", &gc, gc.tex, gc.tex_other, &cam->model, ho_l, ho_f, ho_v, elev, nho, mc);
        write_map(mapdir, "fgeo-fbrdf", &gc, mc, nho);
        }
        if (true_normals)
                true_normals_pass(&gc, &gt, cp, tp, org, &cam->model, &capt, &S, mc);
        if (refit_copy) {
                /* the copy's geometry, BRDF refitted here (reproduces the copy: a check; timed) */
                struct imp_btf_texel *rt = fit_on(&gc, &capt, true);
                rerender("fitted geometry + refit", &gc, rt, gc.tex_other, &cam->model, ho_l, ho_f, ho_v, elev, nho, mc);
                write_map(mapdir, "fgeo-refit", &gc, mc, nho);
                free(rt);
        }
        if (refit && !refit_copy && !true_normals) {
                struct imp_btf_texel *rt = fit_on(&gt, &capt, false);
                rerender("true geometry + BRDF refit on it", &gt, rt, gt.tex, &cam->model, ho_l, ho_f, ho_v, elev, nho, mt);
                write_map(mapdir, "tgeo-refit", &gt, mt, nho);
                free(rt);
        }
        return 0;
}
