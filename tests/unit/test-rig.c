/* Rig model: known projections, project → ray round trip under distortion (to 1e-6 px),
 * look_at's frame (x right, y down, z forward), rig.json round trip and its messages. */
#include <errno.h>
#include <math.h>
#include "json-util.h"
#include "rig.h"
#include "test.h"

static struct imp_pinhole frontal(void) {
        struct imp_pinhole m = { .width = 640, .height = 480, .fx = 800, .fy = 810, .cx = 320.5,
                                 .cy = 239.5 };
        m.R[0] = m.R[4] = m.R[8] = 1;
        return m;
}

static void test_known_projection(void) {
        struct imp_pinhole m = frontal();
        m.t[2] = 1000;   /* world origin 1 m in front of the camera */
        double px[2];
        CHECK(imp_pinhole_project(&m, (double[]){ 0, 0, 0 }, px));
        CHECK_NEAR(px[0], 320.5, 1e-12);
        CHECK_NEAR(px[1], 239.5, 1e-12);
        CHECK(imp_pinhole_project(&m, (double[]){ 100, -50, 0 }, px));
        CHECK_NEAR(px[0], 320.5 + 800 * 0.1, 1e-9);
        CHECK_NEAR(px[1], 239.5 - 810 * 0.05, 1e-9);
        CHECK(!imp_pinhole_project(&m, (double[]){ 0, 0, -1000 }, px));   /* at the centre */
        CHECK(!imp_pinhole_project(&m, (double[]){ 0, 0, -2000 }, px));   /* behind */

        /* Distortion, values checked by hand against OpenCV's formula: x=0.1, y=-0.05,
         * r2=0.0125, radial = 1 + 0.1 r2 = 1.00125, xd = 0.1·radial + 2·p1·x·y + p2(r2+2x²). */
        m.k1 = 0.1;
        m.p1 = 0.001;
        m.p2 = -0.002;
        double x = 0.1, y = -0.05, r2 = x * x + y * y, rad = 1 + 0.1 * r2;
        double xd = x * rad + 2 * 0.001 * x * y - 0.002 * (r2 + 2 * x * x);
        double yd = y * rad + 0.001 * (r2 + 2 * y * y) + 2 * -0.002 * x * y;
        CHECK(imp_pinhole_project(&m, (double[]){ 100, -50, 0 }, px));
        CHECK_NEAR(px[0], 320.5 + 800 * xd, 1e-9);
        CHECK_NEAR(px[1], 239.5 + 810 * yd, 1e-9);

        double C[3];
        m.t[0] = 10, m.t[1] = -20;
        imp_pinhole_centre(&m, C);
        CHECK_NEAR(C[0], -10, 1e-12);
        CHECK_NEAR(C[1], 20, 1e-12);
        CHECK_NEAR(C[2], -1000, 1e-12);
}

static void test_round_trip(void) {
        struct imp_pinhole m = frontal();
        /* a moderately distorted lens (a wide-angle machine-vision lens) */
        m.k1 = -0.28, m.k2 = 0.09, m.p1 = 0.0012, m.p2 = -0.0008, m.k3 = -0.012;
        double eye[3] = { 120, -80, 900 }, target[3] = { 0, 0, 0 }, right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&m, eye, target, right);
        double worst_px = 0, worst_dir = 0;
        for (int v = 0; v <= 480; v += 16)
                for (int u = 0; u <= 640; u += 16) {
                        double px[2] = { u, v }, o[3], d[3], back[2];
                        imp_pinhole_ray_world(&m, px, o, d);
                        CHECK_NEAR(d[0] * d[0] + d[1] * d[1] + d[2] * d[2], 1, 1e-12);
                        double X[3] = { o[0] + 700 * d[0], o[1] + 700 * d[1], o[2] + 700 * d[2] };
                        CHECK(imp_pinhole_project(&m, X, back));
                        worst_px = fmax(worst_px, fmax(fabs(back[0] - u), fabs(back[1] - v)));
                        /* and the other way: world point → pixel → ray through the point */
                        double pw[3] = { (u - 320) * 0.5, (v - 240) * 0.5, 3 }, q[2], dir[3];
                        if (!imp_pinhole_project(&m, pw, q))
                                continue;
                        imp_pinhole_ray_world(&m, q, o, dir);
                        double w[3] = { pw[0] - o[0], pw[1] - o[1], pw[2] - o[2] };
                        double n = sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
                        /* sin of the angle (acos near 1 would lose half the digits) */
                        double cx = w[1] * dir[2] - w[2] * dir[1], cy = w[2] * dir[0] - w[0] * dir[2],
                               cz = w[0] * dir[1] - w[1] * dir[0];
                        worst_dir = fmax(worst_dir, sqrt(cx * cx + cy * cy + cz * cz) / n);
                }
        CHECK_LE(worst_px, 1e-6);
        CHECK_LE(worst_dir, 1e-9);
        fprintf(stderr, "round trip: worst %.3g px, %.3g rad\n", worst_px, worst_dir);
}

static void test_look_at(void) {
        struct imp_pinhole m = frontal();
        /* From above the canvas looking down, image x along world +x: image y must run
         * along world -y (y down in the image, the canvas's y up). */
        imp_pinhole_look_at(&m, (double[]){ 50, 60, 1000 }, (double[]){ 50, 60, 0 },
                            (double[]){ 1, 0, 0.3 });   /* off-plane part is dropped */
        double px[2], C[3];
        imp_pinhole_centre(&m, C);
        CHECK_NEAR(C[0], 50, 1e-9);
        CHECK_NEAR(C[1], 60, 1e-9);
        CHECK_NEAR(C[2], 1000, 1e-9);
        CHECK(imp_pinhole_project(&m, (double[]){ 50, 60, 0 }, px));
        CHECK_NEAR(px[0], m.cx, 1e-9);
        CHECK_NEAR(px[1], m.cy, 1e-9);
        CHECK(imp_pinhole_project(&m, (double[]){ 150, 60, 0 }, px));
        CHECK_NEAR(px[0], m.cx + 80, 1e-9);   /* +100 mm in x at 1 m → +0.1 fx */
        CHECK_NEAR(px[1], m.cy, 1e-9);
        CHECK(imp_pinhole_project(&m, (double[]){ 50, 160, 0 }, px));
        CHECK_NEAR(px[0], m.cx, 1e-9);
        CHECK_NEAR(px[1], m.cy - 81, 1e-9);
        /* R is a rotation: det +1 */
        const double *R = m.R;
        double det = R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) +
                     R[2] * (R[3] * R[7] - R[4] * R[6]);
        CHECK_NEAR(det, 1, 1e-12);
        /* `right` parallel to the view still gives a valid rotation */
        imp_pinhole_look_at(&m, (double[]){ 0, 0, 1000 }, (double[]){ 0, 0, 0 }, (double[]){ 0, 0, 1 });
        det = R[0] * (R[4] * R[8] - R[5] * R[7]) - R[1] * (R[3] * R[8] - R[5] * R[6]) +
              R[2] * (R[3] * R[7] - R[4] * R[6]);
        CHECK_NEAR(det, 1, 1e-12);
        CHECK(imp_pinhole_project(&m, (double[]){ 0, 0, 0 }, px));
}

static void sample_rig(struct imp_rig *rig) {
        *rig = (struct imp_rig){ .n_cameras = 2, .has_projector = true, .settle_us = 1500.25 };
        for (int c = 0; c < 2; c++) {
                struct imp_rig_camera *cam = &rig->cameras[c];
                snprintf(cam->name, sizeof cam->name, "cam%d", c);
                cam->model = frontal();
                cam->model.k1 = -0.1 * (c + 1) / 3.0;   /* not exactly representable */
                imp_pinhole_look_at(&cam->model, (double[]){ 200.0 * c - 100, 30, 800 },
                                    (double[]){ 0, 0, 0 }, (double[]){ 1, 0, 0 });
                cam->sensor = (struct imp_sensor){ .bits = 12, .black_level_dn = 64,
                                                   .gain_e_per_dn = 0.7, .read_noise_e = 2.1,
                                                   .full_well_e = 10500, .dark_current_e_per_s = 0.3,
                                                   .prnu = 0.01, .quantum_scale = 1e5,
                                                   .readout_us = 16000, .bayer = c == 1 };
        }
        snprintf(rig->projector.name, sizeof rig->projector.name, "dlp");
        rig->projector.model = frontal();
        rig->projector.model.width = 1280;
        imp_pinhole_look_at(&rig->projector.model, (double[]){ 0, -300, 900 }, (double[]){ 0, 0, 0 },
                            (double[]){ 1, 0, 0 });
        rig->projector.gamma = 2.2;
        rig->projector.black_level = 0.002;
        rig->projector.intensity = 3.5;
        rig->projector.defocus_px = 0.8;
        rig->n_lights = 3;
        rig->lights = calloc(3, sizeof *rig->lights);
        for (int i = 0; i < 3; i++)
                rig->lights[i] = (struct imp_rig_light){
                        .id = i + 10, .pos_mm = { cos(i) * 600, sin(i) * 600, 400 }, .intensity = 1.0 / 7,
                        .colour = { 1, 0.95, 0.9 }, .axis = { 0, 0, -1 }, .profile_exp = 1.5 };
}

static bool rigs_equal(const struct imp_rig *a, const struct imp_rig *b) {
        if (a->n_cameras != b->n_cameras || a->has_projector != b->has_projector ||
            a->n_lights != b->n_lights || a->settle_us != b->settle_us)
                return false;
        /* every field is a number or a zero-padded name: memcmp is exact equality */
        if (memcmp(a->cameras, b->cameras, sizeof a->cameras[0] * (size_t) a->n_cameras))
                return false;
        if (a->has_projector && memcmp(&a->projector, &b->projector, sizeof a->projector))
                return false;
        return memcmp(a->lights, b->lights, sizeof *a->lights * (size_t) a->n_lights) == 0;
}

static void test_json(void) {
        struct imp_rig rig, back = {}, copy = {};
        sample_rig(&rig);
        struct imp_error e = {};
        char path[512];
        snprintf(path, sizeof path, "%s/rig.json", test_tmpdir());
        CHECK_OK(imp_rig_save(path, &rig, &e));
        CHECK_OK(imp_rig_load(path, &back, &e));
        CHECK(rigs_equal(&rig, &back));
        CHECK_OK(imp_rig_copy(&rig, &copy));
        CHECK(rigs_equal(&rig, &copy));
        CHECK(copy.lights != rig.lights);
        imp_rig_free(&back);
        imp_rig_free(&copy);

        /* no projector: null */
        rig.has_projector = false;
        _cleanup_json_ json_t *j = imp_rig_to_json(&rig);
        CHECK(json_is_null(json_object_get(j, "projector")));
        CHECK_OK(imp_rig_from_json(j, "rig.json", &back, &e));
        CHECK(!back.has_projector);
        imp_rig_free(&back);

        /* errors name the field with its full path; *ret untouched */
        struct imp_rig untouched = { .n_cameras = 99 };
        json_t *sensor = json_object_get(json_array_get(json_object_get(j, "cameras"), 1), "sensor");
        json_object_set_new(sensor, "bits", json_string("twelve"));
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "rig.json: cameras[1].sensor.bits: expected an integer, got a string");
        json_object_set_new(sensor, "bits", json_integer(11));
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "cameras[1].sensor.bits: expected 8, 10, 12, 14 or 16, got 11");
        json_object_set_new(sensor, "bits", json_integer(12));
        json_object_del(sensor, "bayer");
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -ENOENT);
        CHECK_STR_EQ(e.msg, "rig.json: cameras[1].sensor.bayer: missing (required)");
        json_object_set_new(sensor, "bayer", json_false());
        CHECK_OK(imp_rig_from_json(j, "rig.json", &back, &e));
        imp_rig_free(&back);

        json_t *light = json_array_get(json_object_get(j, "lights"), 2);
        json_object_set_new(light, "pos_mm", json_pack("[f,f]", 1.0, 2.0));
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -EINVAL);
        CHECK_STR_EQ(e.msg, "rig.json: lights[2].pos_mm: expected 3 numbers, got 2");
        json_object_set_new(light, "pos_mm", json_pack("[f,f,f]", 1.0, 2.0, 3.0));

        json_t *model = json_object_get(json_array_get(json_object_get(j, "cameras"), 0), "model");
        json_object_set_new(model, "R", json_pack("[i,i,i,i,i,i,i,i,i]", 1, 0, 0, 0, 2, 0, 0, 0, 1));
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "rig.json: cameras[0].model.R: expected a rotation");
        json_object_del(model, "fx");
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -ENOENT);
        CHECK_STR_CONTAINS(e.msg, "rig.json: cameras[0].model.fx: missing");
        json_object_set_new(j, "settle_us", json_string("soon"));
        json_object_del(j, "cameras");
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -ENOENT);
        CHECK_STR_EQ(e.msg, "rig.json: cameras: missing (required)");
        json_object_set_new(j, "version", json_integer(2));
        CHECK_ERR(imp_rig_from_json(j, "rig.json", &untouched, &e), -EPROTONOSUPPORT);
        CHECK_INT_EQ(untouched.n_cameras, 99);
        CHECK(untouched.lights == NULL);
        imp_rig_free(&rig);
        imp_rig_free(&rig);   /* idempotent */
}

int main(void) {
        test_known_projection();
        test_round_trip();
        test_look_at();
        test_json();
        return TEST_DONE();
}
