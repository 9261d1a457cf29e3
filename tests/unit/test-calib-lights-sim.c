/* Dome light and radiometric calibration of the simulated rig, end to end (issue #8):
 * renders config/scenes/lights-spheres.cfg with config/plans/lights.cfg (noise on), runs
 * `impasto calibrate lights`, and a noisy copy of config/scenes/flat-white.cfg with
 * config/plans/photon-transfer.cfg, runs `impasto calibrate radiometric`; compares with
 * the simulator's truth/rig.json. About 2 minutes on 2 cores (rendering): labelled slow.
 * Figures and the reasons for the tolerances: docs/calibration-lights.md, "Simulated rig". */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include "json-util.h"
#include "rig.h"
#include "test.h"

#define IMPASTO IMPASTO_BINARY_DIR "/cli/impasto"
#define SPHERES "13,12,9,0;47,12,9,0;30,30,9,0"   /* lights-spheres.cfg: hemispheres */
#define DOME "30,20,0,500"

/* Measured when set (seed 8, noise on): sphere centres ≤ 0.017 mm off (biased towards the
 * image centre in x); directions from the dome centre RMS 0.86 mm, worst 1.49 mm at 500 mm;
 * free triangulation range +17 … +54 mm (flagged ill-conditioned: the spheres are 34 mm
 * apart, a 4° baseline); intensity with --dome worst 1.11 %; PTC gain +0.50 %, read noise
 * +0.2 %, black +0.007 DN. Issue #8 asks 1 mm: met on RMS, NOT by the worst light. */
#define SPHERE_TOL_MM      0.05
#define POS_RMS_MAX_MM     1.0         /* issue #8: 1 mm */
#define POS_WORST_MAX_MM   2.0
#define INTENSITY_REL_TOL  0.02        /* issue #8: 2 % */
#define GAIN_REL_TOL       0.03        /* issue #8: 3 % */
#define READ_NOISE_REL_TOL 0.10        /* issue #8: 10 % */
#define BLACK_TOL_DN       0.5         /* issue #8: 0.5 DN */

static int run(const char *cmd) {
        fprintf(stderr, "$ %s\n", cmd);
        int st = system(cmd);
        return WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static json_t *load(const char *dir, const char *name) {
        char path[1024];
        json_error_t jerr;
        snprintf(path, sizeof path, "%s/%s", dir, name);
        json_t *j = json_load_file(path, 0, &jerr);
        if (!j)
                fprintf(stderr, "%s: %s\n", path, jerr.text);
        return j;
}

static const struct imp_rig_light *truth_light(const struct imp_rig *t, int id) {
        for (int i = 0; i < t->n_lights; i++)
                if (t->lights[i].id == id)
                        return &t->lights[i];
        return NULL;
}

static double dist3(const double *a, const double *b) {
        return sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) + (a[2] - b[2]) * (a[2] - b[2]));
}

static void check_lights(const char *tmp) {
        char cmd[4096], path[1024];
        struct imp_error err = { 0 };
        struct imp_rig truth = { 0 }, est = { 0 };
        snprintf(path, sizeof path, "%s/lights/truth/rig.json", tmp);
        CHECK_OK(imp_rig_load(path, &truth, &err));

        /* free triangulation: the range is ill-conditioned and must say so */
        snprintf(cmd, sizeof cmd, "%s calibrate lights --set %s/lights --spheres \"%s\" --json > %s/free.json",
                 IMPASTO, tmp, SPHERES, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        json_t *j = load(tmp, "free.json");
        CHECK(j != NULL);
        const double true_c[3][3] = { { 13, 12, 0 }, { 47, 12, 0 }, { 30, 30, 0 } };
        json_t *js = json_object_get(j, "spheres");
        CHECK_INT_EQ(json_array_size(js), 3);
        for (size_t s = 0; s < json_array_size(js) && s < 3; s++) {
                double c[3];
                for (int k = 0; k < 3; k++)
                        c[k] = json_number_value(json_array_get(json_object_get(json_array_get(js, s), "centre_mm"), k));
                fprintf(stderr, "sphere %zu: (%.4f, %.4f, %.4f), %.4f mm off\n", s, c[0], c[1], c[2], dist3(c, true_c[s]));
                CHECK_LE(dist3(c, true_c[s]), SPHERE_TOL_MM);
        }
        json_t *jl = json_object_get(j, "lights");
        double rmin = INFINITY, rmax = -INFINITY;
        int flagged = 0;
        for (size_t i = 0; i < json_array_size(jl); i++) {
                json_t *l = json_array_get(jl, i);
                const struct imp_rig_light *t = truth_light(&truth, (int) json_integer_value(json_object_get(l, "id")));
                json_t *p = json_object_get(l, "pos_mm");
                if (!t || !p)
                        continue;
                double e[3], c[3] = { 30, 20, 0 };
                for (int k = 0; k < 3; k++)
                        e[k] = json_number_value(json_array_get(p, k));
                double dr = dist3(e, c) - dist3(t->pos_mm, c);
                rmin = fmin(rmin, dr);
                rmax = fmax(rmax, dr);
                flagged += json_is_true(json_object_get(json_object_get(l, "flags"), "ill_conditioned"));
        }
        fprintf(stderr, "free triangulation: range error %+.1f … %+.1f mm, %d of %zu flagged ill-conditioned\n",
                rmin, rmax, flagged, json_array_size(jl));
        CHECK_INT_EQ(flagged, (long long) json_array_size(jl));
        json_decref(j);

        /* with the dome radius: directions from the highlights, range from the dome */
        snprintf(cmd, sizeof cmd, "%s calibrate lights --set %s/lights --spheres \"%s\" --dome %s --json "
                 "--out %s/rig-lights.json --lp %s/lights.lp > %s/dome.json", IMPASTO, tmp, SPHERES, DOME, tmp, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(path, sizeof path, "%s/rig-lights.json", tmp);
        CHECK_OK(imp_rig_load(path, &est, &err));
        CHECK_INT_EQ(est.n_lights, truth.n_lights);
        double ss = 0, worst = 0, iworst = 0, isum = 0;
        int n = 0;
        for (int i = 0; i < est.n_lights; i++) {
                const struct imp_rig_light *t = truth_light(&truth, est.lights[i].id);
                if (!t)
                        continue;
                double d = dist3(est.lights[i].pos_mm, t->pos_mm), di = est.lights[i].intensity / t->intensity - 1;
                ss += d * d;
                worst = fmax(worst, d);
                iworst = fmax(iworst, fabs(di));
                isum += di;
                n++;
        }
        CHECK_INT_EQ(n, truth.n_lights);
        double rms = n ? sqrt(ss / n) : INFINITY;
        fprintf(stderr, "lights on the dome: position RMS %.3f mm, worst %.3f mm; intensity mean %+.3f %%, "
                "worst %.3f %%\n", rms, worst, n ? 100 * isum / n : NAN, 100 * iworst);
        CHECK_LE(rms, POS_RMS_MAX_MM);
        CHECK_LE(worst, POS_WORST_MAX_MM);
        CHECK_LE(iworst, INTENSITY_REL_TOL);

        FILE *f = fopen((snprintf(path, sizeof path, "%s/lights.lp", tmp), path), "r");
        CHECK(f != NULL);
        int count = 0, lines = 0;
        char line[256];
        if (f && fgets(line, sizeof line, f))
                count = atoi(line);
        while (f && fgets(line, sizeof line, f))
                lines++;
        if (f)
                fclose(f);
        CHECK_INT_EQ(count, truth.n_lights);
        CHECK_INT_EQ(lines, truth.n_lights);
        imp_rig_free(&est);
        imp_rig_free(&truth);
}

static void check_radiometric(const char *tmp) {
        char cmd[4096], src[1024], dst[1024];
        /* flat-white with the noise effect: the same scene, one word changed */
        snprintf(src, sizeof src, "%s/config/scenes/flat-white.cfg", IMPASTO_SOURCE_DIR);
        snprintf(dst, sizeof dst, "%s/flat-noise.cfg", tmp);
        snprintf(cmd, sizeof cmd, "sed 's/effects = \\[\"direct\"\\];/effects = [\"direct\", \"noise\"];/' %s > %s "
                 "&& grep -q '\"noise\"' %s", src, dst, dst);
        CHECK_INT_EQ(run(cmd), 0);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s --plan %s/config/plans/photon-transfer.cfg --out %s/ptc "
                 "--threads 2 --quiet && %s calibrate radiometric --set %s/ptc --json --out %s/rig-ptc.json > %s/ptc.json",
                 IMPASTO, dst, IMPASTO_SOURCE_DIR, tmp, IMPASTO, tmp, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        struct imp_error err = { 0 };
        struct imp_rig truth = { 0 }, est = { 0 };
        snprintf(src, sizeof src, "%s/ptc/truth/rig.json", tmp);
        snprintf(dst, sizeof dst, "%s/rig-ptc.json", tmp);
        CHECK_OK(imp_rig_load(src, &truth, &err));
        CHECK_OK(imp_rig_load(dst, &est, &err));
        if (truth.n_cameras < 1 || est.n_cameras < 1)
                return;
        const struct imp_sensor *t = &truth.cameras[0].sensor, *e = &est.cameras[0].sensor;
        fprintf(stderr, "photon transfer: gain %.4f e/DN (true %.4f, %+.2f %%), read noise %.3f e (true %.3f, "
                "%+.1f %%), black %.3f DN (true %.3f)\n", e->gain_e_per_dn, t->gain_e_per_dn,
                100 * (e->gain_e_per_dn / t->gain_e_per_dn - 1), e->read_noise_e, t->read_noise_e,
                100 * (e->read_noise_e / t->read_noise_e - 1), e->black_level_dn, t->black_level_dn);
        CHECK_NEAR(e->gain_e_per_dn / t->gain_e_per_dn, 1.0, GAIN_REL_TOL);
        CHECK_NEAR(e->read_noise_e / t->read_noise_e, 1.0, READ_NOISE_REL_TOL);
        CHECK_NEAR(e->black_level_dn, t->black_level_dn, BLACK_TOL_DN);
        imp_rig_free(&est);
        imp_rig_free(&truth);
}

int main(void) {
        struct stat st;
        if (stat(IMPASTO, &st) < 0)
                TEST_SKIP("%s not built", IMPASTO);
        const char *tmp = test_tmpdir();
        char cmd[4096];
        check_radiometric(tmp);
        snprintf(cmd, sizeof cmd, "%s sim render --scene %s/config/scenes/lights-spheres.cfg --plan "
                 "%s/config/plans/lights.cfg --out %s/lights --threads 2 --quiet", IMPASTO, IMPASTO_SOURCE_DIR,
                 IMPASTO_SOURCE_DIR, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        check_lights(tmp);
        return TEST_DONE();
}
