/* PNG previews of a digital copy for a conservator, and previews/index.html showing them
 * side by side (relative links: it opens from the file system). Each picture is the copy's
 * grid, canvas up; texels outside the mask are black:
 *   relief.png   shaded by a light from the upper left        normals.png  RGB = (n + 1) / 2
 *   height.png   heights on a blue–red ramp, with a colour bar labelled in mm and a length scale
 *   albedo.png   the diffuse colour ρd (sRGB), when the BTF was fitted
 *   sigma.png    the height σ on the same ramp, its bar labelled in µm
 *   flags.png    the relief in grey, texels carrying any flag in orange */
#define _GNU_SOURCE   /* asprintf */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "copy-previews.h"
#include "json-util.h"
#include "macro.h"
#include "numerics.h"

#define PANEL_W 120       /* the colour bar's panel right of a ramp image, pixels */
#define SCALE_H 40        /* the length scale's strip below it */
#define GLYPH_SCALE 2     /* the 5×7 font drawn 2× */

static void ramp(double t, uint8_t rgb[3]) {
        /* blue → cyan → yellow → red, t in [0, 1] */
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        double r = IMP_CLAMP(1.5 - fabs(4 * t - 3), 0, 1), g = IMP_CLAMP(1.5 - fabs(4 * t - 2), 0, 1);
        double b = IMP_CLAMP(1.5 - fabs(4 * t - 1), 0, 1);
        rgb[0] = (uint8_t) lround(255 * r);
        rgb[1] = (uint8_t) lround(255 * g);
        rgb[2] = (uint8_t) lround(255 * b);
}

/* A 5×7 font for the labels: rows top to bottom, bit 4 = leftmost column. */
static const struct { char c; uint8_t rows[7]; } glyphs[] = {
        { '0', { 14, 17, 19, 21, 25, 17, 14 } }, { '1', { 4, 12, 4, 4, 4, 4, 14 } },
        { '2', { 14, 17, 1, 2, 4, 8, 31 } },     { '3', { 31, 2, 4, 2, 1, 17, 14 } },
        { '4', { 2, 6, 10, 18, 31, 2, 2 } },     { '5', { 31, 16, 30, 1, 1, 17, 14 } },
        { '6', { 6, 8, 16, 30, 17, 17, 14 } },   { '7', { 31, 1, 2, 4, 8, 8, 8 } },
        { '8', { 14, 17, 17, 14, 17, 17, 14 } }, { '9', { 14, 17, 17, 15, 1, 2, 12 } },
        { '.', { 0, 0, 0, 0, 0, 12, 12 } },      { '-', { 0, 0, 0, 31, 0, 0, 0 } },
        { 'm', { 0, 0, 26, 21, 21, 17, 17 } },   { 'u', { 0, 0, 17, 17, 17, 19, 13 } },
        { '+', { 0, 4, 4, 31, 4, 4, 0 } },
};

static void put(struct imp_image *img, int x, int y, const uint8_t rgb[3]) {
        if (x < 0 || y < 0 || x >= img->width || y >= img->height)
                return;
        memcpy(imp_image_u8(img, x, y), rgb, 3);
}

static void text(struct imp_image *img, int x, int y, const char *s, const uint8_t rgb[3]) {
        for (; *s; s++, x += 6 * GLYPH_SCALE) {
                const uint8_t *rows = NULL;
                for (size_t g = 0; g < ARRAY_SIZE(glyphs); g++)
                        if (glyphs[g].c == *s)
                                rows = glyphs[g].rows;
                for (int r = 0; rows && r < 7 * GLYPH_SCALE; r++)
                        for (int c = 0; c < 5 * GLYPH_SCALE; c++)
                                if (rows[r / GLYPH_SCALE] & (16 >> (c / GLYPH_SCALE)))
                                        put(img, x + c, y + r, rgb);
        }
}

static void fill_rect(struct imp_image *img, int x0, int y0, int w, int h, const uint8_t rgb[3]) {
        for (int y = y0; y < y0 + h; y++)
                for (int x = x0; x < x0 + w; x++)
                        put(img, x, y, rgb);
}

/* A copy of grid (nx × ny RGB) with a white panel on the right holding a vertical colour bar
 * from lo (bottom) to hi (top), five labels in unit ("mm" or "um") × scale, and a strip
 * below with a length scale of a round number of mm. */
static int with_bar(const struct imp_image *grid, double lo, double hi, double scale, const char *unit,
                    double pitch_mm, struct imp_image **ret) {
        int W = grid->width + PANEL_W, H = IMP_MAX(grid->height, 160) + SCALE_H;
        struct imp_image *img;
        int r = imp_image_new(W, H, 3, IMP_PIX_U8, &img);
        if (r < 0)
                return r;
        static const uint8_t white[3] = { 255, 255, 255 }, black[3] = { 0, 0, 0 };
        fill_rect(img, 0, 0, W, H, white);
        for (int y = 0; y < grid->height; y++)
                memcpy(imp_image_u8(img, 0, y), imp_image_u8((struct imp_image *) grid, 0, y), 3 * (size_t) grid->width);
        int bx = grid->width + 8, top = 10, bh = IMP_MAX(grid->height, 160) - 20;
        for (int y = 0; y < bh; y++) {
                uint8_t c[3];
                ramp(1 - (double) y / (bh - 1), c);
                fill_rect(img, bx, top + y, 14, 1, c);
        }
        for (int k = 0; k <= 4; k++) {
                int y = top + (bh - 1) * (4 - k) / 4;
                char label[32];
                snprintf(label, sizeof label, "%.*f%s", fabs(hi - lo) * scale < 0.1 ? 4 : fabs(hi - lo) * scale < 10 ? 3 : 1,
                         (lo + (hi - lo) * k / 4) * scale, k == 4 ? unit : "");
                fill_rect(img, bx + 14, y, 4, 1, black);
                text(img, bx + 20, y - 7, label, black);
        }
        /* the length scale: the largest of 1, 2, 5 × 10^k mm within a third of the width */
        double width_mm = grid->width * pitch_mm, len = pow(10, floor(log10(width_mm / 3)));
        len *= width_mm / 3 >= 5 * len ? 5 : width_mm / 3 >= 2 * len ? 2 : 1;
        int lp = (int) lround(len / pitch_mm), y0 = H - SCALE_H + 12;
        fill_rect(img, 8, y0, lp, 4, black);
        fill_rect(img, 8, y0 - 4, 2, 12, black);
        fill_rect(img, 8 + lp - 2, y0 - 4, 2, 12, black);
        char label[32];
        snprintf(label, sizeof label, "%g mm", len);
        text(img, 16 + lp, y0 - 5, label, black);
        *ret = img;
        return 0;
}

/* sRGB encoding of a linear value in [0, 1]. */
static uint8_t srgb(double v) {
        v = IMP_CLAMP(v, 0, 1);
        return (uint8_t) lround(255 * (v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055));
}

struct previews {
        struct imp_image *shade, *nmap, *hmap, *smap, *fmap, *albedo;
        double lo, hi, sigma_hi, flagged_fraction;
        size_t texels;
};

static void previews_done(struct previews *p) {
        imp_image_free(p->shade);
        imp_image_free(p->nmap);
        imp_image_free(p->hmap);
        imp_image_free(p->smap);
        imp_image_free(p->fmap);
        imp_image_free(p->albedo);
}

/* The ranges the ramps span: heights min..max, σ 0..its 99th percentile; the flagged share. */
static int ranges(const struct imp_heightfield *hf, struct previews *p) {
        size_t n = (size_t) hf->nx * hf->ny, m = 0, flagged = 0;
        _cleanup_free_ float *s = malloc((n ? n : 1) * sizeof *s);
        if (!s)
                return -ENOMEM;
        p->lo = INFINITY;
        p->hi = -INFINITY;
        for (size_t i = 0; i < n; i++)
                if (hf->mask[i] && isfinite(hf->height_mm[i])) {
                        p->lo = fmin(p->lo, hf->height_mm[i]);
                        p->hi = fmax(p->hi, hf->height_mm[i]);
                        if (hf->sigma_mm && isfinite(hf->sigma_mm[i]))
                                s[m++] = hf->sigma_mm[i];
                        flagged += hf->texel_flags && hf->texel_flags[i];
                        p->texels++;
                }
        if (!(p->hi > p->lo)) {
                p->lo = isfinite(p->lo) ? p->lo : 0;
                p->hi = p->lo + 1e-3;
        }
        p->sigma_hi = m ? fmax(imp_select_kth_float(s, m, (size_t) (0.99 * (m - 1))), 1e-6) : 1e-3;
        p->flagged_fraction = p->texels ? (double) flagged / p->texels : 0;
        return 0;
}

/* One texel into each picture; (x, yy) is the image position (canvas up). */
static void texel(const struct imp_heightfield *hf, const struct imp_image *rho_d, struct previews *p, int x, int y,
                  int yy) {
        static const double L[3] = { -0.5, 0.5, 0.707 };   /* light from the upper left, 45° up */
        size_t i = (size_t) y * hf->nx + x;
        double nx = hf->nx_[i], ny = hf->ny_[i], s = 1 - nx * nx - ny * ny;
        double nz = sqrt(s > 0 ? s : 0);
        double d = IMP_CLAMP(0.1 + 0.9 * (nx * L[0] + ny * L[1] + nz * L[2]), 0, 1);
        *imp_image_u8(p->shade, x, yy) = (uint8_t) lround(255 * d);
        uint8_t *q = imp_image_u8(p->nmap, x, yy);
        q[0] = (uint8_t) lround(127.5 * (nx + 1));
        q[1] = (uint8_t) lround(127.5 * (ny + 1));
        q[2] = (uint8_t) lround(127.5 * (nz + 1));
        ramp((hf->height_mm[i] - p->lo) / (p->hi - p->lo), imp_image_u8(p->hmap, x, yy));
        ramp(hf->sigma_mm ? hf->sigma_mm[i] / p->sigma_hi : 0, imp_image_u8(p->smap, x, yy));
        q = imp_image_u8(p->fmap, x, yy);
        bool flagged = hf->texel_flags && hf->texel_flags[i];
        static const uint8_t orange[3] = { 255, 120, 0 };
        for (int c = 0; c < 3; c++)
                q[c] = (uint8_t) lround(flagged ? 0.35 * 255 * d + 0.65 * orange[c] : 255 * d);
        if (p->albedo) {
                const float *a = imp_image_f32((struct imp_image *) rho_d, x, y);
                q = imp_image_u8(p->albedo, x, yy);
                for (int c = 0; c < 3; c++)
                        q[c] = srgb(a[c]);
        }
}

static int draw(const struct imp_heightfield *hf, const struct imp_image *rho_d, struct previews *p) {
        int r;
        if ((r = imp_image_new(hf->nx, hf->ny, 1, IMP_PIX_U8, &p->shade)) < 0 ||
            (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &p->nmap)) < 0 ||
            (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &p->hmap)) < 0 ||
            (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &p->smap)) < 0 ||
            (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &p->fmap)) < 0 ||
            (rho_d && (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &p->albedo)) < 0) ||
            (r = ranges(hf, p)) < 0)
                return r;
        for (int y = 0; y < hf->ny; y++)
                for (int x = 0; x < hf->nx; x++)
                        if (hf->mask[(size_t) y * hf->nx + x])   /* grid rows grow along canvas y: flip */
                                texel(hf, rho_d, p, x, y, hf->ny - 1 - y);
        return 0;
}

/* previews/index.html: the pictures side by side with what each shows. */
static int write_index(const char *dir, const struct imp_heightfield *hf, const struct previews *p,
                       struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%s/index.html", dir);
        _cleanup_free_ char *html = NULL;
        int n = asprintf(&html,
                "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>impasto copy previews</title>\n"
                "<style>body{font-family:sans-serif;margin:1em;background:#f4f4f4}"
                "figure{display:inline-block;vertical-align:top;margin:0.5em;background:#fff;padding:0.5em}"
                "img{max-width:46vw;max-height:70vh;image-rendering:pixelated}figcaption{max-width:40em}</style>\n"
                "</head><body>\n<h1>Digital copy: previews</h1>\n"
                "<p>%d &times; %d texels of %.4g mm (%.1f &times; %.1f mm); heights %.3f to %.3f mm; "
                "%.1f %% of the canvas texels flagged. Canvas up; black is off the canvas. "
                "The numbers behind these pictures are in <a href=\"../copy.json\">copy.json</a>.</p>\n"
                "%s"
                "<figure><img src=\"height.png\" alt=\"height map\"><figcaption><b>Height</b> above the canvas plane, "
                "colour bar in mm; the bar below is a length scale.</figcaption></figure>\n"
                "<figure><img src=\"relief.png\" alt=\"shaded relief\"><figcaption><b>Relief</b>, lit from the "
                "upper left.</figcaption></figure>\n"
                "<figure><img src=\"sigma.png\" alt=\"height uncertainty\"><figcaption><b>Height &sigma;</b> per "
                "texel, colour bar in &micro;m (up to its 99th percentile).</figcaption></figure>\n"
                "<figure><img src=\"flags.png\" alt=\"flagged texels\"><figcaption><b>Flags</b>: orange texels "
                "carry a flag (saturated, filled, near the frame, few samples, uncertain normal or fit; "
                "heightfield.exr channel flags): their &sigma; may not describe them.</figcaption></figure>\n"
                "<figure><img src=\"normals.png\" alt=\"normal map\"><figcaption><b>Normals</b>, RGB = "
                "(n + 1) / 2.</figcaption></figure>\n</body></html>\n",
                hf->nx, hf->ny, hf->pitch_mm, hf->nx * hf->pitch_mm, hf->ny * hf->pitch_mm, p->lo, p->hi,
                100 * p->flagged_fraction,
                p->albedo ? "<figure><img src=\"albedo.png\" alt=\"colour\"><figcaption><b>Colour</b>: the "
                            "diffuse albedo &rho;<sub>d</sub>, without shading or gloss.</figcaption></figure>\n" : "");
        if (n < 0)
                return imp_error_set(err, -ENOMEM, "out of memory");
        return imp_file_write_atomic(path, html, (size_t) n, err);
}

int imp_copy_previews(const char *copy_dir, const struct imp_heightfield *hf, const struct imp_image *rho_d,
                      struct imp_error *err) {
        char dir[4096];
        snprintf(dir, sizeof dir, "%s/previews", copy_dir);
        int r = imp_mkdir_p(dir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create directory", dir);
        struct previews p = {};
        _cleanup_image_ struct imp_image *hbar = NULL, *sbar = NULL;
        if ((r = draw(hf, rho_d, &p)) < 0 ||
            (r = with_bar(p.hmap, p.lo, p.hi, 1, "mm", hf->pitch_mm, &hbar)) < 0 ||
            (r = with_bar(p.smap, 0, p.sigma_hi, 1000, "um", hf->pitch_mm, &sbar)) < 0) {
                previews_done(&p);
                return imp_error_set(err, r, "out of memory for previews");
        }
        static const char *const names[] = { "relief.png", "normals.png", "height.png", "sigma.png", "flags.png",
                                             "albedo.png" };
        const struct imp_image *imgs[] = { p.shade, p.nmap, hbar, sbar, p.fmap, p.albedo };
        /* One image a thread (zlib is most of the time); the first failure in this order. */
        int rk[ARRAY_SIZE(names)] = {};
        struct imp_error ek[ARRAY_SIZE(names)] = {};
#pragma omp parallel for schedule(dynamic, 1)
        for (size_t k = 0; k < ARRAY_SIZE(names); k++) {
                char pk[4200];
                snprintf(pk, sizeof pk, "%s/%s", dir, names[k]);
                if (imgs[k])
                        rk[k] = imp_png_write_fast(pk, imgs[k], &ek[k]);
        }
        for (size_t k = 0; k < ARRAY_SIZE(names) && r >= 0; k++)
                if ((r = rk[k]) < 0 && err)
                        *err = ek[k];
        if (r >= 0)
                r = write_index(dir, hf, &p, err);
        previews_done(&p);
        return r;
}
