/* Target 5: the image readers (pipeline/core/image-png.c, image-tiff.c, image-exr.c) through
 * imp_image_read, as every stage and importer reads frames and maps. The first byte picks the
 * format (0 PNG, 1 TIFF, 2 OpenEXR), the rest is the file. Checked: a refusal says why; an
 * accepted image has a size, its channels and its pixels (ASan reads them all); the file
 * is not changed. libFuzzer's -malloc_limit_mb catches an allocation the file's size does not
 * justify. */
#include <errno.h>
#include <string.h>
#include "fuzz.h"
#include "image.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
        static const char *const names[] = { "in.png", "in.tiff", "in.exr" };
        if (size < 1)
                return 0;
        fuzz_clear_scratch();
        const char *path = fuzz_write_file(names[data[0] % 3], data + 1, size - 1);
        char p[4608];
        snprintf(p, sizeof p, "%s", path);
        struct imp_image *img = NULL;
        struct imp_error err = {};
        int r = imp_image_read(p, &img, &err);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "%s: %d %s\n", names[data[0] % 3], r, err.msg);
        if (r < 0) {
                FUZZ_CHECK(err.msg[0], "image refused (%d) without a message", r);
                FUZZ_CHECK(!img, "refused, yet an image returned");
                /* a damaged file of a few KB is bad input, never "out of memory" */
                FUZZ_CHECK(r != -ENOMEM, "%zu bytes refused for memory: %s", size - 1, err.msg);
        } else {
                /* PNG and TIFF: 1 to 4 channels; OpenEXR: one per named channel */
                int max_ch = data[0] % 3 == 2 ? IMP_IMAGE_MAX_CHANNELS : 4;
                FUZZ_CHECK(img && img->width > 0 && img->height > 0 && img->channels >= 1 && img->channels <= max_ch,
                           "accepted an image of %dx%d×%d", img ? img->width : 0, img ? img->height : 0,
                           img ? img->channels : 0);
                size_t row = (size_t) img->width * img->channels * imp_pixel_type_size(img->type);
                FUZZ_CHECK(img->stride >= row, "stride %zu < row of %zu bytes", img->stride, row);
                volatile unsigned sum = 0;
                for (int y = 0; y < img->height; y++)
                        for (size_t i = 0; i < row; i++)
                                sum += ((const uint8_t *) imp_image_row(img, y))[i];
                imp_image_free(img);
        }
        size_t n = 0;
        void *now = fuzz_read_file(p, &n);
        FUZZ_CHECK(now && n == size - 1 && !memcmp(now, data + 1, n), "%s changed while read", names[data[0] % 3]);
        free(now);
        return 0;
}
