/* imp_hugepages_reexec (hugepages.h): a program that calls it runs again, same pid and
 * argv, with glibc.malloc.hugetlb=1 appended to GLIBC_TUNABLES (other tunables kept); a
 * GLIBC_TUNABLES that already names the tunable (=0 included) is left as it is. Where THP is
 * in madvise mode, a 64 MiB malloc'd block is then eligible for huge pages (glibc advised
 * it) and with hugetlb=0 it is not: the setting reaches the allocator. The process keeps its
 * name (/proc/self/comm: what ps and pgrep show). */
#include <stdbool.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <unistd.h>
#include "hugepages.h"
#include "unit/test.h"

/* THPeligible of the mapping holding p, -1 when not found. */
static int thp_eligible(const void *p) {
        FILE *s = fopen("/proc/self/smaps", "r");
        if (!s)
                return -1;
        char line[512];
        bool in = false;
        int eligible = -1;
        uintptr_t at = (uintptr_t) p;
        while (fgets(line, sizeof line, s)) {
                unsigned long lo, hi;
                if (sscanf(line, "%lx-%lx ", &lo, &hi) == 2 && strchr(line, '-') < strchr(line, ' '))
                        in = lo <= at && at < hi;
                else if (in && sscanf(line, "THPeligible: %d", &eligible) == 1)
                        break;
        }
        fclose(s);
        return eligible;
}

/* The child: re-executes itself, then prints its pid before and after, argv and
 * GLIBC_TUNABLES and the eligibility of a fresh 64 MiB block. */
static int child(int argc, char **argv) {
        const char *pid0 = getenv("TEST_HUGEPAGES_PID");
        if (!pid0) {
                char b[32];
                snprintf(b, sizeof b, "%d", (int) getpid());
                setenv("TEST_HUGEPAGES_PID", b, 1);
        }
        imp_hugepages_reexec(argv);
        size_t n = 64u << 20;
        char *p = malloc(n);
        if (!p)
                return 3;
        memset(p, 1, n);
        const char *t = getenv("GLIBC_TUNABLES");
        char comm[64] = "?";
        FILE *c = fopen("/proc/self/comm", "r");
        if (c) {
                if (fscanf(c, "%63s", comm) != 1)
                        snprintf(comm, sizeof comm, "?");
                fclose(c);
        }
        printf("pid %s %d\nargc %d %s %s\ntunables %s\neligible %d\ncomm %s\n", getenv("TEST_HUGEPAGES_PID"),
               (int) getpid(), argc, argv[1], argc > 2 ? argv[2] : "-", t ? t : "(unset)", thp_eligible(p), comm);
        free(p);
        return 0;
}

struct result {
        int pid_before, pid_after, argc, eligible;
        char arg2[64], tunables[512], comm[64];
};

/* Runs this program as a child with GLIBC_TUNABLES = tunables (NULL: unset). */
static bool run_child(const char *self, const char *tunables, struct result *r) {
        int fd[2];
        if (pipe(fd) < 0)
                return false;
        pid_t pid = fork();
        if (pid == 0) {
                dup2(fd[1], 1);
                close(fd[0]);
                if (tunables)
                        setenv("GLIBC_TUNABLES", tunables, 1);
                else
                        unsetenv("GLIBC_TUNABLES");
                unsetenv("TEST_HUGEPAGES_PID");
                execl(self, self, "child", "extra-arg", (char *) NULL);
                _exit(127);
        }
        close(fd[1]);
        FILE *f = fdopen(fd[0], "r");
        char a1[64] = "";
        int n = fscanf(f, "pid %d %d\nargc %d %63s %63s\ntunables %511s\neligible %d\ncomm %63s", &r->pid_before,
                       &r->pid_after, &r->argc, a1, r->arg2, r->tunables, &r->eligible, r->comm);
        fclose(f);
        int st;
        waitpid(pid, &st, 0);
        return n == 8 && WIFEXITED(st) && WEXITSTATUS(st) == 0 && !strcmp(a1, "child");
}

static void check_runs(const char *self, const char *mode) {
        bool madvise = strstr(mode, "[madvise]") != NULL;
        struct result r = {};
        CHECK(run_child(self, NULL, &r));
        CHECK_INT_EQ(r.pid_before, r.pid_after);   /* exec, not fork */
        CHECK_INT_EQ(r.argc, 3);
        CHECK_STR_EQ(r.arg2, "extra-arg");
        CHECK_STR_EQ(r.comm, "test-hugepages");   /* not "exe" */
        CHECK_STR_EQ(r.tunables, "glibc.malloc.hugetlb=1");
        if (madvise)
                CHECK_MSG(r.eligible == 1, "hugetlb=1 set, THP madvise: a 64 MiB block has THPeligible %d",
                          r.eligible);

        r = (struct result) {};
        CHECK(run_child(self, "glibc.malloc.mmap_threshold=1048576", &r));
        CHECK_STR_EQ(r.tunables, "glibc.malloc.mmap_threshold=1048576:glibc.malloc.hugetlb=1");
        CHECK_INT_EQ(r.pid_before, r.pid_after);

        r = (struct result) {};
        CHECK(run_child(self, "glibc.malloc.hugetlb=0", &r));
        CHECK_STR_EQ(r.tunables, "glibc.malloc.hugetlb=0");
        if (madvise)
                CHECK_MSG(r.eligible == 0, "hugetlb=0 kept, THP madvise: a 64 MiB block has THPeligible %d",
                          r.eligible);
}

int main(int argc, char **argv) {
        if (argc > 1 && !strcmp(argv[1], "child"))
                return child(argc, argv);
#if defined(__SANITIZE_ADDRESS__)
        TEST_SKIP("sanitizer build: imp_hugepages_reexec does nothing (ASan's allocator ignores the tunable)\n");
#endif
        char mode[128] = "(no THP)";
        FILE *f = fopen("/sys/kernel/mm/transparent_hugepage/enabled", "r");
        if (f) {
                if (!fgets(mode, sizeof mode, f))
                        snprintf(mode, sizeof mode, "(unreadable)");
                fclose(f);
        }
        fprintf(stderr, "THP mode: %s", mode);
        check_runs(argv[0], mode);
        return TEST_DONE();
}
