/* Bounded line splitter for the control socket: turns a byte stream read in arbitrary
 * chunks into '\n'-terminated lines, reports an oversized line once and skips it up to
 * its newline so that the connection survives. */
#include <errno.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "protocol.h"

struct imp_linebuf {
        char *buf;
        size_t start;           /* first unconsumed byte */
        size_t len;             /* bytes held */
        size_t cap;
        size_t max;             /* longest line, without '\n' */
        bool discarding;        /* an oversized line was reported; drop up to its '\n' */
};

int imp_linebuf_new(size_t max, struct imp_linebuf **ret) {
        if (!ret || max == 0 || max > SIZE_MAX / 4)
                return -EINVAL;
        struct imp_linebuf *lb = calloc(1, sizeof *lb);
        if (!lb)
                return -ENOMEM;
        lb->max = max;
        *ret = lb;
        return 0;
}

void imp_linebuf_free(struct imp_linebuf *lb) {
        if (!lb)
                return;
        free(lb->buf);
        free(lb);
}

size_t imp_linebuf_pending(const struct imp_linebuf *lb) {
        return lb ? lb->len - lb->start : 0;
}

static int reserve(struct imp_linebuf *lb, size_t extra) {
        if (lb->start > 0) {            /* move the unconsumed tail to the front first */
                memmove(lb->buf, lb->buf + lb->start, lb->len - lb->start);
                lb->len -= lb->start;
                lb->start = 0;
        }
        if (extra > SIZE_MAX - lb->len - 1)
                return -ENOMEM;
        size_t need = lb->len + extra + 1;      /* + 1: room to NUL-terminate a line */
        if (need <= lb->cap)
                return 0;
        size_t cap = lb->cap ? lb->cap : 4096;
        while (cap < need)
                cap = cap > SIZE_MAX / 2 ? need : cap * 2;
        char *b = realloc(lb->buf, cap);
        if (!b)
                return -ENOMEM;
        lb->buf = b;
        lb->cap = cap;
        return 0;
}

int imp_linebuf_feed(struct imp_linebuf *lb, const void *data, size_t n) {
        if (!lb || (!data && n))
                return -EINVAL;
        const char *p = data;
        if (lb->discarding) {
                const char *nl = memchr(p, '\n', n);
                if (!nl)
                        return 0;
                lb->discarding = false;
                n -= (size_t) (nl + 1 - p);
                p = nl + 1;
        }
        if (n == 0)
                return 0;
        int r = reserve(lb, n);
        if (r < 0)
                return r;
        memcpy(lb->buf + lb->len, p, n);
        lb->len += n;
        return 0;
}

int imp_linebuf_next(struct imp_linebuf *lb, char **ret_line, size_t *ret_len) {
        if (!lb || !ret_line || !ret_len)
                return -EINVAL;
        for (;;) {
                char *s = lb->buf + lb->start;
                size_t avail = lb->len - lb->start;
                char *nl = avail ? memchr(s, '\n', avail) : NULL;
                if (!nl) {
                        if (avail <= lb->max)
                                return 0;
                        /* Too long and still no newline: drop what we hold, skip the rest. */
                        lb->start = lb->len = 0;
                        lb->discarding = true;
                        return -E2BIG;
                }
                size_t n = (size_t) (nl - s);
                lb->start += n + 1;
                if (n > lb->max)
                        return -E2BIG;
                if (n == 0 || (n == 1 && s[0] == '\r'))
                        continue;               /* blank lines are not messages */
                *nl = '\0';
                *ret_line = s;
                *ret_len = n;
                return 1;
        }
}
