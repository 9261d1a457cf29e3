/* Height fusion (pipeline/geometry/fuse.h) where the normals are wrong: a smooth relief
 * measured with 2 µm noise, normals from the exact surface (σ 1° claimed) except a patch
 * tilted 15° off (what inter-reflection does to photometric normals, still claiming 1°),
 * and a band at the edge with no positions (mask 2, shadow fill) whose normals are 2° off.
 * Asserted: every height finite; in the patch at most 1 % of the heights lie beyond 3σ
 * (the rows the heights contradict are left out, the measured heights stay); in the
 * filled band the σ fusion gives covers the integrated error (≤ 1 % beyond 3σ); both are
 * flagged. Without imp_fuse_texels (no back-off, the input σ) the same assertions fail:
 * the patch's heights bend and the filled band's σ is far too small. */
#include <stdbool.h>
#include <stdint.h>
#include "fuse.h"
#include "quality.h"
#include "test.h"

#define NX 140
#define NY 60
#define PITCH 0.05
#define NOISE_MM 0.002
#define NSIG_DEG 1.0
#define PATCH_BIAS_DEG 15.0
#define FILL_BIAS_DEG 2.0
#define FILL_SIGMA_IN_MM 0.004   /* the σ the heightfield gives a filled texel near its source */

static bool in_patch(int i, int j) { return i >= 40 && i < 70 && j >= 15 && j < 45; }
static bool in_fill(int i) { return i >= 120; }

static double surface(int i, int j) {
        double x = i * PITCH, y = j * PITCH;
        return 0.05 * sin(2 * M_PI * x / 4.0) * cos(2 * M_PI * y / 3.0) + 0.01 * x;
}

struct grid {
        double zt[NX * NY];
        float z[NX * NY], sig[NX * NY], nsd[NX * NY], nrm[3 * NX * NY], sig_out[NX * NY];
        uint8_t mask[NX * NY];
        uint16_t flags[NX * NY];
};

static void make(struct grid *g) {
        uint64_t rng = 11;
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++)
                        g->zt[j * NX + i] = surface(i, j);
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        size_t t = (size_t) j * NX + i;
                        int il = i > 0 ? i - 1 : i, ir = i + 1 < NX ? i + 1 : i;
                        int jd = j > 0 ? j - 1 : j, ju = j + 1 < NY ? j + 1 : j;
                        double gx = (g->zt[j * NX + ir] - g->zt[j * NX + il]) / ((ir - il) * PITCH);
                        double gy = (g->zt[ju * NX + i] - g->zt[jd * NX + i]) / ((ju - jd) * PITCH);
                        double bias = in_patch(i, j) ? PATCH_BIAS_DEG : in_fill(i) ? FILL_BIAS_DEG : 0;
                        gx += tan(bias * M_PI / 180);
                        double l = sqrt(gx * gx + gy * gy + 1);
                        float *q = &g->nrm[3 * t];
                        q[0] = (float) (-gx / l), q[1] = (float) (-gy / l), q[2] = (float) (1 / l);
                        g->nsd[t] = (float) NSIG_DEG;
                        g->flags[t] = 0;
                        if (in_fill(i)) {
                                g->mask[t] = 2;
                                /* start: the nearest measured height, as the heightfield does */
                                g->z[t] = (float) surface(119, j);
                                g->sig[t] = (float) FILL_SIGMA_IN_MM;
                        } else {
                                g->mask[t] = 1;
                                g->z[t] = (float) (g->zt[t] + NOISE_MM * test_nrand(&rng));
                                g->sig[t] = (float) NOISE_MM;
                        }
                }
}

struct figures {
        long nonfinite, patch, patch_beyond, patch_flagged, fill, fill_beyond, fill_flagged;
        double fill_sigma_max_um;
};

static struct figures fuse(struct grid *g, bool checks) {
        struct imp_fuse_params p;
        imp_fuse_params_default(&p);
        struct imp_fuse_stats st = {};
        struct imp_fuse_texels tex = { g->nsd, g->sig_out, g->flags };
        memcpy(g->sig_out, g->sig, sizeof g->sig);
        CHECK_OK(imp_fuse_heights(NX, NY, PITCH, g->z, g->nrm, g->sig, g->mask, &p, checks ? &tex : NULL, &st));
        /* Heights have no absolute origin: compare about the median offset of measured texels
         * away from the patch (the anchor the fusion keeps). */
        double off = 0;
        long n = 0;
        for (int t = 0; t < NX * NY; t++)
                if (g->mask[t] == 1 && !in_patch(t % NX, t / NX)) {
                        off += g->z[t] - g->zt[t];
                        n++;
                }
        off /= n;
        struct figures f = {};
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        size_t t = (size_t) j * NX + i;
                        f.nonfinite += !isfinite(g->z[t]) || !isfinite(g->sig_out[t]);
                        double e = fabs(g->z[t] - off - g->zt[t]), s = g->sig_out[t];
                        if (in_patch(i, j)) {
                                f.patch++;
                                f.patch_beyond += e > 3 * s;
                                f.patch_flagged += !!(g->flags[t] & IMP_TEXEL_PHOTOMETRIC_REJECTED);
                        }
                        if (in_fill(i)) {
                                f.fill++;
                                f.fill_beyond += e > 3 * s;
                                f.fill_flagged += !!(g->flags[t] & IMP_TEXEL_FILLED);
                        }
                }
        fprintf(stderr, "%s: rows rejected %ld; patch %ld texels, %ld beyond 3σ, %ld flagged; filled %ld, "
                "%ld beyond 3σ, %ld flagged (σ up to %.1f µm)\n", checks ? "back-off on" : "back-off off",
                st.n_rows_rejected, f.patch, f.patch_beyond, f.patch_flagged, f.fill, f.fill_beyond,
                f.fill_flagged, st.fill_sigma_max_mm * 1000);
        f.fill_sigma_max_um = st.fill_sigma_max_mm * 1000;
        return f;
}

int main(void) {
        static struct grid g;
        make(&g);
        struct figures on = fuse(&g, true);
        CHECK_INT_EQ(on.nonfinite, 0);
        CHECK_LE(on.patch_beyond, 0.01 * on.patch);
        CHECK_GE(on.patch_flagged, 0.9 * on.patch);
        CHECK_LE(on.fill_beyond, 0.01 * on.fill);
        CHECK_INT_EQ(on.fill_flagged, on.fill);
        /* every filled texel is reached from a measured one: its σ is the cheapest path's
         * (19.6 µm at most here), not the 1 m of a texel the sweeps never reached */
        CHECK_GE(on.fill_sigma_max_um, 5);
        CHECK_LE(on.fill_sigma_max_um, 100);

        make(&g);
        struct figures off = fuse(&g, false);
        CHECK_INT_EQ(off.nonfinite, 0);
        CHECK_GE(off.patch_beyond, 0.1 * off.patch);   /* the biased normals bent the heights */
        CHECK_GE(off.fill_beyond, 0.1 * off.fill);     /* and the input σ does not cover the fill */
        return TEST_DONE();
}
