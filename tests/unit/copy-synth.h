/* A small synthetic digital copy for the viewer and export tests: a W×H grid at PITCH mm
 * with a Gaussian bump (peak COPY_SYNTH_PEAK mm above a tilted base), a one-texel border
 * off the mask, σ growing with x, a colour ramp in ρd, a glossy lobe, flags on one texel
 * and two relief boxes over the bump. Every value is a closed-form function of (i, j) so
 * that tests can check readers against it. */
#pragma once
#include <math.h>
#include <stdio.h>
#include "image.h"
#include "json-util.h"

#define COPY_SYNTH_NX 40
#define COPY_SYNTH_NY 30
#define COPY_SYNTH_PITCH 0.1
#define COPY_SYNTH_PEAK 0.4
#define COPY_SYNTH_HREF 0.01
#define COPY_SYNTH_DELTA0 0.1

static inline bool copy_synth_in(int i, int j) {
        return i > 0 && j > 0 && i < COPY_SYNTH_NX - 1 && j < COPY_SYNTH_NY - 1;
}
static inline double copy_synth_height(int i, int j) {
        double x = i - 20.0, y = j - 15.0;
        return COPY_SYNTH_HREF + 0.001 * i + COPY_SYNTH_PEAK * exp(-(x * x + y * y) / 18.0);
}
static inline double copy_synth_sigma(int i, int j) { return 0.001 + 0.0001 * i; }
static inline double copy_synth_rho_d(int i, int j, int c) { return 0.2 + 0.015 * i + 0.1 * c + 0.005 * j; }
static inline double copy_synth_rho_s(int i, int j, int c) { return 0.05 + 0.002 * j; }
static inline double copy_synth_k(int i, int j) { return 10 + i; }
/* The texel flags (heightfield.exr, quality.h) and, elsewhere, different fit flags (fit-flags.exr,
 * btf.h: matte and k at its bound), so a reader that takes one for the other is caught. */
static inline unsigned copy_synth_flags(int i, int j) { return i == 5 && j == 6 ? (1u << 5) | (1u << 9) : 0; }
static inline unsigned copy_synth_fit_flags(int i, int j) { return i == 7 && j == 3 ? (1u << 2) | (1u << 7) : 0; }

static inline int copy_synth_write(const char *dir, struct imp_error *err) {
        int r = imp_mkdir_p(dir, 0755);
        if (r < 0)
                return r;
        const int W = COPY_SYNTH_NX, H = COPY_SYNTH_NY;
        _cleanup_image_ struct imp_image *hf = NULL, *rd = NULL, *rs = NULL, *lo = NULL, *fl = NULL;
        if ((r = imp_image_new(W, H, 6, IMP_PIX_F32, &hf)) < 0 || (r = imp_image_new(W, H, 3, IMP_PIX_F32, &rd)) < 0 ||
            (r = imp_image_new(W, H, 3, IMP_PIX_F32, &rs)) < 0 || (r = imp_image_new(W, H, 4, IMP_PIX_F32, &lo)) < 0 ||
            (r = imp_image_new(W, H, 1, IMP_PIX_F32, &fl)) < 0)
                return r;
        for (int j = 0; j < H; j++)
                for (int i = 0; i < W; i++) {
                        bool in = copy_synth_in(i, j);
                        float *p = imp_image_f32(hf, i, j);
                        /* the slope of the bump as the normal */
                        double gx = (copy_synth_height(i + 1, j) - copy_synth_height(i - 1, j)) / (2 * COPY_SYNTH_PITCH);
                        double gy = (copy_synth_height(i, j + 1) - copy_synth_height(i, j - 1)) / (2 * COPY_SYNTH_PITCH);
                        double nn = sqrt(1 + gx * gx + gy * gy);
                        p[0] = in ? (float) copy_synth_height(i, j) : 0;
                        p[1] = in ? (float) (-gx / nn) : 0;
                        p[2] = in ? (float) (-gy / nn) : 0;
                        p[3] = in ? (float) copy_synth_sigma(i, j) : 0;
                        p[4] = in;
                        p[5] = in ? (float) copy_synth_flags(i, j) : 0;
                        for (int c = 0; c < 3; c++) {
                                imp_image_f32(rd, i, j)[c] = (float) copy_synth_rho_d(i, j, c);
                                imp_image_f32(rs, i, j)[c] = (float) copy_synth_rho_s(i, j, c);
                        }
                        float *l = imp_image_f32(lo, i, j);
                        l[0] = -1, l[1] = -1, l[2] = 1, l[3] = (float) copy_synth_k(i, j);
                        *imp_image_f32(fl, i, j) = (float) copy_synth_fit_flags(i, j);
                }
        static const char *const HF[] = { "height", "nx", "ny", "sigma", "mask", "flags" }, *const RGB[] = { "R", "G", "B" },
                                 *const LO[] = { "cx", "cy", "cz", "k" }, *const FL[] = { "flags" };
        char path[1024];
#define SYNTH_EXR(name, img, names) \
        snprintf(path, sizeof path, "%s/%s", dir, name); \
        if ((r = imp_exr_write(path, img, names, false, err)) < 0) \
                return r;
        SYNTH_EXR("heightfield.exr", hf, HF);
        SYNTH_EXR("rho_d.exr", rd, RGB);
        SYNTH_EXR("rho_s.exr", rs, RGB);
        SYNTH_EXR("lobe.exr", lo, LO);
        SYNTH_EXR("fit-flags.exr", fl, FL);
#undef SYNTH_EXR
        _cleanup_json_ json_t *cj = json_pack("{s:s, s:i, s:s, s:f, s:i, s:i}", "format", "impasto-digital-copy",
                                              "version", 1, "units", "mm", "pitch_mm", COPY_SYNTH_PITCH, "nx", W, "ny", H);
        double top = copy_synth_height(20, 15);
        _cleanup_json_ json_t *bj = json_pack("{s:f, s:f, s:[{s:i,s:i,s:i,s:i,s:f,s:i,s:i}, {s:i,s:i,s:i,s:i,s:f,s:i,s:i}]}",
                                              "h_ref", COPY_SYNTH_HREF, "delta0", COPY_SYNTH_DELTA0, "boxes",
                                              "u0", 10, "v0", 10, "w", 10, "h", 10, "hmax", copy_synth_height(19, 15), "umax", 19, "vmax", 15,
                                              "u0", 20, "v0", 10, "w", 10, "h", 10, "hmax", top, "umax", 20, "vmax", 15);
        snprintf(path, sizeof path, "%s/copy.json", dir);
        if ((r = imp_json_save_atomic(path, cj, err)) < 0)
                return r;
        snprintf(path, sizeof path, "%s/boxes.json", dir);
        return imp_json_save_atomic(path, bj, err);
}
