/* Appearance figures of a copy against simulator truth (see compare-appearance.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include "btf.h"
#include "compare-appearance.h"
#include "compare.h"
#include "image.h"
#include "json-util.h"

#define CA_MIN_RHO_D        0.05    /* truth ρd below this: relative error meaningless */
#define CA_MIN_RHO_S        0.10    /* truth peak ρs below this: no lobe to speak of */
#define CA_LOBE_FLAGS (IMP_BTF_MATTE | IMP_BTF_FEW_SAMPLES | IMP_BTF_HIDDEN | IMP_BTF_FILLED | \
                       IMP_BTF_MASKED | IMP_BTF_K_BOUND | IMP_BTF_LOBE_UNCERTAIN)

/* One EXR with the channels a caller needs, resolved to indices. */
struct map {
        struct imp_image *img;
        int c[5];
};

static void map_done(struct map *m) {
        imp_image_free(m->img);
        m->img = NULL;
}

static int map_load(const char *dir, const char *file, const char *const *chans, int n, bool optional,
                    struct map *m, struct imp_error *err) {
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", dir, file);
        struct stat st;
        if (optional && stat(path, &st) < 0)
                return 0;
        char **names = NULL;
        int r = imp_exr_read(path, &m->img, &names, err);
        if (r < 0)
                return r;
        for (int i = 0; i < n; i++) {
                m->c[i] = imp_image_channel_index(names, chans[i]);
                if (m->c[i] < 0) {
                        imp_strv_free(names);
                        map_done(m);
                        return imp_error_set(err, -EBADMSG, "%s: channel \"%s\" missing", path, chans[i]);
                }
        }
        imp_strv_free(names);
        return 0;
}

static double at(const struct map *m, int i, int j, int k) {
        return *(imp_image_f32(m->img, i, j) + m->c[k]);
}

static int cmp_double(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

/* Sorts v and returns its q-quantile (nearest rank); -1 for an empty set. */
static double quantile(double *v, size_t n, double q) {
        if (n == 0)
                return -1;
        qsort(v, n, sizeof *v, cmp_double);
        if (q == 0.5)
                return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
        size_t k = (size_t) ceil(q * n);
        return v[k ? k - 1 : 0];
}

static size_t count_nonfinite(const struct imp_image *img) {
        size_t n = 0;
        for (int j = 0; j < img->height; j++)
                for (int i = 0; i < img->width; i++)
                        for (int c = 0; c < img->channels; c++)
                                n += !isfinite(*(imp_image_f32(img, i, j) + c));
        return n;
}

struct truth_grid {
        double pitch, origin[2];
        int nx, ny;
};

/* Truth grid coordinates of world (x, y); false outside. */
static bool truth_coords(const struct truth_grid *g, double x, double y, double *fx, double *fy) {
        *fx = (x - g->origin[0]) / g->pitch;
        *fy = (y - g->origin[1]) / g->pitch;
        return *fx >= 0 && *fy >= 0 && *fx <= g->nx - 1 && *fy <= g->ny - 1;
}

static const char *const RGB[] = { "R", "G", "B" }, *const LOBE[] = { "cx", "cy", "cz", "k" };

/* The held-out re-rendering figures of copy.json stages.btf.validation, when present. */
static void read_validation(json_t *cj, const char *path, struct imp_compare_appearance *res,
                            struct imp_error *err) {
        json_t *val = json_object_get(json_object_get(json_object_get(cj, "stages"), "btf"), "validation");
        if (!json_is_object(val))
                return;
        double v;
        long long n;
        if (imp_json_get_double(val, "rmse", false, &v, path, err) == 0 && isfinite(v))
                res->rerender_rmse = v;
        if (imp_json_get_int(val, "lights", false, &n, path, err) == 0 && n > 0)
                res->rerender_lights = (size_t) n;
        if (imp_json_get_int(val, "texels", false, &n, path, err) == 0 && n > 0)
                res->rerender_texels = (size_t) n;
}

/* True when the copy's ρd is grey everywhere (a mono camera: R = G = B). */
static bool is_mono(const struct map *cd) {
        for (int j = 0; j < cd->img->height; j++)
                for (int i = 0; i < cd->img->width; i++) {
                        double r0 = at(cd, i, j, 0);
                        if (isfinite(r0) && (at(cd, i, j, 1) != r0 || at(cd, i, j, 2) != r0))
                                return false;
                }
        return true;
}

/* The copy's maps (heightfield, ρd, ρs, lobe, fit flags) and the truth's (mask, ρd, ρs,
 * lobe) into all[0..9), each checked against the size its JSON states. */
static int load_maps(const char *copy_dir, const char *truth_dir, struct map *const all[9], long long cnx,
                     long long cny, const struct truth_grid *g, struct imp_error *err) {
        static const char *const HF[] = { "height", "mask" }, *const TM[] = { "mask" }, *const FL[] = { "flags" };
        int r;
        if ((r = map_load(copy_dir, "heightfield.exr", HF, 2, false, all[0], err)) < 0 ||
            (r = map_load(copy_dir, "rho_d.exr", RGB, 3, false, all[1], err)) < 0 ||
            (r = map_load(copy_dir, "rho_s.exr", RGB, 3, false, all[2], err)) < 0 ||
            (r = map_load(copy_dir, "lobe.exr", LOBE, 4, false, all[3], err)) < 0 ||
            (r = map_load(copy_dir, "fit-flags.exr", FL, 1, true, all[4], err)) < 0 ||
            (r = map_load(truth_dir, "heightfield.exr", TM, 1, false, all[5], err)) < 0 ||
            (r = map_load(truth_dir, "rho_d.exr", RGB, 3, false, all[6], err)) < 0 ||
            (r = map_load(truth_dir, "rho_s.exr", RGB, 3, false, all[7], err)) < 0 ||
            (r = map_load(truth_dir, "lobe.exr", LOBE, 4, false, all[8], err)) < 0)
                return r;
        for (size_t k = 0; k < 5; k++)
                if (all[k]->img && (all[k]->img->width != cnx || all[k]->img->height != cny))
                        return imp_error_set(err, -EBADMSG, "%s: copy maps are not %lldx%lld as copy.json says",
                                             copy_dir, cnx, cny);
        for (size_t k = 5; k < 9; k++)
                if (all[k]->img->width != g->nx || all[k]->img->height != g->ny)
                        return imp_error_set(err, -EBADMSG, "%s: truth maps are not %dx%d as truth.json says",
                                             truth_dir, g->nx, g->ny);
        return 0;
}

int imp_compare_appearance(const char *copy_dir, const char *truth_dir,
                           struct imp_compare_appearance *ret, struct imp_error *err) {
        if (!copy_dir || !truth_dir || !ret)
                return imp_error_set(err, -EINVAL, "compare: bad arguments");
        char path[4096];
        struct stat st;
        snprintf(path, sizeof path, "%s/rho_d.exr", copy_dir);
        if (stat(path, &st) < 0)
                return imp_error_set(err, -ENOENT, "%s: no appearance in this copy", path);
        _cleanup_json_ json_t *cj = NULL;
        struct imp_compare_grids grids;
        int r = imp_compare_load_grids(copy_dir, truth_dir, &cj, &grids, err);
        if (r < 0)
                return r;
        const double *M = grids.canvas_to_world;
        const double cpitch = grids.copy_pitch;
        const long long cnx = grids.copy_nx, cny = grids.copy_ny;
        snprintf(path, sizeof path, "%s/copy.json", copy_dir);
        struct imp_compare_appearance res = { .rerender_rmse = -1 };
        read_validation(cj, path, &res, err);

        struct truth_grid g = { .pitch = grids.truth_pitch, .origin = { grids.truth_origin[0], grids.truth_origin[1] },
                                .nx = (int) grids.truth_nx, .ny = (int) grids.truth_ny };

        struct map ch = {}, cd = {}, cs = {}, cl = {}, cf = {}, tm = {}, td = {}, ts = {}, tl = {};
        struct map *all[] = { &ch, &cd, &cs, &cl, &cf, &tm, &td, &ts, &tl };
        _cleanup_free_ double *ed = NULL, *ek = NULL, *es = NULL;
        if ((r = load_maps(copy_dir, truth_dir, all, cnx, cny, &g, err)) < 0)
                goto out;
        res.nan_count = count_nonfinite(cd.img) + count_nonfinite(cs.img) + count_nonfinite(cl.img);

        size_t nt = (size_t) cnx * cny;
        ed = malloc((3 * nt + 1) * sizeof *ed);
        ek = malloc((nt + 1) * sizeof *ek);
        es = malloc((nt + 1) * sizeof *es);
        if (!ed || !ek || !es) {
                r = imp_error_set(err, -ENOMEM, "compare: out of memory");
                goto out;
        }
        /* A mono camera records the Rec. 709 luminance of the radiance (sim/render.h) and the
         * copy then holds grey ρd (R = G = B everywhere): compare it with the luminance of
         * the true ρd, not with each colour channel. */
        bool mono = is_mono(&cd);
        res.mono = mono;
        static const double LUMA[3] = { 0.2126, 0.7152, 0.0722 };
        size_t nd = 0, nk = 0;
        for (int j = 0; j < cny; j++)
                for (int i = 0; i < cnx; i++) {
                        double h = at(&ch, i, j, 0);
                        if (!(at(&ch, i, j, 1) >= 0.5) || !isfinite(h))
                                continue;
                        double X = M[0] * i * cpitch + M[1] * j * cpitch + M[2] * h + M[3];
                        double Y = M[4] * i * cpitch + M[5] * j * cpitch + M[6] * h + M[7];
                        double fx, fy;
                        if (!truth_coords(&g, X, Y, &fx, &fy))
                                continue;
                        int x0 = IMP_MIN((int) fx, IMP_MAX(g.nx - 2, 0)), y0 = IMP_MIN((int) fy, IMP_MAX(g.ny - 2, 0));
                        int x1 = IMP_MIN(x0 + 1, g.nx - 1), y1 = IMP_MIN(y0 + 1, g.ny - 1);
                        double ax = fx - x0, ay = fy - y0;
                        bool canvas = at(&tm, x0, y0, 0) >= 0.5 && at(&tm, x1, y0, 0) >= 0.5 &&
                                      at(&tm, x0, y1, 0) >= 0.5 && at(&tm, x1, y1, 0) >= 0.5;
                        if (!canvas)
                                continue;
                        double tc3[3], tlum = 0;
                        for (int c = 0; c < 3; c++) {
                                tc3[c] = (at(&td, x0, y0, c) * (1 - ax) + at(&td, x1, y0, c) * ax) * (1 - ay) +
                                         (at(&td, x0, y1, c) * (1 - ax) + at(&td, x1, y1, c) * ax) * ay;
                                tlum += LUMA[c] * tc3[c];
                        }
                        for (int c = 0; c < (mono ? 1 : 3); c++) {
                                double t = mono ? tlum : tc3[c], v = at(&cd, i, j, c);
                                if (t >= CA_MIN_RHO_D && isfinite(v))
                                        ed[nd++] = fabs(v - t) / t;
                        }
                        int ti = (int) lround(fx), tj = (int) lround(fy);
                        double tc = fmax(fmax(fabs(at(&tl, ti, tj, 0)), fabs(at(&tl, ti, tj, 1))), fabs(at(&tl, ti, tj, 2)));
                        double tk = at(&tl, ti, tj, 3), peak = tc > 0 ? pow(tc, tk) : 0, ts_peak = 0, cs_mean = 0;
                        for (int c = 0; c < 3; c++) {
                                ts_peak += at(&ts, ti, tj, c) * peak / 3;
                                cs_mean += at(&cs, i, j, c) / 3;
                        }
                        if (!(ts_peak >= CA_MIN_RHO_S) || !(tk > 0))
                                continue;
                        unsigned flags = cf.img ? (unsigned) lround(fmax(0, at(&cf, i, j, 0))) : 0;
                        double ck = at(&cl, i, j, 3);
                        if ((flags & CA_LOBE_FLAGS) || !isfinite(ck)) {
                                res.lobe_flagged++;
                                continue;
                        }
                        ek[nk] = fabs(ck - tk) / tk;
                        es[nk++] = fabs(cs_mean - ts_peak) / ts_peak;
                }
        if (nd == 0) {
                r = imp_error_set(err, -ENODATA, "compare %s vs %s: no copy texel over the truth canvas",
                                  copy_dir, truth_dir);
                goto out;
        }
        res.rho_d_samples = nd;
        res.rho_d_rel_err_median = quantile(ed, nd, 0.5);
        res.rho_d_rel_err_p90 = quantile(ed, nd, 0.9);
        res.lobe_texels = nk;
        res.lobe_k_rel_err_median = quantile(ek, nk, 0.5);
        res.lobe_k_rel_err_p90 = quantile(ek, nk, 0.9);
        res.rho_s_rel_err_median = quantile(es, nk, 0.5);
        *ret = res;
        r = 0;
out:
        for (size_t k = 0; k < ARRAY_SIZE(all); k++)
                map_done(all[k]);
        return r;
}

/* A figure with nothing to measure (-1) is null. */
void imp_compare_appearance_to_json(const struct imp_compare_appearance *r, json_t *obj) {
        json_object_set_new(obj, "rho_d_rel_err_median", imp_json_figure(r->rho_d_rel_err_median));
        json_object_set_new(obj, "rho_d_mono", json_boolean(r->mono));
        json_object_set_new(obj, "rho_d_rel_err_p90", imp_json_figure(r->rho_d_rel_err_p90));
        json_object_set_new(obj, "rho_d_samples", json_integer((json_int_t) r->rho_d_samples));
        json_object_set_new(obj, "lobe_k_rel_err_median", imp_json_figure(r->lobe_k_rel_err_median));
        json_object_set_new(obj, "lobe_k_rel_err_p90", imp_json_figure(r->lobe_k_rel_err_p90));
        json_object_set_new(obj, "rho_s_rel_err_median", imp_json_figure(r->rho_s_rel_err_median));
        json_object_set_new(obj, "lobe_texels", json_integer((json_int_t) r->lobe_texels));
        json_object_set_new(obj, "lobe_flagged", json_integer((json_int_t) r->lobe_flagged));
        json_object_set_new(obj, "rerender_rmse", imp_json_figure(r->rerender_rmse));
        json_object_set_new(obj, "rerender_lights", json_integer((json_int_t) r->rerender_lights));
        json_object_set_new(obj, "rerender_texels", json_integer((json_int_t) r->rerender_texels));
        json_object_set_new(obj, "appearance_nan_count", json_integer((json_int_t) r->nan_count));
}
