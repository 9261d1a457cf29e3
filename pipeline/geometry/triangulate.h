/* Triangulation of decoded structured light: camera pixel + projector coordinate(s) →
 * world point (mm) with an uncertainty, for every camera pixel the decoder marked valid.
 *
 * Pixel conventions: camera pixel (i, j) is pinhole coordinate (i, j) (OpenCV: centre of
 * pixel 0 at 0). Decoded projector coordinates have pixel centres at integer + 0.5 (pixel
 * k covers [k, k+1)), so the pinhole coordinate is proj − proj_offset_px (default 0.5).
 *
 * Method: the point is X(λ) = C + λ d on the (undistorted) camera ray. λ minimises the
 * projector reprojection error — (π_p(X) − p)² with both coordinates, (π_px(X) − p_x)² with
 * the column only (π_py likewise) — by Gauss–Newton from the closed-form start (two-ray
 * midpoint, or the undistorted column/row plane), so projector distortion is handled
 * exactly. Uncertainty: σ_λ = σ_p / |∂π/∂λ| (first-order propagation of an isotropic
 * projector-coordinate σ_p through the geometry), reported along the viewing ray; it grows
 * as the triangulation angle closes. Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "quality.h"
#include "rig.h"
#include "structured-light.h"

/* What the structured-light decoder hands over, per camera pixel (row-major, w × h). */
struct imp_projector_coords {
        int width, height;
        const float *proj_x;          /* projector column, may be NULL (not decoded) */
        const float *proj_y;          /* projector row, may be NULL */
        const uint8_t *valid_x;       /* nonzero: proj_x valid here; NULL: valid where proj_x */
        const uint8_t *valid_y;       /* likewise for proj_y */
        const uint16_t *sl_flags;     /* if not NULL: the decoder's IMP_SL_VALID_X / _Y bits
                                         decide validity (valid_x / valid_y ignored) */
        const uint16_t *confidence;   /* 0..1 as imp_sl_result stores it (imp_sl_conf()),
                                         may be NULL (= 1 everywhere) */
        const uint16_t *sigma_px;     /* the decoder's own 1σ of the coordinate (projector px,
                                         bfloat16: imp_sl_sigma()), may be NULL (= 0) */
};

struct imp_triangulate_options {
        double sigma_proj_px;         /* σ of a projector coordinate at confidence 1; default 0.1 */
        double min_confidence;        /* below: pixel invalid; otherwise σ_p = the larger of
                                         sigma_proj_px / confidence and the decoder's
                                         sigma_px (a Gray centre is not better than q/√12,
                                         whatever its contrast); default 0.05 */
        double min_angle_rad;         /* smaller triangulation angle: invalid; default 2° */
        double proj_offset_px;        /* see above; default 0.5 */
        bool use_both;                /* both coordinates when both valid (default true); false:
                                         columns only, like a line-stripe scanner */
};
/* Points pc at the decoder's maps (no copy: sl must outlive pc). */
void imp_projector_coords_from_sl(const struct imp_sl_result *sl, struct imp_projector_coords *ret);

void imp_triangulate_options_default(struct imp_triangulate_options *opt);

/* Validity codes of a range pixel. */
enum {
        IMP_RANGE_INVALID = 0,        /* no (usable) decoder output */
        IMP_RANGE_BOTH = 1,           /* from column and row */
        IMP_RANGE_COLUMN = 2,         /* column plane only */
        IMP_RANGE_ROW = 3,            /* row plane only */
};

struct imp_range_image {
        int width, height;            /* camera pixels */
        float *xyz;                   /* w·h·3, world mm; 0 where invalid */
        float *sigma_mm;              /* w·h, σ along the viewing ray, mm; 0 where invalid */
        uint8_t *valid;               /* w·h, IMP_RANGE_* */
        /* w·h, per-texel flags (quality.h IMP_TEXEL_*) the decoder's flags imply for the
         * point: SATURATED (a frame it read was clipped), PHASE_REJECTED (the Gray centre
         * was kept; sigma_mm says how much worse that is); 0 where invalid. */
        uint16_t *flags;
        double camera_centre_mm[3];   /* world position of the camera centre */
        /* Mean camera footprint at the valid points, mm: ray length / √(fx·fy). Unlike the
         * distance between neighbouring 3-D points it does not grow with range noise (a
         * grid pitch from it stays put on a noisy scan). 0 when nothing is valid. */
        double footprint_mm;
        size_t n_valid;
};

/* Allocates an empty (all invalid) range image. Caller frees with imp_range_image_done(). */
int imp_range_image_init(struct imp_range_image *r, int width, int height);
void imp_range_image_done(struct imp_range_image *r);   /* frees members; accepts zeroed */

/* Triangulates. cam/proj: calibrated models (pose world→device). Returns 0, -EINVAL on bad
 * arguments (sizes, non-positive focal lengths), -ENOMEM. On success caller frees *ret with
 * imp_range_image_done(); on failure *ret is untouched. */
int imp_triangulate(const struct imp_pinhole *cam, const struct imp_pinhole *proj,
                    const struct imp_projector_coords *pc, const struct imp_triangulate_options *opt,
                    struct imp_range_image *ret);

/* Projection of a world point with the Jacobian of the pixel w.r.t. the world point
 * (row-major 2×3; may be NULL). Returns false when the point is not in front. Exposed for
 * tests and for other stages that need derivatives. */
bool imp_triangulate_project(const struct imp_pinhole *m, const double X[3], double ret_px[2],
                             double ret_J[6]);
/* Pixel → unit world ray direction (undistorted iteratively) and device centre. */
void imp_triangulate_ray(const struct imp_pinhole *m, const double px[2], double ret_C[3],
                         double ret_d[3]);
