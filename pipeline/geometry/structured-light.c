/* Structured-light decoding: Gray code with inverses, robust bit classification after
 * Xu & Aliaga (GI 2007) with the direct/global estimates of Moreno & Taubin (3DIMPVT
 * 2012), and N-step phase shifting unwrapped against the Gray code. Rows are independent:
 * each thread decodes whole rows with its own scratch rows, nothing is allocated per
 * pixel, and the inner loops are branch-free so that they vectorize. */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#ifdef _OPENMP
#include <omp.h>
#endif
#include "structured-light.h"

#define MAX_BITS 24           /* 16 M projector pixels per axis */
#define MAX_STEPS 64
#define MAX_PERIODS 8
#define GRAY_WEAK_ALLOWED 1
#define RESULT_HUGE_BYTES (2u << 20)  /* x86-64 huge page; result maps at least this big */
#define CORR_N 512            /* phase-response correction table: samples per period */
#define RESP_HARMONICS 32     /* harmonics of the gamma-distorted sinusoid modelled */
#define RESP_MIN_SLOPE 0.2    /* response slope below this: not inverted (noise × 5) */
#define PHASE_STAT_MIN 64     /* pixels needed to judge an axis's phase against its Gray code */

struct phase_group {
        double period_px;
        int steps;
        int idx[MAX_STEPS];   /* frame index of each step */
        float cosd[MAX_STEPS], sind[MAX_STEPS];
        bool corr_on;         /* corr[] applies: measured phase φ̂ → φ̂ + corr(φ̂) */
        float corr[CORR_N + 1];   /* at φ̂ = 2π i / CORR_N (radians); corr[CORR_N] = corr[0] */
};

struct axis_plan {
        int nbits;                          /* Gray planes decoded; 0: no Gray code */
        int shift;                          /* finest planes of the code not projected:
                                               the code counts stripes of 2^shift px */
        float quantum;                      /* 2^shift, projector px per code */
        int ncodes;                         /* codes inside the projector */
        int p[MAX_BITS], q[MAX_BITS];       /* frame of bit k (0 = MSB) and of its inverse */
        bool inverse;                       /* q[] valid; else p̄ = white + black − p */
        int nphase;                         /* phase groups, coarsest period first */
        struct phase_group ph[MAX_PERIODS];
        int extent;                         /* projector pixels on this axis */
};

struct plan {
        struct axis_plan ax[2];
        int white, black;                   /* frame index or -1 */
        int dg[4 * MAX_BITS];               /* frames giving L_max / L_min */
        int ndg;
        int width, height;
        enum imp_pixel_type type;
};

int imp_sl_gray_bits(int extent) {
        int n = 0;
        while (n < 31 && (1LL << n) < (long long) extent)
                n++;
        return n;
}

void imp_sl_params_default(struct imp_sl_params *p, enum imp_pixel_type type) {
        /* 8-bit values (OpenCV's 3DUNDERWORLD defaults 40 / 5; Moreno's m = 5) scaled. */
        double scale = type == IMP_PIX_U8 ? 1.0 : type == IMP_PIX_U16 ? 65535.0 / 255.0 : 1.0 / 255.0;
        *p = (struct imp_sl_params) {
                .shadow_threshold = 40 * scale,
                .min_bit_contrast = 5 * scale,
                .min_direct = 5 * scale,
                .black_level = 0.0,
                .saturation = 0.0,
                .min_modulation = 5 * scale,
                .max_disagreement_px = 2.0,
                .phase_margin_px = 0.5,
                .dg_planes = 4,
                .robust = true,
        };
}

double imp_sl_pattern_value(const struct imp_pattern *pat, int px, int py) {
        int c = pat->axis == 0 ? px : py;
        switch (pat->kind) {
        case IMP_PAT_WHITE:
                return 1.0;
        case IMP_PAT_GRAY: {
                if (pat->bit < 0 || pat->bit >= pat->nbits || pat->nbits > 31 || c < 0)
                        return 0.0;
                unsigned g = (unsigned) c ^ ((unsigned) c >> 1);
                int v = (g >> (pat->nbits - 1 - pat->bit)) & 1;
                return pat->inverse ? 1 - v : v;
        }
        case IMP_PAT_PHASE:
                if (!(pat->period_px > 0) || pat->steps <= 0)
                        return 0.0;
                return 0.5 + 0.5 * cos(2 * M_PI * (c + 0.5) / pat->period_px +
                                       2 * M_PI * pat->step / pat->steps);
        default:
                return 0.0;
        }
}

int imp_sl_sequence(int proj_w, int proj_h, int phase_steps, const double *periods_px,
                    int n_periods, struct imp_pattern **ret, int *ret_n) {
        if (proj_w < 1 || proj_h < 1 || n_periods < 0 || (n_periods > 0 && !periods_px))
                return -EINVAL;
        int nb[2] = { imp_sl_gray_bits(proj_w), imp_sl_gray_bits(proj_h) };
        int nph = phase_steps >= 3 ? phase_steps * n_periods * 2 : 0;
        int n = 2 * (nb[0] + nb[1]) + 2 + nph;
        struct imp_pattern *v = calloc(n, sizeof *v);
        if (!v)
                return -ENOMEM;
        int k = 0;
        for (int a = 0; a < 2; a++)
                for (int b = 0; b < nb[a]; b++)
                        for (int inv = 0; inv < 2; inv++)
                                v[k++] = (struct imp_pattern) { .kind = IMP_PAT_GRAY, .axis = a,
                                        .bit = b, .nbits = nb[a], .inverse = inv };
        v[k++] = (struct imp_pattern) { .kind = IMP_PAT_WHITE };
        v[k++] = (struct imp_pattern) { .kind = IMP_PAT_BLACK };
        if (nph)
                for (int a = 0; a < 2; a++)
                        for (int j = 0; j < n_periods; j++)
                                for (int s = 0; s < phase_steps; s++)
                                        v[k++] = (struct imp_pattern) { .kind = IMP_PAT_PHASE,
                                                .axis = a, .period_px = periods_px[j],
                                                .step = s, .steps = phase_steps };
        *ret = v;
        *ret_n = n;
        return 0;
}

/* ---- pattern set → plan ------------------------------------------------------------ */

static int cmp_period_desc(const void *a, const void *b) {
        double pa = ((const struct phase_group *) a)->period_px;
        double pb = ((const struct phase_group *) b)->period_px;
        return (pa < pb) - (pa > pb);
}

static int check_images(const struct imp_sl_frames *in, struct plan *pl, struct imp_error *err) {
        if (!in || in->n <= 0 || !in->patterns || !in->images)
                return imp_error_set(err, -EINVAL, "structured light: no frames");
        for (int i = 0; i < in->n; i++) {
                const struct imp_image *im = in->images[i];
                if (!im || !im->data)
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: no image", i);
                if (im->channels != 1)
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: %d channels, "
                                             "expected 1", i, im->channels);
                if (i == 0) {
                        pl->width = im->width;
                        pl->height = im->height;
                        pl->type = im->type;
                        if (im->width < 1 || im->height < 1)
                                return imp_error_set(err, -EINVAL, "structured light: empty frame");
                } else if (im->width != pl->width || im->height != pl->height || im->type != pl->type) {
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: %dx%d %s, "
                                             "expected %dx%d %s like frame 0", i, im->width,
                                             im->height, imp_pixel_type_name(im->type), pl->width,
                                             pl->height, imp_pixel_type_name(pl->type));
                }
                if (im->stride < (size_t) im->width * imp_pixel_type_size(im->type))
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: stride too small", i);
                const struct imp_image *m = in->saturated ? in->saturated[i] : NULL;
                if (m && (!m->data || m->type != IMP_PIX_U8 || m->channels != 1 ||
                          m->width != im->width || m->height != im->height))
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: saturation "
                                             "mask is not a 1-channel u8 image of %dx%d", i,
                                             im->width, im->height);
        }
        return 0;
}

static int add_phase(struct axis_plan *ax, const struct imp_pattern *pt, int i, struct imp_error *err) {
        if (!(pt->period_px > 0) || !isfinite(pt->period_px))
                return imp_error_set(err, -EINVAL, "structured light: frame %d: phase period %g "
                                     "is not > 0", i, pt->period_px);
        if (pt->steps < 3 || pt->steps > MAX_STEPS || pt->step < 0 || pt->step >= pt->steps)
                return imp_error_set(err, -EINVAL, "structured light: frame %d: phase step %d of "
                                     "%d (need 3 ≤ steps ≤ %d)", i, pt->step, pt->steps, MAX_STEPS);
        struct phase_group *g = NULL;
        for (int j = 0; j < ax->nphase; j++)
                if (ax->ph[j].period_px == pt->period_px)
                        g = &ax->ph[j];
        if (!g) {
                if (ax->nphase == MAX_PERIODS)
                        return imp_error_set(err, -EINVAL, "structured light: more than %d phase "
                                             "periods on axis %d", MAX_PERIODS, pt->axis);
                g = &ax->ph[ax->nphase++];
                g->period_px = pt->period_px;
                g->steps = pt->steps;
                for (int s = 0; s < MAX_STEPS; s++)
                        g->idx[s] = -1;
        }
        if (g->steps != pt->steps)
                return imp_error_set(err, -EINVAL, "structured light: frame %d: period %g has "
                                     "both %d and %d steps", i, pt->period_px, g->steps, pt->steps);
        if (g->idx[pt->step] >= 0)
                return imp_error_set(err, -EINVAL, "structured light: frames %d and %d: same phase "
                                     "step %d (period %g, axis %d)", g->idx[pt->step], i, pt->step,
                                     pt->period_px, pt->axis);
        g->idx[pt->step] = i;
        return 0;
}

/* Phase response of an N-step group under projector gamma γ. The projector emits
 * g(θ) = ((1 + cos θ)/2)^γ (its black level and the global light add constants, which the
 * N-step sums cancel), with cosine harmonics c_k; the projector's pixels (a box of 1 px)
 * and its blur (Gaussian σ) scale harmonic k of a period P by sinc(k/P)·exp(−2π²σ²k²/P²).
 * The decoder's Z = Σ_s I_s e^{−iδ_s} keeps only harmonics k ≡ ±1 (mod N):
 *     Z(φ) = (N/2) Σ_k c_k m_k ([k ≡ 1] e^{ikφ} + [k ≡ −1] e^{−ikφ}),   φ̂ = arg Z(φ),
 * so φ̂ = H(φ) is a known function of the true phase alone, whatever the pixel's albedo or
 * global light. H is tabulated, checked to be increasing with slope ≥ RESP_MIN_SLOPE
 * (a steeper distortion could not be inverted without amplifying noise past that), and
 * inverted into corr(φ̂) = H⁻¹(φ̂) − φ̂. Returns false (no correction) when H is linear or
 * not invertible so. */
static bool build_response(struct phase_group *g, double gamma, double sigma_px) {
        enum { M = 1024, J = 4096 };
        double ck[RESP_HARMONICS + 1] = { 0 };
        for (int m = 0; m < M; m++) {
                double th = 2 * M_PI * m / M, v = pow(0.5 + 0.5 * cos(th), gamma);
                for (int k = 1; k <= RESP_HARMONICS; k++)
                        ck[k] += 2.0 / M * v * cos(k * th);
        }
        double wk[RESP_HARMONICS + 1];          /* c_k m_k of the harmonics kept, else 0 */
        int dir[RESP_HARMONICS + 1];            /* +1: e^{ikφ} (k ≡ 1), −1: e^{−ikφ} (k ≡ −1) */
        bool distorted = false;
        for (int k = 1; k <= RESP_HARMONICS; k++) {
                double f = k / g->period_px, box = sin(M_PI * f) / (M_PI * f);
                double m = box * exp(-2 * M_PI * M_PI * sigma_px * sigma_px * f * f);
                int r = k % g->steps;
                dir[k] = r == 1 ? 1 : r == g->steps - 1 ? -1 : 0;
                wk[k] = dir[k] ? ck[k] * m : 0;
                distorted |= k > 1 && fabs(wk[k]) > 1e-6 * fabs(wk[1]);
        }
        if (!distorted || !(wk[1] > 0))
                return false;
        _cleanup_free_ double *hat = malloc((J + 1) * sizeof *hat);
        if (!hat)
                return false;
        for (int j = 0; j < J; j++) {
                double phi = 2 * M_PI * j / J, re = 0, im = 0;
                for (int k = 1; k <= RESP_HARMONICS; k++) {
                        re += wk[k] * cos(k * phi);
                        im += dir[k] * wk[k] * sin(k * phi);
                }
                double e = remainder(atan2(im, re) - phi, 2 * M_PI);
                hat[j] = phi + e;                               /* H(φ_j), continuous */
                if (j && !(hat[j] - hat[j - 1] >= RESP_MIN_SLOPE * 2 * M_PI / J))
                        return false;
        }
        hat[J] = hat[0] + 2 * M_PI;
        if (!(hat[J] - hat[J - 1] >= RESP_MIN_SLOPE * 2 * M_PI / J))
                return false;
        for (int i = 0, j = 0; i <= CORR_N; i++) {
                double psi = 2 * M_PI * i / CORR_N;
                if (psi < hat[0])
                        psi += 2 * M_PI;
                while (j < J - 1 && hat[j + 1] <= psi)
                        j++;
                double phi = 2 * M_PI * (j + (psi - hat[j]) / (hat[j + 1] - hat[j])) / J;
                g->corr[i] = (float) remainder(phi - psi, 2 * M_PI);
        }
        g->corr[CORR_N] = g->corr[0];
        return true;
}

/* Sorts the frames into the plan: white, black, Gray planes (and inverses) per axis,
 * phase groups. Frames of other kinds are ignored. */
static int collect_frames(const struct imp_sl_frames *in, struct plan *pl, struct imp_error *err) {
        pl->white = pl->black = -1;
        for (int a = 0; a < 2; a++)
                for (int k = 0; k < MAX_BITS; k++)
                        pl->ax[a].p[k] = pl->ax[a].q[k] = -1;
        for (int i = 0; i < in->n; i++) {
                const struct imp_pattern *pt = &in->patterns[i];
                if (pt->kind == IMP_PAT_WHITE || pt->kind == IMP_PAT_BLACK) {
                        int *slot = pt->kind == IMP_PAT_WHITE ? &pl->white : &pl->black;
                        if (*slot >= 0)
                                return imp_error_set(err, -EINVAL, "structured light: frames %d and "
                                                     "%d: two %s frames", *slot, i,
                                                     pt->kind == IMP_PAT_WHITE ? "white" : "black");
                        *slot = i;
                        continue;
                }
                if (pt->kind != IMP_PAT_GRAY && pt->kind != IMP_PAT_PHASE)
                        continue;       /* dark or unrelated frames are ignored */
                if (pt->axis != 0 && pt->axis != 1)
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: axis %d, "
                                             "expected 0 or 1", i, pt->axis);
                struct axis_plan *ax = &pl->ax[pt->axis];
                if (pt->kind == IMP_PAT_PHASE) {
                        int r = add_phase(ax, pt, i, err);
                        if (r < 0)
                                return r;
                        continue;
                }
                if (pt->nbits < 1 || pt->nbits > MAX_BITS || pt->bit < 0 || pt->bit >= pt->nbits)
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: Gray bit %d "
                                             "of %d (need 1 ≤ nbits ≤ %d)", i, pt->bit, pt->nbits,
                                             MAX_BITS);
                if (ax->nbits && ax->nbits != pt->nbits)
                        return imp_error_set(err, -EINVAL, "structured light: frame %d: axis %d has "
                                             "both %d and %d Gray bits", i, pt->axis, ax->nbits,
                                             pt->nbits);
                ax->nbits = pt->nbits;
                int *slot = pt->inverse ? &ax->q[pt->bit] : &ax->p[pt->bit];
                if (*slot >= 0)
                        return imp_error_set(err, -EINVAL, "structured light: frames %d and %d: same "
                                             "Gray plane (axis %d bit %d%s)", *slot, i, pt->axis,
                                             pt->bit, pt->inverse ? ", inverse" : "");
                *slot = i;
        }
        return 0;
}

/* The Gray planes of axis a: which are present (the finest may be left out when phase
 * frames resolve the stripes), inverses all or none, the code's quantum and extent. */
static int plan_gray_axis(const struct imp_sl_params *p, struct plan *pl, int a, struct imp_error *err) {
        struct axis_plan *ax = &pl->ax[a];
        int full = ax->nbits, m = 0;
        while (m < full && (ax->p[m] >= 0 || ax->q[m] >= 0))
                m++;
        for (int k = m; k < full; k++)
                if (ax->p[k] >= 0 || ax->q[k] >= 0 || !ax->nphase)
                        return imp_error_set(err, -EINVAL, "structured light: axis %d: Gray "
                                             "bit %d of %d missing%s", a, m, full,
                                             ax->nphase ? "" : " (only phase frames can "
                                             "stand in for the finest planes)");
        ax->nbits = m;
        ax->shift = full - m;
        ax->quantum = (float) (1 << ax->shift);
        int nq = 0;
        for (int k = 0; k < ax->nbits; k++) {
                if (ax->p[k] < 0)
                        return imp_error_set(err, -EINVAL, "structured light: axis %d: Gray "
                                             "bit %d of %d missing", a, k, full);
                nq += ax->q[k] >= 0;
        }
        if (nq && nq != ax->nbits)
                return imp_error_set(err, -EINVAL, "structured light: axis %d: %d of %d Gray "
                                     "planes have inverses (all or none)", a, nq, ax->nbits);
        ax->inverse = ax->nbits > 0 && nq == ax->nbits;
        if (ax->nbits && !ax->inverse && (pl->white < 0 || pl->black < 0))
                return imp_error_set(err, -EINVAL, "structured light: axis %d: Gray planes "
                                     "without inverses need white and black frames", a);
        int want = a == 0 ? p->proj_width : p->proj_height;
        ax->extent = want > 0 ? want : full ? 1 << full : 0;
        ax->ncodes = (ax->extent + (1 << ax->shift) - 1) >> ax->shift;
        if (full && want > 0 && imp_sl_gray_bits(want) > full)
                return imp_error_set(err, -EINVAL, "structured light: axis %d: %d Gray bits "
                                     "cannot code %d projector pixels", a, full, want);
        return 0;
}

/* The phase groups of axis a: coarsest first, complete, with their response tables, and
 * able to unwrap against the Gray stripes (or to stand alone). */
static int plan_phase_axis(const struct imp_sl_params *p, struct axis_plan *ax, int a,
                           struct imp_error *err) {
        qsort(ax->ph, ax->nphase, sizeof ax->ph[0], cmp_period_desc);
        /* Nearest-period unwrapping against a stripe centre is off by up to half a
         * stripe: a stripe of at most half the coarsest period leaves a quarter
         * period for the phase's own error. */
        if (ax->shift && !(ax->ph[0].period_px >= 2 * ax->quantum))
                return imp_error_set(err, -EINVAL, "structured light: axis %d: Gray code "
                                     "without its %d finest planes (stripes of %g px) needs a "
                                     "phase period ≥ %g px, got %g", a, ax->shift,
                                     ax->quantum, 2 * ax->quantum, ax->ph[0].period_px);
        for (int j = 0; j < ax->nphase; j++) {
                struct phase_group *g = &ax->ph[j];
                for (int s = 0; s < g->steps; s++) {
                        if (g->idx[s] < 0)
                                return imp_error_set(err, -EINVAL, "structured light: axis %d "
                                                     "period %g: phase step %d of %d missing",
                                                     a, g->period_px, s, g->steps);
                        g->cosd[s] = (float) cos(2 * M_PI * s / g->steps);
                        g->sind[s] = (float) sin(2 * M_PI * s / g->steps);
                }
                g->corr_on = p->projector_gamma > 0 && p->projector_gamma != 1 &&
                             build_response(g, p->projector_gamma,
                                            fmax(p->projector_defocus_px, 0));
        }
        if (ax->nphase && !ax->nbits) {
                if (ax->extent <= 0)
                        return imp_error_set(err, -EINVAL, "structured light: axis %d: phase "
                                             "without Gray code needs the projector size", a);
                if (ax->ph[0].period_px < ax->extent)
                        return imp_error_set(err, -EINVAL, "structured light: axis %d: phase "
                                             "without Gray code needs a period ≥ %d px",
                                             a, ax->extent);
        }
        return 0;
}

static int build_plan(const struct imp_sl_frames *in, const struct imp_sl_params *p,
                      struct plan *pl, struct imp_error *err) {
        int r = check_images(in, pl, err);
        if (r < 0)
                return r;
        r = collect_frames(in, pl, err);
        if (r < 0)
                return r;
        bool any = false;
        for (int a = 0; a < 2; a++) {
                if ((r = plan_gray_axis(p, pl, a, err)) < 0 ||
                    (r = plan_phase_axis(p, &pl->ax[a], a, err)) < 0)
                        return r;
                any |= pl->ax[a].nbits > 0 || pl->ax[a].nphase > 0;
        }
        if (!any)
                return imp_error_set(err, -EINVAL, "structured light: no Gray or phase frames");

        /* L_max / L_min come from the finest planes: those split the scene into narrow
         * stripes, so that about half of it is lit (Nayar et al. 2006; Moreno & Taubin). */
        int planes = p->dg_planes > 0 ? p->dg_planes : 1;
        pl->ndg = 0;
        for (int a = 0; a < 2; a++) {
                struct axis_plan *ax = &pl->ax[a];
                for (int k = IMP_MAX(0, ax->nbits - planes); k < ax->nbits; k++) {
                        pl->dg[pl->ndg++] = ax->p[k];
                        if (ax->inverse)
                                pl->dg[pl->ndg++] = ax->q[k];
                }
        }
        return 0;
}

/* ---- per-row kernels ----------------------------------------------------------------- */

/* fminf/fmaxf are library calls unless -ffinite-math-only; inputs here are finite. */
static inline float minf(float a, float b) { return a < b ? a : b; }
static inline float maxf(float a, float b) { return a > b ? a : b; }

/* Vectorize the element-wise loops whatever the optimisation level's cost model says. */
#ifdef _OPENMP
#define SIMD _Pragma("omp simd")
#else
#define SIMD
#endif

static void load_row(const struct imp_image *im, int y, float *restrict dst, int w) {
        const void *row = imp_image_row(im, y);
        switch (im->type) {
        case IMP_PIX_U8: {
                const uint8_t *restrict s = row;
                SIMD
                for (int x = 0; x < w; x++)
                        dst[x] = s[x];
                break;
        }
        case IMP_PIX_U16: {
                const uint16_t *restrict s = row;
                SIMD
                for (int x = 0; x < w; x++)
                        dst[x] = s[x];
                break;
        }
        case IMP_PIX_F32: {
                const float *restrict s = row;
                /* Non-finite input samples become 0 so that nothing non-finite propagates. */
                SIMD
                for (int x = 0; x < w; x++)
                        dst[x] = isfinite(s[x]) ? s[x] : 0.0f;
                break;
        }
        }
}

enum { R_WHITE, R_BLACK, R_LMAX, R_LMIN, R_LD, R_LG, R_P, R_Q, R_HI, R_S, R_C, R_A,
       R_CMIN0, R_CMIN1, R_CODE0, R_CODE1, R_CUR0, R_CUR1, R_WEAK0, R_WEAK1,
       R_POS0, R_POS1, R_MOD0, R_MOD1, R_PCONF0, R_PCONF1, R_SATM, R_DIS0, R_DIS1,
       R_OX, R_OY, R_OC, R_OS, R_OD, R_OG, R_OF, R_NROWS };     /* R_O*: a Gray row's outputs */

/* Bits of the R_SATM row (saturation masks of imp_sl_frames.saturated). */
enum { SATM_ANY = 1u << 0, SATM_PHASE0 = 1u << 1, SATM_PHASE1 = 1u << 2 };
/* Bits of the R_PCONF rows (phase status per axis). */
enum { PST_LOW_MOD = 1u << 0, PST_DISAGREE = 1u << 1, PST_OUTSIDE_CELL = 1u << 2 };
#define INV_SQRT12 0.28867513f   /* σ of a uniform position in a cell of 1 */
#define WEAK_SIGMA 0.57735027f   /* √(1/12 + 1/4): a weak bit may put the code one off */

struct ctx {
        const struct imp_sl_frames *in;
        const struct imp_sl_params *p;
        const struct plan *pl;
        float sat, b;
        int int_path;           /* IMP_PIX_U8 / IMP_PIX_U16: integer Gray path; else -1 */
        unsigned rejected;      /* bit a: axis a's phase was rejected (IMP_SL_PHASE_REJECTED) */
        bool stream;            /* Gray rows built in R_O* and streamed to res (stream_row) */
        struct imp_sl_result *res;
};

/* Gray planes of one axis, MSB first: the binary code is accumulated with the running
 * XOR b_k = b_{k-1} ^ g_k (Gray → binary). A bit is undecided ("weak") when |p − p̄| is
 * below min_bit_contrast, when both samples are saturated, or — robust mode — when the
 * Xu & Aliaga rules do not classify it:
 *     L_d > L_g                 → on iff p > p̄
 *     p ≤ L_d  and  p̄ ≥ L_g     → off
 *     p ≥ L_g  and  p̄ ≤ L_d     → on
 *     otherwise                 → uncertain
 * (L_d < m, their first rule, is the pixel-level shadow test.) When a rule decides, it
 * always agrees with the sign of p − p̄, so the decision itself is the sign. */
static void decode_gray_axis(const struct ctx *c, int a, int y, float **R, int w) {
        const struct axis_plan *ax = &c->pl->ax[a];
        uint32_t *restrict code = (uint32_t *) R[R_CODE0 + a];
        uint32_t *restrict cur = (uint32_t *) R[R_CUR0 + a];
        uint32_t *restrict weak = (uint32_t *) R[R_WEAK0 + a];
        float *restrict cmin = R[R_CMIN0 + a], *restrict hi = R[R_HI];
        float *restrict pr = R[R_P], *restrict qr = R[R_Q];
        const float *restrict ld = R[R_LD], *restrict lg = R[R_LG];
        const float minc = (float) c->p->min_bit_contrast, sat = c->sat;
        SIMD
        for (int x = 0; x < w; x++) {
                code[x] = cur[x] = weak[x] = 0;
                cmin[x] = INFINITY;
        }
        for (int k = 0; k < ax->nbits; k++) {
                load_row(c->in->images[ax->p[k]], y, pr, w);
                if (ax->inverse) {
                        load_row(c->in->images[ax->q[k]], y, qr, w);
                } else {
                        const float *wr = R[R_WHITE], *br = R[R_BLACK];
                        SIMD
                        for (int x = 0; x < w; x++)
                                qr[x] = wr[x] + br[x] - pr[x];
                }
                if (c->p->robust) {
                        SIMD
                        for (int x = 0; x < w; x++) {
                                float pv = pr[x], qv = qr[x], d = pv - qv, ad = fabsf(d);
                                uint32_t on = d > 0;
                                uint32_t cls = (ld[x] > lg[x]) | ((pv <= ld[x]) & (qv >= lg[x])) |
                                               ((pv >= lg[x]) & (qv <= ld[x]));
                                uint32_t wk = (ad < minc) | (minf(pv, qv) >= sat) | (cls ^ 1u);
                                cur[x] ^= on;
                                code[x] = (code[x] << 1) | cur[x];
                                weak[x] += wk;
                                cmin[x] = minf(cmin[x], ad);
                                hi[x] = maxf(hi[x], maxf(pv, qv));
                        }
                } else {
                        SIMD
                        for (int x = 0; x < w; x++) {
                                float pv = pr[x], qv = qr[x], d = pv - qv, ad = fabsf(d);
                                uint32_t on = d > 0;
                                uint32_t wk = (ad < minc) | (minf(pv, qv) >= sat);
                                cur[x] ^= on;
                                code[x] = (code[x] << 1) | cur[x];
                                weak[x] += wk;
                                cmin[x] = minf(cmin[x], ad);
                                hi[x] = maxf(hi[x], maxf(pv, qv));
                        }
                }
        }
}

/* Undoes the projector's phase response (build_response) on wrapped positions u_f ∈ [0, P). */
static void correct_response(const struct phase_group *g, float *restrict uf, int w) {
        const float P = (float) g->period_px, to_i = CORR_N / P, to_u = P / (float) (2 * M_PI);
        const float *restrict corr = g->corr;
        for (int x = 0; x < w; x++) {
                float t = uf[x] * to_i;
                int i = (int) t;
                i = i < 0 ? 0 : i > CORR_N - 1 ? CORR_N - 1 : i;
                float u = uf[x] + to_u * (corr[i] + (t - (float) i) * (corr[i + 1] - corr[i]));
                u = u < 0 ? u + P : u >= P ? u - P : u;
                uf[x] = u >= 0 && u < P ? u : 0.0f;             /* NaN-safe, stays in [0, P) */
        }
}

/* One N-step group: φ = atan2(−Σ I_i sin δ_i, Σ I_i cos δ_i), B = (2/N)·|Σ I_i e^{iδ_i}|,
 * for I_i = A + B cos(φ + δ_i), δ_i = 2π i / N. Position in the period u_f = P φ / 2π. */
static void phase_group_row(const struct ctx *c, const struct phase_group *g, int y, float **R,
                            int w) {
        float *restrict S = R[R_S], *restrict C = R[R_C], *restrict A = R[R_A];
        float *restrict pr = R[R_P], *restrict hi = R[R_Q];
        SIMD
        for (int x = 0; x < w; x++)
                S[x] = C[x] = A[x] = hi[x] = 0.0f;
        for (int s = 0; s < g->steps; s++) {
                load_row(c->in->images[g->idx[s]], y, pr, w);
                float cs = g->cosd[s], sn = g->sind[s];
                SIMD
                for (int x = 0; x < w; x++) {
                        S[x] += pr[x] * sn;
                        C[x] += pr[x] * cs;
                        A[x] += pr[x];
                        hi[x] = maxf(hi[x], pr[x]);
                }
        }
        float inv_n = 1.0f / g->steps;
        SIMD
        for (int x = 0; x < w; x++) {
                A[x] *= inv_n;
                float phi = atan2f(-S[x], C[x]);                /* (−π, π] */
                float uf = (float) (g->period_px / (2 * M_PI)) * phi;
                if (uf < 0)
                        uf += (float) g->period_px;
                float B = 2 * inv_n * sqrtf(S[x] * S[x] + C[x] * C[x]);
                S[x] = uf;                                      /* reuse: wrapped position */
                C[x] = B;                                       /* reuse: modulation */
        }
        if (g->corr_on)
                correct_response(g, S, w);
}

static inline float clamp01(float v) {
        return v > 1.0f ? 1.0f : v > 0.0f ? v : 0.0f;   /* also maps NaN to 0 */
}

/* ---- integer path: u8 / u16 frames, Gray code ----------------------------------------
 * Integer samples are exact in float, and each comparison of the float path has an exact
 * integer twin: p ≤ L_d ⇔ p ≤ ⌊L_d⌋, p̄ ≥ L_g ⇔ p̄ ≥ ⌈L_g⌉, |p − p̄| < t ⇔ |p − p̄| < ⌈t⌉,
 * min(p, p̄) ≥ s ⇔ min(p, p̄) ≥ ⌈s⌉. So the frames are read as they are (u8 in 16-bit lanes,
 * u16 in 32-bit lanes), every Gray plane of a block of IBLK pixels is classified while the
 * block's state stays in L1, the Gray code is accumulated and turned into binary once
 * (g ^ g>>1 ^ g>>2 …, the running XOR b_k = b_{k−1} ⊕ g_k), and the outputs are
 * bit-identical to the float path (L_d, L_g keep the float formulas). */
#define IBLK 1024

/* The integer kernels and the combine step below are built without -ftrapping-math: under
 * it gcc will not if-convert a floating-point operation (or a float → int conversion) that
 * jump threading has moved onto one arm of a select, and such loops stay scalar. The flag
 * only concerns floating-point exception flags, which nothing here reads: every value is
 * the same. Helpers are macros, since functions built with other options are not inlined. */
/* AVX2 doubles the lanes of the Gray and combine loops; chosen at load time by the CPU
 * (ifunc), baseline SSE2 otherwise. Not FMA: contraction would change L_d/L_g.
 * IMPASTO_SL_NO_CLONES builds the baseline alone (test-sl-decode-sse2 runs the checks on
 * it, as a CPU without AVX2 would). */
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__) && !defined(IMPASTO_SL_NO_CLONES)
#define CLONES target_clones("avx2", "default")
#else
#define CLONES
#endif
#define MINF(a, b) ((a) < (b) ? (a) : (b))
#define MAXF(a, b) ((a) > (b) ? (a) : (b))
#define CLAMP01(v) MINF((v) > 0.0f ? (v) : 0.0f, 1.0f)   /* = clamp01(), NaN → 0 */

#define DEFINE_GRAY_INT(NAME, ST, LT, UT, LT_MAX, FAST8)                                          \
static inline __attribute__((always_inline, optimize("no-trapping-math"))) void NAME##_bit(                                  \
                const ST *restrict pr, const ST *restrict qr, bool inv, int n,                 \
                const LT *restrict W, const LT *restrict Bk, const LT *restrict td,            \
                const LT *restrict tg, const LT *restrict alw, LT minc, LT sat,                \
                UT *restrict g, LT *restrict wk, LT *restrict cm, LT *restrict hi) {           \
        SIMD                                                                                   \
        for (int x = 0; x < n; x++) {                                                          \
                LT pv = pr[x];                                                                 \
                LT qv = inv ? (LT) qr[x] : (LT) (W[x] + Bk[x] - pv);                           \
                LT d = (LT) (pv - qv);                                                         \
                LT ad = d < 0 ? (LT) -d : d;                                                   \
                LT lo = pv < qv ? pv : qv, up = pv > qv ? pv : qv;                             \
                LT cls = alw[x] | ((pv <= td[x]) & (qv >= tg[x])) | ((pv >= tg[x]) & (qv <= td[x])); \
                g[x] = (UT) ((UT) (g[x] << 1) | (UT) (d > 0));                                 \
                wk[x] = (LT) (wk[x] + ((ad < minc) | (lo >= sat) | (cls ^ 1)));                \
                cm[x] = cm[x] < ad ? cm[x] : ad;                                               \
                hi[x] = hi[x] > up ? hi[x] : up;                                               \
        }                                                                                      \
}                                                                                              \
                                                                                               \
/* L_d, L_g (the float formulas) and their integer thresholds. Its own function: inlined \
 * into the block loop, gcc leaves this loop scalar. */                                      \
static __attribute__((noinline, optimize("no-trapping-math"))) void NAME##_thr(                \
                int n, const LT *restrict mx, const LT *restrict mn, float k1, float k2,       \
                float b, LT always, float *restrict ld, float *restrict lg, LT *restrict td,   \
                LT *restrict tg, LT *restrict alw) {                                           \
        SIMD                                                                           \
        for (int x = 0; x < n; x++) {                                                  \
                float lmax = mx[x], lmin = mn[x];                                      \
                float d = MAXF(k1 * (lmax - lmin), 0.0f);                              \
                float e = MAXF(k2 * (lmin - b * lmax), 0.0f);                          \
                ld[x] = d;                                                             \
                lg[x] = e;                                                             \
                /* ⌊L_d⌋, ⌈L_g⌉; both ≥ 0 and finite, and no sample reaches LT_MAX.    \
                 * (Statement order matters to gcc 12's vectorizer here.) */          \
                float dc = MINF(d, (float) LT_MAX);                                    \
                int32_t s = (int32_t) dc;                                              \
                td[x] = (LT) (s - ((float) s > dc));                                   \
                float ec = MINF(e, (float) LT_MAX);                                    \
                int32_t t = (int32_t) ec;                                              \
                tg[x] = (LT) (t + ((float) t < ec));                                   \
                alw[x] = (LT) ((d > e) | always);                                      \
        }                                                                              \
}                                                                                              \
                                                                                               \
static __attribute__((noinline, optimize("no-trapping-math"), CLONES)) void NAME(             \
                const struct ctx *c, int y, float **R, int w) {                                \
        const struct plan *pl = c->pl;                                                         \
        const struct imp_image *const *im = c->in->images;                                     \
        const bool have_w = pl->white >= 0, have_b = pl->black >= 0;                           \
        const bool noinv = (pl->ax[0].nbits && !pl->ax[0].inverse) ||                          \
                           (pl->ax[1].nbits && !pl->ax[1].inverse);                            \
        const LT minc = (LT) int_ceil_clamp((float) c->p->min_bit_contrast, 0, LT_MAX);        \
        const LT sat = (LT) int_ceil_clamp(c->sat, -LT_MAX, LT_MAX);                           \
        const float b = c->b, k1 = 1.0f / (1.0f - b), k2 = 2.0f / (1.0f - b * b);              \
        const LT always = c->p->robust ? 0 : 1;                                                \
        for (int x0 = 0; x0 < w; x0 += IBLK) {                                                 \
                const int n = IMP_MIN(IBLK, w - x0);                                           \
                LT W[IBLK], Bk[IBLK], hi[IBLK], mx[IBLK], mn[IBLK], td[IBLK], tg[IBLK], alw[IBLK]; \
                LT wk[IBLK], cm[IBLK];                                                         \
                UT g[IBLK];                                                                    \
                const ST *wr = have_w ? (const ST *) imp_image_row(im[pl->white], y) + x0 : NULL; \
                const ST *br = have_b ? (const ST *) imp_image_row(im[pl->black], y) + x0 : NULL; \
                SIMD                                                                           \
                for (int x = 0; x < n; x++)                                                    \
                        W[x] = Bk[x] = 0;                                                      \
                if (have_w) {                                                                  \
                        SIMD                                                                   \
                        for (int x = 0; x < n; x++)                                            \
                                W[x] = wr[x];                                                  \
                }                                                                              \
                if (have_b) {                                                                  \
                        SIMD                                                                   \
                        for (int x = 0; x < n; x++)                                            \
                                Bk[x] = br[x];                                                 \
                }                                                                              \
                SIMD                                                                           \
                for (int x = 0; x < n; x++)                                                    \
                        hi[x] = W[x];           /* the black frame never counted here */       \
                const ST *p0 = (const ST *) imp_image_row(im[pl->dg[0]], y) + x0;              \
                SIMD                                                                           \
                for (int x = 0; x < n; x++)                                                    \
                        mx[x] = mn[x] = p0[x];                                                 \
                for (int i = 1; i < pl->ndg; i++) {                                            \
                        const ST *pi = (const ST *) imp_image_row(im[pl->dg[i]], y) + x0;      \
                        SIMD                                                                   \
                        for (int x = 0; x < n; x++) {                                          \
                                LT v = pi[x];                                                  \
                                mx[x] = mx[x] > v ? mx[x] : v;                                 \
                                mn[x] = mn[x] < v ? mn[x] : v;                                 \
                        }                                                                      \
                }                                                                              \
                if (noinv) {                                                                   \
                        SIMD                                                                   \
                        for (int x = 0; x < n; x++) {                                          \
                                LT a1 = (LT) (W[x] + Bk[x] - mx[x]), a2 = (LT) (W[x] + Bk[x] - mn[x]); \
                                mx[x] = mx[x] > a2 ? mx[x] : a2;                               \
                                mn[x] = mn[x] < a1 ? mn[x] : a1;                               \
                        }                                                                      \
                }                                                                              \
                NAME##_thr(n, mx, mn, k1, k2, b, always, R[R_LD] + x0, R[R_LG] + x0, td, tg, alw); \
                for (int a = 0; a < 2; a++) {                                                  \
                        const struct axis_plan *ax = &pl->ax[a];                               \
                        if (!ax->nbits)                                                        \
                                continue;                                                      \
                        SIMD                                                                   \
                        for (int x = 0; x < n; x++) {                                          \
                                g[x] = 0;                                                      \
                                wk[x] = 0;                                                     \
                                cm[x] = LT_MAX;                                                \
                        }                                                                      \
                        bool bytes = ax->inverse && FAST8(im, ax, y, x0, n, td, tg, alw, minc, sat, hi, \
                                                          g, wk, cm);                          \
                        for (int k = 0; k < ax->nbits && !bytes; k++) {                        \
                                const ST *pr = (const ST *) imp_image_row(im[ax->p[k]], y) + x0; \
                                if (ax->inverse)                                               \
                                        NAME##_bit(pr, (const ST *) imp_image_row(im[ax->q[k]], y) + x0, \
                                                   true, n, W, Bk, td, tg, alw, minc, sat, g, wk, cm, hi); \
                                else                                                           \
                                        NAME##_bit(pr, NULL, false, n, W, Bk, td, tg, alw, minc, \
                                                   sat, g, wk, cm, hi);                        \
                        }                                                                      \
                        uint32_t *restrict code = (uint32_t *) R[R_CODE0 + a] + x0;            \
                        uint32_t *restrict weak = (uint32_t *) R[R_WEAK0 + a] + x0;            \
                        float *restrict cmin = R[R_CMIN0 + a] + x0;                            \
                        SIMD                                                                   \
                        for (int x = 0; x < n; x++) {                                          \
                                uint32_t v = g[x];                                             \
                                v ^= v >> 1;                                                   \
                                v ^= v >> 2;                                                   \
                                v ^= v >> 4;                                                   \
                                v ^= v >> 8;                                                   \
                                v ^= v >> 16;                                                  \
                                code[x] = v;                                                   \
                                weak[x] = (uint32_t) wk[x];                                    \
                                cmin[x] = cm[x];                                               \
                        }                                                                      \
                }                                                                              \
                float *restrict hr = R[R_HI] + x0, *restrict wf = R[R_WHITE] + x0;             \
                float *restrict bf = R[R_BLACK] + x0;                                          \
                SIMD                                                                           \
                for (int x = 0; x < n; x++) {                                                  \
                        hr[x] = hi[x];                                                         \
                        wf[x] = W[x];                                                          \
                        bf[x] = Bk[x];                                                         \
                }                                                                              \
        }                                                                                      \
}

/* ⌈v⌉ clamped to [lo, hi]; v finite or ±∞ (a NaN threshold never compares true: hi). */
static inline int32_t int_ceil_clamp(float v, int32_t lo, int32_t hi) {
        if (!(v < (float) hi))
                return hi;
        if (!(v > (float) lo))
                return lo;
        return (int32_t) ceilf(v);
}

/* u8 frames with inverse planes: every operand of the Gray classification is a byte
 * (p, p̄ ∈ [0, 255], |p − p̄|, ⌊L_d⌋ and ⌈L_g⌉ clamped to a byte with the cases that the
 * clamp would change kept as masks), so a plane is classified in byte lanes: 32 pixels a
 * AVX2 instruction instead of 16 in the 16-bit path, and no widening of the frames. The
 * code's bits go to two bytes (planes 0–7 and 8–15). Same decisions as gray_int_u8_bit(). */
static inline __attribute__((always_inline)) void gray_u8_plane(
                const uint8_t *restrict pr, const uint8_t *restrict qr, int n,
                const uint8_t *restrict td, const uint8_t *restrict tg, const uint8_t *restrict alw,
                const uint8_t *restrict tgok, uint8_t minc, uint8_t weak_all, uint8_t sat, uint8_t sat_on,
                uint8_t *restrict g, uint8_t *restrict wk, uint8_t *restrict cm, uint8_t *restrict hi) {
        SIMD
        for (int x = 0; x < n; x++) {
                uint8_t pv = pr[x], qv = qr[x];
                uint8_t lo = pv < qv ? pv : qv, up = pv < qv ? qv : pv;
                uint8_t ad = (uint8_t) (up - lo);
                uint8_t c1 = (uint8_t) ((pv <= td[x]) & (qv >= tg[x]));
                uint8_t c2 = (uint8_t) ((pv >= tg[x]) & (qv <= td[x]));
                uint8_t cls = (uint8_t) (alw[x] | (tgok[x] & (c1 | c2)));
                g[x] = (uint8_t) ((g[x] << 1) | (pv > qv));
                wk[x] = (uint8_t) (wk[x] + ((ad < minc) | weak_all | ((lo >= sat) & sat_on) | (cls ^ 1)));
                cm[x] = cm[x] < ad ? cm[x] : ad;
                hi[x] = hi[x] > up ? hi[x] : up;
        }
}

#define NO_BYTES(...) false

/* Byte-lane classification settings, from the type's integer thresholds. */
struct u8_lim {
        uint8_t minc, weak_all, sat, sat_on;
};

static struct u8_lim u8_limits(int16_t minc, int16_t sat) {
        return (struct u8_lim) { (uint8_t) (minc > 255 ? 255 : minc), minc > 255,
                                 (uint8_t) (sat < 0 ? 0 : sat > 255 ? 255 : sat), sat <= 255 };
}

/* The next row of axis ax's frames over [x0, x0 + n): the thread decodes it next (rows come
 * in chunks), and 40 streams of a row each are more than the hardware prefetchers follow. */
static inline __attribute__((always_inline)) void prefetch_next_rows(
                const struct imp_image *const *im, const struct axis_plan *ax, int y, int x0, int n) {
        if (y + 1 >= im[0]->height)
                return;
        for (int k = 0; k < ax->nbits; k++) {
                const char *pn = (const char *) imp_image_row(im[ax->p[k]], y + 1) + x0;
                const char *qn = (const char *) imp_image_row(im[ax->q[k]], y + 1) + x0;
                for (int x = 0; x < n; x += 64) {
                        __builtin_prefetch(pn + x);
                        __builtin_prefetch(qn + x);
                }
        }
}

/* Every Gray plane of axis ax over n pixels from x0, in byte lanes: g0 takes planes 0–7, g1
 * planes 8–15; wk8, cm8, g0, g1 start at 0, 255, 0, 0; hi8 is raised by every sample. */
static inline __attribute__((always_inline)) void gray_u8_planes(
                const struct imp_image *const *im, const struct axis_plan *ax, int y, int x0, int n,
                const uint8_t *restrict td8, const uint8_t *restrict tg8, const uint8_t *restrict alw8,
                const uint8_t *restrict tgok, struct u8_lim lim, uint8_t *restrict g0, uint8_t *restrict g1,
                uint8_t *restrict wk8, uint8_t *restrict cm8, uint8_t *restrict hi8) {
        for (int k = 0; k < ax->nbits; k++) {
                const uint8_t *pr = (const uint8_t *) imp_image_row(im[ax->p[k]], y) + x0;
                const uint8_t *qr = (const uint8_t *) imp_image_row(im[ax->q[k]], y) + x0;
                gray_u8_plane(pr, qr, n, td8, tg8, alw8, tgok, lim.minc, lim.weak_all, lim.sat, lim.sat_on,
                              k >= 8 ? g1 : g0, wk8, cm8, hi8);
        }
}

static __attribute__((noinline, CLONES)) bool gray_u8_axis(
                const struct imp_image *const *im, const struct axis_plan *ax, int y, int x0, int n,
                const int16_t *td, const int16_t *tg, const int16_t *alw, int16_t minc, int16_t sat,
                int16_t *hi, uint16_t *g, int16_t *wk, int16_t *cm) {
        uint8_t td8[IBLK], tg8[IBLK], alw8[IBLK], tgok[IBLK], g8[2][IBLK], wk8[IBLK], cm8[IBLK], hi8[IBLK];
        SIMD
        for (int x = 0; x < n; x++) {
                td8[x] = (uint8_t) (td[x] > 255 ? 255 : td[x]);         /* p ≤ 255 anyway */
                tgok[x] = tg[x] <= 255;                                 /* else p̄ ≥ ⌈L_g⌉ never */
                tg8[x] = (uint8_t) (tg[x] > 255 ? 255 : tg[x]);
                alw8[x] = (uint8_t) alw[x];
                hi8[x] = (uint8_t) hi[x];
                g8[0][x] = g8[1][x] = wk8[x] = 0;
                cm8[x] = 255;
        }
        prefetch_next_rows(im, ax, y, x0, n);
        gray_u8_planes(im, ax, y, x0, n, td8, tg8, alw8, tgok, u8_limits(minc, sat), g8[0], g8[1], wk8,
                       cm8, hi8);
        const int low = ax->nbits > 8 ? ax->nbits - 8 : 0;      /* bits in g8[1] */
        SIMD
        for (int x = 0; x < n; x++) {
                g[x] = (uint16_t) ((g8[0][x] << low) | (low ? g8[1][x] : 0));
                wk[x] = wk8[x];
                cm[x] = ax->nbits ? cm8[x] : INT16_MAX;
                hi[x] = hi8[x];
        }
        return true;
}

DEFINE_GRAY_INT(gray_int_u8, uint8_t, int16_t, uint16_t, INT16_MAX, gray_u8_axis)
DEFINE_GRAY_INT(gray_int_u16, uint16_t, int32_t, uint32_t, (1 << 20), NO_BYTES)   /* ≫ any W + B − p */

/* ---- u8 frames with white, black and every Gray plane's inverse (the procam captures, the
 * simulator's plans): the whole block in byte lanes. L_max / L_min are byte maxima, and the
 * thresholds go from the float L_d, L_g (same formulas, same values as gray_int_u8_thr)
 * straight to bytes: ⌊min(L_d, 255)⌋ = min(⌊L_d⌋, 255), and with c = ⌈min(L_g, 256)⌉,
 * min(c, 255) = min(⌈L_g⌉, 255) and c ≤ 255 ⇔ ⌈L_g⌉ ≤ 255 (L_d, L_g ≥ 0, finite).
 * Bit-identical to gray_int_u8 with gray_u8_axis (test-sl-decode, bench-decode --checksum),
 * without its 16-bit round trips.
 * The thresholds are computed eight lanes at a time in GCC's generic vectors: written as a
 * loop, gcc 12 jump-threads the MAXF/MINF selects into branches ("control flow in loop")
 * and leaves it scalar, ≈ 30 instructions a pixel. The operations are those of the scalar
 * formulas lane by lane (a > b ? a : b as a mask select, float → int by truncation, no FMA),
 * so every value is the same; the SSE2 clone runs each as two 4-lane halves. */
typedef float v8f __attribute__((vector_size(32)));
typedef int32_t v8i __attribute__((vector_size(32)));

/* m ? a : b lane by lane, m a comparison's −1 / 0 (a macro: a 32-byte vector argument
 * would change the ABI of the SSE2 clone) */
#define SEL8(m, a, b) ((v8f) (((v8i) (a) & (m)) | ((v8i) (b) & ~(m))))
/* 8 bytes as int lanes, element by element (see thr##SFX) */
#define LD8(p) ((v8i) { (p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7] })

/* thr##SFX and u8_thresholds##SFX, N lanes (VF, VI; LD: N bytes as int lanes), built with ATTR
 * (IATTR: the inlined helper's). */
#define DEFINE_THR(SFX, ATTR, IATTR, N, VF, VI, LD, SEL) \
static inline __attribute__((always_inline)) IATTR void thr##SFX(                                        \
                const uint8_t *mx, const uint8_t *mn, float k1, float k2, float b, uint8_t always,       \
                float *ld, float *lg, int32_t *ti, int32_t *gi, int32_t *ai) {                           \
        /* Bytes → int lanes element by element: gcc 12 turns this into one pmovzxbd (AVX2) or           \
         * two unpacks, but converts a loaded 8-byte vector (v8b) lane by lane in scalar code. */        \
        const VI ix = LD(mx), in = LD(mn);                                                               \
        const VF lmax = __builtin_convertvector(ix, VF), lmin = __builtin_convertvector(in, VF);         \
        const VF zero = { 0 }, c255 = zero + 255.0f, c256 = zero + 256.0f;                               \
        VF d = (zero + k1) * (lmax - lmin), e = (zero + k2) * (lmin - (zero + b) * lmax);                \
        d = SEL(d > zero, d, zero);                                                                      \
        e = SEL(e > zero, e, zero);                                                                      \
        memcpy(ld, &d, sizeof d);                                                                        \
        memcpy(lg, &e, sizeof e);                                                                        \
        const VF dc = SEL(d < c255, d, c255), ec = SEL(e < c256, e, c256);                               \
        const VI s = __builtin_convertvector(dc, VI), t = __builtin_convertvector(ec, VI);               \
        /* comparisons give −1 where true: s − [s > dc], t + [t < ec] */                                 \
        const VI tiv = s + (__builtin_convertvector(s, VF) > dc);                                        \
        const VI giv = t - (__builtin_convertvector(t, VF) < ec);                                        \
        const VI aiv = ((d > e) & 1) | (int32_t) always;                                                 \
        memcpy(ti, &tiv, sizeof tiv);                                                                    \
        memcpy(gi, &giv, sizeof giv);                                                                    \
        memcpy(ai, &aiv, sizeof aiv);                                                                    \
}                                                                                                        \
                                                                                                         \
static __attribute__((noinline)) ATTR void u8_thresholds##SFX(                                           \
                int n, const uint8_t *restrict mx, const uint8_t *restrict mn, float k1, float k2,       \
                float b, uint8_t always, float *restrict ld, float *restrict lg, uint8_t *restrict td8,  \
                uint8_t *restrict tg8, uint8_t *restrict tgok, uint8_t *restrict alw8) {                 \
        /* in 32-bit lanes first: float → byte conversions in one loop stay scalar in gcc 12 */          \
        int32_t ti[IBLK + N], gi[IBLK + N], ai[IBLK + N];     /* + the tail's padding lanes */           \
        int x = 0;                                                                                       \
        for (; x + N <= n; x += N)                                                                       \
                thr##SFX(mx + x, mn + x, k1, k2, b, always, ld + x, lg + x, ti + x, gi + x, ai + x);     \
        if (x < n) {            /* the tail through zero-padded lanes */                                 \
                uint8_t px[N] = { 0 }, pn[N] = { 0 };                                                    \
                float pd[N], pg[N];                                                                      \
                memcpy(px, mx + x, (size_t) (n - x));                                                    \
                memcpy(pn, mn + x, (size_t) (n - x));                                                    \
                thr##SFX(px, pn, k1, k2, b, always, pd, pg, ti + x, gi + x, ai + x);                     \
                memcpy(ld + x, pd, (size_t) (n - x) * sizeof *pd);                                       \
                memcpy(lg + x, pg, (size_t) (n - x) * sizeof *pg);                                       \
        }                                                                                                \
        SIMD                                                                                             \
        for (x = 0; x < n; x++) {                                                                        \
                td8[x] = (uint8_t) ti[x];                                                                \
                tg8[x] = (uint8_t) (gi[x] > 255 ? 255 : gi[x]);                                          \
                tgok[x] = gi[x] <= 255;                                                                  \
                alw8[x] = (uint8_t) ai[x];                                                               \
        }                                                                                                \
}

DEFINE_THR(_v8, __attribute__((CLONES)), , 8, v8f, v8i, LD8, SEL8)

/* Axis a's block code: Gray → binary on the 16-bit code (g ^ g>>1 ^ g>>2 …), planes 0–7 in
 * g0, 8–15 in g1. This loop and u8_thresholds are functions of their own: inlined into the
 * block loop, gcc 12 leaves them scalar (≈ 100 instructions a pixel under callgrind). */
static __attribute__((noinline, CLONES)) void u8_axis_code(
                int n, int nbits, const uint8_t *restrict g0, const uint8_t *restrict g1,
                uint16_t *restrict code) {
        /* (two loops: with the select between them in one, gcc 12 leaves it scalar) */
        if (nbits > 8) {
                const int low = nbits - 8;      /* bits in g1 */
                SIMD
                for (int x = 0; x < n; x++)
                        code[x] = (uint16_t) ((g0[x] << low) | g1[x]);
        } else {
                SIMD
                for (int x = 0; x < n; x++)
                        code[x] = g0[x];
        }
        SIMD
        for (int x = 0; x < n; x++) {
                uint16_t v = code[x];
                v ^= v >> 1;
                v ^= v >> 2;
                v ^= v >> 4;
                v ^= v >> 8;
                code[x] = v;
        }
}

/* Axis a's block result into the combine step's rows: the code, the weak-bit count and the
 * smallest contrast, widened. */
static __attribute__((noinline, CLONES)) void u8_axis_out(
                int n, const uint16_t *restrict cd16, const uint8_t *restrict wk8, const uint8_t *restrict cm8,
                uint32_t *restrict code, uint32_t *restrict weak, float *restrict cmin) {
        SIMD
        for (int x = 0; x < n; x++) {
                code[x] = cd16[x];
                weak[x] = wk8[x];
                cmin[x] = cm8[x];
        }
}

/* ---- the byte-lane block in explicit vectors (x86) ----------------------------------------
 * gray_u8_planes as gcc vectorizes it keeps the block's state (code bits, weak count, smallest
 * contrast, maximum) in memory: every plane loads and stores four arrays and loads four
 * threshold arrays, ≈ 46 instructions per 32 pixels and plane. Here one vector of pixels
 * runs through every plane of the axis with its state in registers (≈ 26). Same decisions:
 * for the thresholds t_d = ⌊L_d⌋ ≤ t_g = ⌈L_g⌉ (when L_d ≤ L_g, i.e. the rules apply) the
 * two classifying rules reduce to min(p, p̄) ≤ t_d and max(p, p̄) ≥ t_g (with p > p̄ the
 * first, p ≤ t_d ≤ t_g ≤ p̄, cannot hold, nor the second with p < p̄), and L_d > L_g (or
 * !robust: every bit classified) becomes t_d = 255, t_g = 0, which always hold. Unsigned
 * byte comparisons as min/max and equality (SSE2 has no unsigned compare); the bit p > p̄ as
 * min(p − min(p, p̄), 1). Instantiated for AVX-512BW (64 lanes), AVX2 (32) and SSE2 (16),
 * chosen by the CPU at run time (IMPASTO_SL_NO_CLONES: SSE2 alone); integer operations
 * only, so every width gives the same bytes. */
#if defined(__x86_64__) && defined(__SSE2__) && defined(__GNUC__)
#define U8_SIMD 1
#include <immintrin.h>

/* VT: vector type, VW: its bytes; LD/ST unaligned load/store; the rest byte-wise ops. */
#define DEFINE_U8_BLOCK(SFX, ATTR, VT, VW, LD, ST, MINU, MAXU, SUB, SUBS, ADD, OR, ANDN, CMPEQ, SET1) \
/* L_max / L_min over the frames D[0..nd) for pixels [0, nv), nv a multiple of VW. */              \
static ATTR void u8_maxima_##SFX(const uint8_t *const *D, int nd, int nv, uint8_t *restrict mx,   \
                                 uint8_t *restrict mn) {                                          \
        for (int x = 0; x < nv; x += VW) {                                                        \
                VT hi = LD((const VT *) (const void *) (D[0] + x)), lo = hi;                       \
                for (int i = 1; i < nd; i++) {                                                     \
                        VT v = LD((const VT *) (const void *) (D[i] + x));                         \
                        hi = MAXU(hi, v);                                                          \
                        lo = MINU(lo, v);                                                          \
                }                                                                                  \
                ST((VT *) (void *) (mx + x), hi);                                                  \
                ST((VT *) (void *) (mn + x), lo);                                                  \
        }                                                                                          \
}                                                                                                  \
                                                                                                   \
/* Every plane k < nbits (frames P[k], Q[k]) for pixels [0, nv): g0/g1 (planes 0–7 / 8–15),   \
 * wk, cm written, hi raised; the arrays as gray_u8_planes leaves them. A bit is decided when    \
 * min(p, p̄) ≤ t_d, max(p, p̄) ≥ t_g and |p − p̄| ≥ minc, i.e. when the three saturating      \
 * differences are all 0; min(p, p̄) ≥ sat (both clipped) is folded into t_d (≤ sat − 1), and   \
 * what no sample can pass (⌈L_g⌉ > 255, minc > 255, sat ≤ 0) into a per-pixel "never" mask.   \
 * Decided bits are counted; the weak count is nbits minus that. */                            \
static ATTR void u8_axis_##SFX(const uint8_t *const *P, const uint8_t *const *Q,                   \
                               const uint8_t *const *Pn, const uint8_t *const *Qn, int nbits,     \
                               int nv, const uint8_t *restrict td8, const uint8_t *restrict tg8,  \
                               const uint8_t *restrict tgok, const uint8_t *restrict alw8,        \
                               struct u8_lim lim, uint8_t *restrict g0o, uint8_t *restrict g1o,   \
                               uint8_t *restrict wko, uint8_t *restrict cmo, uint8_t *restrict hio) { \
        const VT zero = SET1(0), one = SET1(1), ff = SET1(-1), nb = SET1((char) nbits);            \
        const VT minc = SET1((char) lim.minc);                                                     \
        const VT tdmax = SET1((char) (lim.sat_on && lim.sat ? lim.sat - 1 : 255));                 \
        const VT never = lim.weak_all || (lim.sat_on && !lim.sat) ? ff : zero;                     \
        for (int x = 0; x < nv; x += VW) {                                                        \
                const VT alw = SUB(zero, LD((const VT *) (const void *) (alw8 + x)));               \
                const VT td = MINU(OR(LD((const VT *) (const void *) (td8 + x)), alw), tdmax);     \
                const VT tg = ANDN(alw, LD((const VT *) (const void *) (tg8 + x)));                \
                const VT ok = OR(alw, SUB(zero, LD((const VT *) (const void *) (tgok + x))));      \
                const VT no = OR(ANDN(ok, ff), never);                                             \
                VT g[2] = { zero, zero }, good = zero, cm = ff;                                    \
                VT hi = LD((const VT *) (const void *) (hio + x));                                 \
                for (int h = 0, k = 0; h < 2; h++) {                                               \
                        VT gh = zero;                                                              \
                        for (; k < nbits && k < 8 * (h + 1); k++) {                                \
                                if (Pn && !(x & 63)) {                                             \
                                        __builtin_prefetch(Pn[k] + x);                             \
                                        __builtin_prefetch(Qn[k] + x);                             \
                                }                                                                  \
                                const VT p = LD((const VT *) (const void *) (P[k] + x));           \
                                const VT q = LD((const VT *) (const void *) (Q[k] + x));           \
                                const VT lo = MINU(p, q), up = MAXU(p, q), ad = SUB(up, lo);      \
                                gh = OR(ADD(gh, gh), MINU(SUB(p, lo), one));                       \
                                const VT miss = OR(OR(SUBS(lo, td), SUBS(tg, up)), OR(SUBS(minc, ad), no)); \
                                good = SUB(good, CMPEQ(miss, zero));                               \
                                cm = MINU(cm, ad);                                                 \
                                hi = MAXU(hi, up);                                                 \
                        }                                                                          \
                        g[h] = gh;                                                                 \
                }                                                                                  \
                ST((VT *) (void *) (g0o + x), g[0]);                                               \
                ST((VT *) (void *) (g1o + x), g[1]);                                               \
                ST((VT *) (void *) (wko + x), SUB(nb, good));                                      \
                ST((VT *) (void *) (cmo + x), cm);                                                 \
                ST((VT *) (void *) (hio + x), hi);                                                 \
        }                                                                                          \
}

DEFINE_U8_BLOCK(sse2, , __m128i, 16, _mm_loadu_si128, _mm_storeu_si128, _mm_min_epu8, _mm_max_epu8,
                _mm_sub_epi8, _mm_subs_epu8, _mm_add_epi8, _mm_or_si128, _mm_andnot_si128,
                _mm_cmpeq_epi8, _mm_set1_epi8)
#if !defined(IMPASTO_SL_NO_CLONES) && !defined(__clang__)
#define U8_AVX2 1
DEFINE_U8_BLOCK(avx2, __attribute__((target("avx2"))), __m256i, 32, _mm256_loadu_si256,
                _mm256_storeu_si256, _mm256_min_epu8, _mm256_max_epu8, _mm256_sub_epi8,
                _mm256_subs_epu8, _mm256_add_epi8, _mm256_or_si256, _mm256_andnot_si256,
                _mm256_cmpeq_epi8, _mm256_set1_epi8)
/* AVX-512BW: 64 lanes; its byte compare gives a mask, made a vector again. */
#define U8_AVX512 1
static inline __attribute__((target("avx512bw"), always_inline)) __m512i cmpeq512(__m512i a, __m512i b) {
        return _mm512_movm_epi8(_mm512_cmpeq_epi8_mask(a, b));
}
DEFINE_U8_BLOCK(avx512, __attribute__((target("avx512bw"))), __m512i, 64, _mm512_loadu_si512,
                _mm512_storeu_si512, _mm512_min_epu8, _mm512_max_epu8, _mm512_sub_epi8,
                _mm512_subs_epu8, _mm512_add_epi8, _mm512_or_si512, _mm512_andnot_si512,
                cmpeq512, _mm512_set1_epi8)
#endif

/* The vector width in use and its kernels: AVX-512BW, else AVX2, where the CPU has it. */
struct u8_kernels {
        int vw;
        void (*maxima)(const uint8_t *const *, int, int, uint8_t *, uint8_t *);
        void (*axis)(const uint8_t *const *, const uint8_t *const *, const uint8_t *const *,
                     const uint8_t *const *, int, int, const uint8_t *,
                     const uint8_t *, const uint8_t *, const uint8_t *, struct u8_lim, uint8_t *,
                     uint8_t *, uint8_t *, uint8_t *, uint8_t *);
};

static struct u8_kernels u8_kernels(void) {
#ifdef U8_AVX512
        if (__builtin_cpu_supports("avx512bw"))
                return (struct u8_kernels) { 64, u8_maxima_avx512, u8_axis_avx512 };
#endif
#ifdef U8_AVX2
        if (__builtin_cpu_supports("avx2"))
                return (struct u8_kernels) { 32, u8_maxima_avx2, u8_axis_avx2 };
#endif
        return (struct u8_kernels) { 16, u8_maxima_sse2, u8_axis_sse2 };
}
#endif

/* ---- row bands -----------------------------------------------------------------------
 * A thread decodes rows in bands of BAND_ROWS and knows the band it decodes next (claimed
 * when it starts the current one). While it decodes the current band, the next band's frame
 * rows are prefetched frame by frame: chunk i of the next band (nframes × rows of them, one
 * frame row each, frame-major) is frame i / rows, row i % rows, and row j of the current
 * band prefetches its share of the chunks. The 40 Gray frames then arrive as a few frames'
 * consecutive rows at a time instead of one row of each of 42 frames (the read pattern of
 * a row-by-row decode, 42 interleaved streams). */
#define BAND_ROWS 8

struct band {
        int next0, next_rows;   /* the thread's next band: first row, rows (0: none) */
        int j, rows;            /* the row of the current band being decoded, of rows */
};

/* The frames a byte-lane row reads, in the order their chunks are prefetched: the Gray
 * planes and their inverses (axis 0, then 1: the kernels' prefetch slots), white, black. */
static int band_frames(const struct plan *pl, int *f) {
        int n = 0;
        for (int a = 0; a < 2; a++)
                for (int k = 0; k < pl->ax[a].nbits; k++) {
                        f[n++] = pl->ax[a].p[k];
                        f[n++] = pl->ax[a].q[k];
                }
        f[n++] = pl->white;
        f[n++] = pl->black;
        return n;
}

/* Row j's share of the next band's chunks: the first ns into slot[] (row pointers, for the
 * kernels to prefetch as they go; slots past the share repeat its last chunk), the rest
 * prefetched here. Returns false when there is nothing to prefetch (no next band). */
static bool band_slots(const struct ctx *c, const struct band *bd, const uint8_t **slot, int ns) {
        if (!bd || !bd->next_rows)
                return false;
        const struct imp_image *const *im = c->in->images;
        int f[4 * MAX_BITS + 2];
        const int nf = band_frames(c->pl, f), total = nf * bd->next_rows;
        const int i0 = (int) ((long) total * bd->j / bd->rows), i1 = (int) ((long) total * (bd->j + 1) / bd->rows);
        if (i1 <= i0)
                return false;
        const size_t w = (size_t) c->pl->width;
        for (int s = 0, i = i0; i < i1 || s < ns; i++) {
                const int ii = IMP_MIN(i, i1 - 1);
                const uint8_t *row = (const uint8_t *) imp_image_row(im[f[ii / bd->next_rows]],
                                                                     bd->next0 + ii % bd->next_rows);
                if (s < ns) {
                        slot[s++] = row;
                        continue;
                }
                for (size_t x = 0; x < w; x += 64)
                        __builtin_prefetch(row + x);
        }
        return true;
}

/* L_max / L_min (mx, mn) over the frames giving them, and hi8 = white, for n pixels from x0:
 * the first nv (a multiple of the vector width) in explicit vectors. */
static void u8_block_maxima(const struct ctx *c, int y, int x0, int n, int nv, uint8_t *restrict mx,
                            uint8_t *restrict mn, uint8_t *restrict hi8) {
        const struct plan *pl = c->pl;
        const struct imp_image *const *im = c->in->images;
        const uint8_t *D[4 * MAX_BITS];
        for (int i = 0; i < pl->ndg; i++)
                D[i] = (const uint8_t *) imp_image_row(im[pl->dg[i]], y) + x0;
        const uint8_t *wr = (const uint8_t *) imp_image_row(im[pl->white], y) + x0;
#ifdef U8_SIMD
        if (nv)
                u8_kernels().maxima(D, pl->ndg, nv, mx, mn);
#endif
        for (int x = nv; x < n; x++)
                mx[x] = mn[x] = D[0][x];
        for (int i = 1; i < pl->ndg; i++)
                for (int x = nv; x < n; x++) {
                        mx[x] = mx[x] > D[i][x] ? mx[x] : D[i][x];
                        mn[x] = mn[x] < D[i][x] ? mn[x] : D[i][x];
                }
        memcpy(hi8, wr, (size_t) n);    /* the black frame never counted here */
}

/* Every Gray plane of axis ax over n pixels from x0 into g8, wk8, cm8 (hi8 raised): the
 * first nv in explicit vectors, the rest by gray_u8_plane. */
static void u8_block_axis(const struct ctx *c, const struct axis_plan *ax, int y, int x0, int n, int nv,
                          const uint8_t *td8, const uint8_t *tg8, const uint8_t *tgok, const uint8_t *alw8,
                          struct u8_lim lim, const uint8_t *const *slot, uint8_t (*g8)[IBLK], uint8_t *wk8,
                          uint8_t *cm8, uint8_t *hi8) {
        const struct imp_image *const *im = c->in->images;
#ifdef U8_SIMD
        if (nv) {
                /* the next band's chunks (slot: 2 rows a plane, band_slots) are prefetched as
                 * the kernel goes (Pn, Qn) */
                const uint8_t *P[MAX_BITS], *Q[MAX_BITS], *Pn[MAX_BITS], *Qn[MAX_BITS];
                for (int k = 0; k < ax->nbits; k++) {
                        P[k] = (const uint8_t *) imp_image_row(im[ax->p[k]], y) + x0;
                        Q[k] = (const uint8_t *) imp_image_row(im[ax->q[k]], y) + x0;
                        if (slot) {
                                Pn[k] = slot[2 * k] + x0;
                                Qn[k] = slot[2 * k + 1] + x0;
                        }
                }
                u8_kernels().axis(P, Q, slot ? Pn : NULL, slot ? Qn : NULL, ax->nbits, nv, td8, tg8, tgok,
                                  alw8, lim, g8[0], g8[1], wk8, cm8, hi8);
        }
        if (nv < n)
                prefetch_next_rows(im, ax, y, x0 + nv, n - nv);
#else
        prefetch_next_rows(im, ax, y, x0, n);
#endif
        if (nv == n)
                return;
        for (int x = nv; x < n; x++) {
                g8[0][x] = g8[1][x] = wk8[x] = 0;
                cm8[x] = 255;
        }
        gray_u8_planes(im, ax, y, x0 + nv, n - nv, td8 + nv, tg8 + nv, alw8 + nv, tgok + nv, lim, g8[0] + nv,
                       g8[1] + nv, wk8 + nv, cm8 + nv, hi8 + nv);
}

/* ---- the combine step of a Gray-only byte-lane row, straight from the block's bytes -----
 * combine_gray_row as gcc vectorizes it reads eleven 32-bit rows (the block's bytes widened
 * by u8_axis_out and gray_u8_row) and costs ≈ 29 instructions a pixel; here eight pixels
 * at a time in GCC's generic vectors from the bytes and 16-bit codes themselves. The same
 * operations on the same float values (the integer tests are exact twins: for an integer
 * v, v > t ⇔ v > ⌊t⌋ and v ≥ s ⇔ v ≥ ⌈s⌉), so every map and count is bit-identical. */
typedef uint16_t v8s __attribute__((vector_size(16)));

struct comb_in {                /* one block's inputs, pixel 0 at the block's start */
        const uint8_t *w, *b, *hi, *cm[2], *wk[2];
        const uint16_t *cd[2];
        const float *ld;
};

struct comb_k {                 /* the row's constants */
        int32_t thr, sat, ext[2];
        float minc_d, ob, q[2], sw[2], ss[2];   /* 1 − b; σ of a weak / a sure Gray centre */
        int32_t robust, rej[2];
};

struct comb_out {
        float *ox, *oy;
        uint16_t *oc, *os, *of;        /* confidence, σ: imp_sl_conf16, imp_sl_sigma16 */
};

#define BIT8(m, f) ((m) & (int32_t) (f))

/* The combine step N pixels a step in GCC's generic vectors VF, VI (N floats, int32) and VS (N
 * uint16): comb##SFX and combine_u8_block##SFX, built with ATTR. Every operation lane by
 * lane, so every width gives the same values. */
#define DEFINE_COMB(SFX, ATTR, IATTR, N, VF, VI, VS, LD, SEL) \
/* Pixels [x, x + N); cnt: −(count) per lane (masks are −1), in the order of counts[]. */                \
static inline __attribute__((always_inline)) IATTR void comb##SFX(const struct comb_in *in, const struct comb_k *k, \
                                                         int x, const struct comb_out *o, VI cnt[6]) {   \
        const VF zero = { 0 }, one = zero + 1.0f;                                                        \
        VF ld;                                                                                           \
        memcpy(&ld, in->ld + x, sizeof ld);                                                              \
        const VI shadow = (LD(in->w + x) - LD(in->b + x) <= k->thr) | ((ld < k->minc_d) & k->robust);    \
        const VF span = ld * k->ob;                                                                      \
        const VF sd = SEL(span > zero, span, zero + INFINITY);                                           \
        VI ok[2], und[2], wb[2], oor[2];                                                                 \
        VF ca[2], pos[2], sg[2];                                                                         \
_Pragma("GCC unroll 2")                                                                                     \
        for (int a = 0; a < 2; a++) {                                                                    \
                const VI wk = LD(in->wk[a] + x), cd = LD(in->cd[a] + x);                                 \
                und[a] = wk > GRAY_WEAK_ALLOWED;                                                         \
                wb[a] = wk == 1;                                                                         \
                oor[a] = cd >= k->ext[a];                                                                \
                ok[a] = ~(shadow | und[a] | oor[a]);                                                     \
                const VF v = __builtin_convertvector(LD(in->cm[a] + x), VF) / sd;                        \
                const VF t = SEL(v > zero, v, zero);                                                     \
                ca[a] = SEL(wb[a], zero + 0.5f, one) * SEL(t < one, t, one);                             \
                pos[a] = SEL(ok[a], (__builtin_convertvector(cd, VF) + 0.5f) * k->q[a],                  \
                              zero + IMP_SL_INVALID_COORD);                                              \
                sg[a] = SEL(ok[a], SEL(wb[a], zero + k->sw[a], zero + k->ss[a]), zero);                  \
        }                                                                                                \
        VF conf = SEL(ok[0], SEL(one < ca[0], one, ca[0]), one);                                         \
        conf = SEL(ok[1], SEL(conf < ca[1], conf, ca[1]), conf);                                         \
        conf = SEL(ok[0] | ok[1], conf, zero);                                                           \
        const VF os = SEL(sg[0] > sg[1], sg[0], sg[1]);                                                  \
        const VI sat = LD(in->hi + x) >= k->sat;                                                         \
        const VI f = BIT8(shadow, IMP_SL_SHADOW) | BIT8(sat, IMP_SL_SATURATED) |                         \
                      BIT8(und[0] | und[1], IMP_SL_UNDECODABLE) | BIT8(wb[0] | wb[1], IMP_SL_WEAK_BIT) | \
                      BIT8(oor[0] | oor[1], IMP_SL_OUT_OF_RANGE) | BIT8(ok[0], IMP_SL_VALID_X) |         \
                      BIT8(ok[1], IMP_SL_VALID_Y) |                                                      \
                      BIT8((ok[0] & k->rej[0]) | (ok[1] & k->rej[1]), IMP_SL_PHASE_REJECTED);            \
        const VS f16 = __builtin_convertvector(f, VS);                                                   \
        /* imp_sl_conf16 (conf ∈ [0, 1] already) and imp_sl_sigma16 (os ≥ 0), lane by lane */            \
        const VS c16 = __builtin_convertvector(__builtin_convertvector(                                  \
                conf * (zero + (float) IMP_SL_CONF_ONE) + 0.5f, VI), VS);                                \
        const VI ub = (VI) os;                                                                           \
        const VS s16 = __builtin_convertvector((ub + 0x7fff + ((ub >> 16) & 1)) >> 16, VS);              \
        memcpy(o->ox + x, &pos[0], sizeof pos[0]);                                                       \
        memcpy(o->oy + x, &pos[1], sizeof pos[1]);                                                       \
        memcpy(o->oc + x, &c16, sizeof c16);                                                             \
        memcpy(o->os + x, &s16, sizeof s16);                                                             \
        memcpy(o->of + x, &f16, sizeof f16);                                                             \
        cnt[0] += ok[0];                                                                                 \
        cnt[1] += ok[1];                                                                                 \
        cnt[2] += ok[0] & ok[1];                                                                         \
        cnt[3] += shadow;                                                                                \
        cnt[4] += sat;                                                                                   \
        cnt[5] += wb[0] | wb[1];                                                                         \
}                                                                                                        \
                                                                                                         \
/* Pixels [0, n) of a block; the last n % N through zero-padded copies of their inputs. */               \
static __attribute__((noinline, optimize("no-trapping-math"))) ATTR void combine_u8_block##SFX(          \
                const struct comb_in *inp, const struct comb_k *kp, int n, const struct comb_out *op,    \
                size_t counts[8]) {                                                                      \
        /* local copies: gcc then keeps the pointers and constants in registers instead of               \
         * reloading them after every store */                                                           \
        const struct comb_in lin = *inp, *in = &lin;                                                     \
        const struct comb_k lk = *kp, *k = &lk;                                                          \
        const struct comb_out lo = *op, *o = &lo;                                                        \
        VI cnt[6] = { { 0 } };                                                                           \
        int x = 0;                                                                                       \
        for (; x + N <= n; x += N)                                                                       \
                comb##SFX(in, k, x, o, cnt);                                                             \
        if (x < n) {                                                                                     \
                const size_t m = (size_t) (n - x);                                                       \
                uint8_t bw[N] = { 0 }, bb[N] = { 0 }, bh[N] = { 0 }, bc[2][N] = { { 0 } }, bk[2][N] = { { 0 } }; \
                uint16_t bd[2][N] = { { 0 } }, tf[N], tc[N], ts[N];                                      \
                float bl[N] = { 0 }, tx[N], ty[N];                                                       \
                memcpy(bw, in->w + x, m);                                                                \
                memcpy(bb, in->b + x, m);                                                                \
                memcpy(bh, in->hi + x, m);                                                               \
                memcpy(bl, in->ld + x, m * sizeof *bl);                                                  \
                for (int a = 0; a < 2; a++) {                                                            \
                        memcpy(bc[a], in->cm[a] + x, m);                                                 \
                        memcpy(bk[a], in->wk[a] + x, m);                                                 \
                        memcpy(bd[a], in->cd[a] + x, m * sizeof **bd);                                   \
                }                                                                                        \
                const struct comb_in t = { bw, bb, bh, { bc[0], bc[1] }, { bk[0], bk[1] }, { bd[0], bd[1] }, bl }; \
                const struct comb_out to = { tx, ty, tc, ts, tf };                                       \
                VI tcnt[6] = { { 0 } };                                                                  \
                comb##SFX(&t, k, 0, &to, tcnt);                                                          \
                memcpy(o->ox + x, tx, m * sizeof *tx);                                                   \
                memcpy(o->oy + x, ty, m * sizeof *ty);                                                   \
                memcpy(o->oc + x, tc, m * sizeof *tc);                                                   \
                memcpy(o->os + x, ts, m * sizeof *ts);                                                   \
                memcpy(o->of + x, tf, m * sizeof *tf);                                                   \
                for (int i = 0; i < 6; i++)     /* only the m lanes that are pixels */                   \
                        for (size_t l = 0; l < m; l++)                                                   \
                                cnt[i][l] += tcnt[i][l];                                                 \
        }                                                                                                \
        for (int i = 0; i < 6; i++) {                                                                    \
                int32_t s = 0;                                                                           \
                for (int l = 0; l < N; l++)                                                              \
                        s -= cnt[i][l];                                                                  \
                counts[i] += (size_t) s;                                                                 \
        }                                                                                                \
}

DEFINE_COMB(_v8, __attribute__((CLONES)), , 8, v8f, v8i, v8s, LD8, SEL8)
#ifdef U8_AVX512
/* AVX-512: 16 pixels a step. Its target brings FMA, and gcc contracts a·b + c by default:
 * fp-contract=off keeps every product and sum rounded on its own, as in the other widths. */
#define AVX512_ATTR __attribute__((target("avx512bw"), optimize("fp-contract=off")))
typedef float v16f __attribute__((vector_size(64)));
typedef int32_t v16i __attribute__((vector_size(64)));
typedef uint16_t v16s __attribute__((vector_size(32)));
#define LD16(p) ((v16i) { (p)[0], (p)[1], (p)[2], (p)[3], (p)[4], (p)[5], (p)[6], (p)[7], (p)[8], (p)[9], \
                          (p)[10], (p)[11], (p)[12], (p)[13], (p)[14], (p)[15] })
#define SEL16(m, a, b) ((v16f) (((v16i) (a) & (m)) | ((v16i) (b) & ~(m))))
DEFINE_COMB(_v16, AVX512_ATTR, AVX512_ATTR, 16, v16f, v16i, v16s, LD16, SEL16)
DEFINE_THR(_v16, AVX512_ATTR, AVX512_ATTR, 16, v16f, v16i, LD16, SEL16)
#endif

/* The constants of combine_u8_block for this decode. */
static struct comb_k comb_constants(const struct ctx *c) {
        const struct plan *pl = c->pl;
        const float thr = (float) c->p->shadow_threshold;
        struct comb_k k = {
                .thr = !(thr < 1000.0f) ? 1000 : !(thr > -1000.0f) ? -1000 : (int32_t) floorf(thr),
                .sat = int_ceil_clamp(c->sat, -INT16_MAX, INT16_MAX),
                .minc_d = (float) c->p->min_direct, .ob = 1 - c->b,
                .robust = c->p->robust ? -1 : 0,
        };
        for (int a = 0; a < 2; a++) {
                k.ext[a] = pl->ax[a].ncodes;
                k.q[a] = pl->ax[a].quantum;
                k.sw[a] = WEAK_SIGMA * pl->ax[a].quantum;
                k.ss[a] = INV_SQRT12 * pl->ax[a].quantum;
                k.rej[a] = (c->rejected >> a & 1) ? -1 : 0;
        }
        return k;
}

/* Whether a row's combine step runs in gray_u8_row (combine_u8_block): a Gray-only byte-lane
 * row with both axes. */
static bool u8_combines(const struct plan *pl) {
        return pl->ax[0].nbits && pl->ax[1].nbits && !pl->ax[0].nphase && !pl->ax[1].nphase;
}

/* counts NULL: the block's results into the combine step's rows (R_CODE, R_WEAK, R_CMIN, R_HI,
 * R_WHITE, R_BLACK); else (u8_combines) combined into o (row y's maps) and counts. */
static __attribute__((noinline, optimize("no-trapping-math"), CLONES)) void gray_u8_row(
                const struct ctx *c, int y, float **R, int w, const struct comb_out *o, size_t counts[8],
                const struct band *bd) {
        const struct plan *pl = c->pl;
        const struct imp_image *const *im = c->in->images;
        const uint8_t *slot[4 * MAX_BITS];
        const bool pf = band_slots(c, bd, slot, 2 * (pl->ax[0].nbits + pl->ax[1].nbits));
        const struct u8_lim lim = u8_limits((int16_t) int_ceil_clamp((float) c->p->min_bit_contrast, 0, INT16_MAX),
                                            (int16_t) int_ceil_clamp(c->sat, -INT16_MAX, INT16_MAX));
        const float b = c->b, k1 = 1.0f / (1.0f - b), k2 = 2.0f / (1.0f - b * b);
        const uint8_t always = c->p->robust ? 0 : 1;
        const struct comb_k ck = comb_constants(c);
#ifdef U8_SIMD
        const int vw = u8_kernels().vw;
#else
        const int vw = 0;
#endif
        for (int x0 = 0; x0 < w; x0 += IBLK) {
                const int n = IMP_MIN(IBLK, w - x0), nv = vw ? n - n % vw : 0;
                uint8_t mx[IBLK], mn[IBLK], td8[IBLK], tg8[IBLK], tgok[IBLK], alw8[IBLK], hi8[IBLK];
                uint8_t g8[2][IBLK], wk8[2][IBLK], cm8[2][IBLK];
                uint16_t cd16[2][IBLK];
                u8_block_maxima(c, y, x0, n, nv, mx, mn, hi8);
#ifdef U8_AVX512
                if (vw == 64)
                        u8_thresholds_v16(n, mx, mn, k1, k2, b, always, R[R_LD] + x0, R[R_LG] + x0, td8, tg8, tgok,
                                          alw8);
                else
#endif
                        u8_thresholds_v8(n, mx, mn, k1, k2, b, always, R[R_LD] + x0, R[R_LG] + x0, td8, tg8, tgok,
                                         alw8);
                for (int a = 0; a < 2; a++) {
                        const struct axis_plan *ax = &pl->ax[a];
                        if (!ax->nbits)
                                continue;
                        u8_block_axis(c, ax, y, x0, n, nv, td8, tg8, tgok, alw8, lim,
                                      pf ? slot + (a ? 2 * pl->ax[0].nbits : 0) : NULL, g8, wk8[a], cm8[a], hi8);
                        u8_axis_code(n, ax->nbits, g8[0], g8[1], cd16[a]);
                        if (!counts)
                                u8_axis_out(n, cd16[a], wk8[a], cm8[a], (uint32_t *) R[R_CODE0 + a] + x0,
                                            (uint32_t *) R[R_WEAK0 + a] + x0, R[R_CMIN0 + a] + x0);
                }
                const uint8_t *wr = (const uint8_t *) imp_image_row(im[pl->white], y) + x0;
                const uint8_t *br = (const uint8_t *) imp_image_row(im[pl->black], y) + x0;
                if (counts) {
                        const struct comb_in in = { wr, br, hi8, { cm8[0], cm8[1] }, { wk8[0], wk8[1] },
                                                    { cd16[0], cd16[1] }, R[R_LD] + x0 };
                        const struct comb_out ob = { o->ox + x0, o->oy + x0, o->oc + x0, o->os + x0, o->of + x0 };
#ifdef U8_AVX512
                        if (vw == 64)
                                combine_u8_block_v16(&in, &ck, n, &ob, counts);
                        else
#endif
                                combine_u8_block_v8(&in, &ck, n, &ob, counts);
                        continue;
                }
                float *restrict hr = R[R_HI] + x0, *restrict wf = R[R_WHITE] + x0, *restrict bf = R[R_BLACK] + x0;
                SIMD
                for (int x = 0; x < n; x++) {
                        hr[x] = hi8[x];
                        wf[x] = wr[x];
                        bf[x] = br[x];
                }
        }
}

/* Whether gray_u8_row applies: u8 frames (the integer path) with white, black and inverses. */
static bool u8_row_applies(const struct plan *pl) {
        return pl->white >= 0 && pl->black >= 0 && (!pl->ax[0].nbits || pl->ax[0].inverse) &&
               (!pl->ax[1].nbits || pl->ax[1].inverse);
}

/* The direct and global maps of a Gray-only row into od, og (og NULL with direct_only;
 * modulation 0: no phase, om, NULL when streamed: stream_zero writes it); not called with
 * coords_only. */
static void light_maps_row(float *restrict od, float *restrict og, float *restrict om, const float *restrict ld,
                           const float *restrict lg, int w) {
        SIMD
        for (int x = 0; x < w; x++)
                od[x] = isfinite(ld[x]) ? ld[x] : 0.0f;
        if (!og)
                return;
        SIMD
        for (int x = 0; x < w; x++)
                og[x] = isfinite(lg[x]) ? lg[x] : 0.0f;
        if (om)
                memset(om, 0, (size_t) w * sizeof *om);
}

/* ---- streamed rows ----------------------------------------------------------------------
 * A result larger than the last-level cache is written to memory anyway: plain stores first
 * read every line they fill (read for ownership), so the 26 bytes a pixel written cost 52 of
 * memory traffic. A Gray row's maps are built in the thread's scratch rows (R_O*, in L2) and
 * copied with non-temporal stores, which fill whole lines without reading them: the same
 * bytes, 26 fewer a pixel over the memory bus (68 instead of 94 with the 42 B a pixel of
 * frames read). Below STREAM_MIN_BYTES the result may stay cached for its reader, and is
 * written in place. */
#define STREAM_MIN_BYTES (16u << 20)

#ifdef U8_AVX2
/* 32 bytes a store, unrolled: the copy costs half the instructions of the 16-byte loop. */
static __attribute__((target("avx2"))) void stream_body_avx2(char *d, const char *s, size_t bytes) {
        for (; bytes >= 64; d += 64, s += 64, bytes -= 64) {
                __m256i a = _mm256_loadu_si256((const __m256i *) (const void *) s);
                __m256i b = _mm256_loadu_si256((const __m256i *) (const void *) (s + 32));
                _mm256_stream_si256((__m256i *) (void *) d, a);
                _mm256_stream_si256((__m256i *) (void *) (d + 32), b);
        }
        memcpy(d, s, bytes);    /* < 64 bytes; whole rows of 1280 px have none */
}
#endif

static void stream_row(void *dst, const void *src, size_t bytes) {
#if defined(__SSE2__)
        char *d = dst;
        const char *s = src;
        size_t head = (size_t) (-(uintptr_t) d & 15);
#ifdef U8_AVX2
        const bool avx2 = __builtin_cpu_supports("avx2");
        if (avx2)
                head = (size_t) (-(uintptr_t) d & 31);
#endif
        head = head < bytes ? head : bytes;
        memcpy(d, s, head);
        d += head, s += head, bytes -= head;
#ifdef U8_AVX2
        if (avx2) {
                stream_body_avx2(d, s, bytes);
                return;
        }
#endif
        for (; bytes >= 16; d += 16, s += 16, bytes -= 16)
                _mm_stream_si128((__m128i *) (void *) d, _mm_loadu_si128((const __m128i *) (const void *) s));
        memcpy(d, s, bytes);
#else
        memcpy(dst, src, bytes);
#endif
}

static void stream_zero(void *dst, size_t bytes) {
#if defined(__SSE2__)
        char *d = dst;
        size_t head = (size_t) (-(uintptr_t) d & 15);
        head = head < bytes ? head : bytes;
        memset(d, 0, head);
        d += head, bytes -= head;
        for (; bytes >= 16; d += 16, bytes -= 16)
                _mm_stream_si128((__m128i *) (void *) d, _mm_setzero_si128());
        memset(d, 0, bytes);
#else
        memset(dst, 0, bytes);
#endif
}

/* Row y's maps from R_O* to the result (c->stream); light: direct and global from R_LD, R_LG
 * as they are (finite: gray_u8_row's), else from R_OD, R_OG (light_maps_row). */
static void stream_gray_row(const struct ctx *c, int y, float **R, int w, bool light) {
        struct imp_sl_result *res = c->res;
        const size_t off = (size_t) y * w, fb = (size_t) w * sizeof(float);
        stream_row(res->proj_x + off, R[R_OX], fb);
        stream_row(res->proj_y + off, R[R_OY], fb);
        stream_row(res->confidence + off, R[R_OC], (size_t) w * sizeof(uint16_t));
        stream_row(res->sigma_px + off, R[R_OS], (size_t) w * sizeof(uint16_t));
        stream_row(res->flags + off, R[R_OF], (size_t) w * sizeof(uint16_t));
        if (res->direct)
                stream_row(res->direct + off, R[light ? R_LD : R_OD], fb);
        if (res->global) {
                stream_row(res->global + off, R[light ? R_LG : R_OG], fb);
                stream_zero(res->modulation + off, fb);
        }
}

__attribute__((optimize("no-trapping-math"), CLONES))
static void combine_gray_row(const struct ctx *c, int y, float **R, int w, bool light, size_t counts[8]) {
        const struct plan *pl = c->pl;
        const struct imp_sl_params *p = c->p;
        const size_t off = (size_t) y * w;
        struct imp_sl_result *res = c->res;
        const bool st = c->stream;
        float *restrict ox = st ? R[R_OX] : res->proj_x + off, *restrict oy = st ? R[R_OY] : res->proj_y + off;
        uint16_t *restrict oc = st ? (uint16_t *) R[R_OC] : res->confidence + off;
        uint16_t *restrict os = st ? (uint16_t *) R[R_OS] : res->sigma_px + off;
        uint16_t *restrict of = st ? (uint16_t *) R[R_OF] : res->flags + off;
        const float *restrict wr = R[R_WHITE], *restrict br = R[R_BLACK], *restrict hi = R[R_HI];
        const float *restrict ld = R[R_LD], *restrict lg = R[R_LG];
        const float *restrict cm0 = R[R_CMIN0], *restrict cm1 = R[R_CMIN1];
        const uint32_t *restrict cd0 = (const uint32_t *) R[R_CODE0];
        const uint32_t *restrict cd1 = (const uint32_t *) R[R_CODE1];
        const uint32_t *restrict wk0 = (const uint32_t *) R[R_WEAK0];
        const uint32_t *restrict wk1 = (const uint32_t *) R[R_WEAK1];
        const float thr = (float) p->shadow_threshold, minc_d = (float) p->min_direct;
        const float b = c->b, sat = c->sat;
        const uint32_t has_wb = pl->white >= 0 && pl->black >= 0, robust = p->robust;
        const uint32_t g0 = pl->ax[0].nbits > 0, g1 = pl->ax[1].nbits > 0;
        const uint32_t ext0 = (uint32_t) pl->ax[0].ncodes, ext1 = (uint32_t) pl->ax[1].ncodes;
        const float q0 = pl->ax[0].quantum, q1 = pl->ax[1].quantum;
        const uint32_t rej0 = c->rejected & 1, rej1 = (c->rejected >> 1) & 1;
        uint32_t nx = 0, ny = 0, nxy = 0, nsh = 0, nsat = 0, nwk = 0;
#ifdef _OPENMP
#pragma omp simd reduction(+ : nx, ny, nxy, nsh, nsat, nwk)
#endif
        for (int x = 0; x < w; x++) {
                uint32_t shadow = (has_wb & !(wr[x] - br[x] > thr)) | (robust & !(ld[x] >= minc_d));
                float span = ld[x] * (1 - b);                   /* = L_max − L_min */
                uint32_t und0 = g0 & (wk0[x] > GRAY_WEAK_ALLOWED), und1 = g1 & (wk1[x] > GRAY_WEAK_ALLOWED);
                uint32_t wb0 = g0 & (wk0[x] != 0) & !und0, wb1 = g1 & (wk1[x] != 0) & !und1;
                uint32_t oor0 = g0 & (cd0[x] >= ext0), oor1 = g1 & (cd1[x] >= ext1);
                uint32_t ok0 = g0 & ((shadow | und0 | oor0) ^ 1), ok1 = g1 & ((shadow | und1 | oor1) ^ 1);
                /* span > 0 ? clamp01(cmin / span) : 0, without a branch (a conditional
                 * division blocks if-conversion): cmin ≥ 0, and cmin / ∞ is 0 (∞/∞ = NaN
                 * clamps to 0 too). */
                float sd = span > 0 ? span : INFINITY;
                float ca0 = (wb0 ? 0.5f : 1.0f) * CLAMP01(cm0[x] / sd);
                float ca1 = (wb1 ? 0.5f : 1.0f) * CLAMP01(cm1[x] / sd);
                float conf = 1.0f;
                conf = ok0 ? MINF(conf, ca0) : conf;
                conf = ok1 ? MINF(conf, ca1) : conf;
                uint32_t f = (shadow ? IMP_SL_SHADOW : 0) | (hi[x] >= sat ? IMP_SL_SATURATED : 0) |
                             ((und0 | und1) ? IMP_SL_UNDECODABLE : 0) |
                             ((wb0 | wb1) ? IMP_SL_WEAK_BIT : 0) |
                             ((oor0 | oor1) ? IMP_SL_OUT_OF_RANGE : 0) |
                             (ok0 ? IMP_SL_VALID_X : 0) | (ok1 ? IMP_SL_VALID_Y : 0) |
                             ((ok0 & rej0) | (ok1 & rej1) ? IMP_SL_PHASE_REJECTED : 0);
                ox[x] = ok0 ? ((float) (int32_t) cd0[x] + 0.5f) * q0 : IMP_SL_INVALID_COORD;
                oy[x] = ok1 ? ((float) (int32_t) cd1[x] + 0.5f) * q1 : IMP_SL_INVALID_COORD;
                oc[x] = imp_sl_conf16(ok0 | ok1 ? conf : 0.0f);
                /* Gray centres: q/√12, √(1/12 + 1/4)·q with a weak bit (one code off). */
                float s0 = ok0 ? (wb0 ? WEAK_SIGMA : INV_SQRT12) * q0 : 0.0f;
                float s1 = ok1 ? (wb1 ? WEAK_SIGMA : INV_SQRT12) * q1 : 0.0f;
                os[x] = imp_sl_sigma16(MAXF(s0, s1));
                of[x] = (uint16_t) f;
                nx += ok0;
                ny += ok1;
                nxy += ok0 & ok1;
                nsh += shadow;
                nsat += hi[x] >= sat;
                nwk += wb0 | wb1;
        }
        counts[0] += nx;
        counts[1] += ny;
        counts[2] += nxy;
        counts[3] += nsh;
        counts[4] += nsat;
        counts[5] += nwk;
        if (res->direct && !(st && light))
                light_maps_row(st ? R[R_OD] : res->direct + off,
                               !res->global ? NULL : st ? R[R_OG] : res->global + off,
                               st ? NULL : res->modulation + off, ld, lg, w);
}

/* The phase's disagreement with the Gray code on one row: Σ (u/q − (code + ½))² (q the
 * code's quantum) and its count per axis, over valid pixels refined by phase whose Gray
 * bits were all decided. Pixels whose phase left its cell are rejected one by one and do
 * not count: a band of them (a reflection, a clipped patch) must not condemn the phase of
 * the whole axis; a phase that is poor everywhere still shows within the cells. */
static void phase_stats_row(const struct ctx *c, int y, float **R, double st[4]) {
        const struct imp_sl_result *res = c->res;
        const size_t off = (size_t) y * res->width;
        for (int a = 0; a < 2; a++) {
                const struct axis_plan *ax = &c->pl->ax[a];
                if (!ax->nbits || !ax->nphase)
                        continue;
                const uint32_t *code = (const uint32_t *) R[R_CODE0 + a];
                const uint32_t *weak = (const uint32_t *) R[R_WEAK0 + a];
                const uint32_t *pst = (const uint32_t *) R[R_PCONF0 + a];
                const float *pos = R[R_POS0 + a];
                const uint16_t need = a == 0 ? IMP_SL_VALID_X : IMP_SL_VALID_Y;
                double s2 = 0, n = 0;
                for (int x = 0; x < res->width; x++)
                        if ((res->flags[off + x] & need) && !weak[x] &&
                            !(pst[x] & (PST_LOW_MOD | PST_DISAGREE | PST_OUTSIDE_CELL))) {
                                double d = pos[x] / ax->quantum - ((double) code[x] + 0.5);
                                s2 += d * d;
                                n++;
                        }
                st[2 * a] += s2;
                st[2 * a + 1] += n;
        }
}

/* Float path of the Gray code: white, black, L_d / L_g from the finest planes (Moreno &
 * Taubin §3, after Nayar et al.: L_d = (L_max − L_min)/(1 − b), L_g = 2 (L_min − b L_max)/
 * (1 − b²); L_g < 0, noise or an overestimated b, is clamped to 0), then each axis. */
static void float_gray_row(const struct ctx *c, int y, float **R, int w) {
        const struct plan *pl = c->pl;
        const float b = c->b;
        float *restrict lmax = R[R_LMAX], *restrict lmin = R[R_LMIN], *restrict pr = R[R_P];
        float *restrict ld = R[R_LD], *restrict lg = R[R_LG], *restrict hi = R[R_HI];
        SIMD
        for (int x = 0; x < w; x++)
                hi[x] = 0.0f;
        if (pl->white >= 0) {
                load_row(c->in->images[pl->white], y, R[R_WHITE], w);
                SIMD
                for (int x = 0; x < w; x++)
                        hi[x] = maxf(hi[x], R[R_WHITE][x]);
        }
        if (pl->black >= 0)
                load_row(c->in->images[pl->black], y, R[R_BLACK], w);
        if (pl->ndg > 0) {
                SIMD
                for (int x = 0; x < w; x++) {
                        lmax[x] = -INFINITY;
                        lmin[x] = INFINITY;
                }
                for (int i = 0; i < pl->ndg; i++) {
                        load_row(c->in->images[pl->dg[i]], y, pr, w);
                        SIMD
                        for (int x = 0; x < w; x++) {
                                lmax[x] = maxf(lmax[x], pr[x]);
                                lmin[x] = minf(lmin[x], pr[x]);
                        }
                }
                if ((pl->ax[0].nbits && !pl->ax[0].inverse) || (pl->ax[1].nbits && !pl->ax[1].inverse)) {
                        /* Without inverses the implied p̄ = W + B − p belongs to the set too. */
                        const float *wr = R[R_WHITE], *br = R[R_BLACK];
                        SIMD
                        for (int x = 0; x < w; x++) {
                                float a1 = wr[x] + br[x] - lmax[x], a2 = wr[x] + br[x] - lmin[x];
                                lmax[x] = maxf(lmax[x], a2);
                                lmin[x] = minf(lmin[x], a1);
                        }
                }
                float k1 = 1.0f / (1.0f - b), k2 = 2.0f / (1.0f - b * b);
                SIMD
                for (int x = 0; x < w; x++) {
                        ld[x] = maxf(k1 * (lmax[x] - lmin[x]), 0.0f);
                        lg[x] = maxf(k2 * (lmin[x] - b * lmax[x]), 0.0f);
                }
        } else {
                /* Phase only: A = (L_d + L_g)(1 + b)/2 and B = L_d (1 − b)/2. */
                int a = pl->ax[0].nphase ? 0 : 1;
                phase_group_row(c, &pl->ax[a].ph[0], y, R, w);
                SIMD
                for (int x = 0; x < w; x++) {
                        ld[x] = 2 * R[R_C][x] / (1 - b);
                        lg[x] = maxf(2 * R[R_A][x] / (1 + b) - ld[x], 0.0f);
                        lmax[x] = R[R_A][x] + R[R_C][x];
                        lmin[x] = R[R_A][x] - R[R_C][x];
                }
        }
        for (int a = 0; a < 2; a++)
                if (pl->ax[a].nbits)
                        decode_gray_axis(c, a, y, R, w);
}

static void or_mask_row(const struct imp_image *m, int y, uint32_t bit, uint32_t *restrict dst, int w) {
        if (!m)
                return;
        const uint8_t *restrict s = imp_image_row(m, y);
        SIMD
        for (int x = 0; x < w; x++)
                dst[x] |= s[x] ? bit : 0u;
}

/* The R_SATM row from the caller's saturation masks: SATM_ANY for any frame the decode
 * reads, SATM_PHASE0/1 for the phase frames of each axis. False when there are none. */
static bool saturation_row(const struct ctx *c, int y, float **R, int w) {
        const struct imp_image *const *m = c->in->saturated;
        if (!m)
                return false;
        const struct plan *pl = c->pl;
        uint32_t *restrict sm = (uint32_t *) R[R_SATM];
        SIMD
        for (int x = 0; x < w; x++)
                sm[x] = 0;
        if (pl->white >= 0)
                or_mask_row(m[pl->white], y, SATM_ANY, sm, w);
        for (int a = 0; a < 2; a++) {
                const struct axis_plan *ax = &pl->ax[a];
                for (int k = 0; k < ax->nbits; k++) {
                        or_mask_row(m[ax->p[k]], y, SATM_ANY, sm, w);
                        if (ax->inverse)
                                or_mask_row(m[ax->q[k]], y, SATM_ANY, sm, w);
                }
                for (int j = 0; j < ax->nphase; j++)
                        for (int s = 0; s < ax->ph[j].steps; s++)
                                or_mask_row(m[ax->ph[j].idx[s]], y, SATM_ANY | (a ? SATM_PHASE1 : SATM_PHASE0),
                                            sm, w);
        }
        return true;
}

/* Phase of axis a: unwrap each group, coarsest first, against the previous estimate (the
 * Gray centre at first): k = round((ref − u_f)/P) is the period nearest to it, which also
 * settles the ±1-period ambiguity where a code boundary meets a phase wrap. Status per
 * pixel in R_PCONF (PST_*); R_DIS: |phase − Gray centre| at the first level. */
static void unwrap_phase_axis(const struct ctx *c, int a, int y, float **R, int w, bool have_satm) {
        const struct imp_sl_params *p = c->p;
        const struct axis_plan *ax = &c->pl->ax[a];
        const float sat = c->sat;
        float *restrict pos = R[R_POS0 + a], *restrict mod = R[R_MOD0 + a], *restrict hi = R[R_HI];
        float *restrict dis = R[R_DIS0 + a];
        uint32_t *restrict pst = (uint32_t *) R[R_PCONF0 + a];
        const uint32_t *code = (const uint32_t *) R[R_CODE0 + a];
        const uint32_t *weak = (const uint32_t *) R[R_WEAK0 + a];
        const uint32_t *satm = (const uint32_t *) R[R_SATM];
        const uint32_t satbit = have_satm ? (a ? SATM_PHASE1 : SATM_PHASE0) : 0;
        SIMD
        for (int x = 0; x < w; x++) {
                pos[x] = ax->nbits ? ((float) code[x] + 0.5f) * ax->quantum : 0.0f;
                mod[x] = INFINITY;
                pst[x] = have_satm && (satm[x] & satbit) ? PST_LOW_MOD : 0;
                dis[x] = 0.0f;
        }
        /* The Gray cell holds the true position: a phase farther than half a cell plus the
         * margin (one code more where a bit was weak) contradicts it. */
        const float cell = 0.5f * ax->quantum + (float) p->phase_margin_px;
        for (int j = 0; j < ax->nphase; j++) {
                const struct phase_group *g = &ax->ph[j];
                phase_group_row(c, g, y, R, w);
                float P = (float) g->period_px;
                /* Later levels: the coarser phase is trusted to a quarter period
                 * of this one (nearest-k alone guarantees half a period). */
                float tol = j == 0 ? (float) p->max_disagreement_px + (ax->quantum - 1) / 2
                                   : maxf((float) p->max_disagreement_px, P / 4);
                bool absolute = j == 0 && !ax->nbits;   /* period covers the projector */
                bool first = j == 0 && ax->nbits;
                const float *uf = R[R_S], *B = R[R_C], *ph_hi = R[R_Q];
                SIMD
                for (int x = 0; x < w; x++) {
                        float u = uf[x];
                        if (!absolute) {
                                float k = rintf((pos[x] - u) / P);
                                u += k * P;
                                float d = fabsf(u - pos[x]);
                                if (d > tol)
                                        pst[x] |= PST_DISAGREE;
                                if (first && d > cell + (weak[x] ? ax->quantum : 0.0f)) {
                                        pst[x] |= PST_OUTSIDE_CELL;
                                        dis[x] = d;
                                }
                        }
                        if (B[x] < (float) p->min_modulation || ph_hi[x] >= sat || !(B[x] >= 0))
                                pst[x] |= PST_LOW_MOD;
                        mod[x] = minf(mod[x], B[x]);
                        hi[x] = maxf(hi[x], ph_hi[x]);
                        pos[x] = u;
                }
        }
}

/* One axis of one pixel of the phase path: flags, position, confidence, σ. False when
 * the axis is not valid there. */
static bool combine_axis(const struct ctx *c, int a, int x, float **R, float span, bool shadow,
                         uint32_t *f, float *ret_pos, float *ret_conf, float *ret_sigma, float *modv) {
        const struct axis_plan *ax = &c->pl->ax[a];
        bool ok = !shadow;
        float ca = 1.0f, pos = R[R_POS0 + a][x], sig = 0.0f;
        const float gray = ax->nbits ? ((float) ((uint32_t *) R[R_CODE0 + a])[x] + 0.5f) * ax->quantum : 0.0f;
        float gsig = INV_SQRT12 * ax->quantum;
        if (ax->nbits) {
                uint32_t nweak = ((uint32_t *) R[R_WEAK0 + a])[x];
                uint32_t code = ((uint32_t *) R[R_CODE0 + a])[x];
                if (nweak > GRAY_WEAK_ALLOWED) {
                        *f |= IMP_SL_UNDECODABLE;
                        ok = false;
                } else if (nweak) {
                        *f |= IMP_SL_WEAK_BIT;
                        ca = 0.5f;
                        gsig = WEAK_SIGMA * ax->quantum;
                }
                if (code >= (uint32_t) ax->ncodes) {
                        *f |= IMP_SL_OUT_OF_RANGE;
                        ok = false;
                }
                ca *= span > 0 ? clamp01(R[R_CMIN0 + a][x] / span) : 0.0f;
                sig = gsig;
        }
        if (ax->nphase) {
                uint32_t st = ((uint32_t *) R[R_PCONF0 + a])[x];
                *modv = minf(*modv, R[R_MOD0 + a][x]);
                if (st & PST_LOW_MOD) {
                        *f |= IMP_SL_LOW_MODULATION;
                        if (!ax->nbits)
                                ok = false;
                        pos = gray;
                } else if (st & PST_DISAGREE) {
                        *f |= IMP_SL_DISAGREE;
                        ok = false;
                } else if (st & PST_OUTSIDE_CELL) {
                        /* Gray and phase cannot both be right: the Gray centre, with a σ
                         * that covers the phase's answer too. */
                        if (ok)
                                *f |= IMP_SL_PHASE_REJECTED;
                        pos = gray;
                        float d = R[R_DIS0 + a][x];
                        sig = sqrtf(gsig * gsig + d * d);
                } else {
                        if (ok)
                                *f |= a == 0 ? IMP_SL_SUBPIXEL_X : IMP_SL_SUBPIXEL_Y;
                        ca = span > 0 ? clamp01(2 * R[R_MOD0 + a][x] / span) : 0.0f;
                        sig = 0.0f;     /* raised to the axis's measured phase error later */
                }
        }
        if (ok && !isfinite(pos))
                ok = false;
        if (ok && (c->rejected >> a & 1))
                *f |= IMP_SL_PHASE_REJECTED;
        *ret_pos = pos;
        *ret_conf = ca;
        *ret_sigma = sig;
        return ok;
}

/* Flags, coordinates, confidence and σ of a row decoded with phase frames. */
static void combine_phase_row(const struct ctx *c, int y, float **R, int w, bool have_satm,
                              size_t counts[8]) {
        const struct plan *pl = c->pl;
        const struct imp_sl_params *p = c->p;
        struct imp_sl_result *res = c->res;
        const float *ld = R[R_LD], *lg = R[R_LG], *hi = R[R_HI];
        const uint32_t *satm = (const uint32_t *) R[R_SATM];
        const bool have_wb = pl->white >= 0 && pl->black >= 0;
        const float minc_d = (float) p->min_direct;
        size_t off = (size_t) y * w;
        for (int x = 0; x < w; x++) {
                uint32_t f = 0;
                bool shadow = (have_wb && !(R[R_WHITE][x] - R[R_BLACK][x] > (float) p->shadow_threshold)) ||
                              (p->robust && !(ld[x] >= minc_d));
                if (shadow)
                        f |= IMP_SL_SHADOW;
                if (hi[x] >= c->sat || (have_satm && satm[x]))
                        f |= IMP_SL_SATURATED;
                float span = ld[x] * (1 - c->b);                /* = L_max − L_min */
                float conf = 1.0f, out[2] = { IMP_SL_INVALID_COORD, IMP_SL_INVALID_COORD };
                float modv = INFINITY, sigma = 0.0f;
                int nvalid = 0;
                for (int a = 0; a < 2; a++) {
                        if (!pl->ax[a].nbits && !pl->ax[a].nphase)
                                continue;
                        float pos, ca, sa;
                        if (combine_axis(c, a, x, R, span, shadow, &f, &pos, &ca, &sa, &modv)) {
                                f |= a == 0 ? IMP_SL_VALID_X : IMP_SL_VALID_Y;
                                out[a] = pos;
                                conf = minf(conf, ca);
                                sigma = maxf(sigma, sa);
                                nvalid++;
                        }
                }
                res->proj_x[off + x] = out[0];
                res->proj_y[off + x] = out[1];
                res->confidence[off + x] = imp_sl_conf16(nvalid ? conf : 0.0f);
                res->sigma_px[off + x] = imp_sl_sigma16(nvalid ? sigma : 0.0f);
                res->flags[off + x] = (uint16_t) f;
                if (res->direct)
                        res->direct[off + x] = isfinite(ld[x]) ? ld[x] : 0.0f;
                if (res->global) {
                        res->global[off + x] = isfinite(lg[x]) ? lg[x] : 0.0f;
                        res->modulation[off + x] = isfinite(modv) ? modv : 0.0f;
                }
                counts[0] += !!(f & IMP_SL_VALID_X);
                counts[1] += !!(f & IMP_SL_VALID_Y);
                counts[2] += (f & (IMP_SL_VALID_X | IMP_SL_VALID_Y)) == (IMP_SL_VALID_X | IMP_SL_VALID_Y);
                counts[3] += !!(f & IMP_SL_SHADOW);
                counts[4] += !!(f & IMP_SL_SATURATED);
                counts[5] += !!(f & IMP_SL_WEAK_BIT);
                counts[6] += !!(f & IMP_SL_DISAGREE);
        }
}

/* Saturation masks on a Gray-only row: the flag, and the counts it changes. */
static void gray_row_saturation(const struct ctx *c, int y, float **R, int w, size_t counts[8]) {
        const uint32_t *satm = (const uint32_t *) R[R_SATM];
        uint16_t *f = c->stream ? (uint16_t *) R[R_OF] : c->res->flags + (size_t) y * w;
        for (int x = 0; x < w; x++)
                if (satm[x] && !(f[x] & IMP_SL_SATURATED)) {
                        f[x] |= IMP_SL_SATURATED;
                        counts[4]++;
                }
}

/* Where a Gray-only row's maps go: the R_O* rows when streamed, else the result's row y. */
static struct comb_out gray_row_out(const struct ctx *c, int y, float **R) {
        struct imp_sl_result *res = c->res;
        const size_t off = (size_t) y * res->width;
        if (c->stream)
                return (struct comb_out) { R[R_OX], R[R_OY], (uint16_t *) R[R_OC], (uint16_t *) R[R_OS],
                                           (uint16_t *) R[R_OF] };
        return (struct comb_out) { res->proj_x + off, res->proj_y + off, res->confidence + off,
                                   res->sigma_px + off, res->flags + off };
}

static void decode_row(const struct ctx *c, int y, float **R, size_t counts[8], const struct band *bd) {
        const struct plan *pl = c->pl;
        const int w = pl->width;
        /* gray_u8_row's L_d, L_g are finite: the light maps as they are */
        const bool bytes = c->int_path == IMP_PIX_U8 && u8_row_applies(pl), comb = bytes && u8_combines(pl);
        if (bytes) {
                const struct comb_out o = gray_row_out(c, y, R);
                gray_u8_row(c, y, R, w, &o, comb ? counts : NULL, bd);
        } else if (c->int_path == IMP_PIX_U8) {
                gray_int_u8(c, y, R, w);
        } else if (c->int_path == IMP_PIX_U16) {
                gray_int_u16(c, y, R, w);
        } else {
                float_gray_row(c, y, R, w);
        }
        bool have_satm = saturation_row(c, y, R, w);
        if (!pl->ax[0].nphase && !pl->ax[1].nphase) {
                struct imp_sl_result *res = c->res;
                const size_t off = (size_t) y * w;
                if (!comb)
                        combine_gray_row(c, y, R, w, bytes, counts);
                else if (res->direct && !c->stream)
                        light_maps_row(res->direct + off, res->global ? res->global + off : NULL,
                                       res->global ? res->modulation + off : NULL, R[R_LD], R[R_LG], w);
                if (have_satm)
                        gray_row_saturation(c, y, R, w, counts);
                if (c->stream)
                        stream_gray_row(c, y, R, w, bytes);
                return;
        }
        for (int a = 0; a < 2; a++)
                unwrap_phase_axis(c, a, y, R, w, have_satm);
        combine_phase_row(c, y, R, w, have_satm, counts);
}

/* ---- entry points ---------------------------------------------------------------------- */

void imp_sl_result_free(struct imp_sl_result *r) {
        if (!r)
                return;
        free(r->proj_x);        /* one block holds every map */
        free(r);
}

/* Float maps of a result: the coordinates (2), direct with direct_only (3), else direct,
 * global and modulation too (5). Every result has RESULT_NU16 16-bit maps: confidence, σ,
 * flags. */
#define RESULT_NU16 3
static int result_nfloat(const struct imp_sl_params *p) {
        return p->coords_only ? 2 : p->direct_only ? 3 : 5;
}

/* Bytes a pixel of a result: 14 with coords_only, 18 with direct_only, else 26. */
static size_t result_px_bytes(int nfloat) {
        return (size_t) nfloat * sizeof(float) + RESULT_NU16 * sizeof(uint16_t);
}

static int result_new(int w, int h, int nfloat, struct imp_sl_result **ret) {
        size_t n = (size_t) w * h;
        _cleanup_free_ struct imp_sl_result *r = calloc(1, sizeof *r);
        if (!r)
                return -ENOMEM;
        /* nfloat float maps, then the 16-bit ones; floats first keep alignment. The block is
         * 26 bytes a pixel (every map), written once: with 4 KiB pages, faulting it in costs
         * about as much as the Gray decoding itself, so it asks for transparent huge pages
         * (a hint; ignored where THP is off). */
        size_t bytes = n * result_px_bytes(nfloat);
        char *blk;
        if (bytes >= RESULT_HUGE_BYTES) {
                size_t round = (bytes + RESULT_HUGE_BYTES - 1) & ~(size_t) (RESULT_HUGE_BYTES - 1);
                blk = aligned_alloc(RESULT_HUGE_BYTES, round);
                if (blk)
                        (void) madvise(blk, round, MADV_HUGEPAGE);
        } else {
                blk = malloc(bytes);
        }
        if (!blk)
                return -ENOMEM;
        float *fl = (float *) blk;
        r->proj_x = fl;
        r->proj_y = fl + n;
        if (nfloat > 2)
                r->direct = fl + 2 * n;
        if (nfloat > 3) {
                r->global = fl + 3 * n;
                r->modulation = fl + 4 * n;
        }
        uint16_t *u16 = (uint16_t *) (fl + nfloat * n);
        r->confidence = u16;
        r->sigma_px = u16 + n;
        r->flags = u16 + 2 * n;
        r->width = w;
        r->height = h;
        *ret = TAKE_PTR(r);
        return 0;
}

static float saturation_level(const struct imp_sl_params *p, enum imp_pixel_type t) {
        if (p->saturation > 0)
                return (float) p->saturation;
        return t == IMP_PIX_U8 ? 255.0f : t == IMP_PIX_U16 ? 65535.0f : INFINITY;
}

/* Decodes every row into c->res (maps and counts); st (or NULL): phase_stats_row sums. */
static void decode_pass(const struct ctx *c, int nthreads, float *scratch, size_t wpad,
                        double st[4]) {
        size_t c0 = 0, c1 = 0, c2 = 0, c3 = 0, c4 = 0, c5 = 0, c6 = 0;
        double s0 = 0, s1 = 0, s2 = 0, s3 = 0;
        const int height = c->pl->height, nbands = (height + BAND_ROWS - 1) / BAND_ROWS;
        int claimed = 0;
#pragma omp parallel num_threads(nthreads) reduction(+ : c0, c1, c2, c3, c4, c5, c6, s0, s1, s2, s3)
        {
                int t = 0;
#ifdef _OPENMP
                t = omp_get_thread_num();
#endif
                float *R[R_NROWS];
                for (int i = 0; i < R_NROWS; i++)
                        R[i] = scratch + ((size_t) t * R_NROWS + i) * wpad;
                /* bands claimed one ahead: the next one is prefetched during the current */
                int next;
#pragma omp atomic capture
                next = claimed++;
                while (next < nbands) {
                        const int cur = next;
#pragma omp atomic capture
                        next = claimed++;
                        struct band bd = { .next0 = next * BAND_ROWS,
                                           .next_rows = next < nbands ? IMP_MIN(BAND_ROWS, height - next * BAND_ROWS) : 0,
                                           .rows = IMP_MIN(BAND_ROWS, height - cur * BAND_ROWS) };
                        for (bd.j = 0; bd.j < bd.rows; bd.j++) {
                                const int y = cur * BAND_ROWS + bd.j;
                                size_t cnt[8] = { 0 };
                                decode_row(c, y, R, cnt, &bd);
                                c0 += cnt[0]; c1 += cnt[1]; c2 += cnt[2]; c3 += cnt[3];
                                c4 += cnt[4]; c5 += cnt[5]; c6 += cnt[6];
                                if (st) {
                                        double row[4] = { 0 };
                                        phase_stats_row(c, y, R, row);
                                        s0 += row[0]; s1 += row[1]; s2 += row[2]; s3 += row[3];
                                }
                        }
                }
#if defined(__SSE2__)
                if (c->stream)
                        _mm_sfence();   /* the streamed rows before the region's barrier */
#endif
        }
        struct imp_sl_result *res = c->res;
        res->n_valid_x = c0;
        res->n_valid_y = c1;
        res->n_valid_xy = c2;
        res->n_shadow = c3;
        res->n_saturated = c4;
        res->n_weak = c5;
        res->n_disagree = c6;
        if (st) {
                st[0] = s0; st[1] = s1; st[2] = s2; st[3] = s3;
        }
}

/* A phase-refined axis is as good as its measured error (phase_err_px), at best. */
static void raise_phase_sigma(struct imp_sl_result *res) {
        size_t n = (size_t) res->width * res->height;
        const float e0 = fmaxf(res->phase_err_px[0], 0.0f), e1 = fmaxf(res->phase_err_px[1], 0.0f);
        for (size_t i = 0; i < n; i++) {
                uint16_t f = res->flags[i];
                const float s0 = imp_sl_sigma(res->sigma_px[i]);
                float s = s0;
                s = (f & IMP_SL_SUBPIXEL_X) && (f & IMP_SL_VALID_X) ? fmaxf(s, e0) : s;
                s = (f & IMP_SL_SUBPIXEL_Y) && (f & IMP_SL_VALID_Y) ? fmaxf(s, e1) : s;
                if (s != s0)    /* rounded once: a kept σ is not encoded again */
                        res->sigma_px[i] = imp_sl_sigma16(s);
        }
}

int imp_sl_decode(const struct imp_sl_frames *in, const struct imp_sl_params *p,
                  struct imp_sl_result **ret, struct imp_error *err) {
        if (!ret)
                return imp_error_set(err, -EINVAL, "structured light: no result pointer");
        struct imp_sl_result *res = NULL;
        int r = imp_sl_decode_reuse(in, p, &res, err);
        if (r == 0)
                *ret = res;
        return r;
}

int imp_sl_decode_reuse(const struct imp_sl_frames *in, const struct imp_sl_params *p,
                        struct imp_sl_result **ret, struct imp_error *err) {
        if (!p || !ret)
                return imp_error_set(err, -EINVAL, "structured light: no parameters");
        if (!(p->black_level >= 0 && p->black_level < 1))
                return imp_error_set(err, -EINVAL, "structured light: black level %g not in [0, 1)",
                                     p->black_level);
        if (!isfinite(p->shadow_threshold) || !isfinite(p->min_bit_contrast) ||
            !isfinite(p->min_direct) || !isfinite(p->min_modulation) ||
            !(p->max_disagreement_px > 0) || !isfinite(p->max_disagreement_px) ||
            !(p->phase_margin_px >= 0))
                return imp_error_set(err, -EINVAL, "structured light: thresholds must be finite "
                                     "(max_disagreement_px > 0, phase_margin_px ≥ 0)");
        struct plan *pl = calloc(1, sizeof *pl);
        if (!pl)
                return -ENOMEM;
        _cleanup_free_ struct plan *pl_owner = pl;
        int r = build_plan(in, p, pl, err);
        if (r < 0)
                return r;

        _cleanup_(imp_sl_result_freep) struct imp_sl_result *fresh = NULL;
        struct imp_sl_result *res = *ret;
        if (!res || res->width != pl->width || res->height != pl->height ||
            2 + !!res->direct + 2 * !!res->global != result_nfloat(p)) {
                r = result_new(pl->width, pl->height, result_nfloat(p), &fresh);
                if (r < 0)
                        return imp_error_set(err, r, "structured light: out of memory for %dx%d maps",
                                             pl->width, pl->height);
                res = fresh;
        }

        int nthreads = 1;
#ifdef _OPENMP
        nthreads = p->threads > 0 ? p->threads : omp_get_max_threads();
#endif
        size_t wpad = ((size_t) pl->width + 15) & ~(size_t) 15;
        _cleanup_free_ float *scratch = aligned_alloc(64, (size_t) nthreads * R_NROWS * wpad * sizeof(float));
        if (!scratch)
                return imp_error_set(err, -ENOMEM, "structured light: out of memory for scratch rows");

        struct ctx c = { .in = in, .p = p, .pl = pl, .sat = saturation_level(p, pl->type),
                         .b = (float) p->black_level, .res = res, .int_path = -1 };
        c.stream = (size_t) pl->width * pl->height * result_px_bytes(result_nfloat(p)) >= STREAM_MIN_BYTES;
        /* The integer path needs Gray planes (it computes L_d, L_g from them) and, for
         * bytes in 16-bit lanes, a Gray code of at most 16 bits. */
        if (pl->ndg > 0 && pl->type == IMP_PIX_U16)
                c.int_path = IMP_PIX_U16;
        if (pl->ndg > 0 && pl->type == IMP_PIX_U8 && pl->ax[0].nbits <= 16 && pl->ax[1].nbits <= 16)
                c.int_path = IMP_PIX_U8;
        double st[4] = { 0 };
        const bool any_phase = pl->ax[0].nphase > 0 || pl->ax[1].nphase > 0;
        decode_pass(&c, nthreads, scratch, wpad, st);

        /* The phase against the Gray code: on a pixel decoded without a weak bit, the true
         * position lies uniformly in its code's pixel, so the mean (u − centre)² is the
         * phase's error variance plus 1/12 px² (the centre's own). A phase error larger
         * than the Gray centre's makes the phase useless: e.g. 3 steps under gamma 2.2
         * without the response correction (0.48 vs 0.29 px RMS, test-sl-decode). */
        unsigned reject = 0;
        for (int a = 0; a < 2; a++) {
                res->phase_err_px[a] = -1.0f;
                res->phase_rejected[a] = false;
                if (st[2 * a + 1] < PHASE_STAT_MIN)
                        continue;
                double var = st[2 * a] / st[2 * a + 1] - 1.0 / 12;     /* in quanta² */
                res->phase_err_px[a] = (float) (sqrt(fmax(var, 0)) * pl->ax[a].quantum);
                if (var > 1.0 / 12 && !p->keep_phase)
                        reject |= 1u << a;
        }
        if (reject) {
                /* Decode again with the rejected axes' phase left out. */
                for (int a = 0; a < 2; a++)
                        if (reject >> a & 1) {
                                pl->ax[a].nphase = 0;
                                res->phase_rejected[a] = true;
                        }
                c.rejected = reject;
                decode_pass(&c, nthreads, scratch, wpad, NULL);
        }
        if (any_phase)          /* else no pixel is IMP_SL_SUBPIXEL_*: nothing to raise */
                raise_phase_sigma(res);
        if (fresh) {
                imp_sl_result_free(*ret);
                *ret = TAKE_PTR(fresh);
        }
        return 0;
}
