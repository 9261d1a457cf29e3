/* Range image from structured-light frames alone (process-range.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "captureset.h"
#include "json-util.h"
#include "process-range.h"

/* Camera 0's structured-light frames: the first frame of each pattern, as u8 when the
 * sensor is 8-bit (the decoder's 8-bit thresholds, OpenCV's), else u16. */
static int load_sl(const struct imp_captureset *cs, struct imp_image ***ret_imgs, struct imp_pattern **ret_pats,
                   int *ret_n, struct imp_error *err) {
        const struct imp_rig *rig = imp_captureset_rig(cs);
        size_t count = imp_captureset_count(cs);
        struct imp_image **imgs = calloc(count ? count : 1, sizeof *imgs);
        struct imp_pattern *pats = calloc(count ? count : 1, sizeof *pats);
        int n = 0, r = 0;
        bool eight = rig->cameras[0].sensor.bits <= 8;
        if (!imgs || !pats)
                r = imp_error_set(err, -ENOMEM, "out of memory");
        for (size_t i = 0; i < count && r >= 0; i++) {
                const struct imp_frame_record *rec = imp_captureset_record(cs, i);
                if (strcmp(rec->step, "structured-light") || strcmp(rec->camera, rig->cameras[0].name) || rec->tile)
                        continue;
                bool seen = false;
                for (int k = 0; k < n && !seen; k++)
                        seen = !memcmp(&pats[k], &rec->pattern, sizeof pats[k]);
                if (seen)
                        continue;
                struct imp_image *f = NULL;
                if ((r = imp_captureset_load_frame(cs, i, &f, err)) < 0)
                        break;
                if (f->channels != 1) {
                        imp_image_free(f);
                        r = imp_error_set(err, -EINVAL, "%s: frame %zu: %d channels, expected grey", imp_captureset_dir(cs),
                                          i, f->channels);
                        break;
                }
                if (eight) {
                        struct imp_image *g = NULL;
                        if ((r = imp_image_new(f->width, f->height, 1, IMP_PIX_U8, &g)) >= 0)
                                for (int y = 0; y < f->height; y++)
                                        for (int x = 0; x < f->width; x++)
                                                *imp_image_u8(g, x, y) = (uint8_t) IMP_MIN(255, *imp_image_u16(f, x, y));
                        imp_image_free(f);
                        f = g;
                        if (r < 0) {
                                r = imp_error_set(err, r, "out of memory");
                                break;
                        }
                }
                pats[n] = rec->pattern;
                imgs[n++] = f;
        }
        if (r >= 0 && n == 0)
                r = imp_error_set(err, -EINVAL, "%s/manifest.jsonl: no structured-light frames for camera %s",
                                  imp_captureset_dir(cs), rig->cameras[0].name);
        if (r < 0) {
                for (int k = 0; k < n; k++)
                        imp_image_free(imgs[k]);
                free(imgs);
                free(pats);
                return r;
        }
        *ret_imgs = imgs;
        *ret_pats = pats;
        *ret_n = n;
        return 0;
}

int imp_range_from_set(const char *capture_dir, struct imp_range_image *ret_range, struct imp_sl_result **ret_sl,
                       struct imp_error *err) {
        _cleanup_(imp_captureset_closep) struct imp_captureset *cs = NULL;
        int r = imp_captureset_open(capture_dir, &cs, err);
        if (r < 0)
                return r;
        const struct imp_rig *rig = imp_captureset_rig(cs);
        if (rig->n_cameras < 1 || !rig->has_projector)
                return imp_error_set(err, -EINVAL, "%s/rig.json: a camera and a projector are needed", capture_dir);
        struct imp_image **imgs = NULL;
        struct imp_pattern *pats = NULL;
        int n = 0;
        if ((r = load_sl(cs, &imgs, &pats, &n, err)) < 0)
                return r;
        struct imp_sl_params p;
        imp_sl_params_default(&p, imgs[0]->type);
        p.proj_width = rig->projector.model.width;
        p.proj_height = rig->projector.model.height;
        p.coords_only = true;   /* triangulation and range.exr read no light map */
        struct imp_sl_frames fr = { pats, (const struct imp_image *const *) imgs, n };
        struct imp_sl_result *sl = NULL;
        r = imp_sl_decode(&fr, &p, &sl, err);
        for (int k = 0; k < n; k++)
                imp_image_free(imgs[k]);
        free(imgs);
        free(pats);
        if (r < 0)
                return imp_error_prefix(err, "%s: structured light: ", capture_dir);
        struct imp_projector_coords pc;
        struct imp_triangulate_options to;
        imp_projector_coords_from_sl(sl, &pc);
        imp_triangulate_options_default(&to);
        r = imp_triangulate(&rig->cameras[0].model, &rig->projector.model, &pc, &to, ret_range);
        if (r < 0) {
                imp_sl_result_free(sl);
                return imp_error_set(err, r, "%s: triangulation failed: %s", capture_dir, strerror(-r));
        }
        if (ret_sl)
                *ret_sl = sl;
        else
                imp_sl_result_free(sl);
        return 0;
}

static int write_range(const char *out_dir, const struct imp_range_image *rg, const struct imp_sl_result *sl,
                       struct imp_error *err) {
        _cleanup_image_ struct imp_image *img = NULL;
        int r = imp_image_new(rg->width, rg->height, 7, IMP_PIX_F32, &img);
        if (r < 0)
                return imp_error_set(err, r, "range: cannot allocate");
        for (int y = 0; y < rg->height; y++)
                for (int x = 0; x < rg->width; x++) {
                        size_t t = (size_t) y * rg->width + x;
                        float *o = imp_image_f32(img, x, y);
                        bool vx = sl->flags[t] & IMP_SL_VALID_X, vy = sl->flags[t] & IMP_SL_VALID_Y;
                        o[0] = rg->xyz[3 * t], o[1] = rg->xyz[3 * t + 1], o[2] = rg->xyz[3 * t + 2];
                        o[3] = rg->sigma_mm[t];
                        o[4] = rg->valid[t];
                        o[5] = vx ? sl->proj_x[t] : -1.f;
                        o[6] = vy ? sl->proj_y[t] : -1.f;
                }
        static const char *const names[] = { "X", "Y", "Z", "sigma_mm", "valid", "proj_x", "proj_y" };
        char path[4200];
        snprintf(path, sizeof path, "%s/range.exr", out_dir);
        if ((r = imp_exr_write(path, img, names, false, err)) < 0)
                return r;
        _cleanup_json_ json_t *j = json_pack("{s:s,s:i,s:i,s:I,s:I,s:I,s:I}", "format", "impasto-range", "width",
                                             rg->width, "height", rg->height, "points", (json_int_t) rg->n_valid,
                                             "decoded_x", (json_int_t) sl->n_valid_x, "decoded_y",
                                             (json_int_t) sl->n_valid_y, "shadow", (json_int_t) sl->n_shadow);
        snprintf(path, sizeof path, "%s/range.json", out_dir);
        return j ? imp_json_save_atomic(path, j, err) : imp_error_set(err, -ENOMEM, "out of memory");
}

int imp_process_range(const char *capture_dir, const char *out_dir, struct imp_error *err) {
        struct imp_range_image rg = {};
        _cleanup_(imp_sl_result_freep) struct imp_sl_result *sl = NULL;
        int r = imp_range_from_set(capture_dir, &rg, &sl, err);
        if (r < 0)
                return r;
        if ((r = imp_mkdir_p(out_dir, 0755)) < 0)
                imp_error_set(err, r, "%s: cannot create: %s", out_dir, strerror(-r));
        else
                r = write_range(out_dir, &rg, sl, err);
        imp_range_image_done(&rg);
        return r;
}
