/* `impasto render COPY_DIR --view X,Y,Z[,TX,TY,TZ] --light X,Y,Z --out FILE.png|.exr
 *  [--mode bump|relief|adaptive] [--size WxH] [--fov DEG] [--shadows]`: a picture of a digital
 * copy with the hybrid bump/relief renderer (pipeline/appearance/relief-render.h, seed §5).
 *
 * Everything is in the copy's canvas frame (mm; texel (i, j) at (i·pitch, j·pitch), z out of
 * the paint): the copy is rendered with canvas_to_world = identity. The view is a pinhole at
 * X,Y,Z looking at TX,TY,TZ (default: the canvas centre on the bump plane), image x along
 * canvas x; --fov is the horizontal field of view. The light is an isotropic point light at
 * X,Y,Z whose intensity gives irradiance 1 at the canvas centre, so a white Lambertian facing
 * it renders as 1. PNG: V clamped to [0, 1], sRGB-encoded, 8 bit; EXR: linear float R, G, B. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "commands.h"
#include "exit-codes.h"
#include "image.h"
#include "json-util.h"
#include "log.h"
#include "relief-render.h"

#define RENDER_DEFAULT_W    800
#define RENDER_DEFAULT_H    600
#define RENDER_DEFAULT_FOV  40.0   /* degrees, horizontal */
#define RENDER_MAX_SIDE     16384

static void usage(FILE *f) {
        fprintf(f, "usage: impasto render COPY_DIR --view X,Y,Z[,TX,TY,TZ] --light X,Y,Z --out FILE.png|.exr\n"
                   "                      [--mode bump|relief|adaptive] [--size WxH] [--fov DEG] [--shadows]\n"
                   "  coordinates in mm in the copy's canvas frame; the target defaults to the canvas centre\n");
}

/* Parses n or m comma-separated finite numbers; returns how many, or -1. */
static int parse_vec(const char *s, double *v, int n, int m) {
        int k = 0;
        const char *p = s;
        while (k < m) {
                char *end;
                errno = 0;
                double x = strtod(p, &end);
                if (end == p || errno || !isfinite(x))
                        return -1;
                v[k++] = x;
                if (*end == 0)
                        break;
                if (*end != ',')
                        return -1;
                p = end + 1;
        }
        return (k == n || k == m) && *p && p[strlen(p) - 1] != ',' ? k : -1;
}

static bool ends_with(const char *s, const char *suffix) {
        size_t a = strlen(s), b = strlen(suffix);
        return a >= b && !strcasecmp(s + a - b, suffix);
}

/* The copy's files loaded into a struct imp_relief_copy (canvas frame: identity transform). */
struct loaded {
        struct imp_relief_copy copy;
        float *height, *nx, *ny;
        struct imp_lafortune *brdf;
        struct imp_relief_box *boxes;
        double h_ref;
};

static void loaded_done(struct loaded *l) {
        free(l->height);
        free(l->nx);
        free(l->ny);
        free(l->brdf);
        free(l->boxes);
}

static int read_exr(const char *dir, const char *file, const char *const *chans, int n, int w, int h,
                    struct imp_image **ret, int *ret_c, struct imp_error *err) {
        char path[4096];
        snprintf(path, sizeof path, "%s/%s", dir, file);
        char **names = NULL;
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_exr_read(path, &img, &names, err);
        if (r < 0)
                return r;
        for (int i = 0; i < n; i++)
                if ((ret_c[i] = imp_image_channel_index(names, chans[i])) < 0) {
                        imp_strv_free(names);
                        return imp_error_set(err, -EBADMSG, "%s: channel \"%s\" missing", path, chans[i]);
                }
        imp_strv_free(names);
        if (w > 0 && (img->width != w || img->height != h))
                return imp_error_set(err, -EBADMSG, "%s: %dx%d, copy.json says %dx%d", path, img->width,
                                     img->height, w, h);
        *ret = TAKE_PTR(img);
        return 0;
}

static float finite_or(double v, float dflt) {
        return isfinite(v) ? (float) v : dflt;
}

static int load_copy(const char *dir, struct loaded *L, struct imp_error *err) {
        char path[4096];
        _cleanup_json_ json_t *cj = NULL, *bj = NULL;
        snprintf(path, sizeof path, "%s/copy.json", dir);
        int r = imp_json_load(path, &cj, err);
        if (r < 0)
                return r;
        long long nx, ny;
        double pitch;
        if ((r = imp_json_get_int(cj, "nx", true, &nx, path, err)) < 0 ||
            (r = imp_json_get_int(cj, "ny", true, &ny, path, err)) < 0 ||
            (r = imp_json_get_double(cj, "pitch_mm", true, &pitch, path, err)) < 0)
                return r;
        if (nx < 1 || ny < 1 || nx > 1 << 20 || ny > 1 << 20 || !(pitch > 0))
                return imp_error_set(err, -EBADMSG, "%s: bad grid %lldx%lld at pitch %g", path, nx, ny, pitch);
        snprintf(path, sizeof path, "%s/boxes.json", dir);
        if ((r = imp_json_load(path, &bj, err)) < 0)
                return r;
        double h_ref, delta0;
        if ((r = imp_json_get_double(bj, "h_ref", true, &h_ref, path, err)) < 0 ||
            (r = imp_json_get_double(bj, "delta0", true, &delta0, path, err)) < 0)
                return r;

        static const char *const HF[] = { "height", "nx", "ny", "mask" }, *const RGB[] = { "R", "G", "B" },
                                 *const LOBE[] = { "cx", "cy", "cz", "k" };
        _cleanup_image_ struct imp_image *hf = NULL, *rd = NULL, *rs = NULL, *lo = NULL;
        int ch[4], cd[3], cs[3], cl[4];
        if ((r = read_exr(dir, "heightfield.exr", HF, 4, (int) nx, (int) ny, &hf, ch, err)) < 0 ||
            (r = read_exr(dir, "rho_d.exr", RGB, 3, (int) nx, (int) ny, &rd, cd, err)) < 0 ||
            (r = read_exr(dir, "rho_s.exr", RGB, 3, (int) nx, (int) ny, &rs, cs, err)) < 0 ||
            (r = read_exr(dir, "lobe.exr", LOBE, 4, (int) nx, (int) ny, &lo, cl, err)) < 0)
                return r;

        size_t n = (size_t) nx * ny;
        L->height = malloc(n * sizeof(float));
        L->nx = malloc(n * sizeof(float));
        L->ny = malloc(n * sizeof(float));
        L->brdf = calloc(n, sizeof *L->brdf);
        if (!L->height || !L->nx || !L->ny || !L->brdf)
                return imp_error_set(err, -ENOMEM, "out of memory");
        /* Texels off the canvas mask get the bump plane and black paint: the renderer wants
         * finite, non-negative values everywhere. */
        float plane = (float) (h_ref + delta0);
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t k = (size_t) j * nx + i;
                        const float *p = imp_image_f32(hf, i, j);
                        bool in = p[ch[3]] >= 0.5f && isfinite(p[ch[0]]);
                        L->height[k] = in ? p[ch[0]] : plane;
                        L->nx[k] = in ? finite_or(p[ch[1]], 0) : 0;
                        L->ny[k] = in ? finite_or(p[ch[2]], 0) : 0;
                        struct imp_lafortune *b = &L->brdf[k];
                        const float *d = imp_image_f32(rd, i, j), *s = imp_image_f32(rs, i, j);
                        const float *l = imp_image_f32(lo, i, j);
                        for (int c = 0; c < 3; c++) {
                                b->rho_d[c] = in ? fmaxf(finite_or(d[cd[c]], 0), 0) : 0;
                                b->rho_s[c] = in ? fmaxf(finite_or(s[cs[c]], 0), 0) : 0;
                        }
                        b->cx = finite_or(l[cl[0]], -1), b->cy = finite_or(l[cl[1]], -1);
                        b->cz = finite_or(l[cl[2]], 1), b->k = fmaxf(finite_or(l[cl[3]], 1), 0);
                }

        json_t *arr = json_object_get(bj, "boxes");
        size_t nb = json_is_array(arr) ? json_array_size(arr) : 0;
        L->boxes = calloc(nb ? nb : 1, sizeof *L->boxes);
        if (!L->boxes)
                return imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t b = 0; b < nb; b++) {
                json_t *o = json_array_get(arr, b);
                long long u0, v0, w, h, um, vm;
                double hmax;
                if ((r = imp_json_get_int(o, "u0", true, &u0, path, err)) < 0 ||
                    (r = imp_json_get_int(o, "v0", true, &v0, path, err)) < 0 ||
                    (r = imp_json_get_int(o, "w", true, &w, path, err)) < 0 ||
                    (r = imp_json_get_int(o, "h", true, &h, path, err)) < 0 ||
                    (r = imp_json_get_int(o, "umax", true, &um, path, err)) < 0 ||
                    (r = imp_json_get_int(o, "vmax", true, &vm, path, err)) < 0 ||
                    (r = imp_json_get_double(o, "hmax", true, &hmax, path, err)) < 0)
                        return r;
                L->boxes[b] = (struct imp_relief_box) { (int) u0, (int) v0, (int) w, (int) h, (float) hmax,
                                                        (int) um, (int) vm };
        }
        L->h_ref = h_ref;
        L->copy = (struct imp_relief_copy) {
                .nx = (int) nx, .ny = (int) ny, .pitch_mm = pitch, .height_mm = L->height,
                .normal_x = L->nx, .normal_y = L->ny, .brdf = L->brdf, .boxes = L->boxes, .n_boxes = nb,
                .delta0_mm = plane,
                .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 },
        };
        return 0;
}

static uint8_t srgb8(double v) {
        v = v < 0 ? 0 : v > 1 ? 1 : v;
        double s = v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
        return (uint8_t) lround(s * 255);
}

/* The command line. */
struct render_args {
        const char *copy, *out;
        double view[6], light[3], fov;
        int n_view, W, H;
        bool have_light, shadows, png;
        enum imp_relief_mode mode;
};

/* Parses argv into *a: 0, an exit code, or -1 after --help. */
static int parse_args(int argc, char **argv, struct render_args *a) {
        *a = (struct render_args) { .W = RENDER_DEFAULT_W, .H = RENDER_DEFAULT_H, .fov = RENDER_DEFAULT_FOV,
                                    .mode = IMP_RELIEF_ADAPTIVE };
        static const struct option longopts[] = {
                { "view", required_argument, NULL, 'v' }, { "light", required_argument, NULL, 'l' },
                { "out", required_argument, NULL, 'o' }, { "mode", required_argument, NULL, 'm' },
                { "size", required_argument, NULL, 's' }, { "fov", required_argument, NULL, 'f' },
                { "shadows", no_argument, NULL, 'S' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        char tail, *end;
        while ((c = getopt_long(argc, argv, "v:l:o:m:s:f:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'v':
                        if ((a->n_view = parse_vec(optarg, a->view, 3, 6)) < 0)
                                return log_error("--view: expected X,Y,Z or X,Y,Z,TX,TY,TZ in mm, got '%s'", optarg),
                                       IMP_EXIT_USAGE;
                        break;
                case 'l':
                        if (parse_vec(optarg, a->light, 3, 3) < 0)
                                return log_error("--light: expected X,Y,Z in mm, got '%s'", optarg), IMP_EXIT_USAGE;
                        a->have_light = true;
                        break;
                case 'o': a->out = optarg; break;
                case 'm':
                        if (!strcmp(optarg, "bump")) a->mode = IMP_RELIEF_BUMP_ONLY;
                        else if (!strcmp(optarg, "relief")) a->mode = IMP_RELIEF_RELIEF_ALL;
                        else if (!strcmp(optarg, "adaptive")) a->mode = IMP_RELIEF_ADAPTIVE;
                        else
                                return log_error("--mode: expected bump, relief or adaptive, got '%s'", optarg),
                                       IMP_EXIT_USAGE;
                        break;
                case 's':
                        if (sscanf(optarg, "%dx%d%c", &a->W, &a->H, &tail) != 2 || a->W < 1 || a->H < 1 ||
                            a->W > RENDER_MAX_SIDE || a->H > RENDER_MAX_SIDE)
                                return log_error("--size: expected WxH with 1..%d pixels a side, got '%s'",
                                                 RENDER_MAX_SIDE, optarg), IMP_EXIT_USAGE;
                        break;
                case 'f':
                        a->fov = strtod(optarg, &end);
                        if (end == optarg || *end || !(a->fov > 0.1 && a->fov < 170))
                                return log_error("--fov: expected degrees in (0.1, 170), got '%s'", optarg),
                                       IMP_EXIT_USAGE;
                        break;
                case 'S': a->shadows = true; break;
                case 'h': usage(stdout); return -1;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        if (optind + 1 != argc || !a->n_view || !a->have_light || !a->out) {
                if (optind + 1 != argc)
                        log_error("expected one COPY_DIR");
                else
                        log_error("missing %s", !a->n_view ? "--view" : !a->have_light ? "--light" : "--out");
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        a->copy = argv[optind];
        a->png = ends_with(a->out, ".png");
        if (!a->png && !ends_with(a->out, ".exr"))
                return log_error("--out: '%s' must end in .png or .exr", a->out), IMP_EXIT_USAGE;
        return 0;
}

/* The camera and the light of the command line for the copy: an exit code. */
static int view_and_light(const struct render_args *a, const struct imp_relief_copy *copy, struct imp_pinhole *ret_cam,
                          struct imp_rig_light *ret_light) {
        double centre[3] = { 0.5 * (copy->nx - 1) * copy->pitch_mm, 0.5 * (copy->ny - 1) * copy->pitch_mm,
                             copy->delta0_mm };
        double target[3] = { centre[0], centre[1], centre[2] };
        const double *view = a->view, *light = a->light;
        if (a->n_view == 6)
                memcpy(target, view + 3, sizeof target);
        double dv = hypot(hypot(view[0] - target[0], view[1] - target[1]), view[2] - target[2]);
        if (!(dv > 0))
                return log_error("--view: the eye and the target coincide"), IMP_EXIT_USAGE;
        double fx = 0.5 * a->W / tan(0.5 * a->fov * M_PI / 180);
        struct imp_pinhole cam = { .width = a->W, .height = a->H, .fx = fx, .fy = fx, .cx = (a->W - 1) / 2.0,
                                   .cy = (a->H - 1) / 2.0 };
        double right[3] = { 1, 0, 0 };
        if (fabs(view[1] - target[1]) < 1e-9 && fabs(view[2] - target[2]) < 1e-9)
                right[0] = 0, right[1] = 1;   /* looking along x: image x along canvas y */
        imp_pinhole_look_at(&cam, view, target, right);
        double d[3] = { centre[0] - light[0], centre[1] - light[1], centre[2] - light[2] };
        double dl = hypot(hypot(d[0], d[1]), d[2]);
        if (!(dl > 0))
                return log_error("--light: the light is at the canvas centre"), IMP_EXIT_USAGE;
        /* E = intensity·(1000/r)²: intensity (r/1000)² gives E = 1 at the centre. */
        *ret_light = (struct imp_rig_light) { .pos_mm = { light[0], light[1], light[2] },
                                              .intensity = (dl / 1000) * (dl / 1000), .colour = { 1, 1, 1 },
                                              .axis = { d[0] / dl, d[1] / dl, d[2] / dl } };
        *ret_cam = cam;
        return 0;
}

/* Writes the f32 picture as PNG (sRGB, 8 bit) or EXR (linear): an exit code. */
static int write_picture(const struct render_args *a, const struct imp_image *img) {
        struct imp_error err = {};
        _cleanup_image_ struct imp_image *o8 = NULL;
        int r;
        if (a->png) {
                if ((r = imp_image_new(a->W, a->H, 3, IMP_PIX_U8, &o8)) < 0)
                        return log_error("out of memory"), IMP_EXIT_FAILURE;
                for (int y = 0; y < a->H; y++)
                        for (int x = 0; x < a->W; x++)
                                for (int k = 0; k < 3; k++)
                                        imp_image_u8(o8, x, y)[k] = srgb8(imp_image_f32(img, x, y)[k]);
                r = imp_png_write(a->out, o8, &err);
        } else {
                static const char *const rgb[] = { "R", "G", "B" };
                r = imp_exr_write(a->out, img, rgb, false, &err);
        }
        if (r < 0)
                return log_error("%s", err.msg[0] ? err.msg : strerror(-r)), IMP_EXIT_FAILURE;
        return 0;
}

/* Renders the loaded copy and writes the picture: an exit code. */
static int render_copy(const struct render_args *a, const struct imp_relief_scene *scene,
                       const struct imp_relief_copy *copy) {
        struct imp_pinhole cam;
        struct imp_rig_light lt;
        int ret = view_and_light(a, copy, &cam, &lt);
        if (ret != 0)
                return ret;
        struct imp_relief_options ro;
        imp_relief_options_default(&ro);
        ro.mode = a->mode;
        ro.shadows = a->shadows;
        _cleanup_image_ struct imp_image *img = NULL;
        if (imp_image_new(a->W, a->H, 3, IMP_PIX_F32, &img) < 0)
                return log_error("out of memory"), IMP_EXIT_FAILURE;
        struct imp_relief_stats st = {};
        int r = imp_relief_render(scene, &cam, &lt, &ro, img, NULL, &st);
        if (r < 0)
                return log_error("render failed: %s", strerror(-r)), IMP_EXIT_FAILURE;
        if (st.flags & IMP_RELIEF_CAMERA_BELOW)
                log_warning("the view is on or below the bump plane: the picture is black");
        if ((ret = write_picture(a, img)) != 0)
                return ret;
        printf("%s: %dx%d, %zu pixels see the copy, %zu by relief mapping, %zu of %zu boxes drawn\n", a->out, a->W,
               a->H, st.n_pixels_hit, st.n_pixels_relief, st.n_boxes_drawn, copy->n_boxes);
        return 0;
}

static int run(int argc, char **argv) {
        struct render_args a;
        int ret = parse_args(argc, argv, &a);
        if (ret != 0)
                return ret < 0 ? 0 : ret;
        struct imp_error err = {};
        struct loaded L = {};
        struct imp_relief_scene *scene = NULL;
        int r = load_copy(a.copy, &L, &err);
        ret = IMP_EXIT_BAD_INPUT;
        if (r < 0)
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
        else if ((r = imp_relief_scene_new(&L.copy, &scene)) < 0)
                log_error("%s: the copy cannot be rendered: %s", a.copy, strerror(-r));
        else
                ret = render_copy(&a, scene, &L.copy);
        imp_relief_scene_free(scene);
        loaded_done(&L);
        return ret;
}

const struct imp_command imp_cmd_render = {
        .name = "render",
        .summary = "render a digital copy under a point light (bump / relief / adaptive)",
        .run = run,
};
