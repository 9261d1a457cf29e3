/* Import of a photometric/RTI stack (import-photometric.h): the .lp and intensity readers,
 * and the capture set with its rig. The images are read, never written. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include "captureset.h"
#include "import-photometric.h"
#include "json-util.h"

#define LP_MAX_LINE 4096
#define IMPORT_EXPOSURE_US 1e6         /* one exposure of 1 s: V = DN / (2^bits − 1) */
#define IMPORT_READ_NOISE_E 0.5        /* DN below 3 × this are "dark" (hdr.h dark_k 3) */

void imp_import_photometric_options_default(struct imp_import_photometric_options *ret) {
        *ret = (struct imp_import_photometric_options) { .kind = IMP_LP_AUTO, .lp_unit_mm = 1.0 };
}

void imp_lp_done(struct imp_lp *lp) {
        if (!lp)
                return;
        free(lp->lights);
        *lp = (struct imp_lp) {};
}

/* Strips the newline and a trailing \r; true when the line holds only blanks or a comment. */
static bool blank_line(char *s) {
        s[strcspn(s, "\r\n")] = 0;
        s += strspn(s, " \t");
        return !*s || *s == '#';
}

/* A finite number filling the whole token. */
static bool parse_number(const char *tok, double *ret) {
        char *end;
        errno = 0;
        double v = strtod(tok, &end);
        if (end == tok || *end || errno == ERANGE || !isfinite(v))
                return false;
        *ret = v;
        return true;
}

/* One light row: the file name (everything before the last three tokens) and x y z. */
static int parse_row(char *line, const char *path, int lineno, struct imp_lp_light *ret, struct imp_error *err) {
        char *tok[3] = {};
        char *end = line + strlen(line);
        for (int k = 2; k >= 0; k--) {
                while (end > line && (end[-1] == ' ' || end[-1] == '\t'))
                        *--end = 0;
                char *start = end;
                while (start > line && start[-1] != ' ' && start[-1] != '\t')
                        start--;
                if (start == end || start == line)
                        return imp_error_set(err, -EBADMSG, "%s:%d: expected 'filename x y z'", path, lineno);
                tok[k] = start;
                end = start;
        }
        while (end > line && (end[-1] == ' ' || end[-1] == '\t'))
                *--end = 0;
        char *name = line + strspn(line, " \t");
        if (!*name)
                return imp_error_set(err, -EBADMSG, "%s:%d: expected 'filename x y z', no file name", path, lineno);
        if (strlen(name) >= sizeof ret->file)
                return imp_error_set(err, -EBADMSG, "%s:%d: file name longer than %zu bytes", path, lineno,
                                     sizeof ret->file - 1);
        static const char axis[] = "xyz";
        for (int k = 0; k < 3; k++)
                if (!parse_number(tok[k], &ret->v[k]))
                        return imp_error_set(err, -EBADMSG, "%s:%d: %c: expected a finite number, got '%s'",
                                             path, lineno, axis[k], tok[k]);
        snprintf(ret->file, sizeof ret->file, "%s", name);
        ret->rgb[0] = ret->rgb[1] = ret->rgb[2] = 1.0;
        ret->line = lineno;
        return 0;
}

/* The first line: the number of rows. */
static int parse_count(const char *line, const char *path, int lineno, int *ret, struct imp_error *err) {
        char *end;
        const char *s = line + strspn(line, " \t");
        long n = strtol(s, &end, 10);
        end += strspn(end, " \t");
        if (end == s || *end || n < 1 || n > IMP_LP_MAX_LIGHTS)
                return imp_error_set(err, -EBADMSG, "%s:%d: expected the number of lights (1..%d) on the first line, got '%s'",
                                     path, lineno, IMP_LP_MAX_LIGHTS, s);
        *ret = (int) n;
        return 0;
}

/* Decides directions vs positions and checks every row against it. */
static int classify(struct imp_lp *lp, enum imp_lp_kind kind, double unit_mm, const char *path, struct imp_error *err) {
        bool all_unit = true, all_far = true;
        for (int i = 0; i < lp->n; i++) {
                const double *v = lp->lights[i].v;
                double len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                all_unit &= fabs(len - 1) <= IMP_LP_UNIT_TOL;
                all_far &= len > IMP_LP_POSITION_MIN;
        }
        if (kind == IMP_LP_AUTO) {
                if (!all_unit && !all_far) {
                        for (int i = 0; i < lp->n; i++) {
                                const double *v = lp->lights[i].v;
                                double len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                                if (fabs(len - 1) > IMP_LP_UNIT_TOL && len <= IMP_LP_POSITION_MIN)
                                        return imp_error_set(err, -EBADMSG,
                                                "%s:%d: |(%g, %g, %g)| = %.4g: neither a unit direction (|v| = 1 ± %g) "
                                                "nor a position (|v| > %g); rows must be all directions or all positions",
                                                path, lp->lights[i].line, v[0], v[1], v[2], len, IMP_LP_UNIT_TOL,
                                                IMP_LP_POSITION_MIN);
                        }
                        return imp_error_set(err, -EBADMSG, "%s: rows mix unit directions and positions", path);
                }
                kind = all_unit ? IMP_LP_DIRECTIONS : IMP_LP_POSITIONS;
        }
        lp->distant = kind == IMP_LP_DIRECTIONS;
        for (int i = 0; i < lp->n; i++) {
                double *v = lp->lights[i].v;
                double len = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
                if (lp->distant && fabs(len - 1) > IMP_LP_UNIT_TOL)
                        return imp_error_set(err, -EBADMSG, "%s:%d: direction (%g, %g, %g) has length %.4g, expected a unit vector (± %g)",
                                             path, lp->lights[i].line, v[0], v[1], v[2], len, IMP_LP_UNIT_TOL);
                if (!(v[2] > 0))
                        return imp_error_set(err, -EBADMSG, "%s:%d: z = %g: the light must be above the surface (z > 0, towards the camera)",
                                             path, lp->lights[i].line, v[2]);
                for (int k = 0; k < 3; k++)
                        v[k] = lp->distant ? v[k] / len : v[k] * unit_mm;
        }
        return 0;
}

int imp_lp_read(const char *path, enum imp_lp_kind kind, double lp_unit_mm, struct imp_lp *ret, struct imp_error *err) {
        if (!path || !ret || !(lp_unit_mm > 0))
                return imp_error_set(err, -EINVAL, "lp read: bad arguments");
        _cleanup_fclose_ FILE *f = fopen(path, "re");
        if (!f)
                return imp_error_set(err, -errno, "%s: cannot open: %s", path, strerror(errno));
        char line[LP_MAX_LINE];
        int lineno = 0, r, want = 0, have = 0;
        struct imp_lp lp = {};
        while (fgets(line, sizeof line, f)) {
                lineno++;
                if (!strchr(line, '\n') && !feof(f)) {
                        r = imp_error_set(err, -EBADMSG, "%s:%d: line longer than %d bytes", path, lineno, LP_MAX_LINE - 1);
                        goto fail;
                }
                if (blank_line(line))
                        continue;
                if (!lp.lights) {
                        if ((r = parse_count(line, path, lineno, &want, err)) < 0)
                                goto fail;
                        if (!(lp.lights = calloc((size_t) want, sizeof *lp.lights))) {
                                r = imp_error_set(err, -ENOMEM, "out of memory");
                                goto fail;
                        }
                        continue;
                }
                if (have == want) {
                        r = imp_error_set(err, -EBADMSG, "%s:%d: more rows than the %d the first line announces",
                                          path, lineno, want);
                        goto fail;
                }
                if ((r = parse_row(line, path, lineno, &lp.lights[have++], err)) < 0)
                        goto fail;
        }
        if (!lp.lights) {
                r = imp_error_set(err, -EBADMSG, "%s: empty: expected the number of lights on the first line", path);
                goto fail;
        }
        if (have != want) {
                r = imp_error_set(err, -EBADMSG, "%s:%d: the first line announces %d lights, found %d rows",
                                  path, lineno, want, have);
                goto fail;
        }
        lp.n = have;
        if ((r = classify(&lp, kind, lp_unit_mm, path, err)) < 0)
                goto fail;
        *ret = lp;
        return 0;
fail:
        imp_lp_done(&lp);
        return r;
}

int imp_lp_read_intensities(const char *path, struct imp_lp *lp, struct imp_error *err) {
        _cleanup_fclose_ FILE *f = fopen(path, "re");
        if (!f)
                return imp_error_set(err, -errno, "%s: cannot open: %s", path, strerror(errno));
        char line[LP_MAX_LINE];
        int lineno = 0, i = 0;
        double rgb[IMP_LP_MAX_LIGHTS][3];
        while (fgets(line, sizeof line, f)) {
                lineno++;
                if (blank_line(line))
                        continue;
                if (i == lp->n)
                        return imp_error_set(err, -EBADMSG, "%s:%d: more intensity lines than the %d lights of the .lp",
                                             path, lineno, lp->n);
                char *save = NULL, *tok = strtok_r(line, " \t,", &save);
                for (int c = 0; c < 3; c++, tok = strtok_r(NULL, " \t,", &save))
                        if (!tok || !parse_number(tok, &rgb[i][c]) || !(rgb[i][c] > 0))
                                return imp_error_set(err, -EBADMSG, "%s:%d: value %d: expected 'r g b', three numbers > 0, got '%s'",
                                                     path, lineno, c + 1, tok ? tok : "(nothing)");
                if (tok)
                        return imp_error_set(err, -EBADMSG, "%s:%d: expected 'r g b', found more: '%s'", path, lineno, tok);
                i++;
        }
        if (i != lp->n)
                return imp_error_set(err, -EBADMSG, "%s: %d intensity lines, expected one per light of the .lp (%d)",
                                     path, i, lp->n);
        for (i = 0; i < lp->n; i++)
                memcpy(lp->lights[i].rgb, rgb[i], sizeof rgb[i]);
        return 0;
}

/* ---- the capture set ------------------------------------------------------------------ */

static const char *base_name(const char *p) {
        const char *s = strrchr(p, '/'), *b = strrchr(p, '\\');
        if (b && (!s || b > s))
                s = b;
        return s ? s + 1 : p;
}

/* The image of a row: DIR/basename, else DIR/name as written. */
static int find_image(const char *dir, const struct imp_lp_light *L, const char *lp_path, char *ret, size_t size,
                      struct imp_error *err) {
        struct stat st;
        snprintf(ret, size, "%s/%s", dir, base_name(L->file));
        if (stat(ret, &st) == 0)
                return 0;
        snprintf(ret, size, "%s/%s", dir, L->file);
        if (stat(ret, &st) == 0)
                return 0;
        return imp_error_set(err, -ENOENT, "%s:%d: image '%s' not found in %s", lp_path, L->line, base_name(L->file), dir);
}

/* An image as the capture set stores it: u16, 1 or 3 channels (alpha dropped). */
static int to_frame(const struct imp_image *src, const char *path, struct imp_image **ret, struct imp_error *err) {
        if (src->type == IMP_PIX_F32)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: floating-point image: expected 8- or 16-bit", path);
        int ch = src->channels == 2 ? 1 : src->channels == 4 ? 3 : src->channels;
        if (ch != 1 && ch != 3)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: %d channels: expected grey or RGB", path, src->channels);
        struct imp_image *d;
        int r = imp_image_new(src->width, src->height, ch, IMP_PIX_U16, &d);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot allocate %dx%d", path, src->width, src->height);
        for (int y = 0; y < src->height; y++)
                for (int x = 0; x < src->width; x++)
                        for (int c = 0; c < ch; c++)
                                imp_image_u16(d, x, y)[c] = (uint16_t) imp_image_get(src, x, y, c);
        *ret = d;
        return 0;
}

/* The rig of an import: one camera looking down −z from above the origin, the lights. */
static int import_rig(const struct imp_import_photometric_options *o, const struct imp_lp *lp, int w, int h, int bits,
                      double pixel_mm, struct imp_rig *ret) {
        double D = o->camera_distance_mm > 0 ? o->camera_distance_mm : IMP_IMPORT_ORTHO_DISTANCE_MM;
        struct imp_rig rig = { .n_cameras = 1, .n_lights = lp->n };
        struct imp_rig_camera *cam = &rig.cameras[0];
        snprintf(cam->name, sizeof cam->name, "cam0");
        cam->model = (struct imp_pinhole) { .width = w, .height = h, .fx = D / pixel_mm, .fy = D / pixel_mm,
                                            .cx = (w - 1) / 2.0, .cy = (h - 1) / 2.0,
                                            .R = { 1, 0, 0, 0, -1, 0, 0, 0, -1 }, .t = { 0, 0, D } };
        double levels = ldexp(1.0, bits) - 1;
        cam->sensor = (struct imp_sensor) { .bits = bits, .gain_e_per_dn = 1, .read_noise_e = IMPORT_READ_NOISE_E,
                                            .full_well_e = levels + 1, .quantum_scale = levels };
        if (!(rig.lights = calloc((size_t) lp->n, sizeof *rig.lights)))
                return -ENOMEM;
        for (int i = 0; i < lp->n; i++) {
                const struct imp_lp_light *L = &lp->lights[i];
                struct imp_rig_light *R = &rig.lights[i];
                double mean = (L->rgb[0] + L->rgb[1] + L->rgb[2]) / 3, dist = 0;
                R->id = i;
                for (int k = 0; k < 3; k++) {
                        R->pos_mm[k] = lp->distant ? L->v[k] * IMP_IMPORT_ORTHO_DISTANCE_MM : L->v[k];
                        dist += R->pos_mm[k] * R->pos_mm[k];
                        R->colour[k] = L->rgb[k] / mean;
                }
                dist = sqrt(dist);
                for (int k = 0; k < 3; k++)
                        R->axis[k] = -R->pos_mm[k] / dist;
                /* distant: the irradiance at the origin is the file's intensity */
                R->intensity = lp->distant ? mean * (dist / 1000) * (dist / 1000) : mean;
        }
        *ret = rig;
        return 0;
}

static int read_mask(const char *path, int w, int h, struct imp_image **ret, struct imp_error *err) {
        _cleanup_image_ struct imp_image *m = NULL;
        int r = imp_image_read(path, &m, err);
        if (r < 0)
                return r;
        if (m->width != w || m->height != h)
                return imp_error_set(err, -EINVAL, "%s: mask is %dx%d, the images %dx%d", path, m->width, m->height, w, h);
        if (m->type == IMP_PIX_F32)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: expected an 8- or 16-bit mask", path);
        struct imp_image *d;
        if ((r = imp_image_new(w, h, 1, IMP_PIX_U8, &d)) < 0)
                return imp_error_set(err, r, "%s: cannot allocate", path);
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++)
                        *imp_image_u8(d, x, y) = imp_image_get(m, x, y, 0) > 0 ? 255 : 0;
        *ret = d;
        return 0;
}

static json_t *import_json(const struct imp_import_photometric_options *o, const struct imp_lp *lp, double pixel_mm,
                           int bits) {
        json_t *files = json_array();
        for (int i = 0; i < lp->n; i++)
                json_array_append_new(files, json_string(lp->lights[i].file));
        return json_pack("{s:s,s:i,s:s,s:s,s:s,s:s?,s:s?,s:s,s:f,s:b,s:s,s:f,s:i,s:o}",
                         "format", "impasto-import", "version", 1, "source", "photometric",
                         "images", o->images_dir, "lights_file", o->lp_path, "intensities", o->intensities_path,
                         "mask", o->mask_path ? "mask.png" : NULL,
                         "lights", lp->distant ? "directions" : "positions", "pixel_mm", pixel_mm,
                         "pixel_mm_given", o->pixel_mm > 0,
                         "camera", o->camera_distance_mm > 0 ? "pinhole" : "orthographic",
                         "camera_distance_mm", o->camera_distance_mm > 0 ? o->camera_distance_mm : 0.0,
                         "bits", bits, "files", files);
}

/* Reads every image, checking sizes and depths agree; frames[i] u16. */
static int read_images(const struct imp_import_photometric_options *o, const struct imp_lp *lp,
                       struct imp_image **frames, int *ret_bits, struct imp_error *err) {
        char first[4200] = "";
        for (int i = 0; i < lp->n; i++) {
                char path[4200];
                int r = find_image(o->images_dir, &lp->lights[i], o->lp_path, path, sizeof path, err);
                if (r < 0)
                        return r;
                _cleanup_image_ struct imp_image *img = NULL;
                if ((r = imp_image_read(path, &img, err)) < 0)
                        return r == -EINVAL ? imp_error_set(err, -EINVAL, "%s:%d: %s: expected a PNG or TIFF image",
                                                            o->lp_path, lp->lights[i].line, path) : r;
                int bits = img->type == IMP_PIX_U8 ? 8 : 16;
                if (i == 0) {
                        snprintf(first, sizeof first, "%s", path);
                        *ret_bits = bits;
                } else if (img->width != frames[0]->width || img->height != frames[0]->height)
                        return imp_error_set(err, -EINVAL, "%s: %dx%d, but %s is %dx%d: all images must be the same size",
                                             path, img->width, img->height, first, frames[0]->width, frames[0]->height);
                else if (bits != *ret_bits)
                        return imp_error_set(err, -EINVAL, "%s: %d-bit, but %s is %d-bit: all images must have one depth",
                                             path, bits, first, *ret_bits);
                if ((r = to_frame(img, path, &frames[i], err)) < 0)
                        return r;
                if (i > 0 && frames[i]->channels != frames[0]->channels)
                        return imp_error_set(err, -EINVAL, "%s: %d channels, but %s has %d", path,
                                             frames[i]->channels, first, frames[0]->channels);
        }
        return 0;
}

static int write_set(const struct imp_import_photometric_options *o, const struct imp_lp *lp,
                     struct imp_image *const *frames, int bits, const char *out_dir, struct imp_error *err) {
        double pixel_mm = o->pixel_mm > 0 ? o->pixel_mm : 1.0;
        _cleanup_image_ struct imp_image *mask = NULL;
        int r;
        if (o->mask_path && (r = read_mask(o->mask_path, frames[0]->width, frames[0]->height, &mask, err)) < 0)
                return r;
        struct imp_rig rig = {};
        if ((r = import_rig(o, lp, frames[0]->width, frames[0]->height, bits, pixel_mm, &rig)) < 0)
                return imp_error_set(err, r, "out of memory");
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        r = imp_captureset_create(out_dir, &rig, NULL, &cs, err);
        imp_rig_free(&rig);
        if (r < 0)
                return r;
        for (int i = 0; i < lp->n; i++) {
                struct imp_frame_record rec = { .seq = i, .light = i, .exposure_us = IMPORT_EXPOSURE_US };
                snprintf(rec.step, sizeof rec.step, "dome");
                snprintf(rec.camera, sizeof rec.camera, "cam0");
                if ((r = imp_captureset_add_frame(cs, &rec, frames[i], err)) < 0)
                        return r;
        }
        char path[4200];
        if (mask) {
                snprintf(path, sizeof path, "%s/mask.png", out_dir);
                if ((r = imp_png_write(path, mask, err)) < 0)
                        return r;
        }
        _cleanup_json_ json_t *j = import_json(o, lp, pixel_mm, bits);
        if (!j)
                return imp_error_set(err, -ENOMEM, "out of memory");
        snprintf(path, sizeof path, "%s/import.json", out_dir);
        return imp_json_save_atomic(path, j, err);
}

int imp_import_photometric(const struct imp_import_photometric_options *o, const char *out_dir, struct imp_error *err) {
        if (!o || !o->images_dir || !o->lp_path || !out_dir)
                return imp_error_set(err, -EINVAL, "import: --images, --lights and --out are needed");
        struct imp_lp lp = {};
        int r = imp_lp_read(o->lp_path, o->kind, o->lp_unit_mm > 0 ? o->lp_unit_mm : 1.0, &lp, err);
        if (r < 0)
                return r;
        struct imp_image **frames = NULL;
        int bits = 16;
        if (!lp.distant && !(o->pixel_mm > 0)) {
                r = imp_error_set(err, -EINVAL, "%s: the lights are positions: --pixel-size MM is needed to place the "
                                  "pixels relative to them", o->lp_path);
                goto out;
        }
        if (o->intensities_path && (r = imp_lp_read_intensities(o->intensities_path, &lp, err)) < 0)
                goto out;
        if (!(frames = calloc((size_t) lp.n, sizeof *frames))) {
                r = imp_error_set(err, -ENOMEM, "out of memory");
                goto out;
        }
        if ((r = read_images(o, &lp, frames, &bits, err)) < 0)
                goto out;
        r = write_set(o, &lp, frames, bits, out_dir, err);
out:
        for (int i = 0; frames && i < lp.n; i++)
                imp_image_free(frames[i]);
        free(frames);
        imp_lp_done(&lp);
        return r;
}
