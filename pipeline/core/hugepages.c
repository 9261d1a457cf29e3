/* Transparent huge pages for malloc (hugepages.h). */
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "hugepages.h"
#include "log.h"

#if defined(__SANITIZE_ADDRESS__)
#define IMP_HUGEPAGES_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define IMP_HUGEPAGES_SANITIZED 1
#endif
#endif

#define HUGEPAGES_TUNABLE "glibc.malloc.hugetlb"

void imp_hugepages_reexec(char **argv) {
#ifdef IMP_HUGEPAGES_SANITIZED
        (void) argv;
#else
        const char *t = getenv("GLIBC_TUNABLES");
        if (!argv || !argv[0] || (t && strstr(t, HUGEPAGES_TUNABLE)))
                return;
        char value[4096];
        int n = t && *t ? snprintf(value, sizeof value, "%s:" HUGEPAGES_TUNABLE "=1", t)
                        : snprintf(value, sizeof value, HUGEPAGES_TUNABLE "=1");
        if (n < 0 || (size_t) n >= sizeof value)
                return;
        char *old = t ? strdup(t) : NULL;
        if ((t && !old) || setenv("GLIBC_TUNABLES", value, 1) < 0) {
                free(old);
                return;
        }
        /* The program's own path, not /proc/self/exe: the new image's name (ps, top,
         * /proc/PID/comm) is the basename of what is executed. */
        char self[PATH_MAX];
        ssize_t len = readlink("/proc/self/exe", self, sizeof self - 1);
        if (len > 0) {
                self[len] = 0;
                execv(self, argv);
        }
        /* No /proc, or the exec failed (the binary replaced since): the run goes on
         * without huge pages, with the environment as it found it. */
        log_debug("huge pages for malloc: exec %s: %m", len > 0 ? self : "/proc/self/exe");
        if (old)
                setenv("GLIBC_TUNABLES", old, 1);
        else
                unsetenv("GLIBC_TUNABLES");
        free(old);
#endif
}
