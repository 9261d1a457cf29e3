/* Image arenas (image.h): arena images have the layout of heap ones, start zeroed, never
 * overlap (within a block, across blocks, from several threads at once), adopt() moves the
 * samples byte for byte, the blocks are advised for huge pages (THPeligible in smaps when
 * THP is not disabled), imp_image_free() of an arena image leaves its samples to the arena,
 * and the arena is freed as a whole (under ASan: no leak, no double free; a write past an
 * image's end is reported). */
#include <errno.h>
#include <pthread.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>
#include <unistd.h>
#include "image.h"
#include "macro.h"
#include "unit/test.h"

/* The bytes checked and filled, in turn: all of the first and last 64 KiB (where two images
 * laid out one after the other would overlap) and every 509th byte between (the test stays
 * fast on 291 MB). */
static size_t next_probe(size_t i, size_t n) {
        return i < 65536 || i + 65537 >= n ? i + 1 : IMP_MIN(i + 509 - i % 509, n - 65536);
}

static bool all_zero(const struct imp_image *img) {
        const uint8_t *p = img->data;
        size_t n = img->stride * (size_t) img->height;
        for (size_t i = 0; i < n; i = next_probe(i, n))
                if (p[i])
                        return false;
        return true;
}

static void fill(struct imp_image *img, unsigned seed) {
        uint8_t *p = img->data;
        size_t n = img->stride * (size_t) img->height;
        for (size_t i = 0; i < n; i = next_probe(i, n))
                p[i] = (uint8_t) (i * 131u + seed * 7u + 1u);
}

static bool filled(const struct imp_image *img, unsigned seed) {
        const uint8_t *p = img->data;
        size_t n = img->stride * (size_t) img->height;
        for (size_t i = 0; i < n; i = next_probe(i, n))
                if (p[i] != (uint8_t) (i * 131u + seed * 7u + 1u))
                        return false;
        return true;
}

/* Same layout as imp_image_new's, zeroed, 64-byte aligned; filled images keep their bytes
 * while later ones (past the first 256 MiB block: 291 MB in all) are allocated and filled. */
static void test_layout_and_blocks(void) {
        struct imp_image_arena *a = NULL;
        CHECK_OK(imp_image_arena_new(&a));
        enum { N = 64 };
        struct imp_image *img[N] = {};
        for (int i = 0; i < N; i++) {
                int w = 1400 + (i % 3), h = 1000;
                enum imp_pixel_type t = i % 4 == 3 ? IMP_PIX_U8 : IMP_PIX_F32;
                struct imp_image *heap = NULL;
                CHECK_OK(imp_image_new(w, h, 1, t, &heap));
                CHECK_OK(imp_image_new_in(a, w, h, 1, t, &img[i]));
                if (!heap || !img[i])
                        return;
                CHECK(img[i]->in_arena && !heap->in_arena);
                CHECK(img[i]->width == heap->width && img[i]->height == heap->height &&
                      img[i]->channels == heap->channels && img[i]->type == heap->type &&
                      img[i]->stride == heap->stride);
                CHECK_INT_EQ((uintptr_t) img[i]->data % 64, 0);
                CHECK_MSG(all_zero(img[i]), "arena image %d not zeroed", i);
                fill(img[i], (unsigned) i);
                imp_image_free(heap);
        }
        for (int i = 0; i < N; i++)
                CHECK_MSG(filled(img[i], (unsigned) i), "arena image %d overwritten by a later one", i);
        CHECK_MSG(imp_image_arena_mapped(a) >= (size_t) 290 << 20,
                  "64 images (291 MB) mapped in %zu bytes", imp_image_arena_mapped(a));
        for (int i = 0; i < N; i++)   /* headers only: the samples stay readable */
                if (i % 2)
                        imp_image_free(TAKE_PTR(img[i]));
        for (int i = 0; i < N; i += 2)
                CHECK(filled(img[i], (unsigned) i));
        for (int i = 0; i < N; i++)
                imp_image_free(img[i]);
        imp_image_arena_free(a);
        struct imp_image *bad = NULL;
        CHECK_ERR(imp_image_new_in(NULL, 0, 5, 1, IMP_PIX_U8, &bad), -EINVAL);
        CHECK_OK(imp_image_arena_new(&a));
        CHECK_ERR(imp_image_new_in(a, 5, 5, 0, IMP_PIX_U8, &bad), -EINVAL);
        CHECK_INT_EQ(imp_image_arena_mapped(a), 0);
        CHECK_OK(imp_image_new_in(NULL, 3, 2, 2, IMP_PIX_U16, &bad));   /* NULL arena: the heap */
        CHECK(bad && !bad->in_arena);
        imp_image_free(bad);
        imp_image_arena_free(a);
        imp_image_arena_free(NULL);
}

/* adopt(): the same bytes, now in the arena; a second adopt and a NULL arena do nothing. */
static void test_adopt(void) {
        struct imp_image_arena *a = NULL;
        struct imp_image *img = NULL, *ref = NULL;
        CHECK_OK(imp_image_arena_new(&a));
        CHECK_OK(imp_image_new(333, 77, 3, IMP_PIX_U16, &img));
        fill(img, 5);
        CHECK_OK(imp_image_dup(img, &ref));
        CHECK_OK(imp_image_arena_adopt(NULL, img));
        CHECK(!img->in_arena);
        CHECK_OK(imp_image_arena_adopt(a, img));
        CHECK(img->in_arena && img->stride == ref->stride);
        CHECK(memcmp(img->data, ref->data, ref->stride * (size_t) ref->height) == 0);
        void *at = img->data;
        CHECK_OK(imp_image_arena_adopt(a, img));
        CHECK(img->data == at);
        CHECK_ERR(imp_image_arena_adopt(a, NULL), -EINVAL);
        imp_image_free(img);
        imp_image_free(ref);
        imp_image_arena_free(a);
}

/* Raw scratch bytes: zeroed, aligned, between images without overlapping them. */
static void test_alloc(void) {
        struct imp_image_arena *a = NULL;
        struct imp_image *img = NULL;
        CHECK_OK(imp_image_arena_new(&a));
        CHECK(imp_image_arena_alloc(NULL, 16) == NULL);
        CHECK_OK(imp_image_new_in(a, 99, 7, 1, IMP_PIX_U8, &img));
        CHECK(imp_image_arena_alloc(a, (size_t) 200 << 20) != NULL);   /* untouched */
        size_t n = (size_t) 72 << 20;   /* more than the first block has left: a block of its own */
        uint8_t *p = imp_image_arena_alloc(a, n);
        CHECK(p && (uintptr_t) p % 64 == 0);
        bool zero = p != NULL;
        for (size_t i = 0; p && i < n; i += 4096)
                zero &= p[i] == 0 && p[i + 4095] == 0;
        CHECK_MSG(zero, "arena scratch not zeroed");
        if (p && img) {
                memset(p, 0xff, n);
                fill(img, 3);
                CHECK(filled(img, 3) && p[0] == 0xff && p[n - 1] == 0xff);
        }
        CHECK(imp_image_arena_mapped(a) >= n + ((size_t) 256 << 20));
        imp_image_free(img);
        imp_image_arena_free(a);
}

/* A reset keeps the blocks: the next allocations reuse their addresses (nothing more is
 * mapped), come back zeroed where they were written before (also when one straddles the end
 * of what was written), and trim unmaps the blocks not reused and gives back the written
 * pages past the last allocation (they read zero when handed out again). */
static void test_reset_reuse(void) {
        struct imp_image_arena *a = NULL;
        CHECK_OK(imp_image_arena_new(&a));
        size_t mb = (size_t) 1 << 20;
        uint8_t *first = imp_image_arena_alloc(a, 200 * mb);   /* block 1, 3 MB of it written */
        uint8_t *second = imp_image_arena_alloc(a, 100 * mb);  /* block 2 */
        CHECK(first && second);
        if (!first || !second) {
                imp_image_arena_free(a);
                return;
        }
        memset(first, 0xab, 3 * mb);
        memset(second, 0xcd, 8 * mb);
        size_t mapped = imp_image_arena_mapped(a);
        CHECK(mapped >= 300 * mb);
        imp_image_arena_reset(a);
        uint8_t *p = imp_image_arena_alloc(a, 5 * mb);   /* a spare block; 8 MB of it written */
        CHECK_MSG(p == second || p == first, "after a reset the allocation is not in a kept block");
        CHECK_INT_EQ(imp_image_arena_mapped(a), mapped);
        bool zero = p != NULL;
        for (size_t i = 0; p && i < 5 * mb; i += 511)
                zero &= p[i] == 0;
        CHECK_MSG(zero, "reused arena bytes not zeroed");
        uint8_t *q = imp_image_arena_alloc(a, 6 * mb);   /* straddles the written 8 MB */
        zero = q != NULL;
        for (size_t i = 0; q && i < 6 * mb; i += 509)
                zero &= q[i] == 0;
        CHECK_MSG(zero, "an allocation straddling the written end not zeroed");
        if (p && q)
                memset(p, 0xee, 5 * mb), memset(q, 0xee, 6 * mb);
        imp_image_arena_trim(a);   /* the other block goes */
        CHECK_MSG(imp_image_arena_mapped(a) < mapped, "trim kept the unused block (%zu of %zu bytes mapped)",
                  imp_image_arena_mapped(a), mapped);
        imp_image_arena_reset(a);
        uint8_t *r = imp_image_arena_alloc(a, 64);
        imp_image_arena_trim(a);   /* written pages past the first 2 MiB released */
        uint8_t *s = imp_image_arena_alloc(a, 10 * mb);
        zero = r && s && r[0] == 0;
        for (size_t i = 0; s && i < 10 * mb; i += 509)
                zero &= s[i] == 0;
        CHECK_MSG(zero, "pages released by trim not zero when handed out again");
        imp_image_arena_free(a);
}

/* Two threads allocating from one arena at once get disjoint images. */
enum { PER_THREAD = 24 };
struct worker {
        struct imp_image_arena *a;
        struct imp_image *img[PER_THREAD];
        unsigned seed;
};

static void *worker_run(void *p) {
        struct worker *w = p;
        for (int i = 0; i < PER_THREAD; i++)
                if (imp_image_new_in(w->a, 700, 500 + i, 1, IMP_PIX_F32, &w->img[i]) == 0)
                        fill(w->img[i], w->seed + (unsigned) i);
        return NULL;
}

static void test_threads(void) {
        struct imp_image_arena *a = NULL;
        CHECK_OK(imp_image_arena_new(&a));
        struct worker w[2] = { { .a = a, .seed = 0 }, { .a = a, .seed = 1000 } };
        pthread_t t[2];
        for (int k = 0; k < 2; k++)
                CHECK_INT_EQ(pthread_create(&t[k], NULL, worker_run, &w[k]), 0);
        for (int k = 0; k < 2; k++)
                pthread_join(t[k], NULL);
        for (int k = 0; k < 2; k++)
                for (int i = 0; i < PER_THREAD; i++) {
                        CHECK(w[k].img[i] && w[k].img[i]->in_arena);
                        CHECK_MSG(w[k].img[i] && filled(w[k].img[i], w[k].seed + (unsigned) i),
                                  "thread %d image %d overwritten", k, i);
                        imp_image_free(w[k].img[i]);
                }
        imp_image_arena_free(a);
}

/* The mapping holding an arena image is eligible for huge pages, unless THP is off. */
static void test_huge_page_advice(void) {
        char mode[128] = "";
        FILE *f = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
        if (!f || !fgets(mode, sizeof mode, f) || strstr(mode, "[never]")) {
                if (f)
                        fclose(f);
                fprintf(stderr, "THP unavailable or disabled: huge-page advice not checked\n");
                return;
        }
        fclose(f);
        struct imp_image_arena *a = NULL;
        struct imp_image *img = NULL;
        CHECK_OK(imp_image_arena_new(&a));
        CHECK_OK(imp_image_new_in(a, 1024, 1024, 1, IMP_PIX_F32, &img));
        if (!img)
                return;
        uintptr_t at = (uintptr_t) img->data;
        FILE *s = fopen("/proc/self/smaps", "r");
        CHECK(s);
        char line[512];
        bool in = false, seen = false;
        int eligible = -1;
        while (s && fgets(line, sizeof line, s)) {
                unsigned long lo, hi;
                if (sscanf(line, "%lx-%lx ", &lo, &hi) == 2 && strchr(line, '-') < strchr(line, ' ')) {
                        in = lo <= at && at < hi;
                        seen |= in;
                } else if (in && sscanf(line, "THPeligible: %d", &eligible) == 1)
                        in = false;
        }
        if (s)
                fclose(s);
        CHECK_MSG(seen, "the arena image's mapping is not in /proc/self/smaps");
        CHECK_MSG(eligible == 1, "arena mapping THPeligible %d (THP mode %.*s): not advised for huge pages",
                  eligible, (int) strcspn(mode, "\n"), mode);
        imp_image_free(img);
        imp_image_arena_free(a);
}

#if defined(__SANITIZE_ADDRESS__)
/* Under ASan a write just past an arena image's last sample is reported, even with the next
 * image allocated right after it (the red zone between them). */
static void test_overrun_reported(void) {
        fprintf(stderr, "a child process now writes past an arena image: the ASan report below is expected\n");
        fflush(stderr);
        pid_t pid = fork();
        if (pid == 0) {
                struct imp_image_arena *a = NULL;
                struct imp_image *img = NULL, *next = NULL;
                if (imp_image_arena_new(&a) < 0 || imp_image_new_in(a, 128, 10, 1, IMP_PIX_U8, &img) < 0 ||
                    imp_image_new_in(a, 128, 10, 1, IMP_PIX_U8, &next) < 0)
                        _exit(3);
                ((volatile uint8_t *) img->data)[img->stride * (size_t) img->height] = 1;
                _exit(0);
        }
        int st = 0;
        CHECK(pid > 0 && waitpid(pid, &st, 0) == pid);
        CHECK_MSG(!(WIFEXITED(st) && WEXITSTATUS(st) == 0), "an overrun of an arena image went unreported");
}
#endif

int main(void) {
        test_layout_and_blocks();
        test_adopt();
        test_alloc();
        test_reset_reuse();
        test_threads();
        test_huge_page_advice();
#if defined(__SANITIZE_ADDRESS__)
        test_overrun_reported();
#endif
        return TEST_DONE();
}
