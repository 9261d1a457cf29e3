/* An OpenLIME BRDF layer in deepzoom tiles (export.h). The maps are written as PNGs, then
 * cut by libvips' dzsave; the refit runs per texel (ward-refit.c). */
#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <tiffio.h>
#include "export.h"
#include "image.h"
#include "json-util.h"
#ifdef IMPASTO_HAVE_VIPS
#include <vips/vips.h>
#endif

static uint8_t u8(double v) {
        return (uint8_t) lround(255 * (v < 0 ? 0 : v > 1 ? 1 : v));
}
static double srgb(double v) {
        v = v < 0 ? 0 : v > 1 ? 1 : v;
        return v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
}

static int cmp_float(const void *a, const void *b) {
        float x = *(const float *) a, y = *(const float *) b;
        return (x > y) - (x < y);
}

/* kd, ks (sRGB), normals, gloss into four images; the refit error per texel into e. */
static void fill_maps(const struct imp_copy *c, struct imp_image *const m[4], float *e, size_t *ret_ks_clipped) {
        size_t clipped = 0;
        for (int j = 0; j < c->ny; j++)
                for (int i = 0; i < c->nx; i++) {
                        size_t k = (size_t) j * c->nx + i;
                        const struct imp_lafortune *b = &c->brdf[k];
                        struct imp_ward_fit w;
                        imp_ward_refit(b, &w);
                        double nx = c->normal_x[k], ny = c->normal_y[k], q = nx * nx + ny * ny;
                        double nz = q < 1 ? sqrt(1 - q) : 0;
                        for (int ch = 0; ch < 3; ch++) {
                                imp_image_u8(m[0], i, j)[ch] = u8(srgb(b->rho_d[ch]));
                                imp_image_u8(m[1], i, j)[ch] = u8(srgb(w.ks[ch]));
                                clipped += w.ks[ch] > 1;
                        }
                        /* image rows run down the texel rows: y towards image up is −canvas y */
                        double n[3] = { nx, -ny, nz };
                        for (int ch = 0; ch < 3; ch++)
                                imp_image_u8(m[2], i, j)[ch] = c->mask[k] ? u8(0.5 * (n[ch] + 1)) : 0;
                        imp_image_u8(m[3], i, j)[0] = u8(w.gloss);
                        e[k] = c->mask[k] ? w.rel_error : NAN;
                }
        *ret_ks_clipped = clipped;
}

static int write_error_tiff(const struct imp_copy *c, const float *e, const char *path, struct imp_error *err) {
        TIFF *t = TIFFOpen(path, "w");
        if (!t)
                return imp_error_set(err, -EIO, "%s: cannot create the TIFF", path);
        bool ok = TIFFSetField(t, TIFFTAG_IMAGEWIDTH, (uint32_t) c->nx) && TIFFSetField(t, TIFFTAG_IMAGELENGTH, (uint32_t) c->ny) &&
                  TIFFSetField(t, TIFFTAG_SAMPLESPERPIXEL, (uint16_t) 1) && TIFFSetField(t, TIFFTAG_BITSPERSAMPLE, (uint16_t) 32) &&
                  TIFFSetField(t, TIFFTAG_SAMPLEFORMAT, (uint16_t) SAMPLEFORMAT_IEEEFP) &&
                  TIFFSetField(t, TIFFTAG_PHOTOMETRIC, (uint16_t) PHOTOMETRIC_MINISBLACK) &&
                  TIFFSetField(t, TIFFTAG_IMAGEDESCRIPTION, "Ward refit: RMS residual / RMS of the Lafortune lobe; NaN off the mask");
        for (int j = 0; ok && j < c->ny; j++)
                ok = TIFFWriteScanline(t, (void *) (e + (size_t) j * c->nx), (uint32_t) j, 0) >= 0;
        TIFFClose(t);
        return ok ? 0 : imp_error_set(err, -EIO, "%s: write failed", path);
}

#ifdef IMPASTO_HAVE_VIPS
static int dzsave(const char *png, const char *base, struct imp_error *err) {
        VipsImage *im = vips_image_new_from_file(png, NULL);
        if (!im)
                return imp_error_set(err, -EIO, "%s: libvips cannot read it: %s", png, vips_error_buffer());
        int r = vips_dzsave(im, base, "suffix", ".png", "overlap", 0, "tile_size", 256, NULL);
        g_object_unref(im);
        if (r) {
                imp_error_set(err, -EIO, "%s: libvips dzsave failed: %s", base, vips_error_buffer());
                vips_error_clear();
                return -EIO;
        }
        return 0;
}
#endif

static int describe(const struct imp_copy *c, const char *dir, double med, double p95, size_t clipped,
                    struct imp_error *err) {
        char path[PATH_MAX];
        snprintf(path, sizeof path, "%s/openlime.json", dir);
        _cleanup_json_ json_t *j = json_pack(
                "{s:s, s:s, s:{s:s, s:s, s:s, s:s}, s:{s:s, s:s}, s:i, s:i, s:f, s:[f, f], "
                "s:{s:s, s:f, s:f, s:I, s:s}}",
                "type", "brdf", "layout", "deepzoom", "channels", "kd", "kd.dzi", "ks", "ks.dzi", "normals",
                "normals.dzi", "gloss", "gloss.dzi", "colorspaces", "kd", "srgb", "ks", "srgb", "width", c->nx,
                "height", c->ny, "pitch_mm", c->pitch_mm, "alphaLimits", 0.01, 0.5, "refit", "model",
                "Lafortune lobe -> isotropic Ward, viewer on the normal", "rel_error_median", med, "rel_error_p95",
                p95, "ks_clipped_samples", (json_int_t) clipped, "error_map", "refit-error.tif");
        return j ? imp_json_save_atomic(path, j, err) : imp_error_set(err, -ENOMEM, "out of memory");
}

int imp_export_openlime(const struct imp_copy *c, const char *dir, double *ret_med, double *ret_p95,
                        struct imp_error *err) {
#ifndef IMPASTO_HAVE_VIPS
        return imp_error_set(err, -ENOTSUP, "this impasto was built without libvips: no deepzoom tiles");
#else
        if (VIPS_INIT("impasto"))
                return imp_error_set(err, -EIO, "libvips: %s", vips_error_buffer());
        static const char *const names[4] = { "kd", "ks", "normals", "gloss" };
        struct imp_image *m[4] = {};
        size_t n = (size_t) c->nx * c->ny, clipped = 0, nm = 0;
        float *e = malloc(sizeof *e * n), *sorted = malloc(sizeof *sorted * (n ? n : 1));
        int r = e && sorted ? 0 : -ENOMEM;
        for (int i = 0; r >= 0 && i < 4; i++)
                r = imp_image_new(c->nx, c->ny, i == 3 ? 1 : 3, IMP_PIX_U8, &m[i]);
        if (r < 0)
                imp_error_set(err, r, "out of memory");
        else
                fill_maps(c, m, e, &clipped);
        char png[PATH_MAX], base[PATH_MAX];
        for (int i = 0; r >= 0 && i < 4; i++) {
                snprintf(png, sizeof png, "%s/%s.png", dir, names[i]);
                snprintf(base, sizeof base, "%s/%s", dir, names[i]);
                if ((r = imp_png_write(png, m[i], err)) >= 0)
                        r = dzsave(png, base, err);
        }
        if (r >= 0) {
                snprintf(png, sizeof png, "%s/refit-error.tif", dir);
                r = write_error_tiff(c, e, png, err);
        }
        double med = 0, p95 = 0;
        for (size_t k = 0; r >= 0 && k < n; k++)
                if (c->mask[k])
                        sorted[nm++] = e[k];
        if (r >= 0 && nm) {
                qsort(sorted, nm, sizeof *sorted, cmp_float);
                med = sorted[nm / 2], p95 = sorted[(size_t) floor(0.95 * (double) (nm - 1))];
        }
        if (r >= 0)
                r = describe(c, dir, med, p95, clipped, err);
        if (r >= 0 && ret_med)
                *ret_med = med;
        if (r >= 0 && ret_p95)
                *ret_p95 = p95;
        for (int i = 0; i < 4; i++)
                imp_image_free(m[i]);
        free(e);
        free(sorted);
        return r;
#endif
}
