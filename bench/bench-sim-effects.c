/* Simulator cost per effect: the demo scene (or --scene FILE) rendered with `direct` alone
 * and with each other effect alone on top of it; four frames each (two dome lights, a Gray
 * code and a phase pattern). Prints view-map time, ms per frame and the counters.
 *   bench-sim-effects [--scene FILE] [--threads N] */
#include <stdio.h>
#include <string.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "render.h"
#include "scene.h"

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

int main(int argc, char **argv) {
        const char *path = IMPASTO_SOURCE_DIR "/config/scenes/demo.cfg";
        for (int i = 1; i + 1 < argc; i += 2) {
                if (!strcmp(argv[i], "--scene"))
                        path = argv[i + 1];
#ifdef _OPENMP
                else if (!strcmp(argv[i], "--threads"))
                        omp_set_num_threads(atoi(argv[i + 1]));
#endif
        }
        struct imp_error err = { 0 };
        struct imp_scene *scene = NULL;
        double t0 = now_s();
        if (imp_scene_load(path, &scene, &err) < 0) {
                fprintf(stderr, "%s\n", err.msg);
                return 3;
        }
        printf("scene %s loaded in %.2f s\n", path, now_s() - t0);
        const struct imp_rig *rig = imp_scene_rig(scene);
        struct imp_frame_record frames[4] = {
                { .seq = 0, .step = "dome", .light = rig->n_lights > 3 ? rig->lights[3].id : -1, .exposure_us = 10000 },
                { .seq = 1, .step = "structured-light", .light = -1, .exposure_us = 10000,
                  .pattern = { .kind = IMP_PAT_GRAY, .bit = 5, .nbits = 10 } },
                { .seq = 2, .step = "dome", .light = rig->n_lights > 20 ? rig->lights[20].id : -1, .exposure_us = 10000 },
                { .seq = 3, .step = "structured-light", .light = -1, .exposure_us = 10000,
                  .pattern = { .kind = IMP_PAT_PHASE, .period_px = 16, .step = 1, .steps = 4 } },
        };
        for (int f = 0; f < 4; f++)
                snprintf(frames[f].camera, sizeof frames[f].camera, "%s", rig->cameras[0].name);
        bool listed[IMP_FX_COUNT];
        for (int i = 0; i < IMP_FX_COUNT; i++)
                listed[i] = imp_scene_has_effect(scene, i);
        printf("%-14s %9s %9s %12s %12s %12s %12s %12s %12s %12s\n", "effect", "view_s", "ms/frame", "shading",
               "shadow_rays", "shadow_steps", "grid_vert", "random", "proj_look", "taps");
        for (int fx = -1; fx < IMP_FX_COUNT; fx++) {
                if (fx == IMP_FX_DIRECT || (fx == IMP_FX_PROJECTOR && !rig->has_projector))
                        continue;
                for (int i = 0; i < IMP_FX_COUNT; i++)
                        imp_scene_set_effect(scene, i, i == IMP_FX_DIRECT || i == fx);
                struct imp_render *r = NULL;
                double t1 = now_s();
                if (imp_render_new(scene, &r, &err) < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        return 1;
                }
                double tv = now_s() - t1;
                t1 = now_s();
                int n = 0;
                for (int f = 0; f < 4; f++) {
                        struct imp_image *img = NULL;
                        if (imp_render_frame(r, &frames[f], &img, &err) == 0)
                                n++;
                        imp_image_free(img);
                }
                double ms = n ? (now_s() - t1) * 1e3 / n : 0;
                const struct imp_sim_counters *c = imp_render_counters(r);
                printf("%-14s %9.2f %9.1f %12llu %12llu %12llu %12llu %12llu %12llu %12llu\n",
                       fx < 0 ? "direct" : imp_sim_effect_name(fx), tv, ms, (unsigned long long) c->shading_evals,
                       (unsigned long long) c->shadow_rays, (unsigned long long) c->shadow_steps,
                       (unsigned long long) c->grid_vertices, (unsigned long long) c->random_draws,
                       (unsigned long long) c->projector_lookups, (unsigned long long) c->defocus_taps);
                fflush(stdout);
                imp_render_free(r);
        }
        for (int i = 0; i < IMP_FX_COUNT; i++)
                imp_scene_set_effect(scene, i, listed[i]);
        imp_scene_free(scene);
        return 0;
}
