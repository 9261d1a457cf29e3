/* Simulated photometric stacks for the import round trip and the Woodham baseline
 * (docs/import.md): a dome sweep of a scene rendered into a capture set, the truth normals
 * per camera pixel, and the export of a capture set's dome sweep as another rig would
 * hand it over: 16-bit PNG images, an RTI .lp file (light positions, mm, x right, y up,
 * z towards the camera, origin on z = 0 under the image centre) and per-light intensities. */
#pragma once
#include "error.h"

/* Renders every dome light of SCENE once (exposure_us) into a new capture set at DIR, and
 * DIR/truth-normals.exr (nx, ny, nz per camera pixel, image frame; height: the surface's z,
 * mm) with DIR/truth-mask.png
 * (255 where the pixel sees the paint, not the frame). */
int sim_dome_capture(const char *scene_path, double exposure_us, const char *dir, struct imp_error *err);

struct sim_export_info {
        double pixel_mm;              /* for `import photometric --pixel-size` */
        double camera_distance_mm;    /* for --camera-distance */
        int n_lights, width, height;
};

/* Writes OUT/img-NNN.png, OUT/lights.lp, OUT/intensities.txt from the set's dome sweep
 * (linear values scaled into 16 bits, saturated samples at 65535, under-exposed ones at 0). */
int sim_export_stack(const char *capture_dir, const char *out_dir, struct sim_export_info *ret,
                     struct imp_error *err);
