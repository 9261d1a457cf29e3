/* `impasto compare COPY_DIR --truth TRUTH_DIR [--json]`: accuracy of a digital copy
 * against the simulator's ground truth (pipeline/compare.h says how each figure is made). */
#include <getopt.h>
#include <stdio.h>
#include <string.h>
#include "commands.h"
#include "compare.h"
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
        struct imp_compare_result res;
        int r = imp_compare_dirs(argv[optind], truth, &res, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return 3;
        }
        if (as_json) {
                _cleanup_json_ json_t *j = imp_compare_result_to_json(&res);
                char *s = json_dumps(j, JSON_COMPACT);
                printf("%s\n", s);
                free(s);
                return 0;
        }
        printf("height rmse        %8.2f µm   (offset %.4f mm removed, max |err| %.1f µm)\n",
               res.height_rmse_um, res.height_offset_mm, res.height_max_abs_um);
        printf("normal error mean  %8.3f °\n", res.normal_err_deg_mean);
        printf("canvas mask IoU    %8.4f\n", res.mask_iou);
        printf("NaN/Inf samples    %8zu\n", res.nan_count);
        printf("texels compared    %8zu\n", res.n_compared);
        return 0;
}

const struct imp_command imp_cmd_compare = {
        .name = "compare",
        .summary = "accuracy of a digital copy against simulator truth",
        .run = run,
};
