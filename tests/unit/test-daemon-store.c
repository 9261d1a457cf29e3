/* The capture store under a full disk and a failing file system, with the store writer
 * thread holding frames: the state directory is a small tmpfs of the test's own
 * (private mount namespace; skipped when the test may not create one).
 *  1. A filler file takes the free space after a few frames: the session pauses with the
 *     disk-space fault (the per-frame check) or the writer's ENOSPC, the manifest lists only
 *     durable, correct frames, and the frames shown by `frame` events are all in it.
 *  2. Resumed with the space back, empty files take the tmpfs's last inodes after a few
 *     frames (bytes stay free, so the per-frame check passes): the writer cannot create the
 *     next frame file, and its failure pauses the session with a storage fault naming that
 *     frame; nothing after it is in the manifest.
 *  3. Read-write again and resumed: the session completes and the set equals an
 *     uninterrupted one frame for frame (plan order, pixels the emulator produced). */
#define _GNU_SOURCE
#include <sched.h>
#include <sys/mount.h>
#include <sys/statvfs.h>
#include "test-daemon-harness.c"

#define PORT 15890
#define N_LIGHTS 8
#define N_EXPOSURES 6
#define TMPFS_OPTS "size=4m,nr_inodes=4096,mode=0750"

static bool private_tmpfs(const char *dir, const char *opts) {
        if (unshare(CLONE_NEWNS) < 0 || mount(NULL, "/", NULL, MS_REC | MS_PRIVATE, NULL) < 0)
                return false;
        return mount("impasto-test", dir, "tmpfs", 0, opts) == 0;
}

/* Polls session.show until the state is `want`; returns the reply (caller frees) or NULL. */
static json_t *wait_state(struct tclient *c, const char *id, const char *want, unsigned timeout_ms) {
        uint64_t end = h_deadline_ms(timeout_ms);
        while (h_now_ms() < end) {
                json_t *r = tc_ok(c, "session.show", h_arg("session", id));
                const char *st = json_string_value(json_object_get(r, "state"));
                if (st && !strcmp(st, want))
                        return r;
                json_decref(r);
                usleep(20000);
        }
        return NULL;
}

static void wait_frames(struct tclient *c, unsigned n) {
        unsigned start = c->n_frames;
        uint64_t end = h_deadline_ms(10000);
        while (c->n_frames < start + n && !c->n_done && h_now_ms() < end) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, 500, &m) == 0)
                        imp_proto_message_done(&m);
        }
}

/* The last fault's message of a session.show reply. */
static const char *last_fault(json_t *show) {
        json_t *faults = json_object_get(show, "faults");
        size_t n = json_array_size(faults);
        return n ? json_string_value(json_object_get(json_array_get(faults, n - 1), "message")) : NULL;
}

static size_t manifest_lines(const char *setdir) {
        char p[1100];
        snprintf(p, sizeof p, "%s/manifest.jsonl", setdir);
        FILE *f = fopen(p, "re");
        size_t n = 0;
        int ch;
        while (f && (ch = fgetc(f)) != EOF)
                n += ch == '\n';
        if (f)
                fclose(f);
        return n;
}

int main(void) {
        if (geteuid() != 0) {
                fprintf(stderr, "needs root for a private tmpfs, skipping\n");
                return 77;
        }
        struct harness h;
        h_setup(&h, PORT, N_LIGHTS);
        mkdir(h.state, 0750);
        if (!private_tmpfs(h.state, TMPFS_OPTS)) {
                fprintf(stderr, "cannot mount a private tmpfs on %s (%m), skipping\n", h.state);
                h_teardown(&h);
                return 77;
        }
        char plan[512], filler[400];
        snprintf(plan, sizeof plan, "%s/sweep.cfg", h.dir);
        snprintf(filler, sizeof filler, "%s/filler", h.state);
        h_write(plan, "dome = { lights = \"all\"; exposures_us = [1000.0, 1200.0, 1400.0, 1600.0, 1800.0, 2000.0]; };\n");
        const size_t frames = N_LIGHTS * N_EXPOSURES;
        h_start(&h, (const char *const[]) { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", NULL });
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        char id[128], setdir[1024];
        tc_start_session(&c, plan, "store", id, setdir);
        json_t *r;
        if (!id[0])
                goto out;

        /* 1. The disk fills up under a running capture. */
        wait_frames(&c, 3);
        struct statvfs sv;
        CHECK(statvfs(h.state, &sv) == 0);
        long long room = (long long) sv.f_bavail * (long long) sv.f_frsize - 4096;
        int fd = open(filler, O_WRONLY | O_CREAT | O_CLOEXEC, 0600);
        CHECK(fd >= 0);
        static char block[65536];
        while (fd >= 0 && room > 0) {
                ssize_t k = write(fd, block, (size_t) IMP_MIN(room, (long long) sizeof block));
                if (k <= 0)
                        break;
                room -= k;
        }
        if (fd >= 0)
                close(fd);
        r = wait_state(&c, id, "paused", 10000);
        CHECK_MSG(r != NULL, "the session did not pause on a full disk");
        const char *msg = last_fault(r);
        CHECK_MSG(msg && (strstr(msg, "bytes free") || strstr(msg, "No space")), "fault: %s", msg ? msg : "(none)");
        size_t stored = (size_t) json_integer_value(json_object_get(r, "frames"));
        json_decref(r);
        CHECK(stored >= 3 && stored < frames);
        CHECK_INT_EQ(manifest_lines(setdir), stored);
        CHECK_INT_EQ(h_verify_set(setdir, plan, false), stored);
        CHECK(c.n_frames <= stored);            /* a `frame` event names a durable frame */
        CHECK(c.n_faults >= 1);

        /* 2. Space again; then no inode left: the writer's own failure pauses. */
        CHECK(unlink(filler) == 0);
        json_decref(tc_ok(&c, "session.resume", h_arg("session", id)));
        wait_frames(&c, 2);
        unsigned n_inodes = 0;
        for (;; n_inodes++) {
                char p[512];
                snprintf(p, sizeof p, "%s/inode-%u", h.state, n_inodes);
                int ifd = open(p, O_WRONLY | O_CREAT | O_CLOEXEC, 0600);
                if (ifd < 0) {
                        CHECK_INT_EQ(errno, ENOSPC);
                        break;
                }
                close(ifd);
        }
        r = wait_state(&c, id, "paused", 10000);
        CHECK_MSG(r != NULL, "the session did not pause when no file could be created");
        char fault[1024];
        snprintf(fault, sizeof fault, "%s", r && last_fault(r) ? last_fault(r) : "(none)");
        size_t stored2 = (size_t) json_integer_value(json_object_get(r, "frames"));
        json_decref(r);
        CHECK(stored2 > stored && stored2 < frames);
        CHECK_INT_EQ(manifest_lines(setdir), stored2);
        char want[64];
        snprintf(want, sizeof want, "storing frame %zu:", stored2);     /* the first one not stored */
        CHECK_STR_CONTAINS(fault, want);

        /* 3. Inodes back: resume to the end; the set is whole. */
        for (unsigned i = 0; i < n_inodes; i++) {
                char p[512];
                snprintf(p, sizeof p, "%s/inode-%u", h.state, i);
                CHECK(unlink(p) == 0);
        }
        unsigned done0 = c.n_done;
        json_decref(tc_ok(&c, "session.resume", h_arg("session", id)));
        CHECK_OK(tc_wait_done(&c, done0 + 1, 20000));
        CHECK_STR_EQ(c.done_state, "completed");
        h_check_completed(&h, &c, id, setdir, plan, frames);
out:
        if (h.pid > 0)
                h_kill(&h, SIGKILL);
        tc_close(&c);
        (void) umount2(h.state, MNT_DETACH);
        h_teardown(&h);
        return TEST_DONE();
}
