/* Relief classification into n×n-cell boxes (seed §4.3; see boxes.h). */
#include <math.h>
#include <string.h>
#include "boxes.h"
#include "json-util.h"
#include "numerics.h"

#define BOXES_DEFAULT_DELTA_FRAC   0.3
#define BOXES_DEFAULT_CELL_PX      20
#define BOXES_DEFAULT_MIN_COMP     8
#define BOXES_DEFAULT_REF_PCT      5.0
#define BOXES_DEFAULT_NOISE_K      6.0

void imp_boxes_options_default(struct imp_boxes_options *opt) {
        *opt = (struct imp_boxes_options) {
                .delta_frac = BOXES_DEFAULT_DELTA_FRAC,
                .cell_px = BOXES_DEFAULT_CELL_PX,
                .min_component_px = BOXES_DEFAULT_MIN_COMP,
                .ref_percentile = BOXES_DEFAULT_REF_PCT,
                .noise_k = BOXES_DEFAULT_NOISE_K,
        };
}

void imp_boxes_done(struct imp_boxes *b) {
        if (!b)
                return;
        free(b->boxes);
        free(b->significant);
        *b = (struct imp_boxes) {};
}

/* Label 8-connected components of sig; drop those below min_px. */
static int clean_components(uint8_t *sig, int w, int h, size_t min_px, size_t *ret_n, size_t *ret_removed) {
        size_t N = (size_t) w * h, n = 0, removed = 0;
        _cleanup_free_ uint32_t *stack = malloc(N * sizeof(uint32_t));
        _cleanup_free_ uint32_t *comp = malloc(N * sizeof(uint32_t));
        _cleanup_free_ uint8_t *seen = calloc(N, 1);
        if (!stack || !comp || !seen)
                return -ENOMEM;
        for (size_t s = 0; s < N; s++) {
                if (!sig[s] || seen[s])
                        continue;
                size_t top = 0, cnt = 0;
                stack[top++] = (uint32_t) s;
                seen[s] = 1;
                while (top > 0) {
                        size_t i = stack[--top];
                        comp[cnt++] = (uint32_t) i;
                        int x = (int) (i % w), y = (int) (i / w);
                        for (int dy = -1; dy <= 1; dy++)
                                for (int dx = -1; dx <= 1; dx++) {
                                        int xx = x + dx, yy = y + dy;
                                        if (xx < 0 || yy < 0 || xx >= w || yy >= h)
                                                continue;
                                        size_t j = (size_t) yy * w + xx;
                                        if (sig[j] && !seen[j]) {
                                                seen[j] = 1;
                                                stack[top++] = (uint32_t) j;
                                        }
                                }
                }
                n++;
                if (cnt < min_px) {
                        removed++;
                        for (size_t k = 0; k < cnt; k++)
                                sig[comp[k]] = 0;
                }
        }
        *ret_n = n;
        *ret_removed = removed;
        return 0;
}

/* Median height σ over the measured texels (mask 1), 0 without σ; tmp: room for nx·ny. */
static double median_sigma(const struct imp_heightfield *hf, float *tmp) {
        if (!hf->sigma_mm)
                return 0;
        size_t N = (size_t) hf->nx * hf->ny, m = 0;
        for (size_t i = 0; i < N; i++)
                if (hf->mask[i] == IMP_HF_MASK_MEASURED && isfinite(hf->sigma_mm[i]) && hf->sigma_mm[i] > 0)
                        tmp[m++] = hf->sigma_mm[i];
        if (!m)
                return 0;
        return imp_select_kth_float(tmp, m, m / 2);   /* the sorted array's element, without sorting */
}

int imp_boxes_classify(const struct imp_heightfield *hf, const struct imp_boxes_options *opt,
                       struct imp_boxes *ret) {
        struct imp_boxes_options defaults;
        if (!hf || !ret || hf->nx <= 0 || hf->ny <= 0 || !hf->height_mm || !hf->mask)
                return -EINVAL;
        if (!opt) {
                imp_boxes_options_default(&defaults);
                opt = &defaults;
        }
        if (opt->cell_px <= 0 || !(opt->delta_frac >= 0 && opt->delta_frac <= 1) ||
            !(opt->ref_percentile >= 0 && opt->ref_percentile <= 100) || !(opt->noise_k >= 0))
                return -EINVAL;
        int w = hf->nx, h = hf->ny, r;
        size_t N = (size_t) w * h, n = 0;
        _cleanup_free_ float *hv = malloc(N * sizeof(float));
        _cleanup_free_ uint8_t *sig = calloc(N, 1);
        if (!hv || !sig)
                return -ENOMEM;
        float hmax = -INFINITY;
        for (size_t i = 0; i < N; i++)
                if (hf->mask[i] && isfinite(hf->height_mm[i])) {
                        hv[n++] = hf->height_mm[i];
                        hmax = fmaxf(hmax, hf->height_mm[i]);
                }
        if (n == 0)
                return -ENODATA;
        double href = imp_select_kth_float(hv, n, (size_t) llround(opt->ref_percentile / 100.0 * (double) (n - 1)));
        double H = fmax(hmax - href, 0.0), floor_mm = opt->noise_k * median_sigma(hf, hv);
        double delta0 = fmax(opt->delta_frac * H, floor_mm);
        for (size_t i = 0; i < N; i++)
                sig[i] = H > 0 && hf->mask[i] && isfinite(hf->height_mm[i]) && hf->height_mm[i] - href > delta0;

        struct imp_boxes b = {
                .cell_px = opt->cell_px, .nx = w, .ny = h, .pitch_mm = hf->pitch_mm,
                .cells_u = (w + opt->cell_px - 1) / opt->cell_px,
                .cells_v = (h + opt->cell_px - 1) / opt->cell_px,
                .h_ref_mm = href, .H_mm = H, .delta0_mm = delta0, .delta0_floor_mm = floor_mm,
                .below_noise = floor_mm > opt->delta_frac * H,
        };
        if ((r = clean_components(sig, w, h, opt->min_component_px, &b.n_components, &b.n_components_removed)) < 0)
                return r;
        for (size_t i = 0; i < N; i++)
                b.n_significant += sig[i];

        size_t n_cells = (size_t) b.cells_u * b.cells_v;
        _cleanup_free_ struct imp_box *boxes = calloc(n_cells ? n_cells : 1, sizeof(struct imp_box));
        if (!boxes)
                return -ENOMEM;
        for (int cv = 0; cv < b.cells_v; cv++)
                for (int cu = 0; cu < b.cells_u; cu++) {
                        struct imp_box bx = {
                                .cell_u = cu, .cell_v = cv, .u0 = cu * opt->cell_px, .v0 = cv * opt->cell_px,
                                .hmax_mm = -INFINITY,
                        };
                        bx.w = IMP_MIN(opt->cell_px, w - bx.u0);
                        bx.h = IMP_MIN(opt->cell_px, h - bx.v0);
                        for (int v = bx.v0; v < bx.v0 + bx.h; v++)
                                for (int u = bx.u0; u < bx.u0 + bx.w; u++) {
                                        size_t i = (size_t) v * w + u;
                                        bx.n_significant += sig[i];
                                        if (hf->mask[i] && hf->height_mm[i] > bx.hmax_mm) {
                                                bx.hmax_mm = hf->height_mm[i];
                                                bx.umax = u, bx.vmax = v;
                                        }
                                }
                        if (bx.n_significant > 0)
                                boxes[b.n_boxes++] = bx;
                }
        b.boxes = TAKE_PTR(boxes);
        b.significant = TAKE_PTR(sig);
        *ret = b;
        return 0;
}

json_t *imp_boxes_to_json(const struct imp_boxes *b) {
        json_t *arr = json_array();
        for (size_t k = 0; k < b->n_boxes; k++) {
                const struct imp_box *x = &b->boxes[k];
                json_array_append_new(arr, json_pack("{s:i,s:i,s:i,s:i,s:i,s:i,s:f,s:i,s:i,s:I}",
                        "cell_u", x->cell_u, "cell_v", x->cell_v, "u0", x->u0, "v0", x->v0,
                        "w", x->w, "h", x->h, "hmax", (double) x->hmax_mm, "umax", x->umax,
                        "vmax", x->vmax, "significant_texels", (json_int_t) x->n_significant));
        }
        return json_pack("{s:s,s:f,s:i,s:i,s:i,s:i,s:i,s:f,s:f,s:f,s:f,s:f,s:b,s:I,s:I,s:o}",
                         "units", "mm", "pitch_mm", b->pitch_mm, "nx", b->nx, "ny", b->ny,
                         "cell_px", b->cell_px, "cells_u", b->cells_u, "cells_v", b->cells_v,
                         "h_ref", b->h_ref_mm, "H", b->H_mm, "delta0", b->delta0_mm,
                         "bump_plane", b->h_ref_mm + b->delta0_mm,
                         "delta0_noise_floor", b->delta0_floor_mm, "below_noise", b->below_noise,
                         "significant_texels", (json_int_t) b->n_significant,
                         "components_removed", (json_int_t) b->n_components_removed,
                         "boxes", arr);
}

int imp_boxes_save(const struct imp_boxes *b, const char *path, struct imp_error *err) {
        if (!b || !path)
                return imp_error_set(err, -EINVAL, "boxes save: bad arguments");
        _cleanup_json_ json_t *j = imp_boxes_to_json(b);
        if (!j)
                return imp_error_set(err, -ENOMEM, "%s: cannot build JSON", path);
        return imp_json_save_atomic(path, j, err);
}
