/* Dome light calibration: light positions from highlights on glossy spheres,
 * per-light intensity and colour from a white Lambertian target, and RTI .lp files.
 * Geometry in mm in the world (canvas) frame, pixels in the camera's full-frame coordinates.
 * Method and conventions: docs/calibration-lights.md. Library code: no logging. */
#pragma once
#include <stdbool.h>
#include "error.h"
#include "image.h"
#include "rig.h"

/* A pixel window of a larger frame: an image that holds the crop whose top-left pixel is
 * (x0, y0) of the full frame (so that crops of big frames can be passed around). */
struct imp_frame_view {
        const struct imp_image *img;  /* channel 0 is used */
        int x0, y0;
};

/* ---- spheres ---- */

struct imp_sphere {
        double centre_mm[3];          /* world */
        double radius_mm;             /* known (given), not estimated */
        double image_centre_px[2];    /* projection of centre_mm (of the rim's centre for a cut sphere) */
        double image_radius_px;       /* mean apparent radius of the silhouette */
        double rms_px;                /* RMS of the silhouette edge residuals, pixels */
        double centre_sigma_mm;       /* 1σ of the fitted centre (worst direction, fit covariance) */
        double centre_cov_mm2[9];     /* the fit's covariance of the centre, row-major (zz = 0 when held);
                                       * all 0: unknown, centre_sigma_mm isotropic is used */
        bool centre_z_held;           /* C_z was given (centre_z_mm), not fitted */
        int n_edge;                   /* edge points used */
        double cut_mm;                /* the sphere exists above z = C_z + cut_mm only; NAN: whole */
};

/* Sphere from its silhouette: a dark (glossy black) sphere on a brighter background,
 * wholly inside the view `v`. Edges are found along 360 radial profiles from the centroid
 * of the dark pixels (threshold halfway between the 10th and 90th percentile), each at the
 * crossing of the local half level. The centre C minimises Σ (dist(C, edge ray) − r)²
 * (Gauss–Newton, ≤ 50 iterations, stops when the step < 1e-7 mm). When `centre_z_mm` is
 * finite, C_z = centre_z_mm is held (a ball resting on a plane: plane + r; the depth from
 * the cone angle alone is weak), otherwise C_z is fitted too. `cut_mm` finite: the sphere
 * is cut by the plane z = C_z + cut_mm and only the part above exists (0: a half ball on a
 * board; > 0: a spherical cap, a convex mirror whose rim meets the board at a slant); an
 * edge ray whose closest point to C lies below the cut is the rim's: its residual is the
 * distance of its crossing of the cut plane from C minus √(r² − cut²). Initial guess: the
 * ray through the edge points' circle centre at C_z, or at the depth r·f/ρ_px.
 * -EINVAL bad arguments; -ENOENT no contrast (no silhouette); -EDOM fewer than 32 usable
 * edge points or a non-converged fit. *ret untouched on failure. */
int imp_lights_sphere_fit(const struct imp_pinhole *cam, const struct imp_frame_view *v, double radius_mm,
                          double centre_z_mm, double cut_mm, struct imp_sphere *ret, struct imp_error *err);

/* A dark disc found in an image (image coordinates only). */
struct imp_sphere_circle {
        double centre_px[2];          /* full-frame pixels, sub-pixel */
        double radius_px;
        double rms_px;                /* RMS radial residual of the edge points kept */
        int n_edge;                   /* edge points kept (of 360 profiles) */
};

/* Mirror spheres in an image where the background is bright around each sphere and the
 * sphere's body dark (the per-pixel maximum over the light frames of a calibration
 * capture: every canvas pixel is lit in some frame, the body only at its highlights).
 * Dark pixels (below the midpoint of the 5th and 95th percentiles) form 8-connected
 * components; each that does not touch the view's border and whose equivalent radius is in
 * [min_radius_px, max_radius_px] seeds 360 radial profiles from outside inwards (the first
 * crossing of the local half level, so highlights inside the body do not matter); a
 * circle is fitted to the edge points (Kåsa, then three passes dropping points beyond
 * 3 × 1.4826 MAD and 0.5 px). Kept: ≥ 70 % of the profiles give an edge and the RMS is
 * below 0.1 × radius — a shadow, the canvas border or a blob is no circle. Sorted by
 * image position (rows of 1/4 image height, then x), at most `max` written.
 * Returns the number found (≥ 0) or -EINVAL / -ENOMEM. */
int imp_lights_sphere_detect(const struct imp_frame_view *v, double min_radius_px, double max_radius_px,
                             struct imp_sphere_circle *ret, int max);

/* ---- highlights ---- */

struct imp_highlight {
        double px[2];                 /* sub-pixel centroid, full-frame pixels */
        double sigma_px;              /* 1σ of the centroid, pixels (see docs) */
        double peak;                  /* brightest value */
        int n_pixels;                 /* pixels in the blob */
        bool saturated;               /* blob contains values ≥ saturation */
};

/* The highlight of one light on a sphere: the brightest pixel inside the sphere's image
 * disc (shrunk by 2 px), its 4-connected blob above thr = bg + ½(peak − bg) (bg = median of
 * the disc), and the centroid weighted by (min(v, sat) − thr). A saturated blob (peak ≥
 * saturation, pass INFINITY when nothing saturates) gets σ = max(0.25 px, 0.5/√n) because
 * its plateau hides the true peak; an unsaturated one gets σ from the background noise
 * (σ_bg √Σ|x − x̄|² / Σw, at least 0.01 px). -ENOENT when no pixel stands out above the
 * background by 10 σ_bg (light not reflected towards the camera). */
int imp_lights_highlight(const struct imp_frame_view *v, const struct imp_sphere *s, double saturation,
                         struct imp_highlight *ret);

/* The ray O + t·u (u a unit vector) meets the sphere (C, r) first at ret_P and leaves it
 * reflected along the unit direction ret_d. false, outputs untouched, when it misses. */
bool imp_lights_reflect_ray(const double O[3], const double u[3], const double C[3], double r, double ret_P[3],
                            double ret_d[3]);

/* The reflected ray of a highlight: camera ray through px → first intersection with the
 * sphere → reflection about the sphere normal. ret_sigma_rad (may be NULL) is the angular
 * 1σ of the reflected direction for a centroid 1σ of sigma_px (numerical derivative),
 * combined with that of the sphere centre's 1σ (s->centre_sigma_mm moves the normal by
 * σ_C/r, the ray by twice that).
 * -EDOM when the pixel ray misses the sphere. */
int imp_lights_reflect(const struct imp_pinhole *cam, const struct imp_sphere *s, const double px[2],
                       double sigma_px, double ret_origin[3], double ret_dir[3], double *ret_sigma_rad);

/* ---- light position from rays ---- */

enum {
        IMP_LIGHT_ILL_CONDITIONED = 1 << 0,   /* rays (nearly) parallel: cond(A) > cond_max */
        IMP_LIGHT_FEW_RAYS = 1 << 1,          /* fewer than 2 rays */
        IMP_LIGHT_SATURATED = 1 << 2,         /* a saturated highlight was used */
        IMP_LIGHT_BEHIND = 1 << 3,            /* the point lies behind a ray origin */
};

struct imp_light_fit_opts {
        double cond_max;              /* flag above this condition number; 0 → 1000 */
        double prior_distance_mm;     /* weak prior: this far along the mean ray; 0 → 500 */
        double prior_sigma_mm;        /* its 1σ; 0 → 1000 */
};

struct imp_light_estimate {
        double pos_mm[3];
        double cov_mm2[9];            /* row-major 3×3 */
        double sigma_mm;              /* √λmax(cov): worst-direction 1σ */
        double cond;                  /* condition number of the ray normal matrix */
        double rms_mm;                /* RMS distance of the point from the rays */
        int n_rays;
        unsigned flags;               /* IMP_LIGHT_* */
};

/* Least-squares closest point of n rays (origins o, unit directions d, angular 1σ each):
 * minimises Σ |(I − d dᵀ)(X − o)|² / (σ_i |X − o_i|)² + |X − X_p|²/σ_p² (two reweighting
 * passes), X_p the prior point. Covariance (A + I/σ_p²)⁻¹ · max(1, χ²/(2n − 3)). The prior
 * keeps X finite when the rays are parallel; then (and whenever cond > cond_max) the flag
 * is set and the uncertainty along the weak direction is that of the prior (σ_p).
 * Always returns finite values; -EINVAL for n < 1 or non-finite input. */
int imp_lights_triangulate(int n, const double (*o)[3], const double (*d)[3], const double *sigma_rad,
                           const struct imp_light_fit_opts *opts, struct imp_light_estimate *ret);

/* ---- intensity ---- */

struct imp_light_intensity {
        double intensity;             /* mean of the three channels' irradiance at 1000 mm */
        double colour[3];             /* channel / intensity (mean 1) */
        double rel_sigma;             /* relative 1σ of the intensity (pixel scatter / √n) */
        int n_pixels;
};

/* Intensity and colour of a light at pos_mm from a view of a flat white Lambertian target
 * (ρd = 1) in the plane z = plane_z_mm, in radiometric values (V = E cos θ, see
 * lafortune.h; convert DN with imp_radiometric_dn_to_value()). Every pixel of the view
 * (1 or 3 channels; 1 → colour (1,1,1)) whose value is finite and > 0 counts:
 * E(1000 mm) = V / (cos θ · (1000/d)² · cos^p(axis angle)); axis/profile_exp may be
 * NULL/0 (isotropic). -ENOENT when no pixel counts. */
int imp_lights_intensity(const struct imp_pinhole *cam, const struct imp_frame_view *v, double plane_z_mm,
                         const double pos_mm[3], const double *axis, double profile_exp,
                         struct imp_light_intensity *ret);

/* ---- RTI light position files ---- */

/* .lp: first line the light count N, then N lines "filename x y z". Standard (RTIBuilder,
 * relight): (x, y, z) the unit direction from the scene centre towards the light, in the
 * canvas frame (x along the width, y along the height, z out of the paint). Near-field
 * extension (impasto, marked by a first line "N # impasto near-field mm"): (x, y, z) are
 * positions in mm. Write: centre_mm is subtracted and normalised for the standard form.
 * names may be NULL (→ "light_%03d.png"). */
int imp_lights_lp_write(const char *path, int n, const struct imp_rig_light *lights, const char *const *names,
                        const double centre_mm[3], bool near_field, struct imp_error *err);
/* Reads either form. Directions come back in pos_mm at distance `radius_mm` from
 * centre_mm (unit directions × radius); near-field files give positions. *ret_lights
 * (malloc'd, ids 0..n−1, intensity 1, colour 1) and *ret_names (malloc'd, NULL-terminated,
 * free with imp_strv_free; may be NULL) untouched on failure. -EBADMSG names FILE:LINE. */
int imp_lights_lp_read(const char *path, const double centre_mm[3], double radius_mm, int *ret_n,
                       struct imp_rig_light **ret_lights, char ***ret_names, bool *ret_near_field,
                       struct imp_error *err);
