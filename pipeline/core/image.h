/* The image type every impasto module passes around, and its file formats:
 * PNG (libpng, 8/16-bit), TIFF (libtiff, 8/16-bit/float, metadata in ImageDescription),
 * OpenEXR (OpenEXR 3 C API, half/float channels, ZIP compression).
 * Pixels are interleaved, rows `stride` bytes apart. Library code: no logging. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include "error.h"

enum imp_pixel_type { IMP_PIX_U8, IMP_PIX_U16, IMP_PIX_F32 };

/* Limits of imp_image_new() (and so of every reader): bigger images are refused with
 * -EINVAL instead of attempting a huge allocation on a corrupt header. */
#define IMP_IMAGE_MAX_SIDE      (1 << 16)               /* pixels per side */
#define IMP_IMAGE_MAX_CHANNELS  256
#define IMP_IMAGE_MAX_BYTES     ((size_t) 1 << 31)      /* total pixel data */

struct imp_image {
        int width, height;
        int channels;                 /* 1..4 for files; any count in memory */
        enum imp_pixel_type type;
        size_t stride;                /* bytes per row, >= width * channels * sample size */
        void *data;                   /* owned by the image, or by an arena (below) */
        bool in_arena;                /* data lives in an imp_image_arena: not freed with the image */
};

size_t imp_pixel_type_size(enum imp_pixel_type t);
const char *imp_pixel_type_name(enum imp_pixel_type t);

/* Allocates a zeroed image. Caller frees with imp_image_free(). -EINVAL on bad size,
 * -ENOMEM when out of memory. */
int imp_image_new(int width, int height, int channels, enum imp_pixel_type type,
                  struct imp_image **ret);
/* The row stride and total bytes of such an image, or -EINVAL (the limits above). */
int imp_image_layout(int width, int height, int channels, enum imp_pixel_type type,
                     size_t *ret_stride, size_t *ret_total);
void imp_image_free(struct imp_image *img);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_image *, imp_image_free);
#define _cleanup_image_ _cleanup_(imp_image_freep)
int imp_image_dup(const struct imp_image *src, struct imp_image **ret);

/* An arena for the images a stage keeps until it ends (e.g. the merged structured-light
 * values until the decode): their samples are carved from large mappings advised for
 * transparent huge pages, so faulting them in costs one fault per 2 MiB instead of one per
 * 4 KiB (about 30x less CPU on the VMs measured), and the whole arena goes back to the system
 * at once. imp_image_free() of an arena image frees only its header; the samples stay until
 * imp_image_arena_free(), so an arena suits images that live as long as it does.
 * Allocation is thread-safe. */
struct imp_image_arena;
int imp_image_arena_new(struct imp_image_arena **ret);
/* Unmaps every block; the arena's images must not be read afterwards (their headers are
 * still freed with imp_image_free()). NULL: no-op. */
void imp_image_arena_free(struct imp_image_arena *a);
DEFINE_TRIVIAL_CLEANUP_FUNC(struct imp_image_arena *, imp_image_arena_free);
/* Empties the arena but keeps its blocks, faulted in: the next allocations reuse them
 * (zeroed again, at memset speed instead of a page fault per page), e.g. the structured-
 * light values' pages for the dome values. The arena's images must not be read afterwards. */
void imp_image_arena_reset(struct imp_image_arena *a);
/* Gives back what a reset kept and the allocations since have not reused: unmaps the spare
 * blocks and releases the written pages past the last allocation. */
void imp_image_arena_trim(struct imp_image_arena *a);
/* Bytes mapped by the arena so far (its blocks). */
size_t imp_image_arena_mapped(const struct imp_image_arena *a);
/* n zeroed bytes (64-byte aligned) from arena a, for a stage's large scratch arrays; freed
 * with the arena. NULL when out of memory. */
void *imp_image_arena_alloc(struct imp_image_arena *a, size_t n);
/* imp_image_new() with the samples in arena a (zeroed, the same layout); a == NULL:
 * imp_image_new(). */
int imp_image_new_in(struct imp_image_arena *a, int width, int height, int channels,
                     enum imp_pixel_type type, struct imp_image **ret);
/* Moves *img's samples into arena a (a copy; the heap block is freed, for the next
 * allocation of its size to reuse). Nothing happens when a is NULL or *img is in an arena
 * already. -ENOMEM leaves *img as it was. */
int imp_image_arena_adopt(struct imp_image_arena *a, struct imp_image *img);
/* Converts to float (u8/u16 values kept as raw numbers, not normalised). */
int imp_image_to_f32(const struct imp_image *src, struct imp_image **ret);

static inline void *imp_image_row(const struct imp_image *img, int y) {
        return (uint8_t *) img->data + (size_t) y * img->stride;
}
static inline float *imp_image_f32(const struct imp_image *img, int x, int y) {
        return (float *) imp_image_row(img, y) + (size_t) x * img->channels;
}
static inline uint16_t *imp_image_u16(const struct imp_image *img, int x, int y) {
        return (uint16_t *) imp_image_row(img, y) + (size_t) x * img->channels;
}
static inline uint8_t *imp_image_u8(const struct imp_image *img, int x, int y) {
        return (uint8_t *) imp_image_row(img, y) + (size_t) x * img->channels;
}
/* Sample c of pixel (x, y) as a double whatever the type. */
double imp_image_get(const struct imp_image *img, int x, int y, int c);

/* File readers and writers return 0 or a negative errno and fill err with a message
 * naming the file and what was expected:
 *   -ENOENT, -EACCES, ... the file cannot be opened (errno of open());
 *   -EBADMSG      not a valid file of that format: empty, truncated, corrupt, wrong type;
 *   -EMEDIUMTYPE  a valid file whose layout is not supported (e.g. 32-bit integer TIFF);
 *   -EINVAL       bad arguments (e.g. writing an f32 image as PNG);
 *   -ENOMEM, -EIO, -ENOSPC  out of memory, write failures.
 * Writers replace the file; on failure no partial file is left under that name. */

/* PNG: 8- or 16-bit, 1-4 channels (grey, grey+alpha, RGB, RGBA). Exact round trip. */
int imp_png_write(const char *path, const struct imp_image *img, struct imp_error *err);
/* The same pixels coded for speed (zlib level 3, the Sub filter): for previews. */
int imp_png_write_fast(const char *path, const struct imp_image *img, struct imp_error *err);
int imp_png_read(const char *path, struct imp_image **ret, struct imp_error *err);

/* TIFF: u8, u16 or f32, 1-4 channels; `description` (may be NULL) goes into the
 * ImageDescription tag (frames store their metadata there as JSON). Exact round trip.
 * On read, *ret_description (if not NULL) receives a malloc'd copy or NULL. */
int imp_tiff_write(const char *path, const struct imp_image *img, const char *description,
                   struct imp_error *err);
/* The same with the cheapest good lossless codec (Zstandard level 1 with the predictor when
 * libtiff has it, else deflate): for frames stored as they are captured. imp_tiff_read (any
 * libtiff with zstd) reads it back exactly. */
int imp_tiff_write_fast(const char *path, const struct imp_image *img, const char *description,
                        struct imp_error *err);
int imp_tiff_read(const char *path, struct imp_image **ret, char **ret_description,
                  struct imp_error *err);
/* imp_tiff_read into *io when it already has the file's layout (width, height, channels,
 * pixel type): its pages are reused, none allocated or zeroed; otherwise *io is freed and
 * replaced by a new image (*io may be NULL). The pixels are those imp_tiff_read returns,
 * byte for byte. On failure *io is an image of unspecified content or NULL. */
int imp_tiff_read_reuse(const char *path, struct imp_image **io, char **ret_description,
                        struct imp_error *err);

/* OpenEXR (C API, ZIP compression): an f32 image with one named channel per image
 * channel (names[c], e.g. "R","G","B" or "height","nx","ny"); half=true stores HALF.
 * Read returns f32 with the file's channels in file order; *ret_names (if not NULL)
 * gets a NULL-terminated malloc'd array of malloc'd names (free with imp_strv_free). */
int imp_exr_write(const char *path, const struct imp_image *img, const char *const *names,
                  bool half, struct imp_error *err);
/* The same with the chunks packed and compressed on `threads` threads (0: the CPUs the
 * process may run on, at most 8; 1: on the calling thread alone): byte for byte the file
 * imp_exr_write with any thread count writes. imp_exr_write uses 0. */
int imp_exr_write_threads(const char *path, const struct imp_image *img, const char *const *names,
                          bool half, int threads, struct imp_error *err);
int imp_exr_read(const char *path, struct imp_image **ret, char ***ret_names,
                 struct imp_error *err);
void imp_strv_free(char **v);
/* Index of `name` in a NULL-terminated name array (as returned by imp_exr_read), or
 * -ENOENT when absent. */
int imp_image_channel_index(char **names, const char *name);

/* By extension (.png, .tif/.tiff, .exr; case-insensitive); -EINVAL for another. */
int imp_image_read(const char *path, struct imp_image **ret, struct imp_error *err);
