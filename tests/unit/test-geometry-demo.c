/* Geometry accuracy on simulated scenes (issue #4 acceptance), end to end through the
 * `impasto` binary: sim render → process --no-btf → compare --json, plus a check that the
 * relief boxes cover every significant texel.
 *
 *   test-geometry-demo small   tests/data/geometry-small.cfg (15 × 10 mm, ~15 s)
 *   test-geometry-demo demo    config/scenes/demo.cfg + config/plans/demo.cfg (~3 min)
 *
 * Asserted: height RMSE ≤ 9 µm, no NaN/Inf, every 8-connected component of texels above
 * the bump plane that the classifier keeps (≥ min_component_px) lies inside boxes, each
 * box's hmax is its cell's highest texel. Mask IoU and normal error are asserted against
 * the floors the pipeline reaches today (docs/geometry.md: IoU ≥ 0.99 is out of reach
 * because of the projector's shadow strip beside the frame; ≤ 2° needs the dome's
 * photometric normals, which this --no-btf run does not compute); the targets
 * are printed as ACCEPTANCE lines so a run shows how far they are. */
#include <fcntl.h>
#include <spawn.h>
#include <unistd.h>
#include <sys/wait.h>
#include <jansson.h>
#include "test.h"
#include "image.h"

extern char **environ;

static int run(char *const argv[], const char *out_path) {
        posix_spawn_file_actions_t fa;
        posix_spawn_file_actions_init(&fa);
        if (out_path)
                posix_spawn_file_actions_addopen(&fa, 1, out_path, O_WRONLY | O_CREAT | O_TRUNC, 0644);
        pid_t pid;
        int r = posix_spawn(&pid, argv[0], &fa, NULL, argv, environ);
        posix_spawn_file_actions_destroy(&fa);
        if (r != 0) {
                fprintf(stderr, "spawn %s: %s\n", argv[0], strerror(r));
                return -1;
        }
        int st;
        if (waitpid(pid, &st, 0) < 0)
                return -1;
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

/* Box coverage: every kept component above the bump plane is inside boxes. */
static void check_boxes(const char *copy) {
        char path[4096 + 32];
        struct imp_error err = {};
        snprintf(path, sizeof path, "%s/boxes.json", copy);
        json_error_t je;
        json_t *b = json_load_file(path, 0, &je);
        CHECK_MSG(b != NULL, "%s: %s", path, je.text);
        if (!b)
                return;
        snprintf(path, sizeof path, "%s/heightfield.exr", copy);
        struct imp_image *img = NULL;
        char **names = NULL;
        CHECK_OK(imp_exr_read(path, &img, &names, &err));
        if (!img) {
                json_decref(b);
                return;
        }
        int ch = imp_image_channel_index(names, "height"), cm = imp_image_channel_index(names, "mask");
        CHECK(ch >= 0 && cm >= 0);
        int nx = img->width, ny = img->height;
        CHECK_INT_EQ(json_integer_value(json_object_get(b, "nx")), nx);
        CHECK_INT_EQ(json_integer_value(json_object_get(b, "ny")), ny);
        double plane = json_real_value(json_object_get(b, "bump_plane"));
        size_t N = (size_t) nx * ny;
        uint8_t *boxed = calloc(N, 1), *sig = calloc(N, 1);
        int *comp = calloc(N, sizeof(int)), *stack = malloc(N * sizeof(int));
        json_t *boxes = json_object_get(b, "boxes"), *bx;
        size_t k, bad_hmax = 0;
        json_array_foreach(boxes, k, bx) {
                int u0 = json_integer_value(json_object_get(bx, "u0")), v0 = json_integer_value(json_object_get(bx, "v0"));
                int w = json_integer_value(json_object_get(bx, "w")), h = json_integer_value(json_object_get(bx, "h"));
                double hmax = json_real_value(json_object_get(bx, "hmax")), best = -INFINITY;
                for (int v = v0; v < v0 + h && v < ny; v++)
                        for (int u = u0; u < u0 + w && u < nx; u++) {
                                boxed[(size_t) v * nx + u] = 1;
                                const float *p = imp_image_f32(img, u, v);
                                if (p[cm] >= 0.5)
                                        best = fmax(best, p[ch]);
                        }
                bad_hmax += fabs(best - hmax) > 1e-6;
        }
        CHECK_INT_EQ(bad_hmax, 0);
        for (int v = 0; v < ny; v++)
                for (int u = 0; u < nx; u++) {
                        const float *p = imp_image_f32(img, u, v);
                        sig[(size_t) v * nx + u] = p[cm] >= 0.5 && p[ch] > plane;
                }
        /* 8-connected components of the texels above the plane; kept ones need boxes. */
        size_t uncovered = 0, n_kept = 0;
        int nc = 0;
        for (size_t s = 0; s < N; s++) {
                if (!sig[s] || comp[s])
                        continue;
                size_t size = 0, miss = 0, top = 0;
                comp[s] = ++nc;
                stack[top++] = (int) s;
                while (top) {
                        int i = stack[--top];
                        size++;
                        miss += !boxed[i];
                        int x = i % nx, y = i / nx;
                        for (int dy = -1; dy <= 1; dy++)
                                for (int dx = -1; dx <= 1; dx++) {
                                        int xx = x + dx, yy = y + dy;
                                        if (xx < 0 || yy < 0 || xx >= nx || yy >= ny)
                                                continue;
                                        size_t j = (size_t) yy * nx + xx;
                                        if (sig[j] && !comp[j]) {
                                                comp[j] = nc;
                                                stack[top++] = (int) j;
                                        }
                                }
                }
                if (size >= 8) {
                        n_kept += size;
                        uncovered += miss;
                }
        }
        fprintf(stderr, "boxes: %zu, texels above the bump plane in kept components %zu, uncovered %zu\n",
                json_array_size(boxes), n_kept, uncovered);
        CHECK_INT_EQ(uncovered, 0);
        CHECK(json_array_size(boxes) > 0);
        free(boxed), free(sig), free(comp), free(stack);
        imp_image_free(img);
        imp_strv_free(names);
        json_decref(b);
}

int main(int argc, char **argv) {
        bool demo = argc > 1 && !strcmp(argv[1], "demo");
        const char *tmp = test_tmpdir();
        char bin[4096], scene[4096], plan[4096], cap[4096], copy[4096], truth[4096], cmp[4096];
        snprintf(bin, sizeof bin, "%s/cli/impasto", IMPASTO_BINARY_DIR);
        if (demo) {
                snprintf(scene, sizeof scene, "%s/config/scenes/demo.cfg", IMPASTO_SOURCE_DIR);
                snprintf(plan, sizeof plan, "%s/config/plans/demo.cfg", IMPASTO_SOURCE_DIR);
        } else {
                snprintf(scene, sizeof scene, "%s/tests/data/geometry-small.cfg", IMPASTO_SOURCE_DIR);
                snprintf(plan, sizeof plan, "%s/tests/data/geometry-small-plan.cfg", IMPASTO_SOURCE_DIR);
        }
        snprintf(cap, sizeof cap, "%s/capture", tmp);
        snprintf(copy, sizeof copy, "%s/copy", tmp);
        snprintf(truth, sizeof truth, "%s/capture/truth", tmp);
        snprintf(cmp, sizeof cmp, "%s/compare.json", tmp);
        if (access(bin, X_OK) != 0)
                TEST_SKIP("%s not built", bin);

        char *render[] = { bin, "sim", "render", "--scene", scene, "--plan", plan, "--out", cap, NULL };
        CHECK_INT_EQ(run(render, "/dev/null"), 0);
        /* The full demo runs every stage as scripts/demo does (photometric normals, fusion,
         * shadow fill and the BTF with light 8 held out), so both issues' targets are checked;
         * the small scene checks geometry alone. */
        char *process_small[] = { bin, "process", cap, "--out", copy, "--no-btf", "--quiet", NULL };
        char *process_demo[] = { bin, "process", cap, "--out", copy, "--holdout", "8", "--quiet", NULL };
        char **process = demo ? process_demo : process_small;
        CHECK_INT_EQ(run(process, NULL), 0);
        char *compare[] = { bin, "compare", copy, "--truth", truth, "--json", NULL };
        CHECK_INT_EQ(run(compare, cmp), 0);

        json_error_t je;
        json_t *c = json_load_file(cmp, 0, &je);
        CHECK_MSG(c != NULL, "%s: %s", cmp, je.text);
        if (c) {
                double rmse = json_real_value(json_object_get(c, "height_rmse_um"));
                double nerr = json_real_value(json_object_get(c, "normal_err_deg_mean"));
                double iou = json_real_value(json_object_get(c, "mask_iou"));
                double iou_obs = json_real_value(json_object_get(c, "mask_iou_observable"));
                long long nan = json_integer_value(json_object_get(c, "nan_count"));
                long long n = json_integer_value(json_object_get(c, "n_compared"));
                fprintf(stderr, "%s: height rmse %.2f um, normal error %.2f deg, mask IoU %.4f, NaN %lld, compared %lld\n",
                        demo ? "demo" : "small", rmse, nerr, iou, nan, n);
                fprintf(stderr, "ACCEPTANCE height rmse <= 9 um: %s\n", rmse <= 9 ? "met" : "NOT MET");
                fprintf(stderr, "ACCEPTANCE normal error <= 2 deg: %s\n", nerr <= 2 ? "met" : "NOT MET");
                fprintf(stderr, "ACCEPTANCE mask IoU >= 0.99: %s (%.4f; over the measurable canvas %.4f)\n",
                        iou >= 0.99 ? "met" : "NOT MET", iou, iou_obs);
                CHECK_LE(rmse, 9.0);
                CHECK_INT_EQ(nan, 0);
                CHECK_GE(n, demo ? 800000 : 40000);
                /* Floors measured today (docs/geometry.md), to catch regressions. */
                CHECK_GE(iou, demo ? 0.96 : 0.90);
                /* Over the canvas one shot can measure (the frame's projector shadow
                 * excluded); with the shadow fill on, the filled strip counts against it. */
                CHECK_GE(iou_obs, demo ? 0.97 : 0.95);
                CHECK_LE(nerr, demo ? 9.5 : 8.0);
                if (demo) {
                        /* Issue #4 and #5 acceptance on the demo scene (true rig here; the
                         * estimated one is scripts/demo's). */
                        double rho = json_real_value(json_object_get(c, "rho_d_rel_err_median"));
                        double k = json_real_value(json_object_get(c, "lobe_k_rel_err_median"));
                        double rr = json_real_value(json_object_get(c, "rerender_rmse"));
                        fprintf(stderr, "demo appearance: rho_d %.4f, k %.4f, re-render %.4f\n", rho, k, rr);
                        CHECK_LE(nerr, 2.0);
                        CHECK_GE(iou, 0.99);
                        CHECK_LE(rho, 0.03);
                        CHECK_LE(k, 0.20);
                        CHECK(rr >= 0 && rr <= 0.02);
                        CHECK_INT_EQ(json_integer_value(json_object_get(c, "appearance_nan_count")), 0);
                }
                json_decref(c);
        }
        check_boxes(copy);
        if (!getenv("IMPASTO_KEEP_TEST_OUTPUT")) {
                char *rm[] = { "/bin/rm", "-rf", (char *) tmp, NULL };
                run(rm, NULL);
        } else
                fprintf(stderr, "output kept in %s\n", tmp);
        return TEST_DONE();
}
