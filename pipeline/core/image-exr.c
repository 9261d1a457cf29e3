/* OpenEXR reading and writing through the OpenEXR 3 Core C API: scanline files, ZIP
 * compression, one named HALF or FLOAT channel per image channel, chunk-by-chunk encode and
 * decode straight from/into the interleaved f32 image. The library's error callback keeps
 * the first message in a thread-local buffer instead of printing it. */
#define _GNU_SOURCE   /* CPU_COUNT, sched_getaffinity */
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <openexr.h>
#include <pthread.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "image.h"

#define EXR_SAMPLE_BYTES 4      /* we always hand the library 32-bit floats */
#define EXR_ZIP_LEVEL_FLOAT 1
#define EXR_ZIP_LEVEL_HALF  4

static _Thread_local char exr_msg[512];
static _Thread_local int exr_file_errno;   /* errno seen with EXR_ERR_FILE_ACCESS */

static void on_exr_error(exr_const_context_t ctxt, exr_result_t code, const char *msg) {
        (void) ctxt;
        /* called right after the failed open(): errno still says why */
        if (code == EXR_ERR_FILE_ACCESS && !exr_file_errno && errno > 0)
                exr_file_errno = errno;
        if (!exr_msg[0])
                snprintf(exr_msg, sizeof exr_msg, "%s", msg ? msg : exr_get_default_error_message(code));
}

static const char *exr_detail(exr_result_t rv) {
        return exr_msg[0] ? exr_msg : exr_get_default_error_message(rv);
}

static exr_context_initializer_t exr_initializer(void) {
        exr_context_initializer_t init = EXR_DEFAULT_CONTEXT_INITIALIZER;
        init.error_handler_fn = on_exr_error;
        exr_msg[0] = 0;
        exr_file_errno = 0;
        return init;
}

static void exr_finishp(exr_context_t *c) {
        if (*c)
                exr_finish(c);
}

/* ---- writing ---- */

static int exr_write_errno(exr_result_t rv) {
        if (rv == EXR_ERR_OUT_OF_MEMORY)
                return -ENOMEM;
        if (rv == EXR_ERR_FILE_ACCESS && exr_file_errno > 0)
                return -exr_file_errno;
        return -EIO;
}

static int find_name(const char *const *names, int n, const char *name) {
        for (int i = 0; i < n; i++)
                if (strcmp(names[i], name) == 0)
                        return i;
        return -1;
}

static int check_names(const char *path, const struct imp_image *img, const char *const *names,
                       struct imp_error *err) {
        if (!names)
                return imp_error_set(err, -EINVAL, "%s: no channel names given", path);
        for (int c = 0; c < img->channels; c++) {
                if (!names[c] || !names[c][0])
                        return imp_error_set(err, -EINVAL, "%s: channel %d has no name "
                                             "(expected one name per channel)", path, c);
                if (find_name(names, c, names[c]) >= 0)
                        return imp_error_set(err, -EINVAL, "%s: channel name \"%s\" used twice "
                                             "(expected unique names)", path, names[c]);
        }
        return 0;
}

static exr_result_t exr_write_header_for(exr_context_t ctxt, const struct imp_image *img,
                                         const char *const *names, bool half) {
        int part;
        exr_result_t rv = exr_add_part(ctxt, "image", EXR_STORAGE_SCANLINE, &part);
        if (rv == EXR_ERR_SUCCESS)
                rv = exr_initialize_required_attr_simple(ctxt, part, img->width, img->height,
                                                         EXR_COMPRESSION_ZIP);
        /* zlib's level, not the library's default 6: 32-bit floats' low mantissa bytes are
         * noise no level compresses (the demo's heightfield.exr: level 1 +0.6 % size, -17 % CPU;
         * level 9 only -0.3 %), half data gain from a middle level (level 4: +0.5 to +7 %,
         * -33 % CPU). Any ZIP reader decodes the same pixels. */
        if (rv == EXR_ERR_SUCCESS)
                rv = exr_set_zip_compression_level(ctxt, part, half ? EXR_ZIP_LEVEL_HALF : EXR_ZIP_LEVEL_FLOAT);
        for (int c = 0; c < img->channels && rv == EXR_ERR_SUCCESS; c++)
                rv = exr_add_channel(ctxt, part, names[c], half ? EXR_PIXEL_HALF : EXR_PIXEL_FLOAT,
                                     EXR_PERCEPTUALLY_LOGARITHMIC, 1, 1);
        if (rv == EXR_ERR_SUCCESS)
                rv = exr_write_header(ctxt);
        return rv;
}

/* The library orders channels by name: each encoder channel finds its image channel. */
static int point_encoder(exr_encode_pipeline_t *enc, const struct imp_image *img,
                         const char *const *names, int start_y) {
        for (int i = 0; i < enc->channel_count; i++) {
                exr_coding_channel_info_t *ch = &enc->channels[i];
                int c = find_name(names, img->channels, ch->channel_name);
                if (c < 0)
                        return -EINVAL;
                ch->user_data_type = EXR_PIXEL_FLOAT;
                ch->user_bytes_per_element = EXR_SAMPLE_BYTES;
                ch->user_pixel_stride = img->channels * EXR_SAMPLE_BYTES;
                ch->user_line_stride = (int32_t) img->stride;
                ch->encode_from_ptr = (const uint8_t *) imp_image_f32(img, 0, start_y) +
                                      (size_t) c * EXR_SAMPLE_BYTES;
        }
        return 0;
}

/* Chunk y's encoder pointed at the image; the first call chooses the library's routines. */
static exr_result_t encode_setup(exr_context_t ctxt, const struct imp_image *img, const char *const *names,
                                 int y, exr_encode_pipeline_t *enc, bool *started) {
        exr_chunk_info_t cinfo;
        exr_result_t rv = exr_write_scanline_chunk_info(ctxt, 0, y, &cinfo);
        if (rv != EXR_ERR_SUCCESS)
                return rv;
        rv = *started ? exr_encoding_update(ctxt, 0, &cinfo, enc) : exr_encoding_initialize(ctxt, 0, &cinfo, enc);
        if (rv != EXR_ERR_SUCCESS)
                return rv;
        if (point_encoder(enc, img, names, y) < 0)
                return EXR_ERR_INVALID_ARGUMENT;
        if (!*started)
                rv = exr_encoding_choose_default_routines(ctxt, 0, enc);
        *started = true;
        return rv;
}

static exr_result_t exr_write_chunks_serial(exr_context_t ctxt, const struct imp_image *img,
                                            const char *const *names, int lines) {
        exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
        exr_result_t rv = EXR_ERR_SUCCESS;
        bool started = false;
        for (int y = 0; y < img->height && rv == EXR_ERR_SUCCESS; y += lines) {
                rv = encode_setup(ctxt, img, names, y, &enc, &started);
                if (rv == EXR_ERR_SUCCESS)
                        rv = exr_encoding_run(ctxt, 0, &enc);
        }
        if (started)
                exr_encoding_destroy(ctxt, &enc);
        return rv;
}

/* Parallel writing: worker threads pack and compress chunks (the costly part: zlib) into
 * memory, the calling thread writes them to the file in chunk order. A chunk's bytes are
 * exactly what the serial encoder writes: the same library routines run, only the last
 * step (the write) is replaced by keeping the chunk. At most EXR_PAR_WINDOW chunks are
 * held in memory ahead of the writer. */
#define EXR_PAR_WINDOW   64
#define EXR_PAR_MAX      8       /* threads at most */

struct exr_chunk_out {
        void *data;
        uint64_t size;
        bool done;
};

struct exr_par {
        exr_context_t ctxt;
        const struct imp_image *img;
        const char *const *names;
        int lines, n_chunks;
        pthread_mutex_t mu;
        pthread_cond_t cv;
        int next, written;              /* next chunk to encode; chunks written */
        exr_result_t fail;              /* first failure (EXR_ERR_SUCCESS: none) */
        char fail_msg[sizeof exr_msg];
        struct exr_chunk_out *out;
};

/* write_fn of the workers' pipelines: keeps the chunk the default would write. */
static exr_result_t keep_chunk(exr_encode_pipeline_t *enc) {
        struct exr_chunk_out *o = enc->encoding_user_data;
        o->data = malloc(enc->compressed_bytes ? enc->compressed_bytes : 1);
        if (!o->data)
                return EXR_ERR_OUT_OF_MEMORY;
        memcpy(o->data, enc->compressed_buffer, enc->compressed_bytes);
        o->size = enc->compressed_bytes;
        return EXR_ERR_SUCCESS;
}

static void par_failed(struct exr_par *p, exr_result_t rv) {   /* with p->mu held */
        if (p->fail == EXR_ERR_SUCCESS) {
                p->fail = rv;
                snprintf(p->fail_msg, sizeof p->fail_msg, "%s", exr_detail(rv));
        }
        pthread_cond_broadcast(&p->cv);
}

static void *exr_par_worker(void *arg) {
        struct exr_par *p = arg;
        exr_encode_pipeline_t enc = EXR_ENCODE_PIPELINE_INITIALIZER;
        bool started = false;
        pthread_mutex_lock(&p->mu);
        for (;;) {
                while (p->fail == EXR_ERR_SUCCESS && p->next < p->n_chunks && p->next >= p->written + EXR_PAR_WINDOW)
                        pthread_cond_wait(&p->cv, &p->mu);
                if (p->fail != EXR_ERR_SUCCESS || p->next >= p->n_chunks)
                        break;
                int k = p->next++;
                pthread_mutex_unlock(&p->mu);
                exr_msg[0] = 0;
                exr_result_t rv = encode_setup(p->ctxt, p->img, p->names, k * p->lines, &enc, &started);
                if (rv == EXR_ERR_SUCCESS) {
                        enc.yield_until_ready_fn = NULL;   /* the order is the writer's */
                        enc.write_fn = keep_chunk;
                        enc.encoding_user_data = &p->out[k];
                        rv = exr_encoding_run(p->ctxt, 0, &enc);
                }
                pthread_mutex_lock(&p->mu);
                if (rv != EXR_ERR_SUCCESS)
                        par_failed(p, rv);
                p->out[k].done = true;
                pthread_cond_broadcast(&p->cv);
        }
        pthread_mutex_unlock(&p->mu);
        if (started)
                exr_encoding_destroy(p->ctxt, &enc);
        return NULL;
}

/* The writer: chunk k once it is encoded, in order. */
static exr_result_t exr_par_write(struct exr_par *p) {
        exr_result_t rv = EXR_ERR_SUCCESS;
        for (int k = 0; k < p->n_chunks && rv == EXR_ERR_SUCCESS; k++) {
                pthread_mutex_lock(&p->mu);
                while (!p->out[k].done && p->fail == EXR_ERR_SUCCESS)
                        pthread_cond_wait(&p->cv, &p->mu);
                rv = p->fail;
                pthread_mutex_unlock(&p->mu);
                if (rv == EXR_ERR_SUCCESS)
                        rv = exr_write_scanline_chunk(p->ctxt, 0, k * p->lines, p->out[k].data, p->out[k].size);
                free(p->out[k].data);
                p->out[k].data = NULL;
                pthread_mutex_lock(&p->mu);
                if (rv != EXR_ERR_SUCCESS)
                        par_failed(p, rv);
                p->written = k + 1;
                pthread_cond_broadcast(&p->cv);
                pthread_mutex_unlock(&p->mu);
        }
        return rv;
}

static exr_result_t exr_write_chunks_parallel(exr_context_t ctxt, const struct imp_image *img,
                                              const char *const *names, int lines, int threads) {
        int n_chunks = (img->height + lines - 1) / lines;
        _cleanup_free_ struct exr_chunk_out *out = calloc((size_t) n_chunks, sizeof *out);
        pthread_t tid[EXR_PAR_MAX];
        if (!out)
                return EXR_ERR_OUT_OF_MEMORY;
        struct exr_par p = { .ctxt = ctxt, .img = img, .names = names, .lines = lines, .n_chunks = n_chunks,
                             .mu = PTHREAD_MUTEX_INITIALIZER, .cv = PTHREAD_COND_INITIALIZER, .out = out };
        int started = 0;
        for (; started < threads; started++)
                if (pthread_create(&tid[started], NULL, exr_par_worker, &p) != 0)
                        break;
        exr_result_t rv = started > 0 ? exr_par_write(&p) : EXR_ERR_OUT_OF_MEMORY;
        if (rv != EXR_ERR_SUCCESS) {   /* stop the workers at their next chunk */
                pthread_mutex_lock(&p.mu);
                par_failed(&p, rv);
                pthread_mutex_unlock(&p.mu);
        }
        for (int t = 0; t < started; t++)
                pthread_join(tid[t], NULL);
        for (int k = 0; k < n_chunks; k++)
                free(out[k].data);
        if (rv != EXR_ERR_SUCCESS && p.fail_msg[0] && !exr_msg[0])
                snprintf(exr_msg, sizeof exr_msg, "%s", p.fail_msg);
        pthread_cond_destroy(&p.cv);
        pthread_mutex_destroy(&p.mu);
        return rv;
}

/* The CPUs this process may run on (its affinity: a job's cpuset), at most EXR_PAR_MAX. */
static int exr_default_threads(void) {
        cpu_set_t set;
        int n = sched_getaffinity(0, sizeof set, &set) == 0 ? CPU_COUNT(&set) : 1;
        return n < 1 ? 1 : n > EXR_PAR_MAX ? EXR_PAR_MAX : n;
}

static exr_result_t exr_write_chunks(exr_context_t ctxt, const struct imp_image *img,
                                     const char *const *names, int threads) {
        int32_t lines = 0;
        exr_result_t rv = exr_get_scanlines_per_chunk(ctxt, 0, &lines);
        if (rv == EXR_ERR_SUCCESS && lines < 1)
                rv = EXR_ERR_INVALID_ARGUMENT;
        if (rv != EXR_ERR_SUCCESS)
                return rv;
        if (threads <= 0)
                threads = exr_default_threads();
        int n_chunks = (img->height + lines - 1) / lines;
        if (threads > EXR_PAR_MAX)
                threads = EXR_PAR_MAX;
        if (threads > n_chunks)
                threads = n_chunks;
        if (threads <= 1)
                return exr_write_chunks_serial(ctxt, img, names, lines);
        return exr_write_chunks_parallel(ctxt, img, names, lines, threads);
}

int imp_exr_write(const char *path, const struct imp_image *img, const char *const *names,
                  bool half, struct imp_error *err) {
        return imp_exr_write_threads(path, img, names, half, 0, err);
}

int imp_exr_write_threads(const char *path, const struct imp_image *img, const char *const *names,
                          bool half, int threads, struct imp_error *err) {
        _cleanup_(exr_finishp) exr_context_t ctxt = NULL;
        exr_result_t rv;
        int r;

        if (!path || !img)
                return imp_error_set(err, -EINVAL, "imp_exr_write: no path or image given");
        if (img->type != IMP_PIX_F32)
                return imp_error_set(err, -EINVAL, "%s: cannot store a %s image as OpenEXR "
                                     "(expected f32)", path, imp_pixel_type_name(img->type));
        r = check_names(path, img, names, err);
        if (r < 0)
                return r;

        exr_context_initializer_t init = exr_initializer();
        /* Written under a temporary name and renamed by exr_finish() once complete. */
        rv = exr_start_write(&ctxt, path, EXR_INTERMEDIATE_TEMP_FILE, &init);
        if (rv != EXR_ERR_SUCCESS)
                return imp_error_set(err, exr_write_errno(rv), "%s: cannot create OpenEXR file: %s",
                                     path, exr_detail(rv));
        rv = exr_write_header_for(ctxt, img, names, half);
        if (rv != EXR_ERR_SUCCESS)      /* e.g. a channel name longer than EXR allows */
                return imp_error_set(err, rv == EXR_ERR_OUT_OF_MEMORY ? -ENOMEM : -EINVAL,
                                     "%s: cannot write OpenEXR header: %s", path, exr_detail(rv));
        rv = exr_write_chunks(ctxt, img, names, threads);
        if (rv == EXR_ERR_SUCCESS)
                rv = exr_finish(&ctxt);         /* writes the chunk table, renames */
        if (rv != EXR_ERR_SUCCESS)
                return imp_error_set(err, exr_write_errno(rv), "%s: cannot write OpenEXR file: %s",
                                     path, exr_detail(rv));
        return 0;
}

/* ---- reading ---- */

static int exr_errno(exr_result_t rv) {
        return rv == EXR_ERR_OUT_OF_MEMORY ? -ENOMEM : -EBADMSG;
}

/* Checks the part is something we can hold; returns the channel list and data window. */
static int exr_layout(exr_context_t ctxt, const char *path, const exr_attr_chlist_t **ret_chans,
                      exr_attr_box2i_t *ret_dw, struct imp_error *err) {
        exr_storage_t storage;
        exr_result_t rv;

        rv = exr_get_storage(ctxt, 0, &storage);
        if (rv == EXR_ERR_SUCCESS)
                rv = exr_get_channels(ctxt, 0, ret_chans);
        if (rv == EXR_ERR_SUCCESS)
                rv = exr_get_data_window(ctxt, 0, ret_dw);
        if (rv != EXR_ERR_SUCCESS)
                return imp_error_set(err, exr_errno(rv), "%s: corrupt OpenEXR header: %s", path,
                                     exr_detail(rv));
        if (storage != EXR_STORAGE_SCANLINE)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported OpenEXR layout: %s "
                                     "(expected scanline)", path,
                                     storage == EXR_STORAGE_TILED ? "tiled" : "deep");
        const exr_attr_chlist_t *chans = *ret_chans;
        if (!chans || chans->num_channels < 1 || chans->num_channels > IMP_IMAGE_MAX_CHANNELS)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported OpenEXR layout: %d "
                                     "channels (expected 1 to %d)", path,
                                     chans ? chans->num_channels : 0, IMP_IMAGE_MAX_CHANNELS);
        for (int c = 0; c < chans->num_channels; c++) {
                const exr_attr_chlist_entry_t *e = &chans->entries[c];
                if (e->x_sampling != 1 || e->y_sampling != 1)
                        return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported OpenEXR layout: "
                                             "channel %s subsampled %dx%d (expected 1x1)", path,
                                             e->name.str, e->x_sampling, e->y_sampling);
        }
        int64_t w = (int64_t) ret_dw->max.x - ret_dw->min.x + 1;
        int64_t h = (int64_t) ret_dw->max.y - ret_dw->min.y + 1;
        if (w < 1 || h < 1 || w > IMP_IMAGE_MAX_SIDE || h > IMP_IMAGE_MAX_SIDE)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: unsupported OpenEXR data window "
                                     "%" PRId64 "x%" PRId64 " (expected 1 to %d pixels per side)",
                                     path, w, h, IMP_IMAGE_MAX_SIDE);
        return 0;
}

/* Where a chunk's samples go: channel c of pixel x on line y of the chunk lands at
 * base + y * line_stride + x * pixel_stride + c * 4. */
struct decode_target {
        uint8_t *base;
        int32_t pixel_stride, line_stride;
};

/* Decoder channels come in channel-list order, which is also the image's channel order. */
static void point_decoder(exr_decode_pipeline_t *dec, const struct decode_target *t) {
        for (int c = 0; c < dec->channel_count; c++) {
                exr_coding_channel_info_t *ch = &dec->channels[c];
                ch->user_data_type = EXR_PIXEL_FLOAT;
                ch->user_bytes_per_element = EXR_SAMPLE_BYTES;
                ch->user_pixel_stride = t->pixel_stride;
                ch->user_line_stride = t->line_stride;
                ch->decode_to_ptr = t->base + (size_t) c * EXR_SAMPLE_BYTES;
        }
}

/* OpenEXR 3.1's specialised unpacker for exactly four HALF channels decoded to
 * interleaved FLOAT stores the channels in reverse order. Such files are decoded into a
 * scratch buffer with one padding sample per pixel, which makes the library take its
 * generic (correct) path, and copied from there. */
static bool needs_padded_decode(const exr_attr_chlist_t *chans) {
        if (chans->num_channels != 4)
                return false;
        for (int c = 0; c < chans->num_channels; c++)
                if (chans->entries[c].pixel_type != EXR_PIXEL_HALF)
                        return false;
        return true;
}

static void copy_from_padded(struct imp_image *img, const float *scratch, int row, int lines) {
        size_t n = (size_t) img->channels;
        for (int y = 0; y < lines; y++)
                for (int x = 0; x < img->width; x++)
                        memcpy(imp_image_f32(img, x, row + y),
                               scratch + ((size_t) y * img->width + x) * (n + 1), n * sizeof(float));
}

static int exr_read_chunks(exr_context_t ctxt, const char *path, const exr_attr_chlist_t *chans,
                           const exr_attr_box2i_t *dw, struct imp_image *img, struct imp_error *err) {
        exr_decode_pipeline_t dec = EXR_DECODE_PIPELINE_INITIALIZER;
        _cleanup_free_ float *scratch = NULL;
        exr_result_t rv = EXR_ERR_SUCCESS;
        int32_t lines = 0;
        bool started = false;
        int y = dw->min.y;

        rv = exr_get_scanlines_per_chunk(ctxt, 0, &lines);
        if (rv == EXR_ERR_SUCCESS && (lines < 1 || lines > IMP_IMAGE_MAX_SIDE))
                rv = EXR_ERR_INVALID_ATTR;
        if (rv == EXR_ERR_SUCCESS && needs_padded_decode(chans)) {
                scratch = calloc((size_t) lines * img->width * (img->channels + 1), sizeof(float));
                if (!scratch)
                        return imp_error_set(err, -ENOMEM, "%s: out of memory", path);
        }
        /* Chunks start at multiples of `lines` from the data window's top. */
        for (; y <= dw->max.y && rv == EXR_ERR_SUCCESS; y += lines) {
                exr_chunk_info_t cinfo;
                rv = exr_read_scanline_chunk_info(ctxt, 0, y, &cinfo);
                if (rv != EXR_ERR_SUCCESS)
                        break;
                if (cinfo.start_y < dw->min.y || cinfo.height < 1 || cinfo.height > lines ||
                    cinfo.start_y + cinfo.height - 1 > dw->max.y) {
                        rv = EXR_ERR_CORRUPT_CHUNK;
                        break;
                }
                rv = started ? exr_decoding_update(ctxt, 0, &cinfo, &dec)
                             : exr_decoding_initialize(ctxt, 0, &cinfo, &dec);
                if (rv != EXR_ERR_SUCCESS)
                        break;
                int row = cinfo.start_y - dw->min.y;
                struct decode_target t = {
                        .base = (uint8_t *) imp_image_row(img, row),
                        .pixel_stride = img->channels * EXR_SAMPLE_BYTES,
                        .line_stride = (int32_t) img->stride,
                };
                if (scratch)
                        t = (struct decode_target) {
                                .base = (uint8_t *) scratch,
                                .pixel_stride = (img->channels + 1) * EXR_SAMPLE_BYTES,
                                .line_stride = img->width * (img->channels + 1) * EXR_SAMPLE_BYTES,
                        };
                point_decoder(&dec, &t);
                if (!started)
                        rv = exr_decoding_choose_default_routines(ctxt, 0, &dec);
                started = true;
                if (rv == EXR_ERR_SUCCESS)
                        rv = exr_decoding_run(ctxt, 0, &dec);
                if (rv == EXR_ERR_SUCCESS && scratch)
                        copy_from_padded(img, scratch, row, cinfo.height);
        }
        if (started)
                exr_decoding_destroy(ctxt, &dec);
        /* -EBADMSG whatever the code: OpenEXR 3.1 says EXR_ERR_OUT_OF_MEMORY for a corrupt ZIP
         * chunk ("Unable to decompress image data 178 -> 192"), and a chunk's buffers are
         * bounded by the data window, checked against IMP_IMAGE_MAX_BYTES before this */
        if (rv != EXR_ERR_SUCCESS)
                return imp_error_set(err, -EBADMSG, "%s: truncated or corrupt OpenEXR data "
                                     "at line %d: %s", path, y, exr_detail(rv));
        return 0;
}

static int copy_names(const exr_attr_chlist_t *chans, char ***ret) {
        char **v = calloc((size_t) chans->num_channels + 1, sizeof *v);
        if (!v)
                return -ENOMEM;
        for (int c = 0; c < chans->num_channels; c++) {
                v[c] = strdup(chans->entries[c].name.str);
                if (!v[c]) {
                        imp_strv_free(v);
                        return -ENOMEM;
                }
        }
        *ret = v;
        return 0;
}

/* The library's "cannot open" carries no errno: find it ourselves, and catch empty files. */
static int exr_precheck(const char *path, struct imp_error *err) {
        struct stat st;
        _cleanup_close_ int fd = open(path, O_RDONLY | O_CLOEXEC);
        if (fd < 0 || fstat(fd, &st) < 0) {
                int r = negative_errno();
                return imp_error_set(err, r, "%s: cannot open OpenEXR file: %s", path, strerror(-r));
        }
        if (st.st_size == 0)
                return imp_error_set(err, -EBADMSG, "%s: empty file (expected an OpenEXR image)", path);
        return 0;
}

int imp_exr_read(const char *path, struct imp_image **ret, char ***ret_names,
                 struct imp_error *err) {
        _cleanup_(exr_finishp) exr_context_t ctxt = NULL;
        _cleanup_image_ struct imp_image *img = NULL;
        const exr_attr_chlist_t *chans = NULL;
        exr_attr_box2i_t dw;
        exr_result_t rv;
        int r;

        if (!path || !ret)
                return imp_error_set(err, -EINVAL, "imp_exr_read: no path or result given");
        r = exr_precheck(path, err);
        if (r < 0)
                return r;
        exr_context_initializer_t init = exr_initializer();
        rv = exr_start_read(&ctxt, path, &init);
        if (rv != EXR_ERR_SUCCESS)
                return imp_error_set(err, exr_errno(rv), "%s: not a valid OpenEXR file: %s", path,
                                     exr_detail(rv));
        r = exr_layout(ctxt, path, &chans, &dw, err);
        if (r < 0)
                return r;
        r = imp_image_new(dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1, chans->num_channels,
                          IMP_PIX_F32, &img);
        if (r == -EINVAL)
                return imp_error_set(err, -EMEDIUMTYPE, "%s: OpenEXR image too large (expected "
                                     "at most %zu bytes of pixels)", path, IMP_IMAGE_MAX_BYTES);
        if (r < 0)
                return imp_error_set(err, r, "%s: cannot allocate the image: %s", path, strerror(-r));
        r = exr_read_chunks(ctxt, path, chans, &dw, img, err);
        if (r < 0)
                return r;
        if (ret_names) {
                r = copy_names(chans, ret_names);
                if (r < 0)
                        return imp_error_set(err, r, "%s: out of memory", path);
        }
        *ret = TAKE_PTR(img);
        return 0;
}
