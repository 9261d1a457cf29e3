/* `impasto compare-normals COPY --truth-normals FILE [--mask MASK.png] [--json]`: the angular
 * error of a copy's normals (or of any normal map) against reference normals on the same
 * pixel grid (pipeline/eval/compare-normals.h; conventions in docs/import.md). */
#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <string.h>
#include "commands.h"
#include "compare-normals.h"
#include "log.h"

#define EXIT_USAGE 2
#define EXIT_BADINPUT 3

static void usage(FILE *f) {
        fprintf(f, "usage: impasto compare-normals COPY --truth-normals FILE [--mask MASK.png] [--json]\n"
                   "  COPY           a copy directory (its heightfield.exr: nx, ny, nz on the pixel grid,\n"
                   "                 as `impasto process --photometric-only` writes it) or a normal map\n"
                   "  --truth-normals FILE  reference normals: 3-channel float EXR/TIFF, or 16-bit PNG/TIFF\n"
                   "                 storing (n + 1) / 2; x right, y up, z towards the camera\n"
                   "  --mask MASK.png  only pixels with a non-zero mask value are compared\n"
                   "  prints normal_err_deg_mean, normal_err_deg_median, normal_err_deg_rms,\n"
                   "  normal_err_deg_p90, n, within_10deg, within_20deg (fractions of n)\n");
}

static int run(int argc, char **argv) {
        const char *truth_path = NULL, *mask_path = NULL;
        bool json = false;
        static const struct option longopts[] = {
                { "truth-normals", required_argument, NULL, 't' }, { "mask", required_argument, NULL, 'm' },
                { "json", no_argument, NULL, 'j' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        optind = 1;
        while ((c = getopt_long(argc, argv, "h", longopts, NULL)) >= 0)
                switch (c) {
                case 't': truth_path = optarg; break;
                case 'm': mask_path = optarg; break;
                case 'j': json = true; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return EXIT_USAGE;
                }
        if (optind + 1 != argc || !truth_path) {
                usage(stderr);
                return EXIT_USAGE;
        }
        struct imp_error err = {};
        _cleanup_image_ struct imp_image *est = NULL, *truth = NULL, *mask = NULL;
        int r = imp_normals_read(argv[optind], &est, &err);
        if (r >= 0)
                r = imp_normals_read(truth_path, &truth, &err);
        if (r >= 0 && mask_path)
                r = imp_image_read(mask_path, &mask, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return EXIT_BADINPUT;
        }
        if (est->width != truth->width || est->height != truth->height ||
            (mask && (mask->width != est->width || mask->height != est->height))) {
                log_error("%s is %dx%d, %s %dx%d%s: the maps must share one pixel grid", argv[optind], est->width,
                          est->height, truth_path, truth->width, truth->height, mask ? " (and the mask)" : "");
                return EXIT_BADINPUT;
        }
        struct imp_normals_cmp s;
        r = imp_normals_compare(est, truth, mask, &s);
        if (r == -ENODATA) {
                log_error("%s vs %s: no pixel with both normals inside the mask", argv[optind], truth_path);
                return EXIT_BADINPUT;
        }
        if (r < 0) {
                log_error("compare-normals: %s", strerror(-r));
                return 1;
        }
        if (json)
                printf("{\"normal_err_deg_mean\": %.4f, \"normal_err_deg_median\": %.4f, \"normal_err_deg_rms\": %.4f, "
                       "\"normal_err_deg_p90\": %.4f, \"n\": %ld, \"within_10deg\": %.5f, \"within_20deg\": %.5f}\n",
                       s.mean_deg, s.median_deg, s.rms_deg, s.p90_deg, s.n, s.within_10deg, s.within_20deg);
        else
                printf("normals: mean %.3f°, median %.3f°, rms %.3f°, p90 %.3f° over %ld pixels; %.1f %% within 10°, "
                       "%.1f %% within 20°\n", s.mean_deg, s.median_deg, s.rms_deg, s.p90_deg, s.n,
                       100 * s.within_10deg, 100 * s.within_20deg);
        return 0;
}

const struct imp_command imp_cmd_compare_normals = {
        .name = "compare-normals",
        .summary = "angular error of a copy's normals against reference normals (pixel grid)",
        .run = run,
};
