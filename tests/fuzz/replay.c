/* The corpus replay: feeds every file of the directories (or files) on the command line to
 * the harness's LLVMFuzzerTestOneInput, as `fuzzer DIR` would without mutating anything.
 * Linked with each fuzz-<target>.c into the ctest unit test test-fuzz-<target>, it makes
 * every crash a campaign found (kept in tests/fuzz/corpus/<target>/) a regression test. */
#include <dirent.h>
#include <string.h>
#include <sys/stat.h>
#include "fuzz.h"

static int by_name(const void *a, const void *b) {
        return strcmp(*(char *const *) a, *(char *const *) b);
}

static int replay_file(const char *path) {
        size_t n = 0;
        uint8_t *data = fuzz_read_file(path, &n);
        if (!data) {
                fprintf(stderr, "replay: %s: cannot read\n", path);
                return -1;
        }
        fprintf(stderr, "replay: %s (%zu bytes)\n", path, n);
        /* an exact-size copy, so that ASan sees a read past the input's end */
        uint8_t *exact = malloc(n ? n : 1);
        memcpy(exact, data, n);
        free(data);
        LLVMFuzzerTestOneInput(exact, n);
        free(exact);
        return 0;
}

static int replay_dir(const char *dir, size_t *count) {
        DIR *d = opendir(dir);
        if (!d) {
                fprintf(stderr, "replay: %s: cannot open\n", dir);
                return -1;
        }
        char **names = NULL;
        size_t n = 0;
        struct dirent *de;
        while ((de = readdir(d))) {
                if (de->d_name[0] == '.')
                        continue;
                names = realloc(names, (n + 1) * sizeof *names);
                names[n++] = strdup(de->d_name);
        }
        closedir(d);
        qsort(names, n, sizeof *names, by_name);
        int r = 0;
        for (size_t i = 0; i < n; i++) {
                char p[4096];
                snprintf(p, sizeof p, "%s/%s", dir, names[i]);
                if (replay_file(p) < 0)
                        r = -1;
                else
                        (*count)++;
                free(names[i]);
        }
        free(names);
        return r;
}

int main(int argc, char **argv) {
        if (argc < 2) {
                fprintf(stderr, "usage: %s CORPUS_DIR_OR_FILE...\n", argv[0]);
                return 2;
        }
        size_t count = 0;
        int r = 0;
        for (int i = 1; i < argc; i++) {
                struct stat st;
                if (stat(argv[i], &st) == 0 && S_ISDIR(st.st_mode))
                        r |= replay_dir(argv[i], &count) < 0;
                else if (replay_file(argv[i]) == 0)
                        count++;
                else
                        r = 1;
        }
        fprintf(stderr, "replay: %zu inputs\n", count);
        if (count == 0) {
                fprintf(stderr, "replay: no inputs: an empty corpus tests nothing\n");
                return 1;
        }
        return r ? 1 : 0;
}
