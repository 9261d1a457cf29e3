/* Photometric normals (pipeline/photometric.h): synthetic texels under a 48-light
 * near-field dome with known normals tilted up to 40°, ρd 0.2–0.8, a small mirror lobe
 * (ρs 0.05, k 10) and 1 % noise, seen through the local frame of a geometric normal that
 * is off by a few degrees; the degenerate cases keep the geometric normal with a flag. */
#include <errno.h>
#include <stdlib.h>
#include "btf-synth.h"
#include "photometric.h"
#include "test.h"

#define N_TEXELS 400

static const double eye[3] = { 30, -20, 900 };

/* Samples of a texel at P with true normal nt, expressed in the local frame of the
 * geometric normal ng (what imp_btf_samples_extract gives when the heightfield has ng). */
static int make_samples(const double P[3], const double nt[3], const double ng[3], const struct imp_rig_light *L,
                        int n_lights, const struct imp_lafortune *b, double noise, uint64_t *rng,
                        struct imp_btf_sample *out) {
        int m = 0;
        for (int j = 0; j < n_lights; j++) {
                double vg[3], lg[3], ecg, vt[3], lt[3], ect;
                if (!synth_geometry(P, ng, eye, &L[j], vg, lg, &ecg) || lg[2] < 0.02)
                        continue;
                synth_geometry(P, nt, eye, &L[j], vt, lt, &ect);
                double E = imp_btf_light_irradiance(&L[j], P);
                struct imp_btf_sample *s = &out[m++];
                for (int c = 0; c < 3; c++) {
                        double V = E * fmax(0.0, lt[2]) * imp_lafortune_eval(b, c, vt, lt);
                        s->value[c] = (float) (V * (1.0 + noise * synth_gauss(rng)));
                        s->v[c] = (float) vg[c];
                        s->l[c] = (float) lg[c];
                }
                s->e_cos = (float) (E * lg[2]);
        }
        return m;
}

static void tilt(const double n0[3], double deg, double az, double ret[3]) {
        double t[3], b[3], th = deg * SYNTH_DEG;
        imp_local_frame(n0, t, b);
        for (int k = 0; k < 3; k++)
                ret[k] = cos(th) * n0[k] + sin(th) * (cos(az) * t[k] + sin(az) * b[k]);
}

/* Local photometric normal (frame of ng) → world; angle to nt in degrees. */
static double err_deg(const struct imp_pn_texel *r, const double ng[3], const double nt[3]) {
        double t[3], b[3], n[3], d = 0, len = 0;
        imp_local_frame(ng, t, b);
        for (int k = 0; k < 3; k++) {
                n[k] = r->n[0] * t[k] + r->n[1] * b[k] + r->n[2] * ng[k];
                len += n[k] * n[k];
        }
        for (int k = 0; k < 3; k++)
                d += n[k] * nt[k] / sqrt(len);
        return acos(fmin(1.0, d)) / SYNTH_DEG;
}

static int cmp(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return x < y ? -1 : x > y;
}

int main(void) {
        struct imp_rig_light L[48];
        static const double elev[6] = { 15, 28, 41, 54, 67, 80 }, centre[3] = { 0, 0, 0 };
        int nl = synth_dome(L, elev, 6, 8, 600.0, centre, 1.0, 0.0);
        CHECK_INT_EQ(nl, 48);
        struct imp_photometric_params p;
        imp_photometric_params_default(&p);
        uint64_t rng = 0x9e3779b97f4a7c15ULL;
        static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
        double errs[N_TEXELS], geo_errs[N_TEXELS];
        int n_ok = 0, n_flag = 0;
        for (int i = 0; i < N_TEXELS; i++) {
                double P[3] = { 40 * (synth_uniform(&rng) - 0.5), 40 * (synth_uniform(&rng) - 0.5), 0 };
                double z[3] = { 0, 0, 1 }, nt[3], ng[3];
                tilt(z, 40.0 * synth_uniform(&rng), 2 * M_PI * synth_uniform(&rng), nt);
                double gdev = 8.0 * synth_uniform(&rng);   /* geometric normal off by up to 8° */
                tilt(nt, gdev, 2 * M_PI * synth_uniform(&rng), ng);
                struct imp_lafortune b = { .cx = -1, .cy = -1, .cz = 1, .k = 10 };
                for (int c = 0; c < 3; c++) {
                        b.rho_d[c] = (float) (0.2 + 0.6 * synth_uniform(&rng));
                        b.rho_s[c] = 0.05f;
                }
                int m = make_samples(P, nt, ng, L, nl, &b, 0.01, &rng, s);
                struct imp_pn_texel r;
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                CHECK_FINITE(r.n[0] + r.n[1] + r.n[2] + r.albedo + r.dev_deg + r.sigma_deg + r.rms + r.cond);
                geo_errs[i] = gdev;
                errs[i] = err_deg(&r, ng, nt);
                if (r.flags & IMP_PN_KEPT)
                        n_flag++;
                else
                        n_ok++;
        }
        qsort(errs, N_TEXELS, sizeof *errs, cmp);
        qsort(geo_errs, N_TEXELS, sizeof *geo_errs, cmp);
        printf("normal error median %.3f deg, p90 %.3f, max %.3f (geometric median %.3f); refined %d, kept %d\n",
               errs[N_TEXELS / 2], errs[N_TEXELS * 9 / 10], errs[N_TEXELS - 1], geo_errs[N_TEXELS / 2], n_ok, n_flag);
        CHECK_LE(errs[N_TEXELS / 2], 1.0);
        CHECK_LE(errs[N_TEXELS * 9 / 10], 2.5);
        CHECK_GE(n_ok, N_TEXELS * 95 / 100);

        /* Two usable samples: flagged, the geometric normal kept, finite outputs. */
        {
                double P[3] = { 0, 0, 0 }, nt[3] = { 0, 0, 1 };
                struct imp_lafortune b = { { 0.5f, 0.5f, 0.5f }, { 0.05f, 0.05f, 0.05f }, -1, -1, 1, 10 };
                int m = make_samples(P, nt, nt, L, nl, &b, 0.01, &rng, s);
                CHECK_GE(m, 2);
                struct imp_pn_texel r;
                CHECK_OK(imp_photometric_texel(s, 2, &p, &r));
                CHECK(r.flags & IMP_PN_FEW_SAMPLES);
                CHECK_NEAR(r.n[2], 1.0, 0.0);
                CHECK_FINITE(r.albedo + r.dev_deg + r.sigma_deg + r.rms + r.cond);
                CHECK_OK(imp_photometric_texel(s, 0, &p, &r));
                CHECK(r.flags & IMP_PN_FEW_SAMPLES);

                /* One light direction repeated: ill-conditioned. */
                for (int k = 1; k < 12; k++)
                        s[k] = s[0];
                CHECK_OK(imp_photometric_texel(s, 12, &p, &r));
                CHECK(r.flags & IMP_PN_ILL_COND);
                CHECK_NEAR(r.n[2], 1.0, 0.0);
                CHECK_FINITE(r.cond);

                /* Black paint: no shading signal. */
                struct imp_lafortune black = { .cx = -1, .cy = -1, .cz = 1, .k = 10 };
                m = make_samples(P, nt, nt, L, nl, &black, 0.01, &rng, s);
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                CHECK(r.flags & IMP_PN_DARK);
                CHECK_NEAR(r.n[2], 1.0, 0.0);

                /* Geometric normal 35° off the shading: disagreement, geometric kept. */
                double ng[3];
                tilt(nt, 35.0, 0.3, ng);
                m = make_samples(P, nt, ng, L, nl, &b, 0.01, &rng, s);
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                CHECK(r.flags & IMP_PN_DISAGREES);
                CHECK_NEAR(r.n[2], 1.0, 0.0);
                CHECK_NEAR(r.dev_deg, 35.0, 3.0);

                /* Non-finite and bad samples are ignored; bad params rejected. */
                m = make_samples(P, nt, nt, L, nl, &b, 0.0, &rng, s);
                s[0].value[0] = NAN;
                s[1].e_cos = -1;
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                CHECK(!(r.flags & IMP_PN_KEPT));
                CHECK_LE(r.dev_deg, 0.5);
                CHECK_ERR(imp_photometric_texel(s, IMP_BTF_MAX_SAMPLES + 1, &p, &r), -E2BIG);
                struct imp_photometric_params bad = p;
                bad.passes = 0;
                CHECK_ERR(imp_photometric_texel(s, m, &bad, &r), -EINVAL);
        }
        return test_failures_ ? 1 : 0;
}
