/* `impasto calibrate`: rig calibration from recorded captures.
 *   impasto calibrate procam --captures DIR… --projector WxH --board COLSxROWS --square S
 *                            [--black-threshold N] [--white-threshold N] [--window PX]
 *                            [--json] [--out rig.json] [--mm-per-unit F]
 * Projector–camera calibration after Moreno & Taubin (2012), see docs/calibration.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib.h"
#include "commands.h"
#include "log.h"
#ifdef IMPASTO_HAVE_CV
#include "cv-calib.h"
#endif

#define EXIT_USAGE 2
#define EXIT_BADINPUT 3

static void usage(FILE *f) {
        fprintf(f, "usage: impasto calibrate procam --captures DIR... --projector WxH --board COLSxROWS\n"
                   "                                --square SIZE [--black-threshold N (40)]\n"
                   "                                [--white-threshold N (5)] [--window PX (auto)]\n"
                   "                                [--json] [--out RIG.json] [--mm-per-unit F (1)]\n"
                   "  DIR holds graycode_00.png ... (Gray-code frames, then white, then black);\n"
                   "  COLSxROWS counts inner corners; SIZE is the square side (output unit).\n");
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

static int parse_num(const char *opt, const char *s, double min, double *ret) {
        char *end;
        double v = strtod(s, &end);
        if (end == s || *end || !isfinite(v) || v < min) {
                log_error("%s: expected a number >= %g, got '%s'", opt, min, s);
                return -EINVAL;
        }
        *ret = v;
        return 0;
}

#ifdef IMPASTO_HAVE_CV
static int run_procam(int argc, char **argv) {
        struct imp_calib_procam_opts o;
        imp_calib_procam_opts_default(&o);
        const char *dirs[IMP_CALIB_MAX_CAPTURES];
        int n_dirs = 0;
        bool json = false, have_proj = false, have_board = false, have_square = false;
        const char *out = NULL;
        double mm_per_unit = 1, v;
        for (int i = 1; i < argc; i++) {
                const char *a = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                if (!strcmp(a, "--json")) {
                        json = true;
                        continue;
                }
                if (!strcmp(a, "--help") || !strcmp(a, "-h")) {
                        usage(stdout);
                        return 0;
                }
                if (!strcmp(a, "--captures")) {
                        while (i + 1 < argc && strncmp(argv[i + 1], "--", 2)) {
                                if (n_dirs == IMP_CALIB_MAX_CAPTURES) {
                                        log_error("--captures: at most %d directories", IMP_CALIB_MAX_CAPTURES);
                                        return EXIT_USAGE;
                                }
                                dirs[n_dirs++] = argv[++i];
                        }
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", a);
                        usage(stderr);
                        return EXIT_USAGE;
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
                else if (!strcmp(a, "--black-threshold") && !(r = parse_num(a, val, 0, &v)))
                        o.black_threshold = (int) v;
                else if (!strcmp(a, "--white-threshold") && !(r = parse_num(a, val, 0, &v)))
                        o.white_threshold = (int) v;
                else if (!strcmp(a, "--window") && !(r = parse_num(a, val, 3, &v)))
                        o.window_half_px = (int) v / 2;
                else if (r == 0) {
                        log_error("unknown option '%s'", a);
                        usage(stderr);
                        return EXIT_USAGE;
                }
                if (r < 0)
                        return EXIT_USAGE;
        }
        if (!n_dirs || !have_proj || !have_board || !have_square) {
                log_error("--captures, --projector, --board and --square are required");
                usage(stderr);
                return EXIT_USAGE;
        }
        static struct imp_calib_procam res;
        struct imp_error err = {};
        int r = imp_cv_calib_procam(dirs, n_dirs, &o, &res, &err);
        if (r < 0) {
                log_error("calibrate procam: %s", err.msg);
                return r == -ENOMEM ? 1 : EXIT_BADINPUT;
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
                return argc < 2 ? EXIT_USAGE : 0;
        }
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
        return EXIT_USAGE;
}

const struct imp_command imp_cmd_calibrate = { "calibrate", "projector-camera calibration from Gray-code chessboard captures", run };
