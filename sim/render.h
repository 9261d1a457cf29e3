/* Image formation for the simulated rig: a frame record (camera, light, projector
 * pattern, exposure) → the raw frame that camera would deliver.
 *
 * Per camera a *view map* is computed once (the camera does not move within a tile): the
 * ray of every pixel marched through the heightfield (linear search at ≤ half a sample per
 * step, then 24 bisections; seed §5.2), giving the hit point, normal, local frame, view
 * direction and texel. Frames then only shade. Effects (sim/scene.h) are read when the
 * renderer is created; an effect not listed costs nothing — no rays, no random draws.
 *
 * Conventions:
 * - Radiance: V = E · cos θl · f(v, l) (pipeline/model/lafortune.h), E = intensity ·
 *   (1000 / d)² · cos^p(angle to the LED axis) · colour; projector E = intensity ·
 *   (1000 / d)² · (black + (1 − black) · value^gamma), white light.
 * - Mono sensors see the Rec. 709 luminance 0.2126 R + 0.7152 G + 0.0722 B of the RGB
 *   radiance; colour cameras give 3-channel frames; `bayer` a 1-channel RGGB mosaic
 *   (R at even x and even y).
 * - Patterns, with x the continuous projector coordinate along the pattern's axis (OpenCV
 *   convention: pixel i covers [i − 0.5, i + 0.5)): GRAY bit b of code g = i ^ (i >> 1) for
 *   column (row) i = floor(x + 0.5), b = 0 the most significant of nbits, 1 = lit, inverse
 *   flips; PHASE value = 0.5 + 0.5 · cos(2π (x + 0.5) / period + 2π step / steps), as
 *   imp_sl_pattern_value() defines it for the decoder; WHITE 1, BLACK 0
 *   (black still emits the black level); NONE: projector dark.
 * - Sensor: electrons = V · quantum_scale · exposure_us · 1e-6; with `noise`: × (1 + PRNU),
 *   + dark current · t, Poisson shot noise (inversion below 20 e⁻, Gaussian above), clip at
 *   full well, + Gaussian read noise; DN = e / (gain_e_per_dn · 10^(−gain_db / 20)) +
 *   black level, rounded, clipped to [0, 2^bits − 1]. Random numbers are a hash of (seed,
 *   frame seq, camera, pixel, draw), so frames are bit-identical whatever the thread count.
 * - `dark` step frames see no light at all (capped lens); ambient applies to other frames.
 * - Indirect light is computed for dome lights only (not the projector). */
#pragma once
#include <stdbool.h>
#include "captureset.h"
#include "image.h"
#include "scene.h"
#include "surface.h"

struct imp_render;   /* opaque; holds view maps and caches; one thread of control at a time */

/* Builds the view maps of every camera. The scene must outlive the renderer.
 * Caller frees with imp_render_free(). */
int imp_render_new(const struct imp_scene *scene, struct imp_render **ret, struct imp_error *err);
void imp_render_free(struct imp_render *r);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_render *, imp_render_free);

/* The frame `rec` as raw DN (u16; 1 channel, or 3 for colour cameras). -EAGAIN when the
 * frame is dropped (effect dropped_frame); -ENOENT for an unknown camera or light.
 * Caller frees with imp_image_free(). */
int imp_render_frame(struct imp_render *r, const struct imp_frame_record *rec, struct imp_image **ret,
                     struct imp_error *err);
/* The linear radiance V of `rec` before the sensor (f32; 1 or 3 channels), with
 * vignetting and defocus applied when listed. */
int imp_render_radiance(struct imp_render *r, const struct imp_frame_record *rec, struct imp_image **ret,
                        struct imp_error *err);

/* The calibration the frames obey: the scene's rig with distortion coefficients zeroed
 * when `distortion` is not listed. */
const struct imp_rig *imp_render_rig(const struct imp_render *r);
const struct imp_sim_counters *imp_render_counters(const struct imp_render *r);
void imp_render_reset_counters(struct imp_render *r);

/* The view map at pixel (x, y) of camera `cam`: world hit point and unit normal.
 * -ENODATA when the pixel's ray misses the sampled surface, -EINVAL out of range. */
int imp_render_view_point(const struct imp_render *r, int cam, int x, int y, double ret_p[3],
                          double ret_n[3]);

/* Ground truth for structured light: f32 image of camera `cam` with channels proj_x,
 * proj_y, valid, depth_mm (valid 0 where the ray misses, the projector does not reach or
 * the point is shadowed from the projector — always tested geometrically; values 0
 * there). -ENODEV without a projector. Not counted in the counters. */
int imp_render_correspondence(struct imp_render *r, int cam, struct imp_image **ret);

/* Writes DIR/truth/ (sim/truth.c): truth.json, heightfield.exr (height, nx, ny, nz, mask),
 * rho_d.exr, rho_s.exr (R, G, B), lobe.exr (cx, cy, cz, k) on the surface grid, rig.json
 * (the calibration the frames obey, imp_render_rig) and correspondence-NAME.exr per camera
 * when the rig has a projector. */
int imp_sim_write_truth(const struct imp_scene *scene, struct imp_render *r, const char *dir,
                        struct imp_error *err);
/* The sampled surface's truth alone (truth.json and the four EXR files above) in DIR/truth/:
 * for a gantry scene placed whole (imp_scene_place_whole), the painting-frame truth. */
int imp_sim_write_painting_truth(const struct imp_scene *scene, const char *dir, struct imp_error *err);
