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
#include "copy-load.h"
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

static uint8_t srgb8(double v) {
        v = v < 0 ? 0 : v > 1 ? 1 : v;
        double s = v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
        return (uint8_t) lround(s * 255);
}

static int run(int argc, char **argv) {
        double view[6], light[3];
        int n_view = 0, W = RENDER_DEFAULT_W, H = RENDER_DEFAULT_H;
        bool have_light = false, shadows = false;
        double fov = RENDER_DEFAULT_FOV;
        const char *out = NULL;
        enum imp_relief_mode mode = IMP_RELIEF_ADAPTIVE;
        static const struct option longopts[] = {
                { "view", required_argument, NULL, 'v' }, { "light", required_argument, NULL, 'l' },
                { "out", required_argument, NULL, 'o' }, { "mode", required_argument, NULL, 'm' },
                { "size", required_argument, NULL, 's' }, { "fov", required_argument, NULL, 'f' },
                { "shadows", no_argument, NULL, 'S' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        while ((c = getopt_long(argc, argv, "v:l:o:m:s:f:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'v':
                        if ((n_view = parse_vec(optarg, view, 3, 6)) < 0) {
                                log_error("--view: expected X,Y,Z or X,Y,Z,TX,TY,TZ in mm, got '%s'", optarg);
                                return 2;
                        }
                        break;
                case 'l':
                        if (parse_vec(optarg, light, 3, 3) < 0) {
                                log_error("--light: expected X,Y,Z in mm, got '%s'", optarg);
                                return 2;
                        }
                        have_light = true;
                        break;
                case 'o': out = optarg; break;
                case 'm':
                        if (!strcmp(optarg, "bump")) mode = IMP_RELIEF_BUMP_ONLY;
                        else if (!strcmp(optarg, "relief")) mode = IMP_RELIEF_RELIEF_ALL;
                        else if (!strcmp(optarg, "adaptive")) mode = IMP_RELIEF_ADAPTIVE;
                        else {
                                log_error("--mode: expected bump, relief or adaptive, got '%s'", optarg);
                                return 2;
                        }
                        break;
                case 's': {
                        char tail;
                        if (sscanf(optarg, "%dx%d%c", &W, &H, &tail) != 2 || W < 1 || H < 1 ||
                            W > RENDER_MAX_SIDE || H > RENDER_MAX_SIDE) {
                                log_error("--size: expected WxH with 1..%d pixels a side, got '%s'",
                                          RENDER_MAX_SIDE, optarg);
                                return 2;
                        }
                        break;
                }
                case 'f': {
                        char *end;
                        fov = strtod(optarg, &end);
                        if (end == optarg || *end || !(fov > 0.1 && fov < 170)) {
                                log_error("--fov: expected degrees in (0.1, 170), got '%s'", optarg);
                                return 2;
                        }
                        break;
                }
                case 'S': shadows = true; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return 2;
                }
        if (optind + 1 != argc || !n_view || !have_light || !out) {
                if (optind + 1 != argc)
                        log_error("expected one COPY_DIR");
                else
                        log_error("missing %s", !n_view ? "--view" : !have_light ? "--light" : "--out");
                usage(stderr);
                return 2;
        }
        bool png = ends_with(out, ".png");
        if (!png && !ends_with(out, ".exr")) {
                log_error("--out: '%s' must end in .png or .exr", out);
                return 2;
        }

        struct imp_error err = {};
        struct imp_copy L;
        int r = imp_copy_load(argv[optind], &L, &err);
        _cleanup_image_ struct imp_image *img = NULL, *o8 = NULL;
        struct imp_relief_scene *scene = NULL;
        int ret = 3;
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                goto out;
        }
        struct imp_relief_copy copy;
        imp_copy_relief(&L, &copy);
        r = imp_relief_scene_new(&copy, &scene);
        if (r < 0) {
                log_error("%s: the copy cannot be rendered: %s", argv[optind], strerror(-r));
                goto out;
        }
        double centre[3] = { 0.5 * (copy.nx - 1) * copy.pitch_mm, 0.5 * (copy.ny - 1) * copy.pitch_mm,
                             copy.delta0_mm };
        double target[3] = { centre[0], centre[1], centre[2] };
        if (n_view == 6)
                memcpy(target, view + 3, sizeof target);
        double dv = hypot(hypot(view[0] - target[0], view[1] - target[1]), view[2] - target[2]);
        if (!(dv > 0)) {
                log_error("--view: the eye and the target coincide");
                ret = 2;
                goto out;
        }
        double fx = 0.5 * W / tan(0.5 * fov * M_PI / 180);
        struct imp_pinhole cam = { .width = W, .height = H, .fx = fx, .fy = fx, .cx = (W - 1) / 2.0,
                                   .cy = (H - 1) / 2.0 };
        double right[3] = { 1, 0, 0 };
        if (fabs(view[1] - target[1]) < 1e-9 && fabs(view[2] - target[2]) < 1e-9)
                right[0] = 0, right[1] = 1;   /* looking along x: image x along canvas y */
        imp_pinhole_look_at(&cam, view, target, right);
        double d[3] = { centre[0] - light[0], centre[1] - light[1], centre[2] - light[2] };
        double dl = hypot(hypot(d[0], d[1]), d[2]);
        if (!(dl > 0)) {
                log_error("--light: the light is at the canvas centre");
                ret = 2;
                goto out;
        }
        /* E = intensity·(1000/r)²: intensity (r/1000)² gives E = 1 at the centre. */
        struct imp_rig_light lt = { .pos_mm = { light[0], light[1], light[2] }, .intensity = (dl / 1000) * (dl / 1000),
                                    .colour = { 1, 1, 1 }, .axis = { d[0] / dl, d[1] / dl, d[2] / dl } };
        struct imp_relief_options ro;
        imp_relief_options_default(&ro);
        ro.mode = mode;
        ro.shadows = shadows;
        if ((r = imp_image_new(W, H, 3, IMP_PIX_F32, &img)) < 0) {
                log_error("out of memory");
                ret = 1;
                goto out;
        }
        struct imp_relief_stats st = {};
        r = imp_relief_render(scene, &cam, &lt, &ro, img, NULL, &st);
        if (r < 0) {
                log_error("render failed: %s", strerror(-r));
                ret = 1;
                goto out;
        }
        if (st.flags & IMP_RELIEF_CAMERA_BELOW)
                log_warning("the view is on or below the bump plane: the picture is black");
        if (png) {
                if ((r = imp_image_new(W, H, 3, IMP_PIX_U8, &o8)) < 0) {
                        log_error("out of memory");
                        ret = 1;
                        goto out;
                }
                for (int y = 0; y < H; y++)
                        for (int x = 0; x < W; x++)
                                for (int k = 0; k < 3; k++)
                                        imp_image_u8(o8, x, y)[k] = srgb8(imp_image_f32(img, x, y)[k]);
                r = imp_png_write(out, o8, &err);
        } else {
                static const char *const rgb[] = { "R", "G", "B" };
                r = imp_exr_write(out, img, rgb, false, &err);
        }
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                ret = 1;
                goto out;
        }
        printf("%s: %dx%d, %zu pixels see the copy, %zu by relief mapping, %zu of %zu boxes drawn\n", out, W, H,
               st.n_pixels_hit, st.n_pixels_relief, st.n_boxes_drawn, copy.n_boxes);
        ret = 0;
out:
        imp_relief_scene_free(scene);
        imp_copy_done(&L);
        return ret;
}

const struct imp_command imp_cmd_render = {
        .name = "render",
        .summary = "render a digital copy under a point light (bump / relief / adaptive)",
        .run = run,
};
