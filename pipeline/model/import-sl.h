/* Structured-light sequences from other rigs (docs/import.md): a folder of camera frames of
 * OpenCV's structured_light::GrayCodePattern sequence — for a W×H projector, ⌈log2 W⌉
 * column bit planes then ⌈log2 H⌉ row planes, most significant first, each followed by
 * its inverse, then white, then black (as ../shared/data/procam-graycode holds them) — and a
 * camera–projector calibration (the rig.json `impasto calibrate procam --out` writes),
 * turned into a capture set whose "structured-light" frames carry their pattern
 * descriptors. Library code: no logging; errors name the file and what was expected. */
#pragma once
#include "error.h"
#include "rig.h"

enum imp_sl_order {
        IMP_SL_ORDER_OPENCV_GRAYCODE = 0,
};

struct imp_import_sl_options {
        const char *frames_dir;       /* the frames, read only: the .png/.tif/.tiff files in
                                         name order */
        enum imp_sl_order order;
        int proj_width, proj_height;  /* the projector the patterns were made for */
        const char *calib_path;       /* rig.json with a camera and a projector (named in
                                         messages also when calib_rig is given) */
        const struct imp_rig *calib_rig; /* not NULL: this calibration instead of reading
                                         calib_path (e.g. from OpenCV XML, cv-procam-xml.h);
                                         device sizes 0 are taken from the frames and
                                         proj_width × proj_height */
};

/* Number of frames of the sequence: 2·(⌈log2 W⌉ + ⌈log2 H⌉) + 2. */
int imp_import_sl_frame_count(enum imp_sl_order order, int proj_width, int proj_height);

/* Writes the capture set at out_dir (must not exist or be empty). -EINVAL/-EBADMSG on bad
 * input (frame count, sizes against the calibration, projector size), -ENOENT, I/O errors. */
int imp_import_sl(const struct imp_import_sl_options *o, const char *out_dir, struct imp_error *err);
