/* The simulated rig served through the real protocols (serve.h): GigE cameras whose fill
 * callback renders the frame for the emulated rig's state, and the Modbus controller that
 * sets that state. The renderer has one thread of control at a time, so the camera
 * threads take turns on it. */
#include <arpa/inet.h>
#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <math.h>
#include "gantry.h"
#include "render.h"
#include "serve.h"
#if defined(IMPASTO_EMU_HAVE_GIGE) && defined(IMPASTO_EMU_HAVE_MODBUS)
#define SERVE_AVAILABLE 1
#include "emu.h"
#include "emu-stage.h"
#endif

#define DEFAULT_ADDRESS "127.0.0.1"
#define DEFAULT_MODBUS_PORT 15020
#define MAX_CAMERAS 4
#define NO_DROP UINT64_MAX

#ifdef SERVE_AVAILABLE

struct serve_cam {
        struct imp_serve *serve;
        int index;                      /* scene camera index */
        char address[INET_ADDRSTRLEN];
        struct imp_emu_gige *gige;      /* NULL: skipped */
        atomic_uint_fast64_t frames, blank;
};

struct imp_serve {
        struct imp_scene *scene;        /* re-placed under the gantry (imp_scene_place) */
        struct imp_render *render;
        pthread_mutex_t render_lock;
        struct imp_emu_rig *rig;
        struct imp_emu_modbus *modbus;
        char address[INET_ADDRSTRLEN];
        uint16_t modbus_port;
        int n_cameras;
        struct serve_cam cams[MAX_CAMERAS];
        char skipped[512];              /* "cam1 on 127.0.0.2: ..." */
        atomic_uint_fast64_t drop_frame;        /* NO_DROP */
        atomic_uint frame_delay_ms;
        /* A gantry scene: the GRBL controller on a pty; the scene placed for where the
         * carriage stands (placed_mm) when a frame is filled. */
        struct imp_emu_stage *stage;
        const struct imp_tile_plan *tiles;
        double placed_mm[3];
        bool placed;
        struct imp_rig rig_copy;        /* what imp_serve_rig returns: the renderer is rebuilt */
        bool have_rig_copy;
};

/* The tile whose target the carriage stands at (within 1 µm), -1 between tiles. */
static long tile_at(const struct imp_tile_plan *tp, const double pos_mm[3]) {
        for (size_t k = 0; k < imp_tile_plan_count(tp); k++) {
                const double *t = imp_tile_plan_tile(tp, k)->stage_mm;
                if (fabs(t[0] - pos_mm[0]) < 1e-3 && fabs(t[1] - pos_mm[1]) < 1e-3 && fabs(t[2] - pos_mm[2]) < 1e-3)
                        return (long) k;
        }
        return -1;
}

/* Under render_lock: the painting placed for the carriage's position now. At a tile's target
 * the pose is `sim render`'s for that tile (stage_error included, deterministic in the seed
 * and the tile); elsewhere the carriage is where it reads back. The renderer is rebuilt for
 * the new window (what the tile sees, never the whole painting). */
static int place_for_stage(struct imp_serve *s, struct imp_error *err) {
        double pos[3];
        imp_emu_stage_position(s->stage, pos);
        if (s->placed && !memcmp(pos, s->placed_mm, sizeof pos))
                return 0;
        struct imp_sim_tile_pose pose = { 0 };
        long k = tile_at(s->tiles, pos);
        if (k >= 0)
                imp_sim_tile_pose(s->scene, s->tiles, (size_t) k, &pose);
        else
                for (int a = 0; a < 3; a++)
                        pose.commanded_mm[a] = pose.readback_mm[a] = pose.true_mm[a] = pos[a];
        struct imp_painting_place pl;
        imp_sim_tile_place(s->tiles, &pose, &pl);
        struct imp_render *rd = NULL;
        int r = imp_scene_place(s->scene, &pl, err);
        if (r < 0 || (r = imp_render_new(s->scene, &rd, err)) < 0)
                return r;
        imp_render_free(s->render);
        s->render = rd;
        memcpy(s->placed_mm, pos, sizeof pos);
        s->placed = true;
        return 0;
}

static void blank_frame(struct serve_cam *c, void *buf, int w, int h, int bpp) {
        memset(buf, 0, (size_t) w * h * bpp);
        atomic_fetch_add(&c->blank, 1);
}

static int serve_fill(void *userdata, const struct imp_emu_camera_state *st, void *buf, int w, int h, int bpp) {
        struct serve_cam *c = userdata;
        struct imp_serve *s = c->serve;
        uint64_t n = atomic_fetch_add(&c->frames, 1);
        unsigned delay_ms = atomic_load(&s->frame_delay_ms);
        if (delay_ms)
                usleep(delay_ms * 1000u);
        if (n == atomic_load(&s->drop_frame)) {
                blank_frame(c, buf, w, h, bpp);
                return 0;
        }
        pthread_mutex_lock(&s->render_lock);
        struct imp_error err = { 0 };
        if (s->stage && place_for_stage(s, &err) < 0) {
                pthread_mutex_unlock(&s->render_lock);
                blank_frame(c, buf, w, h, bpp);
                return -EIO;
        }
        const struct imp_rig *rig = imp_render_rig(s->render);
        int lit = -1, n_on = 0;
        for (unsigned i = 0; i < st->n_lights && i < (unsigned) rig->n_lights; i++)
                if (st->level_permille[i] > 0) {
                        n_on++;
                        lit = (int) i;
                }
        /* The renderer forms one light at full intensity. */
        if (n_on > 1 || (n_on == 1 && st->level_permille[lit] != 1000)) {
                pthread_mutex_unlock(&s->render_lock);
                blank_frame(c, buf, w, h, bpp);
                return -ENOTSUP;
        }
        struct imp_frame_record rec = {
                .seq = (long long) st->frame_id,
                .pattern = st->pattern_desc,
                .light = lit >= 0 ? rig->lights[lit].id : -1,
                .exposure_us = st->exposure_us,
                .gain_db = st->gain_raw,
        };
        snprintf(rec.step, sizeof rec.step, "%s", rec.pattern.kind != IMP_PAT_NONE ? "structured-light" : "dome");
        snprintf(rec.camera, sizeof rec.camera, "%s", rig->cameras[c->index].name);
        struct imp_image *img = NULL;
        int r = imp_render_frame(s->render, &rec, &img, &err);
        int bits = rig->cameras[c->index].sensor.bits;
        pthread_mutex_unlock(&s->render_lock);
        if (r < 0) {
                blank_frame(c, buf, w, h, bpp);
                return r;
        }
        int shift = bits > 8 ? bits - 8 : 0;
        /* The sensor is the scene camera's size; a smaller ROI gets its top-left window. */
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        uint16_t v = 0;
                        if (x < img->width && y < img->height)
                                v = ((const uint16_t *) ((const uint8_t *) img->data + (size_t) y * img->stride))[x];
                        if (bpp == 2)
                                ((uint16_t *) buf)[(size_t) y * w + x] = v;
                        else
                                ((uint8_t *) buf)[(size_t) y * w + x] = (uint8_t) IMP_MIN(v >> shift, 255);
                }
        imp_image_free(img);
        return 0;
}

/* base + k in the last octet; -EINVAL when it does not exist. */
static int nth_address(const char *base, int k, char out[INET_ADDRSTRLEN]) {
        struct in_addr a;
        if (inet_pton(AF_INET, base, &a) != 1)
                return -EINVAL;
        uint32_t h = ntohl(a.s_addr);
        if ((h & 0xff) + (uint32_t) k > 254)
                return -EINVAL;
        a.s_addr = htonl(h + (uint32_t) k);
        return inet_ntop(AF_INET, &a, out, INET_ADDRSTRLEN) ? 0 : -EINVAL;
}

/* The GRBL controller, its travel covering the plan's tiles, and the painting placed at the
 * first tile until the carriage moves. */
static int serve_gantry(struct imp_serve *s, const struct imp_tile_plan *tp, struct imp_error *err) {
        struct imp_emu_stage_config sc = { .n_axes = 3 };
        for (size_t k = 0; k < imp_tile_plan_count(tp); k++)
                for (int a = 0; a < 3; a++)
                        sc.travel_mm[a] = fmax(sc.travel_mm[a], imp_tile_plan_tile(tp, k)->stage_mm[a]);
        for (int a = 0; a < 3; a++)
                sc.travel_mm[a] = fmax(50, ceil(sc.travel_mm[a] * 1.2 + 10));
        int r = imp_emu_stage_grbl_new(&sc, &s->stage);
        if (r < 0)
                return imp_error_set(err, r, "serve: GRBL stage controller on a pseudo-terminal: %s", strerror(-r));
        s->tiles = tp;
        struct imp_sim_tile_pose pose;
        imp_sim_tile_pose(s->scene, tp, 0, &pose);
        struct imp_painting_place pl;
        imp_sim_tile_place(tp, &pose, &pl);
        if ((r = imp_scene_place(s->scene, &pl, err)) < 0)
                return r;
        return imp_render_new(s->scene, &s->render, err);
}

int imp_serve_new(const struct imp_scene *scene, const struct imp_serve_config *cfg, struct imp_serve **ret,
                  struct imp_error *err) {
        if (!scene || !ret)
                return imp_error_set(err, -EINVAL, "serve: no scene");
        const struct imp_rig *srig = imp_scene_rig(scene);
        if (srig->n_cameras < 1 || srig->n_cameras > MAX_CAMERAS)
                return imp_error_set(err, -EINVAL, "serve: scene %s has %d cameras, expected 1 to %d",
                                     imp_scene_name(scene), srig->n_cameras, MAX_CAMERAS);
        if (srig->n_lights > IMP_EMU_MAX_LIGHTS)
                return imp_error_set(err, -EINVAL, "serve: scene %s has %d dome lights, the controller holds %d",
                                     imp_scene_name(scene), srig->n_lights, IMP_EMU_MAX_LIGHTS);
        if (imp_scene_is_gantry(scene) && !(cfg && cfg->tiles))
                return imp_error_set(err, -EINVAL, "serve: scene %s is a painting on a gantry: give the plan whose "
                                     "painting group places the tiles (--plan, docs/painting.md)", imp_scene_name(scene));
        for (int i = 0; i < srig->n_cameras; i++)
                if (imp_scene_camera_opts(scene, i)->colour)
                        return imp_error_set(err, -EOPNOTSUPP,
                                             "serve: camera %s is a colour camera; the GigE emulator serves Mono only",
                                             srig->cameras[i].name);
        struct imp_serve *s = calloc(1, sizeof *s);
        if (!s)
                return imp_error_set(err, -ENOMEM, "serve: out of memory");
        s->scene = (struct imp_scene *) scene;   /* placed only when it is a gantry scene */
        pthread_mutex_init(&s->render_lock, NULL);
        atomic_init(&s->drop_frame, NO_DROP);
        atomic_init(&s->frame_delay_ms, 0);
        snprintf(s->address, sizeof s->address, "%s", cfg && cfg->address ? cfg->address : DEFAULT_ADDRESS);
        s->modbus_port = cfg && cfg->modbus_port ? cfg->modbus_port : DEFAULT_MODBUS_PORT;
        int r;
        char probe[INET_ADDRSTRLEN];
        if (nth_address(s->address, 0, probe) < 0) {
                r = imp_error_set(err, -EINVAL, "serve: address '%s': expected an IPv4 address like 127.0.0.1",
                                  s->address);
                goto fail;
        }
        if (imp_scene_is_gantry(scene) && (r = serve_gantry(s, cfg->tiles, err)) < 0)
                goto fail;
        if (!s->render && (r = imp_render_new(scene, &s->render, err)) < 0)
                goto fail;
        if ((r = imp_rig_copy(imp_render_rig(s->render), &s->rig_copy)) < 0) {
                imp_error_set(err, r, "serve: out of memory");
                goto fail;
        }
        s->have_rig_copy = true;
        const struct imp_rig *rig = imp_render_rig(s->render);
        if ((r = imp_emu_rig_new((unsigned) rig->n_lights, &s->rig)) < 0) {
                imp_error_set(err, r, "serve: emulated rig state");
                goto fail;
        }
        struct imp_emu_modbus_config mc = {
                .address = s->address,
                .port = s->modbus_port,
                .n_lights = (unsigned) rig->n_lights,
                .projector_width = rig->has_projector ? (unsigned) rig->projector.model.width : 0,
                .projector_height = rig->has_projector ? (unsigned) rig->projector.model.height : 0,
        };
        if (mc.n_lights == 0) {
                r = imp_error_set(err, -EINVAL, "serve: scene %s has no dome lights", imp_scene_name(scene));
                goto fail;
        }
        if ((r = imp_emu_modbus_new(&mc, s->rig, &s->modbus)) < 0) {
                imp_error_set(err, r, "serve: Modbus controller on %s:%u: %s", s->address, s->modbus_port,
                              r == -EADDRINUSE ? "port in use" : strerror(-r));
                goto fail;
        }
        s->n_cameras = rig->n_cameras;
        for (int i = 0; i < rig->n_cameras; i++) {
                struct serve_cam *c = &s->cams[i];
                c->serve = s;
                c->index = i;
                atomic_init(&c->frames, 0);
                atomic_init(&c->blank, 0);
                size_t used = strlen(s->skipped);
                if (nth_address(s->address, i, c->address) < 0) {
                        snprintf(s->skipped + used, sizeof s->skipped - used, "%scamera %s: no address %s+%d",
                                 used ? "; " : "", rig->cameras[i].name, s->address, i);
                        continue;
                }
                char serial[48];         /* GigE Vision: at most 15 characters */
                snprintf(serial, sizeof serial, "SIM-%s", rig->cameras[i].name);
                serial[15] = 0;
                r = imp_emu_gige_new(c->address, serial, s->rig, serve_fill, c, &c->gige);
                if (r >= 0)
                        r = imp_emu_gige_set_sensor_size(c->gige, (unsigned) rig->cameras[i].model.width,
                                                         (unsigned) rig->cameras[i].model.height);
                if (r < 0) {
                        imp_emu_gige_free(c->gige);
                        c->gige = NULL;
                        if (i == 0) {
                                imp_error_set(err, r, "serve: camera %s on %s (UDP 3956): %s",
                                              rig->cameras[i].name, c->address,
                                              r == -EADDRINUSE ? "GVCP port in use by another camera" : strerror(-r));
                                goto fail;
                        }
                        snprintf(s->skipped + used, sizeof s->skipped - used, "%scamera %s on %s: %s",
                                 used ? "; " : "", rig->cameras[i].name, c->address,
                                 r == -EADDRINUSE ? "GVCP port in use" : "address not available");
                }
        }
        *ret = s;
        return 0;
fail:
        imp_serve_free(s);
        return r;
}

void imp_serve_free(struct imp_serve *s) {
        if (!s)
                return;
        for (int i = 0; i < MAX_CAMERAS; i++)
                imp_emu_gige_free(s->cams[i].gige);     /* joins the camera threads first */
        imp_emu_modbus_free(s->modbus);
        imp_emu_stage_free(s->stage);
        imp_emu_rig_free(s->rig);
        imp_render_free(s->render);
        if (s->have_rig_copy)
                imp_rig_free(&s->rig_copy);
        pthread_mutex_destroy(&s->render_lock);
        free(s);
}

static bool parse_uint(const char *p, char **end, unsigned long max, unsigned long *ret) {
        if (*p < '0' || *p > '9')
                return false;
        errno = 0;
        unsigned long v = strtoul(p, end, 10);
        if (errno || v > max)
                return false;
        *ret = v;
        return true;
}

int imp_serve_fault(struct imp_serve *s, const char *spec, struct imp_error *err) {
        if (!s || !spec)
                return -EINVAL;
        const char *eq = strchr(spec, '=');
        size_t klen = eq ? (size_t) (eq - spec) : strlen(spec);
        const char *v = eq ? eq + 1 : "";
        char *end = NULL;
        unsigned long a = 0, b = 0;
#define KEY(k) (klen == strlen(k) && strncmp(spec, k, klen) == 0)
        if (KEY("drop-frame")) {
                if (parse_uint(v, &end, UINT32_MAX, &a) && !*end) {
                        atomic_store(&s->drop_frame, a);
                        return 0;
                }
                return imp_error_set(err, -EINVAL, "--fault %s: expected drop-frame=N (frame number >= 0)", spec);
        }
        if (KEY("modbus-exception")) {
                if (parse_uint(v, &end, 1000000, &a) && a >= 1) {
                        b = 4;      /* server device failure */
                        if (!*end || (*end == ':' && parse_uint(end + 1, &end, 255, &b) && !*end && b >= 1)) {
                                imp_emu_modbus_fail_nth(s->modbus, (unsigned) a, (uint8_t) b);
                                return 0;
                        }
                }
                return imp_error_set(err, -EINVAL,
                                     "--fault %s: expected modbus-exception=N[:CODE] (N >= 1, CODE 1..255)", spec);
        }
        if (KEY("modbus-delay")) {
                if (parse_uint(v, &end, 1000000, &a) && *end == ':' && parse_uint(end + 1, &end, 60000, &b) && !*end) {
                        imp_emu_modbus_delay(s->modbus, (unsigned) a, (unsigned) b);
                        return 0;
                }
                return imp_error_set(err, -EINVAL, "--fault %s: expected modbus-delay=N:MS (MS up to 60000)", spec);
        }
        if (KEY("modbus-disconnect")) {
                if (parse_uint(v, &end, 1000000, &a) && !*end && a >= 1) {
                        imp_emu_modbus_drop_nth(s->modbus, (unsigned) a);
                        return 0;
                }
                return imp_error_set(err, -EINVAL, "--fault %s: expected modbus-disconnect=N (N >= 1)", spec);
        }
        if (KEY("frame-delay")) {
                if (parse_uint(v, &end, 60000, &a) && !*end) {
                        atomic_store(&s->frame_delay_ms, (unsigned) a);
                        return 0;
                }
                return imp_error_set(err, -EINVAL, "--fault %s: expected frame-delay=MS (0 to 60000)", spec);
        }
        if (KEY("projector-fault")) {
                if (parse_uint(v, &end, 65535, &a) && !*end && a >= 1) {
                        imp_emu_modbus_projector_fault(s->modbus, (unsigned) a);
                        return 0;
                }
                return imp_error_set(err, -EINVAL, "--fault %s: expected projector-fault=CODE (1..65535)", spec);
        }
#undef KEY
        return imp_error_set(err, -EINVAL,
                             "--fault %s: unknown fault; expected drop-frame=N, modbus-exception=N[:CODE], "
                             "modbus-delay=N:MS, modbus-disconnect=N, frame-delay=MS or projector-fault=CODE",
                             spec);
}

const struct imp_rig *imp_serve_rig(const struct imp_serve *s) {
        return s ? &s->rig_copy : NULL;
}

int imp_serve_n_cameras(const struct imp_serve *s) {
        return s ? s->n_cameras : 0;
}

const char *imp_serve_camera_address(const struct imp_serve *s, int cam) {
        if (!s || cam < 0 || cam >= s->n_cameras || !s->cams[cam].gige)
                return NULL;
        return s->cams[cam].address;
}

uint64_t imp_serve_frames(const struct imp_serve *s, int cam) {
        if (!s || cam < 0 || cam >= s->n_cameras)
                return 0;
        return atomic_load(&((struct imp_serve *) s)->cams[cam].frames);
}

uint64_t imp_serve_blank_frames(const struct imp_serve *s, int cam) {
        if (!s || cam < 0 || cam >= s->n_cameras)
                return 0;
        return atomic_load(&((struct imp_serve *) s)->cams[cam].blank);
}

struct imp_emu_rig *imp_serve_emu_rig(struct imp_serve *s) {
        return s ? s->rig : NULL;
}

struct imp_emu_modbus *imp_serve_modbus(struct imp_serve *s) {
        return s ? s->modbus : NULL;
}

struct imp_emu_stage *imp_serve_stage(struct imp_serve *s) {
        return s ? s->stage : NULL;
}

const char *imp_serve_stage_device(const struct imp_serve *s) {
        return s && s->stage ? imp_emu_stage_device(s->stage) : NULL;
}

char *imp_serve_describe(const struct imp_serve *s) {
        if (!s)
                return NULL;
        const struct imp_rig *rig = &s->rig_copy;
        char *text = NULL;
        size_t size = 0;
        FILE *f = open_memstream(&text, &size);
        if (!f)
                return NULL;
        fprintf(f, "scene %s, seed %llu\n", imp_scene_name(s->scene), (unsigned long long) imp_scene_seed(s->scene));
        for (int i = 0; i < s->n_cameras; i++)
                if (s->cams[i].gige)
                        fprintf(f, "camera %s: GigE Vision on %s, %dx%d Mono8/Mono16, %d-bit DN\n",
                                rig->cameras[i].name, s->cams[i].address, rig->cameras[i].model.width,
                                rig->cameras[i].model.height, rig->cameras[i].sensor.bits);
        if (s->skipped[0])
                fprintf(f, "skipped: %s\n", s->skipped);
        fprintf(f, "controller: Modbus TCP on %s:%u, %d dome lights", s->address, s->modbus_port, rig->n_lights);
        if (rig->has_projector)
                fprintf(f, ", projector %s %dx%d", rig->projector.name, rig->projector.model.width,
                        rig->projector.model.height);
        fputc('\n', f);
        if (s->stage)
                fprintf(f, "stage: GRBL 1.1 on %s (rig config: stage = { backend = \"grbl\"; address = \"%s\"; };), "
                        "%zu tiles\n", imp_emu_stage_device(s->stage), imp_emu_stage_device(s->stage),
                        imp_tile_plan_count(s->tiles));
        fclose(f);
        return text;
}

#else /* built without Aravis or libmodbus */

struct imp_serve { int unused; };

int imp_serve_new(const struct imp_scene *scene, const struct imp_serve_config *cfg, struct imp_serve **ret,
                  struct imp_error *err) {
        (void) scene, (void) cfg, (void) ret;
        return imp_error_set(err, -EOPNOTSUPP, "serve: impasto was built without Aravis or libmodbus");
}
void imp_serve_free(struct imp_serve *s) { free(s); }
int imp_serve_fault(struct imp_serve *s, const char *spec, struct imp_error *err) {
        (void) s, (void) spec;
        return imp_error_set(err, -EOPNOTSUPP, "serve: not built");
}
const struct imp_rig *imp_serve_rig(const struct imp_serve *s) { (void) s; return NULL; }
int imp_serve_n_cameras(const struct imp_serve *s) { (void) s; return 0; }
const char *imp_serve_camera_address(const struct imp_serve *s, int cam) { (void) s, (void) cam; return NULL; }
uint64_t imp_serve_frames(const struct imp_serve *s, int cam) { (void) s, (void) cam; return 0; }
uint64_t imp_serve_blank_frames(const struct imp_serve *s, int cam) { (void) s, (void) cam; return 0; }
struct imp_emu_rig *imp_serve_emu_rig(struct imp_serve *s) { (void) s; return NULL; }
struct imp_emu_modbus *imp_serve_modbus(struct imp_serve *s) { (void) s; return NULL; }
struct imp_emu_stage *imp_serve_stage(struct imp_serve *s) { (void) s; return NULL; }
const char *imp_serve_stage_device(const struct imp_serve *s) { (void) s; return NULL; }
char *imp_serve_describe(const struct imp_serve *s) { (void) s; return NULL; }

#endif
