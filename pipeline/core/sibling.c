/* The path of a program beside the running one (sibling.h). */
#include <errno.h>
#include <libgen.h>
#include <limits.h>
#include <stdio.h>
#include <unistd.h>
#include "sibling.h"

int imp_sibling_path(const char *name, char *buf, size_t size) {
        char self[PATH_MAX];
        ssize_t n = readlink("/proc/self/exe", self, sizeof self - 1);
        if (n < 0)
                return -errno;
        self[n] = 0;
        if ((size_t) snprintf(buf, size, "%s/%s", dirname(self), name) >= size)
                return -ENAMETOOLONG;
        return 0;
}
