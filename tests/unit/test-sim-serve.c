/* The served simulated rig (sim/serve.h) through the REAL drivers: Aravis camera, Modbus
 * dome and Modbus projector. Every frame grabbed must equal, bit for bit, the renderer's
 * frame for the same record (seq = the GigE frame id, same scene and seed); patterns,
 * lights, exposure and gain set through the devices must show in the pixels; faults on the
 * projector leave it dark. */
#include <math.h>
#include "camera.h"
#include "dome.h"
#include "emu.h"
#include "projector.h"
#include "render.h"
#include "scene.h"
#include "serve.h"
#include "unit/test.h"

#define ADDRESS "127.0.0.1"
#define PORT 15842
#define MB_ADDR "127.0.0.1:15842;timeout_ms=500"
#define GRAB_TIMEOUT_MS 3000

static struct imp_render *ref;
static const struct imp_rig *rig;

/* Triggers one frame and grabs it. */
static const struct imp_frame *shoot(struct imp_camera *cam) {
        const struct imp_frame *f = NULL;
        CHECK_OK(imp_camera_trigger_software(cam));
        int r = imp_camera_grab(cam, GRAB_TIMEOUT_MS, &f);
        CHECK_OK(r);
        return r < 0 ? NULL : f;
}

/* The frame must be the renderer's for this state; returns the mean DN (NAN on mismatch). */
static double expect_rendered(const struct imp_frame *f, int light_index, const struct imp_pattern *pat,
                              double exposure_us, double gain_db, const char *what) {
        if (!f)
                return NAN;
        struct imp_frame_record rec = { .seq = (long long) f->meta.frame_id, .camera = "cam0",
                                        .light = light_index >= 0 ? rig->lights[light_index].id : -1,
                                        .exposure_us = exposure_us, .gain_db = gain_db };
        if (pat)
                rec.pattern = *pat;
        struct imp_error err = { 0 };
        _cleanup_image_ struct imp_image *img = NULL;
        CHECK_OK(imp_render_frame(ref, &rec, &img, &err));
        if (!img)
                return NAN;
        CHECK_INT_EQ(f->width, img->width);
        CHECK_INT_EQ(f->height, img->height);
        CHECK_INT_EQ(f->pixel_format, IMP_PIXEL_MONO16);
        if ((int) f->width != img->width || (int) f->height != img->height)
                return NAN;
        const uint16_t *got = f->data;
        size_t n_diff = 0, first = 0;
        double sum = 0;
        for (int y = 0; y < img->height; y++)
                for (int x = 0; x < img->width; x++) {
                        uint16_t want = ((const uint16_t *) ((const uint8_t *) img->data + y * img->stride))[x];
                        size_t i = (size_t) y * img->width + x;
                        if (got[i] != want && n_diff++ == 0)
                                first = i;
                        sum += got[i];
                }
        CHECK_MSG(n_diff == 0, "%s: %zu pixels differ from the renderer (first at %zu: %u vs rendered)", what,
                  n_diff, first, got[first]);
        return sum / ((double) img->width * img->height);
}

int main(void) {
        if (!imp_emu_gige_port_free(ADDRESS))
                TEST_SKIP("UDP %s:3956 (GVCP) is taken by another camera", ADDRESS);
        struct imp_error err = { 0 };
        _cleanup_(imp_scene_freep) struct imp_scene *scene = NULL;
        CHECK_OK(imp_scene_load(IMPASTO_SOURCE_DIR "/config/scenes/small.cfg", &scene, &err));
        if (!scene)
                return TEST_DONE();
        imp_scene_set_seed(scene, 7);
        _cleanup_(imp_serve_freep) struct imp_serve *srv = NULL;
        int r = imp_serve_new(scene, &(struct imp_serve_config) { .address = ADDRESS, .modbus_port = PORT },
                              &srv, &err);
        if (r == -EADDRINUSE)
                TEST_SKIP("%s", err.msg);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();
        _cleanup_(imp_render_freep) struct imp_render *rd = NULL;
        CHECK_OK(imp_render_new(scene, &rd, &err));
        ref = rd;
        rig = imp_serve_rig(srv);
        CHECK_INT_EQ(rig->n_lights, 12);
        CHECK_STR_EQ(imp_serve_camera_address(srv, 0), ADDRESS);

        /* Bad fault specs name what was expected. */
        CHECK_ERR(imp_serve_fault(srv, "modbus-delay=3", &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "modbus-delay=N:MS");
        CHECK_ERR(imp_serve_fault(srv, "melt=1", &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "unknown fault");

        _cleanup_(imp_camera_closep) struct imp_camera *cam = NULL;
        _cleanup_(imp_dome_closep) struct imp_dome *dome = NULL;
        _cleanup_(imp_projector_closep) struct imp_projector *proj = NULL;
        CHECK_OK(imp_camera_open("aravis", ADDRESS, 3000, &cam));
        CHECK_OK(imp_dome_open("modbus", MB_ADDR, 0, &dome));
        CHECK_OK(imp_projector_open("modbus", MB_ADDR, 0, &proj));
        if (!cam || !dome || !proj)
                return TEST_DONE();
        struct imp_camera_info ci;
        CHECK_OK(imp_camera_get_info(cam, &ci));
        /* The sensor is the scene camera's. */
        CHECK_INT_EQ(ci.sensor_width, 320);
        CHECK_INT_EQ(ci.sensor_height, 240);
        CHECK_INT_EQ(ci.width, 320);
        struct imp_projector_info pi;
        CHECK_OK(imp_projector_get_info(proj, &pi));
        CHECK_INT_EQ(pi.width, 256);
        CHECK_INT_EQ(pi.height, 192);

        const struct imp_pattern seq[] = {
                { .kind = IMP_PAT_WHITE },
                { .kind = IMP_PAT_GRAY, .axis = 0, .bit = 2, .nbits = 8 },
                { .kind = IMP_PAT_GRAY, .axis = 0, .bit = 2, .nbits = 8, .inverse = true },
        };
        CHECK_OK(imp_projector_upload(proj, seq, ARRAY_SIZE(seq)));
        CHECK_OK(imp_camera_set_pixel_format(cam, IMP_PIXEL_MONO16));
        CHECK_OK(imp_camera_set_exposure_us(cam, 10000));
        CHECK_OK(imp_camera_set_gain_db(cam, 0));
        CHECK_OK(imp_camera_start(cam, &(struct imp_camera_acq) { .n_buffers = 4, .software_trigger = true }));

        /* Light 3 at full under a white pattern. */
        CHECK_OK(imp_dome_set_light(dome, 3, 1000, 0));
        CHECK_OK(imp_projector_show(proj, 0));
        double m_white = expect_rendered(shoot(cam), 3, &seq[0], 10000, 0, "light 3 + white");
        /* Gray bit 2 and its inverse: different frames, both as rendered, adding up to about
         * white plus one black level (projector black and noise aside). */
        CHECK_OK(imp_projector_show(proj, 1));
        double m_gray = expect_rendered(shoot(cam), 3, &seq[1], 10000, 0, "light 3 + gray bit 2");
        CHECK_OK(imp_projector_show(proj, 2));
        double m_inv = expect_rendered(shoot(cam), 3, &seq[2], 10000, 0, "light 3 + gray bit 2 inverse");
        CHECK_LE(m_gray, m_white - 20);
        CHECK_LE(m_inv, m_white - 20);
        double m_light_only = 0;

        /* Projector dark, light only; then half the exposure: (DN - black) halves. */
        CHECK_OK(imp_projector_dark(proj));
        m_light_only = expect_rendered(shoot(cam), 3, NULL, 10000, 0, "light 3, projector dark");
        CHECK_LE(m_light_only, m_gray);
        CHECK_OK(imp_camera_set_exposure_us(cam, 5000));
        double m_half = expect_rendered(shoot(cam), 3, NULL, 5000, 0, "light 3 at 5 ms");
        double black = rig->cameras[0].sensor.black_level_dn;
        CHECK_NEAR((m_half - black) / (m_light_only - black), 0.5, 0.02);
        /* Gain 6 dB (GainRaw 6): about twice the signal. */
        CHECK_OK(imp_camera_set_gain_db(cam, 6));
        double m_gain = expect_rendered(shoot(cam), 3, NULL, 5000, 6, "light 3 at 5 ms, 6 dB");
        CHECK_NEAR((m_gain - black) / (m_half - black), pow(10, 6 / 20.0), 0.05);
        CHECK_OK(imp_camera_set_gain_db(cam, 0));

        /* Another light: the dome wrapper switches 3 off first; two are never on. */
        CHECK_OK(imp_dome_set_light(dome, 7, 1000, 0));
        expect_rendered(shoot(cam), 7, NULL, 5000, 0, "light 7");
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(imp_serve_emu_rig(srv)), 1);
        /* Dimmed: the renderer has no dimmer, the frame comes all zero and is counted. */
        uint64_t blank0 = imp_serve_blank_frames(srv, 0);
        CHECK_OK(imp_dome_set_light(dome, 7, 500, 0));
        const struct imp_frame *f = shoot(cam);
        if (f)
                CHECK_INT_EQ(((const uint16_t *) f->data)[f->width * 10 + 10], 0);
        CHECK_INT_EQ(imp_serve_blank_frames(srv, 0), blank0 + 1);
        CHECK_OK(imp_dome_set_light(dome, 7, 1000, 0));

        /* A Modbus exception on show: the error reaches the caller and the projector is dark;
         * the next frame is the light alone. */
        CHECK_OK(imp_projector_show(proj, 0));
        CHECK_OK(imp_serve_fault(srv, "modbus-exception=1:4", &err));
        CHECK_ERR(imp_projector_show(proj, 1), -EIO);
        CHECK_STR_CONTAINS(imp_projector_last_error(proj), "show pattern 1");
        CHECK_INT_EQ(imp_emu_rig_get_pattern(imp_serve_emu_rig(srv)), -1);
        expect_rendered(shoot(cam), 7, NULL, 5000, 0, "after the failed show");
        /* An LED fault latched on the controller: show refused, dark, status says why. */
        CHECK_OK(imp_serve_fault(srv, "projector-fault=3", &err));
        CHECK_ERR(imp_projector_show(proj, 0), -EIO);
        struct imp_projector_status ps;
        CHECK_OK(imp_projector_get_status(proj, &ps));
        CHECK(ps.fault);
        CHECK_INT_EQ(ps.fault_code, 3);
        CHECK_INT_EQ(ps.shown, -1);
        /* drop-frame: the next frame of this camera comes all zero. */
        char spec[64];
        snprintf(spec, sizeof spec, "drop-frame=%llu", (unsigned long long) imp_serve_frames(srv, 0));
        CHECK_OK(imp_serve_fault(srv, spec, &err));
        f = shoot(cam);
        if (f)
                CHECK_INT_EQ(((const uint16_t *) f->data)[f->width * 100 + 100], 0);
        expect_rendered(shoot(cam), 7, NULL, 5000, 0, "after the dropped frame");
        CHECK_OK(imp_camera_stop(cam));
        fprintf(stderr, "means: white %.1f, gray %.1f, inverse %.1f, light only %.1f, half %.1f, 6 dB %.1f\n",
                m_white, m_gray, m_inv, m_light_only, m_half, m_gain);
        return TEST_DONE();
}
