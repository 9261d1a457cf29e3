/* Shared by the libFuzzer harnesses of tests/fuzz (docs/fuzzing.md). Each fuzz-<target>.c
 * defines LLVMFuzzerTestOneInput; linked with -fsanitize=fuzzer it is a fuzzer, linked with
 * replay.c it is the ctest unit test that replays tests/fuzz/corpus/<target>/. A harness
 * aborts (FUZZ_CHECK) when a reader accepts what it should have refused or hands on a NaN,
 * so that libFuzzer keeps the input as a crash. */
#pragma once
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define FUZZ_CHECK(cond, ...)                                                          \
        do {                                                                           \
                if (!(cond)) {                                                         \
                        fprintf(stderr, "%s:%d: FUZZ_CHECK(%s) failed: ", __FILE__,     \
                                __LINE__, #cond);                                      \
                        fprintf(stderr, __VA_ARGS__);                                  \
                        fputc('\n', stderr);                                           \
                        abort();                                                       \
                }                                                                      \
        } while (0)

/* A private scratch directory of this process (created on first use, under $TMPDIR or
 * /tmp, removed at exit). */
const char *fuzz_scratch_dir(void);
/* Writes data to scratch/NAME (NAME may hold one '/': its folder is created). Returns the
 * path (static buffer, valid until the next call) or aborts. */
const char *fuzz_write_file(const char *name, const void *data, size_t size);
/* Empties the scratch directory (files and one level of folders). */
void fuzz_clear_scratch(void);
/* Reads a whole file into a malloc'd buffer (for "a reader never modifies what it reads"). */
void *fuzz_read_file(const char *path, size_t *ret_size);
/* Splits data at lines "--8<-- NAME\n" into named parts; *ret_n parts (at most max). Parts
 * point into data (not NUL-terminated); names are copied into name[][64]. The '\n' that ends
 * the line before a marker belongs to no part. Bytes before the first marker are a part
 * named "". */
struct fuzz_part {
        char name[64];
        const uint8_t *data;
        size_t size;
};
size_t fuzz_split(const uint8_t *data, size_t size, struct fuzz_part *parts, size_t max);
