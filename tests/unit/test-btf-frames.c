/* The BTF fit's own local frames (btf.h struct imp_btf_frames, photometric.h
 * imp_photometric_frames()): the fit estimates each texel's frame with the photometric
 * model on the samples it reads itself (the bilinear values) and fits in that frame.
 * On a flat canvas painted with bumps (shading normals up to ≈ 17° off the geometric
 * (0, 0, 1)), with a masked corner and shadow-filled texels (mask value 2):
 *  - the frames are the model's normals of the fit's own samples: bit for bit what
 *    imp_photometric_normals() gives without its Lanczos re-read (lanczos = 0: the bilinear
 *    values, the filled texels' parameters), and for some texels imp_photometric_texel()
 *    on imp_btf_extract_texel()'s samples turned to the canvas frame;
 *  - each texel is fitted in its frame: imp_btf_fit_texel() on the samples extracted in
 *    the frames gives the same texel byte for byte;
 *  - the estimator runs once per texel the fit sees (not on masked ones), and a fit
 *    without frames never runs it;
 *  - the ROTATE mode estimates the same frames and, without the grazing ring's samples
 *    the geometric frame cut, fits within 1 % of ρd. */
#include <string.h>
#include "btf-synth.h"
#include "photometric.h"
#include "test.h"

enum { W = 70, H = 60, CW = 100, CH = 90, NL = 50 };

static const double pitch = 0.051, eye[3] = { 0, 0, 300 };

/* Shading normal of the painted bumps at canvas point (x, y) (mm). */
static void bump_normal(double x, double y, double n[3]) {
        double gx = 0.3 * cos(2 * M_PI * x / 0.7), gy = 0.2 * sin(2 * M_PI * (x + 2 * y) / 0.9);
        double l = sqrt(gx * gx + gy * gy + 1);
        n[0] = -gx / l, n[1] = -gy / l, n[2] = 1 / l;
}

/* Frame j: the bumpy canvas at z = 0, Lambertian ρ 0.5 with 1 % noise, mono f32. */
static void make_frame(const struct imp_pinhole *cam, const struct imp_rig_light *L, uint64_t *rng,
                       struct imp_image **ret) {
        CHECK_OK(imp_image_new(CW, CH, 1, IMP_PIX_F32, ret));
        for (int py = 0; py < CH; py++)
                for (int px = 0; px < CW; px++) {
                        double d[3] = { (px - cam->cx) / cam->fx, (py - cam->cy) / cam->fy, 1 }, dw[3], n[3];
                        for (int i = 0; i < 3; i++)
                                dw[i] = cam->R[i] * d[0] + cam->R[3 + i] * d[1] + cam->R[6 + i] * d[2];
                        double t = -eye[2] / dw[2], P[3] = { eye[0] + t * dw[0], eye[1] + t * dw[1], 0 }, v[3], l[3];
                        double ec = 0;
                        bump_normal(P[0], P[1], n);
                        bool lit = synth_geometry(P, n, eye, L, v, l, &ec);
                        *imp_image_f32(*ret, px, py) = (float) (lit ? 0.5 * ec * (1 + 0.01 * synth_gauss(rng)) : 0.0);
                }
}

/* The model's estimator, counting its calls. */
struct counted {
        const struct imp_btf_frames *inner;
        long calls;
};
static bool counted_estimate(const void *data, long texel, const struct imp_btf_sample *s, int n, const float n0[3],
                             float ret_n[3]) {
        struct counted *c = (struct counted *) data;
        __atomic_add_fetch(&c->calls, 1, __ATOMIC_RELAXED);
        return c->inner->estimate(c->inner->data, texel, s, n, n0, ret_n);
}

static double angle_deg(const float *a, const float *b) {
        double c = (double) a[0] * b[0] + (double) a[1] * b[1] + (double) a[2] * b[2];
        return acos(fmin(1.0, c)) / SYNTH_DEG;
}

int main(void) {
        struct imp_rig_light L[NL];
        /* a ring at 0.5°: below min_cos_l in the geometric frame, above it in frames
         * tilted towards it (what ROTATE misses) */
        static const double elev[5] = { 0.5, 20, 35, 55, 75 }, centre[3] = { 0, 0, 0 };
        CHECK_INT_EQ(synth_dome(L, elev, 5, 10, 600.0, centre, 1.0, 0.0), NL);
        struct imp_pinhole cam;
        const double target[3] = { 0, 0, 0 };
        synth_camera(&cam, eye, target, CW, CH, 6000.0);
        uint64_t rng = 0x9e3779b97f4a7c15ULL;
        struct imp_image *frames[NL];
        for (int j = 0; j < NL; j++)
                make_frame(&cam, &L[j], &rng, &frames[j]);
        struct imp_btf_capture cap = { &cam, L, NL, (const struct imp_image *const *) frames, NULL };

        static float hgt[W * H], geo[3 * W * H];
        static uint8_t mask[W * H];
        for (int t = 0; t < W * H; t++) {
                hgt[t] = 0, geo[3 * t] = geo[3 * t + 1] = 0, geo[3 * t + 2] = 1;
                int u = t % W, v = t / W;
                mask[t] = u < 4 && v < 4 ? 0 : u >= W - 12 ? 2 : 1;   /* a masked corner, a filled strip */
        }
        struct imp_btf_heightfield hf = { W, H, pitch, hgt, geo, mask,
                                          { 1, 0, 0, -0.5 * (W - 1) * pitch, 0, 1, 0, -0.5 * (H - 1) * pitch,
                                            0, 0, 1, 0, 0, 0, 0, 1 } };
        struct imp_btf_sample_params sp;
        struct imp_photometric_params pp;
        struct imp_btf_fit_params fp;
        imp_btf_sample_params_default(&sp);
        imp_photometric_params_default(&pp);
        imp_btf_fit_params_default(&fp);

        /* the photometric stage's normals of the bilinear values, filled texels included */
        static float nb[3 * W * H];
        struct imp_photometric_params pb = pp;
        pb.lanczos = 0;
        struct imp_photometric_out po = { .normal = nb };
        struct imp_photometric_stats ps;
        CHECK_OK(imp_photometric_normals(&hf, &cap, &sp, &pb, &po, &ps));

        static float fe[3 * W * H], fr[3 * W * H];
        static struct imp_btf_texel te[W * H], tr[W * H], tn[W * H];
        struct imp_photometric_frames pf;
        struct imp_btf_frames bf;
        CHECK_OK(imp_photometric_frames(&hf, &pp, IMP_BTF_FRAMES_EXTRACT, fe, &pf, &bf));
        struct counted cnt = { &bf, 0 };
        struct imp_btf_frames counting = bf;
        counting.estimate = counted_estimate;
        counting.data = &cnt;
        fp.frames = &counting;
        struct imp_btf_stats se, sr, sn;
        CHECK_OK(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 0, te, &se));
        long seen = 0, tilted = 0;
        for (int t = 0; t < W * H; t++) {
                seen += mask[t] != 0;
                tilted += angle_deg(&fe[3 * t], &geo[3 * t]) > 3.0;
        }
        printf("frames: %ld of %d texels seen, %ld estimator calls, %ld frames > 3° off the geometric normal; "
               "photometric stage (lanczos 0): %ld refined\n", seen, W * H, cnt.calls, tilted, ps.n_refined);
        CHECK_INT_EQ(cnt.calls, seen);
        CHECK_GE(tilted, seen / 2);
        CHECK_GE(ps.n_refined, seen * 9 / 10);
        CHECK(memcmp(fe, nb, sizeof fe) == 0);

        /* some texels by hand: the model on the extractor's samples, in the canvas frame;
         * the fit on the samples extracted in the frames */
        struct imp_btf_hf_pyramid *py = NULL;
        struct imp_btf_extractor *x0 = NULL, *xf = NULL;
        struct imp_btf_heightfield hff = hf;
        hff.normal = fe;
        CHECK_OK(imp_btf_hf_pyramid_new(&hf, &py));
        CHECK_OK(imp_btf_extractor_new(&hf, &cap, &sp, py, &x0));
        CHECK_OK(imp_btf_extractor_new(&hff, &cap, &sp, py, &xf));
        struct imp_photometric_params pfill = pp;
        pfill.shadow_trim_sigma = pp.filled_trim_sigma;
        pfill.passes = IMP_MAX(pp.passes, pp.filled_passes);
        pfill.max_dev_deg = pp.filled_max_dev_deg;
        int checked = 0;
        for (int t = 5 * W + 5; t < W * H; t += 37) {
                static struct imp_btf_sample s[IMP_BTF_MAX_SAMPLES];
                uint16_t fl, nsh;
                int n = imp_btf_extract_texel(x0, t % W, t / W, s, &fl, &nsh);
                struct imp_pn_texel pt;
                CHECK_OK(imp_photometric_texel(s, n, mask[t] == 2 ? &pfill : &pp, &pt));
                if (pt.flags & IMP_PN_KEPT) {
                        CHECK(memcmp(&fe[3 * t], &geo[3 * t], 3 * sizeof *fe) == 0);
                        continue;
                }
                float nc[3] = { (float) pt.n[0], (float) pt.n[1], (float) pt.n[2] };   /* geo = z: t = x, b = y */
                for (int k = 0; k < 3; k++)   /* the model's float n, normalised again in double */
                        CHECK_NEAR(fe[3 * t + k], nc[k], 1e-6);
                n = imp_btf_extract_texel(xf, t % W, t / W, s, &fl, &nsh);
                struct imp_btf_texel ft;
                CHECK_OK(imp_btf_fit_texel(s, n, &fp, &ft));
                ft.flags |= fl;
                CHECK(memcmp(&ft, &te[t], sizeof ft) == 0);
                checked++;
        }
        printf("%d texels checked by hand\n", checked);
        CHECK_GE(checked, 90);
        imp_btf_extractor_free(x0);
        imp_btf_extractor_free(xf);
        imp_btf_hf_pyramid_free(py);

        /* ROTATE: the same frames; the samples turned instead of extracted again */
        CHECK_OK(imp_photometric_frames(&hf, &pp, IMP_BTF_FRAMES_ROTATE, fr, &pf, &bf));
        fp.frames = &bf;
        CHECK_OK(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 0, tr, &sr));
        CHECK(memcmp(fe, fr, sizeof fe) == 0);
        int off = 0, fitted = 0;
        for (int t = 0; t < W * H; t++) {
                if (!mask[t])
                        continue;
                fitted++;
                off += !(fabsf(tr[t].rho_d[0] - te[t].rho_d[0]) <= 0.01f * te[t].rho_d[0]);
        }
        printf("rotate: %ld samples (extract %ld), %d of %d texels' ρd more than 1 %% off\n", sr.n_samples,
               se.n_samples, off, fitted);
        CHECK(sr.n_samples < se.n_samples);
        CHECK_LE(off, fitted / 100);

        /* without frames the estimator never runs and the fit is in hf->normal's frames */
        cnt.calls = 0;
        fp.frames = NULL;
        CHECK_OK(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 0, tn, &sn));
        CHECK_INT_EQ(cnt.calls, 0);
        int same = 0;
        for (int t = 0; t < W * H; t++)
                same += memcmp(&tn[t], &te[t], sizeof tn[t]) == 0 && mask[t];
        printf("without frames: %d of %ld texels as with them\n", same, seen);
        CHECK_LE(same, seen / 10);

        /* bad arguments */
        CHECK_ERR(imp_photometric_frames(&hf, &pp, 7, fr, &pf, &bf), -EINVAL);
        CHECK_ERR(imp_photometric_frames(&hf, &pp, IMP_BTF_FRAMES_EXTRACT, geo, &pf, &bf), -EINVAL);
        struct imp_btf_frames bad = { .estimate = NULL, .normal = fr };
        fp.frames = &bad;
        CHECK_ERR(imp_btf_fit_grid(&hf, &cap, &sp, &fp, 0, tn, &sn), -EINVAL);
        for (int j = 0; j < NL; j++)
                imp_image_free(frames[j]);
        return 0;
}
