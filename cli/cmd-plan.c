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
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/statvfs.h>
#include <unistd.h>
#include "client.h"
#include "commands.h"
#include "help.h"
#include "json-util.h"
#include "log.h"
#include "numparse.h"
#include "plan.h"
#include "rig.h"
#include "scene.h"

#define FRAME_BYTES_PER_PIXEL 2   /* frames are stored as 16-bit TIFF (docs/capture-set.md) */
/* With --scene of a gantry scene, the moves default to the scene's gantry (sim/scene.h): its
 * speed, and its settle plus speed/acceleration, what the trapezoidal profile adds to a move
 * longer than speed²/acceleration (sim/gantry.c), so that the estimate follows the simulator. */

/* How the whole-painting figures are played through (options of `plan estimate`). */
struct painting_opts {
        struct imp_plan_painting_opts est;
        unsigned given;                           /* 1 --workers, 2 --stage-speed, 4 --settle, 8 --process-s */
        const char *target;                       /* directory whose free space must hold the plan */
};

static void usage(FILE *f) {
        fprintf(f, "usage: impasto plan validate PLAN (--rig RIG.json | --scene SCENE.cfg | --daemon) [--json] [--socket PATH]\n"
                   "       impasto plan estimate PLAN (--rig RIG.json | --scene SCENE.cfg | --daemon) [--json] [--socket PATH]\n"
                   "                     [--target DIR] [--workers N] [--stage-speed MM_S] [--settle S] [--process-s S]\n"
                   "  --rig RIG.json  the rig's model (rig.json of a capture set or of `impasto calibrate`)\n"
                   "         --target DIR: refuse a plan whose bytes exceed DIR's free space (default .)\n"
                   "         a plan with a painting group: whole-painting figures; --workers tiles processed at once,\n"
                   "         --stage-speed and --settle the gantry's moves (default: a --scene's gantry, else 50 mm/s\n"
                   "         and 0.5 s), --process-s one tile's processing\n");
}

/* A step is one exposure of the rig: consecutive frames that differ only by camera. */
static bool same_step(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return a->tile == b->tile && a->light == b->light && a->exposure_index == b->exposure_index &&
               a->exposure_us == b->exposure_us && !strcmp(a->step, b->step) &&
               a->pattern.kind == b->pattern.kind && a->pattern.axis == b->pattern.axis &&
               a->pattern.bit == b->pattern.bit && a->pattern.step == b->pattern.step &&
               a->pattern.inverse == b->pattern.inverse && strcmp(a->camera, b->camera);
}

static json_t *offline_result(const struct imp_plan *plan, const struct imp_rig *rig, bool estimate,
                              const struct painting_opts *po) {
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
        json_t *res = json_pack("{s:I,s:I,s:I,s:f}", "steps", (json_int_t) steps, "frames", (json_int_t) n, "bytes",
                                (json_int_t) bytes, "duration_s", imp_plan_estimate_s(plan, rig));
        if (res && imp_plan_tiles(plan))
                json_object_set_new(res, "painting", imp_plan_painting_estimate_json(plan, rig, bytes, &po->est));
        return res;
}

static void human_painting(const json_t *p) {
        char b[32], d[4][32];
        printf("painting      %lld tiles (%lld × %lld, overlap %.0f %% × %.0f %%, edge margin %.2f mm)\n"
               "  frames      %lld\n  bytes       %s\n  capture     %s (moves %s)\n"
               "  processing  %s on %lld worker(s), done %s after the first frame\n",
               imp_client_int(p, "tiles"), imp_client_int(p, "cols"), imp_client_int(p, "rows"),
               100 * json_number_value(json_array_get(json_object_get(p, "overlap"), 0)),
               100 * json_number_value(json_array_get(json_object_get(p, "overlap"), 1)),
               json_number_value(json_object_get(p, "edge_margin_mm")), imp_client_int(p, "frames"),
               imp_client_fmt_bytes(imp_client_num(p, "bytes"), b, sizeof b),
               imp_client_fmt_duration(imp_client_num(p, "capture_s"), d[0], sizeof d[0]),
               imp_client_fmt_duration(imp_client_num(p, "move_s"), d[1], sizeof d[1]),
               imp_client_fmt_duration(imp_client_num(p, "process_s"), d[2], sizeof d[2]),
               imp_client_int(p, "workers"), imp_client_fmt_duration(imp_client_num(p, "wall_s"), d[3], sizeof d[3]));
        if (!(json_number_value(json_object_get(p, "edge_margin_mm")) > 0))
                printf("  note        no edge margin: a copy stops ~0.15 mm inside its field and the stage lands within "
                       "its repeatability, so the painting's border will not be covered (docs/painting.md, \"The edge "
                       "margin\")\n");
}

/* Refuses a plan whose bytes (the whole painting's when it has one) exceed the free space of
 * the directory it will be written to. */
static int check_disk(const json_t *res, const char *dir) {
        const json_t *p = json_object_get(res, "painting");
        double need = p ? imp_client_num(p, "bytes") : (double) imp_client_int(res, "bytes");
        struct statvfs st;
        if (statvfs(dir, &st) < 0)
                return log_error_errno(-errno, "plan estimate: --target %s: %m", dir), IMP_EXIT_BAD_INPUT;
        double avail = (double) st.f_bavail * (double) st.f_frsize;
        if (need <= avail)
                return 0;
        char a[32], b[32];
        log_error("plan estimate: the plan needs %s on disk but %s has %s free; choose a smaller plan or another disk",
                  imp_client_fmt_bytes(need, a, sizeof a), dir, imp_client_fmt_bytes(avail, b, sizeof b));
        return IMP_EXIT_BAD_INPUT;
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
        printf("%s\n", json_object_get(r, "painting") ? " per tile" : "");
        if (json_object_get(r, "painting"))
                human_painting(json_object_get(r, "painting"));
        const json_t *acc = json_object_get(r, "expected_accuracy"), *other = json_object_get(r, "accuracy_not_measured");
        json_t *cpu = json_object_get(acc, "processing_cpu_s");
        if (json_is_object(other)) {
                const json_t *m = json_object_get(other, "measured");
                const char *scene = json_string_value(json_object_get(m, "scene")) ?: "the study scene";
                printf("processing    not measured for this rig (%.1f s CPU on %s with %lld frames)\n",
                       imp_client_num(m, "processing_cpu_s"), scene, imp_client_int(m, "frames"));
                printf("expected accuracy  not measured for %lld lights of a %lld-light dome (%lld frames): the "
                       "preset's figures (height RMSE %.1f µm, normal error %.1f°) were measured on %s",
                       imp_client_int(other, "lights"), imp_client_int(other, "dome_lights"),
                       imp_client_int(other, "frames"), imp_client_num(m, "height_rmse_um"),
                       imp_client_num(m, "normal_err_deg_mean"), scene);
                if (json_is_integer(json_object_get(m, "dome_lights")))
                        printf("'s %lld-light dome", imp_client_int(m, "dome_lights"));
                printf(" with %lld frames; impasto bench accuracy measures them on this rig's scene\n",
                       imp_client_int(m, "frames"));
                return;
        }
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

/* The preset's figures hold for the configuration they were measured with: on a rig where the
 * plan expands to other frames (another light count, another projector) they are not
 * promised but shown as "accuracy_not_measured" with this rig's frames and lights. */
/* The dome size of the rig a preset was measured on: PLAN_DIR/../scenes/SCENE.cfg's rig, or -1. */
static int measured_dome(const char *plan_path, const json_t *acc) {
        const char *scene = json_string_value(json_object_get(acc, "scene"));
        char dir[PATH_MAX], path[PATH_MAX + 300];
        snprintf(dir, sizeof dir, "%s", plan_path);
        if (!scene || strchr(scene, '/') ||
            snprintf(path, sizeof path, "%s/../scenes/%.200s.cfg", dirname(dir), scene) >= (int) sizeof path)
                return -1;
        _cleanup_(imp_scene_freep) struct imp_scene *sc = NULL;
        struct imp_error err = {};
        return imp_scene_load(path, &sc, &err) < 0 ? -1 : imp_scene_rig(sc)->n_lights;
}

static void set_accuracy(json_t *res, const char *plan_path, const struct imp_plan *plan, const struct imp_rig *rig,
                         json_t *acc) {
        size_t n = imp_plan_count(plan), lights = 0;
        int max = -1;
        for (size_t i = 0; i < n; i++)
                max = IMP_MAX(max, imp_plan_frame(plan, i)->light);
        _cleanup_free_ bool *seen = calloc((size_t) max + 2, sizeof *seen);
        for (size_t i = 0; seen && i < n; i++) {
                int l = imp_plan_frame(plan, i)->light;
                if (l >= 0 && !seen[l]) {
                        seen[l] = true;
                        lights++;
                }
        }
        json_t *measured = json_object_get(acc, "frames");
        int dome = measured_dome(plan_path, acc);
        if ((!json_is_integer(measured) || (size_t) json_integer_value(measured) == n) &&
            (dome < 0 || dome == rig->n_lights)) {
                json_object_set_new(res, "expected_accuracy", acc);
                return;
        }
        if (dome >= 0)
                json_object_set_new(acc, "dome_lights", json_integer(dome));
        json_object_set_new(res, "expected_accuracy", json_null());
        json_object_set_new(res, "accuracy_not_measured", json_pack("{s:I, s:I, s:i, s:o}", "frames", (json_int_t) n,
                                                                    "lights", (json_int_t) lights, "dome_lights",
                                                                    rig->n_lights, "measured", acc));
}

static void gantry_defaults(const struct imp_scene_gantry *g, struct painting_opts *po) {
        if (!g || g->speed_mm_s <= 0 || g->accel_mm_s2 <= 0)
                return;
        if (!(po->given & 2))
                po->est.speed_mm_s = g->speed_mm_s;
        if (!(po->given & 4))
                po->est.settle_s = g->settle_s + po->est.speed_mm_s / g->accel_mm_s2;
}

/* The rig from --rig or --scene; a gantry scene's moves fill the options not given. */
static int load_rig(const char *rig_path, const char *scene_path, struct imp_rig *ret, struct painting_opts *po) {
        struct imp_error err = {};
        int r;
        if (rig_path)
                r = imp_rig_load(rig_path, ret, &err);
        else {
                _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
                r = imp_scene_load(scene_path, &scene, &err);
                if (r >= 0)
                        r = imp_rig_copy(imp_scene_rig(scene), ret);
                if (r >= 0 && imp_scene_is_gantry(scene))
                        gantry_defaults(imp_scene_gantry(scene), po);
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

static int offline(const char *plan_path, const char *rig_path, const char *scene_path, bool estimate, bool json,
                   struct painting_opts *po) {
        struct imp_rig rig = {};
        int rc = load_rig(rig_path, scene_path, &rig, po);
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
        _cleanup_json_ json_t *res = offline_result(plan, &rig, estimate, po);
        json_t *acc = res && estimate ? expected_accuracy(plan_path) : NULL;
        if (acc)
                set_accuracy(res, plan_path, plan, &rig, acc);
        imp_rig_free(&rig);
        if (!res)
                return log_error("out of memory"), IMP_EXIT_FAILURE;
        if (estimate && (rc = check_disk(res, po->target ? po->target : ".")))
                return rc;
        if (json) {
                _cleanup_free_ char *s = json_dumps(res, JSON_COMPACT | JSON_PRESERVE_ORDER);
                puts(s ? s : "{}");
        } else if (estimate)
                human_estimate(res);
        else
                human_validate(res);
        return fflush(stdout) == 0 ? 0 : IMP_EXIT_FAILURE;
}

static int painting_option(int c, const char *arg, struct painting_opts *po) {
        int workers = 1;
        po->given |= c == 'W' ? 1u : c == 'V' ? 2u : c == 'T' ? 4u : 8u;
        switch (c) {
        case 'W':
                if (imp_parse_int("--workers", arg, 1, 256, &workers) < 0)
                        return -EINVAL;
                po->est.workers = (unsigned) workers;
                return 0;
        case 'V': return imp_parse_double("--stage-speed", arg, 1e-3, 1e4, &po->est.speed_mm_s);
        case 'T': return imp_parse_double("--settle", arg, 0, 3600, &po->est.settle_s);
        default: return imp_parse_double("--process-s", arg, 0, 1e6, &po->est.process_s);
        }
}

/* plan.validate / plan.estimate's args: the plan and, for an estimate, the painting options
 * given on the command line (the others are the daemon's: its stage's feed, one job at a time). */
static json_t *daemon_args(const char *plan, bool estimate, const struct painting_opts *po) {
        json_t *args = json_pack("{s:s}", "plan", plan);
        json_t *pj = estimate && po->given ? json_object() : NULL;
        if (pj && po->given & 1)
                json_object_set_new(pj, "workers", json_integer(po->est.workers));
        if (pj && po->given & 2)
                json_object_set_new(pj, "stage_speed_mm_s", json_real(po->est.speed_mm_s));
        if (pj && po->given & 4)
                json_object_set_new(pj, "settle_s", json_real(po->est.settle_s));
        if (pj && po->given & 8)
                json_object_set_new(pj, "process_s", json_real(po->est.process_s));
        if (pj && args)
                json_object_set_new(args, "painting", pj);
        else
                json_decref(pj);
        return args;
}

static int run(int argc, char **argv) {
        struct imp_client_opts o = {};
        const char *rig = NULL, *scene = NULL;
        bool daemon = false;
        static const struct option opts[] = {
                { "json", no_argument, NULL, 'j' },      { "socket", required_argument, NULL, 'S' },
                { "rig", required_argument, NULL, 'r' }, { "scene", required_argument, NULL, 's' },
                { "daemon", no_argument, NULL, 'd' },    { "help", no_argument, NULL, 'h' },
                { "workers", required_argument, NULL, 'W' }, { "stage-speed", required_argument, NULL, 'V' },
                { "settle", required_argument, NULL, 'T' }, { "process-s", required_argument, NULL, 'P' },
                { "target", required_argument, NULL, 'D' }, {} };
        struct painting_opts po = { .est = { .speed_mm_s = IMP_PLAN_STAGE_SPEED_MM_S, .settle_s = IMP_PLAN_SETTLE_S,
                                             .process_s = -1, .workers = 1 } };
        int c;
        while ((c = getopt_long(argc, argv, "h", opts, NULL)) >= 0)
                switch (c) {
                case 'j': o.json = true; break;
                case 'S': o.socket = optarg; break;
                case 'r': rig = optarg; break;
                case 's': scene = optarg; break;
                case 'd': daemon = true; break;
                case 'D': po.target = optarg; break;
                case 'W': case 'V': case 'T': case 'P':
                        if (painting_option(c, optarg, &po) < 0)
                                return IMP_EXIT_USAGE;
                        break;
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        static const char *const verbs[] = { "validate", "estimate" };
        if (argc - optind >= 1 && strcmp(argv[optind], "validate") && strcmp(argv[optind], "estimate"))
                return imp_cli_unknown_action("plan", argv[optind], verbs, ARRAY_SIZE(verbs));
        if (argc - optind != 2) {
                if (argc - optind == 0)
                        fprintf(stderr, "impasto plan: expected an action (validate or estimate) and a PLAN\n");
                else
                        fprintf(stderr, "impasto plan %s: expected one PLAN, got %d words\n", argv[optind],
                                argc - optind - 1);
                fprintf(stderr, "Run 'impasto help plan' for the usage.\n");
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
                return offline(plan, rig, scene, estimate, o.json, &po);
        char abs[PATH_MAX];
        if (realpath(plan, abs))   /* the daemon opens the plan itself */
                plan = abs;
        json_t *args = daemon_args(plan, estimate, &po);
        if (po.target)
                log_warning("plan estimate --daemon: --target ignored: the daemon checks its own store");
        return imp_client_simple(&o, estimate ? "plan.estimate" : "plan.validate", args,
                                 estimate ? human_estimate : human_validate);
}

const struct imp_command imp_cmd_plan = {
        .name = "plan",
        .summary = "validate a scan plan and estimate its frames, bytes and capture time",
        .run = run,
};
