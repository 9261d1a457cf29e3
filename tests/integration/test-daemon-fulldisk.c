/* A real full disk under a running capture: the test enters a private mount
 * namespace (unshare, root only: skipped when not permitted), mounts a small tmpfs as
 * impastod's state directory, starts a long dome sweep on the emulated rig, and fills the
 * tmpfs to the last byte while frames are being written. The session must pause with an
 * io_error fault that says the store is full, a resume while the disk is still full must be
 * refused with io_error, and after the filler is removed the resumed session completes: the
 * finished set holds every planned frame once, each with the emulator's exact pixels (no
 * frame lost, duplicated or corrupt). */
#define _GNU_SOURCE 1
#include <sched.h>
#include <sys/mount.h>
#include <sys/statvfs.h>
#include "unit/test-daemon-harness.c"

#define PORT 15896
#define N_LIGHTS 4
#define N_REPEATS 8             /* the light list repeated: 32 lights × 8 exposures = 256 frames */
#define N_EXPOSURES 8           /* of 4 KiB each: a few seconds of capture */
#define N_FRAMES (N_LIGHTS * N_REPEATS * N_EXPOSURES)
#define TMPFS_SIZE "16m"
#define FILL_AFTER_FRAMES 20

static int enter_tmpfs(const char *dir) {
        if (unshare(CLONE_NEWNS) < 0)
                return -errno;
        if (mount(NULL, "/", NULL, MS_REC | MS_PRIVATE, NULL) < 0)
                return -errno;
        if (mkdir(dir, 0755) < 0 && errno != EEXIST)
                return -errno;
        if (mount("impasto-fulldisk", dir, "tmpfs", MS_NOSUID | MS_NODEV, "size=" TMPFS_SIZE ",mode=0755") < 0)
                return -errno;
        return 0;
}

/* Writes zeros until the file system says ENOSPC; the bytes written. */
static long long fill(const char *path) {
        int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0600);
        if (fd < 0)
                return -errno;
        static char buf[65536];
        long long n = 0;
        for (;;) {
                ssize_t k = write(fd, buf, sizeof buf);
                if (k <= 0)
                        break;
                n += k;
        }
        /* the last partial blocks too */
        for (;;) {
                if (write(fd, buf, 512) <= 0)
                        break;
                n += 512;
        }
        close(fd);
        return n;
}

/* Reads events until a fault arrives; its message and code into the buffers. */
static bool wait_fault(struct tclient *c, char *msg, size_t msize, char *code, size_t csize, int *ret_errno,
                       unsigned timeout_ms) {
        uint64_t end = h_now_ms() + timeout_ms;
        while (h_now_ms() < end) {
                struct imp_proto_message m = { 0 };
                if (tc_read(c, (unsigned) (end - h_now_ms()), &m) < 0)
                        return false;
                bool fault = m.kind == IMP_PROTO_MSG_EVENT && !strcmp(m.event, "fault");
                if (fault) {
                        snprintf(msg, msize, "%s", json_string_value(json_object_get(m.root, "message")) ?: "");
                        snprintf(code, csize, "%s", json_string_value(json_object_get(m.root, "code")) ?: "");
                        *ret_errno = (int) json_integer_value(json_object_get(m.root, "errno"));
                }
                imp_proto_message_done(&m);
                if (fault)
                        return true;
        }
        return false;
}

int main(void) {
        struct harness h;
        if (geteuid() != 0)
                TEST_SKIP("needs root for a mount namespace and a tmpfs");
        h_setup(&h, PORT, N_LIGHTS);
        int r = enter_tmpfs(h.state);
        if (r < 0) {
                h_teardown(&h);
                TEST_SKIP("no private tmpfs here (%s)", strerror(-r));
        }
        char plan[512], exposures[2048] = "", lights[1024] = "", filler[600];
        snprintf(plan, sizeof plan, "%s/long.cfg", h.dir);
        snprintf(filler, sizeof filler, "%s/filler", h.state);
        for (int i = 0; i < N_EXPOSURES; i++)
                snprintf(exposures + strlen(exposures), sizeof exposures - strlen(exposures), "%s%d.0", i ? ", " : "",
                         1000 + 100 * i);
        for (int i = 0; i < N_LIGHTS * N_REPEATS; i++)
                snprintf(lights + strlen(lights), sizeof lights - strlen(lights), "%s%d", i ? ", " : "", i % N_LIGHTS);
        char text[4096];
        snprintf(text, sizeof text, "dome = { lights = [%s]; exposures_us = [%s]; };\n", lights, exposures);
        h_write(plan, text);

        h_start(&h, (const char *const[]) { "--worker-cmd", "/bin/true", "--min-free-bytes", "0", NULL });
        struct tclient c;
        CHECK_OK(tc_open(&c, h.socket, true));
        if (c.fd < 0)
                goto out;
        json_t *res = tc_ok(&c, "session.start", json_pack("{s:s, s:s}", "plan", plan, "name", "fulldisk"));
        const char *sid = json_string_value(json_object_get(res, "session"));
        char session[160] = "", set_dir[1024] = "";
        snprintf(session, sizeof session, "%s", sid ? sid : "");
        snprintf(set_dir, sizeof set_dir, "%s", json_string_value(json_object_get(res, "path")) ?: "");
        json_decref(res);
        CHECK(session[0]);
        if (!session[0])
                goto out;

        /* fill the store while frames are being written */
        while (c.n_frames < FILL_AFTER_FRAMES) {
                struct imp_proto_message m = { 0 };
                if (tc_read(&c, 20000, &m) < 0)
                        break;
                imp_proto_message_done(&m);
        }
        CHECK_MSG(c.n_done == 0, "the session ended before the disk was filled; lengthen the plan");
        long long filled = fill(filler);
        struct statvfs sv;
        CHECK(statvfs(h.state, &sv) == 0 && sv.f_bavail == 0);
        fprintf(stderr, "filled the %s tmpfs with %lld bytes after %u frames\n", TMPFS_SIZE, filled, c.n_frames);

        char msg[1024] = "", code[64] = "";
        int fault_errno = 0;
        CHECK_MSG(wait_fault(&c, msg, sizeof msg, code, sizeof code, &fault_errno, 20000),
                  "no fault after the disk filled");
        fprintf(stderr, "fault: %s: %s\n", code, msg);
        CHECK_STR_EQ(code, "io_error");
        CHECK_INT_EQ(fault_errno, ENOSPC);
        CHECK_MSG(strstr(msg, "bytes free") || strstr(msg, "No space left on device"), "the fault does not say the disk is full: %s",
                  msg);
        CHECK_INT_EQ(c.n_done, 0);
        res = tc_ok(&c, "session.show", json_pack("{s:s}", "session", session));
        CHECK_STR_EQ(json_string_value(json_object_get(res, "state")), "paused");
        long long frames_paused = json_integer_value(json_object_get(res, "frames"));
        CHECK(frames_paused >= FILL_AFTER_FRAMES && frames_paused < N_FRAMES);
        json_decref(res);

        /* still full: resume refused, nothing lost */
        char emsg[512];
        CHECK_INT_EQ(tc_err(&c, "session.resume", json_pack("{s:s}", "session", session), emsg, sizeof emsg),
                     IMP_PROTO_E_IO);
        CHECK_STR_CONTAINS(emsg, "not enough disk space");

        /* space again: resume completes the set */
        CHECK(unlink(filler) == 0);
        res = tc_ok(&c, "session.resume", json_pack("{s:s}", "session", session));
        json_decref(res);
        CHECK_OK(tc_wait_done(&c, 1, 60000));
        CHECK_STR_EQ(c.done_state, "completed");
        size_t n = h_verify_set(set_dir, plan, true);
        CHECK_INT_EQ(n, (size_t) N_FRAMES);
        fprintf(stderr, "paused at %lld frames, completed with %zu frames, every one checked\n", frames_paused, n);
        tc_close(&c);
out:
        h_kill(&h, SIGTERM);
        CHECK(h_wait(&h, 10000) >= 0);
        h_teardown(&h);
        return TEST_DONE();
}
