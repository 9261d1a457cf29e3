/* The copy converted once for the browser viewer (docs/viewer.md, "What the server sends"):
 * four RGBA half-float textures in one blob and a JSON description. Heights are stored
 * relative to the bump plane so that half floats keep micrometres (11-bit mantissa: 1 µm
 * steps up to 2 mm of relief). Library code: no logging. */
#pragma once
#include <stddef.h>
#include <stdint.h>
#include "copy-load.h"
#include "error.h"

#define IMP_VIEW_PACK_TEXTURES 4      /* surface, diffuse, specular, lobe */

struct imp_view_pack {
        uint16_t *data;               /* IMP_VIEW_PACK_TEXTURES × nx·ny × 4 halves, row-major */
        size_t size;                  /* bytes */
        char *meta;                   /* JSON, NUL-terminated */
        size_t meta_size;             /* bytes without the NUL */
};

/* Texture t, texel k, channel c: data[(t·nx·ny + k)·4 + c]. The channels:
 *   0 surface:  height − plane_mm, nx, ny, mask (0 off, 1 measured, 2 filled)
 *   1 diffuse:  ρd R, G, B, σ (mm)
 *   2 specular: ρs R, G, B, fit flags (an integer below 2048, exact in half)
 *   3 lobe:     Cx, Cy, Cz, k
 * The meta JSON holds the grid, the plane, height and σ ranges, the boxes with their tops
 * (as the CPU renderer computes them) and the channel names. */
int imp_view_pack_build(const struct imp_copy *c, struct imp_view_pack *ret, struct imp_error *err);
void imp_view_pack_done(struct imp_view_pack *p);

/* IEEE half from float, rounding to nearest even; NaN stays NaN, overflow gives ±inf. */
uint16_t imp_half_from_float(float f);
float imp_half_to_float(uint16_t h);

/* The cache: DIR/KEY.bin and DIR/KEY.json. Load returns -ENOENT when absent, -EBADMSG when
 * the files do not match (truncated). Save writes both crash-safely. */
int imp_view_pack_cache_load(const char *dir, const char *key, struct imp_view_pack *ret, struct imp_error *err);
int imp_view_pack_cache_save(const char *dir, const char *key, const struct imp_view_pack *p,
                             struct imp_error *err);
/* A key naming the copy's files by path, size and modification time (FNV-1a, 16 hex
 * digits): it changes when any of them changes. ret holds at least 17 bytes. */
int imp_view_pack_key(const char *copy_dir, char *ret, size_t size, struct imp_error *err);
