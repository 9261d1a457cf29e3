/* Heights from positions and normals (pipeline/geometry/fuse.h) on synthetic surfaces with a known
 * answer: a relief of 3 mm undulations plus 0.2 mm grooves (4 texels per period, the
 * demo's bristle grooves) on a tilted plane, its normals the central differences of the
 * exact heights, the positions the exact heights plus 5 µm noise. */
#include <errno.h>
#include <stdint.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "test.h"
#include "fuse.h"

#define NX 120
#define NY 90
#define PITCH 0.05
#define NOISE_MM 0.005

static double surface(int i, int j) {
        double x = i * PITCH, y = j * PITCH;
        return 0.02 * x - 0.01 * y + 0.1 * sin(2 * M_PI * x / 3.0) * cos(2 * M_PI * y / 2.5) +
               0.02 * sin(2 * M_PI * (x + 0.3 * y) / 0.2);
}

/* Deterministic N(0, 1) (xorshift + Box–Muller). */
static double gauss(uint64_t *s) {
        double u[2];
        for (int k = 0; k < 2; k++) {
                *s ^= *s << 13, *s ^= *s >> 7, *s ^= *s << 17;
                u[k] = ((*s >> 11) + 0.5) / 9007199254740992.0;
        }
        return sqrt(-2 * log(u[0])) * cos(2 * M_PI * u[1]);
}

/* Exact heights, their central-difference normals (one-sided at the border) plus a slope
 * bias, noisy positions. */
static void make(double *zt, float *z0, float *n, double bias_gx, uint64_t seed) {
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++)
                        zt[j * NX + i] = surface(i, j);
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        int il = i > 0 ? i - 1 : i, ir = i + 1 < NX ? i + 1 : i;
                        int jd = j > 0 ? j - 1 : j, ju = j + 1 < NY ? j + 1 : j;
                        double gx = (zt[j * NX + ir] - zt[j * NX + il]) / ((ir - il) * PITCH) + bias_gx;
                        double gy = (zt[ju * NX + i] - zt[jd * NX + i]) / ((ju - jd) * PITCH);
                        double l = sqrt(gx * gx + gy * gy + 1);
                        float *q = &n[3 * (j * NX + i)];
                        q[0] = (float) (-gx / l), q[1] = (float) (-gy / l), q[2] = (float) (1 / l);
                        z0[j * NX + i] = (float) (zt[j * NX + i] + (seed ? NOISE_MM * gauss(&seed) : 0));
                }
}

/* RMS of (z − zt) over the mask after removing the mean (heights have no absolute origin). */
static double rms_err(const float *z, const double *zt, const uint8_t *mask) {
        double s = 0, ss = 0;
        long n = 0;
        for (int t = 0; t < NX * NY; t++)
                if (!mask || mask[t]) {
                        double d = z[t] - zt[t];
                        s += d, ss += d * d, n++;
                }
        return sqrt(ss / n - (s / n) * (s / n));
}

/* ‖∇E(z)‖ of the energy the fusion minimises with no σ and no mask (every interior texel
 * has every row its neighbours allow): E = λ Σ (z − z0)² + Σ (z[t+1] − z[t−1] − 2p gx)² + Σ (z[t+NX] − z[t−NX] − 2p gy)²,
 * written from E itself, not from the solver's operator. */
static double energy_grad_norm(const float *z, const float *zin, const float *n, double lambda) {
        static double g[NX * NY];
        for (int t = 0; t < NX * NY; t++)
                g[t] = 2 * lambda * ((double) z[t] - zin[t]);
        for (int j = 0; j < NY; j++)
                for (int i = 0; i < NX; i++) {
                        int t = j * NX + i;
                        const float *q = &n[3 * t];
                        if (i > 0 && i + 1 < NX) {
                                double ex = (double) z[t + 1] - z[t - 1] - 2 * PITCH * (-q[0] / (double) q[2]);
                                g[t + 1] += 2 * ex, g[t - 1] -= 2 * ex;
                        }
                        if (j > 0 && j + 1 < NY) {
                                double ey = (double) z[t + NX] - z[t - NX] - 2 * PITCH * (-q[1] / (double) q[2]);
                                g[t + NX] += 2 * ey, g[t - NX] -= 2 * ey;
                        }
                }
        double ss = 0;
        for (int t = 0; t < NX * NY; t++)
                ss += g[t] * g[t];
        return sqrt(ss);
}

static double zt[NX * NY];
static float z[NX * NY], z0[NX * NY], nrm[3 * NX * NY];

int main(void) {
        struct imp_fuse_params p;
        struct imp_fuse_stats st;
        imp_fuse_params_default(&p);

        /* Noise-free positions consistent with the normals: the answer is the input. */
        make(zt, z, nrm, 0, 0);
        CHECK_OK(imp_fuse_heights(NX, NY, PITCH, z, nrm, NULL, NULL, &p, NULL, &st));
        CHECK_LE(rms_err(z, zt, NULL), 1e-6);
        CHECK_INT_EQ(st.n_texels, NX * NY);
        CHECK_INT_EQ(st.n_rows, (NX - 2) * NY + NX * (NY - 2));

        /* Noisy positions, exact normals: the noise is removed except in the band the
         * central differences cannot see (2-texel checkerboard) and below ω ≈ √λ. */
        make(zt, z0, nrm, 0, 42);
        memcpy(z, z0, sizeof z);
        double before = rms_err(z0, zt, NULL);
        CHECK_OK(imp_fuse_heights(NX, NY, PITCH, z, nrm, NULL, NULL, &p, NULL, &st));
        double after = rms_err(z, zt, NULL);
        fprintf(stderr, "noisy positions: rms %.2f µm -> %.2f µm, %d iterations, agreement %.2f° -> %.2f°\n",
                before * 1e3, after * 1e3, st.iterations, st.agree_deg_before, st.agree_deg_after);
        CHECK_NEAR(before, NOISE_MM, 0.1 * NOISE_MM);
        CHECK_LE(after, 0.4 * before);
        CHECK_LE(st.residual_rel, 1e-5);
        CHECK_GE(st.agree_deg_before, 3.0);       /* 5 µm noise over 0.1 mm: ~4–5° */
        CHECK_LE(st.agree_deg_after, 0.5 * st.agree_deg_before);
        CHECK_NEAR(st.change_rms_mm, NOISE_MM, 0.2 * NOISE_MM);

        /* Low frequencies come from the positions: normals with a slope bias of 0.01
         * (0.6°) would tilt integrated heights by 60 µm across the 6 mm grid; the fused
         * heights stay near the truth. */
        make(zt, z0, nrm, 0.01, 7);
        memcpy(z, z0, sizeof z);
        CHECK_OK(imp_fuse_heights(NX, NY, PITCH, z, nrm, NULL, NULL, &p, NULL, &st));
        after = rms_err(z, zt, NULL);
        fprintf(stderr, "biased normals: rms %.2f µm\n", after * 1e3);
        CHECK_LE(after, 0.6 * NOISE_MM);

        /* Holes in the mask and a NaN height: masked texels untouched, all finite; a
         * normal near grazing gives no rows; σ weights accepted. */
        make(zt, z0, nrm, 0, 9);
        memcpy(z, z0, sizeof z);
        static uint8_t mask[NX * NY];
        static float sigma[NX * NY];
        for (int t = 0; t < NX * NY; t++) {
                int i = t % NX, j = t / NX;
                mask[t] = !((i - 40) * (i - 40) + (j - 40) * (j - 40) < 100 || i == 80);
                sigma[t] = (float) (i < NX / 2 ? NOISE_MM : 2 * NOISE_MM);
        }
        z[5 * NX + 5] = NAN;
        nrm[3 * (6 * NX + 6) + 2] = 0.1f;
        z[40 * NX + 40] = 123.0f;                 /* masked: must stay */
        CHECK_OK(imp_fuse_heights(NX, NY, PITCH, z, nrm, sigma, mask, &p, NULL, &st));
        CHECK_NEAR(z[40 * NX + 40], 123.0, 0);
        CHECK(isnan(z[5 * NX + 5]));
        long finite = 0;
        for (int t = 0; t < NX * NY; t++)
                finite += mask[t] && isfinite(z[t]);
        CHECK_INT_EQ(finite, st.n_texels);
        mask[5 * NX + 5] = 0;                     /* the NaN is not a texel of the result */
        after = rms_err(z, zt, mask);
        CHECK_LE(after, 0.5 * NOISE_MM);

        /* The solve (one parallel region, per-thread ranges and partial sums) reaches the
         * minimum of the energy whatever the number of threads: the gradient of E at the
         * result is below 1e-5 of its value at z = 0 (‖b‖; the float heights limit it to
         * ~1e-6), and the heights of 1, 2 and 7 threads (10 800 texels: unequal ranges) agree within
         * 1e-9 mm. */
        make(zt, z0, nrm, 0, 11);
        static float zthr[3][NX * NY];
        static const float zero[NX * NY];
        double g0 = energy_grad_norm(zero, z0, nrm, p.lambda);
        for (int k = 0; k < 3; k++) {
#ifdef _OPENMP
                omp_set_num_threads(k == 2 ? 7 : k + 1);
#endif
                memcpy(zthr[k], z0, sizeof z0);
                CHECK_OK(imp_fuse_heights(NX, NY, PITCH, zthr[k], nrm, NULL, NULL, &p, NULL, &st));
                double gr = energy_grad_norm(zthr[k], z0, nrm, p.lambda) / g0;
                fprintf(stderr, "%d thread(s): %d iterations, |grad E| / |b| %.2e\n", k == 2 ? 7 : k + 1, st.iterations, gr);
                CHECK_LE(gr, 1e-5);
                CHECK_GE(st.iterations, 10);
        }
        double dmax = 0;
        for (int t = 0; t < NX * NY; t++)
                dmax = fmax(dmax, fmax(fabs(zthr[1][t] - zthr[0][t]), fabs(zthr[2][t] - zthr[0][t])));
        CHECK_LE(dmax, 1e-9);
        double before_g = energy_grad_norm(z0, z0, nrm, p.lambda) / g0;
        fprintf(stderr, "positions alone: |grad E| / |b| %.2e; threads differ by %.1e mm\n", before_g, dmax);
        CHECK_GE(before_g, 1e-3);   /* the check above can fail */

        /* Bad arguments. */
        CHECK_ERR(imp_fuse_heights(0, NY, PITCH, z, nrm, NULL, NULL, &p, NULL, NULL), -EINVAL);
        CHECK_ERR(imp_fuse_heights(NX, NY, 0, z, nrm, NULL, NULL, &p, NULL, NULL), -EINVAL);
        CHECK_ERR(imp_fuse_heights(NX, NY, PITCH, z, NULL, NULL, NULL, &p, NULL, NULL), -EINVAL);
        p.lambda = 0;
        CHECK_ERR(imp_fuse_heights(NX, NY, PITCH, z, nrm, NULL, NULL, &p, NULL, NULL), -EINVAL);
        return TEST_DONE();
}
