/* PNG previews of a heightfield: a relief shaded by a light from the upper left, the
 * normal map (RGB = (n + 1) / 2) and heights on a blue–red colour ramp. Texels outside
 * the mask are black. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include "copy-previews.h"
#include "json-util.h"

static void ramp(double t, uint8_t rgb[3]) {
        /* blue → cyan → yellow → red, t in [0, 1] */
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        double r = IMP_CLAMP(1.5 - fabs(4 * t - 3), 0, 1), g = IMP_CLAMP(1.5 - fabs(4 * t - 2), 0, 1);
        double b = IMP_CLAMP(1.5 - fabs(4 * t - 1), 0, 1);
        rgb[0] = (uint8_t) lround(255 * r);
        rgb[1] = (uint8_t) lround(255 * g);
        rgb[2] = (uint8_t) lround(255 * b);
}

int imp_copy_previews(const char *copy_dir, const struct imp_heightfield *hf, struct imp_error *err) {
        char dir[4096], path[4200];
        snprintf(dir, sizeof dir, "%s/previews", copy_dir);
        int r = imp_mkdir_p(dir, 0755);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot create directory", dir);
        _cleanup_image_ struct imp_image *shade = NULL, *nmap = NULL, *hmap = NULL;
        if ((r = imp_image_new(hf->nx, hf->ny, 1, IMP_PIX_U8, &shade)) < 0 ||
            (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &nmap)) < 0 ||
            (r = imp_image_new(hf->nx, hf->ny, 3, IMP_PIX_U8, &hmap)) < 0)
                return imp_error_set(err, r, "out of memory for previews");
        double lo = INFINITY, hi = -INFINITY;
        size_t n = (size_t) hf->nx * hf->ny;
        for (size_t i = 0; i < n; i++)
                if (hf->mask[i] && isfinite(hf->height_mm[i])) {
                        lo = fmin(lo, hf->height_mm[i]);
                        hi = fmax(hi, hf->height_mm[i]);
                }
        double span = hi > lo ? hi - lo : 1;
        const double L[3] = { -0.5, 0.5, 0.707 };   /* light from the upper left, 45° up */
        for (int y = 0; y < hf->ny; y++)
                for (int x = 0; x < hf->nx; x++) {
                        size_t i = (size_t) y * hf->nx + x;
                        /* grid row v grows along canvas y; images grow downwards: flip */
                        int yy = hf->ny - 1 - y;
                        if (!hf->mask[i])
                                continue;
                        double nx = hf->nx_[i], ny = hf->ny_[i], s = 1 - nx * nx - ny * ny;
                        double nz = sqrt(s > 0 ? s : 0);
                        double d = nx * L[0] + ny * L[1] + nz * L[2];
                        *imp_image_u8(shade, x, yy) = (uint8_t) lround(255 * IMP_CLAMP(0.1 + 0.9 * d, 0, 1));
                        uint8_t *p = imp_image_u8(nmap, x, yy);
                        p[0] = (uint8_t) lround(127.5 * (nx + 1));
                        p[1] = (uint8_t) lround(127.5 * (ny + 1));
                        p[2] = (uint8_t) lround(127.5 * (nz + 1));
                        ramp((hf->height_mm[i] - lo) / span, imp_image_u8(hmap, x, yy));
                }
        static const char *const names[] = { "relief.png", "normals.png", "height.png" };
        const struct imp_image *imgs[] = { shade, nmap, hmap };
        for (int k = 0; k < 3; k++) {
                snprintf(path, sizeof path, "%s/%s", dir, names[k]);
                r = imp_png_write(path, imgs[k], err);
                if (r < 0)
                        return r;
        }
        return 0;
}
