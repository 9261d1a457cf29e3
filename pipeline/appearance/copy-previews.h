/* PNG previews of a digital copy for people: shaded relief, normal map, height colour map
 * (COPY/previews/). Library code: no logging. */
#pragma once
#include "error.h"
#include "heightfield.h"

int imp_copy_previews(const char *copy_dir, const struct imp_heightfield *hf, struct imp_error *err);
