/* The light calibration target in whole frames: crops around the mirror spheres, dark
 * subtraction, the clip level of a highlight, the white board's radiometric values out of
 * the spheres' discs and shadows, the light's intensity pooled over patches, a light
 * moved onto a dome of known radius. The per-sphere numerics are in calib-lights.h;
 * docs/calibration-lights.md explains the choices. Library code: no logging. */
#pragma once
#include "calib-lights.h"
#include "captureset.h"
#include "error.h"
#include "image.h"
#include "rig.h"

/* A window of a frame, pixels. */
struct imp_crop {
        int x0, y0, w, h;
};

/* The window around an image circle (centre c, radius rho px) with a margin, clipped to the
 * camera's frame. */
struct imp_crop imp_lights_crop_circle(const struct imp_pinhole *m, const double c[2], double rho);
/* The window that holds a sphere of radius r_mm centred at centre_mm (world). */
struct imp_crop imp_lights_crop_sphere(const struct imp_pinhole *m, const double centre_mm[3], double r_mm);
/* Apparent radius (px) of a sphere of radius r_mm whose centre is at height z_mm under the camera. */
double imp_lights_image_radius(const struct imp_pinhole *m, double r_mm, double z_mm);

/* The crop c of frame f (channel 0) less dark (f32, per pixel) or, when dark is NULL, less
 * the constant black: a new f32 image in *ret, which the caller frees. */
int imp_lights_crop_dn(const struct imp_image *f, const struct imp_image *dark, double black,
                       const struct imp_crop *c, struct imp_image **ret);
/* The crop c of the f32 image img, a new f32 image in *ret (caller frees). */
int imp_lights_crop_image(const struct imp_image *img, const struct imp_crop *c, struct imp_image **ret);

/* Mean of camera cam's dark frames ("dark" step) at exposure_us (any exposure when < 0) of
 * cs, per pixel, as a new f32 image in *ret (caller frees; NULL when the set has none).
 * Returns the number of darks averaged, or a negative errno (err says which frame). */
int imp_lights_mean_dark(const struct imp_captureset *cs, const char *cam, double exposure_us,
                         struct imp_image **ret, struct imp_error *err);

/* The highest dark-subtracted DN a highlight pixel is trusted at: the ADC clip (or the full
 * well, if lower) less 4 read-noise σ (at least 4 DN). */
double imp_lights_clip_level(const struct imp_sensor *s);

/* Whether a sphere (radius + 0.5 mm) stands between board point p and light position L. */
bool imp_lights_sphere_shadows(const struct imp_sphere *sp, const double p[3], const double L[3]);

/* The white board of a frame: where the target is seen. */
struct imp_lights_board {
        const struct imp_rig_camera *cam;
        const struct imp_image *dark;         /* mean dark (f32) or NULL: the sensor's black level */
        double plane_z_mm;                    /* the board's height */
        const struct imp_sphere *spheres;
        int n_spheres;
        const double *white;                  /* x0, y0, x1, y1 on the board (mm), or NULL: anywhere */
};

/* The radiometric values (imp_radiometric_dn_to_value()) of frame f on the white board's
 * pixels, NAN elsewhere: off the spheres' discs (+1 mm), out of their shadows from light
 * position L, inside board->white, and lit (> 0.5 × the frame's 90th percentile, which
 * drops pixels off the target). A new f32 image in *ret (caller frees). */
int imp_lights_white_values(const struct imp_image *f, const struct imp_lights_board *board, const double L[3],
                            double exposure_us, double gain_db, struct imp_image **ret);

/* The light's intensity and colour from white values v (imp_lights_white_values()):
 * imp_lights_intensity() over 16 × 16 patches on a grid of step 48 px (the per-pixel ray
 * costs an undistortion, so the board is sampled rather than read whole), pooled by pixel
 * count. -ENOENT when no patch has a usable pixel. */
int imp_lights_intensity_pooled(const struct imp_image *v, const struct imp_rig_camera *cam, double plane_z_mm,
                                const struct imp_rig_light *nominal, const double pos_mm[3],
                                struct imp_light_intensity *ret);

/* est moved onto the dome (centre dome[0..2], radius dome[3], mm) along its direction from
 * the centre, the covariance mapped by that projection's Jacobian (R/|X − c|)(I − n nᵀ):
 * the range is the dome's, only the direction is uncertain; sigma_mm the largest σ of the
 * mapped covariance. An estimate at the centre is returned unchanged. */
void imp_lights_onto_dome(const double dome[4], const struct imp_light_estimate *est, struct imp_light_estimate *ret);
