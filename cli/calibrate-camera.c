/* `impasto calibrate camera`: one camera's intrinsics and distortion from chessboard
 * images (folders or files: PNG, TIFF, EXR) and/or capture sets (one lit frame each),
 * dispatched from cli/cmd-calibrate.c. Detection and the fit are the procam calibration's
 * (pipeline/calib/cv/cv-calib-camera.h); see docs/calibration.md. */
#define _GNU_SOURCE
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include "calib-camera.h"
#include "calibrate-ext.h"
#include "exit-codes.h"
#include "log.h"
#include "rig.h"
#ifdef IMPASTO_HAVE_CV
#include "cv-calib-camera.h"
#include "cv-calib.h"
#endif

#define MAX_SETS 64

static void usage(FILE *f) {
        fprintf(f, "usage: impasto calibrate camera (--images DIR|FILE... | --sets SET...) --board COLSxROWS\n"
                   "                                --square MM [--camera NAME] [--k3 auto|fit|fix]\n"
                   "                                [--k2 auto|fit|fix] [--min-views N (3)] [--opencv-only] [--json] [--out RIG.json]\n"
                   "  --images: chessboard images (PNG, TIFF, EXR; colour is reduced to luma); a directory\n"
                   "            stands for its *.png, *.tif(f), *.exr files in name order.\n"
                   "  --sets:   capture sets; from each, camera NAME's white projector frame, else its\n"
                   "            first dome or flat frame (config/plans/camera-target.cfg).\n"
                   "  COLSxROWS counts inner corners; MM is the square side (the poses' unit).\n"
                   "  --camera: the camera to read from the sets and to write in RIG.json (default: the\n"
                   "            first; \"camera0\" for images).\n"
                   "  --k3, --k2: fit the distortion term, hold it at 0 (fix), or auto: k3 is held below a\n"
                   "            20° diagonal field of view, k2 below 20° too (docs/calibration.md).\n"
                   "  --min-views: fewer views with the board is an error; below 3 the result is\n"
                   "            flagged few_views with inflated uncertainties.\n"
                   "  --out:    rig.json: the first set's rig (or a one-camera rig) with the camera's\n"
                   "            intrinsics and distortion replaced; poses are not calibrated here.\n"
                   "exit status: 0 done (warnings and \"confident\" say how far to trust it), 1 failure,\n"
                   "             2 usage, 3 bad input (missing or unreadable file, no board found,\n"
                   "             too few views, images of different sizes).\n");
}

struct camera_args {
        struct imp_calib_camera_opts o;
        const char *images[IMP_CALIB_CAMERA_MAX_VIEWS], *sets[MAX_SETS];
        int n_images, n_sets;
        const char *camera, *out;
        bool json;
};

static int parse_board(const char *s, int *cols, int *rows) {
        char extra;
        if (sscanf(s, "%dx%d%c", cols, rows, &extra) != 2 || *cols < 2 || *rows < 2 || *cols > 1000 ||
            *rows > 1000) {
                log_error("--board: expected COLSxROWS inner corners (e.g. 11x8), got '%s'", s);
                return -EINVAL;
        }
        return 0;
}

static int parse_args(int argc, char **argv, struct camera_args *a) {
        imp_calib_camera_opts_default(&a->o);
        bool have_board = false, have_square = false;
        for (int i = 1; i < argc; i++) {
                const char *o = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                if (!strcmp(o, "--help") || !strcmp(o, "-h")) {
                        usage(stdout);
                        return 1;
                }
                if (!strcmp(o, "--json") || !strcmp(o, "--opencv-only")) {
                        *(o[2] == 'j' ? &a->json : &a->o.opencv_only) = true;
                        continue;
                }
                if (!strcmp(o, "--images") || !strcmp(o, "--sets")) {
                        bool img = !strcmp(o, "--images");
                        int *n = img ? &a->n_images : &a->n_sets, max = img ? IMP_CALIB_CAMERA_MAX_VIEWS : MAX_SETS;
                        const char **list = img ? a->images : a->sets;
                        while (i + 1 < argc && strncmp(argv[i + 1], "--", 2)) {
                                if (*n == max) {
                                        log_error("%s: at most %d", o, max);
                                        return -EINVAL;
                                }
                                list[(*n)++] = argv[++i];
                        }
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", o);
                        return -EINVAL;
                }
                i++;
                char *end;
                if (!strcmp(o, "--board")) {
                        if (parse_board(val, &a->o.board_cols, &a->o.board_rows) < 0)
                                return -EINVAL;
                        have_board = true;
                } else if (!strcmp(o, "--square")) {
                        a->o.square = strtod(val, &end);
                        if (end == val || *end || !(a->o.square > 0) || !isfinite(a->o.square)) {
                                log_error("--square: expected a length > 0, got '%s'", val);
                                return -EINVAL;
                        }
                        have_square = true;
                } else if (!strcmp(o, "--min-views")) {
                        long v = strtol(val, &end, 10);
                        if (end == val || *end || v < 1 || v > IMP_CALIB_CAMERA_MAX_VIEWS) {
                                log_error("--min-views: expected 1 to %d, got '%s'", IMP_CALIB_CAMERA_MAX_VIEWS, val);
                                return -EINVAL;
                        }
                        a->o.min_views = (int) v;
                } else if (!strcmp(o, "--k3") || !strcmp(o, "--k2")) {
                        static const char *const mode[] = { [IMP_CALIB_K3_AUTO] = "auto", [IMP_CALIB_K3_FIT] = "fit",
                                                            [IMP_CALIB_K3_FIX] = "fix" };
                        int *dst = !strcmp(o, "--k3") ? &a->o.k3 : &a->o.k2;
                        *dst = -1;
                        for (int k = 0; k < 3; k++)
                                if (!strcmp(val, mode[k]))
                                        *dst = k;
                        if (*dst < 0) {
                                log_error("%s: expected auto, fit or fix, got '%s'", o, val);
                                return -EINVAL;
                        }
                } else if (!strcmp(o, "--camera")) {
                        a->camera = val;
                } else if (!strcmp(o, "--out")) {
                        a->out = val;
                } else {
                        log_error("unknown option '%s'", o);
                        return -EINVAL;
                }
        }
        if ((!a->n_images && !a->n_sets) || !have_board || !have_square) {
                log_error("--images or --sets, --board and --square are required");
                return -EINVAL;
        }
        return 0;
}

#ifdef IMPASTO_HAVE_CV
static bool image_name(const char *name) {
        const char *dot = strrchr(name, '.');
        return dot && (!strcasecmp(dot, ".png") || !strcasecmp(dot, ".tif") || !strcasecmp(dot, ".tiff") ||
                       !strcasecmp(dot, ".exr"));
}

static int cmp_str(const void *a, const void *b) {
        return strcmp(*(char *const *) a, *(char *const *) b);
}

/* The inputs, one view each: image files (directories expanded) then sets. Names are
 * malloc'd into names[]; *ret_n of them. */
static int list_inputs(const struct camera_args *a, char **names, bool *is_set, int *ret_n) {
        int *n = ret_n;         /* kept current: the caller frees names[0 .. *ret_n) on any return */
        *n = 0;
        for (int i = 0; i < a->n_images; i++) {
                struct stat st;
                if (stat(a->images[i], &st) < 0) {
                        log_error("calibrate camera: %s: %m", a->images[i]);
                        return -errno;
                }
                if (!S_ISDIR(st.st_mode)) {
                        if (*n == IMP_CALIB_CAMERA_MAX_VIEWS)
                                goto too_many;
                        if (!(names[*n] = strdup(a->images[i])))
                                return -ENOMEM;
                        (*n)++;
                        continue;
                }
                DIR *d = opendir(a->images[i]);
                if (!d) {
                        log_error("calibrate camera: %s: %m", a->images[i]);
                        return -errno;
                }
                int first = *n;
                for (struct dirent *e; (e = readdir(d));) {
                        if (e->d_name[0] == '.' || !image_name(e->d_name))
                                continue;
                        if (*n == IMP_CALIB_CAMERA_MAX_VIEWS) {
                                closedir(d);
                                goto too_many;
                        }
                        if (asprintf(&names[*n], "%s/%s", a->images[i], e->d_name) < 0) {
                                closedir(d);
                                return -ENOMEM;
                        }
                        (*n)++;
                }
                closedir(d);
                if (*n == first) {
                        log_error("calibrate camera: %s: no *.png, *.tif, *.tiff or *.exr image in this directory",
                                  a->images[i]);
                        return -ENOENT;
                }
                qsort(names + first, (size_t) (*n - first), sizeof *names, cmp_str);
        }
        for (int i = 0; i < a->n_sets; i++) {
                if (*n == IMP_CALIB_CAMERA_MAX_VIEWS)
                        goto too_many;
                if (!(names[*n] = strdup(a->sets[i])))
                        return -ENOMEM;
                is_set[(*n)++] = true;
        }
        return 0;
too_many:
        log_error("calibrate camera: more than %d views", IMP_CALIB_CAMERA_MAX_VIEWS);
        return -E2BIG;
}

/* Loads view i as 8-bit grey and finds its corners. -errno on bad input (logged); 0 with
 * v->found false when the board is not in it. */
static int detect(const struct camera_args *a, const char *name, bool is_set, int *w, int *h,
                  struct imp_calib_camera_view *v, double *corners, struct imp_rig *rig, bool *have_rig) {
        struct imp_error err = {};
        _cleanup_image_ struct imp_image *u8 = NULL;
        int r;
        snprintf(v->name, sizeof v->name, "%s", name);
        if (is_set) {
                struct imp_rig set_rig = {};
                r = imp_calib_camera_set_frame(name, a->camera, &u8, NULL, *have_rig ? NULL : &set_rig, &err);
                if (r >= 0 && !*have_rig) {
                        *rig = set_rig;
                        *have_rig = true;
                }
        } else {
                _cleanup_image_ struct imp_image *im = NULL;
                r = imp_image_read(name, &im, &err);
                if (r >= 0) {
                        r = imp_calib_image_to_u8(im, 0, &u8, &err);
                        if (r < 0)
                                imp_error_prefix(&err, "%s: ", name);
                }
        }
        if (r < 0) {
                log_error("calibrate camera: %s", err.msg);
                return r;
        }
        if (*w == 0) {
                *w = u8->width;
                *h = u8->height;
        } else if (u8->width != *w || u8->height != *h) {
                log_error("calibrate camera: %s: %dx%d, the first view is %dx%d", name, u8->width, u8->height, *w, *h);
                return -EINVAL;
        }
        r = imp_cv_calib_find_corners(u8, a->o.board_cols, a->o.board_rows, corners, &err);
        if (r == -ENOENT) {
                snprintf(v->why, sizeof v->why, "%.200s", err.msg);
                log_warning("calibrate camera: %s: %s, ignoring", name, err.msg);
                return 0;
        }
        if (r < 0) {
                log_error("calibrate camera: %s: %s", name, err.msg);
                return r;
        }
        v->found = true;
        return 0;
}

static int report(const struct camera_args *a, const struct imp_calib_camera *res, const struct imp_rig *base) {
        for (int i = 0; i < res->n_warnings; i++)
                log_warning("%s", res->warnings[i]);
        if (a->json) {
                json_t *j = imp_calib_camera_to_json(res);
                if (!j || json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10)) < 0) {
                        json_decref(j);
                        log_error("calibrate camera: cannot write JSON");
                        return 1;
                }
                json_decref(j);
                fputc('\n', stdout);
        } else {
                imp_calib_camera_print(res, stdout);
        }
        if (!a->out)
                return 0;
        struct imp_error err = {};
        struct imp_rig rig;
        int r = imp_calib_camera_rig(res, a->camera, base, &rig, &err);
        if (r >= 0) {
                r = imp_rig_save(a->out, &rig, &err);
                imp_rig_free(&rig);
        }
        if (r < 0) {
                log_error("calibrate camera: %s", err.msg);
                return r == -ENOENT ? IMP_EXIT_BAD_INPUT : IMP_EXIT_FAILURE;
        }
        return 0;
}

static int run_camera(struct camera_args *a) {
        static char *names[IMP_CALIB_CAMERA_MAX_VIEWS];
        static bool is_set[IMP_CALIB_CAMERA_MAX_VIEWS];
        int n = 0, ret = IMP_EXIT_BAD_INPUT;
        const int nc = a->o.board_cols * a->o.board_rows;
        struct imp_calib_camera *res = calloc(1, sizeof *res);
        double *corners = calloc((size_t) IMP_CALIB_CAMERA_MAX_VIEWS * 2 * nc, sizeof *corners);
        double *obj = calloc((size_t) 3 * nc, sizeof *obj);
        struct imp_calib_view *views = calloc(IMP_CALIB_CAMERA_MAX_VIEWS, sizeof *views);
        struct imp_rig rig = {};
        bool have_rig = false;
        if (!res || !corners || !obj || !views) {
                log_error("calibrate camera: out of memory");
                ret = 1;
                goto out;
        }
        int r = list_inputs(a, names, is_set, &n);
        if (r < 0) {
                ret = r == -ENOMEM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
                goto out;
        }
        for (int k = 0; k < nc; k++) {
                obj[3 * k] = a->o.square * (k % a->o.board_cols);
                obj[3 * k + 1] = a->o.square * (k / a->o.board_cols);
        }
        int w = 0, h = 0;
        res->n_views = n;
        for (int i = 0; i < n; i++) {
                double *c = corners + (size_t) 2 * nc * i;
                r = detect(a, names[i], is_set[i], &w, &h, &res->views[i], c, &rig, &have_rig);
                if (r < 0)
                        goto out;
                views[i] = (struct imp_calib_view) { res->views[i].found ? nc : 0, obj, c };
        }
        struct imp_error err = {};
        r = imp_cv_calib_camera(views, w, h, &a->o, res, &err);
        if (r < 0) {
                log_error("calibrate camera: %s", err.msg);
                ret = r == -ENOMEM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
                goto out;
        }
        ret = report(a, res, have_rig ? &rig : NULL);
out:
        for (int i = 0; i < n; i++)
                free(names[i]);
        if (have_rig)
                imp_rig_free(&rig);
        free(views);
        free(obj);
        free(corners);
        free(res);
        return ret;
}
#endif

int imp_calibrate_camera_main(int argc, char **argv) {
        struct camera_args a = {};
        int r = parse_args(argc, argv, &a);
        if (r > 0)
                return 0;       /* --help */
        if (r < 0) {
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
#ifdef IMPASTO_HAVE_CV
        return run_camera(&a);
#else
        log_error("calibrate camera: this impasto was built without OpenCV");
        return 1;
#endif
}
