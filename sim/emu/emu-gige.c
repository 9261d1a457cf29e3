/* GigE Vision camera emulator: Aravis' ArvGvFakeCamera serving GVCP/GVSP on a loopback
 * address (and unplugged and plugged back in on demand), its pixels from an impasto fill callback that sees the emulated rig (which
 * lights are on, which pattern is projected) and the exposure, gain and format set by
 * the client. Aravis issue #955: inside the callback the buffer's size reads as 0, so the
 * size is computed from the image geometry and the data pointer written directly. */
#include <arpa/inet.h>
#include <arv.h>
#include <netinet/in.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <unistd.h>
#include "emu.h"

#define GVCP_PORT 3956

struct imp_emu_gige {
        ArvGvFakeCamera *gv;            /* NULL while unplugged */
        char address[64], serial[64];
        unsigned sensor_width, sensor_height;   /* 0: the fake camera's own */
        struct imp_emu_rig *rig;
        imp_emu_fill_fn fill;
        void *userdata;
        atomic_uint_fast64_t frames;
};

static void fill_pattern(ArvBuffer *buffer, void *data, guint32 exposure_us, guint32 gain,
                         ArvPixelFormat pixel_format) {
        struct imp_emu_gige *g = data;
        int width = arv_buffer_get_image_width(buffer);
        int height = arv_buffer_get_image_height(buffer);
        int bpp = (int) ARV_PIXEL_FORMAT_BIT_PER_PIXEL(pixel_format) / 8;
        void *pixels = (void *) arv_buffer_get_data(buffer, NULL);
        if (!pixels || width <= 0 || height <= 0 || (bpp != 1 && bpp != 2))
                return;
        struct imp_emu_camera_state st = {
                .exposure_us = exposure_us,
                .gain_raw = gain,
                .pixel_format = pixel_format,
                .lit_light = imp_emu_rig_lit_light(g->rig),
                .pattern = imp_emu_rig_get_pattern(g->rig),
                .n_lights = imp_emu_rig_n_lights(g->rig),
                .frame_index = atomic_load(&g->frames),
                .frame_id = arv_buffer_get_frame_id(buffer),
        };
        imp_emu_rig_get_pattern_desc(g->rig, &st.pattern_desc);
        imp_emu_rig_get_lights(g->rig, st.level_permille, IMP_EMU_MAX_LIGHTS);
        (void) g->fill(g->userdata, &st, pixels, width, height, bpp);
        atomic_fetch_add(&g->frames, 1);
}

bool imp_emu_gige_port_free(const char *address) {
        struct sockaddr_in sa = { .sin_family = AF_INET, .sin_port = htons(GVCP_PORT) };
        if (inet_pton(AF_INET, address ? address : "127.0.0.1", &sa.sin_addr) != 1)
                return false;
        int fd = socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
        if (fd < 0)
                return false;
        bool ok = bind(fd, (struct sockaddr *) &sa, sizeof sa) == 0;
        close(fd);
        return ok;
}

static int set_sensor_size(ArvGvFakeCamera *gv, unsigned width, unsigned height) {
        ArvFakeCamera *fc = arv_gv_fake_camera_get_fake_camera(gv);
        if (!arv_fake_camera_write_register(fc, ARV_FAKE_CAMERA_REGISTER_SENSOR_WIDTH, width) ||
            !arv_fake_camera_write_register(fc, ARV_FAKE_CAMERA_REGISTER_SENSOR_HEIGHT, height) ||
            !arv_fake_camera_write_register(fc, ARV_FAKE_CAMERA_REGISTER_X_OFFSET, 0) ||
            !arv_fake_camera_write_register(fc, ARV_FAKE_CAMERA_REGISTER_Y_OFFSET, 0) ||
            !arv_fake_camera_write_register(fc, ARV_FAKE_CAMERA_REGISTER_WIDTH, width) ||
            !arv_fake_camera_write_register(fc, ARV_FAKE_CAMERA_REGISTER_HEIGHT, height))
                return -EIO;
        return 0;
}

/* A fresh fake camera on the address: power-on state, as a camera plugged in again. */
static int plug(struct imp_emu_gige *g) {
        g->gv = arv_gv_fake_camera_new(g->address, g->serial);
        if (!g->gv || !arv_gv_fake_camera_is_running(g->gv)) {
                g_clear_object(&g->gv);
                return -EADDRNOTAVAIL;
        }
        arv_fake_camera_set_fill_pattern(arv_gv_fake_camera_get_fake_camera(g->gv), fill_pattern, g);
        if (g->sensor_width && set_sensor_size(g->gv, g->sensor_width, g->sensor_height) < 0) {
                g_clear_object(&g->gv);
                return -EIO;
        }
        return 0;
}

int imp_emu_gige_new(const char *address, const char *serial, struct imp_emu_rig *rig,
                     imp_emu_fill_fn fill, void *userdata, struct imp_emu_gige **ret_gige) {
        if (!ret_gige)
                return -EINVAL;
        if (!address)
                address = "127.0.0.1";
        if (!imp_emu_gige_port_free(address))
                return -EADDRINUSE;
        struct imp_emu_gige *g = calloc(1, sizeof *g);
        if (!g)
                return -ENOMEM;
        g->rig = rig;
        g->fill = fill ? fill : imp_emu_fill_default;
        g->userdata = userdata;
        atomic_init(&g->frames, 0);
        snprintf(g->address, sizeof g->address, "%s", address);
        snprintf(g->serial, sizeof g->serial, "%s", serial ? serial : "IMPASTO-EMU");
        int r = plug(g);
        if (r < 0) {
                imp_emu_gige_free(g);
                return r;
        }
        *ret_gige = g;
        return 0;
}

int imp_emu_gige_unplug(struct imp_emu_gige *g) {
        if (!g)
                return -EINVAL;
        if (!g->gv)
                return -EALREADY;
        g_clear_object(&g->gv);         /* joins its thread, closes the GVCP and GVSP sockets */
        return 0;
}

int imp_emu_gige_replug(struct imp_emu_gige *g) {
        if (!g)
                return -EINVAL;
        if (g->gv)
                return -EALREADY;
        if (!imp_emu_gige_port_free(g->address))
                return -EADDRINUSE;
        return plug(g);
}

void imp_emu_gige_free(struct imp_emu_gige *g) {
        if (!g)
                return;
        if (g->gv)
                g_object_unref(g->gv);  /* joins the camera thread before the callback data goes */
        free(g);
}

int imp_emu_gige_set_sensor_size(struct imp_emu_gige *g, unsigned width, unsigned height) {
        if (!g || width == 0 || height == 0 || width > 16384 || height > 16384)
                return -EINVAL;
        if (!g->gv)
                return -ENODEV;
        int r = set_sensor_size(g->gv, width, height);
        if (r < 0)
                return r;
        g->sensor_width = width;        /* kept for a replug */
        g->sensor_height = height;
        return 0;
}

uint64_t imp_emu_gige_frames_filled(struct imp_emu_gige *g) {
        return g ? atomic_load(&g->frames) : 0;
}
