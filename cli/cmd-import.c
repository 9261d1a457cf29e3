/* `impasto import`: captures from other rigs into capture sets (docs/import.md).
 *   impasto import photometric --images DIR --lights FILE.lp [--intensities FILE] [--mask MASK.png]
 *                              [--pixel-size MM] [--camera-distance MM] [--light-kind K] [--lp-unit MM]
 *                              --out CAPSET
 *   impasto import sl --frames DIR --order opencv-graycode --projector WxH --calib RIG.json --out CAPSET
 * The parsing and writing are in pipeline/model/import-photometric.c. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include "commands.h"
#include "import-photometric.h"
#include "import-sl.h"
#ifdef IMPASTO_HAVE_CV
#include "cv-procam-xml.h"
#endif
#include "log.h"

#define EXIT_USAGE 2
#define EXIT_BADINPUT 3

static void usage(FILE *f) {
        fprintf(f, "usage: impasto import photometric --images DIR --lights FILE.lp --out CAPSET\n"
                   "                                  [--intensities FILE] [--mask MASK.png] [--pixel-size MM]\n"
                   "                                  [--camera-distance MM] [--light-kind auto|directions|positions]\n"
                   "                                  [--lp-unit MM]\n"
                   "  A folder of 8/16-bit PNG/TIFF images, one per light, and the RTI .lp light file\n"
                   "  (first line the count, then 'filename x y z'; x right, y up, z towards the camera)\n"
                   "  become a capture set for `impasto process CAPSET --out COPY --photometric-only`.\n"
                   "  --intensities FILE   one 'r g b' line per image, in .lp order (default 1 1 1)\n"
                   "  --mask MASK.png      non-zero = object; other pixels are not processed\n"
                   "  --pixel-size MM      pixel footprint on the surface (needed when the .lp gives positions)\n"
                   "  --camera-distance MM a pinhole this far above the surface (default: orthographic)\n"
                   "  --light-kind K       auto (default): unit vectors are distant lights, vectors longer\n"
                   "                       than 1.5 are positions; directions: every row must be unit\n"
                   "  --lp-unit MM         millimetres per .lp position unit (default 1)\n"
                   "  The images folder is only read.\n"
                   "usage: impasto import sl --frames DIR --order opencv-graycode --projector WxH\n"
                   "                         --calib RIG.json|CALIB.xml --out CAPSET\n"
                   "  The camera frames of OpenCV's GrayCodePattern sequence (column then row bit planes,\n"
                   "  most significant first, each followed by its inverse; then white, black), in file\n"
                   "  name order, with the rig.json of `impasto calibrate procam --out` (or an OpenCV\n"
                   "  XML/YAML file with cam_int, cam_dist, proj_int, proj_dist, rotation, translation,\n"
                   "  as procam-calibration writes it), become a capture set for\n"
                   "  `impasto process CAPSET --out DIR --range-only` (range.exr on the camera grid).\n");
}

static int positive_arg(const char *name, const char *arg, double *ret) {
        char *end;
        double v = strtod(arg, &end);
        if (end == arg || *end || !isfinite(v) || !(v > 0)) {
                log_error("--%s: expected a number > 0, got '%s'", name, arg);
                return -EINVAL;
        }
        *ret = v;
        return 0;
}

static int parse_kind(const char *arg, enum imp_lp_kind *ret) {
        static const char *const names[] = { "auto", "directions", "positions" };
        for (int i = 0; i < 3; i++)
                if (!strcmp(arg, names[i])) {
                        *ret = (enum imp_lp_kind) i;
                        return 0;
                }
        log_error("--light-kind: expected auto, directions or positions, got '%s'", arg);
        return -EINVAL;
}

static int run_photometric(int argc, char **argv) {
        struct imp_import_photometric_options o;
        imp_import_photometric_options_default(&o);
        const char *out = NULL;
        static const struct option longopts[] = {
                { "images", required_argument, NULL, 'i' }, { "lights", required_argument, NULL, 'l' },
                { "intensities", required_argument, NULL, 'I' }, { "mask", required_argument, NULL, 'm' },
                { "pixel-size", required_argument, NULL, 'p' }, { "camera-distance", required_argument, NULL, 'd' },
                { "light-kind", required_argument, NULL, 'k' }, { "lp-unit", required_argument, NULL, 'u' },
                { "out", required_argument, NULL, 'o' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        optind = 1;
        while ((c = getopt_long(argc, argv, "o:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'i': o.images_dir = optarg; break;
                case 'l': o.lp_path = optarg; break;
                case 'I': o.intensities_path = optarg; break;
                case 'm': o.mask_path = optarg; break;
                case 'o': out = optarg; break;
                case 'p': if (positive_arg("pixel-size", optarg, &o.pixel_mm) < 0) return EXIT_USAGE; break;
                case 'd': if (positive_arg("camera-distance", optarg, &o.camera_distance_mm) < 0) return EXIT_USAGE; break;
                case 'u': if (positive_arg("lp-unit", optarg, &o.lp_unit_mm) < 0) return EXIT_USAGE; break;
                case 'k': if (parse_kind(optarg, &o.kind) < 0) return EXIT_USAGE; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return EXIT_USAGE;
                }
        if (optind != argc || !o.images_dir || !o.lp_path || !out) {
                log_error("import photometric: --images, --lights and --out are required");
                usage(stderr);
                return EXIT_USAGE;
        }
        struct imp_error err = {};
        int r = imp_import_photometric(&o, out, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return r == -ENOMEM || r == -EIO || r == -ENOSPC ? 1 : EXIT_BADINPUT;
        }
        printf("capture set written to %s\n", out);
        return 0;
}

static int parse_wxh(const char *arg, int *w, int *h) {
        char *end;
        long a = strtol(arg, &end, 10), b = *end == 'x' ? strtol(end + 1, &end, 10) : 0;
        if (*end || a < 2 || b < 2 || a > 65536 || b > 65536) {
                log_error("--projector: expected WxH (2..65536 each), got '%s'", arg);
                return -EINVAL;
        }
        *w = (int) a, *h = (int) b;
        return 0;
}

static int run_sl(int argc, char **argv) {
        struct imp_import_sl_options o = {};
        const char *out = NULL, *order = NULL;
        static const struct option longopts[] = {
                { "frames", required_argument, NULL, 'f' }, { "order", required_argument, NULL, 'r' },
                { "projector", required_argument, NULL, 'p' }, { "calib", required_argument, NULL, 'c' },
                { "out", required_argument, NULL, 'o' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        optind = 1;
        while ((c = getopt_long(argc, argv, "o:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'f': o.frames_dir = optarg; break;
                case 'r': order = optarg; break;
                case 'c': o.calib_path = optarg; break;
                case 'o': out = optarg; break;
                case 'p': if (parse_wxh(optarg, &o.proj_width, &o.proj_height) < 0) return EXIT_USAGE; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return EXIT_USAGE;
                }
        if (optind != argc || !o.frames_dir || !o.calib_path || !out || !o.proj_width || !order) {
                log_error("import sl: --frames, --order, --projector, --calib and --out are required");
                usage(stderr);
                return EXIT_USAGE;
        }
        if (strcmp(order, "opencv-graycode")) {
                log_error("--order: expected opencv-graycode, got '%s'", order);
                return EXIT_USAGE;
        }
        struct imp_error err = {};
        struct imp_rig xml_rig = {};
        int r = 0;
        const char *ext = strrchr(o.calib_path, '.');
        if (ext && (!strcasecmp(ext, ".xml") || !strcasecmp(ext, ".yml") || !strcasecmp(ext, ".yaml"))) {
#ifdef IMPASTO_HAVE_CV
                r = imp_cv_procam_xml_rig(o.calib_path, &xml_rig, &err);
                o.calib_rig = &xml_rig;
#else
                r = imp_error_set(&err, -EOPNOTSUPP, "%s: OpenCV XML/YAML needs impasto built with OpenCV", o.calib_path);
#endif
        }
        if (r >= 0)
                r = imp_import_sl(&o, out, &err);
        imp_rig_free(&xml_rig);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return r == -ENOMEM || r == -EIO || r == -ENOSPC ? 1 : EXIT_BADINPUT;
        }
        printf("capture set written to %s\n", out);
        return 0;
}

static int run(int argc, char **argv) {
        if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
                usage(argc < 2 ? stderr : stdout);
                return argc < 2 ? EXIT_USAGE : 0;
        }
        if (!strcmp(argv[1], "photometric"))
                return run_photometric(argc - 1, argv + 1);
        if (!strcmp(argv[1], "sl"))
                return run_sl(argc - 1, argv + 1);
        log_error("import: unknown source '%s' (expected photometric or sl)", argv[1]);
        usage(stderr);
        return EXIT_USAGE;
}

const struct imp_command imp_cmd_import = {
        .name = "import",
        .summary = "turn captures from other rigs (RTI/photometric stacks, Gray-code sequences) into capture sets",
        .run = run,
};
