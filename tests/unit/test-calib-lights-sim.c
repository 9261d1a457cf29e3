/* Dome light and radiometric calibration of the simulated rig, end to end:
 * renders the light calibration target config/scenes/lights-target.cfg and the same board
 * raised 20 and 40 mm (lights-target-mid.cfg, lights-target-raised.cfg) with
 * config/plans/lights.cfg (noise on), runs `impasto calibrate lights` with sphere
 * detection (no positions given), per-light triangulation (--no-joint), the joint refinement
 * of lights and mirror centres (the default), free and constrained to the dome; and a noisy copy of
 * config/scenes/flat-white.cfg with config/plans/photon-transfer.cfg through `impasto
 * calibrate radiometric`; compares with the simulator's truth/rig.json. About 8 minutes on
 * 2 loaded cores (rendering 3 × 60 frames): labelled slow.
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
#define DETECT "--sphere-radius 10 --sphere-cut 7"   /* lights-target*.cfg: caps of r 10, centre 7 under */
#define DOME "30,20,0,500"
#define N_MIRRORS 5

/* Measured when set (seed 8/10/9, noise on, 48 lights): mirror centres from the silhouettes
 * ≤ 1.7 µm off (RMS 0.75 µm); per-light triangulation from the three captures RMS 0.42 mm,
 * worst 0.92 mm, predicted σ (worst direction) 0.40–0.58 mm, mean Mahalanobis² 1.9 (3
 * expected: σ a little conservative); joint refinement: centres RMS 0.38 µm, worst 0.70 µm,
 * lights RMS 0.28 mm, worst 0.71 mm, σ 0.22–0.33 mm, mean Mahalanobis² 2.2, worst 9.8; on the
 * dome RMS 0.021 mm, worst 0.047 mm; one capture alone: 14 of 48 lights flagged
 * ill-conditioned, all within 3σ. Intensity worst ~0.07 %. Issue #8 asks 1 mm.
 * With the demo's 56-light dome (the 80° ring added, 2026-11-25): triangulation RMS 0.49 mm,
 * worst 1.07 mm (light 47, 60° ring, σ 0.41 mm: 2.6σ; every light within 3σ by eᵀC⁻¹e);
 * joint RMS 0.28 mm, worst 0.68 mm; on the dome RMS 0.025 mm, worst 0.059 mm. The per-light
 * triangulation's worst of 56 lands near 1 mm by chance (σ up to 0.54 mm), so it is held to
 * 1.2 mm and each light to its own 3σ; the 1 mm is held by the default (joint) and the
 * dome-constrained positions. */
#define MIRROR_TOL_MM      0.005
#define POS_WORST_MAX_MM   1.2         /* free triangulation (--no-joint), every light; see above */
#define JOINT_WORST_MAX_MM 0.8         /* joint refinement: 0.71 measured, 0.92 without */
#define JOINT_RMS_MAX_MM   0.35        /* 0.28 measured, 0.42 without */
#define CHI2_3DOF_3SIGMA   14.2        /* e ᵀC⁻¹e of 3 dof at 99.73 % */
#define DOME_WORST_MAX_MM  0.25        /* constrained: better still */
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

static bool json_vec(const json_t *a, double *v, int n) {
        if (json_array_size(a) != (size_t) n)
                return false;
        for (int k = 0; k < n; k++)
                v[k] = json_number_value(json_array_get(a, k));
        return true;
}

/* e ᵀ C⁻¹ e for a 3×3 covariance (cofactors). */
static double mahalanobis2(const double e[3], const double C[9]) {
        double a = C[0], b = C[1], c = C[2], d = C[3], f = C[4], g = C[5], h = C[6], i = C[7], k = C[8];
        double det = a * (f * k - g * i) - b * (d * k - g * h) + c * (d * i - f * h);
        double inv[9] = { (f * k - g * i) / det, (c * i - b * k) / det, (b * g - c * f) / det,
                          (g * h - d * k) / det, (a * k - c * h) / det, (c * d - a * g) / det,
                          (d * i - f * h) / det, (b * h - a * i) / det, (a * f - b * d) / det };
        double m = 0;
        for (int r = 0; r < 3; r++)
                for (int s = 0; s < 3; s++)
                        m += e[r] * inv[r * 3 + s] * e[s];
        return m;
}

struct light_stats {
        int n, flagged, within_3sigma, within_m2;
        double rms, worst, sigma_max, mean_m2, worst_m2;
};

/* Errors of the lights of a report (its "dome" member when `dome`) against the truth; the
 * dome estimate's covariance is rank 2 (no range error): its Mahalanobis distance is taken
 * with unit variance added along the radial direction. */
static struct light_stats light_errors(const json_t *report, const struct imp_rig *truth, bool dome) {
        struct light_stats st = { 0 };
        const double dc[3] = { 30, 20, 0 };
        double ss = 0, sm = 0;
        const json_t *jl = json_object_get(report, "lights");
        for (size_t i = 0; i < json_array_size(jl); i++) {
                const json_t *l = json_array_get(jl, i), *e = dome ? json_object_get(l, "dome") : l;
                const struct imp_rig_light *t = truth_light(truth, (int) json_integer_value(json_object_get(l, "id")));
                double p[3], C[9];
                if (!t || !e || !json_vec(json_object_get(e, "pos_mm"), p, 3) || !json_vec(json_object_get(e, "cov_mm2"), C, 9))
                        continue;
                double err[3] = { p[0] - t->pos_mm[0], p[1] - t->pos_mm[1], p[2] - t->pos_mm[2] };
                double d = dist3(p, t->pos_mm), sig = json_number_value(json_object_get(e, "sigma_mm"));
                if (dome) {
                        double r[3] = { p[0] - dc[0], p[1] - dc[1], p[2] - dc[2] }, lr = dist3(p, dc);
                        for (int a = 0; a < 3; a++)
                                for (int b = 0; b < 3; b++)
                                        C[a * 3 + b] += r[a] * r[b] / (lr * lr);
                }
                double m2 = mahalanobis2(err, C);
                st.n++;
                ss += d * d;
                sm += m2;
                st.worst = fmax(st.worst, d);
                st.sigma_max = fmax(st.sigma_max, sig);
                st.within_3sigma += d <= 3 * sig;
                st.within_m2 += m2 < CHI2_3DOF_3SIGMA;
                st.worst_m2 = fmax(st.worst_m2, m2);
                st.flagged += json_is_true(json_object_get(json_object_get(l, "flags"), "ill_conditioned"));
        }
        st.rms = st.n ? sqrt(ss / st.n) : INFINITY;
        st.mean_m2 = st.n ? sm / st.n : INFINITY;
        fprintf(stderr, "%s: %d lights, RMS %.3f mm, worst %.3f mm; predicted σ max %.3f mm, mean Mahalanobis² %.2f "
                "(%d expected), worst %.1f, %d within 3σ, %d flagged ill-conditioned\n", dome ? "on the dome" : "free", st.n,
                st.rms, st.worst, st.sigma_max, st.mean_m2, dome ? 2 : 3, st.worst_m2, st.within_3sigma, st.flagged);
        return st;
}

static void check_lights(const char *tmp) {
        char cmd[4096], path[1024], sets[1024];
        struct imp_error err = { 0 };
        struct imp_rig truth = { 0 }, est = { 0 };
        snprintf(path, sizeof path, "%s/target/truth/rig.json", tmp);
        CHECK_OK(imp_rig_load(path, &truth, &err));
        snprintf(sets, sizeof sets, "--set %s/target@0 --set %s/target-mid@20 --set %s/target-raised@40", tmp, tmp, tmp);

        /* three captures, per-light triangulation (--no-joint): every light within 1 mm, σ honest */
        snprintf(cmd, sizeof cmd, "%s calibrate lights %s %s --no-joint --json > %s/free.json", IMPASTO, sets, DETECT, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        json_t *j = load(tmp, "free.json");
        CHECK(j != NULL);
        const double mirrors[N_MIRRORS][2] = { { 8.7, 8.7 }, { 51.3, 8.7 }, { 30, 20 }, { 8.7, 31.3 }, { 51.3, 31.3 } };
        const double board_z[3] = { 0, 20, 40 };
        json_t *js_ = json_object_get(j, "spheres");
        CHECK_INT_EQ(json_array_size(js_), 3 * N_MIRRORS);
        double worst_c = 0;
        for (size_t s = 0; s < json_array_size(js_); s++) {
                double c[3], best = INFINITY;
                if (!json_vec(json_object_get(json_array_get(js_, s), "centre_mm"), c, 3))
                        continue;
                for (int m = 0; m < N_MIRRORS; m++)
                        for (int b = 0; b < 3; b++) {
                                double t[3] = { mirrors[m][0], mirrors[m][1], board_z[b] - 7 };
                                best = fmin(best, dist3(c, t));
                        }
                worst_c = fmax(worst_c, best);
        }
        fprintf(stderr, "mirror centres: worst %.5f mm off\n", worst_c);
        CHECK_LE(worst_c, MIRROR_TOL_MM);
        struct light_stats fs = light_errors(j, &truth, false);
        CHECK_INT_EQ(fs.n, truth.n_lights);
        CHECK_LE(fs.worst, POS_WORST_MAX_MM);
        CHECK_INT_EQ(fs.flagged, 0);
        /* predicted σ consistent with the errors: not optimistic (mean e ᵀC⁻¹e near 3, not ≫),
         * not uselessly pessimistic, and every light within 3σ of the truth */
        CHECK_LE(fs.mean_m2, 4.5);
        CHECK_GE(fs.mean_m2, 0.5);
        CHECK_INT_EQ(fs.within_3sigma, fs.n);
        CHECK(json_object_get(j, "joint") == NULL);
        json_decref(j);

        /* the same with the joint refinement (the default): the mirror centres move towards the
         * truth, and the lights with them; its σ stays honest */
        snprintf(cmd, sizeof cmd, "%s calibrate lights %s %s --json > %s/joint.json", IMPASTO, sets, DETECT, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        j = load(tmp, "joint.json");
        CHECK(j != NULL);
        struct light_stats js = light_errors(j, &truth, false);
        CHECK_INT_EQ(js.n, truth.n_lights);
        CHECK_LE(js.worst, JOINT_WORST_MAX_MM);
        CHECK_LE(js.rms, JOINT_RMS_MAX_MM);
        CHECK(js.rms < 0.8 * fs.rms);
        CHECK_INT_EQ(js.flagged, 0);
        CHECK_LE(js.mean_m2, 4.5);
        CHECK_GE(js.mean_m2, 0.5);
        CHECK_INT_EQ(js.within_m2, js.n);
        const json_t *jj = json_object_get(j, "joint");
        CHECK(jj != NULL);
        CHECK_INT_EQ(json_integer_value(json_object_get(jj, "highlights")), 3 * N_MIRRORS * truth.n_lights);
        CHECK_INT_EQ(json_integer_value(json_object_get(jj, "outliers")), 0);
        CHECK_LE(json_number_value(json_object_get(jj, "cond")), 1e4);
        CHECK(!json_is_true(json_object_get(json_object_get(jj, "flags"), "weak_centres")));
        CHECK_LE(json_number_value(json_object_get(jj, "rms_px_after")), json_number_value(json_object_get(jj, "rms_px_before")));
        /* every refined centre, RMS against the truth, better than the silhouettes' */
        double ss_sil = 0, ss_joint = 0;
        js_ = json_object_get(j, "spheres");
        for (size_t s = 0; s < json_array_size(js_); s++) {
                double c[3], cj[3], best = INFINITY, bestj = INFINITY;
                const json_t *e = json_array_get(js_, s);
                if (!json_vec(json_object_get(e, "centre_mm"), c, 3) || !json_vec(json_object_get(e, "joint_centre_mm"), cj, 3))
                        continue;
                for (int m = 0; m < N_MIRRORS; m++)
                        for (int b = 0; b < 3; b++) {
                                double t[3] = { mirrors[m][0], mirrors[m][1], board_z[b] - 7 };
                                best = fmin(best, dist3(c, t));
                                bestj = fmin(bestj, dist3(cj, t));
                        }
                ss_sil += best * best;
                ss_joint += bestj * bestj;
        }
        fprintf(stderr, "mirror centres: silhouettes RMS %.3f µm, joint RMS %.3f µm\n", 1000 * sqrt(ss_sil / (3 * N_MIRRORS)),
                1000 * sqrt(ss_joint / (3 * N_MIRRORS)));
        CHECK(ss_joint > 0);
        CHECK_LE(ss_joint, 0.7 * 0.7 * ss_sil);   /* measured 0.50× */
        json_decref(j);

        /* one capture alone: the mirrors are only 23–43 mm apart; lights whose rays are nearly
         * parallel are flagged with the prior's σ, and no light is confidently wrong */
        snprintf(cmd, sizeof cmd, "%s calibrate lights --set %s/target %s --json > %s/one.json 2> %s/one.err", IMPASTO,
                 tmp, DETECT, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        j = load(tmp, "one.json");
        CHECK(j != NULL);
        struct light_stats os = light_errors(j, &truth, false);
        CHECK_GE(os.flagged, 1);
        CHECK_INT_EQ(os.within_3sigma, os.n);
        CHECK(os.worst > js.worst);
        json_decref(j);
        snprintf(cmd, sizeof cmd, "grep -q 'ill-conditioned' %s/one.err", tmp);
        CHECK_INT_EQ(run(cmd), 0);

        /* constrained to the dome: better still; rig.json and an .lp written. --rig BASE (the
         * demo's calibration chain): the camera from BASE and rig.json a copy of BASE with the
         * lights replaced, matched by id — BASE is the truth with its lights in reverse order
         * and moved, and a marker gamma on the projector. */
        struct imp_rig base = { 0 };
        CHECK_OK(imp_rig_copy(&truth, &base));
        for (int i = 0; i < base.n_lights / 2; i++) {
                struct imp_rig_light tmp_l = base.lights[i];
                base.lights[i] = base.lights[base.n_lights - 1 - i];
                base.lights[base.n_lights - 1 - i] = tmp_l;
        }
        for (int i = 0; i < base.n_lights; i++)
                base.lights[i].pos_mm[2] += 100;
        base.projector.gamma = 2.9;
        snprintf(path, sizeof path, "%s/base.json", tmp);
        CHECK_OK(imp_rig_save(path, &base, &err));
        snprintf(cmd, sizeof cmd, "%s calibrate lights %s %s --dome %s --rig %s/base.json --json --out %s/rig-lights.json "
                 "--lp %s/lights.lp > %s/dome.json", IMPASTO, sets, DETECT, DOME, tmp, tmp, tmp, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        j = load(tmp, "dome.json");
        CHECK(j != NULL);
        struct light_stats ds = light_errors(j, &truth, true);
        CHECK_INT_EQ(ds.n, truth.n_lights);
        CHECK_LE(ds.worst, DOME_WORST_MAX_MM);
        CHECK(ds.worst < fs.worst);
        CHECK_INT_EQ(ds.within_3sigma, ds.n);
        json_decref(j);
        snprintf(path, sizeof path, "%s/rig-lights.json", tmp);
        CHECK_OK(imp_rig_load(path, &est, &err));
        CHECK_INT_EQ(est.n_lights, truth.n_lights);
        CHECK(est.has_projector && est.projector.gamma == 2.9);          /* BASE's, not the sets' */
        CHECK_INT_EQ(est.n_lights > 0 ? est.lights[0].id : -1, base.n_lights > 0 ? base.lights[0].id : -2);
        imp_rig_free(&base);
        double worst = 0, iworst = 0, isum = 0;
        int n = 0;
        for (int i = 0; i < est.n_lights; i++) {
                const struct imp_rig_light *t = truth_light(&truth, est.lights[i].id);
                if (!t)
                        continue;
                double di = est.lights[i].intensity / t->intensity - 1;
                worst = fmax(worst, dist3(est.lights[i].pos_mm, t->pos_mm));
                iworst = fmax(iworst, fabs(di));
                isum += di;
                n++;
        }
        CHECK_INT_EQ(n, truth.n_lights);
        fprintf(stderr, "rig.json: position worst %.3f mm; intensity mean %+.3f %%, worst %.3f %%\n", worst,
                n ? 100 * isum / n : NAN, 100 * iworst);
        CHECK_LE(worst, DOME_WORST_MAX_MM);
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
        /* .lp import: the directions put back on the dome give the same positions */
        snprintf(cmd, sizeof cmd, "%s calibrate lights --import-lp %s/lights.lp --rig %s/target/truth/rig.json --dome "
                 "%s --out %s/rig-imported.json", IMPASTO, tmp, tmp, DOME, tmp);
        CHECK_INT_EQ(run(cmd), 0);
        struct imp_rig imp = { 0 };
        snprintf(path, sizeof path, "%s/rig-imported.json", tmp);
        CHECK_OK(imp_rig_load(path, &imp, &err));
        CHECK_INT_EQ(imp.n_lights, est.n_lights);
        double wimp = 0;
        for (int i = 0; i < imp.n_lights && i < est.n_lights; i++)
                wimp = fmax(wimp, dist3(imp.lights[i].pos_mm, truth.lights[i].pos_mm));
        fprintf(stderr, ".lp import (standard directions, put on the dome): worst %.3f mm from the truth\n", wimp);
        CHECK_LE(wimp, 1.0);
        imp_rig_free(&imp);
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
        const char *scenes[3][2] = { { "lights-target", "target" }, { "lights-target-mid", "target-mid" },
                                     { "lights-target-raised", "target-raised" } };
        for (int k = 0; k < 3; k++) {
                snprintf(cmd, sizeof cmd, "%s sim render --scene %s/config/scenes/%s.cfg --plan %s/config/plans/lights.cfg "
                         "--out %s/%s --threads 2 --quiet", IMPASTO, IMPASTO_SOURCE_DIR, scenes[k][0], IMPASTO_SOURCE_DIR,
                         tmp, scenes[k][1]);
                CHECK_INT_EQ(run(cmd), 0);
        }
        check_lights(tmp);
        return TEST_DONE();
}
