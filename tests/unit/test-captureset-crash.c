/* Crash safety of capture sets: a child appends frames in a loop and is SIGKILLed after
 * a random (seeded) delay, 20 times; after each kill an explicit repair moves what the kill
 * left (torn line, .tmp, unrecorded frame) into quarantine/, and the set must reopen with
 * every recorded frame intact (CRC), no .tmp left, no unrecorded frame file, the count equal
 * to the complete frames, and appending must continue with the next seq. */
#include <dirent.h>
#include <errno.h>
#include <signal.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>
#include "captureset.h"
#include "json-util.h"
#include "test.h"

#define W 64
#define H 48
#define ROUNDS 20
#define SEED 20240611u
#define MAX_DELAY_US 40000

static struct imp_image *make_frame(long long seq) {
        struct imp_image *img = NULL;
        if (imp_image_new(W, H, 1, IMP_PIX_U16, &img) < 0)
                abort();
        for (int y = 0; y < H; y++)
                for (int x = 0; x < W; x++)
                        *imp_image_u16(img, x, y) = (uint16_t) (seq * 7919 + x * 31 + y * 1013);
        return img;
}

static int append(struct imp_captureset *cs, struct imp_error *e) {
        size_t n = imp_captureset_count(cs);
        long long seq = n ? imp_captureset_record(cs, n - 1)->seq + 1 : 0;
        struct imp_frame_record r = { .seq = seq, .light = (int) (seq % 5), .exposure_us = 1000,
                                      .pattern = { .kind = IMP_PAT_GRAY, .bit = (int) (seq % 10),
                                                   .nbits = 10 },
                                      .t_frame_ns = seq * 1000 };
        snprintf(r.step, sizeof r.step, "structured-light");
        snprintf(r.camera, sizeof r.camera, "cam0");
        _cleanup_image_ struct imp_image *img = make_frame(seq);
        return imp_captureset_add_frame(cs, &r, img, e);
}

static _Noreturn void child(const char *dir, int ready_fd) {
        struct imp_captureset *cs = NULL;
        struct imp_error e = {};
        if (imp_captureset_open(dir, &cs, &e) < 0) {
                fprintf(stderr, "child: %s\n", e.msg);
                _exit(3);
        }
        /* The delay starts once the child has stored its first frame, so that on a loaded
         * machine the kill still lands among the writes rather than during start-up. */
        for (bool first = true;; first = false) {
                if (append(cs, &e) < 0) {
                        fprintf(stderr, "child: %s\n", e.msg);
                        _exit(4);
                }
                if (first) {
                        if (write(ready_fd, "r", 1) != 1)
                                _exit(5);
                        close(ready_fd);
                }
        }
}

static int count_files(const char *dir, const char *suffix) {
        DIR *d = opendir(dir);
        int n = 0;
        struct dirent *de;
        while (d && (de = readdir(d))) {
                size_t l = strlen(de->d_name), m = strlen(suffix);
                n += strcmp(de->d_name, ".") && strcmp(de->d_name, "..") && l >= m && strcmp(de->d_name + l - m, suffix) == 0;
        }
        if (d)
                closedir(d);
        return n;
}

/* What the kill left behind, before repair moves it: for the summary, to show that
 * the interesting instants were hit. */
static void inspect(const char *dir, const char *frames, int *torn, int *tmp, int *unrecorded) {
        char path[700];
        snprintf(path, sizeof path, "%s/manifest.jsonl", dir);
        FILE *f = fopen(path, "r");
        int lines = 0, c, last = '\n';
        while (f && (c = fgetc(f)) != EOF) {
                lines += c == '\n';
                last = c;
        }
        if (f)
                fclose(f);
        *torn += last != '\n';
        *tmp += count_files(frames, ".tmp") > 0;
        *unrecorded += count_files(frames, ".tiff") > lines;
}

/* Repair moves what the kill left into quarantine/ (nothing is deleted): the files there
 * grow by exactly the number of items reported. */
static void repair(const char *dir, int round) {
        char q[700];
        snprintf(q, sizeof q, "%s/quarantine", dir);
        int before = count_files(q, "");
        json_t *report = NULL;
        struct imp_error e = {};
        int n = imp_captureset_repair(dir, false, &report, &e);
        CHECK_MSG(n >= 0, "round %d: repair: %s", round, e.msg);
        if (n < 0)
                return;
        CHECK_INT_EQ(json_array_size(report), (size_t) n);
        CHECK_INT_EQ(count_files(q, ""), before + n);
        json_decref(report);
}

static void check_set(const char *dir, const char *frames, int round, size_t *ret_count) {
        struct imp_captureset *cs = NULL;
        struct imp_error e = {};
        repair(dir, round);
        CHECK_OK(imp_captureset_open(dir, &cs, &e));
        if (!cs) {
                fprintf(stderr, "round %d: %s\n", round, e.msg);
                return;
        }
        CHECK_INT_EQ(count_files(dir, ".tmp"), 0);
        CHECK_INT_EQ(count_files(frames, ".tmp"), 0);
        size_t n = imp_captureset_count(cs);
        CHECK_INT_EQ(count_files(frames, ".tiff"), n);
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *r = imp_captureset_record(cs, i);
                CHECK_INT_EQ(r->seq, i);
                _cleanup_image_ struct imp_image *img = NULL, *want = make_frame(r->seq);
                int ret = imp_captureset_load_frame(cs, i, &img, &e);
                CHECK_MSG(ret == 0, "round %d frame %zu: %s", round, i, e.msg);
                if (ret == 0)
                        CHECK_MSG(memcmp(img->data, want->data, want->stride * H) == 0,
                                  "round %d frame %zu: pixels of seq %lld", round, i, r->seq);
        }
        /* appending continues with the next seq in the next file */
        CHECK_OK(append(cs, &e));
        CHECK_INT_EQ(imp_captureset_count(cs), n + 1);
        CHECK_INT_EQ(imp_captureset_record(cs, n)->seq, n);
        char want_file[64];
        snprintf(want_file, sizeof want_file, "frames/%06zu.tiff", n);
        CHECK_STR_EQ(imp_captureset_record(cs, n)->file, want_file);
        *ret_count = n + 1;
        imp_captureset_close(cs);
}

int main(void) {
        char dir[512], frames[600];
        snprintf(dir, sizeof dir, "%s/crash", test_tmpdir());
        snprintf(frames, sizeof frames, "%s/frames", dir);
        struct imp_rig rig = { .n_cameras = 1, .settle_us = 100 };
        snprintf(rig.cameras[0].name, sizeof rig.cameras[0].name, "cam0");
        rig.cameras[0].model = (struct imp_pinhole){ .width = W, .height = H, .fx = 50, .fy = 50,
                                                     .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 } };
        rig.cameras[0].sensor = (struct imp_sensor){ .bits = 12, .gain_e_per_dn = 1, .full_well_e = 1 };
        struct imp_captureset *cs = NULL;
        struct imp_error e = {};
        CHECK_OK(imp_captureset_create(dir, &rig, NULL, &cs, &e));
        imp_captureset_close(cs);

        srand(SEED);
        size_t count = 0;
        int rounds_with_child_frames = 0, torn = 0, tmp = 0, unrecorded = 0;
        struct timespec t0;
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (int round = 0; round < ROUNDS; round++) {
                fflush(stderr);
                int ready[2];
                CHECK(pipe(ready) == 0);
                pid_t pid = fork();
                CHECK(pid >= 0);
                if (pid == 0) {
                        close(ready[0]);
                        child(dir, ready[1]);
                }
                close(ready[1]);
                char byte;
                CHECK_MSG(read(ready[0], &byte, 1) == 1, "round %d: child did not open the set", round);
                close(ready[0]);
                useconds_t delay_us = (useconds_t) (rand() % MAX_DELAY_US);
                usleep(delay_us);
                kill(pid, SIGKILL);
                int status = 0;
                CHECK(waitpid(pid, &status, 0) == pid);
                CHECK_MSG(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL,
                          "round %d: the child was killed, not exited (status %d)", round, status);
                size_t before = count;
                inspect(dir, frames, &torn, &tmp, &unrecorded);
                check_set(dir, frames, round, &count);
                /* the child's frames are those beyond the parent's own append */
                rounds_with_child_frames += count > before + 1;
        }
        struct timespec t1;
        clock_gettime(CLOCK_MONOTONIC, &t1);
        fprintf(stderr, "%d rounds, %zu frames, %d rounds where the child wrote frames, %.2f s\n",
                ROUNDS, count, rounds_with_child_frames,
                (double) (t1.tv_sec - t0.tv_sec) + (t1.tv_nsec - t0.tv_nsec) * 1e-9);
        fprintf(stderr, "kills that left a torn manifest line: %d, a .tmp frame: %d, an unrecorded "
                "frame: %d\n", torn, tmp, unrecorded);
        /* the kills must have landed in the middle of appends (a .tmp, an unrecorded frame or
         * a torn line left behind) often enough to test the repair: ~half of them do */
        CHECK_INT_GE(rounds_with_child_frames, ROUNDS);
        CHECK_INT_GE(torn + tmp + unrecorded, ROUNDS / 4);
        return TEST_DONE();
}
