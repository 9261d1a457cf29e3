/* Exports of a digital copy for the tools conservators already use (docs/export.md).
 * Library code: no logging; the copy is only read. Every writer names the file it could not
 * write in err. Coordinates are the copy's canvas frame (texel (i, j) at (i·pitch, j·pitch),
 * height z out of the paint, mm) unless a format says otherwise (glTF: metres). */
#pragma once
#include <stddef.h>
#include <stdint.h>
#include "copy-load.h"
#include "error.h"

/* A float32 TIFF heightmap: one sample per texel, row r = texel row j = r (the orientation
 * of heightfield.exr), heights in mm, NaN off the mask; XResolution = YResolution =
 * 10 / pitch_mm pixels per centimetre (ResolutionUnit 3), so the pixel size is exact to
 * float precision; ImageDescription a JSON object (units, pitch_mm, h_ref_mm, nodata). */
int imp_export_tiff_height(const struct imp_copy *c, const char *path, struct imp_error *err);

/* A triangle mesh of the heightfield on a regular sub-grid of step texels (the step at
 * which the full grid fits the triangle budget, or larger): vertices sit exactly on texels and carry the
 * copy's height, normal and albedo there; cells with a corner off the mask are left out. */
struct imp_mesh {
        size_t n_vertices, n_triangles;
        int step;                     /* texels between neighbouring vertices */
        float *pos;                   /* 3 per vertex, mm, canvas frame */
        float *normal;                /* 3 per vertex, unit */
        float *uv;                    /* 2 per vertex: texel centre / grid size (glTF convention) */
        uint8_t *rgb;                 /* 3 per vertex: ρd, sRGB-encoded, clamped */
        int32_t *texel;               /* 2 per vertex: i, j */
        uint32_t *tri;                /* 3 per triangle, counter-clockwise seen from +z */
};
int imp_mesh_build(const struct imp_copy *c, size_t max_triangles, struct imp_mesh *ret, struct imp_error *err);
void imp_mesh_done(struct imp_mesh *m);

/* Binary little-endian PLY: x y z nx ny nz (float), red green blue (uchar), faces as
 * uchar-counted int lists; comments give the units and the pitch. */
int imp_export_ply(const struct imp_mesh *m, const struct imp_copy *c, const char *path, struct imp_error *err);

/* glTF 2.0 binary: the mesh in metres with normals and texture coordinates, a material with
 * the albedo (ρd, sRGB PNG) as base colour and the copy's normals as a tangent-space normal
 * map (tangent +x, bitangent +y: exact for a flat canvas, the mesh's tilt is not removed). */
int imp_export_glb(const struct imp_mesh *m, const struct imp_copy *c, const char *path, struct imp_error *err);

/* The texture maps: albedo.png (ρd, sRGB, 8 bit) and normal.png (RGB = (n + 1) / 2, 8 bit),
 * copy-sized, row r = texel row j = r. Written into dir; also returned as PNG bytes when
 * ret_* are not NULL (caller frees). */
int imp_export_maps(const struct imp_copy *c, const char *dir, uint8_t **ret_albedo, size_t *ret_albedo_size,
                    uint8_t **ret_normal, size_t *ret_normal_size, struct imp_error *err);

/* The raw dome stack for RTI tools (RelightLab, RTIBuilder): from the capture set CAPSET
 * (its first camera, first tile), one 16-bit PNG per dome light, linear (black level
 * removed, the sensor's range stretched to 0..65535), all at one exposure: the longest at
 * which no light's frame has more than 0.5 % of its pixels saturated (or exposure_index
 * when >= 0). Writes DIR/images/light-NNN.png, DIR/lights.lp ("N", then "FILE x y z" per
 * light: the unit direction from the canvas point at the image centre to the light) and
 * DIR/lights.dome (Relight's dome JSON, "lights3d": positions in mm in the same frame:
 * z the canvas normal towards the camera, x the image's right projected on the canvas,
 * y = z × x; ledAdjust = mean intensity over the LED's, per channel). The copy gives the
 * canvas plane (canvas_to_world and the bump plane). */
struct imp_lp_summary {
        size_t n_lights;
        int exposure_index;
        double exposure_us;
        int width, height;
        double image_width_mm;        /* the image's footprint on the canvas plane */
};
int imp_export_lp(const struct imp_copy *c, const char *capset_dir, const char *dir, int exposure_index,
                  struct imp_lp_summary *ret, struct imp_error *err);

/* OpenLIME's isotropic Ward model (its ShaderBRDF): physical BRDF kd/π + ks·spec with
 * spec = exp(−tan²θh / α²) / (4π α² √(cosθl cosθv)) and α = (1 − g·(G1 − G0) − G0)^4 from
 * the gloss g in [0, 1], G0 = 1 − 0.5^¼, G1 = 1 − 0.01^¼ (α from 0.5 down to 0.01). */
struct imp_ward_fit {
        float ks[3];                  /* linear */
        float gloss;                  /* [0, 1] */
        float alpha;
        float rel_error;              /* RMS residual / RMS of the Lafortune specular term,
                                         cosine- and solid-angle-weighted; 0 without a lobe */
};
/* Refits the Lafortune specular lobe of b with the viewer on the normal (OpenLIME looks
 * straight down), over light elevations 0..85°: kd = ρd, α on a gloss grid, ks by least
 * squares for each α (the best α is the same for all channels since ρs only scales). */
void imp_ward_refit(const struct imp_lafortune *b, struct imp_ward_fit *ret);
double imp_ward_alpha(double gloss);

/* An OpenLIME BRDF layer: the maps kd (ρd), ks, normals ((n + 1) / 2, y towards image
 * up), gloss as 8-bit PNGs cut into deepzoom tiles by libvips (DIR/NAME.dzi and
 * DIR/NAME_files/), DIR/refit-error.tif (float32 per texel), DIR/openlime.json (the layer's
 * options: layout, channels, colour spaces, sizes, refit figures). ret_* (may be NULL)
 * get the median and 95th percentile of the refit error over the mask. Returns -ENOTSUP
 * when impasto was built without libvips. */
int imp_export_openlime(const struct imp_copy *c, const char *dir, double *ret_err_median, double *ret_err_p95,
                        struct imp_error *err);
