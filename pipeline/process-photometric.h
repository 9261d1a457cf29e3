/* `impasto process --photometric-only`: a capture set's dome sweep (impasto's own, or one
 * imported from another rig, import-photometric.h) turned into normals, albedo, a
 * per-pixel Lafortune fit and integrated heights, all on the camera's pixel grid, without
 * structured light. Method, flags and biases: docs/import.md. Library code: no logging. */
#pragma once
#include <stdbool.h>
#include "error.h"
#include "image.h"
#include "rig.h"

enum imp_po_method {
        IMP_PO_ROBUST = 0,            /* saturated and dark samples dropped; attached shadow,
                                         the specular cone and cast shadows (trimmed
                                         darkest samples) left out; Huber reweighting */
        IMP_PO_WOODHAM,               /* the baseline: every sample, one least-squares solve
                                         (Woodham 1980) */
};

struct imp_po_options {
        enum imp_po_method method;
        bool btf;                     /* the Lafortune fit per pixel (true) */
        bool heights;                 /* integrate the normals into heights (true) */
        int integrate_iterations;     /* conjugate-gradient iterations of the integration (4000) */
        int threads;                  /* OpenMP threads; <= 0: as is */
};
void imp_po_options_default(struct imp_po_options *ret);

/* Writes COPY_DIR/heightfield.exr (channels height, nx, ny, nz, sigma_deg, flags, mask:
 * pixel grid, normals x right, y up, z towards the camera; flags = quality.h
 * IMP_TEXEL_* bits), albedo.exr (R, G, B), rho_d.exr, rho_s.exr, lobe.exr, fit-flags.exr
 * (with btf) and copy.json ("grid": "image", stages.photometric_only). The dome frames
 * of camera 0 are read (exposure stacks merged); the surface is taken as the world plane
 * z = 0 for the near-field light directions and irradiance. -EINVAL/-EBADMSG for a set
 * that cannot be processed (message names it), I/O and memory errors. */
int imp_process_photometric(const char *capture_dir, const char *copy_dir, const struct imp_po_options *o,
                            struct imp_error *err);

/* The dome sweep of camera 0 of a capture set, merged per light (the first frame of each
 * distinct exposure and gain; repeats are not averaged), and its pixel geometry. */
struct imp_po_dome {
        const char *dir;               /* the capture directory (not owned) */
        struct imp_rig_camera camera;
        int n;                         /* lights with a frame, manifest order */
        struct imp_rig_light *lights;  /* [n] */
        struct imp_image **value;      /* [n] f32, `channels` channels: linear radiance */
        struct imp_image **flags;      /* [n] u8 per channel: hdr.h IMP_HDR_* bits */
        uint8_t *mask;                 /* width·height from DIR/mask.png (non-zero = process);
                                          NULL = every pixel */
        int width, height, channels;
        double pixel_mm;               /* import.json's, else the camera footprint on z = 0 */
};
/* Caller frees with imp_po_dome_done(); *ret untouched on failure. Errors as
 * imp_process_photometric(). */
int imp_po_dome_load(const char *capture_dir, struct imp_po_dome *ret, struct imp_error *err);
void imp_po_dome_done(struct imp_po_dome *d);
/* The surface point of pixel (x, y): the camera ray on the world plane z = 0. False when
 * the ray does not reach it. */
bool imp_po_pixel_point(const struct imp_pinhole *m, double x, double y, double ret_X[3]);
