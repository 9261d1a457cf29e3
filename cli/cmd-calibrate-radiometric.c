/* `impasto calibrate radiometric`: the camera's photon transfer from a set of flat-field
 * pairs and dark frames, and the projector's gamma and black level from white, black and
 * phase-shift frames of a flat target, printed and written into a copy of a rig. The
 * numerics: pipeline/calib/calib-radiometric.c and calib-projector-gamma.c;
 * docs/calibration-lights.md. */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "calib-projector-gamma.h"
#include "calib-radiometric.h"
#include "calibrate-args.h"
#include "calibrate-ext.h"
#include "captureset.h"
#include "exit-codes.h"
#include "log.h"
#include "rig.h"

/* The photon transfer of one camera (--set). */
struct ptc_run {
        struct imp_ptc_result res;
        char camera[32];
        int n_levels, n_darks;
        struct imp_rig rig;           /* the set's */
};

/* The projector's gamma (--projector-set) and the set's rig. */
struct gamma_run {
        struct imp_projector_gamma g;
        char camera[32];
        struct imp_rig rig;           /* the set's */
};

/* A library error as an exit code: the input at fault, or a failure. */
static int exit_code(int r) {
        return r == -ENOMEM || r == -EDOM ? IMP_EXIT_FAILURE : IMP_EXIT_BAD_INPUT;
}

/* Opens set and finds its camera (NULL: the first): an exit code. */
static int open_set(const char *set, const char *camera, struct imp_captureset **ret_cs, const char **ret_cam) {
        struct imp_error err = {};
        if (imp_captureset_open(set, ret_cs, &err) < 0)
                return log_error("calibrate radiometric: %s", err.msg), IMP_EXIT_BAD_INPUT;
        const struct imp_rig *rig = imp_captureset_rig(*ret_cs);
        int ci = imp_cli_camera_index(rig, camera);
        if (ci < 0)
                return log_error("calibrate radiometric: no camera '%s' in %s/rig.json", camera ? camera : "(any)", set),
                       IMP_EXIT_BAD_INPUT;
        *ret_cam = rig->cameras[ci].name;
        return 0;
}

/* Photon transfer from the pairs and darks of `set` into *ret (rig copied: the caller frees
 * ret->rig). Returns an exit code. */
static int measure_ptc(const char *set, const char *camera, const int roi[4], struct ptc_run *ret) {
        struct imp_error err = {};
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        const char *cam;
        int r = open_set(set, camera, &cs, &cam);
        if (r != 0)
                return r;
        if ((r = imp_radiometric_ptc_measure(cs, cam, roi, &ret->res, &ret->n_levels, &ret->n_darks, &err)) < 0)
                return log_error("calibrate radiometric: %s", err.msg), exit_code(r);
        if (imp_rig_copy(imp_captureset_rig(cs), &ret->rig) < 0)
                return IMP_EXIT_FAILURE;
        snprintf(ret->camera, sizeof ret->camera, "%s", cam);
        return 0;
}

/* The projector's gamma from the white, black and phase frames of `set` into *ret (rig
 * copied: the caller frees ret->rig); its black level above sensor_black_dn (NAN: the set's
 * rig's camera black level). Returns an exit code. */
static int measure_gamma(const char *set, const char *camera, double sensor_black_dn, struct gamma_run *ret) {
        struct imp_error err = {};
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        const char *cam;
        int r = open_set(set, camera, &cs, &cam);
        if (r != 0)
                return r;
        if ((r = imp_projector_gamma_measure(cs, cam, sensor_black_dn, &ret->g, &err)) < 0)
                return log_error("calibrate radiometric: %s", err.msg), exit_code(r);
        if (imp_rig_copy(imp_captureset_rig(cs), &ret->rig) < 0)
                return IMP_EXIT_FAILURE;
        snprintf(ret->camera, sizeof ret->camera, "%s", cam);
        return 0;
}

static void usage_radiometric(FILE *f) {
        fprintf(f, "usage: impasto calibrate radiometric (--set DIR | --projector-set DIR | both) [--camera NAME]\n"
                   "                                     [--roi X,Y,W,H] [--json] [--out RIG.json [--rig BASE.json]]\n"
                   "  --set:     the camera's photon transfer: pairs of equal frames (same exposure, gain,\n"
                   "             light, pattern) at rising exposures, and dark frames (those at the\n"
                   "             shortest dark exposure are used); --roi limits it to a window\n"
                   "  --projector-set: the projector's gamma: a flat diffuse target lit by the projector,\n"
                   "             with white, black and N >= 3 phase-shift frames (config/plans/\n"
                   "             projector-gamma.cfg); the longest period's steps on one axis, at the\n"
                   "             longest exposure whose white frame does not clip; and its black level\n"
                   "             (black / white above the sensor's black level: --set's, else the set's)\n"
                   "  --out:     a copy of the projector set's rig (else the set's) with the camera's sensor\n"
                   "             and the projector's gamma and black level replaced; with --rig, a copy of BASE.json\n"
                   "             instead (its camera of the same name gets the sensor)\n"
                   "exit status: 0 done (flags and sigmas say how far to trust it), 1 failure, 2 usage,\n"
                   "             3 bad input (a set missing the frames it needs, mismatched frames),\n"
                   "             6 the projector's gamma not determined (its root outside [0.3, 5]):\n"
                   "             reported with the flag at_bound; --out is written with the base's gamma\n");
}

static json_t *gamma_to_json(const struct imp_projector_gamma *g) {
        json_t *flags = json_array();
        if (g->status)
                json_array_append_new(flags, json_string("at_bound"));
        if (g->blocks < IMP_GAMMA_MIN_BLOCKS)
                json_array_append_new(flags, json_string("few_blocks"));
        return json_pack("{s:f, s:f, s:f, s:f, s:i, s:i, s:f, s:s, s:f, s:f, s:i, s:f, s:i, s:i, s:o}", "gamma",
                         g->gamma, "gamma_sigma", g->gamma_sigma, "black_level", g->black_level, "sensor_black_dn",
                         g->sensor_black_dn, "pixels", g->pixels, "steps", g->steps, "period_px",
                         g->period_px, "axis", g->axis ? "y" : "x", "exposure_us", g->exposure_us, "gain_db",
                         g->gain_db, "bin", g->bin, "min_contrast_dn", g->min_contrast_dn, "blocks", g->blocks,
                         "clipped_pixels", g->clipped_px, "flags", flags);
}

static void print_ptc(const struct ptc_run *p) {
        const struct imp_ptc_result *res = &p->res;
        printf("%s (%d levels, %d darks): black %.3f DN, gain %.4f ± %.4f e/DN (0 dB), read noise %.3f e "
               "(dark pair %.3f, intercept %.3f), full well %.0f e, nonlinearity %.3f %%%s%s\n",
               p->camera, p->n_levels, p->n_darks, res->sensor.black_level_dn, res->sensor.gain_e_per_dn,
               res->gain_sigma_e_per_dn, res->sensor.read_noise_e, res->read_noise_dark_e, res->read_noise_fit_e,
               res->sensor.full_well_e, res->max_nonlinearity_pct, res->flags & IMP_PTC_FEW_LEVELS ? ", FEW LEVELS" : "",
               res->flags & IMP_PTC_SATURATION_FOUND ? "" : ", saturation not reached (full well is a lower bound)");
}

static void print_gamma(const struct gamma_run *run) {
        const struct imp_projector_gamma *g = &run->g;
        char sigma[64] = "σ not measured";
        if (g->blocks >= IMP_GAMMA_MIN_BLOCKS)
                snprintf(sigma, sizeof sigma, "± %.4f", g->gamma_sigma);
        printf("projector %s (camera %s, %d phase steps of period %g px along %s, %g us): gamma %.4f %s "
               "(%d blocks) from %d pixels in %d x %d bins%s; black level %.5f of white\n", run->rig.projector.name,
               run->camera, g->steps, g->period_px, g->axis ? "y" : "x", g->exposure_us, g->gamma, sigma, g->blocks,
               g->pixels, g->bin, g->bin, g->status ? ", AT THE SEARCH BOUND (not determined)" : "", g->black_level);
}

/* Writes the rig: BASE (else the projector set's, else the photon-transfer set's) with the
 * estimates put in. Returns an exit code. */
static int write_rig(const char *out, const char *base, const struct ptc_run *ptc, const struct gamma_run *gm) {
        struct imp_error err = {};
        struct imp_rig copy;
        const char *from = base ? base : "the set's rig";
        if (base) {
                if (imp_rig_load(base, &copy, &err) < 0)
                        return log_error("calibrate radiometric: %s", err.msg), IMP_EXIT_BAD_INPUT;
        } else if (imp_rig_copy(gm ? &gm->rig : &ptc->rig, &copy) < 0)
                return IMP_EXIT_FAILURE;
        int ret = IMP_EXIT_BAD_INPUT;
        if (ptc) {
                int bi = imp_cli_camera_index(&copy, ptc->camera);
                if (bi < 0) {
                        log_error("calibrate radiometric: no camera '%s' in %s", ptc->camera, from);
                        goto out;
                }
                struct imp_sensor *s = &copy.cameras[bi].sensor;
                s->black_level_dn = ptc->res.sensor.black_level_dn;
                s->gain_e_per_dn = ptc->res.sensor.gain_e_per_dn;
                s->read_noise_e = ptc->res.sensor.read_noise_e;
                if (ptc->res.flags & IMP_PTC_SATURATION_FOUND)
                        s->full_well_e = ptc->res.sensor.full_well_e;
        }
        if (gm) {
                if (!copy.has_projector) {
                        log_error("calibrate radiometric: no projector in %s", from);
                        goto out;
                }
                if (gm->g.status == 0) {
                        copy.projector.gamma = gm->g.gamma;
                        copy.projector.black_level = gm->g.black_level;
                } else
                        log_warning("the projector's gamma is not determined: projector.gamma left at %g in %s",
                                    copy.projector.gamma, out);
        }
        int r = imp_rig_save(out, &copy, &err);
        if (r < 0) {
                log_error_errno(r, "calibrate radiometric: %s", err.msg);
                ret = IMP_EXIT_FAILURE;
        } else
                ret = 0;
out:
        imp_rig_free(&copy);
        return ret;
}

static int run_radiometric(const char *set, const char *pset, const char *camera, const int roi[4], bool json,
                           const char *out, const char *base) {
        struct ptc_run ptc = {};
        struct gamma_run gm = {};
        int ret;
        if (set && (ret = measure_ptc(set, camera, roi, &ptc)) != 0)
                return ret;
        if (pset && (ret = measure_gamma(pset, camera, set ? ptc.res.sensor.black_level_dn : NAN, &gm)) != 0) {
                if (set)
                        imp_rig_free(&ptc.rig);
                return ret;
        }
        if (json) {
                json_t *j = set ? imp_radiometric_ptc_to_json(&ptc.res) : json_object();
                if (pset)
                        json_object_set_new(j, "projector", gamma_to_json(&gm.g));
                json_dumpf(j, stdout, JSON_INDENT(2) | JSON_REAL_PRECISION(10));
                fputc('\n', stdout);
                json_decref(j);
        } else {
                if (set)
                        print_ptc(&ptc);
                if (pset)
                        print_gamma(&gm);
        }
        if (pset && gm.g.status)
                log_warning("%s: the projector's gamma lies outside [0.3, 5] (the search's bound %g): not "
                            "determined; check that the set's frames are what their records say", pset, gm.g.gamma);
        else if (pset && gm.g.blocks < IMP_GAMMA_MIN_BLOCKS)
                log_warning("%s: only %d blocks with enough contrast: gamma_sigma not measured", pset, gm.g.blocks);
        if (pset && gm.g.clipped_px > 0)
                log_warning("%s: %d pixels clipped at %g us, left out", pset, gm.g.clipped_px, gm.g.exposure_us);
        ret = out ? write_rig(out, base, set ? &ptc : NULL, pset ? &gm : NULL) : 0;
        if (ret == 0 && pset && gm.g.status)
                ret = IMP_EXIT_UNDETERMINED;
        if (set)
                imp_rig_free(&ptc.rig);
        if (pset)
                imp_rig_free(&gm.rig);
        return ret;
}

int imp_calibrate_radiometric_main(int argc, char **argv) {
        const char *set = NULL, *pset = NULL, *camera = NULL, *out = NULL, *base = NULL;
        int roi[4] = { 0, 0, 0, 0 };
        bool json = false;
        for (int i = 1; i < argc; i++) {
                const char *o = argv[i], *val = i + 1 < argc ? argv[i + 1] : NULL;
                if (!strcmp(o, "--help") || !strcmp(o, "-h"))
                        return usage_radiometric(stdout), 0;
                if (!strcmp(o, "--json")) {
                        json = true;
                        continue;
                }
                if (!val) {
                        log_error("%s: unknown option or missing value", o);
                        return usage_radiometric(stderr), IMP_EXIT_USAGE;
                }
                i++;
                if (!strcmp(o, "--set"))
                        set = val;
                else if (!strcmp(o, "--projector-set"))
                        pset = val;
                else if (!strcmp(o, "--camera"))
                        camera = val;
                else if (!strcmp(o, "--out"))
                        out = val;
                else if (!strcmp(o, "--rig"))
                        base = val;
                else if (!strcmp(o, "--roi")) {
                        double v[4];
                        int n;
                        if (imp_cli_parse_list(o, val, v, 4, 4, &n) < 0)
                                return IMP_EXIT_USAGE;
                        for (int k = 0; k < 4; k++)
                                roi[k] = (int) v[k];
                        if (roi[0] < 0 || roi[1] < 0 || roi[2] <= 0 || roi[3] <= 0) {
                                log_error("--roi: expected X, Y >= 0 and W, H > 0");
                                return IMP_EXIT_USAGE;
                        }
                } else {
                        log_error("unknown option '%s'", o);
                        return usage_radiometric(stderr), IMP_EXIT_USAGE;
                }
        }
        if (!set && !pset) {
                log_error("calibrate radiometric: give --set, --projector-set or both");
                return usage_radiometric(stderr), IMP_EXIT_USAGE;
        }
        if (base && !out) {
                log_error("calibrate radiometric: --rig is the base of --out: give --out too");
                return usage_radiometric(stderr), IMP_EXIT_USAGE;
        }
        return run_radiometric(set, pset, camera, roi, json, out, base);
}
