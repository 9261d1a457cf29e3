/* A digital copy read whole into memory (docs/copy-quality.md, heightfield.h, btf.h): the
 * grid, the heightfield with its σ, mask and flags, the per-texel Lafortune BRDF and the
 * relief boxes, with the values the renderers need (off-mask texels on the bump plane,
 * black paint, finite everywhere). Readers of the copy (the viewer, the exports) share it.
 * Library code: no logging; the copy is never modified. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "error.h"
#include "lafortune.h"
#include "relief-render.h"

struct imp_copy {
        int nx, ny;                   /* texels */
        double pitch_mm;
        double canvas_to_world[16];   /* copy.json, row-major; identity when absent */
        double h_ref_mm, delta0_mm;   /* boxes.json: reference height and the threshold above it */
        double plane_mm;              /* the bump plane h_ref + δ0, canvas frame (seed §5.1) */
        float *height;                /* nx·ny mm, canvas frame; off the mask: plane_mm */
        float *normal_x, *normal_y;   /* off the mask: 0 */
        float *sigma;                 /* height σ in mm; off the mask: 0 */
        uint8_t *mask;                /* heightfield.exr mask: 0 off, 1 measured, 2 filled */
        uint16_t *texel_flags;        /* heightfield.exr flags: the copy's quality flags (bits of
                                         enum imp_texel_flag, quality.h); zeros when it has none */
        bool has_flags;
        uint16_t *fit_flags;          /* fit-flags.exr: the BRDF fit's flags (bits of enum
                                         imp_btf_flag, btf.h); zeros when the copy has none */
        bool has_fit_flags;
        struct imp_lafortune *brdf;   /* nx·ny; off the mask: black (ρd = ρs = 0) */
        struct imp_relief_box *boxes; /* n_boxes (from boxes.json) */
        size_t n_boxes;
        size_t n_mask;                /* texels on the mask */
};

/* Reads COPY_DIR/{copy.json, boxes.json, heightfield.exr (its flags channel optional),
 * rho_d.exr, rho_s.exr, lobe.exr, fit-flags.exr (optional)}. Errors name the file and the field: a missing file, a missing
 * channel, a size other than copy.json's, a bad box. Returns 0 or a negative errno; *ret
 * is zeroed first and freed with imp_copy_done() in every case. */
int imp_copy_load(const char *dir, struct imp_copy *ret, struct imp_error *err);
void imp_copy_done(struct imp_copy *c);

/* The copy as the hybrid renderer takes it (canvas frame: identity transform). Borrows c's
 * arrays. */
void imp_copy_relief(const struct imp_copy *c, struct imp_relief_copy *ret);

/* Classifies the relief again into boxes of cell_px texels (seed §4.3, imp_boxes_classify)
 * with the copy's δ0 / H, replacing c's boxes, h_ref, δ0 and plane: for the benchmark of
 * box sizes (seed Table 2). Returns 0 or a negative errno. */
int imp_copy_reclassify(struct imp_copy *c, int cell_px, struct imp_error *err);
