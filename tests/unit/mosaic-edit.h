/* Test helper for the mosaic tests: edit one channel of a synthetic painting's tile copy. */
#pragma once
#include <stdio.h>
#include "image.h"
#include "test.h"

/* Reads tile k's copy, lets edit() change one channel (index c; ctx passed on) and writes it back. */
static inline void edit_tile(const char *dir, unsigned k, const char *channel,
                             void (*edit)(struct imp_image *img, int c, void *ctx), void *ctx) {
        char path[700];
        snprintf(path, sizeof path, "%s/copies/%04u/heightfield.exr", dir, k);
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
                edit(img, c, ctx);
        CHECK_OK(imp_exr_write(path, img, (const char *const *) names, false, &err));
        imp_strv_free(names);
        imp_image_free(img);
}

static inline void edit_tile0_call(struct imp_image *img, int c, void *ctx) {
        (*(void (**)(struct imp_image *, int)) ctx)(img, c);
}

/* The same for tile 0 with an edit that needs no context. */
static inline void edit_tile0(const char *dir, const char *channel, void (*edit)(struct imp_image *img, int c)) {
        edit_tile(dir, 0, channel, edit_tile0_call, &edit);
}
