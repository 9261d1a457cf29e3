/* Scratch files and input splitting shared by the harnesses (fuzz.h). */
#include <dirent.h>
#include <errno.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "fuzz.h"

static char scratch[4096];

static void remove_tree(const char *dir, int depth) {
        DIR *d = opendir(dir);
        if (!d)
                return;
        struct dirent *de;
        while ((de = readdir(d))) {
                if (!strcmp(de->d_name, ".") || !strcmp(de->d_name, ".."))
                        continue;
                char p[4608];
                snprintf(p, sizeof p, "%s/%s", dir, de->d_name);
                struct stat st;
                if (lstat(p, &st) == 0 && S_ISDIR(st.st_mode)) {
                        if (depth < 8)
                                remove_tree(p, depth + 1);
                        rmdir(p);
                } else {
                        unlink(p);
                }
        }
        closedir(d);
}

static void scratch_cleanup(void) {
        if (scratch[0]) {
                remove_tree(scratch, 0);
                rmdir(scratch);
        }
}

const char *fuzz_scratch_dir(void) {
        if (scratch[0])
                return scratch;
        const char *tmp = getenv("TMPDIR");
        snprintf(scratch, sizeof scratch, "%s/impasto-fuzz-XXXXXX", tmp && *tmp ? tmp : "/tmp");
        if (!mkdtemp(scratch)) {
                perror("fuzz: mkdtemp");
                abort();
        }
        atexit(scratch_cleanup);
        return scratch;
}

void fuzz_clear_scratch(void) {
        remove_tree(fuzz_scratch_dir(), 0);
}

const char *fuzz_write_file(const char *name, const void *data, size_t size) {
        static char path[4608];
        const char *slash = strchr(name, '/');
        if (slash) {
                snprintf(path, sizeof path, "%s/%.*s", fuzz_scratch_dir(), (int) (slash - name), name);
                if (mkdir(path, 0700) < 0 && errno != EEXIST) {
                        perror("fuzz: mkdir");
                        abort();
                }
        }
        snprintf(path, sizeof path, "%s/%s", fuzz_scratch_dir(), name);
        FILE *f = fopen(path, "wb");
        if (!f || (size && fwrite(data, 1, size, f) != size) || fclose(f) != 0) {
                perror("fuzz: write");
                abort();
        }
        return path;
}

void *fuzz_read_file(const char *path, size_t *ret_size) {
        FILE *f = fopen(path, "rb");
        if (!f)
                return NULL;
        size_t cap = 4096, n = 0;
        char *b = malloc(cap);
        size_t k;
        while (b && (k = fread(b + n, 1, cap - n, f)) > 0) {
                n += k;
                if (n == cap) {
                        char *nb = realloc(b, cap * 2);
                        if (!nb) {
                                free(b);
                                b = NULL;
                                break;
                        }
                        b = nb;
                        cap *= 2;
                }
        }
        fclose(f);
        *ret_size = n;
        return b;
}

size_t fuzz_split(const uint8_t *data, size_t size, struct fuzz_part *parts, size_t max) {
        static const char marker[] = "--8<-- ";
        const size_t mlen = sizeof marker - 1;
        size_t n = 0, i = 0, start = 0;
        char name[64] = "";
        while (i <= size && n < max) {
                bool at_line = i == 0 || data[i - 1] == '\n';
                if (i == size || (at_line && size - i >= mlen && !memcmp(data + i, marker, mlen))) {
                        if (i > start || name[0] || i == size) {
                                size_t end = i;
                                /* the '\n' before a marker separates, it is not the part's */
                                if (i < size && end > start)
                                        end--;
                                parts[n] = (struct fuzz_part) { .data = data + start, .size = end - start };
                                snprintf(parts[n].name, sizeof parts[n].name, "%s", name);
                                n++;
                        }
                        if (i == size)
                                break;
                        const uint8_t *nl = memchr(data + i, '\n', size - i);
                        size_t end = nl ? (size_t) (nl - data) : size;
                        size_t len = end - i - mlen;
                        snprintf(name, sizeof name, "%.*s", (int) (len < 63 ? len : 63), data + i + mlen);
                        i = start = nl ? end + 1 : size;
                        continue;
                }
                i++;
        }
        return n;
}
