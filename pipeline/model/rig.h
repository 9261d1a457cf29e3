/* The rig model shared by the simulator (truth) and the pipeline (calibration):
 * pinhole cameras and projectors with Brown–Conrady distortion (OpenCV's model), the
 * sensor noise model, and the dome's near-field point lights. Units: mm, pixels, radians.
 * Pose convention (OpenCV): X_cam = R · X_world + t, world = canvas frame (x along the
 * width, y along the height, z out of the paint towards the viewer). */
#pragma once
#include <stdbool.h>
#include <jansson.h>
#include "error.h"

struct imp_pinhole {
        int width, height;            /* pixels */
        double fx, fy, cx, cy;        /* pixels */
        double k1, k2, p1, p2, k3;    /* Brown–Conrady, OpenCV order */
        double R[9];                  /* row-major world→device rotation */
        double t[3];                  /* world→device translation, mm */
};

struct imp_sensor {
        int bits;                     /* ADC bit depth: 8, 10, 12, 14, 16 */
        double black_level_dn;        /* offset added before quantisation */
        double gain_e_per_dn;         /* electrons per digital number at gain 0 dB */
        double read_noise_e;          /* read noise, electrons rms */
        double full_well_e;           /* saturation, electrons */
        double dark_current_e_per_s;
        double prnu;                  /* photo-response non-uniformity, relative rms */
        double quantum_scale;         /* electrons per second per unit radiance (1.0 = white
                                         Lambertian under a light of intensity 1 at 1 m... see
                                         docs/capture-set.md) */
        double readout_us;            /* frame readout time, for capture-time estimates */
        bool bayer;                   /* RGGB mosaic */
};

struct imp_rig_camera {
        char name[32];
        struct imp_pinhole model;
        struct imp_sensor sensor;
};

struct imp_rig_projector {
        char name[32];
        struct imp_pinhole model;
        double gamma;                 /* emitted = black + (1 - black) · value^gamma */
        double black_level;           /* relative emission of a black pixel, 0..1 */
        double intensity;             /* irradiance scale of a white pixel at 1000 mm */
        double defocus_px;            /* Gaussian blur sigma in projector pixels */
};

struct imp_rig_light {
        int id;
        double pos_mm[3];             /* world frame */
        double intensity;             /* radiant intensity scale: irradiance at 1000 mm */
        double colour[3];             /* RGB relative */
        double axis[3];               /* unit vector the LED points along (towards the canvas) */
        double profile_exp;           /* angular profile cos^p(angle to axis); 0 = isotropic */
};

struct imp_rig {
        int n_cameras;
        struct imp_rig_camera cameras[4];
        bool has_projector;
        struct imp_rig_projector projector;
        int n_lights;
        struct imp_rig_light *lights; /* owned */
        double settle_us;             /* light switching settle time */
};

void imp_rig_free(struct imp_rig *rig);    /* frees members, not the struct */
/* Deep copy (lights duplicated); *ret untouched on failure. Free with imp_rig_free(). */
int imp_rig_copy(const struct imp_rig *src, struct imp_rig *ret);

/* Projection with distortion: world point (mm) → pixel. Returns false if behind. */
bool imp_pinhole_project(const struct imp_pinhole *m, const double X[3], double ret_px[2]);
/* Pixel → unit ray direction in the device frame, undistorting iteratively. */
void imp_pinhole_ray_device(const struct imp_pinhole *m, const double px[2], double ret_dir[3]);
/* Pixel → world ray (origin = device centre in world, unit direction in world). */
void imp_pinhole_ray_world(const struct imp_pinhole *m, const double px[2], double ret_origin[3],
                           double ret_dir[3]);
/* Device centre in world coordinates: C = -Rᵀ t. */
void imp_pinhole_centre(const struct imp_pinhole *m, double ret_C[3]);
/* A pose that looks from `eye` at `target` with image x roughly along world `right`. */
void imp_pinhole_look_at(struct imp_pinhole *m, const double eye[3], const double target[3],
                         const double right[3]);

/* rig.json (written into every capture set and every calibration result). */
json_t *imp_rig_to_json(const struct imp_rig *rig);
int imp_rig_from_json(const json_t *j, const char *what, struct imp_rig *ret, struct imp_error *err);
int imp_rig_load(const char *path, struct imp_rig *ret, struct imp_error *err);
int imp_rig_save(const char *path, const struct imp_rig *rig, struct imp_error *err);
