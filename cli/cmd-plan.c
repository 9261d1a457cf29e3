/* `impasto plan validate|estimate PLAN`: check a scan plan against a rig and say what it
 * will cost (frames, bytes, capture time) — offline, from a rig file, or with --daemon from
 * impastod (plan.validate / plan.estimate of proto/PROTOCOL.md) against the daemon's rig.
 *   impasto plan validate PLAN (--rig RIG.json | --scene SCENE.cfg | --daemon) [--json]
 *   impasto plan estimate PLAN (--rig RIG.json | --scene SCENE.cfg | --daemon) [--json]
 * Errors name FILE:LINE: FIELD and exit 3. Offline --json prints the same result object
 * the daemon would send, plus, for a plan with an entry in presets.json beside it (written
 * by `impasto bench accuracy`, keyed by the plan's file name without .cfg), the measured
 * "expected_accuracy". */
#include <getopt.h>
#include <libgen.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "client.h"
#include "commands.h"
#include "json-util.h"
#include "log.h"
#include "plan.h"
#include "rig.h"
#include "scene.h"

#define FRAME_BYTES_PER_PIXEL 2   /* frames are stored as 16-bit TIFF (docs/capture-set.md) */

static void usage(FILE *f) {
        fprintf(f, "usage: impasto plan validate PLAN (--rig RIG.json | --scene SCENE.cfg | --daemon) [--json] [--socket PATH]\n"
                   "       impasto plan estimate PLAN (--rig RIG.json | --scene SCENE.cfg | --daemon) [--json] [--socket PATH]\n"
                   "  --rig RIG.json  the rig's model (rig.json of a capture set or of `impasto calibrate`)\n");
}

/* A step is one exposure of the rig: consecutive frames that differ only by camera. */
static bool same_step(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return a->tile == b->tile && a->light == b->light && a->exposure_index == b->exposure_index &&
               a->exposure_us == b->exposure_us && !strcmp(a->step, b->step) &&
               a->pattern.kind == b->pattern.kind && a->pattern.axis == b->pattern.axis &&
               a->pattern.bit == b->pattern.bit && a->pattern.step == b->pattern.step &&
               a->pattern.inverse == b->pattern.inverse && strcmp(a->camera, b->camera);
}

static json_t *offline_result(const struct imp_plan *plan, const struct imp_rig *rig, bool estimate) {
        size_t n = imp_plan_count(plan), steps = 0;
        double bytes = 0;
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *f = imp_plan_frame(plan, i);
                if (i == 0 || !same_step(imp_plan_frame(plan, i - 1), f))
                        steps++;
                for (int c = 0; c < rig->n_cameras; c++)
                        if (!strcmp(rig->cameras[c].name, f->camera))
                                bytes += (double) rig->cameras[c].model.width * rig->cameras[c].model.height *
                                         FRAME_BYTES_PER_PIXEL;
        }
        if (!estimate)
                return json_pack("{s:b,s:I,s:I}", "valid", 1, "steps", (json_int_t) steps, "frames", (json_int_t) n);
        return json_pack("{s:I,s:I,s:I,s:f}", "steps", (json_int_t) steps, "frames", (json_int_t) n, "bytes",
                         (json_int_t) bytes, "duration_s", imp_plan_estimate_s(plan, rig));
}

static void human_validate(const json_t *r) {
        printf("plan is valid: %lld frames in %lld steps\n", imp_client_int(r, "frames"), imp_client_int(r, "steps"));
}

static void human_estimate(const json_t *r) {
        char b[32], d[32];
        double t = imp_client_num(r, "duration_s");
        printf("frames        %lld\nsteps         %lld\nbytes         %lld (%s)\ncapture time  %.1f s",
               imp_client_int(r, "frames"), imp_client_int(r, "steps"), imp_client_int(r, "bytes"),
               imp_client_fmt_bytes((double) imp_client_int(r, "bytes"), b, sizeof b), t);
        if (t >= 60)
                printf(" (%s)", imp_client_fmt_duration(t, d, sizeof d));
        putchar('\n');
        const json_t *acc = json_object_get(r, "expected_accuracy");
        json_t *cpu = json_object_get(acc, "processing_cpu_s");
        if (json_is_number(cpu))
                printf("processing    %.1f s CPU as measured on %s (impasto bench accuracy)\n",
                       json_number_value(cpu), json_string_value(json_object_get(acc, "scene")) ?: "the study scene");
        else
                printf("processing    not measured for this plan (impasto bench accuracy measures the presets)\n");
        if (acc) {
                json_t *k = json_object_get(acc, "lobe_k_rel_err_median");
                printf("expected accuracy  height RMSE %.1f µm, normal error %.1f°, ρd median rel. error %.3f",
                       imp_client_num(acc, "height_rmse_um"), imp_client_num(acc, "normal_err_deg_mean"),
                       imp_client_num(acc, "rho_d_rel_err_median"));
                if (json_is_number(k) && json_number_value(k) >= 0)
                        printf(", lobe k %.2f", json_number_value(k));
                printf(" (measured on %s by impasto bench accuracy)\n",
                       json_string_value(json_object_get(acc, "scene")) ?: "the study scene");
        }
}

/* The measured accuracy of a preset: PLAN_DIR/presets.json["NAME"] for PLAN_DIR/NAME.cfg,
 * or NULL when there is none. */
static json_t *expected_accuracy(const char *plan_path) {
        char dir[PATH_MAX], base[PATH_MAX], path[PATH_MAX + 16];
        snprintf(dir, sizeof dir, "%s", plan_path);
        snprintf(base, sizeof base, "%s", plan_path);
        const char *name = basename(base);
        size_t len = strlen(name);
        if (len < 5 || strcmp(name + len - 4, ".cfg"))
                return NULL;
        if (snprintf(path, sizeof path, "%s/presets.json", dirname(dir)) >= (int) sizeof path)
                return NULL;
        struct imp_error err = {};
        _cleanup_json_ json_t *all = NULL;
        if (access(path, F_OK) < 0 || imp_json_load(path, &all, &err) < 0)
                return NULL;
        char key[PATH_MAX];
        snprintf(key, sizeof key, "%.*s", (int) (len - 4), name);
        json_t *e = json_object_get(all, key);
        return json_is_object(e) ? json_incref(e) : NULL;
}

static int load_rig(const char *rig_path, const char *scene_path, struct imp_rig *ret) {
        struct imp_error err = {};
        int r;
        if (rig_path)
                r = imp_rig_load(rig_path, ret, &err);
        else {
                _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
                r = imp_scene_load(scene_path, &scene, &err);
                if (r >= 0)
                        r = imp_rig_copy(imp_scene_rig(scene), ret);
        }
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                if (rig_path && strstr(rig_path, ".cfg"))
                        log_error("--rig wants the rig's model, rig.json (as in a capture set or written by "
                                  "`impasto calibrate`), not the rig config %s; --scene takes a scene's rig", rig_path);
                return IMP_EXIT_BAD_INPUT;
        }
        return 0;
}

static int offline(const char *plan_path, const char *rig_path, const char *scene_path, bool estimate, bool json) {
        struct imp_rig rig = {};
        int rc = load_rig(rig_path, scene_path, &rig);
        if (rc)
                return rc;
        struct imp_error err = {};
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        int r = imp_plan_load(plan_path, &rig, &plan, &err);
        if (r < 0) {
                imp_rig_free(&rig);
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return r == -ENOMEM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
        }
        _cleanup_json_ json_t *res = offline_result(plan, &rig, estimate);
        imp_rig_free(&rig);
        if (!res)
                return log_error("out of memory"), IMP_EXIT_FAILURE;
        json_t *acc = estimate ? expected_accuracy(plan_path) : NULL;
        if (acc)
                json_object_set_new(res, "expected_accuracy", acc);
        if (json) {
                _cleanup_free_ char *s = json_dumps(res, JSON_COMPACT | JSON_PRESERVE_ORDER);
                puts(s ? s : "{}");
        } else if (estimate)
                human_estimate(res);
        else
                human_validate(res);
        return fflush(stdout) == 0 ? 0 : IMP_EXIT_FAILURE;
}

static int run(int argc, char **argv) {
        struct imp_client_opts o = {};
        const char *rig = NULL, *scene = NULL;
        bool daemon = false;
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' },      { "socket", required_argument, NULL, 'S' },
                { "rig", required_argument, NULL, 'r' }, { "scene", required_argument, NULL, 's' },
                { "daemon", no_argument, NULL, 'd' },    { "help", no_argument, NULL, 'h' }, {} };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'r': rig = optarg; break;
                case 's': scene = optarg; break;
                case 'd': daemon = true; break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        if (argc - optind != 2 || (strcmp(argv[optind], "validate") && strcmp(argv[optind], "estimate"))) {
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        bool estimate = !strcmp(argv[optind], "estimate");
        const char *plan = argv[optind + 1];
        if ((rig != NULL) + (scene != NULL) + daemon != 1) {
                log_error("plan %s: name the rig: exactly one of --rig RIG.json, --scene SCENE.cfg, --daemon",
                          argv[optind]);
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        if (!daemon)
                return offline(plan, rig, scene, estimate, o.json);
        char abs[PATH_MAX];
        if (realpath(plan, abs))   /* the daemon opens the plan itself */
                plan = abs;
        return imp_client_simple(&o, estimate ? "plan.estimate" : "plan.validate", json_pack("{s:s}", "plan", plan),
                                 estimate ? human_estimate : human_validate);
}

const struct imp_command imp_cmd_plan = {
        .name = "plan",
        .summary = "validate a scan plan and estimate its frames, bytes and capture time",
        .run = run,
};
