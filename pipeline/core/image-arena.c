/* Image arenas (image.h): bump allocation from large anonymous mappings advised for
 * transparent huge pages. With THP in `madvise` mode a fresh 4 KiB page costs a fault each
 * (about 5 ms of CPU per MB on the 2-core VM this was measured on, against about 0.15 with
 * huge pages: docs/processing-speed.md), and the images a stage keeps are faulted in once.
 * Advising malloc'd images instead was tried and lost: 2 MiB-aligned heap blocks are no
 * longer recycled by glibc. An arena owns its blocks and returns them all at once. */
#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include "image.h"

#if defined(__SANITIZE_ADDRESS__)
#include <sanitizer/asan_interface.h>
#define ARENA_REDZONE 64        /* poisoned after every image: overruns are reported */
#else
#define ASAN_POISON_MEMORY_REGION(p, n) ((void) (p), (void) (n))
#define ASAN_UNPOISON_MEMORY_REGION(p, n) ((void) (p), (void) (n))
#define ARENA_REDZONE 0
#endif

#define ARENA_HUGE   ((size_t) 2 << 20)     /* the x86-64 huge page */
#define ARENA_BLOCK  ((size_t) 256 << 20)   /* address space only until touched; few blocks, few part-used huge pages */
#define ARENA_ALIGN  ((size_t) 64)          /* every image starts on a cache line */

struct arena_block {
        struct arena_block *next;
        uint8_t *base;
        size_t size, used;
        size_t dirty;                        /* bytes from base written before a reset: zeroed when handed out again */
};

struct imp_image_arena {
        pthread_mutex_t lock;
        struct arena_block *blocks;          /* the newest first: allocations come from it */
        struct arena_block *spare;           /* blocks a reset emptied, faulted in: used before new ones */
        size_t mapped;
};

static size_t round_up(size_t n, size_t to) {
        return (n + to - 1) / to * to;
}

/* A block of at least `need` bytes, 2 MiB-aligned and advised for huge pages (an advice the
 * kernel refuses, e.g. THP disabled, leaves ordinary pages: the same bytes, slower). */
static struct arena_block *block_new(size_t need) {
        size_t size = round_up(need > ARENA_BLOCK ? need : ARENA_BLOCK, ARENA_HUGE);
        struct arena_block *b = calloc(1, sizeof *b);
        if (!b)
                return NULL;
        uint8_t *map = mmap(NULL, size + ARENA_HUGE, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (map == MAP_FAILED) {
                free(b);
                return NULL;
        }
        uint8_t *base = (uint8_t *) round_up((uintptr_t) map, ARENA_HUGE);
        size_t head = (size_t) (base - map), tail = ARENA_HUGE - head;
        if (head)
                munmap(map, head);
        if (tail)
                munmap(base + size, tail);
        (void) madvise(base, size, MADV_HUGEPAGE);
        ASAN_POISON_MEMORY_REGION(base, size);
        *b = (struct arena_block) { .base = base, .size = size };
        return b;
}

int imp_image_arena_new(struct imp_image_arena **ret) {
        if (!ret)
                return -EINVAL;
        struct imp_image_arena *a = calloc(1, sizeof *a);
        if (!a)
                return -ENOMEM;
        pthread_mutex_init(&a->lock, NULL);
        *ret = a;
        return 0;
}

static void blocks_unmap(struct arena_block *b) {
        for (struct arena_block *next; b; b = next) {
                next = b->next;
                ASAN_UNPOISON_MEMORY_REGION(b->base, b->size);   /* the range may be mapped again */
                munmap(b->base, b->size);
                free(b);
        }
}

void imp_image_arena_free(struct imp_image_arena *a) {
        if (!a)
                return;
        blocks_unmap(a->blocks);
        blocks_unmap(a->spare);
        pthread_mutex_destroy(&a->lock);
        free(a);
}

void imp_image_arena_reset(struct imp_image_arena *a) {
        if (!a)
                return;
        pthread_mutex_lock(&a->lock);
        struct arena_block **tail = &a->spare;
        while (*tail)
                tail = &(*tail)->next;
        *tail = a->blocks;
        a->blocks = NULL;
        for (struct arena_block *b = a->spare; b; b = b->next) {
                b->dirty = b->used > b->dirty ? b->used : b->dirty;
                b->used = 0;
                ASAN_POISON_MEMORY_REGION(b->base, b->size);
        }
        pthread_mutex_unlock(&a->lock);
}

void imp_image_arena_trim(struct imp_image_arena *a) {
        if (!a)
                return;
        pthread_mutex_lock(&a->lock);
        for (struct arena_block *b = a->spare; b; b = b->next)
                a->mapped -= b->size;
        blocks_unmap(TAKE_PTR(a->spare));
        for (struct arena_block *b = a->blocks; b; b = b->next) {
                size_t keep = round_up(b->used, ARENA_HUGE);
                if (b->dirty > keep) {   /* the written pages past the last image go back */
                        (void) madvise(b->base + keep, b->dirty - keep, MADV_DONTNEED);
                        b->dirty = keep;
                }
        }
        pthread_mutex_unlock(&a->lock);
}

size_t imp_image_arena_mapped(const struct imp_image_arena *a) {
        return a ? a->mapped : 0;
}

/* A spare block (emptied by a reset) with room for `take` bytes, unlinked; NULL if none. */
static struct arena_block *spare_take(struct imp_image_arena *a, size_t take) {
        for (struct arena_block **pb = &a->spare; *pb; pb = &(*pb)->next)
                if ((*pb)->size >= take) {
                        struct arena_block *b = *pb;
                        *pb = b->next;
                        b->next = NULL;
                        return b;
                }
        return NULL;
}

/* n zeroed bytes, or NULL: fresh pages are the kernel's zeros, written ones (before a
 * reset) are cleared here. */
static void *arena_alloc(struct imp_image_arena *a, size_t n) {
        size_t take = round_up(n + ARENA_REDZONE, ARENA_ALIGN);
        void *p = NULL;
        pthread_mutex_lock(&a->lock);
        struct arena_block *b = a->blocks;
        if (!b || b->size - b->used < take) {
                struct arena_block *nb = spare_take(a, take);
                if (nb) {
                        nb->next = a->blocks;
                        a->blocks = b = nb;
                        nb = NULL;
                        goto have_block;
                }
                nb = block_new(take);
                if (nb) {
                        nb->next = a->blocks;
                        a->blocks = b = nb;
                        a->mapped += nb->size;
                } else
                        b = NULL;
        }
have_block:
        if (b) {
                p = b->base + b->used;
                size_t stale = b->dirty > b->used ? b->dirty - b->used : 0;
                b->used += take;
                ASAN_UNPOISON_MEMORY_REGION(p, n);   /* the red zone after it stays poisoned */
                if (stale)
                        memset(p, 0, stale < n ? stale : n);
        }
        pthread_mutex_unlock(&a->lock);
        return p;
}

void *imp_image_arena_alloc(struct imp_image_arena *a, size_t n) {
        return a ? arena_alloc(a, n) : NULL;
}

int imp_image_new_in(struct imp_image_arena *a, int width, int height, int channels,
                     enum imp_pixel_type type, struct imp_image **ret) {
        if (!a)
                return imp_image_new(width, height, channels, type, ret);
        size_t stride, total;
        int r = imp_image_layout(width, height, channels, type, &stride, &total);
        if (r < 0 || !ret)
                return r < 0 ? r : -EINVAL;
        struct imp_image *img = calloc(1, sizeof *img);
        if (!img)
                return -ENOMEM;
        if (!(img->data = arena_alloc(a, total))) {
                free(img);
                return -ENOMEM;
        }
        *img = (struct imp_image) { width, height, channels, type, stride, img->data, true };
        *ret = img;
        return 0;
}

int imp_image_arena_adopt(struct imp_image_arena *a, struct imp_image *img) {
        if (!img)
                return -EINVAL;
        if (!a || img->in_arena)
                return 0;
        size_t total = img->stride * (size_t) img->height;
        void *p = arena_alloc(a, total);
        if (!p)
                return -ENOMEM;
        memcpy(p, img->data, total);
        free(img->data);
        img->data = p;
        img->in_arena = true;
        return 0;
}
