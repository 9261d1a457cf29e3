/* What one normal per texel can promise (pipeline/appearance/normal-trust.h).
 *  1. A roof: two planes tilted ±25° meeting at a ridge that runs through a column of
 *     texels. The copy's normal there is the blend over the texel's footprint (30 % on
 *     one side), the truth at the texel's centre the other side's: 15° off, while every
 *     stage gave σ_n = 1°. With the rules, no unflagged texel is beyond 3σ_n nor more
 *     than 10° off; without them (rough_k 0, edge off) the ridge is, so the check can fail.
 *  2. A texel whose normal is not vouched for (photometric_rejected, σ_n 6°) passes its σ
 *     and NORMAL_UNCERTAIN to its 8 neighbours and no further; frame_adjacent does not.
 *  3. Grooves: aliased ones (2.3 texels per period) must be flagged by rule 3, resolved
 *     ones (8–10 texels per period, bending up to 24° between neighbours) must not.
 *  4. Bad arguments.
 *  5. The cache of rules 1 and 3's reading (imp_normal_trust_cached): two calls on the
 *     same mask and normals with other σ_n and flags, the second reading the first's
 *     cache, give bit for bit what two uncached calls give; a cache filled from other
 *     normals changes the result (the second call reads it instead of recomputing). */
#include <errno.h>
#include <stdbool.h>
#include <stdint.h>
#include <string.h>
#include "normal-trust.h"
#include "quality.h"
#include "test.h"

#define N 40
#define DEG (M_PI / 180.0)

static void set_normal(float *nx, float *ny, int t, double tilt_deg) {
        nx[t] = (float) sin(tilt_deg * DEG);
        ny[t] = 0;
}

static double angle_deg(double ax, double bx) {   /* two normals tilted about y */
        double az = sqrt(1 - ax * ax), bz = sqrt(1 - bx * bx);
        return acos(fmin(1.0, ax * bx + az * bz)) / DEG;
}

/* Runs the roof with p; returns the number of unflagged texels beyond 3σ or over 10°. */
static int roof(const struct imp_normal_trust_params *p, int *ret_flagged) {
        static float nx[N * N], ny[N * N], sig[N * N];
        static uint16_t fl[N * N];
        static uint8_t mask[N * N];
        static double truth[N * N];
        const double tilt = 25, edge = 19.8;  /* ridge at x = 19.8: texel 20 spans 19.5..20.5 */
        for (int j = 0; j < N; j++)
                for (int i = 0; i < N; i++) {
                        int t = j * N + i;
                        mask[t] = 1;
                        fl[t] = 0;
                        sig[t] = 1.0f;
                        double left = fmin(1.0, fmax(0.0, edge - (i - 0.5)));   /* footprint share left of the ridge */
                        double a = sin(tilt * DEG), b = sin(-tilt * DEG);
                        double vx = left * a + (1 - left) * b, vz = cos(tilt * DEG);
                        double l = sqrt(vx * vx + vz * vz);
                        set_normal(nx, ny, t, asin(vx / l) / DEG);
                        truth[t] = i < edge ? a : b;
                }
        struct imp_normal_trust_stats st;
        CHECK_OK(imp_normal_trust(N, N, mask, nx, ny, sig, fl, p, &st));
        int bad = 0, flagged = 0;
        for (int t = 0; t < N * N; t++) {
                double e = angle_deg(nx[t], truth[t]);
                if (fl[t]) {
                        flagged++;
                        continue;
                }
                bad += e > 3 * sig[t] || e > 10;
        }
        *ret_flagged = flagged;
        return bad;
}

static void test_roof(void) {
        struct imp_normal_trust_params p, off;
        imp_normal_trust_params_default(&p);
        off = p;
        off.rough_k = 0;
        off.edge = false;
        off.fine_k = 0;
        int fl_on, fl_off;
        int bad_on = roof(&p, &fl_on), bad_off = roof(&off, &fl_off);
        printf("roof: %d bad unflagged texels with the rules (%d flagged), %d without (%d flagged)\n", bad_on, fl_on,
               bad_off, fl_off);
        CHECK_INT_EQ(bad_on, 0);
        CHECK_INT_EQ(bad_off, N);          /* the ridge's column: the check can fail */
        CHECK_INT_EQ(fl_off, 0);
        CHECK_LE(fl_on, 8 * N);            /* the two columns either side of the ridge, the
                                              5-texel windows of rule 3 and their rims */
}

static void test_edge(void) {
        static float nx[N * N], ny[N * N], sig[N * N];
        static uint16_t fl[N * N];
        static uint8_t mask[N * N];
        for (int t = 0; t < N * N; t++) {
                mask[t] = 1;
                nx[t] = ny[t] = 0;
                sig[t] = 1.0f;
                fl[t] = 0;
        }
        int c = 10 * N + 10, f = 30 * N + 30;
        fl[c] = IMP_TEXEL_PHOTOMETRIC_REJECTED;
        sig[c] = 6.0f;
        fl[f] = IMP_TEXEL_FRAME_ADJACENT;
        struct imp_normal_trust_params p;
        imp_normal_trust_params_default(&p);
        struct imp_normal_trust_stats st;
        CHECK_OK(imp_normal_trust(N, N, mask, nx, ny, sig, fl, &p, &st));
        CHECK_INT_EQ(st.n_texels, N * N);
        CHECK_INT_EQ(st.n_edge_flagged, 8);
        CHECK_INT_EQ(st.n_rough_flagged, 0);
        for (int dj = -2; dj <= 2; dj++)
                for (int di = -2; di <= 2; di++) {
                        int t = c + dj * N + di;
                        bool ring = abs(di) <= 1 && abs(dj) <= 1 && (di || dj);
                        CHECK_MSG(!!(fl[t] & IMP_TEXEL_NORMAL_UNCERTAIN) == (ring || !(di || dj)), "(%d, %d): flags %u", di, dj, fl[t]);
                        if (ring)
                                CHECK_NEAR(sig[t], 6.0, 1e-6);
                        else if (di || dj)
                                CHECK_NEAR(sig[t], 1.0, 1e-6);
                }
        CHECK_INT_EQ(fl[f + 1], 0);        /* frame_adjacent is where, not how well */
        CHECK_INT_EQ(fl[c] & IMP_TEXEL_PHOTOMETRIC_REJECTED, IMP_TEXEL_PHOTOMETRIC_REJECTED);
}

/* Grooves of period P texels along x whose normal tilts by ±amp° (the phase drifts along
 * y); the copy's normal is the mean over a footprint fw texels wide (the pixel, the
 * lens's blur and the resampling), the truth the texel centre's. Returns the unflagged
 * texels beyond 3σ_n (bad3) and over 10° (bad10), and the flagged count. */
static void grooves(const struct imp_normal_trust_params *p, double P, double amp, double fw, int *ret_bad3,
                    int *ret_bad10, int *ret_flagged) {
        static float nx[N * N], ny[N * N], sig[N * N];
        static uint16_t fl[N * N];
        static uint8_t mask[N * N];
        static double truth[N * N];
        const int S = 64;   /* sub-samples of a footprint */
        for (int j = 0; j < N; j++)
                for (int i = 0; i < N; i++) {
                        int t = j * N + i;
                        double ph = 2 * M_PI * j / 23.0, vx = 0, vz = 0;
                        for (int k = 0; k < S; k++) {
                                double x = i + fw * ((k + 0.5) / S - 0.5), a = amp * DEG * sin(2 * M_PI * x / P + ph);
                                vx += sin(a) / S, vz += cos(a) / S;
                        }
                        mask[t] = 1;
                        fl[t] = 0;
                        sig[t] = 1.0f;
                        set_normal(nx, ny, t, atan2(vx, vz) / DEG);
                        truth[t] = sin(amp * DEG * sin(2 * M_PI * i / P + ph));
                }
        struct imp_normal_trust_stats st;
        CHECK_OK(imp_normal_trust(N, N, mask, nx, ny, sig, fl, p, &st));
        *ret_bad3 = *ret_bad10 = *ret_flagged = 0;
        for (int t = 0; t < N * N; t++) {
                double e = angle_deg(nx[t], truth[t]);
                if (fl[t]) {
                        ++*ret_flagged;
                        continue;
                }
                *ret_bad3 += e > 3 * sig[t];
                *ret_bad10 += e > 10;
        }
}

static void test_grooves(void) {
        struct imp_normal_trust_params p, off;
        imp_normal_trust_params_default(&p);
        off = p;
        off.fine_k = 0;
        int b3, b10, f, b3o, b10o, fo;
        /* near the grid's Nyquist, seen through a 1.5-texel footprint: the copy shows an
         * aliased trace of them (±9°), the truth bends by ±20° */
        grooves(&p, 2.3, 20, 1.5, &b3, &b10, &f);
        grooves(&off, 2.3, 20, 1.5, &b3o, &b10o, &fo);
        printf("grooves of 2.3 texels, ±20°: %d beyond 3σ, %d over 10° unflagged, %d flagged with rule 3; "
               "%d, %d, %d without\n", b3, b10, f, b3o, b10o, fo);
        CHECK_INT_EQ(b10, 0);
        CHECK_LE(b3, N * N / 100);
        CHECK(b10o > N * N / 100);          /* without rule 3 the check can fail */
        /* resolved relief: 10 texels per period, ±20°: rule 3 leaves most of it unflagged */
        grooves(&p, 10, 20, 1.5, &b3, &b10, &f);
        grooves(&off, 10, 20, 1.5, &b3o, &b10o, &fo);
        printf("grooves of 10 texels, ±20°: %d beyond 3σ, %d over 10° unflagged, %d flagged with rule 3; "
               "%d, %d, %d without\n", b3, b10, f, b3o, b10o, fo);
        CHECK_INT_EQ(b10, 0);
        CHECK_INT_EQ(b3, 0);
        CHECK_LE(f, N * N / 4);
}

/* Resolved relief that bends hard between neighbours (8 texels per period, ±30°, as on
 * the demo's strokes): the footprint's blend is off by ≈ 0.2× the texel-scale bend, which
 * rules 1–2 already cover, so rule 3 must not flag it: it adds at most 5 % to what rules
 * 1–2 flag (a bend measured at the texel's scale alone flagged all of it), and what it
 * leaves unflagged stays honest. */
static void test_resolved(void) {
        struct imp_normal_trust_params p, off;
        imp_normal_trust_params_default(&p);
        off = p;
        off.fine_k = 0;
        int b3, b10, f, b3o, b10o, fo;
        grooves(&p, 8, 30, 1.5, &b3, &b10, &f);
        grooves(&off, 8, 30, 1.5, &b3o, &b10o, &fo);
        printf("grooves of 8 texels, ±30°: %d beyond 3σ, %d over 10° unflagged, %d flagged with rule 3; "
               "%d, %d, %d without\n", b3, b10, f, b3o, b10o, fo);
        CHECK_INT_EQ(b10, 0);
        CHECK_INT_EQ(b3, 0);
        CHECK_LE(f - fo, N * N / 20);
        CHECK(fo < N * N / 2);              /* rules 1–2 leave most of it: rule 3 decides */
}

static void test_args(void) {
        float v = 0, s = 1;
        uint16_t f = 0;
        uint8_t m = 1;
        struct imp_normal_trust_params p;
        imp_normal_trust_params_default(&p);
        CHECK_ERR(imp_normal_trust(0, 1, &m, &v, &v, &s, &f, &p, NULL), -EINVAL);
        CHECK_ERR(imp_normal_trust(1, 1, NULL, &v, &v, &s, &f, &p, NULL), -EINVAL);
        p.rough_k = NAN;
        CHECK_ERR(imp_normal_trust(1, 1, &m, &v, &v, &s, &f, &p, NULL), -EINVAL);
        p.rough_k = 0.1;
        CHECK_OK(imp_normal_trust(1, 1, &m, &v, &v, &s, &f, &p, NULL));
        CHECK_INT_EQ(f, 0);
        CHECK_NEAR(s, 1.0, 1e-6);
}

/* Random normals (bends up to ~20° between neighbours), a hole in the mask, σ_n and flags
 * drawn per call. */
static void random_field(unsigned seed, float *nx, float *ny, uint8_t *mask, float *sig, uint16_t *fl) {
        for (int t = 0; t < N * N; t++) {
                seed = seed * 1103515245u + 12345u;
                double a = ((seed >> 8) & 0xffff) / 65536.0, b = ((seed >> 4) & 0xfff) / 4096.0;
                nx[t] = (float) (0.35 * sin(0.7 * (t % N) + 3 * a));
                ny[t] = (float) (0.35 * cos(0.5 * (t / N)) * b);
                mask[t] = !(t % N > 10 && t % N < 14 && t / N > 5 && t / N < 30);
                sig[t] = (float) (0.5 + 4 * a);
                fl[t] = b < 0.05 ? IMP_TEXEL_PHOTOMETRIC_REJECTED : 0;
        }
}

static void test_cache(void) {
        static float nx[N * N], ny[N * N], other[N * N], s1[N * N], s2[N * N], c1[N * N], c2[N * N];
        static uint16_t f1[N * N], f2[N * N], g1[N * N], g2[N * N];
        static uint8_t mask[N * N];
        struct imp_normal_trust_params p;
        imp_normal_trust_params_default(&p);
        random_field(7, nx, ny, mask, s1, f1);
        random_field(8, other, other, mask, s2, f2);   /* σ_n and flags of a second call */
        random_field(7, nx, ny, mask, s1, f1);
        memcpy(c1, s1, sizeof s1), memcpy(g1, f1, sizeof f1);
        memcpy(c2, s2, sizeof s2), memcpy(g2, f2, sizeof f2);
        struct imp_normal_trust_stats a1, a2, b1, b2;
        CHECK_OK(imp_normal_trust(N, N, mask, nx, ny, s1, f1, &p, &a1));
        CHECK_OK(imp_normal_trust(N, N, mask, nx, ny, s2, f2, &p, &a2));
        struct imp_normal_trust_cache cache = {};
        CHECK_OK(imp_normal_trust_cached(N, N, mask, nx, ny, c1, g1, &p, &cache, &b1));
        CHECK(cache.angle_max != NULL && cache.fine_rms != NULL);
        CHECK_OK(imp_normal_trust_cached(N, N, mask, nx, ny, c2, g2, &p, &cache, &b2));
        CHECK(memcmp(s1, c1, sizeof s1) == 0 && memcmp(f1, g1, sizeof f1) == 0);
        CHECK(memcmp(s2, c2, sizeof s2) == 0 && memcmp(f2, g2, sizeof f2) == 0);
        CHECK(memcmp(&a1, &b1, sizeof a1) == 0 && memcmp(&a2, &b2, sizeof a2) == 0);
        CHECK(a2.n_rough_flagged + a2.n_fine_flagged > 0);   /* the rules did something */
        /* a cache of other normals is read, not recomputed: the result moves */
        imp_normal_trust_cache_done(&cache);
        for (int t = 0; t < N * N; t++)
                other[t] = 0.5f * nx[t];
        random_field(8, c2, c2, mask, c2, g2);
        CHECK_OK(imp_normal_trust_cached(N, N, mask, other, ny, c1, g1, &p, &cache, NULL));
        CHECK_OK(imp_normal_trust_cached(N, N, mask, nx, ny, c2, g2, &p, &cache, NULL));
        CHECK(memcmp(s2, c2, sizeof s2) != 0);
        imp_normal_trust_cache_done(&cache);
        CHECK(cache.angle_max == NULL && cache.fine_rms == NULL);
}

int main(void) {
        test_cache();
        test_roof();
        test_edge();
        test_grooves();
        test_resolved();
        test_args();
        return TEST_DONE();
}
