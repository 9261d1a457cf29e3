/* A frame flush with its canvas (or standing a fraction of a millimetre off it) found by
 * what the captured images show rather than by the height: the frame is a band of one
 * material along each side of the canvas, ending at a straight line where the albedo
 * steps. Used by the heightfield's canvas extraction (heightfield.c) on the seed fill,
 * which geometry alone lets run across such a frame.
 *
 * Method: in the canvas plane (u along world x projected, v = n × u), per side, the
 * canvas pixels of the central half of the side's length are binned by their inward
 * distance t from the fill's edge, in four segments along the side; per segment and bin
 * the median albedo. The outermost bins give the outer material's level A and its pixel
 * spread σ; walking inward, the boundary is the first bin where two consecutive bins and
 * the next few on average differ from A by more than τ = max(HF_EDGE_STEP_REL·A, 4σ),
 * every bin before it staying within τ/2 of A (a uniform band that ends abruptly: the
 * slow drift of shading towards a deep frame's wall is no frame). A side
 * is trimmed when at least three of its four segments find a boundary and those agree
 * within HF_EDGE_AGREE_BINS (a frame's edge is straight; a paint region's is not): every
 * pixel nearer the edge than the middle of the farthest boundary bin leaves the canvas
 * (that bin's median is the paint's, so less than half of it is frame, and the frame
 * lies on its outer side). A frame
 * of the canvas's own albedo is not found. Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "triangulate.h"

struct imp_frame_edge {
        double trim_mm[4];            /* per side (−u, +u, −v, +v): inward distance removed, 0 none */
        unsigned sides_trimmed;       /* bit k: side k trimmed */
        size_t n_trimmed;             /* canvas pixels removed */
};

/* The canvas frame's in-plane axes for plane normal n (unit): ex = world x projected on
 * the plane (world y when the plane is nearly perpendicular to world x), ey = n × ex. */
void imp_canvas_axes(const double n[3], double ret_ex[3], double ret_ey[3]);

/* Trims the frame bands off canvas (w·h, nonzero = canvas) in place. albedo: per range
 * pixel (w·h; e.g. the decoder's direct component), non-finite values ignored; (m, n):
 * the canvas plane (n unit); bin_mm > 0: the bin width (about two camera footprints).
 * Returns 0 or -ENOMEM; -EINVAL on bad arguments. */
int imp_frame_edge_trim(const struct imp_range_image *r, const float *albedo, const double m[3], const double n[3],
                        double bin_mm, uint8_t *canvas, struct imp_frame_edge *ret);
