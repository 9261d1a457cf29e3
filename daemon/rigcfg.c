/* The rig config (config/rigs/NAME.cfg): which devices the daemon drives, through which
 * backend and at which address, and where the rig's calibration (rig.json) is. Devices
 * are opened on demand and kept open; a device that failed is closed and reopened. */
#include <libgen.h>
#include <pthread.h>
#include <string.h>
#include <sys/eventfd.h>
#include <unistd.h>
#include "conf.h"
#include "impastod.h"
#include "json-util.h"
#include "log.h"
#include "tile-session.h"

static const char *const dev_state_names[] = { "absent", "ok", "busy", "fault" };

const char *dev_state_name(enum dev_state s) {
        return dev_state_names[s];
}

static int get_dev(struct imp_conf *c, config_setting_t *g, char *name, size_t name_size,
                   char *backend, char *address, const char *default_name, struct imp_error *err) {
        static const char *const known[] = { "name", "backend", "address", NULL };
        /* cameras (no default name) may also say `stream = false;` (session.c, streamed runs) */
        static const char *const camera_known[] = { "name", "backend", "address", "stream", NULL };
        /* the stage's repeatability: the prior of tile poses in painting.json (docs/painting.md) */
        static const char *const stage_known[] = { "name", "backend", "address", "sigma_mm", "sigma_deg",
                                                    "settle_timeout_ms", NULL };
        const char *n = default_name, *b = NULL, *a = NULL;
        int r;
        bool stage = default_name && !strcmp(default_name, "stage");
        if ((r = imp_conf_check_known(c, g, stage ? stage_known : default_name ? known : camera_known, err)) < 0 ||
            (r = imp_conf_get_string(c, g, "name", default_name == NULL, &n, err)) < 0 ||
            (r = imp_conf_get_string(c, g, "backend", true, &b, err)) < 0 ||
            (r = imp_conf_get_string(c, g, "address", true, &a, err)) < 0)
                return r;
        snprintf(name, name_size, "%s", n);
        snprintf(backend, 32, "%s", b);
        snprintf(address, 128, "%s", a);
        return 0;
}

static json_t *setting_json(const config_setting_t *s) {
        switch (config_setting_type(s)) {
        case CONFIG_TYPE_INT: return json_integer(config_setting_get_int(s));
        case CONFIG_TYPE_INT64: return json_integer(config_setting_get_int64(s));
        case CONFIG_TYPE_FLOAT: return json_real(config_setting_get_float(s));
        case CONFIG_TYPE_BOOL: return json_boolean(config_setting_get_bool(s));
        case CONFIG_TYPE_STRING: return json_string(config_setting_get_string(s));
        case CONFIG_TYPE_GROUP: {
                json_t *o = json_object();
                for (int i = 0; i < config_setting_length(s); i++) {
                        config_setting_t *m = config_setting_get_elem(s, i);
                        json_object_set_new(o, config_setting_name(m), setting_json(m));
                }
                return o;
        }
        default: {
                json_t *a = json_array();
                for (int i = 0; i < config_setting_length(s); i++)
                        json_array_append_new(a, setting_json(config_setting_get_elem(s, i)));
                return a;
        }
        }
}

int rigcfg_load(const char *path, struct rigcfg **ret, struct imp_error *err) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        int r = imp_conf_load(path, &c, err);
        if (r < 0)
                return r;
        config_setting_t *g, *list;
        if ((r = imp_conf_get_group(c, NULL, "rig", true, &g, err)) < 0)
                return r;
        static const char *const known[] = { "name", "calibration", "cameras", "projector", "dome",
                                             "stage", "tile_pitch_um", "stream", NULL };
        if ((r = imp_conf_check_known(c, g, known, err)) < 0)
                return r;
        struct rigcfg *rc = calloc(1, sizeof *rc);
        if (!rc)
                return imp_error_set(err, -ENOMEM, "out of memory");
        const char *name = "rig", *calib = NULL;
        long long pitch = 0;
        bool stream = true;
        if ((r = imp_conf_get_string(c, g, "name", false, &name, err)) < 0 ||
            (r = imp_conf_get_bool(c, g, "stream", false, &stream, err)) < 0 ||
            (r = imp_conf_get_string(c, g, "calibration", true, &calib, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "tile_pitch_um", false, 0, 10000000, &pitch, err)) < 0 ||
            (r = imp_conf_get_list(c, g, "cameras", true, &list, err)) < 0)
                goto fail;
        snprintf(rc->name, sizeof rc->name, "%s", name);
        snprintf(rc->path, sizeof rc->path, "%s", path);
        rc->tile_pitch_um = (int32_t) pitch;
        rc->timeout_ms = DAEMON_DEVICE_TIMEOUT_MS;
        if (calib[0] == '/')
                snprintf(rc->calibration, sizeof rc->calibration, "%s", calib);
        else {
                char tmp[PATH_MAX];
                snprintf(tmp, sizeof tmp, "%s", path);
                snprintf(rc->calibration, sizeof rc->calibration, "%s/%s", dirname(tmp), calib);
        }
        int n = config_setting_length(list);
        if (n < 1 || n > DAEMON_MAX_CAMERAS) {
                r = imp_error_set(err, -EINVAL, "%s:%d: rig.cameras: expected 1 to %d cameras, got %d",
                                  path, config_setting_source_line(list), DAEMON_MAX_CAMERAS, n);
                goto fail;
        }
        for (int i = 0; i < n; i++) {
                struct dev_camera *cam = &rc->cameras[i];
                cam->stream = stream;
                if ((r = get_dev(c, config_setting_get_elem(list, i), cam->name, sizeof cam->name,
                                 cam->backend, cam->address, NULL, err)) < 0 ||
                    (r = imp_conf_get_bool(c, config_setting_get_elem(list, i), "stream", false, &cam->stream,
                                           err)) < 0)
                        goto fail;
                rc->n_cameras++;
        }
        config_setting_t *sub = config_setting_get_member(g, "dome");
        if (sub) {
                if ((r = get_dev(c, sub, rc->dome.name, sizeof rc->dome.name, rc->dome.backend,
                                 rc->dome.address, "dome", err)) < 0)
                        goto fail;
                rc->dome.configured = true;
        }
        sub = config_setting_get_member(g, "projector");
        if (sub) {
                if ((r = get_dev(c, sub, rc->projector.name, sizeof rc->projector.name,
                                 rc->projector.backend, rc->projector.address, "projector", err)) < 0)
                        goto fail;
                rc->projector.configured = true;
        }
        sub = config_setting_get_member(g, "stage");
        if (sub) {
                rc->stage.sigma_mm = 0.05;
                rc->stage.sigma_deg = 0.05;
                long long settle_ms = TILE_SETTLE_TIMEOUT_MS;
                if ((r = get_dev(c, sub, rc->stage.name, sizeof rc->stage.name, rc->stage.backend,
                                 rc->stage.address, "stage", err)) < 0 ||
                    (r = imp_conf_get_double(c, sub, "sigma_mm", false, 1e-6, 100, &rc->stage.sigma_mm, err)) < 0 ||
                    (r = imp_conf_get_double(c, sub, "sigma_deg", false, 1e-6, 10, &rc->stage.sigma_deg, err)) < 0 ||
                    (r = imp_conf_get_int(c, sub, "settle_timeout_ms", false, 100, 3600000, &settle_ms, err)) < 0)
                        goto fail;
                rc->stage.settle_timeout_ms = (unsigned) settle_ms;
                rc->stage.configured = true;
        }
        rc->config = setting_json(g);
        *ret = rc;
        return 0;
fail:
        free(rc);
        return r;
}

void rigcfg_close_devices(struct rigcfg *rc) {
        for (int i = 0; i < rc->n_cameras; i++) {
                struct dev_camera *cam = &rc->cameras[i];
                if (cam->cam && cam->started)
                        (void) imp_camera_stop(cam->cam);
                imp_camera_close(cam->cam);
                cam->cam = NULL;
                cam->started = false;
        }
        imp_dome_close(rc->dome.dome);
        rc->dome.dome = NULL;
        imp_projector_close(rc->projector.proj);
        rc->projector.proj = NULL;
        imp_stage_close(rc->stage.stage);
        rc->stage.stage = NULL;
}

void rigcfg_free(struct rigcfg *rc) {
        if (!rc)
                return;
        rigcfg_close_devices(rc);
        json_decref(rc->config);
        free(rc);
}

/* Stops and closes a camera, to be opened afresh by rigcfg_open_devices(); what was applied to
 * it (exposure, gain) is forgotten with it. */
void rigcfg_drop_camera(struct dev_camera *cam) {
        if (cam->cam && cam->started)
                (void) imp_camera_stop(cam->cam);
        imp_camera_close(cam->cam);
        cam->cam = NULL;
        cam->started = false;
        cam->applied_valid = false;
}

struct dev_camera *rigcfg_camera(struct rigcfg *rc, const char *name) {
        for (int i = 0; i < rc->n_cameras; i++)
                if (!strcmp(rc->cameras[i].name, name))
                        return &rc->cameras[i];
        return NULL;
}

static int open_camera(struct dev_camera *cam, const struct imp_rig *rig, unsigned cam_timeout_ms,
                       struct imp_error *err) {
        int r = imp_camera_open(cam->backend, cam->address, cam_timeout_ms, &cam->cam);
        if (r < 0)
                goto fail;
        const struct imp_rig_camera *model = NULL;
        for (int i = 0; rig && i < rig->n_cameras; i++)
                if (!strcmp(rig->cameras[i].name, cam->name))
                        model = &rig->cameras[i];
        struct imp_camera_info info;
        if ((r = imp_camera_get_info(cam->cam, &info)) < 0)
                goto fail;
        if (cam->serial[0] && strcmp(cam->serial, info.serial)) {
                imp_camera_close(cam->cam);
                cam->cam = NULL;
                cam->state = DEV_FAULT;
                snprintf(cam->detail, sizeof cam->detail,
                         "%.31s at %.64s: serial %.32s, not %.32s (the camera impastod opened first); restart "
                         "impastod after changing cameras", cam->backend, cam->address, info.serial, cam->serial);
                return imp_error_set(err, -EXDEV, "camera %s: %s", cam->name, cam->detail);
        }
        snprintf(cam->serial, sizeof cam->serial, "%s", info.serial);
        /* The calibrated geometry is the frame size; 16 bits when the camera has them. */
        if (model && (r = imp_camera_set_roi(cam->cam, 0, 0, (unsigned) model->model.width,
                                             (unsigned) model->model.height)) < 0)
                goto fail;
        cam->format = info.pixel_formats & IMP_PIXEL_BIT(IMP_PIXEL_MONO16) ? IMP_PIXEL_MONO16
                      : info.pixel_formats & IMP_PIXEL_BIT(IMP_PIXEL_MONO12) ? IMP_PIXEL_MONO12
                      : IMP_PIXEL_MONO8;
        if ((r = imp_camera_set_pixel_format(cam->cam, cam->format)) < 0 && r != -EOPNOTSUPP)
                goto fail;
        if ((r = imp_camera_start(cam->cam, &(struct imp_camera_acq) { .n_buffers = 4,
                                                                        .software_trigger = true })) < 0)
                goto fail;
        cam->started = true;
        cam->state = DEV_OK;
        snprintf(cam->detail, sizeof cam->detail, "%s %s serial %s", info.vendor, info.model, info.serial);
        return 0;
fail:
        imp_camera_close(cam->cam);
        cam->cam = NULL;
        cam->state = r == -ENODEV || r == -ETIMEDOUT || r == -ECONNREFUSED ? DEV_ABSENT : DEV_FAULT;
        snprintf(cam->detail, sizeof cam->detail, "%s at %s: %s%s", cam->backend, cam->address, strerror(-r),
                 r == -EBUSY ? " (another controller holds it; one that died lets go after the camera's heartbeat "
                               "timeout, a few seconds: probe again)" : "");
        return imp_error_set(err, r, "camera %s: %s", cam->name, cam->detail);
}

static int open_dome(struct dev_dome *dd, struct imp_error *err) {
        int r = imp_dome_open(dd->backend, dd->address, DAEMON_DEVICE_TIMEOUT_MS, &dd->dome);
        if (r < 0) {
                dd->dome = NULL;
                dd->state = DEV_FAULT;
                snprintf(dd->detail, sizeof dd->detail, "%s at %s: %s", dd->backend, dd->address, strerror(-r));
                return imp_error_set(err, r, "dome %s: %s", dd->name, dd->detail);
        }
        struct imp_dome_info info = { 0 };
        (void) imp_dome_get_info(dd->dome, &info);
        dd->state = DEV_OK;
        snprintf(dd->detail, sizeof dd->detail, "%s, %u lights, %u axes", info.model, info.n_lights, info.n_axes);
        return 0;
}

static int open_projector(struct dev_projector *dp, struct imp_error *err) {
        int r = imp_projector_open(dp->backend, dp->address, DAEMON_DEVICE_TIMEOUT_MS, &dp->proj);
        if (r < 0) {
                dp->proj = NULL;
                dp->state = DEV_FAULT;
                snprintf(dp->detail, sizeof dp->detail, "%s at %s: %s", dp->backend, dp->address, strerror(-r));
                return imp_error_set(err, r, "projector %s: %s", dp->name, dp->detail);
        }
        struct imp_projector_info info = { 0 };
        (void) imp_projector_get_info(dp->proj, &info);
        dp->state = DEV_OK;
        snprintf(dp->detail, sizeof dp->detail, "%s serial %s, %dx%d", info.model, info.serial,
                 info.width, info.height);
        return 0;
}

static int open_stage(struct dev_stage *ds, struct imp_error *err) {
        int r = imp_stage_open(ds->backend, ds->address, DAEMON_DEVICE_TIMEOUT_MS, &ds->stage);
        if (r < 0) {
                ds->stage = NULL;
                ds->state = DEV_FAULT;
                snprintf(ds->detail, sizeof ds->detail, "%s at %s: %s", ds->backend, ds->address, strerror(-r));
                return imp_error_set(err, r, "stage %s: %s", ds->name, ds->detail);
        }
        struct imp_stage_info info = { 0 };
        (void) imp_stage_get_info(ds->stage, &info);
        ds->state = DEV_OK;
        snprintf(ds->detail, sizeof ds->detail, "%s, %u axes", info.model, info.n_axes);
        return 0;
}

int rigcfg_open_devices(struct rigcfg *rc, const struct imp_rig *rig, struct imp_error *err) {
        int first = 0, r;
        struct imp_error e = { 0 };
        for (int i = 0; i < rc->n_cameras; i++) {
                struct dev_camera *cam = &rc->cameras[i];
                /* Open, but released by its driver (gone after a grab timeout): a reopen is the
                 * only way back, else every trigger answers -ENOTCONN. */
                if (cam->cam && cam->started && !imp_camera_is_acquiring(cam->cam)) {
                        imp_camera_close(cam->cam);
                        cam->cam = NULL;
                        cam->started = false;
                }
        }
        for (int i = 0; i < rc->n_cameras; i++)
                if (!rc->cameras[i].cam && (r = open_camera(&rc->cameras[i], rig, rc->timeout_ms, first ? &e : err)) < 0 && !first)
                        first = r;
        if (rc->dome.configured && !rc->dome.dome && (r = open_dome(&rc->dome, first ? &e : err)) < 0 && !first)
                first = r;
        if (rc->projector.configured && !rc->projector.proj &&
            (r = open_projector(&rc->projector, first ? &e : err)) < 0 && !first)
                first = r;
        if (rc->stage.configured && !rc->stage.stage && (r = open_stage(&rc->stage, first ? &e : err)) < 0 && !first)
                first = r;
        return first;
}

void rigcfg_safe_state(struct rigcfg *rc) {
        if (rc->dome.dome)
                (void) imp_dome_all_off(rc->dome.dome);
        if (rc->projector.proj)
                (void) imp_projector_dark(rc->projector.proj);
}

json_t *rigcfg_devices_json(struct rigcfg *rc) {
        json_t *a = json_array();
        for (int i = 0; i < rc->n_cameras; i++) {
                struct dev_camera *c = &rc->cameras[i];
                json_array_append_new(a, json_pack("{s:s, s:s, s:s, s:s, s:s, s:s}", "name", c->name,
                                                   "class", "camera", "backend", c->backend, "address",
                                                   c->address, "state", dev_state_name(c->state),
                                                   "detail", c->detail));
        }
        if (rc->projector.configured)
                json_array_append_new(a, json_pack("{s:s, s:s, s:s, s:s, s:s, s:s}", "name",
                                                   rc->projector.name, "class", "projector", "backend",
                                                   rc->projector.backend, "address", rc->projector.address,
                                                   "state", dev_state_name(rc->projector.state),
                                                   "detail", rc->projector.detail));
        if (rc->dome.configured)
                json_array_append_new(a, json_pack("{s:s, s:s, s:s, s:s, s:s, s:s}", "name", rc->dome.name,
                                                   "class", "dome", "backend", rc->dome.backend,
                                                   "address", rc->dome.address, "state",
                                                   dev_state_name(rc->dome.state), "detail", rc->dome.detail));
        if (rc->stage.configured)
                json_array_append_new(a, json_pack("{s:s, s:s, s:s, s:s, s:s, s:s}", "name", rc->stage.name,
                                                   "class", "stage", "backend", rc->stage.backend,
                                                   "address", rc->stage.address, "state",
                                                   dev_state_name(rc->stage.state), "detail", rc->stage.detail));
        return a;
}

/* ---- `devices` off the event loop ------------------------------------------------------------ */

/* Opening an absent camera takes its whole timeout (seconds): done in a thread so the loop
 * keeps serving, with the rig's cameras copied so that a calibration made current meanwhile
 * does not change what the thread reads. */
struct device_probe {
        struct daemon *d;
        pthread_t thread;
        int efd;                        /* the thread's "done" to the loop */
        sd_event_source *src;
        device_probe_done_fn done;
        json_t *snapshot;               /* the devices before the probe, served meanwhile */
        struct imp_rig rig;
        bool have_rig;
        uint64_t t0_us;
};

/* A device open since earlier may be unplugged by now: one control read of each (as
 * arv-tool does); one that does not answer is closed and opened again below, so that an
 * unplugged rig never shows `ok` from the cache. */
static void check_open_devices(struct rigcfg *rc) {
        for (int i = 0; i < rc->n_cameras; i++) {
                struct dev_camera *cam = &rc->cameras[i];
                struct imp_camera_info info;
                int r = cam->cam ? imp_camera_get_info(cam->cam, &info) : 0;
                if (r >= 0)
                        continue;
                rigcfg_drop_camera(cam);
                cam->state = DEV_ABSENT;
                snprintf(cam->detail, sizeof cam->detail, "stopped answering (%s)", strerror(-r));
        }
        struct imp_dome_state ds;
        int r = rc->dome.dome ? imp_dome_get_state(rc->dome.dome, &ds) : 0;
        if (r < 0) {
                imp_dome_close(rc->dome.dome);
                rc->dome.dome = NULL;
                rc->dome.state = DEV_ABSENT;
                snprintf(rc->dome.detail, sizeof rc->dome.detail, "stopped answering (%s)", strerror(-r));
        }
        struct imp_projector_status ps;
        r = rc->projector.proj ? imp_projector_get_status(rc->projector.proj, &ps) : 0;
        if (r < 0 && r != -EOPNOTSUPP) {
                imp_projector_close(rc->projector.proj);
                rc->projector.proj = NULL;
                rc->projector.state = DEV_ABSENT;
                snprintf(rc->projector.detail, sizeof rc->projector.detail, "stopped answering (%s)", strerror(-r));
        }
}

static void *probe_thread(void *userdata) {
        struct device_probe *pr = userdata;
        check_open_devices(pr->d->rigcfg);
        (void) rigcfg_open_devices(pr->d->rigcfg, pr->have_rig ? &pr->rig : NULL, NULL);
        uint64_t one = 1;
        (void) !write(pr->efd, &one, sizeof one);
        return NULL;
}

static void probe_free(struct device_probe *pr) {
        pthread_join(pr->thread, NULL);
        sd_event_source_disable_unref(pr->src);
        close(pr->efd);
        json_decref(pr->snapshot);
        if (pr->have_rig)
                imp_rig_free(&pr->rig);
        free(pr);
}

static int on_probe_done(sd_event_source *src, int fd, uint32_t revents, void *userdata) {
        struct device_probe *pr = userdata;
        struct daemon *d = pr->d;
        device_probe_done_fn done = pr->done;
        uint64_t now = 0;
        (void) sd_event_now(d->event, CLOCK_MONOTONIC, &now);
        log_debug("devices probed in %.3f s", (double) (now - pr->t0_us) / 1e6);
        d->probe = NULL;
        probe_free(pr);
        done(d, rigcfg_devices_json(d->rigcfg));
        return 0;
}

int device_probe_start(struct daemon *d, device_probe_done_fn done) {
        if (d->probe)
                return -EBUSY;
        struct device_probe *pr = calloc(1, sizeof *pr);
        if (!pr)
                return -ENOMEM;
        pr->d = d;
        pr->done = done;
        pr->efd = eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK);
        pr->snapshot = rigcfg_devices_json(d->rigcfg);
        pr->have_rig = d->have_rig && imp_rig_copy(&d->rig, &pr->rig) == 0;
        (void) sd_event_now(d->event, CLOCK_MONOTONIC, &pr->t0_us);
        int r = pr->efd < 0 ? negative_errno() : sd_event_add_io(d->event, &pr->src, pr->efd, EPOLLIN, on_probe_done, pr);
        if (r >= 0 && (r = -pthread_create(&pr->thread, NULL, probe_thread, pr)) < 0)
                pr->src = sd_event_source_disable_unref(pr->src);
        if (r < 0) {
                if (pr->efd >= 0)
                        close(pr->efd);
                json_decref(pr->snapshot);
                if (pr->have_rig)
                        imp_rig_free(&pr->rig);
                free(pr);
                return r;
        }
        d->probe = pr;
        return 0;
}

json_t *device_probe_snapshot(struct daemon *d) {
        return d->probe ? json_deep_copy(d->probe->snapshot) : rigcfg_devices_json(d->rigcfg);
}

void device_probe_wait(struct daemon *d) {
        if (!d->probe)
                return;
        probe_free(d->probe);
        d->probe = NULL;
}
