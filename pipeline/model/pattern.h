/* A projected pattern, as plans, manifests, projector drivers and the decoder name it.
 * Conventions (docs/structured-light.md): projector pixel i spans decoder coordinates
 * [i, i + 1); GRAY bit 0 is the most significant; PHASE value at pixel i is
 * 0.5 + 0.5·cos(2π (i + 0.5) / period + 2π step / steps). */
#pragma once
#include <stdbool.h>

enum imp_pattern_kind { IMP_PAT_NONE, IMP_PAT_WHITE, IMP_PAT_BLACK, IMP_PAT_GRAY, IMP_PAT_PHASE };

struct imp_pattern {
        enum imp_pattern_kind kind;
        int axis;                     /* 0: encodes projector columns (x), 1: rows (y) */
        int bit;                      /* GRAY: bit index, 0 = most significant */
        int nbits;                    /* GRAY: total bits for this axis */
        bool inverse;                 /* GRAY: the inverted pattern */
        double period_px;             /* PHASE: sinusoid period in projector pixels */
        int step, steps;              /* PHASE: step i of N, phase offset 2π i / N */
};
