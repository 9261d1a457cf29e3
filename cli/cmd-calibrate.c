/* `impasto calibrate`: rig calibration from recorded captures.
 *   impasto calibrate procam --captures DIR… --projector WxH --board COLSxROWS --square S
 *                            [--black-threshold N] [--white-threshold N] [--window PX]
 *                            [--json] [--out rig.json] [--mm-per-unit F]
 *   impasto calibrate procam --sets SET… --board COLSxROWS --square S
 *                            [--reference SET --board-origin X,Y] [--projector WxH] [...]
 * With --sets the input is capture sets (`impasto sim render` with config/plans/target.cfg,
 * or the daemon) and --out writes the full rig: the sets' rig.json with the calibrated
 * camera and projector; --reference names the set whose board lies on the canvas plane and
 * so fixes the canvas frame.
 * Projector–camera calibration after Moreno & Taubin (2012), see docs/calibration.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib.h"
#include "calibrate-ext.h"
#include "calibrate-remote.h"
#include "exit-codes.h"
#include "captureset.h"
#include "commands.h"
#include "rig.h"
#include "log.h"
#include "numparse.h"
#ifdef IMPASTO_HAVE_CV
#include "cv-calib.h"
#endif


static void usage(FILE *f) {
        fprintf(f, "usage: impasto calibrate procam --captures DIR... --projector WxH --board COLSxROWS\n"
                   "                                --square SIZE [--black-threshold N (40)]\n"
                   "                                [--white-threshold N (5)] [--window PX (auto)]\n"
                   "                                [--json] [--out RIG.json] [--mm-per-unit F (1)] [--opencv-only]\n"
                   "                                [--no-joint]\n"
                   "       impasto calibrate procam --sets SET... --board COLSxROWS --square SIZE\n"
                   "                                [--reference SET --board-origin X,Y] [--projector WxH]\n"
                   "                                [same options as above]\n"
                   "  --opencv-only: skip the Ceres refinement (robust loss, outliers dropped) that\n"
                   "  follows OpenCV's estimate when impasto is built with Ceres (and the joint one).\n"
                   "  --no-joint: skip the joint refinement of camera, projector and their pose in one\n"
                   "  problem; the pose is then stereoCalibrate's with the per-device intrinsics.\n"
                   "  DIR holds graycode_00.png ... (Gray-code frames, then white, then black);\n"
                   "  SET is a capture set with Gray code on both axes with inverses, white and black\n"
                   "  (config/plans/target.cfg); its rig.json gives the projector size, names, sensor\n"
                   "  and dome, and --out writes it back with the calibrated camera and projector.\n"
                   "  --reference: the set whose board lies on the canvas (z = 0) with inner corner\n"
                   "  (0, 0) at canvas (X, Y) (units of SIZE): it puts the rig in the canvas frame.\n"
                   "  COLSxROWS counts inner corners; SIZE is the square side (output unit).\n"
                   "Other routines (each has --help):\n"
                   "       impasto calibrate camera ...       intrinsics, distortion, pose from target sets\n"
                   "       impasto calibrate lights ...       dome light positions from mirror spheres\n"
                   "       impasto calibrate radiometric ...  black level, response, gain, read noise\n"
                   "       impasto calibrate start|list|show  routines captured and run by impastod\n");
}

static int parse_wxh(const char *opt, const char *s, int *w, int *h) {
        char *end;
        long a = strtol(s, &end, 10);
        if (end == s || (*end != 'x' && *end != 'X'))
                goto bad;
        const char *s2 = end + 1;
        long b = strtol(s2, &end, 10);
        if (end == s2 || *end || a < 1 || b < 1 || a > 65536 || b > 65536)
                goto bad;
        *w = (int) a;
        *h = (int) b;
        return 0;
bad:
        log_error("%s: expected WIDTHxHEIGHT (e.g. 1024x768), got '%s'", opt, s);
        return -EINVAL;
}

static int parse_xy(const char *opt, const char *s, double v[2]) {
        char *end;
        v[0] = strtod(s, &end);
        if (end == s || *end != ',')
                goto bad;
        const char *s2 = end + 1;
        v[1] = strtod(s2, &end);
        if (end == s2 || *end || !isfinite(v[0]) || !isfinite(v[1]))
                goto bad;
        return 0;
bad:
        log_error("%s: expected X,Y (e.g. 6,6.5), got '%s'", opt, s);
        return -EINVAL;
}

static int parse_num(const char *opt, const char *s, double min, double *ret) {
        return imp_parse_double(opt, s, min, INFINITY, ret);
}

#ifdef IMPASTO_HAVE_CV
static int report(const struct imp_calib_procam *res, bool json) {
        for (int i = 0; i < res->n_warnings; i++)
                log_warning("%s", res->warnings[i]);
        if (!json) {
                imp_calib_procam_print(res, stdout);
                return 0;
        }
        json_t *j = imp_calib_procam_to_json(res);
        if (!j || json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10)) < 0) {
                json_decref(j);
                log_error("calibrate procam: cannot write JSON");
                return 1;
        }
        json_decref(j);
        fputc('\n', stdout);
        return 0;
}

static int run_sets(const char **dirs, int n_dirs, const char *reference, struct imp_calib_procam_opts *o,
                    bool have_proj, bool json, const char *out, double mm_per_unit) {
        struct imp_error err = {};
        if (reference) {
                o->reference = -1;
                for (int i = 0; i < n_dirs; i++)
                        if (!strcmp(dirs[i], reference))
                                o->reference = i;
                if (o->reference < 0)
                        o->reference = n_dirs, dirs[n_dirs++] = reference;
        }
        o->orient_board = true;
        if (!have_proj) {
                struct imp_captureset *cs = NULL;
                int r = imp_captureset_open(dirs[0], &cs, &err);
                if (r < 0) {
                        log_error("calibrate procam: %s", err.msg);
                        return IMP_EXIT_BAD_INPUT;
                }
                const struct imp_rig *rig = imp_captureset_rig(cs);
                if (!rig->has_projector) {
                        imp_captureset_close(cs);
                        log_error("calibrate procam: %s/rig.json has no projector; give --projector WxH", dirs[0]);
                        return IMP_EXIT_BAD_INPUT;
                }
                o->proj_w = rig->projector.model.width;
                o->proj_h = rig->projector.model.height;
                imp_captureset_close(cs);
        }
        struct imp_calib_sets *sets = NULL;
        int r = imp_calib_sets_open(dirs, n_dirs, o->proj_w, o->proj_h, &sets, &err);
        if (r < 0) {
                log_error("calibrate procam: %s", err.msg);
                return r == -ENOMEM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
        }
        static struct imp_calib_procam res;
        r = imp_cv_calib_procam_source(dirs, n_dirs, imp_calib_sets_load, sets, o, &res, &err);
        if (r < 0) {
                imp_calib_sets_free(sets);
                log_error("calibrate procam: %s", err.msg);
                return r == -ENOMEM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
        }
        int ret = report(&res, json);
        if (out && !ret) {
                struct imp_rig rig;
                r = imp_calib_procam_rig(&res, mm_per_unit, imp_calib_sets_rig(sets, 0), &rig, &err);
                if (r >= 0) {
                        r = imp_rig_save(out, &rig, &err);
                        imp_rig_free(&rig);
                }
                if (r < 0) {
                        log_error("calibrate procam: %s", err.msg);
                        ret = 1;
                } else if (!res.have_world) {
                        log_warning("%s: no --reference, so the world frame is the camera's; "
                                    "processing needs the canvas frame", out);
                }
        }
        imp_calib_sets_free(sets);
        return ret;
}

static int run_procam(int argc, char **argv) {
        struct imp_calib_procam_opts o;
        imp_calib_procam_opts_default(&o);
        const char *dirs[IMP_CALIB_MAX_CAPTURES + 1];
        int n_dirs = 0;
        bool sets = false;
        const char *reference = NULL;
        bool json = false, have_proj = false, have_board = false, have_square = false;
        const char *out = NULL;
        double mm_per_unit = 1, v;
        for (int i = 1; i < argc; i++) {
                const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                if (!strcmp(a, "--json")) {
                        json = true;
                        continue;
                }
                if (!strcmp(a, "--opencv-only")) {
                        o.opencv_only = true;
                        continue;
                }
                if (!strcmp(a, "--no-joint")) {
                        o.no_joint = true;
                        continue;
                }
                if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
                        usage(stdout);
                        return 0;
                }
                if (!strcmp(a, "--captures") || !strcmp(a, "--sets")) {
                        if (n_dirs && sets != !strcmp(a, "--sets")) {
                                log_error("--captures and --sets cannot be mixed");
                                return IMP_EXIT_USAGE;
                        }
                        sets = !strcmp(a, "--sets");
                        while (i + 1 < argc && strncmp(argv[i + 1], "--", 2)) {
                                if (n_dirs == IMP_CALIB_MAX_CAPTURES) {
                                        log_error("%s: at most %d directories", a, IMP_CALIB_MAX_CAPTURES);
                                        return IMP_EXIT_USAGE;
                                }
                                dirs[n_dirs++] = argv[++i];
                        }
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", a);
                        usage(stderr);
                        return IMP_EXIT_USAGE;
                }
                i++;
                int r = 0;
                if (!strcmp(a, "--projector"))
                        r = parse_wxh(a, val, &o.proj_w, &o.proj_h), have_proj = true;
                else if (!strcmp(a, "--board"))
                        r = parse_wxh(a, val, &o.board_cols, &o.board_rows), have_board = true;
                else if (!strcmp(a, "--square"))
                        r = parse_num(a, val, 1e-9, &o.square), have_square = true;
                else if (!strcmp(a, "--mm-per-unit"))
                        r = parse_num(a, val, 1e-12, &mm_per_unit);
                else if (!strcmp(a, "--out"))
                        out = val;
                else if (!strcmp(a, "--reference"))
                        reference = val;
                else if (!strcmp(a, "--board-origin"))
                        r = parse_xy(a, val, o.board_origin);
                else if (!strcmp(a, "--black-threshold") && !(r = parse_num(a, val, 0, &v)))
                        o.black_threshold = (int) v;
                else if (!strcmp(a, "--white-threshold") && !(r = parse_num(a, val, 0, &v)))
                        o.white_threshold = (int) v;
                else if (!strcmp(a, "--window") && !(r = parse_num(a, val, 3, &v)))
                        o.window_half_px = (int) v / 2;
                else if (r == 0) {
                        log_error("unknown option '%s'", a);
                        usage(stderr);
                        return IMP_EXIT_USAGE;
                }
                if (r < 0)
                        return IMP_EXIT_USAGE;
        }
        if (!n_dirs || (!have_proj && !sets) || !have_board || !have_square) {
                log_error("--captures (or --sets), --projector (not needed with --sets), --board and "
                          "--square are required");
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        if (reference && !sets) {
                log_error("--reference needs --sets");
                return IMP_EXIT_USAGE;
        }
        if (sets)
                return run_sets(dirs, n_dirs, reference, &o, have_proj, json, out, mm_per_unit);
        static struct imp_calib_procam res;
        struct imp_error err = {};
        int r = imp_cv_calib_procam(dirs, n_dirs, &o, &res, &err);
        if (r < 0) {
                log_error("calibrate procam: %s", err.msg);
                return r == -ENOMEM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
        }
        for (int i = 0; i < res.n_warnings; i++)
                log_warning("%s", res.warnings[i]);
        if (json) {
                json_t *j = imp_calib_procam_to_json(&res);
                if (!j || json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10)) < 0) {
                        json_decref(j);
                        log_error("calibrate procam: cannot write JSON");
                        return 1;
                }
                json_decref(j);
                fputc('\n', stdout);
        } else {
                imp_calib_procam_print(&res, stdout);
        }
        if (out) {
                r = imp_calib_procam_save_rig(&res, mm_per_unit, out, &err);
                if (r < 0) {
                        log_error("calibrate procam: %s", err.msg);
                        return 1;
                }
        }
        return 0;
}
#endif

static int run(int argc, char **argv) {
        if (argc < 2 || !strcmp(argv[1], "--help") || !strcmp(argv[1], "-h")) {
                usage(argc < 2 ? stderr : stdout);
                return argc < 2 ? IMP_EXIT_USAGE : 0;
        }
        if (!strcmp(argv[1], "start") || !strcmp(argv[1], "list") || !strcmp(argv[1], "show"))
                return imp_calibrate_remote_main(argc - 1, argv + 1);   /* on the daemon */
        if (!strcmp(argv[1], "lights")) return imp_calibrate_lights_main(argc - 1, argv + 1);
        if (!strcmp(argv[1], "radiometric")) return imp_calibrate_radiometric_main(argc - 1, argv + 1);
        if (!strcmp(argv[1], "camera")) return imp_calibrate_camera_main(argc - 1, argv + 1);
        if (!strcmp(argv[1], "procam")) {
#ifdef IMPASTO_HAVE_CV
                return run_procam(argc - 1, argv + 1);
#else
                log_error("calibrate procam: this impasto was built without OpenCV");
                return 1;
#endif
        }
        log_error("calibrate: unknown target '%s'", argv[1]);
        usage(stderr);
        return IMP_EXIT_USAGE;
}

const struct imp_command imp_cmd_calibrate = { "calibrate", "calibrate camera, projector-camera, dome lights and radiometry", run };
