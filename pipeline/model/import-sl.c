/* Import of a structured-light sequence (import-sl.h). */
#include <dirent.h>
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include "captureset.h"
#include "import-sl.h"

#define IMPORT_SL_EXPOSURE_US 1e4      /* nominal: the frames carry no exposure */
#define IMPORT_SL_MAX_FRAMES 68        /* 2·(16 + 16) + 2 */

static int ceil_log2(int v) {
        int b = 0;
        while ((1 << b) < v)
                b++;
        return b;
}

int imp_import_sl_frame_count(enum imp_sl_order order, int proj_width, int proj_height) {
        if (order != IMP_SL_ORDER_OPENCV_GRAYCODE || proj_width < 2 || proj_height < 2 || proj_width > 65536 ||
            proj_height > 65536)
                return -EINVAL;
        return 2 * (ceil_log2(proj_width) + ceil_log2(proj_height)) + 2;
}

/* Pattern i of OpenCV's order: column planes (bit, inverse) pairs, row planes, white, black. */
static struct imp_pattern opencv_pattern(int i, int proj_w, int proj_h) {
        int nx = ceil_log2(proj_w), ny = ceil_log2(proj_h);
        struct imp_pattern p = {};
        if (i == 2 * (nx + ny))
                p.kind = IMP_PAT_WHITE;
        else if (i == 2 * (nx + ny) + 1)
                p.kind = IMP_PAT_BLACK;
        else {
                p.kind = IMP_PAT_GRAY;
                p.axis = i >= 2 * nx;
                p.bit = (i - (p.axis ? 2 * nx : 0)) / 2;
                p.nbits = p.axis ? ny : nx;
                p.inverse = i % 2;
        }
        return p;
}

static int by_name(const void *a, const void *b) {
        return strcmp(*(char *const *) a, *(char *const *) b);
}

static bool is_image_name(const char *n) {
        const char *dot = strrchr(n, '.');
        return n[0] != '.' && dot && (!strcasecmp(dot, ".png") || !strcasecmp(dot, ".tif") || !strcasecmp(dot, ".tiff"));
}

/* The image files of dir in name order (at most max). */
static int list_frames(const char *dir, char **names, int max, int *ret_n, struct imp_error *err) {
        DIR *d = opendir(dir);
        if (!d)
                return imp_error_set(err, -errno, "%s: cannot open: %s", dir, strerror(errno));
        struct dirent *e;
        int n = 0, r = 0;
        while ((e = readdir(d)))
                if (is_image_name(e->d_name)) {
                        if (n == max) {
                                r = imp_error_set(err, -EINVAL, "%s: more than %d images: expected the sequence only",
                                                  dir, max);
                                break;
                        }
                        if (!(names[n++] = strdup(e->d_name))) {
                                r = imp_error_set(err, -ENOMEM, "out of memory");
                                break;
                        }
                }
        closedir(d);
        qsort(names, (size_t) n, sizeof *names, by_name);
        *ret_n = n;
        return r;
}

/* The calibration as the set's rig, with the sensor of the frames' depth. */
static int sl_rig(const struct imp_import_sl_options *o, int w, int h, int bits, struct imp_rig *ret,
                  struct imp_error *err) {
        struct imp_rig rig = {};
        int r = o->calib_rig ? imp_rig_copy(o->calib_rig, &rig) : imp_rig_load(o->calib_path, &rig, err);
        if (r < 0)
                return o->calib_rig ? imp_error_set(err, r, "out of memory") : r;
        if (o->calib_rig && rig.n_cameras >= 1 && rig.cameras[0].model.width == 0) {
                rig.cameras[0].model.width = w;
                rig.cameras[0].model.height = h;
        }
        if (o->calib_rig && rig.has_projector && rig.projector.model.width == 0) {
                rig.projector.model.width = o->proj_width;
                rig.projector.model.height = o->proj_height;
        }
        if (rig.n_cameras < 1 || !rig.has_projector)
                r = imp_error_set(err, -EINVAL, "%s: expected a camera and a projector (found %d cameras, %s projector)",
                                  o->calib_path, rig.n_cameras, rig.has_projector ? "a" : "no");
        else if (rig.projector.model.width != o->proj_width || rig.projector.model.height != o->proj_height)
                r = imp_error_set(err, -EINVAL, "%s: the projector is %dx%d, --projector says %dx%d", o->calib_path,
                                  rig.projector.model.width, rig.projector.model.height, o->proj_width, o->proj_height);
        else if (rig.cameras[0].model.width != w || rig.cameras[0].model.height != h)
                r = imp_error_set(err, -EINVAL, "%s: camera %s is %dx%d, the frames %dx%d", o->calib_path,
                                  rig.cameras[0].name, rig.cameras[0].model.width, rig.cameras[0].model.height, w, h);
        if (r < 0) {
                imp_rig_free(&rig);
                return r;
        }
        double levels = bits == 8 ? 255 : 65535;
        rig.n_cameras = 1;
        rig.cameras[0].sensor = (struct imp_sensor) { .bits = bits, .gain_e_per_dn = 1, .read_noise_e = 0.5,
                                                      .full_well_e = levels + 1, .quantum_scale = levels };
        *ret = rig;
        return 0;
}

/* Frame i as stored: u16 grey (RGB averaged), the depth in *bits. */
static int load_frame(const char *path, struct imp_image **ret, int *bits, struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_read(path, &img, err);
        if (r < 0)
                return r;
        if (img->type == IMP_PIX_F32)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: floating-point image: expected 8- or 16-bit", path);
        *bits = img->type == IMP_PIX_U8 ? 8 : 16;
        int ch = img->channels >= 3 ? 3 : 1;
        struct imp_image *d;
        if ((r = imp_image_new(img->width, img->height, 1, IMP_PIX_U16, &d)) < 0)
                return imp_error_set(err, r, "%s: cannot allocate", path);
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        double s = 0;
                        for (int c = 0; c < ch; c++)
                                s += imp_image_get(img, x, y, c);
                        *imp_image_u16(d, x, y) = (uint16_t) (s / ch + 0.5);
                }
        *ret = d;
        return 0;
}

static int write_frames(const struct imp_import_sl_options *o, char *const *names, int n, const char *out_dir,
                        struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int bits0 = 0, w = 0, h = 0, r = 0;
        char first[4200] = "";
        for (int i = 0; i < n && r >= 0; i++) {
                char path[4200];
                int bits = 0;
                snprintf(path, sizeof path, "%s/%s", o->frames_dir, names[i]);
                _cleanup_image_ struct imp_image *f = NULL;
                if ((r = load_frame(path, &f, &bits, err)) < 0)
                        return r;
                if (i == 0) {
                        struct imp_rig rig = {};
                        bits0 = bits, w = f->width, h = f->height;
                        snprintf(first, sizeof first, "%s", path);
                        if ((r = sl_rig(o, w, h, bits, &rig, err)) < 0)
                                return r;
                        r = imp_captureset_create(out_dir, &rig, NULL, &cs, err);
                        imp_rig_free(&rig);
                        if (r < 0)
                                return r;
                } else if (f->width != w || f->height != h || bits != bits0)
                        return imp_error_set(err, -EINVAL, "%s: %dx%d %d-bit, but %s is %dx%d %d-bit: one size and depth expected",
                                             path, f->width, f->height, bits, first, w, h, bits0);
                struct imp_frame_record rec = { .seq = i, .light = -1, .exposure_us = IMPORT_SL_EXPOSURE_US,
                                                .pattern = opencv_pattern(i, o->proj_width, o->proj_height) };
                snprintf(rec.step, sizeof rec.step, "structured-light");
                snprintf(rec.camera, sizeof rec.camera, "%s", imp_captureset_rig(cs)->cameras[0].name);
                r = imp_captureset_add_frame(cs, &rec, f, err);
        }
        return r;
}

int imp_import_sl(const struct imp_import_sl_options *o, const char *out_dir, struct imp_error *err) {
        if (!o || !o->frames_dir || (!o->calib_path && !o->calib_rig) || !out_dir)
                return imp_error_set(err, -EINVAL, "import sl: --frames, --calib and --out are needed");
        int want = imp_import_sl_frame_count(o->order, o->proj_width, o->proj_height);
        if (want < 0)
                return imp_error_set(err, -EINVAL, "import sl: projector %dx%d: expected 2..65536 pixels per side",
                                     o->proj_width, o->proj_height);
        char *names[IMPORT_SL_MAX_FRAMES + 1] = {};
        int n = 0;
        int r = list_frames(o->frames_dir, names, IMPORT_SL_MAX_FRAMES + 1, &n, err);
        if (r >= 0 && n != want)
                r = imp_error_set(err, -EINVAL, "%s: %d images, expected %d for OpenCV's Gray-code order on a %dx%d "
                                  "projector (%d column and %d row planes with inverses, white, black)",
                                  o->frames_dir, n, want, o->proj_width, o->proj_height, ceil_log2(o->proj_width),
                                  ceil_log2(o->proj_height));
        if (r >= 0)
                r = write_frames(o, names, n, out_dir, err);
        for (int i = 0; i < n; i++)
                free(names[i]);
        return r;
}
