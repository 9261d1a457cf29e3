/* PNG previews of a digital copy for people (COPY/previews/): shaded relief, normal map,
 * height with a colour bar in mm and a length scale, height σ, flagged texels, the diffuse
 * colour when rho_d (the copy's ρd map, the grid's size, RGB f32; may be NULL) is given, and
 * index.html showing them side by side. Library code: no logging. */
#pragma once
#include "error.h"
#include "heightfield.h"

int imp_copy_previews(const char *copy_dir, const struct imp_heightfield *hf, const struct imp_image *rho_d,
                      struct imp_error *err);
