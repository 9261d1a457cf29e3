/* `impasto compare COPY_DIR --truth TRUTH_DIR [--json]`: accuracy of a digital copy
 * against the simulator's ground truth (pipeline/eval/compare.h and compare-appearance.h say how
 * each figure is made). Appearance figures only when the copy has rho_d.exr; nan_count is
 * then over every EXR of the copy. */
#include <errno.h>
#include <getopt.h>
#include <sys/stat.h>
#include <stdio.h>
#include <string.h>
#include "commands.h"
#include "compare.h"
#include "compare-appearance.h"
#include "json-util.h"
#include "log.h"

static int run(int argc, char **argv) {
        const char *truth = NULL;
        bool as_json = false;
        static const struct option longopts[] = {
                { "truth", required_argument, NULL, 't' }, { "json", no_argument, NULL, 'j' },
                { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        while ((c = getopt_long(argc, argv, "t:jh", longopts, NULL)) >= 0)
                switch (c) {
                case 't': truth = optarg; break;
                case 'j': as_json = true; break;
                case 'h': printf("usage: impasto compare COPY_DIR --truth TRUTH_DIR [--json]\n"); return 0;
                default: return 2;
                }
        if (optind + 1 != argc || !truth) {
                fprintf(stderr, "usage: impasto compare COPY_DIR --truth TRUTH_DIR [--json]\n");
                return 2;
        }
        struct imp_error err = {};
        struct imp_compare_result res = {};
        int r = imp_compare_dirs(argv[optind], truth, &res, &err);
        char not_compared[sizeof err.msg] = "";
        if (r == -ENODATA) {   /* no texel over the truth canvas: the rest is still reported */
                log_warning("%s", err.msg);
                snprintf(not_compared, sizeof not_compared, "%s", err.msg);
        } else if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return 3;
        }
        char path[4096];
        struct stat st;
        snprintf(path, sizeof path, "%s/rho_d.exr", argv[optind]);
        bool has_app = stat(path, &st) == 0;
        struct imp_compare_appearance app = {};
        if (has_app) {
                r = imp_compare_appearance(argv[optind], truth, &app, &err);
                if (r == -ENODATA) {   /* e.g. truth ρd below 0.05 everywhere: report the rest */
                        log_warning("appearance not compared: %s", err.msg);
                        has_app = false;
                } else if (r < 0) {
                        log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                        return 3;
                } else
                        res.nan_count += app.nan_count;
        }
        if (as_json) {
                _cleanup_json_ json_t *j = imp_compare_result_to_json(&res);
                if (has_app)
                        imp_compare_appearance_to_json(&app, j);
                if (not_compared[0])
                        json_object_set_new(j, "not_compared", json_string(not_compared));
                char *s = json_dumps(j, JSON_COMPACT);
                printf("%s\n", s);
                free(s);
                return 0;
        }
        if (not_compared[0])
                printf("not compared: %s\n", not_compared);
        printf("height rmse        %8.2f µm   (offset %.4f mm removed, max |err| %.1f µm)\n",
               res.height_rmse_um, res.height_offset_mm, res.height_max_abs_um);
        printf("normal error mean  %8.3f °   (%.3f ° against truth band-limited to the copy pitch)\n", res.normal_err_deg_mean, res.normal_err_deg_mean_bandlimited);
        printf("canvas mask IoU    %8.4f   (%.4f over the canvas the rig can measure)\n", res.mask_iou, res.mask_iou_observable);
        printf("NaN/Inf samples    %8zu\n", res.nan_count);
        printf("texels compared    %8zu\n", res.n_compared);
        printf("placement          %8.2f °   (copy canvas normal to the truth's)\n", res.placement_deg);
        printf("frame as canvas    %8.4f     (fraction of the copy's canvas texels)\n", res.frame_texel_fraction);
        printf("flagged            %8.4f     (fraction of the compared texels)\n", res.flagged_fraction);
        if (!res.n_unflagged)
                printf("beyond 3σ          not measured (every compared texel is flagged)\n");
        else {
                printf("beyond 3σ          %8.4f height, %.4f normal (unflagged texels, %zu)\n",
                       res.beyond_3sigma_height, res.beyond_3sigma_normal, res.n_unflagged);
                printf("unflagged normals  %8.2f ° max, %zu over 10°\n", res.unflagged_normal_err_deg_max,
                       res.unflagged_normal_over_10deg);
        }
        if (!has_app)
                return 0;
        printf("rho_d rel. error   %8.4f     median (90th pct %.4f) over %zu texel-channels\n",
               app.rho_d_rel_err_median, app.rho_d_rel_err_p90, app.rho_d_samples);
        if (app.lobe_texels)
                printf("lobe k rel. error  %8.4f     median (90th pct %.4f) over %zu glossy texels, %zu flagged\n"
                       "rho_s rel. error   %8.4f     median, peak specular albedo\n",
                       app.lobe_k_rel_err_median, app.lobe_k_rel_err_p90, app.lobe_texels, app.lobe_flagged,
                       app.rho_s_rel_err_median);
        else
                printf("lobe k rel. error       n/a     (no unflagged glossy texel; %zu flagged)\n", app.lobe_flagged);
        if (app.rerender_rmse >= 0)
                printf("re-render rmse     %8.4f     V/E, white units, %zu held-out lights, %zu samples\n",
                       app.rerender_rmse, app.rerender_lights, app.rerender_texels);
        else
                printf("re-render rmse          n/a     (no held-out lights: impasto process --holdout N)\n");
        return 0;
}

const struct imp_command imp_cmd_compare = {
        .name = "compare",
        .summary = "accuracy of a digital copy against simulator truth",
        .run = run,
};
