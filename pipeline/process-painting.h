/* Is a capture set one tile of a whole-painting scan (docs/painting.md), and what does the
 * painting ask of its copy? A tile lies inside the paint: no frame can be in its field, so
 * imp_process_capture() turns the heightfield's frame search off (heightfield.h
 * whole_field), and every tile of one painting must share one pitch (the mosaic refuses
 * mixed pitches), so a tile processed without a pitch gets the painting's. Library code:
 * no logging. */
#pragma once
#include <stdbool.h>
#include "captureset.h"
#include "error.h"

struct imp_painting_tile {
        bool is_tile;
        const char *marker;           /* what said so: "plan.cfg painting group" and/or
                                         "painting.json" (static strings) */
        int index;                    /* the tile's index in painting.json, -1 when unknown */
        double pitch_mm;              /* the painting's pitch for its tile copies (0 when not a
                                         tile): painting.json "pitch_mm" when it gives one,
                                         else IMP_HF_PITCH_NOISE_CAP × the camera footprint
                                         on the rig's canvas plane at the principal point
                                         (what a copy of one field picks on a clean scan;
                                         the same for every tile: the gantry moves the
                                         whole rig), rounded to 0.1 µm */
        const char *pitch_source;     /* "painting.json pitch_mm" or "1.02 x the camera
                                         footprint on the painting's plane" (static strings) */
};

/* Marks: the set's plan.cfg has a painting group (the plan of one tile), or
 * DIR/../../painting.json lists DIR as a tile's "capture" (the layout `impasto sim render
 * --painting` and impastod write). A painting.json that exists there but cannot be read is
 * an error naming it; one that gives a pitch_mm that is not a positive number, -EBADMSG
 * naming the file and field; a set with neither mark is not a tile (is_tile false, 0 returned). */
int imp_painting_tile_detect(const struct imp_captureset *cs, struct imp_painting_tile *ret, struct imp_error *err);
