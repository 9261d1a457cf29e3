/* Captures from other rigs (docs/import.md): a folder of images, one per light, with the
 * RTI light file (.lp: RTIBuilder, RelightLab, photometric-stereo benchmarks) and optional
 * per-light RGB intensities, turned into a capture set (captureset.h) whose rig.json has one
 * camera (orthographic unless a distance is given) and those lights, so that
 * `impasto process --photometric-only` reads it like a dome sweep of impasto's own rig.
 *
 * Frame of the .lp file and of the rig written here: x right, y up (image rows go down),
 * z towards the camera; origin on the surface plane z = 0 under the image centre. A unit
 * vector is a distant light, anything else a position in lp_unit_mm millimetres.
 * Library code: no logging; errors are negative errno with file:line and what was expected. */
#pragma once
#include <stdbool.h>
#include "error.h"

/* How the .lp rows are read. */
enum imp_lp_kind {
        IMP_LP_AUTO = 0,              /* all unit (±IMP_LP_UNIT_TOL) → directions; all with
                                         |v| > IMP_LP_POSITION_MIN → positions; else an error */
        IMP_LP_DIRECTIONS,            /* each row must be unit (±IMP_LP_UNIT_TOL) */
        IMP_LP_POSITIONS,             /* each row is a position */
};
#define IMP_LP_UNIT_TOL      0.01     /* |v| − 1 of a direction: Relight writes 6 decimals */
#define IMP_LP_POSITION_MIN  1.5      /* a position is well off the unit sphere */
#define IMP_LP_MAX_LIGHTS    512      /* IMP_BTF_MAX_SAMPLES: the fits' per-texel limit */

struct imp_lp_light {
        char file[256];               /* as written in the .lp (may hold a directory) */
        double v[3];                  /* unit direction (distant) or position, mm */
        double rgb[3];                /* intensity per channel (1 1 1 without a file) */
        int line;                     /* line of the .lp, for messages */
};

struct imp_lp {
        int n;
        bool distant;                 /* true: v are unit directions */
        struct imp_lp_light *lights;  /* owned */
};

/* Parses an .lp file. lp_unit_mm scales positions (> 0). Caller frees with imp_lp_done().
 * -ENOENT/-EACCES (cannot open), -EBADMSG (a malformed line: message has path:line),
 * -ENOMEM; *ret untouched on failure. */
int imp_lp_read(const char *path, enum imp_lp_kind kind, double lp_unit_mm, struct imp_lp *ret,
                struct imp_error *err);
void imp_lp_done(struct imp_lp *lp);
/* Reads `r g b` per line (blank lines and # comments skipped) into lp->lights[i].rgb, in
 * .lp order; values must be finite and > 0. -EBADMSG on a count mismatch or a bad number. */
int imp_lp_read_intensities(const char *path, struct imp_lp *lp, struct imp_error *err);

struct imp_import_photometric_options {
        const char *images_dir;       /* the images, read only */
        const char *lp_path;
        const char *intensities_path; /* NULL: 1 1 1 */
        const char *mask_path;        /* NULL: every pixel; else 8/16-bit grey PNG/TIFF the
                                         images' size, non-zero = object; copied as mask.png */
        double pixel_mm;              /* pixel footprint on the surface; <= 0: unknown (1 mm
                                         assumed; refused when the .lp has positions) */
        double camera_distance_mm;    /* > 0: a pinhole this far above the origin (view
                                         directions per pixel); <= 0: orthographic */
        enum imp_lp_kind kind;
        double lp_unit_mm;            /* mm per .lp position unit (1) */
};
void imp_import_photometric_options_default(struct imp_import_photometric_options *ret);

/* Writes the capture set at out_dir (must not exist or be empty): rig.json, one "dome"
 * frame per light (16-bit; 8-bit images keep their values and sensor bits = 8), import.json
 * (the source, the light kind, pixel size) and mask.png. Never writes into images_dir.
 * -EINVAL/-EBADMSG on bad input (file named), -ENOENT for a missing image, I/O errors. */
int imp_import_photometric(const struct imp_import_photometric_options *o, const char *out_dir,
                           struct imp_error *err);

/* The rig frame of an import: pixel (u, v) ↔ surface point (x, y, 0) with
 * x = (u − (W−1)/2)·pixel_mm, y = −(v − (H−1)/2)·pixel_mm. */
#define IMP_IMPORT_ORTHO_DISTANCE_MM 1e6   /* the orthographic camera: a pinhole 1 km away
                                              (view direction error < 2e-5 rad) */
