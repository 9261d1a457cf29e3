/* The processing service's whole job: a capture set in, the digital copy out. Runs every
 * stage in order: HDR merge of each exposure stack, structured-light decoding,
 * triangulation, heightfield (seed 000 §4.2), relief boxes (§4.3), and, when the set holds
 * a dome sweep, the shadow-aware Lafortune fit (§4.4); writes the copy's files, PNG
 * previews and copy.json with per-stage figures. Library code: progress goes through a
 * callback, errors through struct imp_error. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <stdarg.h>
#include <sys/resource.h>
#include <unistd.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "boxes.h"
#include "btf.h"
#include "captureset.h"
#include "copy-previews.h"
#include "hdr.h"
#include "fuse.h"
#include "heightfield.h"
#include "process-painting.h"
#include "json-util.h"
#include "photometric.h"
#include "process.h"
#include "quality.h"
#include "structured-light.h"
#include "triangulate.h"
#include "version.h"

#define IMP_HDR_MAX_STACK 8   /* exposures per stack, as many as a plan may list */

/* One exposure stack: the frames of one (step, camera, tile, pattern, light). idx holds the
 * first frame of each distinct exposure (and gain); repeats of one (a plan's `repeat`) are
 * averaged into it when the stack is merged, so every frame counts and none is dropped. */
struct stack {
        size_t first;                 /* manifest index of the first frame */
        size_t idx[IMP_HDR_MAX_STACK];
        int n;
};

static bool same_exposure(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return a->exposure_us == b->exposure_us && a->gain_db == b->gain_db;
}

/* What one run works on. */
struct process_opts {
        const char *capture, *out;
        const struct imp_process_options *opt;
        json_t *incomplete;           /* what the set lacks of its plan (allow_incomplete) */
        struct imp_heightfield_options hf;   /* opt->heightfield with the painting tile's changes */
        json_t *painting_tile;        /* provenance.painting_tile, NULL when not one */
};

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void progress(const struct process_opts *o, const char *stage, size_t done, size_t total) {
        if (o->opt->progress)
                o->opt->progress(o->opt->userdata, stage, done, total);
}

static bool same_shot(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        const struct imp_pattern *p = &a->pattern, *q = &b->pattern;
        return !strcmp(a->step, b->step) && !strcmp(a->camera, b->camera) && a->tile == b->tile &&
               a->light == b->light && p->kind == q->kind && p->axis == q->axis && p->bit == q->bit &&
               p->inverse == q->inverse && p->period_px == q->period_px && p->step == q->step &&
               p->steps == q->steps;
}

/* Groups consecutive manifest records of one camera and step into exposure stacks. */
static int collect_stacks(const struct imp_captureset *cs, const char *step, const char *camera,
                          struct stack **ret, size_t *ret_n) {
        size_t n = imp_captureset_count(cs), count = 0;
        _cleanup_free_ struct stack *v = calloc(n ? n : 1, sizeof *v);
        if (!v)
                return -ENOMEM;
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *r = imp_captureset_record(cs, i);
                if (strcmp(r->step, step) || strcmp(r->camera, camera) || r->tile != 0)
                        continue;
                struct stack *s = NULL;
                for (size_t k = count; k-- > 0;)
                        if (same_shot(imp_captureset_record(cs, v[k].first), r)) {
                                s = &v[k];
                                break;
                        }
                if (!s) {
                        s = &v[count++];
                        s->first = i;
                }
                bool repeat = false;
                for (int k = 0; k < s->n && !repeat; k++)
                        repeat = same_exposure(imp_captureset_record(cs, s->idx[k]), r);
                if (!repeat && s->n < IMP_HDR_MAX_STACK)
                        s->idx[s->n++] = i;
        }
        *ret = TAKE_PTR(v);
        *ret_n = count;
        return 0;
}

/* Frame `first` and its repeats (same shot, exposure and gain) later in the set, as their
 * mean (rounded DN) in *img (decoded into the image *img holds when it has the frame's
 * layout); the number of frames in *ret_n. */
static int load_averaged(const struct imp_captureset *cs, size_t first, struct imp_image **img,
                         unsigned *ret_n, struct imp_error *err) {
        const struct imp_frame_record *a = imp_captureset_record(cs, first);
        int r = imp_captureset_load_frame_reuse(cs, first, img, err);   /* *img: the thread's buffer */
        if (r < 0)
                return r;
        *ret_n = 1;
        if ((*img)->type != IMP_PIX_U16)
                return 0;
        size_t n_px = (size_t) (*img)->width * (*img)->height * (*img)->channels;
        _cleanup_free_ uint32_t *sum = NULL;
        for (size_t i = first + 1; i < imp_captureset_count(cs); i++) {
                const struct imp_frame_record *b = imp_captureset_record(cs, i);
                if (!same_shot(a, b) || !same_exposure(a, b))
                        continue;
                _cleanup_image_ struct imp_image *f = NULL;
                if ((r = imp_captureset_load_frame(cs, i, &f, err)) < 0)
                        return r;
                if (f->type != IMP_PIX_U16 || f->width != (*img)->width || f->height != (*img)->height ||
                    f->channels != (*img)->channels)
                        return imp_error_set(err, -EINVAL, "%s: frame %zu differs in size from frame %zu",
                                             imp_captureset_dir(cs), i, first);
                if (!sum) {
                        if (!(sum = malloc(n_px * sizeof *sum)))
                                return imp_error_set(err, -ENOMEM, "out of memory");
                        for (int y = 0, j = 0; y < (*img)->height; y++) {
                                const uint16_t *p = imp_image_row(*img, y);
                                for (size_t x = 0; x < (size_t) (*img)->width * (*img)->channels; x++)
                                        sum[j++] = p[x];
                        }
                }
                for (int y = 0, j = 0; y < f->height; y++) {
                        const uint16_t *p = imp_image_row(f, y);
                        for (size_t x = 0; x < (size_t) f->width * f->channels; x++)
                                sum[j++] += p[x];
                }
                ++*ret_n;
        }
        if (!sum)
                return 0;
        for (int y = 0, j = 0; y < (*img)->height; y++) {
                uint16_t *p = imp_image_row(*img, y);
                for (size_t x = 0; x < (size_t) (*img)->width * (*img)->channels; x++)
                        p[x] = (uint16_t) ((sum[j++] + *ret_n / 2) / *ret_n);
        }
        return 0;
}

/* What one thread keeps from stack to stack: its decoded frames and the variance and flags
 * images of its last merge, which the next decodes and merges into: the same bytes, without
 * allocating, zeroing and faulting in ~13 MB a stack anew. */
struct stack_scratch {
        struct imp_image *frames[IMP_HDR_MAX_STACK];
        struct imp_hdr_result spare;
};

static void stack_scratch_done(struct stack_scratch *sc) {
        for (int k = 0; k < IMP_HDR_MAX_STACK; k++)
                imp_image_free(sc->frames[k]);
        imp_hdr_result_done(&sc->spare);
        *sc = (struct stack_scratch) {};
}

/* The merge's variance and flags, once read, kept as the thread's spare; h is done. */
static void keep_spare(struct stack_scratch *sc, struct imp_hdr_result *h) {
        imp_hdr_result_done(&sc->spare);
        sc->spare = (struct imp_hdr_result) { .variance = TAKE_PTR(h->variance), .flags = TAKE_PTR(h->flags) };
        imp_hdr_result_done(h);
}

/* Loads and merges one stack into linear values, in the thread's buffers sc; the values in
 * arena (NULL: the heap). */
static int merge_stack(const struct imp_captureset *cs, const struct stack *s,
                       const struct imp_sensor *sensor, struct stack_scratch *sc, struct imp_image_arena *arena,
                       struct imp_hdr_result *ret, struct imp_error *err) {
        struct imp_hdr_exposure ex[IMP_HDR_MAX_STACK];
        int r = 0;
        for (int k = 0; k < s->n; k++) {
                unsigned n_avg = 1;
                r = load_averaged(cs, s->idx[k], &sc->frames[k], &n_avg, err);
                if (r < 0)
                        return r;
                const struct imp_frame_record *rec = imp_captureset_record(cs, s->idx[k]);
                ex[k] = (struct imp_hdr_exposure) { sc->frames[k], rec->exposure_us, rec->gain_db, n_avg };
        }
        struct imp_hdr_options opt;
        imp_hdr_options_default(&opt);
        opt.demosaic = true;
        opt.recycle = &sc->spare;
        opt.arena = arena;
        r = imp_hdr_merge(ex, s->n, sensor, &opt, ret);
        if (r < 0)
                imp_error_set(err, r, "%s: HDR merge of frame %zu failed: %s",
                              imp_captureset_dir(cs), s->first, strerror(-r));
        return r;
}

/* Runs each(ctx, i, err) for i in [0, n) on the OpenMP threads, one stack a thread: reading
 * and decoding a stack's frames is most of its merge and runs on one thread, so stacks side
 * by side are what fills the cores (the merge's own loop then runs on its thread alone:
 * OpenMP does not nest). Progress from the calling thread; returns the error of the first
 * failing stack in manifest order (those after it are not started once it is known). */
static int for_each_stack(const struct process_opts *o, const char *stage, size_t n,
                          int (*each)(void *ctx, size_t i, struct stack_scratch *sc, struct imp_error *err),
                          void *ctx, struct imp_error *err) {
        size_t fail = n, done = 0;
        int r = 0, n_threads = 1;
#ifdef _OPENMP
        n_threads = omp_get_max_threads();
#endif
        _cleanup_free_ struct stack_scratch *scratch = calloc((size_t) n_threads, sizeof *scratch);
        if (!scratch)
                return imp_error_set(err, -ENOMEM, "out of memory");
#pragma omp parallel for schedule(dynamic, 1)
        for (size_t i = 0; i < n; i++) {
                if (__atomic_load_n(&fail, __ATOMIC_RELAXED) < i)
                        continue;
                struct imp_error e = {};
                int t = 0;
#ifdef _OPENMP
                t = omp_get_thread_num();
#endif
                int ri = each(ctx, i, &scratch[t], &e);
                if (ri < 0) {
#pragma omp critical(process_stack_fail)
                        if (i < fail) {
                                __atomic_store_n(&fail, i, __ATOMIC_RELAXED);
                                r = ri;
                                if (err)
                                        *err = e;
                        }
                }
                size_t d = __atomic_add_fetch(&done, 1, __ATOMIC_RELAXED);
#ifdef _OPENMP
                if (omp_get_thread_num() == 0 && d < n)
#endif
                        progress(o, stage, d, n);
        }
        for (int t = 0; t < n_threads; t++)
                stack_scratch_done(&scratch[t]);
        if (fail < n)
                return r;
        progress(o, stage, n, n);
        return 0;
}

/* Collapses a C-channel f32 image to one channel (mean), in place of a new image. */
static int to_mono(struct imp_image **img) {
        struct imp_image *src = *img;
        if (src->channels == 1)
                return 0;
        struct imp_image *m;
        int r = imp_image_new(src->width, src->height, 1, IMP_PIX_F32, &m);
        if (r < 0)
                return r;
        for (int y = 0; y < src->height; y++)
                for (int x = 0; x < src->width; x++) {
                        const float *p = imp_image_f32(src, x, y);
                        double sum = 0;
                        for (int c = 0; c < src->channels; c++)
                                sum += p[c];
                        *imp_image_f32(m, x, y) = (float) (sum / src->channels);
                }
        imp_image_free(src);
        *img = m;
        return 0;
}

static double median_of(const float *v, size_t n) {
        if (n == 0)
                return 0;
        _cleanup_free_ float *c = malloc(n * sizeof *c);
        if (!c)
                return 0;
        size_t m = 0;
        for (size_t i = 0; i < n; i++)
                if (isfinite(v[i]) && v[i] > 0)
                        c[m++] = v[i];
        if (!m)
                return 0;
        /* nth element by partial selection (quickselect) */
        size_t lo = 0, hi = m - 1, k = m / 2;
        while (lo < hi) {
                float piv = c[(lo + hi) / 2];
                size_t i = lo, j = hi;
                while (i <= j) {
                        while (c[i] < piv) i++;
                        while (c[j] > piv) j--;
                        if (i <= j) {
                                float t = c[i]; c[i] = c[j]; c[j] = t;
                                i++;
                                if (j == 0) break;
                                j--;
                        }
                }
                if (k <= j) hi = j;
                else if (k >= i) lo = i;
                else break;
        }
        return c[k];
}

/* The copy as it is built: every stage works on this in memory; write_outputs() writes each
 * file once at the end. */
struct geometry_out {
        struct imp_heightfield hf;
        struct imp_boxes boxes;
        json_t *stages;
        bool refused;                 /* no plausible canvas: copy.json says why, nothing else */
        struct imp_image *maps[4];    /* rho_d, rho_s, lobe, fit flags: NULL without a BTF fit */
        /* normal-trust's reading of the mask and normals at the height fusion, read again by
         * the final normal_trust(): neither changes in between (the fit and flag_edges
         * change σ_n and the flags only) */
        struct imp_normal_trust_cache nt_cache;
        /* the structured-light values' arena, emptied after the decode and kept faulted in:
         * the dome values reuse its pages (dome_load) instead of faulting in fresh ones */
        struct imp_image_arena *spare;
};

static void geometry_out_done(struct geometry_out *g) {
        json_decref(g->stages);
        imp_boxes_done(&g->boxes);
        imp_heightfield_done(&g->hf);
        for (int m = 0; m < 4; m++)
                imp_image_free(g->maps[m]);
        imp_normal_trust_cache_done(&g->nt_cache);
        imp_image_arena_free(g->spare);
}

/* Relief boxes of the final heightfield (seed §4.3), into g->boxes and stages.boxes. */
static int classify_boxes(const struct process_opts *o, struct geometry_out *g, struct imp_error *err) {
        double t0 = now_s();
        imp_boxes_done(&g->boxes);
        int r = imp_boxes_classify(&g->hf, &o->opt->boxes, &g->boxes);
        if (r < 0)
                return imp_error_set(err, r, "%s: relief classification failed: %s", o->capture, strerror(-r));
        json_object_set_new(g->stages, "boxes", json_pack("{s:i,s:I,s:f,s:f}", "cell_px", g->boxes.cell_px,
                            "boxes", (json_int_t) g->boxes.n_boxes, "delta0_mm", g->boxes.delta0_mm,
                            "seconds", now_s() - t0));
        progress(o, "boxes", 1, 1);
        return 0;
}

/* Heights from the triangulated positions and the photometric normals (fuse.h): the
 * heights take the normals' detail. */
static int fuse_heights(const struct process_opts *o, struct geometry_out *g, const float *normal,
                        const float *normal_sigma_deg, struct imp_error *err) {
        struct imp_heightfield *hf = &g->hf;
        double t0 = now_s();
        const struct imp_fuse_params *fp = &o->opt->fuse;
        struct imp_fuse_stats fs = {};
        progress(o, "height fusion", 0, 1);
        /* back-off where the normals contradict the heights beyond their σ; the σ of
         * filled texels from the normals they were integrated from; the rows weighted by
         * the σ_n normal-trust will give them (fuse.h row_weight_max: the relief bending
         * within a texel is where a normal is wrong; the stage's own σ does not see it) */
        size_t n_tex = (size_t) hf->nx * hf->ny;
        _cleanup_free_ float *row_sigma = malloc(n_tex * sizeof(float));
        _cleanup_free_ uint16_t *row_flags = malloc(n_tex * sizeof(uint16_t));
        if (!row_sigma || !row_flags)
                return imp_error_set(err, -ENOMEM, "%s: height fusion: out of memory", o->capture);
        memcpy(row_sigma, normal_sigma_deg, n_tex * sizeof(float));
        memcpy(row_flags, hf->texel_flags, n_tex * sizeof(uint16_t));
        struct imp_normal_trust_stats nts = {};
        bool trusted = fp->row_weight_max > 1 &&
                       imp_normal_trust_cached(hf->nx, hf->ny, hf->mask, hf->nx_, hf->ny_, row_sigma, row_flags,
                                               &o->opt->normal_trust, &g->nt_cache, &nts) >= 0;
        struct imp_fuse_texels ft = { normal_sigma_deg, hf->sigma_mm, hf->texel_flags, trusted ? row_sigma : NULL };
        _cleanup_free_ float *measured = malloc(n_tex * sizeof(float));
        if (!measured)
                return imp_error_set(err, -ENOMEM, "%s: height fusion: out of memory", o->capture);
        memcpy(measured, hf->height_mm, n_tex * sizeof(float));
        int r = imp_fuse_heights(hf->nx, hf->ny, hf->pitch_mm, hf->height_mm, normal, hf->sigma_mm, hf->mask,
                                 fp, &ft, &fs);
        if (r < 0)
                return imp_error_set(err, r, "%s: height fusion failed: %s", o->capture, strerror(-r));
        imp_heightfield_sigma_moved(hf, measured);   /* σ_h covers what the normals moved */
        json_object_set_new(g->stages, "fusion", json_pack("{s:f,s:I,s:I,s:i,s:f,s:f,s:f,s:f,s:f}",
                "lambda", fp->lambda, "texels", (json_int_t) fs.n_texels, "gradient_rows", (json_int_t) fs.n_rows,
                "iterations", fs.iterations, "residual_rel", fs.residual_rel, "change_rms_um", fs.change_rms_mm * 1000,
                "normal_agreement_deg_before", fs.agree_deg_before,
                "normal_agreement_deg_after", fs.agree_deg_after, "seconds", now_s() - t0));
        json_object_set_new(json_object_get(g->stages, "fusion"), "back_off", json_pack("{s:I,s:I,s:f}",
                "rows_rejected", (json_int_t) fs.n_rows_rejected, "texels", (json_int_t) fs.n_backed_off,
                "fill_sigma_max_um", fs.fill_sigma_max_mm * 1000));
        progress(o, "height fusion", 1, 1);
        return 0;
}

/* Shadow-filled texels (heightfield.h) without a usable photometric normal leave the
 * mask: drop[t] nonzero (NULL: all of them); stages.heightfield is updated. */
#define PROCESS_FILL_MIN_NZ 0.5   /* filled texels steeper than 60° are the frame's wall */
static void drop_fill(struct geometry_out *g, const uint8_t *drop) {
        struct imp_heightfield *hf = &g->hf;
        if (hf->n_filled_texels == 0)
                return;
        size_t before = hf->n_filled_texels;
        imp_heightfield_drop_filled(hf, drop);
        json_t *st = imp_heightfield_stage_json(hf);
        json_object_set(st, "seconds", json_object_get(json_object_get(g->stages, "heightfield"), "seconds"));
        json_object_set_new(st, "shadow_fill_dropped", json_integer((json_int_t) (before - hf->n_filled_texels)));
        json_object_set_new(g->stages, "heightfield", st);
}

/* The structured-light stacks of camera 0, merged to linear mono images (imgs, pats), with
 * the white frame's median level and the saturated / dark sample counts. */
struct sl_frames {
        struct imp_image_arena *arena;   /* imgs' and sats' samples, until the decode */
        struct imp_image **imgs;
        struct imp_image **sats;      /* the merge's saturation masks (clipped in every exposure) */
        struct imp_pattern *pats;
        size_t n;
        size_t n_sat, n_dark;
        double white_level;
};

static void sl_frames_done(struct sl_frames *f) {
        for (size_t i = 0; f->imgs && f->sats && i < f->n; i++) {
                imp_image_free(f->imgs[i]);
                imp_image_free(f->sats[i]);
        }
        free(f->imgs);
        free(f->sats);
        free(f->pats);
        imp_image_arena_free(f->arena);
        *f = (struct sl_frames) {};
}

struct sl_merge_ctx {
        const struct imp_captureset *cs;
        const struct stack *stacks;
        const struct imp_rig_camera *cam;
        struct sl_frames *f;
        size_t (*counts)[2];          /* per stack: saturated, dark samples */
};

/* Stack i merged, to mono, with its saturation mask (a for_each_stack step). */
static int sl_merge_one(void *ctx, size_t i, struct stack_scratch *sc, struct imp_error *err) {
        const struct sl_merge_ctx *c = ctx;
        struct sl_frames *f = c->f;
        struct imp_hdr_result h = {};
        int r = merge_stack(c->cs, &c->stacks[i], &c->cam->sensor, sc, f->arena, &h, err);
        if (r < 0)
                return r;
        c->counts[i][0] = h.n_saturated;
        c->counts[i][1] = h.n_dark;
        f->imgs[i] = TAKE_PTR(h.value);
        r = imp_hdr_saturated_mask(h.flags, &f->sats[i]);
        keep_spare(sc, &h);
        if (r < 0 || (r = to_mono(&f->imgs[i])) < 0 || (r = imp_image_arena_adopt(f->arena, f->imgs[i])) < 0 ||
            (r = imp_image_arena_adopt(f->arena, f->sats[i])) < 0)
                return imp_error_set(err, r, "out of memory");
        f->pats[i] = imp_captureset_record(c->cs, c->stacks[i].first)->pattern;
        return 0;
}

static int sl_merge(const struct process_opts *o, const struct imp_captureset *cs, const struct imp_rig_camera *cam,
                    struct sl_frames *f, struct imp_error *err) {
        _cleanup_free_ struct stack *stacks = NULL;
        size_t n_stacks;
        int r = collect_stacks(cs, "structured-light", cam->name, &stacks, &n_stacks);
        if (r < 0)
                return imp_error_set(err, r, "out of memory");
        if (o->opt->sl_gray_only) {   /* Gray-only decoding: the phase frames are not read */
                size_t k = 0;
                for (size_t i = 0; i < n_stacks; i++)
                        if (imp_captureset_record(cs, stacks[i].first)->pattern.kind != IMP_PAT_PHASE)
                                stacks[k++] = stacks[i];
                n_stacks = k;
        }
        if (n_stacks == 0)
                return imp_error_set(err, -EINVAL, "%s/manifest.jsonl: no structured-light frames "
                                     "for camera %s", o->capture, cam->name);
        f->imgs = calloc(n_stacks, sizeof *f->imgs);
        f->sats = calloc(n_stacks, sizeof *f->sats);
        f->pats = calloc(n_stacks, sizeof *f->pats);
        if (!f->imgs || !f->sats || !f->pats || imp_image_arena_new(&f->arena) < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        _cleanup_free_ size_t (*counts)[2] = calloc(n_stacks, sizeof *counts);
        if (!counts)
                return imp_error_set(err, -ENOMEM, "out of memory");
        f->n = n_stacks;
        struct sl_merge_ctx c = { cs, stacks, cam, f, counts };
        if ((r = for_each_stack(o, "hdr merge", n_stacks, sl_merge_one, &c, err)) < 0)
                return r;
        for (size_t i = 0; i < n_stacks; i++) {
                f->n_sat += counts[i][0];
                f->n_dark += counts[i][1];
                if (f->pats[i].kind == IMP_PAT_WHITE)
                        f->white_level = median_of(f->imgs[i]->data, (size_t) f->imgs[i]->width * f->imgs[i]->height);
        }
        return 0;
}

/* Structured-light decode (thresholds scaled by the white level) and triangulation. */
static int sl_range(const struct process_opts *o, const struct imp_rig *rig, struct sl_frames *f,
                    struct imp_sl_result **ret_sl, struct imp_range_image *range, double *ret_t_decoded,
                    struct imp_error *err) {
        struct imp_sl_params slp;
        imp_sl_params_default(&slp, IMP_PIX_F32);
        if (f->white_level > 0) {
                /* Thresholds are fractions of white (defaults assume white = 1). */
                slp.shadow_threshold *= f->white_level;
                slp.min_bit_contrast *= f->white_level;
                slp.min_direct *= f->white_level;
                slp.min_modulation *= f->white_level;
        }
        slp.proj_width = rig->projector.model.width;
        slp.proj_height = rig->projector.model.height;
        slp.black_level = rig->projector.black_level;
        slp.projector_gamma = rig->projector.gamma;     /* phase response inverted (docs/structured-light.md) */
        slp.direct_only = true;   /* L_d is the heightfield's albedo; global and modulation are not read */
        if (o->opt->threads > 0)
                slp.threads = o->opt->threads;
        struct imp_sl_frames fr = { f->pats, (const struct imp_image *const *) f->imgs, (int) f->n,
                                    (const struct imp_image *const *) f->sats };
        int r = imp_sl_decode(&fr, &slp, ret_sl, err);
        if (r < 0)
                return imp_error_prefix(err, "%s: structured light: ", o->capture);
        for (size_t i = 0; i < f->n; i++) {   /* decoded: not held through triangulation */
                imp_image_free(TAKE_PTR(f->imgs[i]));
                imp_image_free(TAKE_PTR(f->sats[i]));
        }
        imp_image_arena_reset(f->arena);   /* its pages go to the dome values (geometry_out.spare) */
        progress(o, "decode", 1, 1);
        *ret_t_decoded = now_s();
        struct imp_projector_coords pc;
        imp_projector_coords_from_sl(*ret_sl, &pc);
        struct imp_triangulate_options to;
        imp_triangulate_options_default(&to);
        r = imp_triangulate(&rig->cameras[0].model, &rig->projector.model, &pc, &to, range);
        if (r < 0)
                return imp_error_set(err, r, "%s: triangulation failed: %s", o->capture, strerror(-r));
        progress(o, "triangulate", 1, 1);
        return 0;
}

/* Why a refused heightfield found no canvas, when the decode says so: the middle of the
 * view (where the canvas is expected: half the width and height) with range at fewer than
 * REFUSAL_CENTRE_RANGE of its pixels, and what its other pixels lack. Empty otherwise.
 * (hard-ambient-dark: the dark paint under ambient light gives the projector no
 * modulation; hard-defocus: a blurred projector leaves the Gray code undecided.) */
#define REFUSAL_CENTRE_RANGE 0.6
static void refusal_cause(const struct imp_range_image *range, const struct imp_sl_result *sl, char *buf,
                          size_t size) {
        size_t n = 0, valid = 0, shadow = 0, undecided = 0, disagree = 0;
        buf[0] = 0;
        if (sl->width != range->width || sl->height != range->height)
                return;
        for (int y = range->height / 4; y < 3 * range->height / 4; y++)
                for (int x = range->width / 4; x < 3 * range->width / 4; x++) {
                        size_t i = (size_t) y * range->width + x;
                        uint16_t fl = sl->flags[i];
                        n++;
                        valid += range->valid[i] != 0;
                        shadow += (fl & IMP_SL_SHADOW) != 0;
                        undecided += !(fl & IMP_SL_SHADOW) && (fl & (IMP_SL_UNDECODABLE | IMP_SL_WEAK_BIT));
                        disagree += !(fl & IMP_SL_SHADOW) && (fl & IMP_SL_DISAGREE);
                }
        if (!n || valid >= REFUSAL_CENTRE_RANGE * n)
                return;
        snprintf(buf, size, "; range at only %.0f %% of the middle of the view: %.0f %% without projector light (dark "
                 "paint, ambient light or a dim projector: brighter projector or longer exposures), %.0f %% with "
                 "Gray bits undecided and %.0f %% with phase and Gray code disagreeing (projector focus)",
                 100.0 * valid / n, 100.0 * shadow / n, 100.0 * undecided / n, 100.0 * disagree / n);
}

/* Canvas extraction and the heightfield (seed §4.2); a refusal marks g->refused. */
static int heightfield_stage(const struct process_opts *o, const struct imp_range_image *range,
                             const struct imp_sl_result *sl, struct geometry_out *g, struct imp_error *err) {
        struct imp_heightfield_options ho = o->hf;
        ho.albedo = sl->direct;   /* a flush frame's albedo step */
        if (!(o->opt->btf && o->opt->photometric_normals && o->opt->fuse_heights))
                ho.shadow_fill_px = 0;   /* the fill needs normals to shape it */
        int r = imp_heightfield_extract(range, &ho, &g->hf, err);
        if (r == -ENODATA) {
                char why[400];
                refusal_cause(range, sl, why, sizeof why);
                g->refused = true;
                return imp_error_prefix(err, "%s: heightfield refused (%zu triangulated points%s): ", o->capture,
                                        range->n_valid, why);
        }
        if (r < 0)
                return imp_error_set(err, r, "%s: heightfield failed: %s", o->capture, strerror(-r));
        progress(o, "heightfield", 1, 1);
        return 0;
}

static int run_geometry(const struct process_opts *o, const struct imp_captureset *cs,
                        struct geometry_out *g, struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        if (rig->n_cameras < 1 || !rig->has_projector)
                return imp_error_set(err, -EINVAL, "%s/rig.json: a camera and a projector are needed "
                                     "for the geometry (found %d cameras, %s projector)", o->capture,
                                     rig->n_cameras, rig->has_projector ? "a" : "no");
        double t0 = now_s(), t_hdr = 0, t_sl = 0, t_tri = 0;
        struct sl_frames f = {};
        struct imp_sl_result *sl = NULL;
        struct imp_range_image range = {};
        int r = sl_merge(o, cs, &rig->cameras[0], &f, err);
        if (r >= 0) {
                t_hdr = now_s();
                r = sl_range(o, rig, &f, &sl, &range, &t_sl, err);
                t_tri = now_s();
        }
        if (r >= 0)
                r = heightfield_stage(o, &range, sl, g, err);
        if (r >= 0) {
                double t_hf = now_s();
                g->stages = json_pack("{s:{s:i,s:I,s:I,s:f,s:f}, s:{s:I,s:I,s:I,s:I,s:I,s:f}, s:{s:I,s:f}, s:o}",
                        "hdr", "stacks", (int) f.n, "saturated_samples", (json_int_t) f.n_sat,
                               "dark_samples", (json_int_t) f.n_dark, "white_level", f.white_level,
                               "seconds", t_hdr - t0,
                        "structured_light", "valid_x", (json_int_t) sl->n_valid_x, "valid_y", (json_int_t) sl->n_valid_y,
                               "valid_xy", (json_int_t) sl->n_valid_xy, "shadow", (json_int_t) sl->n_shadow,
                               "disagree", (json_int_t) sl->n_disagree, "seconds", t_sl - t_hdr,
                        "triangulation", "points", (json_int_t) range.n_valid, "seconds", t_tri - t_sl,
                        "heightfield", imp_heightfield_stage_json(&g->hf));
                json_object_set_new(json_object_get(g->stages, "heightfield"), "seconds", json_real(t_hf - t_tri));
                json_object_set_new(json_object_get(g->stages, "structured_light"), "phase",
                                    json_pack("{s:[f,f],s:[b,b]}", "err_px", sl->phase_err_px[0], sl->phase_err_px[1],
                                              "rejected", sl->phase_rejected[0], sl->phase_rejected[1]));
        }
        if (r >= 0)
                g->spare = TAKE_PTR(f.arena);
        sl_frames_done(&f);
        imp_sl_result_free(sl);
        imp_range_image_done(&range);
        return r;
}

/* Held-out validation: every held-out light's HDR frame against the fitted copy shaded per
 * texel, V = E·cos θl·f(v, l). The sample extractor does the geometry (view and light
 * directions, irradiance, hidden / self-shadowed / saturated / invalid rejection) one light
 * at a time, so every sample is one (texel, light) pair; residuals are of V/E. */
static int validate_holdout(const struct imp_btf_heightfield *bh, const struct imp_pinhole *camera,
                            const struct imp_rig_light *lights, struct imp_image *const *frames,
                            struct imp_image *const *valid, int n, const struct imp_btf_texel *tex,
                            json_t **ret) {
        enum { TILE = 64 };
        _cleanup_btf_samples_ struct imp_btf_samples *smp = NULL;
        _cleanup_(imp_btf_hf_pyramid_freep) struct imp_btf_hf_pyramid *py = NULL;
        int r = imp_btf_samples_new(TILE * TILE, 1, &smp);
        if (r < 0)
                return r;
        r = imp_btf_hf_pyramid_new(bh, &py);   /* once, not per tile and light */
        if (r < 0)
                return r;
        struct imp_btf_sample_params sp;
        imp_btf_sample_params_default(&sp);
        json_t *per = json_array();
        double ss_all = 0;
        size_t n_all = 0;
        for (int li = 0; li < n; li++) {
                const struct imp_image *fr = frames[li], *va = valid[li];
                struct imp_btf_capture cap = { camera, &lights[li], 1, &fr, &va };
                double ss = 0;
                size_t cnt = 0;
                for (int y0 = 0; y0 < bh->height; y0 += TILE)
                        for (int x0 = 0; x0 < bh->width; x0 += TILE) {
                                int w = IMP_MIN(TILE, bh->width - x0), h = IMP_MIN(TILE, bh->height - y0);
                                r = imp_btf_samples_extract_pyramid(bh, &cap, &sp, py, x0, y0, w, h, smp);
                                if (r < 0)
                                        goto fail;
                                for (int k = 0; k < w * h; k++) {
                                        if (smp->count[k] == 0)
                                                continue;
                                        const struct imp_btf_sample *q = &smp->samples[k];
                                        const struct imp_btf_texel *t = &tex[(size_t) (y0 + k / w) * bh->width + x0 + k % w];
                                        if (t->flags & IMP_BTF_MASKED)
                                                continue;
                                        struct imp_lafortune b = { .cx = t->cx, .cy = t->cy, .cz = t->cz, .k = t->k };
                                        memcpy(b.rho_d, t->rho_d, sizeof b.rho_d);
                                        memcpy(b.rho_s, t->rho_s, sizeof b.rho_s);
                                        double v[3] = { q->v[0], q->v[1], q->v[2] }, l[3] = { q->l[0], q->l[1], q->l[2] };
                                        double E = q->e_cos / q->l[2];
                                        for (int c = 0; c < 3; c++) {
                                                double d = (q->value[c] - q->e_cos * imp_lafortune_eval(&b, c, v, l)) / E;
                                                if (isfinite(d)) {
                                                        ss += d * d;
                                                        cnt++;
                                                }
                                        }
                                }
                        }
                ss_all += ss;
                n_all += cnt;
                json_array_append_new(per, cnt ? json_real(sqrt(ss / cnt)) : json_null());   /* null: no texel */
        }
        *ret = json_pack("{s:i,s:I,s:o,s:o}", "lights", n, "texels", (json_int_t) (n_all / 3),
                         "rmse", n_all ? json_real(sqrt(ss_all / n_all)) : json_null(), "rmse_per_light", per);
        return *ret ? 0 : -ENOMEM;
fail:
        json_decref(per);
        return r;
}

/* The dome sweep of camera 0, merged: the frames the fit uses and those held out for
 * validation (every holdout_every-th), with their lights and validity masks. */
struct dome {
        struct imp_image_arena *arena;   /* the samples of frames, valid, ho_frames, ho_valid */
        struct imp_image **frames, **valid, **ho_frames, **ho_valid;
        struct imp_rig_light *lights, *ho_lights;
        size_t n_stacks, n_used, n_held;
        double seconds;
};

static void dome_done(struct dome *d) {
        for (size_t i = 0; i < d->n_stacks; i++) {
                if (d->frames) imp_image_free(d->frames[i]);
                if (d->valid) imp_image_free(d->valid[i]);
                if (d->ho_frames) imp_image_free(d->ho_frames[i]);
                if (d->ho_valid) imp_image_free(d->ho_valid[i]);
        }
        free(d->frames), free(d->valid), free(d->ho_frames), free(d->ho_valid);
        free(d->lights), free(d->ho_lights);
        imp_image_arena_free(d->arena);
        *d = (struct dome) {};
}

static const struct imp_rig_light *rig_light(const struct imp_rig *rig, int id) {
        for (int k = 0; k < rig->n_lights; k++)
                if (rig->lights[k].id == id)
                        return &rig->lights[k];
        return NULL;
}

struct dome_merge_ctx {
        const struct process_opts *o;
        const struct imp_captureset *cs;
        const struct stack *stacks;
        size_t holdout_every;         /* 0: none held out */
        struct dome *d;
};

/* Dome stack i merged with its validity mask, into its place among the used or the held-out
 * lights (a for_each_stack step). */
static int dome_merge_one(void *ctx, size_t i, struct stack_scratch *sc, struct imp_error *err) {
        const struct dome_merge_ctx *c = ctx;
        const struct imp_rig *rig = imp_captureset_rig(c->cs);
        struct dome *d = c->d;
        int id = imp_captureset_record(c->cs, c->stacks[i].first)->light;
        const struct imp_rig_light *L = rig_light(rig, id);
        if (!L)
                return imp_error_set(err, -EINVAL, "%s/manifest.jsonl: frame %zu: light %d is not in rig.json",
                                     c->o->capture, c->stacks[i].first, id);
        struct imp_hdr_result h = {};
        int r = merge_stack(c->cs, &c->stacks[i], &rig->cameras[0].sensor, sc, d->arena, &h, err);
        if (r < 0)
                return r;
        /* Validity per pixel from the merge flags (any channel). */
        struct imp_image *vimg;
        r = imp_btf_valid_from_hdr(h.flags, &vimg);
        if (r >= 0 && (r = imp_image_arena_adopt(d->arena, vimg)) < 0)
                imp_image_free(vimg);
        if (r < 0) {
                imp_hdr_result_done(&h);
                return imp_error_set(err, r, "out of memory");
        }
        size_t N = c->holdout_every;
        if (N > 0 && (i + 1) % N == 0) {
                size_t k = (i + 1) / N - 1;
                d->ho_frames[k] = TAKE_PTR(h.value);
                d->ho_valid[k] = vimg;
                d->ho_lights[k] = *L;
        } else {
                size_t k = i - (N > 0 ? i / N : 0);
                d->frames[k] = TAKE_PTR(h.value);
                d->valid[k] = vimg;
                d->lights[k] = *L;
        }
        keep_spare(sc, &h);
        return 0;
}

static int dome_load(const struct process_opts *o, const struct imp_captureset *cs, const struct stack *stacks,
                     size_t n_stacks, struct dome *d, struct imp_error *err) {
        double t0 = now_s();
        d->n_stacks = n_stacks;
        d->frames = calloc(n_stacks, sizeof *d->frames), d->valid = calloc(n_stacks, sizeof *d->valid);
        d->ho_frames = calloc(n_stacks, sizeof *d->ho_frames), d->ho_valid = calloc(n_stacks, sizeof *d->ho_valid);
        d->lights = calloc(n_stacks, sizeof *d->lights), d->ho_lights = calloc(n_stacks, sizeof *d->ho_lights);
        if (!d->frames || !d->valid || !d->ho_frames || !d->ho_valid || !d->lights || !d->ho_lights ||
            (!d->arena && imp_image_arena_new(&d->arena) < 0))
                return imp_error_set(err, -ENOMEM, "out of memory");
        /* every holdout_every-th stack is held out: stack i's place in either list */
        size_t N = o->opt->holdout_every > 0 ? (size_t) o->opt->holdout_every : 0;
        d->n_held = N ? n_stacks / N : 0;
        d->n_used = n_stacks - d->n_held;
        struct dome_merge_ctx c = { o, cs, stacks, N, d };
        int r = for_each_stack(o, "dome hdr merge", n_stacks, dome_merge_one, &c, err);
        if (r < 0)
                return r;
        imp_image_arena_trim(d->arena);   /* the structured-light pages the dome values did not reuse */
        d->seconds = now_s() - t0;
        if (d->n_used == 0)
                return imp_error_set(err, -EINVAL, "%s: --holdout %d leaves no dome light for the fit",
                                     o->capture, o->opt->holdout_every);
        return 0;
}

/* Photometric normals (pipeline/appearance/photometric.h) replace the heightfield's; the
 * shadow fill keeps only texels whose normal the dome determines and that are not steeper
 * than 60°; the heights are fused with the normals. heightfield.exr and the height fusion
 * take the Lanczos re-reading's normals; the fit estimates its own local frames from the
 * values it reads (btf_stage), starting from the geometric normals (`normal`, unchanged:
 * the frame this stage's model ran in, whose rays it recorded). *ret_frames: whether it
 * should (false when the stage went back to the geometric normals canvas-wide). */
static int photometric_stage(const struct process_opts *o, struct geometry_out *g,
                             const struct imp_btf_heightfield *bh, const struct imp_btf_capture *cap,
                             const struct imp_btf_sample_params *sp, float *normal, bool *ret_frames,
                             struct imp_error *err) {
        struct imp_heightfield *hf = &g->hf;
        size_t nt = (size_t) hf->nx * hf->ny;
        double t0 = now_s();
        const struct imp_photometric_params *pp = &o->opt->photometric;
        struct imp_photometric_stats ps = {};
        _cleanup_free_ float *pn_normal = malloc(nt * 3 * sizeof *pn_normal);
        _cleanup_free_ uint16_t *pn_flags = malloc(nt * sizeof *pn_flags);
        _cleanup_free_ uint16_t *pn_tflags = malloc(nt * sizeof *pn_tflags);
        _cleanup_free_ float *pn_sigma = malloc(nt * sizeof *pn_sigma);
        _cleanup_free_ uint8_t *drop = malloc(nt);
        if (!pn_normal || !pn_flags || !pn_tflags || !pn_sigma || !drop)
                return imp_error_set(err, -ENOMEM, "out of memory");
        progress(o, "photometric normals", 0, 1);
        struct imp_photometric_out pout = { pn_normal, pn_flags, pn_tflags, pn_sigma };
        int r = imp_photometric_normals(bh, cap, sp, pp, &pout, &ps);
        if (r < 0)
                return imp_error_set(err, r, "%s: photometric normals failed: %s", o->capture, strerror(-r));
        long disagree = imp_photometric_agreement(hf->nx, hf->ny, hf->mask, pn_flags, pn_normal, normal,
                                                  hf->sigma_n_deg, pp, pn_sigma);
        if (disagree < 0)
                return imp_error_set(err, (int) disagree, "%s: photometric agreement: %s", o->capture,
                                     strerror((int) -disagree));
        *ret_frames = !ps.ambient_canvas;
        for (size_t i = 0; i < nt; i++)
                if (!hf->mask || hf->mask[i]) {
                        /* The stage's flags join the heightfield's; a refined normal carries
                         * the stage's σ (fit, model check, interpolation floor:
                         * photometric.h), a kept one keeps the geometry's. */
                        hf->texel_flags[i] |= pn_tflags[i];
                        if (!(pn_flags[i] & IMP_PN_KEPT))
                                hf->sigma_n_deg[i] = pn_sigma[i];
                        hf->nx_[i] = pn_normal[3 * i];
                        hf->ny_[i] = pn_normal[3 * i + 1];
                }
        long why[6] = { 0 };   /* filled texels dropped: few, ill, dark, disagree, masked, steep */
        for (size_t i = 0; i < nt; i++) {
                bool steep = !(pn_normal[3 * i + 2] >= PROCESS_FILL_MIN_NZ);
                drop[i] = (pn_flags[i] & IMP_PN_KEPT) || steep;
                if (hf->mask[i] == IMP_HF_MASK_FILLED && drop[i])
                        for (int k = 0; k < 6; k++)
                                why[k] += k < 5 ? (pn_flags[i] >> k) & 1 : steep;
        }
        drop_fill(g, drop);
        if (hf->n_filled_texels || why[0] + why[1] + why[2] + why[3] + why[4] + why[5])
                json_object_set_new(json_object_get(g->stages, "heightfield"), "shadow_fill_dropped_why",
                        json_pack("{s:I,s:I,s:I,s:I,s:I,s:I}", "few_samples", (json_int_t) why[0],
                                  "ill_conditioned", (json_int_t) why[1], "dark", (json_int_t) why[2],
                                  "disagree", (json_int_t) why[3], "masked", (json_int_t) why[4],
                                  "steep", (json_int_t) why[5]));
        if (o->opt->fuse_heights && (r = fuse_heights(o, g, pn_normal, hf->sigma_n_deg, err)) < 0)
                return r;
        json_object_set_new(g->stages, "photometric", json_pack(
                "{s:i,s:I,s:I,s:I,s:I,s:I,s:I,s:I,s:I,s:I,s:I,s:i,s:f,s:f,s:f,s:f,s:f,s:f}",
                "lights", cap->n_lights, "refined", (json_int_t) ps.n_refined,
                "resampled_samples", (json_int_t) ps.n_resampled, "lanczos", pp->lanczos,
                "kept_few_samples", (json_int_t) ps.n_few, "kept_ill_conditioned", (json_int_t) ps.n_ill,
                "kept_dark", (json_int_t) ps.n_dark, "kept_disagree", (json_int_t) ps.n_disagree,
                "kept_ambient", (json_int_t) ps.n_ambient, "kept_residual", (json_int_t) ps.n_residual,
                "kept_saturated", (json_int_t) ps.n_saturated, "sigma_grown_disagree", (json_int_t) disagree,
                "max_dev_deg", pp->max_dev_deg,
                "dev_deg_mean", ps.dev_deg_mean, "dev_deg_median", ps.dev_deg_median,
                "sigma_deg_median", ps.sigma_deg_median, "rms_median", ps.rms_median,
                "seconds", now_s() - t0));
        progress(o, "photometric normals", 1, 1);
        return 0;
}

/* rho_d, rho_s (RGB), lobe (cx, cy, cz, k) and fit flags (integers below 2048, exact in
 * half) as images, seed 000 §6. */
static int brdf_maps(const struct imp_heightfield *hf, const struct imp_btf_texel *tex, struct imp_image *maps[4]) {
        for (int m = 0; m < 4; m++) {
                int r = imp_image_new(hf->nx, hf->ny, m == 2 ? 4 : m == 3 ? 1 : 3, IMP_PIX_F32, &maps[m]);
                if (r < 0)
                        return r;
        }
        for (int y = 0; y < hf->ny; y++)
                for (int x = 0; x < hf->nx; x++) {
                        const struct imp_btf_texel *t = &tex[(size_t) y * hf->nx + x];
                        float *d = imp_image_f32(maps[0], x, y), *s = imp_image_f32(maps[1], x, y);
                        float *l = imp_image_f32(maps[2], x, y);
                        for (int c = 0; c < 3; c++) {
                                d[c] = t->rho_d[c];
                                s[c] = t->rho_s[c];
                        }
                        l[0] = t->cx; l[1] = t->cy; l[2] = t->cz; l[3] = t->k;
                        *imp_image_f32(maps[3], x, y) = t->flags;
                }
        return 0;
}

/* The fit's texels done, as the stage's progress. */
static void btf_progress(void *data, long done, long total) {
        progress(data, "btf fit", (size_t) done, (size_t) total);
}

/* The shadow-aware Lafortune fit (seed 000 §4.4), the held-out validation, the maps. With
 * frames, the fit takes each texel's local frame from the photometric model on the values
 * it reads (photometric.h imp_photometric_frames()) and the validation reads the held-out
 * lights in the same frames; without, both take bh->normal's. */
static int btf_stage(const struct process_opts *o, struct geometry_out *g, const struct imp_btf_heightfield *bh,
                     const struct imp_btf_capture *cap, const struct imp_btf_sample_params *sp, const struct dome *d,
                     bool frames, struct imp_error *err) {
        size_t nt = (size_t) g->hf.nx * g->hf.ny;
        _cleanup_free_ struct imp_btf_texel *tex = calloc(nt, sizeof *tex);
        _cleanup_free_ float *frame_n = frames ? malloc(nt * 3 * sizeof *frame_n) : NULL;
        if (!tex || (frames && !frame_n))
                return imp_error_set(err, -ENOMEM, "out of memory");
        double t0 = now_s();
        struct imp_btf_stats st = {};
        struct imp_btf_fit_params fp = o->opt->btf_fit;
        fp.progress = btf_progress;
        fp.progress_data = (void *) o;
        struct imp_photometric_frames pf;
        struct imp_btf_frames bf;
        struct imp_btf_heightfield bh_fit = *bh;   /* the frames the fit and the validation read in */
        int r;
        if (frames) {
                /* the samples turned, not extracted again: the same figures for less
                 * (docs/processing-speed.md "The fit's frames estimated by the fit") */
                if ((r = imp_photometric_frames(bh, &o->opt->photometric, IMP_BTF_FRAMES_ROTATE, frame_n, &pf,
                                                &bf)) < 0)
                        return imp_error_set(err, r, "%s: BTF frames: %s", o->capture, strerror(-r));
                fp.frames = &bf;
                bh_fit.normal = frame_n;
        }
        progress(o, "btf fit", 0, 1);
        r = imp_btf_fit_grid(bh, cap, sp, &fp, 64, tex, &st);
        if (r < 0)
                return imp_error_set(err, r, "%s: BTF fit failed: %s", o->capture, strerror(-r));
        for (size_t i = 0; i < nt; i++)   /* a non-physical fit is the copy's fit_failed */
                if (g->hf.mask[i])
                        g->hf.texel_flags[i] |= imp_btf_texel_flags(tex[i].flags) & IMP_TEXEL_FIT_FAILED;
        double t_fit = now_s();
        json_t *validation = NULL;
        if (d->n_held > 0) {
                progress(o, "validation", 0, 1);
                r = validate_holdout(&bh_fit, cap->camera, d->ho_lights, d->ho_frames, d->ho_valid, (int) d->n_held,
                                     tex, &validation);
                if (r < 0)
                        return imp_error_set(err, r, "%s: held-out validation failed: %s", o->capture, strerror(-r));
                json_object_set_new(validation, "seconds", json_real(now_s() - t_fit));
                progress(o, "validation", 1, 1);
        }
        json_t *btf = json_pack("{s:i,s:I,s:I,s:I,s:I,s:I,s:I,s:I,s:I,s:f,s:f}",
                "lights", cap->n_lights, "fitted", (json_int_t) st.n_fitted, "matte", (json_int_t) st.n_matte,
                "few_samples", (json_int_t) st.n_few, "hidden", (json_int_t) st.n_hidden,
                "filled", (json_int_t) st.n_filled, "cx_eq_cy", (json_int_t) st.n_cx_eq_cy,
                "samples", (json_int_t) st.n_samples, "shadowed", (json_int_t) st.n_shadowed,
                "seconds_hdr", d->seconds, "seconds_fit", t_fit - t0);
        if (validation)
                json_object_set_new(btf, "validation", validation);
        json_object_set_new(g->stages, "btf", btf);
        if ((r = brdf_maps(&g->hf, tex, g->maps)) < 0)
                return imp_error_set(err, r, "out of memory");
        return 0;
}

/* The dome sweep → photometric normals, fused heights and the per-texel Lafortune BRDF. */
static int run_appearance(const struct process_opts *o, const struct imp_captureset *cs, struct geometry_out *g,
                          struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        _cleanup_free_ struct stack *stacks = NULL;
        size_t n_stacks;
        int r = collect_stacks(cs, "dome", rig->cameras[0].name, &stacks, &n_stacks);
        if (r < 0)
                return imp_error_set(err, r, "out of memory");
        if (n_stacks == 0) {   /* no dome sweep: a geometry-only copy, no normals for a fill */
                drop_fill(g, NULL);
                return 0;
        }
        struct imp_heightfield *hf = &g->hf;
        size_t nt = (size_t) hf->nx * hf->ny;
        struct dome d = {};
        _cleanup_(imp_btf_rays_freep) struct imp_btf_rays *rays = NULL;
        _cleanup_free_ float *normal = malloc(nt * 3 * sizeof *normal);
        if (!normal)
                return imp_error_set(err, -ENOMEM, "out of memory");
        d.arena = TAKE_PTR(g->spare);
        if ((r = dome_load(o, cs, stacks, IMP_MIN(n_stacks, (size_t) IMP_BTF_MAX_SAMPLES), &d, err)) < 0)
                goto out;
        for (size_t i = 0; i < nt; i++) {
                double nx = hf->nx_[i], ny = hf->ny_[i], s = 1 - nx * nx - ny * ny;
                normal[3 * i] = (float) nx;
                normal[3 * i + 1] = (float) ny;
                normal[3 * i + 2] = (float) sqrt(s > 0 ? s : 0);
        }
        struct imp_btf_heightfield bh = { hf->nx, hf->ny, hf->pitch_mm, hf->height_mm, normal, hf->mask, {},
                                          hf->sigma_mm };
        memcpy(bh.canvas_to_world, hf->canvas_to_world, sizeof bh.canvas_to_world);
        struct imp_btf_capture cap = { &rig->cameras[0].model, d.lights, (int) d.n_used,
                                       (const struct imp_image *const *) d.frames,
                                       (const struct imp_image *const *) d.valid };
        /* The photometric stage records its shadow and camera-visibility decisions, the fit
         * takes them instead of marching the rays again (btf.h struct imp_btf_rays): the
         * fused heights differ from the ones they were marched on by µm (docs/btf-fit.md). */
        struct imp_btf_sample_params sp = o->opt->btf_samples;
        bool photometric = o->opt->photometric_normals && d.n_used >= 8;
        if (photometric && imp_btf_rays_new(hf->nx, hf->ny, (int) d.n_used, &rays) >= 0) {
                sp.rays = rays;
                sp.rays_mode = IMP_BTF_RAYS_RECORD;
        }
        bool frames = false;
        if (photometric)
                r = photometric_stage(o, g, &bh, &cap, &sp, normal, &frames, err);
        else {
                drop_fill(g, NULL);
                /* too few lights for a photometric normal anywhere: the texels keep the
                 * geometric one for want of samples, as the photometric stage flags a texel
                 * with too few (hard-one-light's verdict blamed the relief) */
                for (size_t i = 0; o->opt->photometric_normals && i < (size_t) hf->nx * hf->ny; i++)
                        if (hf->mask[i])
                                hf->texel_flags[i] |= IMP_TEXEL_FEW_SAMPLES;
        }
        sp.rays_mode = IMP_BTF_RAYS_REUSE;
        if (r >= 0)
                r = btf_stage(o, g, &bh, &cap, &sp, &d, frames, err);
out:
        dome_done(&d);
        return r;
}

/* The verdict on the copy (copy.json "quality", docs/copy-quality.md). */
#define QUALITY_FLAGGED_DEGRADED 0.25 /* flagged fraction of the canvas texels */
#define QUALITY_FILLED_DEGRADED  0.10 /* shadow-filled fraction */
#define QUALITY_TILT_DEGRADED    20.0 /* degrees from the rig's canvas normal */
#define QUALITY_VIEW_DEGRADED    45.0 /* degrees between canvas normal and camera ray */
#define QUALITY_MIN_TEXELS       5000 /* fewer canvas texels: tiny coverage */
#define QUALITY_HOLES_DEGRADED   0.25 /* of the texels within the canvas's outline, none */

static void reason(json_t *reasons, enum imp_verdict *v, enum imp_verdict at_least, const char *fmt, ...)
        _printf_(4, 5);
static void reason(json_t *reasons, enum imp_verdict *v, enum imp_verdict at_least, const char *fmt, ...) {
        char buf[512];
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(buf, sizeof buf, fmt, ap);
        va_end(ap);
        json_array_append_new(reasons, json_string(buf));
        if (*v < at_least)
                *v = at_least;
}

/* The flags that follow from others: a texel whose photometric normal was not kept (few
 * samples, saturation, shadow, ...) keeps the geometric one and is normal_uncertain or
 * photometric_rejected because of that. */
#define QUALITY_CONSEQUENCE_FLAGS (IMP_TEXEL_PHOTOMETRIC_REJECTED | IMP_TEXEL_NORMAL_UNCERTAIN | IMP_TEXEL_FIT_FAILED)
#define QUALITY_CAUSE_SHARE 0.5  /* a cause flag on at least this share of the top flag's count is named */

/* "X % flagged, T % TOP (advice)": the flag behind most of it and what would lift it. When
 * that flag is a consequence and a cause flag covers most as many texels (hard-deep-frame:
 * every texel normal_uncertain and photometric_rejected because the frame walls hide the
 * dome's lights: few_samples), the cause is named with its advice instead of the
 * consequence's (which told to change the lens or the paint). */
static void flagged_reason(json_t *reasons, enum imp_verdict *v, const size_t per[IMP_TEXEL_FLAG_COUNT],
                           double den, double flagged) {
        unsigned top = 0, cause = IMP_TEXEL_FLAG_COUNT;
        for (unsigned k = 1; k < IMP_TEXEL_FLAG_COUNT; k++)
                if (per[k] > per[top])
                        top = k;
        for (unsigned k = 0; k < IMP_TEXEL_FLAG_COUNT; k++)
                if (!((QUALITY_CONSEQUENCE_FLAGS | IMP_TEXEL_FRAME_ADJACENT) & (1u << k)) &&
                    (cause == IMP_TEXEL_FLAG_COUNT || per[k] > per[cause]))
                        cause = k;
        if ((QUALITY_CONSEQUENCE_FLAGS & (1u << top)) && cause < IMP_TEXEL_FLAG_COUNT && per[cause] > 0 &&
            per[cause] >= QUALITY_CAUSE_SHARE * per[top])
                reason(reasons, v, IMP_VERDICT_DEGRADED, "%.0f %% of the canvas texels are flagged, %.0f %% %s "
                       "after %.0f %% %s (%s)", 100 * flagged, 100.0 * per[top] / den, imp_texel_flag_name(top),
                       100.0 * per[cause] / den, imp_texel_flag_name(cause), imp_texel_flag_advice(cause));
        else
                reason(reasons, v, IMP_VERDICT_DEGRADED, "%.0f %% of the canvas texels are flagged, %.0f %% %s (%s)",
                       100 * flagged, 100.0 * per[top] / den, imp_texel_flag_name(top), imp_texel_flag_advice(top));
}

/* The appearance fitted on too few texels (stages.btf, NULL without the stage): its flags
 * live in fit-flags.exr, not among the texel flags, so the verdict says it (hard-grazing-
 * dome: the frame hid every light from every texel, ρd 0 on the whole canvas, and the copy
 * was degraded only for its normals). */
#define QUALITY_APPEARANCE_UNFIT 0.25  /* fraction of the canvas texels the fit lacked samples for */
static void appearance_reason(json_t *reasons, enum imp_verdict *v, const json_t *btf, double den) {
        double few = json_number_value(json_object_get(btf, "few_samples"));
        double filled = json_number_value(json_object_get(btf, "filled"));
        if (!btf || !(few > QUALITY_APPEARANCE_UNFIT * den))
                return;
        reason(reasons, v, IMP_VERDICT_DEGRADED, "the appearance (rho_d, rho_s, lobe) was fitted on only %.0f %% "
               "of the canvas texels: %.0f %% filled from neighbours, %.0f %% left unmeasured (rho_d 0); "
               "few_samples in fit-flags.exr (%s)", 100 * fmax(0, 1 - few / den), 100 * filled / den,
               100 * fmax(0, few - filled) / den, imp_texel_flag_advice((unsigned) __builtin_ctz(IMP_TEXEL_FEW_SAMPLES)));
}

static json_t *quality_json(const struct geometry_out *g, const char *refusal, const json_t *btf) {
        enum imp_verdict v = IMP_VERDICT_OK;
        json_t *reasons = json_array(), *flags = json_object();
        const struct imp_heightfield *hf = &g->hf;
        size_t n = (size_t) hf->nx * hf->ny, n_mask = 0, n_flagged = 0, per[IMP_TEXEL_FLAG_COUNT] = { 0 };
        for (size_t t = 0; t < n && hf->texel_flags; t++) {
                if (!hf->mask[t])
                        continue;
                n_mask++;
                n_flagged += hf->texel_flags[t] != 0;
                for (unsigned k = 0; k < IMP_TEXEL_FLAG_COUNT; k++)
                        per[k] += (hf->texel_flags[t] >> k) & 1;
        }
        double den = n_mask ? (double) n_mask : 1, flagged = n_flagged / den;
        for (unsigned k = 0; k < IMP_TEXEL_FLAG_COUNT; k++)
                json_object_set_new(flags, imp_texel_flag_name(k), json_real(per[k] / den));
        if (refusal)
                reason(reasons, &v, IMP_VERDICT_UNUSABLE, "%s", refusal);
        else {
                if (flagged > QUALITY_FLAGGED_DEGRADED)
                        flagged_reason(reasons, &v, per, den, flagged);
                if (hf->n_filled_texels > QUALITY_FILLED_DEGRADED * den)
                        reason(reasons, &v, IMP_VERDICT_DEGRADED, "%.0f %% of the canvas was filled from normals",
                               100.0 * hf->n_filled_texels / den);
                if (hf->flags & (IMP_HF_PLANE_WEAK | IMP_HF_PLANE_NO_CONSENSUS))
                        reason(reasons, &v, IMP_VERDICT_DEGRADED, "the canvas plane is weakly determined");
                if (hf->plane_tilt_deg > QUALITY_TILT_DEGRADED)
                        reason(reasons, &v, IMP_VERDICT_DEGRADED, "canvas %.0f° off the rig's canvas pose",
                               hf->plane_tilt_deg);
                if (hf->plane_view_deg > QUALITY_VIEW_DEGRADED)
                        reason(reasons, &v, IMP_VERDICT_DEGRADED, "canvas seen %.0f° off its normal",
                               hf->plane_view_deg);
                appearance_reason(reasons, &v, btf, den);
                if (n_mask < QUALITY_MIN_TEXELS)
                        reason(reasons, &v, IMP_VERDICT_DEGRADED, "only %zu canvas texels", n_mask);
                if ((double) n_mask < (1 - QUALITY_HOLES_DEGRADED) * (double) hf->n_outline_texels)
                        reason(reasons, &v, IMP_VERDICT_DEGRADED, "%.0f %% of the canvas within its outline has "
                               "no texel (the relief shadows it from the projector or hides it from the camera, "
                               "or is too steep to decode: high impasto)",
                               100.0 * (1 - (double) n_mask / (double) hf->n_outline_texels));
        }
        return json_pack("{s:s,s:o,s:f,s:o,s:I}", "verdict", imp_verdict_name(v), "reasons", reasons,
                         "flagged_fraction", flagged, "flags", flags, "texels", (json_int_t) n_mask);
}

static int write_copy_json(const struct process_opts *o, const struct geometry_out *g,
                           json_t *stages, double seconds, const char *refusal, struct imp_error *err) {
        const struct imp_heightfield *hf = &g->hf;
        json_t *m = json_array();
        for (int i = 0; i < 16 && !refusal; i++)
                json_array_append_new(m, json_real(hf->canvas_to_world[i]));
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        _cleanup_json_ json_t *j = json_pack("{s:s,s:i,s:s,s:f,s:i,s:i,s:o,s:{s:s,s:s,s:f,s:I},s:O?,s:o}",
                "format", "impasto-digital-copy", "version", 1, "units", "mm",
                "pitch_mm", hf->pitch_mm, "nx", hf->nx, "ny", hf->ny, "canvas_to_world", m,
                "provenance", "software", "impasto " IMPASTO_VERSION_STRING, "capture", o->capture,
                              "seconds", seconds, "peak_rss_kib", (json_int_t) ru.ru_maxrss,
                "stages", stages, "quality", quality_json(g, refusal, json_object_get(stages, "btf")));
        if (!j)
                return imp_error_set(err, -ENOMEM, "copy.json: out of memory");
        if (o->incomplete)
                json_object_set(json_object_get(j, "provenance"), "incomplete", o->incomplete);
        if (o->painting_tile)
                json_object_set(json_object_get(j, "provenance"), "painting_tile", o->painting_tile);
        char path[4096];
        snprintf(path, sizeof path, "%s/copy.json", o->out);
        return imp_json_save_atomic(path, j, err);
}

/* A painting's tile (process-painting.h): no frame search unless asked for, the painting's
 * pitch unless one was given; o->hf is what the heightfield stage uses. */
static int painting_tile(struct process_opts *o, const struct imp_captureset *cs, struct imp_error *err) {
        o->hf = o->opt->heightfield;
        struct imp_painting_tile pt;
        int r = imp_painting_tile_detect(cs, &pt, err);
        if (r < 0)
                return r;
        enum { GIVEN, PAINTING, OWN } pitch_from = o->hf.pitch_mm > 0 ? GIVEN : OWN;
        if (pt.is_tile && pitch_from == OWN && pt.pitch_mm > 0)
                o->hf.pitch_mm = pt.pitch_mm, pitch_from = PAINTING;
        int fs = o->opt->frame_search;
        o->hf.whole_field = fs == IMP_FRAME_SEARCH_OFF || (fs == IMP_FRAME_SEARCH_AUTO && pt.is_tile);
        if (!pt.is_tile && !o->hf.whole_field)
                return 0;
        o->painting_tile = json_pack("{s:b,s:s?,s:b,s:s}", "is_tile", pt.is_tile, "marker", pt.marker,
                                     "frame_search", !o->hf.whole_field, "pitch_source",
                                     pitch_from == GIVEN ? "--pitch" : pitch_from == PAINTING ? pt.pitch_source
                                                                                              : "the copy's own");
        if (o->painting_tile && pt.index >= 0)
                json_object_set_new(o->painting_tile, "index", json_integer(pt.index));
        if (o->painting_tile && pitch_from == PAINTING)
                json_object_set_new(o->painting_tile, "pitch_mm", json_real(pt.pitch_mm));
        return o->painting_tile ? 0 : imp_error_set(err, -ENOMEM, "out of memory");
}

/* A set lacking frames of its plan is refused unless allow_incomplete (then o->incomplete). */
static int check_complete(struct process_opts *o, const struct imp_captureset *cs, struct imp_error *err) {
        json_t *missing = NULL;
        int r = imp_captureset_check_complete(cs, &missing, err);
        if (r <= 0 || o->opt->allow_incomplete) {
                o->incomplete = missing;
                return r < 0 ? r : 0;
        }
        json_decref(missing);
        char msg[sizeof err->msg];
        snprintf(msg, sizeof msg, "%s", err ? err->msg : "");
        return imp_error_set(err, -ENODATA, "%.900s; refused (--allow-incomplete processes it anyway)", msg);
}

/* Every output of the copy, each written once: heightfield.exr, boxes.json, the BRDF maps
 * (half float), previews/. copy.json comes last (write_copy_json). */
static int write_outputs(const struct process_opts *o, const struct geometry_out *g, struct imp_error *err) {
        int r = imp_heightfield_write_exr(&g->hf, o->out, err);
        if (r < 0)
                return r;
        char path[4096];
        snprintf(path, sizeof path, "%s/boxes.json", o->out);
        if ((r = imp_boxes_save(&g->boxes, path, err)) < 0)
                return r;
        static const char *const rgb[] = { "R", "G", "B" }, *const lobe[] = { "cx", "cy", "cz", "k" };
        static const char *const flags[] = { "flags" };
        static const char *const files[] = { "rho_d.exr", "rho_s.exr", "lobe.exr", "fit-flags.exr" };
        for (int m = 0; m < 4 && g->maps[m]; m++) {
                snprintf(path, sizeof path, "%s/%s", o->out, files[m]);
                if ((r = imp_exr_write(path, g->maps[m], m == 2 ? lobe : m == 3 ? flags : rgb, true, err)) < 0)
                        return r;
        }
        return imp_copy_previews(o->out, &g->hf, g->maps[0], err);
}

void imp_process_options_default(struct imp_process_options *o) {
        *o = (struct imp_process_options) { .btf = true, .photometric_normals = true, .fuse_heights = true };
        imp_heightfield_options_default(&o->heightfield);
        o->heightfield.shadow_fill_px = 80;
        imp_boxes_options_default(&o->boxes);
        imp_btf_sample_params_default(&o->btf_samples);
        imp_btf_fit_params_default(&o->btf_fit);
        imp_photometric_params_default(&o->photometric);
        imp_fuse_params_default(&o->fuse);
        imp_normal_trust_params_default(&o->normal_trust);
}

/* What one normal per texel can promise (normal-trust.h), on the final normals and σ_n. */
static int normal_trust(const struct process_opts *o, struct geometry_out *g) {
        struct imp_heightfield *hf = &g->hf;
        struct imp_normal_trust_stats st = {};
        int r = imp_normal_trust_cached(hf->nx, hf->ny, hf->mask, hf->nx_, hf->ny_, hf->sigma_n_deg, hf->texel_flags,
                                        &o->opt->normal_trust, &g->nt_cache, &st);
        imp_normal_trust_cache_done(&g->nt_cache);
        if (r >= 0)
                json_object_set_new(g->stages, "normal_trust", json_pack("{s:f,s:b,s:f,s:I,s:I,s:I}",
                        "rough_k", o->opt->normal_trust.rough_k, "edge", o->opt->normal_trust.edge,
                        "fine_k", o->opt->normal_trust.fine_k,
                        "rough_flagged", (json_int_t) st.n_rough_flagged, "fine_flagged", (json_int_t) st.n_fine_flagged,
                        "edge_flagged", (json_int_t) st.n_edge_flagged));
        return r;
}

/* A refused copy: no heightfield, copy.json with the verdict and the reason. */
static void write_refusal(const struct process_opts *o, const struct geometry_out *g, double seconds,
                          const struct imp_error *err) {
        char path[4096];
        snprintf(path, sizeof path, "%s/heightfield.exr", o->out);
        unlink(path);
        struct imp_error werr = {};
        write_copy_json(o, g, g->stages, seconds, err && err->msg[0] ? err->msg : "no plausible canvas", &werr);
}

int imp_process_capture(const char *capture_dir, const char *copy_dir,
                        const struct imp_process_options *opt, struct imp_error *err) {
        struct process_opts o = { capture_dir, copy_dir, opt };
        double t0 = now_s();
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(capture_dir, &cs, err);
        if (r < 0 || (r = check_complete(&o, cs, err)) < 0 || (r = painting_tile(&o, cs, err)) < 0) {
                json_decref(o.incomplete);
                return r;
        }
        r = imp_mkdir_p(copy_dir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create the copy directory: %s", copy_dir,
                                     strerror(-r));
#ifdef _OPENMP
        int threads_before = omp_get_max_threads();
        if (opt->threads > 0)
                omp_set_num_threads(opt->threads);
#endif
        struct geometry_out g = {};
        r = run_geometry(&o, cs, &g, err);
        if (r >= 0 && opt->btf)
                r = run_appearance(&o, cs, &g, err);
        else if (r >= 0)
                drop_fill(&g, NULL);   /* no normals to shape the fill */
        if (r >= 0 && (r = imp_heightfield_flag_edges(&g.hf, IMP_HF_FRAME_ADJACENT_PX)) < 0)
                imp_error_set(err, r, "out of memory");   /* the mask and σ_n are final now */
        if (r >= 0 && (r = normal_trust(&o, &g)) < 0)
                imp_error_set(err, r, "out of memory");
        if (r >= 0)
                r = classify_boxes(&o, &g, err);
        if (r >= 0)
                r = write_outputs(&o, &g, err);
        if (r >= 0)
                r = write_copy_json(&o, &g, g.stages, now_s() - t0, NULL, err);
        if (g.refused || r == -EINVAL || r == -EBADMSG)   /* not a copy of this painting */
                write_refusal(&o, &g, now_s() - t0, err);
        geometry_out_done(&g);
        json_decref(o.incomplete);
        json_decref(o.painting_tile);
#ifdef _OPENMP
        omp_set_num_threads(threads_before);
#endif
        return r;
}
