/* `impasto sim`: the simulated rig from the command line.
 *   impasto sim render --scene FILE --plan FILE --out DIR [--seed N] [--threads N] [--quiet] [--painting]
 *       renders every frame of the plan into a capture set at DIR, plus DIR/truth/; a plan
 *       with a painting group on a gantry scene (--painting insists on one) renders every
 *       tile: DIR/painting.json, DIR/tiles/NNNN, DIR/truth/ in the painting frame
 *       (docs/painting.md)
 *   impasto sim info --scene FILE [--plan FILE]
 *       prints the scene summary (and the plan's frame count and capture-time estimate)
 *   impasto sim serve --scene FILE [--plan FILE] [--address A] [--modbus-port P] [--seed N]
 *                     [--rig-out FILE] [--ready-file FILE] [--truth-out DIR] [--fault SPEC]...
 *       serves the scene as devices (sim/serve.h) until SIGTERM/SIGINT, then exits 0;
 *       --truth-out writes DIR/truth/ (the ground truth `sim render` writes beside its
 *       capture set) before the ready file appears; a gantry scene needs --plan (its painting
 *       group): the stage is a GRBL controller on a pseudo-terminal (docs/painting.md), and
 *       --truth-out writes the whole painting's truth and truth/tile-poses.json */
#include <fcntl.h>
#include <getopt.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <pthread.h>
#include <unistd.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include "captureset.h"
#include "commands.h"
#include "help.h"
#include "exit-codes.h"
#include "log.h"
#include "plan.h"
#include "gantry.h"
#include "render.h"
#include "scene.h"
#include "serve.h"

#define MAX_FAULTS 16

struct sim_args {
        const char *scene, *plan, *out;
        const char *address, *rig_out, *ready_file, *truth_out;
        long modbus_port;
        const char *faults[MAX_FAULTS];
        int n_faults;
        long long seed;
        bool has_seed, quiet, painting;
        int threads;
};

static void usage(FILE *f) {
        fprintf(f, "usage: impasto sim render --scene FILE --plan FILE --out DIR [--seed N] [--threads N] [--quiet] [--painting]\n"
                   "       impasto sim info --scene FILE [--plan FILE]\n"
                   "       impasto sim serve --scene FILE [--plan FILE (a gantry scene's)] [--address 127.0.0.1]\n"
                   "                         [--modbus-port 15020] [--seed N]\n"
                   "                         [--rig-out FILE] [--ready-file FILE] [--truth-out DIR] [--fault SPEC]...\n"
                   "         --truth-out DIR: write the ground truth into DIR/truth/ (as sim render does)\n"
                   "         SPEC: drop-frame=N, modbus-exception=N[:CODE], modbus-delay=N:MS,\n"
                   "               modbus-disconnect=N, frame-delay=MS, projector-fault=CODE\n");
}

static int parse_args(int argc, char **argv, struct sim_args *a) {
        static const struct option opts[] = {
                { "scene", required_argument, NULL, 's' }, { "plan", required_argument, NULL, 'p' },
                { "out", required_argument, NULL, 'o' },   { "seed", required_argument, NULL, 'S' },
                { "threads", required_argument, NULL, 't' }, { "quiet", no_argument, NULL, 'q' },
                { "address", required_argument, NULL, 'a' }, { "modbus-port", required_argument, NULL, 'm' },
                { "rig-out", required_argument, NULL, 'r' }, { "ready-file", required_argument, NULL, 'R' },
                { "fault", required_argument, NULL, 'f' },   { "truth-out", required_argument, NULL, 'T' },
                { "painting", no_argument, NULL, 'P' },     { "help", no_argument, NULL, 'h' },         { 0 } };
        int c;
        optind = 1;
        while ((c = getopt_long(argc, argv, "s:p:o:S:t:qh", opts, NULL)) != -1) {
                char *end = NULL;
                switch (c) {
                case 's': a->scene = optarg; break;
                case 'p': a->plan = optarg; break;
                case 'o': a->out = optarg; break;
                case 'q': a->quiet = true; break;
                case 'P': a->painting = true; break;
                case 'S':
                        a->seed = strtoll(optarg, &end, 0);
                        if (!*optarg || *end || a->seed < 0) {
                                log_error("--seed: expected an integer >= 0, got '%s'", optarg);
                                return -EINVAL;
                        }
                        a->has_seed = true;
                        break;
                case 't':
                        a->threads = (int) strtol(optarg, &end, 10);
                        if (!*optarg || *end || a->threads < 1 || a->threads > 1024) {
                                log_error("--threads: expected 1 to 1024, got '%s'", optarg);
                                return -EINVAL;
                        }
                        break;
                case 'a': a->address = optarg; break;
                case 'r': a->rig_out = optarg; break;
                case 'R': a->ready_file = optarg; break;
                case 'T': a->truth_out = optarg; break;
                case 'm':
                        a->modbus_port = strtol(optarg, &end, 10);
                        if (!*optarg || *end || a->modbus_port < 1 || a->modbus_port > 65535) {
                                log_error("--modbus-port: expected 1 to 65535, got '%s'", optarg);
                                return -EINVAL;
                        }
                        break;
                case 'f':
                        if (a->n_faults == MAX_FAULTS) {
                                log_error("--fault: at most %d", MAX_FAULTS);
                                return -EINVAL;
                        }
                        a->faults[a->n_faults++] = optarg;
                        break;
                case 'h': usage(stdout); exit(0);
                default: return -EINVAL;
                }
        }
        if (optind < argc) {
                log_error("unexpected argument '%s'", argv[optind]);
                return -EINVAL;
        }
        return 0;
}

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void print_counters(FILE *f, const struct imp_sim_counters *c) {
        fprintf(f, "counters: shading_evals %llu, shadow_rays %llu, shadow_steps %llu, indirect_paths %llu, "
                   "grid_vertices %llu, indirect_lookups %llu, random_draws %llu, projector_lookups %llu, "
                   "distortion_evals %llu, defocus_taps %llu\n",
                (unsigned long long) c->shading_evals, (unsigned long long) c->shadow_rays,
                (unsigned long long) c->shadow_steps, (unsigned long long) c->indirect_paths,
                (unsigned long long) c->grid_vertices, (unsigned long long) c->indirect_lookups,
                (unsigned long long) c->random_draws, (unsigned long long) c->projector_lookups,
                (unsigned long long) c->distortion_evals, (unsigned long long) c->defocus_taps);
}

static int load_scene(const struct sim_args *a, struct imp_scene **ret) {
        struct imp_error err = { 0 };
        int r = imp_scene_load(a->scene, ret, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return IMP_EXIT_BAD_INPUT;
        }
        if (a->has_seed)
                imp_scene_set_seed(*ret, (uint64_t) a->seed);
        return 0;
}

static int cmd_info(const struct sim_args *a) {
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        int rc = load_scene(a, &scene);
        if (rc)
                return rc;
        _cleanup_free_ char *text = imp_scene_describe(scene);
        fputs(text ? text : "(out of memory)\n", stdout);
        if (a->plan) {
                struct imp_error err = { 0 };
                _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
                int r = imp_plan_load(a->plan, imp_scene_rig(scene), &plan, &err);
                if (r < 0) {
                        log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                        return IMP_EXIT_BAD_INPUT;
                }
                printf("plan %s: %zu frames, estimated capture time %.1f s\n", a->plan, imp_plan_count(plan),
                       imp_plan_estimate_s(plan, imp_scene_rig(scene)));
                if (imp_plan_tiles(plan) && imp_scene_is_gantry(scene)) {
                        double move_s, clock_s = imp_sim_painting_clock_s(scene, plan, &move_s);
                        printf("painting: %zu tiles, simulated clock %.1f s (gantry moves %.1f s)\n",
                               imp_tile_plan_count(imp_plan_tiles(plan)), clock_s, move_s);
                }
        }
        return 0;
}

static void painting_progress(void *userdata, size_t tile, size_t n_tiles, size_t frames) {
        const double *t0 = userdata;
        fprintf(stderr, "sim: tile %zu/%zu, %zu frames, %.1f s\n", tile + 1, n_tiles, frames, now_s() - *t0);
}

/* A plan with a painting group on a gantry scene: every tile's capture set, painting.json and
 * the painting-frame truth (sim/gantry.h). */
static int cmd_render_painting(const struct sim_args *a, struct imp_scene *scene, const struct imp_plan *plan) {
        struct imp_error err = { 0 };
        struct imp_sim_painting_result res;
        double t0 = now_s();
        int r = imp_sim_render_painting(scene, plan, a->plan, a->out, a->quiet ? NULL : painting_progress, &t0, &res,
                                        &err);
        if (r < 0) {
                log_error_errno(r, "%s", err.msg[0] ? err.msg : "sim: %m");
                return r == -EINVAL ? IMP_EXIT_BAD_INPUT : 1;
        }
        printf("sim: wrote %zu tiles, %zu frames (%zu dropped), painting.json and truth/ to %s in %.1f s\n"
               "sim: simulated clock %.1f s (gantry moves %.1f s)\n",
               res.tiles, res.frames, res.dropped, a->out, now_s() - t0, res.clock_s, res.move_s);
        return 0;
}

static int cmd_render(const struct sim_args *a) {
        if (!a->scene || !a->plan || !a->out) {
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
#ifdef _OPENMP
        if (a->threads > 0)
                omp_set_num_threads(a->threads);
#endif
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        int rc = load_scene(a, &scene);
        if (rc)
                return rc;
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        int r = imp_plan_load(a->plan, imp_scene_rig(scene), &plan, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return IMP_EXIT_BAD_INPUT;
        }
        if (a->painting || imp_plan_tiles(plan))
                return cmd_render_painting(a, scene, plan);
        double t0 = now_s();
        _cleanup_(imp_render_freep) struct imp_render *rd = NULL;
        if ((r = imp_render_new(scene, &rd, &err)) < 0) {
                log_error_errno(r, "%s: %m", err.msg);
                return 1;
        }
        const struct imp_rig *rig = imp_render_rig(rd);
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        if ((r = imp_captureset_create(a->out, rig, a->plan, &cs, &err)) < 0) {
                log_error_errno(r, "%s", err.msg[0] ? err.msg : "cannot create the capture set: %m");
                return 1;
        }
        size_t n = imp_plan_count(plan), written = 0, dropped = 0;
        if (!a->quiet)
                fprintf(stderr, "sim: scene %s, %zu frames, view maps in %.2f s\n", imp_scene_name(scene), n,
                        now_s() - t0);
        long long t_ns = 0;
        double last = now_s();
        const struct imp_frame_record *prev = NULL;
        for (size_t i = 0; i < n; i++) {
                struct imp_frame_record rec = *imp_plan_frame(plan, i);
                imp_sim_stamp(&rec, prev, rig, &t_ns);
                prev = imp_plan_frame(plan, i);
                _cleanup_image_ struct imp_image *frame = NULL;
                imp_error_clear(&err);
                r = imp_render_frame(rd, &rec, &frame, &err);
                if (r == -EAGAIN) {
                        dropped++;
                        if (!a->quiet)
                                fprintf(stderr, "sim: frame %zu dropped (effect dropped_frame)\n", i);
                        continue;
                }
                if (r < 0) {
                        log_error_errno(r, "%s", err.msg[0] ? err.msg : "render: %m");
                        return 1;
                }
                if ((r = imp_captureset_add_frame(cs, &rec, frame, &err)) < 0) {
                        log_error_errno(r, "frame %zu: %s", i, err.msg[0] ? err.msg : "cannot write");
                        return 1;
                }
                written++;
                if (!a->quiet && (now_s() - last > 2.0 || i + 1 == n)) {
                        fprintf(stderr, "sim: frame %zu/%zu (%.0f%%), %.1f s\n", i + 1, n, 100.0 * (i + 1) / n,
                                now_s() - t0);
                        last = now_s();
                }
        }
        if ((r = imp_sim_write_truth(scene, rd, a->out, &err)) < 0) {
                log_error_errno(r, "%s", err.msg[0] ? err.msg : "truth: %m");
                return 1;
        }
        printf("sim: wrote %zu frames (%zu dropped) and truth/ to %s in %.1f s\n", written, dropped, a->out,
               now_s() - t0);
        if (!a->quiet)   /* diagnostics, not the result: stdout is the one summary line */
                print_counters(stderr, imp_render_counters(rd));
        return 0;
}

/* Serves until SIGTERM or SIGINT. The signals are blocked before any device thread starts,
 * so every thread inherits the mask and sigwait() here is the only receiver. */
static int cmd_serve(const struct sim_args *a) {
        if (!a->scene) {
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        sigset_t set;
        sigemptyset(&set);
        sigaddset(&set, SIGTERM);
        sigaddset(&set, SIGINT);
        pthread_sigmask(SIG_BLOCK, &set, NULL);
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        int rc = load_scene(a, &scene);
        if (rc)
                return rc;
        struct imp_error err = { 0 };
        _cleanup_(imp_plan_freep) struct imp_plan *plan = NULL;
        int r;
        if (a->plan && (r = imp_plan_load(a->plan, imp_scene_rig(scene), &plan, &err)) < 0) {
                log_error("%s", err.msg);
                return IMP_EXIT_USAGE;
        }
        struct imp_serve_config cfg = { .address = a->address, .modbus_port = (uint16_t) a->modbus_port,
                                        .tiles = plan ? imp_plan_tiles(plan) : NULL };
        _cleanup_(imp_serve_freep) struct imp_serve *s = NULL;
        r = imp_serve_new(scene, &cfg, &s, &err);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        for (int i = 0; i < a->n_faults; i++)
                if (imp_serve_fault(s, a->faults[i], &err) < 0) {
                        log_error("%s", err.msg);
                        return IMP_EXIT_USAGE;
                }
        if (a->rig_out && (r = imp_rig_save(a->rig_out, imp_serve_rig(s), &err)) < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        if (a->truth_out && imp_scene_is_gantry(scene)) {
                /* The painting's truth and every tile's true pose, on a scene of its own (the
                 * served one is re-placed under the carriage). */
                _cleanup_(imp_scene_freep) struct imp_scene *whole = NULL;
                if ((rc = load_scene(a, &whole)))
                        return rc;
                if ((r = imp_sim_write_painting_truth_plan(whole, plan, a->truth_out, &err)) < 0) {
                        log_error_errno(r, "--truth-out %s: %s", a->truth_out, err.msg[0] ? err.msg : "truth: %m");
                        return 1;
                }
        } else if (a->truth_out) {
                /* The served frames come from a renderer of this scene (imp_serve_rig is its
                 * rig); a second renderer of the same scene gives the same truth. */
                _cleanup_(imp_render_freep) struct imp_render *rd = NULL;
                if ((r = imp_render_new(scene, &rd, &err)) < 0 ||
                    (r = imp_sim_write_truth(scene, rd, a->truth_out, &err)) < 0) {
                        log_error_errno(r, "--truth-out %s: %s", a->truth_out, err.msg[0] ? err.msg : "truth: %m");
                        return 1;
                }
        }
        _cleanup_free_ char *text = imp_serve_describe(s);
        fprintf(stderr, "sim serve: %s", text ? text : "serving\n");
        if (a->ready_file) {
                int fd = open(a->ready_file, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
                if (fd < 0) {
                        log_error_errno(-errno, "--ready-file %s: %m", a->ready_file);
                        return 1;
                }
                dprintf(fd, "%d\n", (int) getpid());
                close(fd);
        }
        int sig = 0;
        sigwait(&set, &sig);
        fprintf(stderr, "sim serve: %s, stopping (%llu frames served)\n", strsignal(sig),
                (unsigned long long) imp_serve_frames(s, 0));
        if (a->ready_file)
                unlink(a->ready_file);
        return 0;
}

static int run(int argc, char **argv) {
        if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
                usage(argc < 2 ? stderr : stdout);
                return argc < 2 ? IMP_EXIT_USAGE : 0;
        }
        static const char *const verbs[] = { "render", "serve", "info" };
        if (strcmp(argv[1], "render") && strcmp(argv[1], "serve") && strcmp(argv[1], "info"))
                return imp_cli_unknown_action("sim", argv[1], verbs, ARRAY_SIZE(verbs));
        struct sim_args a = { 0 };
        if (parse_args(argc - 1, argv + 1, &a) < 0) {
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        if (!strcmp(argv[1], "render"))
                return cmd_render(&a);
        if (!strcmp(argv[1], "serve"))
                return cmd_serve(&a);
        if (!strcmp(argv[1], "info")) {
                if (!a.scene) {
                        usage(stderr);
                        return IMP_EXIT_USAGE;
                }
                return cmd_info(&a);
        }
        return IMP_EXIT_USAGE;          /* (not reached: the action was checked above) */
}

const struct imp_command imp_cmd_sim = {
        .name = "sim",
        .summary = "simulated rig: render a capture set with ground truth, serve it as devices, describe a scene",
        .run = run,
};
