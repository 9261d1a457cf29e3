/* Throughput of the photometric texel model (imp_photometric_texel, photometric.h) against
 * main's as it was before it was made faster (pn-model-peer.c), on one thread over the
 * same synthetic texels (pn-model-set.h: the demo's dome, matte and glossy paints, ambient
 * terms, cast shadows, dark paint, few lights; one in twenty with the shadow-filled texels'
 * parameters). Alternates the two, REPS times each, and prints the best run of each as
 * texels/s and their ratio, and how far the two disagree (they should not: any flag or
 * normal that differs is printed and makes the exit code 1). Times are the thread's CPU time.
 *
 *     bench-pn-model [TEXELS (20000)] [REPS (7)] [SEED]
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "unit/pn-model-peer.h"
#include "unit/pn-model-set.h"

typedef int (*texel_fn)(const struct imp_btf_sample *, int, const struct imp_photometric_params *,
                        struct imp_pn_texel *);

static double now(void) {
        struct timespec ts;
        clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);   /* CPU time: the machine is shared */
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double run(texel_fn f, const struct pn_set_texel *set, int n, const struct imp_photometric_params *p,
                  const struct imp_photometric_params *pf, struct imp_pn_texel *out) {
        double t0 = now();
        for (int i = 0; i < n; i++)
                if (f(set[i].s, set[i].n, set[i].filled ? pf : p, &out[i]) < 0)
                        abort();
        return now() - t0;
}

static double angle_deg(const float a[3], const float b[3]) {
        double d = 0, la = 0, lb = 0;
        for (int k = 0; k < 3; k++) {
                d += (double) a[k] * b[k];
                la += (double) a[k] * a[k];
                lb += (double) b[k] * b[k];
        }
        return acos(fmax(-1.0, fmin(1.0, d / sqrt(la * lb)))) * 180 / M_PI;
}

static int compare(const struct imp_pn_texel *a, const struct imp_pn_texel *b, int n) {
        int n_diff = 0, n_flags = 0;
        double max_deg = 0;
        for (int i = 0; i < n; i++) {
                if (memcmp(&a[i], &b[i], sizeof a[i]))
                        n_diff++;
                if (a[i].flags != b[i].flags) {
                        if (n_flags++ < 5)
                                printf("texel %d: flags %#x, main's %#x\n", i, a[i].flags, b[i].flags);
                } else
                        max_deg = fmax(max_deg, angle_deg(a[i].n, b[i].n));
        }
        printf("results: %d of %d texels not bit-identical to main's, %d with other flags, "
               "normals at most %.3g° apart\n", n_diff, n, n_flags, max_deg);
        return n_flags || max_deg > 1e-6 * 180 / M_PI;
}

int main(int argc, char **argv) {
        int n = argc > 1 ? atoi(argv[1]) : 20000, reps = argc > 2 ? atoi(argv[2]) : 7;
        uint64_t seed = argc > 3 ? strtoull(argv[3], NULL, 0) : 0x5eedULL;
        if (n < 1 || reps < 1) {
                fprintf(stderr, "usage: bench-pn-model [TEXELS] [REPS] [SEED]\n");
                return 2;
        }
        struct imp_rig_light L[64];
        int nl = pn_set_dome(L);
        struct pn_set_texel *set = malloc(sizeof *set * n);
        struct imp_pn_texel *a = malloc(sizeof *a * n), *b = malloc(sizeof *b * n);
        if (!set || !a || !b)
                return 1;
        long samples = 0, flagged = 0;
        for (int i = 0; i < n; i++) {
                pn_set_texel(seed, i, L, nl, &set[i]);
                samples += set[i].n;
        }
        struct imp_photometric_params p, pf;
        imp_photometric_params_default(&p);
        pf = p;
        pn_set_filled_params(&pf);
        double best_new = INFINITY, best_old = INFINITY;
        for (int r = 0; r < reps; r++) {
                best_old = fmin(best_old, run(pn_model_peer_texel, set, n, &p, &pf, b));
                best_new = fmin(best_new, run(imp_photometric_texel, set, n, &p, &pf, a));
        }
        for (int i = 0; i < n; i++)
                flagged += (a[i].flags & IMP_PN_KEPT) != 0;
        printf("%d texels, %.1f samples each, %.1f %% kept the geometric normal; best of %d runs, one thread\n",
               n, (double) samples / n, 100.0 * flagged / n, reps);
        printf("main's model: %.0f texels/s\nthis model:   %.0f texels/s\nratio:        %.3f\n", n / best_old,
               n / best_new, best_old / best_new);
        int bad = compare(a, b, n);
        free(set);
        free(a);
        free(b);
        return bad;
}
