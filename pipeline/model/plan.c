/* Scan plan parsing and expansion into the frame list (see plan.h for the file format
 * and the frame order). */
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <strings.h>
#include "conf.h"
#include "plan.h"

struct imp_plan {
        size_t n_frames;
        struct imp_frame_record *frames;
        int gray_bits[2];
        struct imp_tile_plan *tiles;    /* the painting group, NULL without one */
};

void imp_plan_free(struct imp_plan *p) {
        if (!p)
                return;
        free(p->frames);
        imp_tile_plan_free(p->tiles);
        free(p);
}

size_t imp_plan_count(const struct imp_plan *p) { return p->n_frames; }
const struct imp_frame_record *imp_plan_frame(const struct imp_plan *p, size_t i) {
        return i < p->n_frames ? &p->frames[i] : NULL;
}
const struct imp_tile_plan *imp_plan_tiles(const struct imp_plan *p) { return p->tiles; }
int imp_plan_gray_bits(const struct imp_plan *p, int axis) {
        return axis == 0 || axis == 1 ? p->gray_bits[axis] : 0;
}

/* The settings as read, before expansion. */
struct plan_spec {
        int n_cameras;
        char cameras[4][32];
        int tiles;
        double gain_db;
        bool sl;
        int gray_bits[2];          /* per axis; 0 = axis not scanned */
        int code_bits[2];          /* bits of the whole code; gray_bits may keep only its coarsest */
        bool inverse, white, black;
        int n_periods, steps;
        double periods_px[IMP_PLAN_MAX_PERIODS];
        int n_sl_exp;
        double sl_exp_us[IMP_PLAN_MAX_EXPOSURES];
        bool dome;
        int n_lights;
        int *lights;               /* rig light ids */
        int n_dome_exp;
        double dome_exp_us[IMP_PLAN_MAX_EXPOSURES];
        int dome_repeat;           /* frames per light × exposure */
        int dark_count;
};

static int line_of(const config_setting_t *s) {
        return s ? config_setting_source_line(s) : 0;
}

static int parse_cameras(const struct imp_conf *c, const struct imp_rig *rig, struct plan_spec *ps,
                         struct imp_error *err) {
        config_setting_t *list = config_setting_lookup(imp_conf_root(c), "cameras");
        if (!list) {
                ps->n_cameras = rig->n_cameras;
                for (int i = 0; i < rig->n_cameras; i++)
                        snprintf(ps->cameras[i], sizeof ps->cameras[i], "%s", rig->cameras[i].name);
                if (ps->n_cameras == 0)
                        return imp_error_set(err, -EINVAL, "%s: cameras: the rig has no camera",
                                             imp_conf_path(c));
                return 0;
        }
        if (!config_setting_is_aggregate(list) || config_setting_length(list) == 0 ||
            config_setting_length(list) > 4)
                return imp_error_set(err, -EINVAL, "%s:%d: cameras: expected a list of 1 to 4 camera names",
                                     imp_conf_path(c), line_of(list));
        for (int i = 0; i < config_setting_length(list); i++) {
                config_setting_t *e = config_setting_get_elem(list, i);
                const char *name = config_setting_get_string(e);
                if (!name)
                        return imp_error_set(err, -EINVAL, "%s:%d: cameras.[%d]: expected a camera name",
                                             imp_conf_path(c), line_of(e), i);
                bool found = false;
                for (int k = 0; k < rig->n_cameras; k++)
                        found |= !strcmp(rig->cameras[k].name, name);
                if (!found)
                        return imp_error_set(err, -EINVAL, "%s:%d: cameras.[%d]: no camera \"%s\" in the rig",
                                             imp_conf_path(c), line_of(e), i, name);
                snprintf(ps->cameras[i], sizeof ps->cameras[i], "%s", name);
        }
        ps->n_cameras = config_setting_length(list);
        return 0;
}

static int ceil_log2(int n) {
        int b = 0;
        while ((1 << b) < n)
                b++;
        return b;
}

static int parse_sl(const struct imp_conf *c, const struct imp_rig *rig, struct plan_spec *ps,
                    struct imp_error *err) {
        static const char *const known[] = { "gray_bits", "inverse", "axes", "phase", "white",
                                             "black", "exposures_us", NULL };
        config_setting_t *g = NULL;
        int r = imp_conf_get_group(c, NULL, "structured_light", false, &g, err);
        if (r < 0 || !g)
                return r;
        r = imp_conf_check_known(c, g, known, err);
        if (r < 0)
                return r;
        if (!rig->has_projector)
                return imp_error_set(err, -EINVAL, "%s:%d: structured_light: the rig has no projector",
                                     imp_conf_path(c), line_of(g));
        ps->sl = true;
        ps->inverse = true;
        ps->white = ps->black = true;
        bool axes[2] = { true, true };
        config_setting_t *al = config_setting_lookup(g, "axes");
        if (al) {
                if (!config_setting_is_aggregate(al) || config_setting_length(al) == 0)
                        return imp_error_set(err, -EINVAL, "%s:%d: structured_light.axes: expected a list of \"x\", \"y\"",
                                             imp_conf_path(c), line_of(al));
                axes[0] = axes[1] = false;
                for (int i = 0; i < config_setting_length(al); i++) {
                        config_setting_t *e = config_setting_get_elem(al, i);
                        const char *s = config_setting_get_string(e);
                        if (s && !strcmp(s, "x"))
                                axes[0] = true;
                        else if (s && !strcmp(s, "y"))
                                axes[1] = true;
                        else
                                return imp_error_set(err, -EINVAL,
                                                     "%s:%d: structured_light.axes.[%d]: expected \"x\" or \"y\", got %s%s%s",
                                                     imp_conf_path(c), line_of(e), i, s ? "\"" : "",
                                                     s ? s : "a non-string", s ? "\"" : "");
                }
        }
        long long bits = -1;
        r = imp_conf_get_int(c, g, "gray_bits", false, 1, 16, &bits, err);
        if (r < 0)
                return r;
        const int size[2] = { rig->projector.model.width, rig->projector.model.height };
        /* Fewer bits than the projector needs keep the coarsest planes of the full code; the
         * phase periods then resolve the rest (structured-light.c checks they can). */
        for (int a = 0; a < 2; a++) {
                ps->code_bits[a] = !axes[a] ? 0 : ceil_log2(size[a]);
                ps->gray_bits[a] = !axes[a] ? 0 : bits > 0 ? (int) bits : ps->code_bits[a];
                if (ps->gray_bits[a] > ps->code_bits[a])
                        ps->code_bits[a] = ps->gray_bits[a];
        }
        if ((r = imp_conf_get_bool(c, g, "inverse", false, &ps->inverse, err)) < 0 ||
            (r = imp_conf_get_bool(c, g, "white", false, &ps->white, err)) < 0 ||
            (r = imp_conf_get_bool(c, g, "black", false, &ps->black, err)) < 0)
                return r;
        config_setting_t *ph = NULL;
        if ((r = imp_conf_get_group(c, g, "phase", false, &ph, err)) < 0)
                return r;
        if (ph) {
                static const char *const pknown[] = { "periods_px", "steps", NULL };
                long long steps = 4;
                if ((r = imp_conf_check_known(c, ph, pknown, err)) < 0 ||
                    (r = imp_conf_get_doubles(c, ph, "periods_px", false, -1, ps->periods_px,
                                              IMP_PLAN_MAX_PERIODS, &ps->n_periods, err)) < 0 ||
                    (r = imp_conf_get_int(c, ph, "steps", false, 3, 64, &steps, err)) < 0)
                        return r;
                if (!config_setting_lookup(ph, "periods_px")) {
                        ps->periods_px[0] = 16.0;
                        ps->n_periods = 1;
                }
                for (int i = 0; i < ps->n_periods; i++)
                        if (!(ps->periods_px[i] >= 2.0))
                                return imp_error_set(err, -EINVAL,
                                                     "%s:%d: structured_light.phase.periods_px: expected periods >= 2, got %g",
                                                     imp_conf_path(c), line_of(ph), ps->periods_px[i]);
                ps->steps = (int) steps;
        }
        r = imp_conf_get_doubles(c, g, "exposures_us", true, -1, ps->sl_exp_us,
                                 IMP_PLAN_MAX_EXPOSURES, &ps->n_sl_exp, err);
        if (r < 0)
                return r;
        for (int i = 0; i < ps->n_sl_exp; i++)
                if (!(ps->sl_exp_us[i] > 0))
                        return imp_error_set(err, -EINVAL,
                                             "%s:%d: structured_light.exposures_us: expected exposures > 0, got %g",
                                             imp_conf_path(c), line_of(g), ps->sl_exp_us[i]);
        if (ps->n_sl_exp == 0)
                return imp_error_set(err, -EINVAL, "%s:%d: structured_light.exposures_us: expected at least one exposure",
                                     imp_conf_path(c), line_of(g));
        return 0;
}

static int parse_dome(const struct imp_conf *c, const struct imp_rig *rig, struct plan_spec *ps,
                      struct imp_error *err) {
        static const char *const known[] = { "lights", "exposures_us", "repeat", NULL };
        config_setting_t *g = NULL;
        int r = imp_conf_get_group(c, NULL, "dome", false, &g, err);
        if (r < 0 || !g)
                return r;
        long long repeat = 1;
        if ((r = imp_conf_check_known(c, g, known, err)) < 0 ||
            (r = imp_conf_get_int(c, g, "repeat", false, 1, IMP_PLAN_MAX_REPEAT, &repeat, err)) < 0)
                return r;
        ps->dome = true;
        ps->dome_repeat = (int) repeat;
        config_setting_t *l = config_setting_lookup(g, "lights");
        const char *s = l ? config_setting_get_string(l) : "all";
        if (s) {
                /* "spread N": N lights evenly spread over the rig's list (every light when it has
                 * no more), so that a preset fits a dome of any size */
                int spread = 0, end = 0;
                if (strcmp(s, "all") && (sscanf(s, "spread %d%n", &spread, &end) != 1 || s[end] || spread < 1))
                        return imp_error_set(err, -EINVAL, "%s:%d: dome.lights: expected \"all\", \"spread N\" "
                                             "(N ≥ 1) or a list of light ids, got \"%s\"", imp_conf_path(c), line_of(l), s);
                ps->n_lights = spread > 0 && spread < rig->n_lights ? spread : rig->n_lights;
                ps->lights = calloc(ps->n_lights > 0 ? ps->n_lights : 1, sizeof(int));
                if (!ps->lights)
                        return -ENOMEM;
                for (int i = 0; i < ps->n_lights; i++)
                        ps->lights[i] = rig->lights[(long) i * rig->n_lights / ps->n_lights].id;
        } else {
                if (!config_setting_is_aggregate(l))
                        return imp_error_set(err, -EINVAL, "%s:%d: dome.lights: expected \"all\" or a list of light ids",
                                             imp_conf_path(c), line_of(l));
                int n = config_setting_length(l);
                ps->lights = calloc(n > 0 ? n : 1, sizeof(int));
                if (!ps->lights)
                        return -ENOMEM;
                for (int i = 0; i < n; i++) {
                        config_setting_t *e = config_setting_get_elem(l, i);
                        bool ok = config_setting_type(e) == CONFIG_TYPE_INT;
                        int id = ok ? config_setting_get_int(e) : -1;
                        bool found = false;
                        for (int k = 0; ok && k < rig->n_lights; k++)
                                found |= rig->lights[k].id == id;
                        if (!found)
                                return imp_error_set(err, -EINVAL, "%s:%d: dome.lights.[%d]: expected a light id of the rig (%d lights)",
                                                     imp_conf_path(c), line_of(e), i, rig->n_lights);
                        ps->lights[i] = id;
                }
                ps->n_lights = n;
        }
        if (ps->n_lights == 0)
                return imp_error_set(err, -EINVAL, "%s:%d: dome.lights: no light to sweep",
                                     imp_conf_path(c), line_of(g));
        r = imp_conf_get_doubles(c, g, "exposures_us", true, -1, ps->dome_exp_us,
                                 IMP_PLAN_MAX_EXPOSURES, &ps->n_dome_exp, err);
        if (r < 0)
                return r;
        for (int i = 0; i < ps->n_dome_exp; i++)
                if (!(ps->dome_exp_us[i] > 0))
                        return imp_error_set(err, -EINVAL, "%s:%d: dome.exposures_us: expected exposures > 0, got %g",
                                             imp_conf_path(c), line_of(g), ps->dome_exp_us[i]);
        if (ps->n_dome_exp == 0)
                return imp_error_set(err, -EINVAL, "%s:%d: dome.exposures_us: expected at least one exposure",
                                     imp_conf_path(c), line_of(g));
        return 0;
}

/* Appends one record (growing the array); cap is doubled as needed. */
static int push(struct imp_plan *p, size_t *cap, const struct imp_frame_record *tmpl) {
        if (p->n_frames == *cap) {
                size_t ncap = *cap ? *cap * 2 : 256;
                struct imp_frame_record *f = realloc(p->frames, ncap * sizeof *f);
                if (!f)
                        return -ENOMEM;
                p->frames = f;
                *cap = ncap;
        }
        p->frames[p->n_frames] = *tmpl;
        p->frames[p->n_frames].seq = (long long) p->n_frames;
        p->n_frames++;
        return 0;
}

static int expand_sl(struct imp_plan *p, size_t *cap, const struct plan_spec *ps,
                     struct imp_frame_record *t) {
        int r;
        snprintf(t->step, sizeof t->step, "structured-light");
        t->light = -1;
        for (int e = 0; e < ps->n_sl_exp; e++) {
                t->exposure_index = e;
                t->exposure_us = ps->sl_exp_us[e];
                if (ps->white) {
                        t->pattern = (struct imp_pattern) { .kind = IMP_PAT_WHITE };
                        if ((r = push(p, cap, t)) < 0) return r;
                }
                if (ps->black) {
                        t->pattern = (struct imp_pattern) { .kind = IMP_PAT_BLACK };
                        if ((r = push(p, cap, t)) < 0) return r;
                }
                for (int a = 0; a < 2; a++) {
                        for (int b = 0; b < ps->gray_bits[a]; b++)
                                for (int inv = 0; inv <= (ps->inverse ? 1 : 0); inv++) {
                                        t->pattern = (struct imp_pattern) { .kind = IMP_PAT_GRAY, .axis = a,
                                                .bit = b, .nbits = ps->code_bits[a], .inverse = inv };
                                        if ((r = push(p, cap, t)) < 0) return r;
                                }
                        for (int k = 0; ps->gray_bits[a] > 0 && k < ps->n_periods; k++)
                                for (int s = 0; s < ps->steps; s++) {
                                        t->pattern = (struct imp_pattern) { .kind = IMP_PAT_PHASE, .axis = a,
                                                .period_px = ps->periods_px[k], .step = s, .steps = ps->steps };
                                        if ((r = push(p, cap, t)) < 0) return r;
                                }
                }
        }
        return 0;
}

static int expand(struct imp_plan *p, const struct plan_spec *ps) {
        size_t cap = 0;
        int r;
        /* distinct exposures, for the dark frames */
        double dist[2 * IMP_PLAN_MAX_EXPOSURES];
        int nd = 0;
        for (int i = 0; i < ps->n_sl_exp + ps->n_dome_exp; i++) {
                double e = i < ps->n_sl_exp ? ps->sl_exp_us[i] : ps->dome_exp_us[i - ps->n_sl_exp];
                bool seen = false;
                for (int k = 0; k < nd; k++)
                        seen |= dist[k] == e;
                if (!seen)
                        dist[nd++] = e;
        }
        for (int tile = 0; tile < ps->tiles; tile++)
                for (int ci = 0; ci < ps->n_cameras; ci++) {
                        struct imp_frame_record t = { .tile = tile, .light = -1, .gain_db = ps->gain_db };
                        snprintf(t.camera, sizeof t.camera, "%s", ps->cameras[ci]);
                        if (ps->sl && (r = expand_sl(p, &cap, ps, &t)) < 0)
                                return r;
                        t.pattern = (struct imp_pattern) { .kind = IMP_PAT_NONE };
                        snprintf(t.step, sizeof t.step, "dome");
                        for (int l = 0; ps->dome && l < ps->n_lights; l++)
                                for (int e = 0; e < ps->n_dome_exp; e++)
                                        for (int k = 0; k < ps->dome_repeat; k++) {
                                                t.light = ps->lights[l];
                                                t.exposure_index = e;
                                                t.exposure_us = ps->dome_exp_us[e];
                                                if ((r = push(p, &cap, &t)) < 0)
                                                        return r;
                                        }
                        snprintf(t.step, sizeof t.step, "dark");
                        t.light = -1;
                        for (int e = 0; e < nd; e++)
                                for (int k = 0; k < ps->dark_count; k++) {
                                        t.exposure_index = e;
                                        t.exposure_us = dist[e];
                                        if ((r = push(p, &cap, &t)) < 0)
                                                return r;
                                }
                }
        return 0;
}

/* Frames of one tile and camera, by group, before anything is allocated. */
struct plan_counts {
        double sl, dome, dark;
};

static struct plan_counts count_per_camera(const struct plan_spec *ps) {
        struct plan_counts n = { 0 };
        if (ps->sl) {
                double per_exp = (ps->white ? 1 : 0) + (ps->black ? 1 : 0);
                for (int a = 0; a < 2; a++)
                        if (ps->gray_bits[a] > 0)
                                per_exp += ps->gray_bits[a] * (ps->inverse ? 2.0 : 1.0) +
                                           (double) ps->n_periods * ps->steps;
                n.sl = per_exp * ps->n_sl_exp;
        }
        if (ps->dome)
                n.dome = (double) ps->n_lights * ps->n_dome_exp * ps->dome_repeat;
        int nd = 0;   /* distinct exposures, as expand() counts them */
        for (int i = 0; i < ps->n_sl_exp + ps->n_dome_exp; i++) {
                double e = i < ps->n_sl_exp ? ps->sl_exp_us[i] : ps->dome_exp_us[i - ps->n_sl_exp];
                bool seen = false;
                for (int k = 0; k < i; k++)
                        seen |= (k < ps->n_sl_exp ? ps->sl_exp_us[k] : ps->dome_exp_us[k - ps->n_sl_exp]) == e;
                nd += !seen;
        }
        n.dark = (double) nd * ps->dark_count;
        return n;
}

static double camera_frame_bytes(const struct imp_rig *rig, const char *camera) {
        for (int i = 0; i < rig->n_cameras; i++)
                if (!strcmp(rig->cameras[i].name, camera))
                        return (double) rig->cameras[i].model.width * rig->cameras[i].model.height * 2.0;
        return 0;
}

/* Refuses a plan whose expansion exceeds IMP_PLAN_MAX_FRAMES or IMP_PLAN_MAX_BYTES, from
 * the counts alone (each factor is capped, their product is not): the message names the
 * fields whose product explodes. */
static int check_expansion(const struct imp_conf *c, const struct imp_rig *rig, const struct plan_spec *ps,
                           struct imp_error *err) {
        struct plan_counts n = count_per_camera(ps);
        double per_camera = n.sl + n.dome + n.dark, frames = 0, bytes = 0;
        for (int i = 0; i < ps->n_cameras; i++) {
                frames += per_camera * ps->tiles;
                bytes += per_camera * ps->tiles * camera_frame_bytes(rig, ps->cameras[i]);
        }
        if (frames <= IMP_PLAN_MAX_FRAMES && bytes <= IMP_PLAN_MAX_BYTES)
                return 0;
        const char *worst = n.dome >= n.sl && n.dome >= n.dark ? "dome (lights × exposures_us × repeat)"
                            : n.sl >= n.dark ? "structured_light (patterns × exposures_us)"
                                             : "dark.count (× distinct exposures)";
        if (frames > IMP_PLAN_MAX_FRAMES)
                return imp_error_set(err, -E2BIG,
                                     "%s: the plan expands to %.3g frames, more than the %d allowed: "
                                     "tiles %d × cameras %d × %.3g frames per camera and tile, of which "
                                     "%s gives %.3g",
                                     imp_conf_path(c), frames, IMP_PLAN_MAX_FRAMES, ps->tiles, ps->n_cameras,
                                     per_camera, worst, fmax(n.dome, fmax(n.sl, n.dark)));
        return imp_error_set(err, -E2BIG,
                             "%s: the plan's %.3g frames would take %.3g bytes on disk, more than the "
                             "%.3g allowed: tiles %d × cameras %d × %.3g frames per camera and tile, of which "
                             "%s gives %.3g",
                             imp_conf_path(c), frames, bytes, (double) IMP_PLAN_MAX_BYTES, ps->tiles,
                             ps->n_cameras, per_camera, worst, fmax(n.dome, fmax(n.sl, n.dark)));
}

/* The painting group (tiles.h): the tile layout of a whole-painting scan. Its frames are one
 * tile's (tile 0 of each tile's own capture set), so `tiles` must not be given beside it. */
static int parse_painting(const struct imp_conf *c, struct imp_plan *p, struct imp_error *err) {
        config_setting_t *g = NULL;
        int r = imp_conf_get_group(c, NULL, "painting", false, &g, err);
        if (r < 0 || !g)
                return r;
        config_setting_t *t = config_setting_lookup(imp_conf_root(c), "tiles");
        if (t)
                return imp_error_set(err, -EINVAL, "%s:%d: tiles: a plan with a painting group lays its tiles out "
                                     "from the painting's extent and field of view; remove `tiles`",
                                     imp_conf_path(c), line_of(t));
        return imp_tile_plan_from_conf(c, g, &p->tiles, err);
}

static int plan_from_conf(const struct imp_conf *c, const struct imp_rig *rig, struct imp_plan **ret,
                          struct imp_error *err) {
        static const char *const known[] = { "cameras", "tiles", "gain_db", "structured_light",
                                             "dome", "dark", "name", "description", "painting", NULL };
        struct plan_spec ps = { .tiles = 1 };
        long long tiles = 1, dark = 0;
        int r;
        if ((r = imp_conf_check_known(c, imp_conf_root(c), known, err)) < 0 ||
            (r = parse_cameras(c, rig, &ps, err)) < 0 ||
            (r = imp_conf_get_int(c, NULL, "tiles", false, 1, 100000, &tiles, err)) < 0 ||
            (r = imp_conf_get_double(c, NULL, "gain_db", false, 0.0, 48.0, &ps.gain_db, err)) < 0 ||
            (r = parse_sl(c, rig, &ps, err)) < 0 ||
            (r = parse_dome(c, rig, &ps, err)) < 0 ||
            (r = imp_conf_get_int(c, NULL, "dark.count", false, 0, 1000, &dark, err)) < 0)
                goto out;
        ps.tiles = (int) tiles;
        ps.dark_count = (int) dark;
        if (!ps.sl && !ps.dome && ps.dark_count == 0) {
                r = imp_error_set(err, -EINVAL, "%s: the plan captures nothing (no structured_light, dome or dark)",
                                  imp_conf_path(c));
                goto out;
        }
        if ((r = check_expansion(c, rig, &ps, err)) < 0)
                goto out;
        struct imp_plan *p = calloc(1, sizeof *p);
        if (!p) {
                r = -ENOMEM;
                goto out;
        }
        p->gray_bits[0] = ps.gray_bits[0];
        p->gray_bits[1] = ps.gray_bits[1];
        r = parse_painting(c, p, err);
        if (r >= 0)
                r = expand(p, &ps);
        if (r < 0) {
                imp_plan_free(p);
                goto out;
        }
        *ret = p;
out:
        free(ps.lights);
        return r;
}

int imp_plan_load(const char *path, const struct imp_rig *rig, struct imp_plan **ret,
                  struct imp_error *err) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        int r = imp_conf_load(path, &c, err);
        if (r < 0)
                return r;
        return plan_from_conf(c, rig, ret, err);
}

/* libconfig (1.5) honours `@include "F"` at the start of a line even in a string, opening F
 * relative to the working directory with the caller's rights, and it has no hook to refuse
 * it. A plan as text has no directory of its own, and the daemon's plans come from clients:
 * any "@include" (any case, anywhere, even in a comment or a string) is refused before
 * libconfig sees the text, so that nothing is opened and no other file's name, existence or
 * syntax reaches the message. */
static int refuse_include(const char *text, const char *name, struct imp_error *err) {
        int line = 1;
        for (const char *p = text; *p; p++) {
                if (*p == '\n')
                        line++;
                else if (*p == '@' && strncasecmp(p + 1, "include", 7) == 0)
                        return imp_error_set(err, -EINVAL, "%s:%d: @include: a plan read as text (every plan "
                                             "given to impastod) may not include other files; write it out "
                                             "in full", name ? name : "(string)", line);
        }
        return 0;
}

int imp_plan_load_string(const char *text, const char *name, const struct imp_rig *rig,
                         struct imp_plan **ret, struct imp_error *err) {
        _cleanup_(imp_conf_freep) struct imp_conf *c = NULL;
        int r = refuse_include(text, name, err);
        if (r < 0)
                return r;
        r = imp_conf_load_string(text, name, &c, err);
        if (r < 0)
                return r;
        return plan_from_conf(c, rig, ret, err);
}

static bool same_pattern(const struct imp_pattern *a, const struct imp_pattern *b) {
        return a->kind == b->kind && a->axis == b->axis && a->bit == b->bit && a->nbits == b->nbits &&
               a->inverse == b->inverse && a->period_px == b->period_px && a->step == b->step &&
               a->steps == b->steps;
}

bool imp_plan_same_state(const struct imp_frame_record *a, const struct imp_frame_record *b) {
        return a && b && !strcmp(a->camera, b->camera) && a->tile == b->tile && a->light == b->light &&
               a->exposure_us == b->exposure_us && a->gain_db == b->gain_db && same_pattern(&a->pattern, &b->pattern);
}

size_t imp_plan_run_length(const struct imp_plan *p, size_t i) {
        size_t j = i;
        while (j < p->n_frames && imp_plan_same_state(&p->frames[i], &p->frames[j]))
                j++;
        return j - i;
}

double imp_plan_estimate_s(const struct imp_plan *p, const struct imp_rig *rig) {
        double total_us = 0;
        for (size_t i = 0; i < p->n_frames; i++) {
                const struct imp_frame_record *f = &p->frames[i];
                double readout_us = 0;
                for (int k = 0; k < rig->n_cameras; k++)
                        if (!strcmp(rig->cameras[k].name, f->camera))
                                readout_us = rig->cameras[k].sensor.readout_us;
                total_us += f->exposure_us + readout_us + rig->settle_us;
                if (i > 0 && (f->light != p->frames[i - 1].light ||
                              !same_pattern(&f->pattern, &p->frames[i - 1].pattern)))
                        total_us += rig->settle_us;
        }
        return total_us * 1e-6;
}

json_t *imp_plan_painting_estimate_json(const struct imp_plan *p, const struct imp_rig *rig, double tile_bytes,
                                        const struct imp_plan_painting_opts *o) {
        const struct imp_tile_plan *tp = imp_plan_tiles(p);
        if (!tp || !o)
                return NULL;
        double mpix = 0;
        for (size_t i = 0; i < imp_plan_count(p); i++)
                for (int c = 0; c < rig->n_cameras; c++)
                        if (!strcmp(rig->cameras[c].name, imp_plan_frame(p, i)->camera))
                                mpix += rig->cameras[c].model.width * (double) rig->cameras[c].model.height * 1e-6;
        struct imp_tile_cost cost = {
                .frames = imp_plan_count(p), .bytes = tile_bytes, .capture_s = imp_plan_estimate_s(p, rig),
                .process_s = o->process_s >= 0 ? o->process_s : mpix * IMP_PLAN_PROCESS_S_PER_FRAME_MPIX,
                .workers = o->workers, .speed_mm_s = o->speed_mm_s, .settle_s = o->settle_s,
        };
        struct imp_tile_estimate e;
        if (imp_tile_plan_estimate(tp, &cost, &e) < 0)
                return NULL;
        unsigned cols, rows;
        imp_tile_plan_grid(tp, &cols, &rows);
        double step[2], overlap[2];
        imp_tile_plan_spacing(tp, step, overlap);
        return json_pack("{s:I,s:I,s:I,s:[f,f],s:f,s:I,s:f,s:f,s:f,s:f,s:f,s:f,s:I,s:f,s:f}", "tiles", (json_int_t) e.tiles,
                         "cols", (json_int_t) cols, "rows", (json_int_t) rows, "overlap", overlap[0], overlap[1],
                         "edge_margin_mm", imp_tile_plan_options(tp)->edge_margin_mm,
                         "frames", (json_int_t) e.frames, "bytes", e.bytes, "move_s", e.move_s, "capture_s",
                         e.capture_s, "process_s", e.process_s, "wall_s", e.wall_s, "tile_process_s", cost.process_s,
                         "workers", (json_int_t) cost.workers, "stage_speed_mm_s", cost.speed_mm_s, "settle_s",
                         cost.settle_s);
}
