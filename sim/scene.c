/* Scene loading: libconfig file → painting surface, per-texel BRDF map, rig, effect list.
 * The format is documented by config/scenes/demo.cfg. Every error names FILE:LINE: FIELD. */
#include <libgen.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "conf.h"
#include "scene.h"

static const char *const effect_names[IMP_FX_COUNT + 1] = {
        [IMP_FX_DIRECT] = "direct", [IMP_FX_SHADOWS] = "shadows", [IMP_FX_PROJECTOR] = "projector",
        [IMP_FX_INDIRECT] = "indirect", [IMP_FX_AMBIENT] = "ambient", [IMP_FX_NOISE] = "noise",
        [IMP_FX_BAYER] = "bayer", [IMP_FX_DISTORTION] = "distortion", [IMP_FX_VIGNETTING] = "vignetting",
        [IMP_FX_DEFOCUS] = "defocus", [IMP_FX_DROPPED_FRAME] = "dropped_frame",
        [IMP_FX_HOT_PIXELS] = "hot_pixels", [IMP_FX_STAGE_ERROR] = "stage_error", [IMP_FX_COUNT] = NULL,
};

const char *imp_sim_effect_name(enum imp_sim_effect fx) {
        return fx < IMP_FX_COUNT ? effect_names[fx] : "?";
}

int imp_sim_effect_from_name(const char *name) {
        for (int i = 0; i < IMP_FX_COUNT; i++)
                if (name && !strcmp(name, effect_names[i]))
                        return i;
        return -EINVAL;
}

struct imp_scene {
        char name[64];
        char dir[512];                 /* directory of the scene file, for relative paths */
        uint64_t seed;
        bool fx[IMP_FX_COUNT];
        double ambient;
        long long *dropped;
        int n_dropped;
        double hot_fraction, hot_e_per_s;
        struct imp_indirect_params ind;
        struct imp_rig rig;
        struct imp_scene_camera_opts camopts[4];
        struct imp_sim_surface surf;
        float *height, *normals, *albedo, *tint;
        uint8_t *is_frame, *region;
        struct imp_scene_region regions[IMP_SCENE_MAX_REGIONS];
        int n_regions;
        double hmin, hmax, frame_height_mm, frame_width_mm;
        int n_layers;
        double plane_slope[2], plane_offset_mm;   /* the last plane layer (checker boards lie on it) */
        /* What the surface is built from (kept so that a gantry scene rebuilds it per window). */
        struct imp_layer *layers;
        struct imp_shape shapes[IMP_SCENE_MAX_REGIONS];
        int n_shapes;
        double canvas_mm[2], pitch_mm;
        /* Gantry scenes (imp_scene_is_gantry): the surface is a window of the painting. */
        bool gantry;
        struct imp_scene_gantry gantry_params;
        struct imp_stage_error stage_error;
        struct imp_painting_place place;          /* the window's placement on the painting */
        double window_mm[4];                      /* world x0, y0, x1, y1 of the window */
};

void imp_scene_free(struct imp_scene *s) {
        if (!s)
                return;
        imp_rig_free(&s->rig);
        free(s->dropped);
        free(s->height);
        free(s->normals);
        free(s->albedo);
        free(s->tint);
        free(s->is_frame);
        free(s->region);
        free(s->layers);
        free(s);
}

/* ---- accessors ---- */
const char *imp_scene_name(const struct imp_scene *s) { return s->name; }
uint64_t imp_scene_seed(const struct imp_scene *s) { return s->seed; }
void imp_scene_set_seed(struct imp_scene *s, uint64_t seed) { s->seed = seed; s->ind.seed = seed; }
bool imp_scene_has_effect(const struct imp_scene *s, enum imp_sim_effect fx) {
        return fx < IMP_FX_COUNT && s->fx[fx];
}
const struct imp_rig *imp_scene_rig(const struct imp_scene *s) { return &s->rig; }
const struct imp_scene_camera_opts *imp_scene_camera_opts(const struct imp_scene *s, int cam) {
        return cam >= 0 && cam < s->rig.n_cameras ? &s->camopts[cam] : NULL;
}
int imp_scene_camera_index(const struct imp_scene *s, const char *name) {
        for (int i = 0; i < s->rig.n_cameras; i++)
                if (!strcmp(s->rig.cameras[i].name, name))
                        return i;
        return -ENOENT;
}
int imp_scene_light_index(const struct imp_scene *s, int id) {
        for (int i = 0; i < s->rig.n_lights; i++)
                if (s->rig.lights[i].id == id)
                        return i;
        return -ENOENT;
}
const struct imp_sim_surface *imp_scene_surface(const struct imp_scene *s) { return &s->surf; }
const float *imp_scene_normals(const struct imp_scene *s) { return s->normals; }
const uint8_t *imp_scene_region_map(const struct imp_scene *s) { return s->region; }
const float *imp_scene_tint(const struct imp_scene *s) { return s->tint; }
const struct imp_scene_region *imp_scene_regions(const struct imp_scene *s, int *ret_n) {
        if (ret_n)
                *ret_n = s->n_regions;
        return s->regions;
}
void imp_scene_texel_brdf(const struct imp_scene *s, size_t i, struct imp_lafortune *ret) {
        *ret = s->regions[s->region[i]].brdf;
        for (int c = 0; c < 3; c++)
                ret->rho_d[c] *= s->tint[i];
}
double imp_scene_max_height_mm(const struct imp_scene *s) { return s->hmax; }
double imp_scene_min_height_mm(const struct imp_scene *s) { return s->hmin; }
double imp_scene_frame_height_mm(const struct imp_scene *s) { return s->frame_height_mm; }
double imp_scene_ambient(const struct imp_scene *s) { return s->ambient; }
bool imp_scene_frame_dropped(const struct imp_scene *s, long long seq) {
        for (int i = 0; i < s->n_dropped; i++)
                if (s->dropped[i] == seq)
                        return true;
        return false;
}
double imp_scene_hot_pixel_fraction(const struct imp_scene *s) { return s->hot_fraction; }
double imp_scene_hot_pixel_e_per_s(const struct imp_scene *s) { return s->hot_e_per_s; }
void imp_scene_indirect_params(const struct imp_scene *s, struct imp_indirect_params *ret) { *ret = s->ind; }

static int make_albedo(struct imp_scene *s) {
        if (s->albedo)
                return 0;
        size_t n = (size_t) s->surf.nx * s->surf.ny;
        s->albedo = malloc(n * 3 * sizeof(float));
        if (!s->albedo)
                return -ENOMEM;
        for (size_t i = 0; i < n; i++)
                for (int c = 0; c < 3; c++)
                        s->albedo[3 * i + c] = s->regions[s->region[i]].brdf.rho_d[c] * s->tint[i];
        s->surf.albedo = s->albedo;
        return 0;
}

int imp_scene_set_effect(struct imp_scene *s, enum imp_sim_effect fx, bool on) {
        if (fx >= IMP_FX_COUNT)
                return -EINVAL;
        s->fx[fx] = on;
        if (fx == IMP_FX_BAYER)
                for (int i = 0; i < s->rig.n_cameras; i++)
                        s->rig.cameras[i].sensor.bayer = on;
        if (fx == IMP_FX_INDIRECT && on)
                return make_albedo(s);
        return 0;
}

/* ---- parsing helpers ---- */
#define TRY(expr) do { int r_ = (expr); if (r_ < 0) return r_; } while (0)

static int line_of(const config_setting_t *s) { return s ? config_setting_source_line(s) : 0; }

static int get_vec3(const struct imp_conf *c, const config_setting_t *g, const char *name, bool req,
                    double v[3], struct imp_error *err) {
        return imp_conf_get_doubles(c, g, name, req, 3, v, 3, NULL, err);
}

static int get_unit_vec3(const struct imp_conf *c, const config_setting_t *g, const char *name, bool req,
                         double v[3], struct imp_error *err) {
        TRY(get_vec3(c, g, name, req, v, err));
        double n = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        if (!(n > 1e-12))
                return imp_error_set(err, -EINVAL, "%s:%d: %s.%s: expected a non-zero vector",
                                     imp_conf_path(c), line_of(g), imp_conf_setting_path(g), name);
        for (int i = 0; i < 3; i++)
                v[i] /= n;
        return 0;
}

static int parse_stage_error(struct imp_scene *s, const struct imp_conf *c, const config_setting_t *g,
                             struct imp_error *err) {
        static const char *const known[] = { "sigma_mm", "backlash_mm", "sigma_deg", NULL };
        config_setting_t *eg = NULL;
        s->stage_error = (struct imp_stage_error) { .sigma_mm = 0.05, .backlash_mm = 0.0, .sigma_deg = 0.05 };
        TRY(imp_conf_get_group(c, g, "stage_error", false, &eg, err));
        if (!eg)
                return 0;
        TRY(imp_conf_check_known(c, eg, known, err));
        TRY(imp_conf_get_double(c, eg, "sigma_mm", false, 0, 10, &s->stage_error.sigma_mm, err));
        TRY(imp_conf_get_double(c, eg, "backlash_mm", false, 0, 10, &s->stage_error.backlash_mm, err));
        TRY(imp_conf_get_double(c, eg, "sigma_deg", false, 0, 5, &s->stage_error.sigma_deg, err));
        return 0;
}

static int parse_scene_group(struct imp_scene *s, const struct imp_conf *c, struct imp_error *err) {
        static const char *const known[] = { "name", "seed", "effects", "ambient", "dropped_frames",
                                             "hot_pixels", "indirect", "stage_error", NULL };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, NULL, "scene", true, &g, err));
        TRY(imp_conf_check_known(c, g, known, err));
        const char *name = "scene";
        TRY(imp_conf_get_string(c, g, "name", false, &name, err));
        snprintf(s->name, sizeof s->name, "%s", name);
        long long seed = 1;
        TRY(imp_conf_get_int(c, g, "seed", false, 0, INT64_MAX, &seed, err));
        s->seed = (uint64_t) seed;

        config_setting_t *fl = NULL;
        TRY(imp_conf_get_list(c, g, "effects", true, &fl, err));
        for (int i = 0; i < config_setting_length(fl); i++) {
                config_setting_t *e = config_setting_get_elem(fl, i);
                const char *fxn = config_setting_get_string(e);
                int fx = imp_sim_effect_from_name(fxn);
                if (fx < 0) {
                        char all[256] = "";
                        for (int k = 0; k < IMP_FX_COUNT; k++)
                                snprintf(all + strlen(all), sizeof all - strlen(all), "%s%s", k ? ", " : "",
                                         effect_names[k]);
                        return imp_error_set(err, -EINVAL, "%s:%d: scene.effects.[%d]: unknown effect %s%s%s (expected one of: %s)",
                                             imp_conf_path(c), line_of(e), i, fxn ? "\"" : "",
                                             fxn ? fxn : "(not a string)", fxn ? "\"" : "", all);
                }
                s->fx[fx] = true;
        }
        TRY(imp_conf_get_double(c, g, "ambient", false, 0, 100, &s->ambient, err));

        config_setting_t *dl = config_setting_lookup(g, "dropped_frames");
        if (dl) {
                if (!config_setting_is_aggregate(dl))
                        return imp_error_set(err, -EINVAL, "%s:%d: scene.dropped_frames: expected a list of frame indices",
                                             imp_conf_path(c), line_of(dl));
                int n = config_setting_length(dl);
                s->dropped = calloc(n > 0 ? n : 1, sizeof *s->dropped);
                if (!s->dropped)
                        return -ENOMEM;
                for (int i = 0; i < n; i++) {
                        config_setting_t *e = config_setting_get_elem(dl, i);
                        int t = config_setting_type(e);
                        if ((t != CONFIG_TYPE_INT && t != CONFIG_TYPE_INT64) || config_setting_get_int64(e) < 0)
                                return imp_error_set(err, -EINVAL, "%s:%d: scene.dropped_frames.[%d]: expected a frame index >= 0",
                                                     imp_conf_path(c), line_of(e), i);
                        s->dropped[i] = config_setting_get_int64(e);
                }
                s->n_dropped = n;
        }
        s->hot_fraction = 1e-4;
        s->hot_e_per_s = 2e5;
        TRY(imp_conf_get_double(c, g, "hot_pixels.fraction", false, 0, 0.1, &s->hot_fraction, err));
        TRY(imp_conf_get_double(c, g, "hot_pixels.e_per_s", false, 0, 1e9, &s->hot_e_per_s, err));

        TRY(parse_stage_error(s, c, g, err));
        s->ind = (struct imp_indirect_params) { .canvas_pitch_mm = 2.0, .frame_pitch_mm = 4.0,
                                                .paths_per_vertex = 32, .max_bounces = 1, .simplify = 4,
                                                .seed = s->seed };
        config_setting_t *ig = NULL;
        TRY(imp_conf_get_group(c, g, "indirect", false, &ig, err));
        if (ig) {
                long long v;
                TRY(imp_conf_get_double(c, ig, "canvas_pitch_mm", false, 0.01, 100, &s->ind.canvas_pitch_mm, err));
                TRY(imp_conf_get_double(c, ig, "frame_pitch_mm", false, 0.01, 100, &s->ind.frame_pitch_mm, err));
                v = s->ind.paths_per_vertex;
                TRY(imp_conf_get_int(c, ig, "paths_per_vertex", false, 1, 1 << 20, &v, err));
                s->ind.paths_per_vertex = (int) v;
                v = s->ind.max_bounces;
                TRY(imp_conf_get_int(c, ig, "max_bounces", false, 1, 16, &v, err));
                s->ind.max_bounces = (int) v;
                v = s->ind.simplify;
                TRY(imp_conf_get_int(c, ig, "simplify", false, 1, 64, &v, err));
                s->ind.simplify = (int) v;
        }
        return 0;
}

/* Intrinsics, distortion and pose shared by cameras and the projector. */
static int parse_pinhole(const struct imp_conf *c, const config_setting_t *g, struct imp_pinhole *m,
                         struct imp_error *err) {
        long long w = 0, h = 0;
        TRY(imp_conf_get_int(c, g, "width", true, 1, 100000, &w, err));
        TRY(imp_conf_get_int(c, g, "height", true, 1, 100000, &h, err));
        m->width = (int) w;
        m->height = (int) h;
        TRY(imp_conf_get_double(c, g, "fx", true, 1e-3, 1e7, &m->fx, err));
        m->fy = m->fx;
        TRY(imp_conf_get_double(c, g, "fy", false, 1e-3, 1e7, &m->fy, err));
        m->cx = 0.5 * (m->width - 1);
        m->cy = 0.5 * (m->height - 1);
        TRY(imp_conf_get_double(c, g, "cx", false, -1e6, 1e6, &m->cx, err));
        TRY(imp_conf_get_double(c, g, "cy", false, -1e6, 1e6, &m->cy, err));
        TRY(imp_conf_get_double(c, g, "k1", false, -10, 10, &m->k1, err));
        TRY(imp_conf_get_double(c, g, "k2", false, -10, 10, &m->k2, err));
        TRY(imp_conf_get_double(c, g, "k3", false, -10, 10, &m->k3, err));
        TRY(imp_conf_get_double(c, g, "p1", false, -1, 1, &m->p1, err));
        TRY(imp_conf_get_double(c, g, "p2", false, -1, 1, &m->p2, err));
        double eye[3], target[3], right[3] = { 1, 0, 0 };
        TRY(get_vec3(c, g, "pos_mm", true, eye, err));
        TRY(get_vec3(c, g, "look_at_mm", true, target, err));
        TRY(get_unit_vec3(c, g, "right", false, right, err));
        double d[3] = { target[0] - eye[0], target[1] - eye[1], target[2] - eye[2] };
        double dl = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        double dot = dl > 0 ? fabs(d[0] * right[0] + d[1] * right[1] + d[2] * right[2]) / dl : 1;
        if (!(dl > 0) || dot > 0.999)
                return imp_error_set(err, -EINVAL, "%s:%d: %s.look_at_mm: expected a target away from pos_mm and not along `right`",
                                     imp_conf_path(c), line_of(g), imp_conf_setting_path(g));
        imp_pinhole_look_at(m, eye, target, right);
        return 0;
}

static int parse_sensor(const struct imp_conf *c, const config_setting_t *cam, struct imp_sensor *sn,
                        struct imp_error *err) {
        static const char *const known[] = { "bits", "black_level_dn", "gain_e_per_dn", "read_noise_e",
                                             "full_well_e", "dark_current_e_per_s", "prnu", "quantum_scale",
                                             "readout_us", NULL };
        *sn = (struct imp_sensor) { .bits = 12, .black_level_dn = 64, .gain_e_per_dn = 2.5, .read_noise_e = 3,
                                    .full_well_e = 10000, .dark_current_e_per_s = 10, .prnu = 0.005,
                                    .quantum_scale = 7e5, .readout_us = 30000 };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, cam, "sensor", false, &g, err));
        if (!g)
                return 0;
        TRY(imp_conf_check_known(c, g, known, err));
        long long bits = sn->bits;
        TRY(imp_conf_get_int(c, g, "bits", false, 8, 16, &bits, err));
        if (bits != 8 && bits != 10 && bits != 12 && bits != 14 && bits != 16)
                return imp_error_set(err, -EINVAL, "%s:%d: %s.bits: expected 8, 10, 12, 14 or 16, got %lld",
                                     imp_conf_path(c), line_of(config_setting_lookup(g, "bits")),
                                     imp_conf_setting_path(g), bits);
        sn->bits = (int) bits;
        TRY(imp_conf_get_double(c, g, "black_level_dn", false, 0, 65535, &sn->black_level_dn, err));
        TRY(imp_conf_get_double(c, g, "gain_e_per_dn", false, 1e-3, 1e4, &sn->gain_e_per_dn, err));
        TRY(imp_conf_get_double(c, g, "read_noise_e", false, 0, 1e4, &sn->read_noise_e, err));
        TRY(imp_conf_get_double(c, g, "full_well_e", false, 1, 1e7, &sn->full_well_e, err));
        TRY(imp_conf_get_double(c, g, "dark_current_e_per_s", false, 0, 1e7, &sn->dark_current_e_per_s, err));
        TRY(imp_conf_get_double(c, g, "prnu", false, 0, 0.5, &sn->prnu, err));
        TRY(imp_conf_get_double(c, g, "quantum_scale", false, 1e-6, 1e12, &sn->quantum_scale, err));
        TRY(imp_conf_get_double(c, g, "readout_us", false, 0, 1e7, &sn->readout_us, err));
        return 0;
}

static int parse_cameras(struct imp_scene *s, const struct imp_conf *c, const config_setting_t *rig,
                         struct imp_error *err) {
        static const char *const known[] = { "name", "width", "height", "fx", "fy", "cx", "cy", "k1", "k2",
                                             "k3", "p1", "p2", "pos_mm", "look_at_mm", "right", "sensor",
                                             "colour", "defocus_px", NULL };
        config_setting_t *l = NULL;
        TRY(imp_conf_get_list(c, rig, "cameras", true, &l, err));
        int n = config_setting_length(l);
        if (n < 1 || n > (int) ARRAY_SIZE(s->rig.cameras))
                return imp_error_set(err, -EINVAL, "%s:%d: rig.cameras: expected 1 to %zu cameras, got %d",
                                     imp_conf_path(c), line_of(l), ARRAY_SIZE(s->rig.cameras), n);
        for (int i = 0; i < n; i++) {
                config_setting_t *g = config_setting_get_elem(l, i);
                struct imp_rig_camera *cam = &s->rig.cameras[i];
                if (!config_setting_is_group(g))
                        return imp_error_set(err, -EINVAL, "%s:%d: rig.cameras.[%d]: expected a group",
                                             imp_conf_path(c), line_of(g), i);
                TRY(imp_conf_check_known(c, g, known, err));
                const char *name = NULL;
                TRY(imp_conf_get_string(c, g, "name", true, &name, err));
                if (!*name || strlen(name) >= sizeof cam->name)
                        return imp_error_set(err, -EINVAL, "%s:%d: rig.cameras.[%d].name: expected 1 to %zu characters",
                                             imp_conf_path(c), line_of(g), i, sizeof cam->name - 1);
                for (int k = 0; k < i; k++)
                        if (!strcmp(s->rig.cameras[k].name, name))
                                return imp_error_set(err, -EINVAL, "%s:%d: rig.cameras.[%d].name: duplicate camera \"%s\"",
                                                     imp_conf_path(c), line_of(g), i, name);
                snprintf(cam->name, sizeof cam->name, "%s", name);
                TRY(parse_pinhole(c, g, &cam->model, err));
                TRY(parse_sensor(c, g, &cam->sensor, err));
                TRY(imp_conf_get_bool(c, g, "colour", false, &s->camopts[i].colour, err));
                s->camopts[i].defocus_px = 0.8;
                TRY(imp_conf_get_double(c, g, "defocus_px", false, 0, 50, &s->camopts[i].defocus_px, err));
                s->rig.n_cameras = i + 1;
        }
        return 0;
}

static int parse_projector(struct imp_scene *s, const struct imp_conf *c, const config_setting_t *rig,
                           struct imp_error *err) {
        static const char *const known[] = { "name", "width", "height", "fx", "fy", "cx", "cy", "k1", "k2",
                                             "k3", "p1", "p2", "pos_mm", "look_at_mm", "right", "gamma",
                                             "black_level", "intensity", "defocus_px", NULL };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, rig, "projector", false, &g, err));
        if (!g)
                return 0;
        TRY(imp_conf_check_known(c, g, known, err));
        struct imp_rig_projector *p = &s->rig.projector;
        const char *name = "projector";
        TRY(imp_conf_get_string(c, g, "name", false, &name, err));
        snprintf(p->name, sizeof p->name, "%s", name);
        TRY(parse_pinhole(c, g, &p->model, err));
        p->gamma = 2.2;
        p->black_level = 0.01;
        p->intensity = 0.1;
        p->defocus_px = 1.0;
        TRY(imp_conf_get_double(c, g, "gamma", false, 0.1, 10, &p->gamma, err));
        TRY(imp_conf_get_double(c, g, "black_level", false, 0, 1, &p->black_level, err));
        TRY(imp_conf_get_double(c, g, "intensity", false, 0, 1e6, &p->intensity, err));
        if (!(p->intensity > 0))
                return imp_error_set(err, -EINVAL, "%s:%d: rig.projector.intensity: expected > 0 (a dark projector "
                                     "measures nothing)", imp_conf_path(c),
                                     line_of(config_setting_lookup((config_setting_t *) g, "intensity")));
        TRY(imp_conf_get_double(c, g, "defocus_px", false, 0, 50, &p->defocus_px, err));
        s->rig.has_projector = true;
        return 0;
}

static void light_towards(struct imp_rig_light *L, const double target[3]) {
        double d[3] = { target[0] - L->pos_mm[0], target[1] - L->pos_mm[1], target[2] - L->pos_mm[2] };
        double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        for (int i = 0; i < 3; i++)
                L->axis[i] = n > 0 ? d[i] / n : (i == 2 ? -1 : 0);
}

static int parse_dome(struct imp_scene *s, const struct imp_conf *c, const config_setting_t *rig,
                      struct imp_error *err) {
        static const char *const known[] = { "centre_mm", "radius_mm", "intensity", "profile_exp", "colour",
                                             "rings", "lights", NULL };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, rig, "dome", false, &g, err));
        if (!g)
                return 0;
        TRY(imp_conf_check_known(c, g, known, err));
        double centre[3] = { 0.5 * (s->surf.canvas_min_mm[0] + s->surf.canvas_max_mm[0]),
                             0.5 * (s->surf.canvas_min_mm[1] + s->surf.canvas_max_mm[1]), 0 };
        double radius = 500, intensity = 0.25, pexp = 1, colour[3] = { 1, 1, 1 };
        TRY(get_vec3(c, g, "centre_mm", false, centre, err));
        TRY(imp_conf_get_double(c, g, "radius_mm", false, 1, 1e5, &radius, err));
        TRY(imp_conf_get_double(c, g, "intensity", false, 0, 1e6, &intensity, err));
        if (!(intensity > 0))
                return imp_error_set(err, -EINVAL, "%s:%d: rig.dome.intensity: expected > 0 (dark lights measure "
                                     "nothing)", imp_conf_path(c),
                                     line_of(config_setting_lookup((config_setting_t *) g, "intensity")));
        TRY(imp_conf_get_double(c, g, "profile_exp", false, 0, 1000, &pexp, err));
        TRY(get_vec3(c, g, "colour", false, colour, err));
        config_setting_t *rings = NULL, *lights = NULL;
        TRY(imp_conf_get_list(c, g, "rings", false, &rings, err));
        TRY(imp_conf_get_list(c, g, "lights", false, &lights, err));
        if (!rings == !lights)
                return imp_error_set(err, -EINVAL, "%s:%d: rig.dome: expected exactly one of `rings` or `lights`",
                                     imp_conf_path(c), line_of(g));
        struct imp_rig_light tmpl = { .intensity = intensity, .profile_exp = pexp,
                                      .colour = { colour[0], colour[1], colour[2] } };
        int total = 0;
        if (rings) {
                static const char *const rknown[] = { "elevation_deg", "count", "azimuth_offset_deg", NULL };
                for (int i = 0; i < config_setting_length(rings); i++) {
                        config_setting_t *rg = config_setting_get_elem(rings, i);
                        long long cnt = 0;
                        TRY(imp_conf_check_known(c, rg, rknown, err));
                        TRY(imp_conf_get_int(c, rg, "count", true, 1, 4096, &cnt, err));
                        total += (int) cnt;
                }
        } else {
                total = config_setting_length(lights);
        }
        s->rig.lights = calloc(total > 0 ? total : 1, sizeof *s->rig.lights);
        if (!s->rig.lights)
                return -ENOMEM;
        int n = 0;
        for (int i = 0; rings && i < config_setting_length(rings); i++) {
                config_setting_t *rg = config_setting_get_elem(rings, i);
                double el = 0, az0 = 0;
                long long cnt = 0;
                TRY(imp_conf_get_double(c, rg, "elevation_deg", true, 0.5, 90, &el, err));
                TRY(imp_conf_get_double(c, rg, "azimuth_offset_deg", false, -360, 360, &az0, err));
                TRY(imp_conf_get_int(c, rg, "count", true, 1, 4096, &cnt, err));
                for (int k = 0; k < cnt; k++) {
                        struct imp_rig_light *L = &s->rig.lights[n];
                        *L = tmpl;
                        L->id = n;
                        double e = el * M_PI / 180, a = (az0 + 360.0 * k / cnt) * M_PI / 180;
                        L->pos_mm[0] = centre[0] + radius * cos(e) * cos(a);
                        L->pos_mm[1] = centre[1] + radius * cos(e) * sin(a);
                        L->pos_mm[2] = centre[2] + radius * sin(e);
                        light_towards(L, centre);
                        n++;
                        s->rig.n_lights = n;
                }
        }
        static const char *const lknown[] = { "id", "pos_mm", "intensity", "axis", "profile_exp", "colour", NULL };
        for (int i = 0; lights && i < config_setting_length(lights); i++) {
                config_setting_t *lg = config_setting_get_elem(lights, i);
                struct imp_rig_light *L = &s->rig.lights[n];
                *L = tmpl;
                long long id = i;
                TRY(imp_conf_check_known(c, lg, lknown, err));
                TRY(imp_conf_get_int(c, lg, "id", false, 0, 1 << 20, &id, err));
                for (int k = 0; k < n; k++)
                        if (s->rig.lights[k].id == id)
                                return imp_error_set(err, -EINVAL, "%s:%d: rig.dome.lights.[%d].id: duplicate light id %lld",
                                                     imp_conf_path(c), line_of(lg), i, id);
                L->id = (int) id;
                TRY(get_vec3(c, lg, "pos_mm", true, L->pos_mm, err));
                TRY(imp_conf_get_double(c, lg, "intensity", false, 0, 1e6, &L->intensity, err));
                if (!(L->intensity > 0))
                        return imp_error_set(err, -EINVAL, "%s:%d: rig.dome.lights.[%d].intensity: expected > 0",
                                             imp_conf_path(c), line_of(lg), i);
                TRY(imp_conf_get_double(c, lg, "profile_exp", false, 0, 1000, &L->profile_exp, err));
                TRY(get_vec3(c, lg, "colour", false, L->colour, err));
                light_towards(L, centre);
                TRY(get_unit_vec3(c, lg, "axis", false, L->axis, err));
                n++;
                s->rig.n_lights = n;
        }
        return 0;
}

static int parse_rig(struct imp_scene *s, const struct imp_conf *c, struct imp_error *err) {
        static const char *const known[] = { "cameras", "projector", "dome", "settle_us", NULL };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, NULL, "rig", true, &g, err));
        TRY(imp_conf_check_known(c, g, known, err));
        s->rig.settle_us = 2000;
        TRY(imp_conf_get_double(c, g, "settle_us", false, 0, 1e7, &s->rig.settle_us, err));
        TRY(parse_cameras(s, c, g, err));
        TRY(parse_projector(s, c, g, err));
        TRY(parse_dome(s, c, g, err));
        for (int i = 0; i < s->rig.n_cameras; i++)
                s->rig.cameras[i].sensor.bayer = s->fx[IMP_FX_BAYER];
        return 0;
}

/* ---- painting ---- */
static int parse_brdf(const struct imp_conf *c, const config_setting_t *g, struct imp_lafortune *b,
                      struct imp_error *err) {
        double rd[3] = { 0.8, 0.8, 0.8 }, rs[3] = { 0, 0, 0 }, lobe[3] = { -1, -1, 1 }, k = 10;
        TRY(get_vec3(c, g, "rho_d", false, rd, err));
        TRY(get_vec3(c, g, "rho_s", false, rs, err));
        TRY(get_vec3(c, g, "lobe", false, lobe, err));
        TRY(imp_conf_get_double(c, g, "k", false, 0, 10000, &k, err));
        /* A lobe exponent k <= 0 is no lobe (the fit's model cannot hold it); a diffuse
         * albedo above 1 reflects more than it receives. */
        if (!(k > 0))
                return imp_error_set(err, -EINVAL, "%s:%d: %s.k: expected a lobe exponent > 0, got %g",
                                     imp_conf_path(c), line_of(config_setting_lookup((config_setting_t *) g, "k")),
                                     imp_conf_setting_path(g), k);
        for (int i = 0; i < 3; i++)
                if (!(rd[i] >= 0 && rd[i] <= 1 && rs[i] >= 0 && rs[i] <= 1000))
                        return imp_error_set(err, -EINVAL, "%s:%d: %s: expected rho_d in [0, 1] (physical diffuse "
                                             "albedo) and rho_s in [0, 1000], got rho_d %g, rho_s %g",
                                             imp_conf_path(c), line_of(g), imp_conf_setting_path(g), rd[i], rs[i]);
        for (int i = 0; i < 3; i++) {
                b->rho_d[i] = (float) rd[i];
                b->rho_s[i] = (float) rs[i];
        }
        b->cx = (float) lobe[0];
        b->cy = (float) lobe[1];
        b->cz = (float) lobe[2];
        b->k = (float) k;
        return 0;
}

static int parse_layer(const struct imp_conf *c, const config_setting_t *g, int idx, uint64_t seed,
                       const char *dir, struct imp_layer *L, struct imp_error *err) {
        static const char *const types[] = { "weave", "strokes", "ridge", "craquelure", "step", "file",
                                             "plane", "sphere", NULL };
        static const char *const known[] = { "type", "amplitude_mm", "period_mm", "width_mm", "length_mm",
                                             "cliff_mm", "start_mm", "end_mm", "at_mm", "axis", "count",
                                             "seed", "path", "slope", "offset_mm", "centre_mm", "radius_mm",
                                             NULL };
        int kind = 0;
        TRY(imp_conf_check_known(c, g, known, err));
        TRY(imp_conf_get_enum(c, g, "type", true, types, &kind, err));
        *L = (struct imp_layer) { .kind = kind, .seed = imp_mix64(seed + 101 * (uint64_t) (idx + 1)) };
        long long v = 0;
        TRY(imp_conf_get_int(c, g, "seed", false, 0, INT64_MAX, &v, err));
        if (config_setting_lookup((config_setting_t *) g, "seed"))
                L->seed = (uint64_t) v;
        bool amp_req = kind != IMP_LAYER_FILE && kind != IMP_LAYER_PLANE && kind != IMP_LAYER_SPHERE;
        L->amplitude_mm = 1.0;
        TRY(imp_conf_get_double(c, g, "amplitude_mm", amp_req, -20, 20, &L->amplitude_mm, err));
        switch (kind) {
        case IMP_LAYER_WEAVE:
                TRY(imp_conf_get_double(c, g, "period_mm", true, 0.01, 100, &L->period_mm, err));
                break;
        case IMP_LAYER_STROKES:
                L->count = 100;
                L->width_mm = 2;
                L->length_mm = 10;
                v = L->count;
                TRY(imp_conf_get_int(c, g, "count", false, 0, 1000000, &v, err));
                L->count = (int) v;
                TRY(imp_conf_get_double(c, g, "width_mm", false, 0.01, 1000, &L->width_mm, err));
                TRY(imp_conf_get_double(c, g, "length_mm", false, 0.01, 1000, &L->length_mm, err));
                break;
        case IMP_LAYER_RIDGE:
                L->width_mm = 2;
                L->cliff_mm = 0.05;
                TRY(imp_conf_get_doubles(c, g, "start_mm", true, 2, L->start_mm, 2, NULL, err));
                TRY(imp_conf_get_doubles(c, g, "end_mm", true, 2, L->end_mm, 2, NULL, err));
                TRY(imp_conf_get_double(c, g, "width_mm", false, 0.01, 1000, &L->width_mm, err));
                TRY(imp_conf_get_double(c, g, "cliff_mm", false, 1e-4, 1000, &L->cliff_mm, err));
                break;
        case IMP_LAYER_CRAQUELURE:
                L->width_mm = 0.1;
                TRY(imp_conf_get_double(c, g, "period_mm", true, 0.05, 1000, &L->period_mm, err));
                TRY(imp_conf_get_double(c, g, "width_mm", false, 1e-3, 100, &L->width_mm, err));
                break;
        case IMP_LAYER_STEP: {
                static const char *const axes[] = { "x", "y", NULL };
                TRY(imp_conf_get_double(c, g, "at_mm", true, -1e5, 1e5, &L->at_mm, err));
                TRY(imp_conf_get_enum(c, g, "axis", false, axes, &L->axis, err));
                break;
        }
        case IMP_LAYER_PLANE:
                /* |slope| ≤ 2 (63°): steeper boards are seen too obliquely to be useful */
                TRY(imp_conf_get_doubles(c, g, "slope", true, 2, L->slope, 2, NULL, err));
                if (!(fabs(L->slope[0]) <= 2 && fabs(L->slope[1]) <= 2))
                        return imp_error_set(err, -EINVAL, "%s:%d: %s.slope: expected |dz/dx|, |dz/dy| <= 2",
                                             imp_conf_path(c), line_of(g), imp_conf_setting_path(g));
                TRY(imp_conf_get_double(c, g, "offset_mm", false, -1e3, 1e3, &L->offset_mm, err));
                break;
        case IMP_LAYER_SPHERE:
                TRY(imp_conf_get_doubles(c, g, "centre_mm", true, 2, L->centre_mm, 2, NULL, err));
                TRY(imp_conf_get_double(c, g, "radius_mm", true, 1e-2, 1e3, &L->radius_mm, err));
                TRY(imp_conf_get_double(c, g, "offset_mm", false, -0.99 * L->radius_mm, 0, &L->offset_mm, err));
                break;
        case IMP_LAYER_FILE: {
                const char *p = NULL;
                TRY(imp_conf_get_string(c, g, "path", true, &p, err));
                int len = p[0] == '/' || !dir[0] ? snprintf(L->path, sizeof L->path, "%s", p)
                                                 : snprintf(L->path, sizeof L->path, "%s/%s", dir, p);
                if (len >= (int) sizeof L->path)
                        return imp_error_set(err, -ENAMETOOLONG, "%s:%d: %s.path: path too long",
                                             imp_conf_path(c), line_of(g), imp_conf_setting_path(g));
                break;
        }
        }
        return 0;
}

static int parse_shape(const struct imp_conf *c, const config_setting_t *g, uint64_t seed, struct imp_shape *sh,
                       struct imp_error *err) {
        static const char *const kinds[] = { "all", "blob", "stripe", "rect", "checker", "disc", NULL };
        int kind = 0;
        TRY(imp_conf_get_enum(c, g, "shape", false, kinds, &kind, err));
        *sh = (struct imp_shape) { .kind = kind, .seed = seed, .wobble = 0.2 };
        switch (kind) {
        case IMP_SHAPE_ALL:
                break;
        case IMP_SHAPE_BLOB:
                TRY(imp_conf_get_doubles(c, g, "centre_mm", true, 2, sh->centre_mm, 2, NULL, err));
                TRY(imp_conf_get_double(c, g, "radius_mm", true, 1e-3, 1e5, &sh->radius_mm, err));
                TRY(imp_conf_get_double(c, g, "wobble", false, 0, 0.9, &sh->wobble, err));
                break;
        case IMP_SHAPE_DISC:
                TRY(imp_conf_get_doubles(c, g, "centre_mm", true, 2, sh->centre_mm, 2, NULL, err));
                TRY(imp_conf_get_double(c, g, "radius_mm", true, 1e-3, 1e5, &sh->radius_mm, err));
                break;
        case IMP_SHAPE_STRIPE: {
                double ang = 0;
                TRY(imp_conf_get_doubles(c, g, "centre_mm", true, 2, sh->centre_mm, 2, NULL, err));
                TRY(imp_conf_get_double(c, g, "width_mm", true, 1e-3, 1e5, &sh->width_mm, err));
                TRY(imp_conf_get_double(c, g, "angle_deg", false, -360, 360, &ang, err));
                sh->angle_rad = ang * M_PI / 180;
                break;
        }
        case IMP_SHAPE_RECT:
                TRY(imp_conf_get_doubles(c, g, "min_mm", true, 2, sh->min_mm, 2, NULL, err));
                TRY(imp_conf_get_doubles(c, g, "max_mm", true, 2, sh->max_mm, 2, NULL, err));
                break;
        case IMP_SHAPE_CHECKER: {
                struct imp_checker *ck = &sh->checker;
                long long cr[2] = { 0, 0 };
                double crd[2];
                ck->black = 0.1;
                TRY(imp_conf_get_double(c, g, "square_mm", true, 1e-3, 1e4, &ck->square_mm, err));
                TRY(imp_conf_get_doubles(c, g, "corners", true, 2, crd, 2, NULL, err));
                TRY(imp_conf_get_doubles(c, g, "origin_mm", true, 2, ck->origin_mm, 2, NULL, err));
                TRY(imp_conf_get_double(c, g, "black", false, 0, 1, &ck->black, err));
                TRY(imp_conf_get_double(c, g, "filter_mm", false, 0, 100, &ck->filter_mm, err));
                double ang = 0;
                TRY(imp_conf_get_double(c, g, "angle_deg", false, -180, 180, &ang, err));
                ck->angle_rad = ang * M_PI / 180;
                for (int i = 0; i < 2; i++) {
                        cr[i] = llround(crd[i]);
                        if (cr[i] < 2 || cr[i] > 1000 || fabs(crd[i] - (double) cr[i]) > 1e-9)
                                return imp_error_set(err, -EINVAL, "%s:%d: %s.corners: expected two whole "
                                                     "numbers of inner corners in 2..1000",
                                                     imp_conf_path(c), line_of(g), imp_conf_setting_path(g));
                }
                ck->cols = (int) cr[0];
                ck->rows = (int) cr[1];
                break;
        }
        }
        return 0;
}

static int alloc_surface(struct imp_scene *s, double W, double H, double pitch, double fw) {
        double m = fw > 0 ? ceil(fw / pitch - 1e-9) * pitch : 0;
        struct imp_sim_surface *sf = &s->surf;
        sf->pitch_mm = pitch;
        sf->origin_mm[0] = sf->origin_mm[1] = -m;
        sf->nx = (int) llround((W + 2 * m) / pitch) + 1;
        sf->ny = (int) llround((H + 2 * m) / pitch) + 1;
        sf->canvas_min_mm[0] = sf->canvas_min_mm[1] = 0;
        sf->canvas_max_mm[0] = W;
        sf->canvas_max_mm[1] = H;
        size_t n = (size_t) sf->nx * sf->ny;
        s->height = calloc(n, sizeof(float));
        s->normals = malloc(n * 3 * sizeof(float));
        s->tint = malloc(n * sizeof(float));
        s->is_frame = calloc(n, 1);
        s->region = calloc(n, 1);
        if (!s->height || !s->normals || !s->tint || !s->is_frame || !s->region)
                return -ENOMEM;
        sf->height_mm = s->height;
        sf->is_frame = s->is_frame;
        double eps = 1e-6 * pitch;
        for (int j = 0; j < sf->ny; j++)
                for (int i = 0; i < sf->nx; i++) {
                        double x = sf->origin_mm[0] + i * pitch, y = sf->origin_mm[1] + j * pitch;
                        size_t k = (size_t) j * sf->nx + i;
                        bool fr = x < -eps || y < -eps || x > W + eps || y > H + eps;
                        s->is_frame[k] = fr;
                        s->height[k] = fr ? (float) s->frame_height_mm : 0.f;
                }
        return 0;
}

static void compute_normals(struct imp_scene *s) {
        const struct imp_sim_surface *sf = &s->surf;
        int nx = sf->nx, ny = sf->ny;
        double hmin = INFINITY, hmax = -INFINITY;
        for (int j = 0; j < ny; j++)
                for (int i = 0; i < nx; i++) {
                        size_t k = (size_t) j * nx + i;
                        int il = IMP_MAX(i - 1, 0), ir = IMP_MIN(i + 1, nx - 1);
                        int jd = IMP_MAX(j - 1, 0), ju = IMP_MIN(j + 1, ny - 1);
                        double gx = ir > il ? (s->height[(size_t) j * nx + ir] - s->height[(size_t) j * nx + il]) /
                                                      ((ir - il) * sf->pitch_mm) : 0;
                        double gy = ju > jd ? (s->height[(size_t) ju * nx + i] - s->height[(size_t) jd * nx + i]) /
                                                      ((ju - jd) * sf->pitch_mm) : 0;
                        double len = sqrt(gx * gx + gy * gy + 1);
                        s->normals[3 * k] = (float) (-gx / len);
                        s->normals[3 * k + 1] = (float) (-gy / len);
                        s->normals[3 * k + 2] = (float) (1 / len);
                        hmin = IMP_MIN(hmin, s->height[k]);
                        hmax = IMP_MAX(hmax, s->height[k]);
                }
        s->hmin = hmin;
        s->hmax = hmax;
}

/* The varnish group over every paint region: the coat takes ρs from the light before it
 * reaches the paint; the texel keeps one lobe (truth must be one Lafortune lobe): the
 * glossier of coat and paint. */
static int parse_varnish(const struct imp_conf *c, config_setting_t *g, struct imp_scene *s, int nreg,
                         struct imp_error *err) {
        config_setting_t *vg = NULL;
        TRY(imp_conf_get_group(c, g, "varnish", false, &vg, err));
        if (vg) {
                static const char *const vknown[] = { "rho_s", "lobe", "k", NULL };
                double vs = 0.05, lobe[3] = { -1, -1, 1 }, k = 80;
                TRY(imp_conf_check_known(c, vg, vknown, err));
                TRY(imp_conf_get_double(c, vg, "rho_s", false, 0, 1, &vs, err));
                TRY(get_vec3(c, vg, "lobe", false, lobe, err));
                TRY(imp_conf_get_double(c, vg, "k", false, 0, 10000, &k, err));
                for (int i = 0; i < nreg; i++) {
                        struct imp_lafortune *b = &s->regions[i].brdf;
                        double smax = IMP_MAX(b->rho_s[0], IMP_MAX(b->rho_s[1], b->rho_s[2]));
                        if (smax < vs) {
                                b->cx = (float) lobe[0];
                                b->cy = (float) lobe[1];
                                b->cz = (float) lobe[2];
                                b->k = (float) k;
                        }
                        for (int ch = 0; ch < 3; ch++) {
                                b->rho_d[ch] *= (float) (1 - vs);
                                b->rho_s[ch] += (float) vs;
                        }
                }
        }
        return 0;
}

/* Each surface sample's region (the frame, else the last region whose shape holds it) and
 * its tint (value-noise variation, checkerboard squares). */
static void assign_regions(struct imp_scene *s, const struct imp_shape *shapes, int nreg) {
        const struct imp_sim_surface *sf = &s->surf;
        double c = cos(s->place.theta_rad), sn = sin(s->place.theta_rad);
        for (int j = 0; j < sf->ny; j++)
                for (int i = 0; i < sf->nx; i++) {
                        size_t k = (size_t) j * sf->nx + i;
                        double xy[2];
                        imp_sim_surface_sample_xy(sf, i, j, xy);
                        double x = xy[0], y = xy[1];
                        if (s->gantry) {        /* the painting frame (identity otherwise) */
                                double wx = x, wy = y;
                                x = c * wx - sn * wy + s->place.offset_mm[0];
                                y = sn * wx + c * wy + s->place.offset_mm[1];
                        }
                        int reg = 0;
                        if (s->is_frame[k]) {
                                reg = nreg;
                        } else {
                                for (int q = nreg - 1; q >= 0; q--)
                                        if (imp_shape_contains(&shapes[q], x, y)) {
                                                reg = q;
                                                break;
                                        }
                        }
                        s->region[k] = (uint8_t) reg;
                        double tv = s->regions[reg].tint_variation;
                        double t = tv > 0 ? 1 + tv * imp_value_noise(s->seed + 31 * (uint64_t) reg, x, y, 2.0) : 1;
                        if (reg < nreg && shapes[reg].kind == IMP_SHAPE_CHECKER) {
                                const struct imp_checker *ck = &shapes[reg].checker;
                                double uv[2];
                                imp_checker_board_uv(ck, x, y, uv);
                                t *= 1 - (1 - ck->black) * imp_checker_black_fraction(ck, uv[0], uv[1], ck->filter_mm);
                        }
                        s->tint[k] = (float) IMP_MAX(t, 0.0);
                }
}

static int parse_painting(struct imp_scene *s, const struct imp_conf *c, struct imp_error *err) {
        static const char *const known[] = { "width_mm", "height_mm", "pitch_mm", "frame", "layers",
                                             "regions", "varnish", NULL };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, NULL, "painting", true, &g, err));
        TRY(imp_conf_check_known(c, g, known, err));
        double W = 0, H = 0, pitch = 0, fw = 0;
        TRY(imp_conf_get_double(c, g, "width_mm", true, 0.1, 1e4, &W, err));
        TRY(imp_conf_get_double(c, g, "height_mm", true, 0.1, 1e4, &H, err));
        TRY(imp_conf_get_double(c, g, "pitch_mm", true, 1e-3, 100, &pitch, err));
        if (!s->gantry && (W / pitch + 1) * (H / pitch + 1) > 4e8)     /* a gantry scene samples windows */
                return imp_error_set(err, -EINVAL, "%s:%d: painting.pitch_mm: %g mm gives more than 4e8 samples",
                                     imp_conf_path(c), line_of(config_setting_lookup(g, "pitch_mm")), pitch);
        config_setting_t *fr = NULL;
        TRY(imp_conf_get_group(c, g, "frame", false, &fr, err));
        struct imp_lafortune frame_brdf = { .rho_d = { 0.45, 0.35, 0.2 }, .rho_s = { 0.2, 0.18, 0.12 },
                                            .cx = -1, .cy = -1, .cz = 1, .k = 20 };
        if (fr) {
                static const char *const fknown[] = { "width_mm", "height_mm", "rho_d", "rho_s", "lobe", "k", NULL };
                TRY(imp_conf_check_known(c, fr, fknown, err));
                TRY(imp_conf_get_double(c, fr, "width_mm", true, 0.01, 1e4, &fw, err));
                TRY(imp_conf_get_double(c, fr, "height_mm", true, 0, 1e3, &s->frame_height_mm, err));
                if (config_setting_lookup(fr, "rho_d"))
                        TRY(parse_brdf(c, fr, &frame_brdf, err));
        }
        s->frame_width_mm = fw;
        s->canvas_mm[0] = W;
        s->canvas_mm[1] = H;
        s->pitch_mm = pitch;
        if (!s->gantry)
                TRY(alloc_surface(s, W, H, pitch, fw));

        config_setting_t *layers = NULL;
        TRY(imp_conf_get_list(c, g, "layers", false, &layers, err));
        s->layers = calloc(layers ? (size_t) config_setting_length(layers) + 1 : 1, sizeof *s->layers);
        if (!s->layers)
                return -ENOMEM;
        for (int i = 0; layers && i < config_setting_length(layers); i++) {
                struct imp_layer *L = &s->layers[i];
                config_setting_t *lg = config_setting_get_elem(layers, i);
                TRY(parse_layer(c, lg, i, s->seed, s->dir, L, err));
                if (L->kind == IMP_LAYER_PLANE) {
                        s->plane_slope[0] = L->slope[0];
                        s->plane_slope[1] = L->slope[1];
                        s->plane_offset_mm = L->offset_mm;
                }
                int r = s->gantry ? 0 : imp_painting_add_layer(&s->surf, s->height, L, err);
                if (r < 0)
                        return imp_error_prefix(err, "%s:%d: painting.layers.[%d]: ", imp_conf_path(c), line_of(lg), i);
                s->n_layers++;
        }

        /* regions, then the varnish over the paint, then the frame's own region last */
        static const char *const rknown[] = { "name", "shape", "centre_mm", "radius_mm", "wobble", "width_mm",
                                              "angle_deg", "min_mm", "max_mm", "rho_d", "rho_s", "lobe", "k",
                                              "tint_variation", "seed", "square_mm", "corners", "origin_mm",
                                              "black", "filter_mm", NULL };
        config_setting_t *regions = NULL;
        TRY(imp_conf_get_list(c, g, "regions", false, &regions, err));
        int nreg = regions ? config_setting_length(regions) : 0;
        if (nreg > IMP_SCENE_MAX_REGIONS - 1)
                return imp_error_set(err, -EINVAL, "%s:%d: painting.regions: at most %d regions, got %d",
                                     imp_conf_path(c), line_of(regions), IMP_SCENE_MAX_REGIONS - 1, nreg);
        struct imp_shape *shapes = s->shapes;
        if (nreg == 0) {
                s->regions[0] = (struct imp_scene_region) { .name = "paint",
                        .brdf = { .rho_d = { 0.8, 0.8, 0.8 }, .cx = -1, .cy = -1, .cz = 1, .k = 10 } };
                shapes[0] = (struct imp_shape) { .kind = IMP_SHAPE_ALL };
                nreg = 1;
        }
        for (int i = 0; regions && i < config_setting_length(regions); i++) {
                config_setting_t *rg = config_setting_get_elem(regions, i);
                struct imp_scene_region *R = &s->regions[i];
                TRY(imp_conf_check_known(c, rg, rknown, err));
                const char *name = NULL;
                TRY(imp_conf_get_string(c, rg, "name", false, &name, err));
                if (name)
                        snprintf(R->name, sizeof R->name, "%s", name);
                else
                        snprintf(R->name, sizeof R->name, "region%d", i);
                TRY(parse_brdf(c, rg, &R->brdf, err));
                TRY(imp_conf_get_double(c, rg, "tint_variation", false, 0, 1, &R->tint_variation, err));
                long long sd = (long long) (imp_mix64(s->seed + 7 * (uint64_t) i) >> 1);
                TRY(imp_conf_get_int(c, rg, "seed", false, 0, INT64_MAX, &sd, err));
                TRY(parse_shape(c, rg, (uint64_t) sd, &shapes[i], err));
                if (shapes[i].kind == IMP_SHAPE_CHECKER) {
                        struct imp_checker *ck = &shapes[i].checker;
                        ck->slope[0] = s->plane_slope[0];
                        ck->slope[1] = s->plane_slope[1];
                        ck->offset_mm = s->plane_offset_mm;
                        ck->filter_mm = IMP_MAX(ck->filter_mm, pitch);
                }
        }
        TRY(parse_varnish(c, g, s, nreg, err));
        s->regions[nreg] = (struct imp_scene_region) { .name = "frame", .brdf = frame_brdf };
        s->n_regions = nreg + 1;
        s->n_shapes = nreg;
        if (s->gantry)
                return 0;       /* built per window (imp_scene_place) */
        assign_regions(s, shapes, nreg);
        compute_normals(s);
        return 0;
}

/* ---- gantry scenes: the surface is a window of a larger painting ---- */

static int parse_gantry(struct imp_scene *s, const struct imp_conf *c, struct imp_error *err) {
        static const char *const known[] = { "window_mm", "margin_mm", "truth_pitch_mm", "speed_mm_s",
                                             "accel_mm_s2", "settle_s", NULL };
        config_setting_t *g = NULL;
        TRY(imp_conf_get_group(c, NULL, "gantry", false, &g, err));
        if (!g)
                return 0;
        struct imp_scene_gantry *gp = &s->gantry_params;
        *gp = (struct imp_scene_gantry) { .margin_mm = 2.0, .speed_mm_s = 50.0, .accel_mm_s2 = 500.0, .settle_s = 0.3 };
        TRY(imp_conf_check_known(c, g, known, err));
        TRY(imp_conf_get_doubles(c, g, "window_mm", false, 2, gp->window_mm, 2, NULL, err));
        TRY(imp_conf_get_double(c, g, "margin_mm", false, 0, 1000, &gp->margin_mm, err));
        TRY(imp_conf_get_double(c, g, "truth_pitch_mm", false, 1e-3, 100, &gp->truth_pitch_mm, err));
        TRY(imp_conf_get_double(c, g, "speed_mm_s", false, 1e-3, 1e4, &gp->speed_mm_s, err));
        TRY(imp_conf_get_double(c, g, "accel_mm_s2", false, 1e-3, 1e6, &gp->accel_mm_s2, err));
        TRY(imp_conf_get_double(c, g, "settle_s", false, 0, 3600, &gp->settle_s, err));
        for (int a = 0; a < 2; a++)
                if (gp->window_mm[a] < 0 || !isfinite(gp->window_mm[a]))
                        return imp_error_set(err, -EINVAL, "%s:%d: gantry.window_mm: expected two sizes > 0",
                                             imp_conf_path(c), line_of(g));
        s->gantry = true;
        return 0;
}

/* World x0, y0, x1, y1 of what the cameras see of z = 0, around world (0, 0). */
static void camera_footprint(const struct imp_rig *rig, double ret[4]) {
        ret[0] = ret[1] = INFINITY;
        ret[2] = ret[3] = -INFINITY;
        for (int i = 0; i < rig->n_cameras; i++) {
                const struct imp_pinhole *m = &rig->cameras[i].model;
                for (int k = 0; k < 4; k++) {
                        double px[2] = { (k & 1) ? m->width - 0.5 : -0.5, (k & 2) ? m->height - 0.5 : -0.5 }, o[3], d[3];
                        imp_pinhole_ray_world(m, px, o, d);
                        double t = fabs(d[2]) > 1e-12 ? -o[2] / d[2] : 0;
                        for (int a = 0; a < 2; a++) {
                                ret[a] = IMP_MIN(ret[a], o[a] + t * d[a]);
                                ret[2 + a] = IMP_MAX(ret[2 + a], o[a] + t * d[a]);
                        }
                }
        }
}

static void free_surface(struct imp_scene *s) {
        free(s->height);
        free(s->normals);
        free(s->tint);
        free(s->is_frame);
        free(s->region);
        free(s->albedo);
        s->height = s->normals = s->tint = s->albedo = NULL;
        s->is_frame = s->region = NULL;
        s->surf.albedo = NULL;
}

/* The surface over [w[0], w[2]] × [w[1], w[3]] at `pitch`, all canvas, the layers and
 * regions evaluated in the painting frame of s->place; `lattice` (or NULL): the window lies
 * on the painting's lattice, w is in the painting frame (w[0], w[1] on the lattice) and the
 * pose maps world to it. */
static int build_window(struct imp_scene *s, const double w[4], double pitch, const struct imp_sim_surface *lattice,
                        struct imp_error *err) {
        free_surface(s);
        struct imp_sim_surface *sf = &s->surf;
        *sf = (struct imp_sim_surface) { .pitch_mm = pitch, .origin_mm = { w[0], w[1] },
                                         .nx = (int) ceil((w[2] - w[0]) / pitch - 1e-9) + 1,
                                         .ny = (int) ceil((w[3] - w[1]) / pitch - 1e-9) + 1,
                                         .canvas_min_mm = { w[0], w[1] } };
        if (lattice) {
                sf->placed = true;
                memcpy(sf->lattice0, lattice->lattice0, sizeof sf->lattice0);
                memcpy(sf->rot, lattice->rot, sizeof sf->rot);
                memcpy(sf->offset_mm, lattice->offset_mm, sizeof sf->offset_mm);
        }
        sf->canvas_max_mm[0] = w[0] + (sf->nx - 1) * pitch;
        sf->canvas_max_mm[1] = w[1] + (sf->ny - 1) * pitch;
        if ((double) sf->nx * sf->ny > 4e8)
                return imp_error_set(err, -E2BIG, "scene %s: a %d × %d sample window is too large", s->name, sf->nx, sf->ny);
        size_t n = (size_t) sf->nx * sf->ny;
        s->height = calloc(n, sizeof(float));
        s->normals = malloc(n * 3 * sizeof(float));
        s->tint = malloc(n * sizeof(float));
        s->is_frame = calloc(n, 1);
        s->region = calloc(n, 1);
        if (!s->height || !s->normals || !s->tint || !s->is_frame || !s->region)
                return imp_error_set(err, -ENOMEM, "scene %s: out of memory for a %d × %d window", s->name, sf->nx, sf->ny);
        sf->height_mm = s->height;
        sf->is_frame = s->is_frame;
        s->place.canvas_mm[0] = s->canvas_mm[0];
        s->place.canvas_mm[1] = s->canvas_mm[1];
        for (int i = 0; i < s->n_layers; i++) {
                int r = imp_painting_add_layer_placed(sf, &s->place, s->height, &s->layers[i], err);
                if (r < 0)
                        return imp_error_prefix(err, "scene %s: painting.layers.[%d]: ", s->name, i);
        }
        assign_regions(s, s->shapes, s->n_shapes);
        compute_normals(s);
        return s->fx[IMP_FX_INDIRECT] ? make_albedo(s) : 0;
}

/* The window around world (0, 0) a tile's cameras see; the first one shows the painting's
 * centre under the field's centre, unrotated. */
static int first_window(struct imp_scene *s, const struct imp_conf *c, struct imp_error *err) {
        const struct imp_scene_gantry *gp = &s->gantry_params;
        double fp[4];
        if (gp->window_mm[0] > 0 && gp->window_mm[1] > 0) {
                fp[0] = -gp->window_mm[0] / 2, fp[1] = -gp->window_mm[1] / 2;
                fp[2] = gp->window_mm[0] / 2, fp[3] = gp->window_mm[1] / 2;
        } else {
                camera_footprint(&s->rig, fp);
                if (!(isfinite(fp[0]) && isfinite(fp[1]) && isfinite(fp[2]) && isfinite(fp[3])) ||
                    fp[2] - fp[0] > 1e4 || fp[3] - fp[1] > 1e4)
                        return imp_error_set(err, -EINVAL, "%s: gantry: the cameras do not look down at z = 0 near "
                                             "world (0, 0); give gantry.window_mm", imp_conf_path(c));
        }
        for (int a = 0; a < 2; a++) {
                s->window_mm[a] = fp[a] - gp->margin_mm;
                s->window_mm[2 + a] = fp[2 + a] + gp->margin_mm;
        }
        if (!(s->gantry_params.truth_pitch_mm > 0))
                s->gantry_params.truth_pitch_mm = 2 * s->pitch_mm;
        struct imp_painting_place pl = { .offset_mm = { s->canvas_mm[0] / 2, s->canvas_mm[1] / 2 } };
        return imp_scene_place(s, &pl, err);
}

int imp_scene_place(struct imp_scene *s, const struct imp_painting_place *place, struct imp_error *err) {
        if (!s || !place || !s->gantry)
                return imp_error_set(err, -EINVAL, "scene %s: not a gantry scene (no gantry group)", s ? s->name : "?");
        if (!(isfinite(place->theta_rad) && isfinite(place->offset_mm[0]) && isfinite(place->offset_mm[1])))
                return imp_error_set(err, -EINVAL, "scene %s: placement: expected finite numbers", s->name);
        /* The painting's own lattice (origin at its origin, its pitch) under the window the rig
         * sees: the box of the window's corners in the painting frame, one sample beyond. */
        struct imp_sim_surface pose = { .placed = true, .rot = { cos(place->theta_rad), sin(place->theta_rad) },
                                        .offset_mm = { place->offset_mm[0], place->offset_mm[1] } };
        double lo[2] = { INFINITY, INFINITY }, hi[2] = { -INFINITY, -INFINITY }, w[4];
        for (int k = 0; k < 4; k++) {
                double c[2] = { s->window_mm[(k & 1) ? 2 : 0], s->window_mm[(k & 2) ? 3 : 1] }, p[2];
                imp_sim_surface_to_lattice(&pose, c, p);
                for (int a = 0; a < 2; a++) {
                        lo[a] = IMP_MIN(lo[a], p[a]);
                        hi[a] = IMP_MAX(hi[a], p[a]);
                }
        }
        for (int a = 0; a < 2; a++) {
                double i0 = floor(lo[a] / s->pitch_mm) - 1, i1 = ceil(hi[a] / s->pitch_mm) + 1;
                if (!(fabs(i0) < 1e9 && fabs(i1) < 1e9))
                        return imp_error_set(err, -EINVAL, "scene %s: placement: the window lies %g mm off the painting",
                                             s->name, lo[a]);
                pose.lattice0[a] = (int) i0;
                w[a] = i0 * s->pitch_mm;
                w[2 + a] = i1 * s->pitch_mm;
        }
        /* the layers and regions are evaluated at the lattice's own painting-frame points */
        s->place = (struct imp_painting_place) { .canvas_mm = { s->canvas_mm[0], s->canvas_mm[1] } };
        return build_window(s, w, s->pitch_mm, &pose, err);
}

int imp_scene_place_whole(struct imp_scene *s, double pitch_mm, struct imp_error *err) {
        if (!s || !s->gantry || !(pitch_mm > 0))
                return imp_error_set(err, -EINVAL, "scene %s: whole painting: not a gantry scene or no pitch",
                                     s ? s->name : "?");
        s->place = (struct imp_painting_place) { 0 };
        double w[4] = { 0, 0, s->canvas_mm[0], s->canvas_mm[1] };
        return build_window(s, w, pitch_mm, NULL, err);
}

bool imp_scene_is_gantry(const struct imp_scene *s) { return s->gantry; }
void imp_scene_window(const struct imp_scene *s, double ret_mm[4]) { memcpy(ret_mm, s->window_mm, sizeof s->window_mm); }
const struct imp_scene_gantry *imp_scene_gantry(const struct imp_scene *s) { return s->gantry ? &s->gantry_params : NULL; }
const struct imp_stage_error *imp_scene_stage_error(const struct imp_scene *s) {
        return s->fx[IMP_FX_STAGE_ERROR] ? &s->stage_error : NULL;
}
void imp_scene_canvas_size(const struct imp_scene *s, double ret_mm[2]) {
        ret_mm[0] = s->canvas_mm[0];
        ret_mm[1] = s->canvas_mm[1];
}

static int scene_from_conf(const struct imp_conf *c, struct imp_scene **ret, struct imp_error *err) {
        static const char *const known[] = { "scene", "painting", "rig", "gantry", NULL };
        _cleanup_(imp_scene_freep) struct imp_scene *s = calloc(1, sizeof *s);
        if (!s)
                return -ENOMEM;
        char pathbuf[512];
        snprintf(pathbuf, sizeof pathbuf, "%s", imp_conf_path(c));
        if (strchr(pathbuf, '/'))
                snprintf(s->dir, sizeof s->dir, "%s", dirname(pathbuf));
        TRY(imp_conf_check_known(c, imp_conf_root(c), known, err));
        TRY(parse_scene_group(s, c, err));
        TRY(parse_gantry(s, c, err));
        TRY(parse_painting(s, c, err));
        TRY(parse_rig(s, c, err));
        if (s->gantry)
                TRY(first_window(s, c, err));
        if (s->fx[IMP_FX_PROJECTOR] && !s->rig.has_projector)
                return imp_error_set(err, -EINVAL, "%s: scene.effects: `projector` is listed but rig.projector is missing",
                                     imp_conf_path(c));
        if (s->fx[IMP_FX_INDIRECT])
                TRY(make_albedo(s));
        *ret = TAKE_PTR(s);
        return 0;
}

int imp_scene_load(const char *path, struct imp_scene **ret, struct imp_error *err) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        TRY(imp_conf_load(path, &c, err));
        return scene_from_conf(c, ret, err);
}

int imp_scene_load_string(const char *text, const char *name, struct imp_scene **ret, struct imp_error *err) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        TRY(imp_conf_load_string(text, name, &c, err));
        return scene_from_conf(c, ret, err);
}

char *imp_scene_describe(const struct imp_scene *s) {
        char *buf = NULL;
        size_t len = 0;
        FILE *f = open_memstream(&buf, &len);
        if (!f)
                return NULL;
        const struct imp_sim_surface *sf = &s->surf;
        fprintf(f, "scene %s (seed %llu)\n", s->name, (unsigned long long) s->seed);
        if (s->gantry)
                fprintf(f, "  painting: %.1f x %.1f mm canvas at %.3f mm pitch, on a gantry: each tile samples a "
                           "%.1f x %.1f mm window (%d x %d samples); %d layers\n",
                        s->canvas_mm[0], s->canvas_mm[1], s->pitch_mm, s->window_mm[2] - s->window_mm[0],
                        s->window_mm[3] - s->window_mm[1], sf->nx, sf->ny, s->n_layers);
        else
                fprintf(f, "  painting: %.1f x %.1f mm canvas at %.3f mm pitch; %d x %d samples with frame; %d layers\n",
                        sf->canvas_max_mm[0] - sf->canvas_min_mm[0], sf->canvas_max_mm[1] - sf->canvas_min_mm[1],
                        sf->pitch_mm, sf->nx, sf->ny, s->n_layers);
        fprintf(f, "  relief: %.3f .. %.3f mm; frame %.1f mm wide, %.1f mm high\n", s->hmin, s->hmax,
                s->frame_width_mm, s->frame_height_mm);
        for (int i = 0; i < s->n_regions; i++) {
                const struct imp_lafortune *b = &s->regions[i].brdf;
                fprintf(f, "  region %-10s rho_d (%.2f %.2f %.2f) rho_s (%.2f %.2f %.2f) lobe (%.2f %.2f %.2f) k %.1f\n",
                        s->regions[i].name, b->rho_d[0], b->rho_d[1], b->rho_d[2], b->rho_s[0], b->rho_s[1],
                        b->rho_s[2], b->cx, b->cy, b->cz, b->k);
        }
        for (int i = 0; i < s->rig.n_cameras; i++) {
                const struct imp_rig_camera *cam = &s->rig.cameras[i];
                double C[3];
                imp_pinhole_centre(&cam->model, C);
                fprintf(f, "  camera %s: %d x %d, f %.1f px, at (%.1f %.1f %.1f) mm, %d-bit %s\n", cam->name,
                        cam->model.width, cam->model.height, cam->model.fx, C[0], C[1], C[2], cam->sensor.bits,
                        s->camopts[i].colour ? "colour" : cam->sensor.bayer ? "bayer" : "mono");
        }
        if (s->rig.has_projector) {
                double C[3];
                imp_pinhole_centre(&s->rig.projector.model, C);
                fprintf(f, "  projector %s: %d x %d at (%.1f %.1f %.1f) mm, gamma %.2f\n", s->rig.projector.name,
                        s->rig.projector.model.width, s->rig.projector.model.height, C[0], C[1], C[2],
                        s->rig.projector.gamma);
        }
        fprintf(f, "  dome: %d lights\n", s->rig.n_lights);
        fprintf(f, "  effects:");
        for (int i = 0; i < IMP_FX_COUNT; i++)
                if (s->fx[i])
                        fprintf(f, " %s", effect_names[i]);
        fprintf(f, "\n");
        fclose(f);
        return buf;
}
