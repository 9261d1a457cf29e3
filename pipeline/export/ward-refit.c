/* The Lafortune lobe refitted to OpenLIME's isotropic Ward model (export.h). */
#include <math.h>
#include <stdbool.h>
#include <string.h>
#include "export.h"

#define WARD_EXPONENT 4.0
#define N_THETA 86                    /* light elevations 0..85° from the normal */
#define N_GLOSS 201

double imp_ward_alpha(double gloss) {
        double g0 = 1 - pow(0.5, 1 / WARD_EXPONENT), g1 = 1 - pow(0.01, 1 / WARD_EXPONENT);
        return pow(1 - gloss * (g1 - g0) - g0, WARD_EXPONENT);
}

/* s[g][t] = Ward spec × cos θl (viewer on the normal, θh = θl / 2), w[t] = sin θ dθ,
 * ss[g] = Σ w s². */
static struct { bool ready; double s[N_GLOSS][N_THETA], w[N_THETA], ss[N_GLOSS], cos_t[N_THETA]; } T;

static void tables(void) {
        if (T.ready)
                return;
        for (int t = 0; t < N_THETA; t++) {
                double th = t * M_PI / 180;
                T.cos_t[t] = cos(th);
                T.w[t] = sin(th) + 1e-3;   /* the normal direction counts a little */
        }
        for (int g = 0; g < N_GLOSS; g++) {
                double a = imp_ward_alpha((double) g / (N_GLOSS - 1)), ss = 0;
                for (int t = 0; t < N_THETA; t++) {
                        double th = t * M_PI / 180, tan_h = tan(0.5 * th);
                        double spec = exp(-tan_h * tan_h / (a * a)) / (4 * M_PI * a * a * sqrt(T.cos_t[t]));
                        T.s[g][t] = spec * T.cos_t[t];
                        ss += T.w[t] * T.s[g][t] * T.s[g][t];
                }
                T.ss[g] = ss;
        }
        T.ready = true;
}

void imp_ward_refit(const struct imp_lafortune *b, struct imp_ward_fit *ret) {
        tables();
        /* the Lafortune specular term per unit ρs, physical units (f / π) × cos θl */
        double L[N_THETA], LL = 0;
        for (int t = 0; t < N_THETA; t++) {
                double d = b->cz * T.cos_t[t];
                L[t] = d > 0 ? pow(d, b->k) / M_PI * T.cos_t[t] : 0;
                LL += T.w[t] * L[t] * L[t];
        }
        memset(ret, 0, sizeof *ret);
        if (!(LL > 0) || !isfinite(LL)) {
                ret->alpha = (float) imp_ward_alpha(0);
                return;
        }
        int best = 0;
        double best_res = INFINITY, best_scale = 0;
        for (int g = 0; g < N_GLOSS; g++) {
                double sL = 0;
                for (int t = 0; t < N_THETA; t++)
                        sL += T.w[t] * T.s[g][t] * L[t];
                double scale = sL > 0 ? sL / T.ss[g] : 0;
                double res = LL - scale * sL;         /* Σ w (scale·s − L)² at the optimum */
                if (res < best_res)
                        best_res = res, best = g, best_scale = scale;
        }
        for (int c = 0; c < 3; c++)
                ret->ks[c] = (float) (b->rho_s[c] * best_scale);
        ret->gloss = (float) best / (N_GLOSS - 1);
        ret->alpha = (float) imp_ward_alpha(ret->gloss);
        ret->rel_error = (float) sqrt(fmax(best_res, 0) / LL);
}
