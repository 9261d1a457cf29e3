/* `impasto render COPY_DIR --view X,Y,Z[,TX,TY,TZ] --light X,Y,Z --out FILE.png|.exr
 *  [--mode bump|relief|adaptive] [--size WxH] [--fov DEG] [--shadows]`: a picture of a digital
 * copy with the hybrid bump/relief renderer (pipeline/appearance/relief-render.h, seed §5).
 *
 * Everything is in the copy's canvas frame (mm; texel (i, j) at (i·pitch, j·pitch), z out of
 * the paint): the copy is rendered with canvas_to_world = identity. The view is a pinhole at
 * X,Y,Z looking at TX,TY,TZ (default: the canvas centre on the bump plane), image x along
 * canvas x; --fov is the horizontal field of view (default: the canvas fills the frame). The light is an isotropic point light at
 * X,Y,Z whose intensity gives irradiance 1 at the canvas centre, so a white Lambertian facing
 * it renders as 1. PNG: V clamped to [0, 1], sRGB-encoded, 8 bit; EXR: linear float R, G, B. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "commands.h"
#include "copy-load.h"
#include "exit-codes.h"
#include "image.h"
#include "json-util.h"
#include "log.h"
#include "relief-render.h"

#define RENDER_DEFAULT_W    800
#define RENDER_DEFAULT_H    600
#define RENDER_FRAME_FILL   0.95   /* without --fov: the canvas spans this share of the shorter side */
#define RENDER_MAX_SIDE     16384

static void usage(FILE *f) {
        fprintf(f, "usage: impasto render COPY_DIR --view X,Y,Z[,TX,TY,TZ] --light X,Y,Z --out FILE.png|.exr\n"
                   "                      [--mode bump|relief|adaptive] [--size WxH] [--fov DEG] [--shadows]\n"
                   "  coordinates in mm in the copy's canvas frame; the target defaults to the canvas centre\n"
                   "  --fov DEG     horizontal field of view (default: the canvas fills the frame)\n");
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
        *a = (struct render_args) { .W = RENDER_DEFAULT_W, .H = RENDER_DEFAULT_H, .fov = 0,
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
        if (a->fov == 0) {   /* frame the canvas: its bounding sphere fills the shorter side */
                double R = 0.5 * hypot(copy->nx * copy->pitch_mm, copy->ny * copy->pitch_mm) +
                           hypot(hypot(target[0] - centre[0], target[1] - centre[1]), target[2] - centre[2]);
                double half = asin(fmin(R / dv, 0.99));
                fx = RENDER_FRAME_FILL * 0.5 * fmin(a->W, a->H) / tan(half);
        }
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
        struct imp_copy L;
        struct imp_relief_scene *scene = NULL;
        int r = imp_copy_load(a.copy, &L, &err);
        ret = IMP_EXIT_BAD_INPUT;
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return ret;
        }
        struct imp_relief_copy copy;
        imp_copy_relief(&L, &copy);
        if ((r = imp_relief_scene_new(&copy, &scene)) < 0)
                log_error("%s: the copy cannot be rendered: %s", a.copy, strerror(-r));
        else
                ret = render_copy(&a, scene, &copy);
        imp_relief_scene_free(scene);
        imp_copy_done(&L);
        return ret;
}

const struct imp_command imp_cmd_render = {
        .name = "render",
        .summary = "render a digital copy under a point light (bump / relief / adaptive)",
        .run = run,
};
