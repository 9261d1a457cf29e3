/* Photometric normals (pipeline/appearance/photometric.h): synthetic texels under a 48-light
 * near-field dome with known normals tilted up to 40°, ρd 0.2–0.8, a small mirror lobe
 * (ρs 0.05, k 10) and 1 % noise, seen through the local frame of a geometric normal that
 * is off by a few degrees; the degenerate cases keep the geometric normal with a flag. */
#include <errno.h>
#include <stdlib.h>
#include "btf-synth.h"
#include "pn-synth.h"
#include "numerics.h"
#include "photometric.h"
#include "test.h"

#define N_TEXELS 400

static const double cam_eye[3] = { 30, -20, 900 };

/* Samples of a texel at P with true normal nt, expressed in the local frame of the
 * geometric normal ng (what imp_btf_samples_extract gives when the heightfield has ng). */
static int make_samples(const double P[3], const double nt[3], const double ng[3], const struct imp_rig_light *L,
                        int n_lights, const struct imp_lafortune *b, double noise, uint64_t *rng,
                        struct imp_btf_sample *out) {
        int m = 0;
        for (int j = 0; j < n_lights; j++) {
                double vg[3], lg[3], ecg, vt[3], lt[3], ect;
                if (!synth_geometry(P, ng, cam_eye, &L[j], vg, lg, &ecg) || lg[2] < 0.02)
                        continue;
                synth_geometry(P, nt, cam_eye, &L[j], vt, lt, &ect);
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

static int cmp(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return x < y ? -1 : x > y;
}

/* ---- the whole grid: frames of grooves read between pixels ----------------------- */

#define GROOVE_PERIOD_MM 0.2          /* 4 camera pixels, the demo's bristle grooves */
#define GROOVE_SLOPE 0.35             /* slope amplitude (19°) */

/* Shading normal of a flat canvas with grooves along y (bump: heights stay 0). */
static void groove_normal(double x, double y, double n[3]) {
        double g = GROOVE_SLOPE * cos(2 * M_PI * (x + 0.25 * y) / GROOVE_PERIOD_MM), l = sqrt(g * g * 1.0625 + 1);
        n[0] = -g / l, n[1] = -0.25 * g / l, n[2] = 1 / l;
}

/* Mean error of imp_photometric_normals() on a 100 × 80 texel grid at 0.051 mm seen by a
 * 0.05 mm/pixel camera, with the given Lanczos order; *ret_refined: texels refined. */
static double grid_error(const struct imp_rig_light *L, int nl, int lanczos, int *ret_refined) {
        enum { W = 100, H = 80, CW = 130, CH = 110 };
        const double eye[3] = { 0, 0, 300 }, target[3] = { 0, 0, 0 }, pitch = 0.051;
        struct imp_pinhole cam;
        synth_camera(&cam, eye, target, CW, CH, 6000.0);
        struct imp_image *frames[48] = {};
        for (int j = 0; j < nl; j++) {
                CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, &frames[j]));
                for (int py = 0; py < CH; py++)
                        for (int px = 0; px < CW; px++) {
                                double d[3] = { (px - cam.cx) / cam.fx, (py - cam.cy) / cam.fy, 1 }, dw[3], n[3], wl[3], r = 0;
                                for (int i = 0; i < 3; i++)
                                        dw[i] = cam.R[i] * d[0] + cam.R[3 + i] * d[1] + cam.R[6 + i] * d[2];
                                double s = -eye[2] / dw[2], P[3] = { eye[0] + s * dw[0], eye[1] + s * dw[1], 0 };
                                groove_normal(P[0], P[1], n);
                                for (int i = 0; i < 3; i++) {
                                        wl[i] = L[j].pos_mm[i] - P[i];
                                        r += wl[i] * wl[i];
                                }
                                double nl_ = (n[0] * wl[0] + n[1] * wl[1] + n[2] * wl[2]) / sqrt(r);
                                *imp_image_f32(frames[j], px, py) = (float) (0.6 * imp_btf_light_irradiance(&L[j], P) * fmax(0, nl_));
                        }
        }
        static float hgt[W * H], nrm[3 * W * H], out[3 * W * H];
        static uint16_t flags[W * H];
        for (int t = 0; t < W * H; t++)
                hgt[t] = 0, nrm[3 * t] = nrm[3 * t + 1] = 0, nrm[3 * t + 2] = 1;
        struct imp_btf_heightfield hf = { W, H, pitch, hgt, nrm, NULL,
                                          { 1, 0, 0, -0.5 * (W - 1) * pitch, 0, 1, 0, -0.5 * (H - 1) * pitch, 0, 0, 1, 0, 0, 0, 0, 1 } };
        struct imp_btf_capture cap = { &cam, L, nl, (const struct imp_image *const *) frames, NULL };
        struct imp_btf_sample_params sp;
        struct imp_photometric_params p;
        struct imp_photometric_stats st;
        imp_btf_sample_params_default(&sp);
        imp_photometric_params_default(&p);
        p.lanczos = lanczos;
        struct imp_photometric_out po = { out, flags, NULL, NULL };
        CHECK_OK(imp_photometric_normals(&hf, &cap, &sp, &p, &po, &st));
        CHECK_INT_EQ(st.n_resampled > 0, lanczos > 0);
        double sum = 0;
        int n = 0;
        for (int v = 0; v < H; v++)
                for (int u = 0; u < W; u++) {
                        int t = v * W + u;
                        if (flags[t] & IMP_PN_KEPT)
                                continue;
                        double nt[3], x = hf.canvas_to_world[3] + u * pitch, y = hf.canvas_to_world[7] + v * pitch;
                        groove_normal(x, y, nt);
                        double c = out[3 * t] * nt[0] + out[3 * t + 1] * nt[1] + out[3 * t + 2] * nt[2];
                        sum += acos(fmin(1.0, c)) / SYNTH_DEG;
                        n++;
                }
        for (int j = 0; j < nl; j++)
                imp_image_free(frames[j]);
        *ret_refined = n;
        return n ? sum / n : 180;
}

/* Cast shadows the extractor does not predict (a frame wall beside a shadow-filled texel,
 * issue #4): a wall 1 mm away on the +x side, 5 mm high, blocks the lights it hides; those
 * samples read 2 % of their value. Median normal error over 100 texels tilted up to 20°,
 * with shadow_trim_sigma (what imp_photometric_normals uses on shadow-filled texels) and
 * without. */
static void test_cast_shadow(const struct imp_rig_light *L, int nl, uint64_t *rng) {
        static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
        enum { N = 100 };
        double e_trim[N], e_plain[N];
        struct imp_photometric_params plain, trim;
        imp_photometric_params_default(&plain);
        trim = plain;
        trim.shadow_trim_sigma = plain.filled_trim_sigma;
        trim.passes = plain.filled_passes;
        trim.max_dev_deg = plain.filled_max_dev_deg;
        CHECK(trim.shadow_trim_sigma > 0 && plain.shadow_trim_sigma == 0);
        int shadowed = 0, total = 0;
        for (int i = 0; i < N; i++) {
                double P[3] = { 0, 4 * (synth_uniform(rng) - 0.5), 0 }, z[3] = { 0, 0, 1 }, nt[3];
                tilt(z, 20.0 * synth_uniform(rng), 2 * M_PI * synth_uniform(rng), nt);
                struct imp_lafortune b = { .cx = -1, .cy = -1, .cz = 1, .k = 10 };
                for (int c = 0; c < 3; c++)
                        b.rho_d[c] = 0.5f, b.rho_s[c] = 0.05f;
                int m = make_samples(P, nt, z, L, nl, &b, 0.01, rng, s);
                /* The wall x = 1 mm, height 5 mm: a light at d is hidden when its ray
                 * reaches x = 1 below z = 5. */
                for (int k = 0, j = 0; j < nl && k < m; j++) {
                        const double *d = L[j].pos_mm;
                        if (d[2] <= 0)
                                continue;
                        double l[3] = { d[0] - P[0], d[1] - P[1], d[2] - P[2] };
                        double len = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
                        if (l[2] / len < 0.02)   /* make_samples' own skip (z = geometric normal) */
                                continue;
                        if (l[0] > 0 && (1 - P[0]) / l[0] * l[2] < 5) {
                                for (int c = 0; c < 3; c++)
                                        s[k].value[c] *= 0.02f;
                                shadowed++;
                        }
                        total++;
                        k++;
                }
                struct imp_pn_texel r;
                CHECK_OK(imp_photometric_texel(s, m, &trim, &r));
                e_trim[i] = err_deg(&r, z, nt);
                CHECK_OK(imp_photometric_texel(s, m, &plain, &r));
                e_plain[i] = err_deg(&r, z, nt);
        }
        qsort(e_trim, N, sizeof *e_trim, cmp);
        qsort(e_plain, N, sizeof *e_plain, cmp);
        printf("cast shadows (%d of %d samples): median error with trimming %.2f deg, without %.2f deg\n",
               shadowed, total, e_trim[N / 2], e_plain[N / 2]);
        CHECK_GE(shadowed, total / 5);
        CHECK_LE(e_trim[N / 2], 1.0);
        CHECK_LE(e_trim[N / 2], 0.5 * e_plain[N / 2]);
}

/* The condition number a texel reports is its normal matrix's largest / smallest eigenvalue
 * (closed form in photometric.c; Jacobi here, to 1e-6), and max_cond cuts exactly there:
 * 1e-6 above it the texel is solved, 1e-6 below it is flagged ill-conditioned. One solve with
 * every sample taking part (no attached-shadow test; no light near the mirror direction), on
 * one low ring (cond ≈ 7), one high ring (≈ 60) and the whole dome. */
static void test_cond(const struct imp_rig_light *L, int nl, uint64_t *rng) {
        static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
        static const int first[3] = { 0, 40, 0 }, count[3] = { 8, 8, 48 };
        const double P[3] = { 0, 0, 0 }, nt[3] = { 0, 0, 1 };
        const struct imp_lafortune b = { { 0.5f, 0.5f, 0.5f }, { 0, 0, 0 }, -1, -1, 1, 10 };
        for (int c = 0; c < 3; c++) {
                CHECK(first[c] + count[c] <= nl);
                int m = make_samples(P, nt, nt, L + first[c], count[c], &b, 0.01, rng, s);
                CHECK_INT_EQ(m, count[c]);
                double A[9] = { 0 }, lam[3], vec[9];
                for (int i = 0; i < m; i++)
                        for (int j = 0; j < 9; j++)
                                A[j] += (double) s[i].l[j / 3] * s[i].l[j % 3];
                imp_eigen_sym3(A, lam, vec);
                double cond = lam[2] / lam[0];
                struct imp_photometric_params p;
                imp_photometric_params_default(&p);
                p.passes = 1;
                p.spec_cone_deg = 0;
                p.min_cos = -2;
                struct imp_pn_texel r;
                p.max_cond = cond * (1 + 1e-6);
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                printf("cond: lights %d..%d: %.4f (Jacobi %.4f)\n", first[c], first[c] + count[c] - 1, r.cond, cond);
                CHECK_NEAR(r.cond / cond, 1.0, 1e-6);
                CHECK(!(r.flags & IMP_PN_ILL_COND));
                p.max_cond = cond * (1 - 1e-6);
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                CHECK(r.flags & IMP_PN_ILL_COND);
        }
}

/* The mirror cone follows the normal from pass to pass: glossy texels (ρs 0.6, k 40)
 * tilted 20° seen through a flat geometric frame. The first solve leaves out the samples
 * near the flat normal's mirror direction; the later ones must leave out those near the
 * tilted normal's, where the lobe is, or the lobe pulls the normal. Printed: the largest
 * error over 16 azimuths (which samples take part is kept per normal in the model). */
static void test_cone_follows(const struct imp_rig_light *L, int nl, uint64_t *rng) {
        static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
        struct imp_photometric_params p;
        imp_photometric_params_default(&p);
        const double P[3] = { 0, 0, 0 }, z[3] = { 0, 0, 1 };
        const struct imp_lafortune b = { { 0.3f, 0.3f, 0.3f }, { 0.6f, 0.6f, 0.6f }, -1, -1, 1, 40 };
        double worst = 0;
        int kept = 0;
        for (int a = 0; a < 16; a++) {
                double nt[3];
                tilt(z, 20.0, 2 * M_PI * a / 16, nt);
                int m = make_samples(P, nt, z, L, nl, &b, 0.002, rng, s);
                struct imp_pn_texel r;
                CHECK_OK(imp_photometric_texel(s, m, &p, &r));
                kept += (r.flags & IMP_PN_KEPT) != 0;
                worst = fmax(worst, err_deg(&r, z, nt));
        }
        printf("glossy, tilted 20 deg: largest error %.3f deg, %d of 16 kept\n", worst, kept);
        CHECK_INT_EQ(kept, 0);
        /* 0.06° here; 0.42° when the later solves keep the first normal's cone */
        CHECK_LE(worst, 0.2);
}

int main(void) {
        struct imp_rig_light L[48];
        static const double elev[6] = { 15, 28, 41, 54, 67, 80 }, centre[3] = { 0, 0, 0 };
        int nl = synth_dome(L, elev, 6, 8, 600.0, centre, 1.0, 0.0);
        CHECK_INT_EQ(nl, 48);
        struct imp_photometric_params p;
        imp_photometric_params_default(&p);
        uint64_t rng = 0x9e3779b97f4a7c15ULL;
        test_cone_follows(L, nl, &rng);
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

        /* Texels between camera pixels on grooves of 4 pixels per period: reading the
         * frames with the Lanczos kernel recovers the normals that bilinear reading
         * blurs (imp_photometric_params.lanczos). */
        {
                int n_lz, n_bil;
                double e_lz = grid_error(L, nl, 3, &n_lz), e_bil = grid_error(L, nl, 0, &n_bil);
                printf("grooves between pixels: mean error Lanczos-3 %.2f deg (%d texels), bilinear %.2f deg (%d)\n",
                       e_lz, n_lz, e_bil, n_bil);
                CHECK_GE(n_lz, 100 * 80 * 95 / 100);
                CHECK_LE(e_lz, 0.6 * e_bil);
                CHECK_LE(e_lz, 1.0);
                struct imp_photometric_params bad;
                imp_photometric_params_default(&bad);
                bad.lanczos = 9;
                struct imp_btf_sample_params sp;
                imp_btf_sample_params_default(&sp);
                float nrm[3] = { 0, 0, 1 }, hgt[1] = { 0 }, out[3];
                struct imp_btf_heightfield hf = { 1, 1, 0.05, hgt, nrm, NULL, { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 } };
                struct imp_pinhole cam;
                const double eye[3] = { 0, 0, 300 }, target[3] = { 0, 0, 0 };
                synth_camera(&cam, eye, target, 8, 8, 6000.0);
                struct imp_image *f = NULL;
                CHECK_OK(imp_image_new(8, 8, 1, IMP_PIX_F32, &f));
                const struct imp_image *fr[1] = { f };
                struct imp_btf_capture cap = { &cam, L, 1, fr, NULL };
                struct imp_photometric_out po = { out, NULL, NULL, NULL };
                CHECK_ERR(imp_photometric_normals(&hf, &cap, &sp, &bad, &po, NULL), -EINVAL);
                imp_image_free(f);
        }
        test_cast_shadow(L, nl, &rng);
        test_cond(L, nl, &rng);
        return test_failures_ ? 1 : 0;
}
