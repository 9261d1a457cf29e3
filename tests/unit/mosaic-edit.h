/* Test helper for the mosaic tests: edit one channel of a synthetic painting's tile 0 copy. */
#pragma once
#include <stdio.h>
#include "image.h"
#include "test.h"

/* Reads tile 0's copy, lets edit() change one channel (index c) and writes it back. */
static inline void edit_tile0(const char *dir, const char *channel, void (*edit)(struct imp_image *img, int c)) {
        char path[700];
        snprintf(path, sizeof path, "%s/copies/0000/heightfield.exr", dir);
        struct imp_image *img = NULL;
        char **names = NULL;
        struct imp_error err = { 0 };
        int r = imp_exr_read(path, &img, &names, &err);
        CHECK_MSG(r == 0, "%s", err.msg);
        if (r < 0)
                return;
        int c = imp_image_channel_index(names, channel);     /* EXR keeps channels sorted by name */
        CHECK_GE(c, 0);
        if (c >= 0)
                edit(img, c);
        CHECK_OK(imp_exr_write(path, img, (const char *const *) names, false, &err));
        imp_strv_free(names);
        imp_image_free(img);
}
