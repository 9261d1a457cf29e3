/* Simulator radiometry against closed forms: a flat white Lambertian canvas under one
 * dome light gives V = E cos θ with E = intensity (1000/d)² (tolerance 0.5 %), under the
 * projector's white pattern V = intensity (1000/d)² cos θ (0.5 %), and the sensor maps V to
 * DN = V quantum_scale t / gain + black level (±1 DN) with noise off. */
#include "render.h"
#include "scene.h"
#include "test.h"

#define REL_TOL 0.005

static double analytic_light(const struct imp_rig_light *L, const double p[3], const double n[3]) {
        double l[3] = { L->pos_mm[0] - p[0], L->pos_mm[1] - p[1], L->pos_mm[2] - p[2] };
        double d = sqrt(l[0] * l[0] + l[1] * l[1] + l[2] * l[2]);
        double cosl = (l[0] * n[0] + l[1] * n[1] + l[2] * n[2]) / d;
        double prof = 1;
        if (L->profile_exp > 0)
                prof = pow(-(L->axis[0] * l[0] + L->axis[1] * l[1] + L->axis[2] * l[2]) / d, L->profile_exp);
        return L->intensity * (1000.0 / d) * (1000.0 / d) * prof * cosl;
}

int main(void) {
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        CHECK_OK(imp_scene_load(IMPASTO_SOURCE_DIR "/config/scenes/flat-white.cfg", &scene, &err));
        if (!scene) {
                fprintf(stderr, "%s\n", err.msg);
                return 1;
        }
        CHECK_OK(imp_scene_set_effect(scene, IMP_FX_PROJECTOR, true));
        _cleanup_(imp_render_freep) struct imp_render *r = NULL;
        CHECK_OK(imp_render_new(scene, &r, &err));
        const struct imp_rig *rig = imp_render_rig(r);
        const struct imp_sensor *sn = &rig->cameras[0].sensor;
        int w = rig->cameras[0].model.width, h = rig->cameras[0].model.height;

        /* every hit pixel under two lights of different azimuth */
        for (int li = 0; li < 8; li += 3) {
                struct imp_frame_record rec = { .step = "dome", .camera = "cam0", .light = rig->lights[li].id,
                                                .exposure_us = 10000 };
                _cleanup_image_ struct imp_image *rad = NULL, *dn = NULL;
                CHECK_OK(imp_render_radiance(r, &rec, &rad, &err));
                CHECK_OK(imp_render_frame(r, &rec, &dn, &err));
                double worst = 0, worst_dn = 0;
                int hits = 0;
                for (int y = 0; y < h; y++)
                        for (int x = 0; x < w; x++) {
                                double p[3], n[3];
                                if (imp_render_view_point(r, 0, x, y, p, n) < 0)
                                        continue;
                                hits++;
                                double nz[3] = { 0, 0, 1 };
                                double V = imp_image_get(rad, x, y, 0), Va = analytic_light(&rig->lights[li], p, nz);
                                worst = fmax(worst, fabs(V / Va - 1));
                                double dn_a = Va * sn->quantum_scale * rec.exposure_us * 1e-6 / sn->gain_e_per_dn +
                                              sn->black_level_dn;
                                worst_dn = fmax(worst_dn, fabs(imp_image_get(dn, x, y, 0) - dn_a));
                        }
                CHECK_INT_GE(hits, w * h * 9 / 10);
                CHECK_LE(worst, REL_TOL);
                CHECK_LE(worst_dn, 1.0 + REL_TOL * 4096);
                fprintf(stderr, "light %d: worst relative error %.2e, worst DN error %.2f over %d pixels\n", li,
                        worst, worst_dn, hits);
        }

        /* projector white: E = intensity (1000/d)² (black + (1 - black) 1^gamma) = intensity (1000/d)² */
        struct imp_frame_record rec = { .step = "structured-light", .camera = "cam0", .light = -1,
                                        .pattern = { .kind = IMP_PAT_WHITE }, .exposure_us = 10000 };
        _cleanup_image_ struct imp_image *rad = NULL;
        CHECK_OK(imp_render_radiance(r, &rec, &rad, &err));
        double Cp[3], worst = 0;
        imp_pinhole_centre(&rig->projector.model, Cp);
        int lit = 0;
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        double p[3], n[3];
                        if (imp_render_view_point(r, 0, x, y, p, n) < 0 || imp_image_get(rad, x, y, 0) <= 0)
                                continue;
                        struct imp_rig_light pl = { .pos_mm = { Cp[0], Cp[1], Cp[2] }, .intensity = rig->projector.intensity };
                        double nz[3] = { 0, 0, 1 };
                        worst = fmax(worst, fabs(imp_image_get(rad, x, y, 0) / analytic_light(&pl, p, nz) - 1));
                        lit++;
                }
        CHECK_INT_GE(lit, w * h / 2);
        CHECK_LE(worst, REL_TOL);
        fprintf(stderr, "projector white: worst relative error %.2e over %d pixels\n", worst, lit);

        /* black pattern emits the black level only */
        rec.pattern.kind = IMP_PAT_BLACK;
        _cleanup_image_ struct imp_image *radb = NULL;
        CHECK_OK(imp_render_radiance(r, &rec, &radb, &err));
        double ratio = imp_image_get(radb, w / 2, h / 2, 0) / imp_image_get(rad, w / 2, h / 2, 0);
        CHECK_NEAR(ratio, rig->projector.black_level, 1e-6);
        return TEST_DONE();
}
