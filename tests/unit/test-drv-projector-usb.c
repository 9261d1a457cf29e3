/* The "usb-dlp" projector backend (real libusb 1.0) against an emulated DLP controller
 * behind usbdevfs (sim/emu/emu-usb.c, a umockdev ioctl handler that answers libusb's URBs):
 * open by VID:PID, by VID:PID:serial and by bus/address, GET_INFO, a 42-pattern Gray
 * sequence shown pattern by pattern with the status and the rig state read back, dark,
 * trigger; a STALL on SHOW cleared and retried; a STALL that outlasts the retry policy;
 * a lost reply (timeout, the IN URB discarded, re-sent, answered from the reply cache);
 * the wrapper (blanking on open and close); unplugging gives -ENODEV with a clear message.
 * Most checks call the backend's ops table directly, to see its own error texts.
 * Needs the umockdev preload: re-executes itself under umockdev-wrapper, skips (77) when
 * that is not installed. */
#include <unistd.h>
#include "emu.h"
#include "projector.h"
#include "unit/test.h"

extern const struct imp_projector_ops imp_projector_usb_dlp_ops;

#define N_BITS 10
#define N_PATTERNS (2 + 2 * 2 * N_BITS)         /* white, black, 2 axes × bits × (normal, inverse) */

static void reexec_under_umockdev(char **argv) {
        if (imp_emu_usb_available())
                return;
        if (getenv("IMPASTO_UMOCKDEV_REEXEC"))
                TEST_SKIP("umockdev preload not active even under umockdev-wrapper");
        setenv("IMPASTO_UMOCKDEV_REEXEC", "1", 1);
        char *args[] = { "umockdev-wrapper", argv[0], NULL };
        execvp(args[0], args);
        TEST_SKIP("umockdev-wrapper not found (%m): cannot emulate /dev/bus/usb");
}

static unsigned gray_sequence(struct imp_pattern *p) {
        unsigned n = 0;
        p[n++] = (struct imp_pattern) { .kind = IMP_PAT_WHITE };
        p[n++] = (struct imp_pattern) { .kind = IMP_PAT_BLACK };
        for (int axis = 0; axis < 2; axis++)
                for (int bit = 0; bit < N_BITS; bit++)
                        for (int inv = 0; inv < 2; inv++)
                                p[n++] = (struct imp_pattern) { .kind = IMP_PAT_GRAY, .axis = axis, .bit = bit,
                                                                .nbits = N_BITS, .inverse = inv };
        return n;
}

static bool same_pattern(const struct imp_pattern *a, const struct imp_pattern *b) {
        return a->kind == b->kind && a->axis == b->axis && a->bit == b->bit && a->nbits == b->nbits &&
               a->inverse == b->inverse && a->step == b->step && a->steps == b->steps &&
               a->period_px == b->period_px;
}

static void check_open_variants(void) {
        const struct imp_projector_ops *ops = &imp_projector_usb_dlp_ops;
        void *st = NULL;
        CHECK_OK(ops->open("1d50:6020:EMU0001", 500, &st));
        if (st)
                ops->close(st);
        st = NULL;
        CHECK_OK(ops->open("001/005;timeout_ms=300", 0, &st));
        if (st)
                ops->close(st);
        st = NULL;
        CHECK_ERR(ops->open("1d50:6020:NOSUCH", 500, &st), -ENODEV);
        CHECK_ERR(ops->open("1d50:6021", 500, &st), -ENODEV);
        CHECK_ERR(ops->open("not-an-address", 500, &st), -EINVAL);
        CHECK(st == NULL);
}

int main(int argc, char **argv) {
        (void) argc;
        reexec_under_umockdev(argv);
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        CHECK_OK(imp_emu_rig_new(4, &rig));
        _cleanup_(imp_emu_usb_freep) struct imp_emu_usb *emu = NULL;
        struct imp_emu_usb_config cfg = { .serial = "EMU0001" };
        int r = imp_emu_usb_new(&cfg, rig, &emu);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();

        check_open_variants();

        const struct imp_projector_ops *ops = &imp_projector_usb_dlp_ops;
        void *st = NULL;
        CHECK_OK(ops->open("1d50:6020", 500, &st));
        if (!st)
                return TEST_DONE();
        struct imp_projector_info info;
        CHECK_OK(ops->get_info(st, &info));
        CHECK_STR_EQ(info.serial, "EMU0001");
        CHECK_STR_EQ(info.model, "impasto DLP emulator");
        CHECK_INT_EQ(info.width, 1280);
        CHECK_INT_EQ(info.height, 800);
        CHECK_INT_EQ(info.max_patterns, 256);

        struct imp_pattern seq[N_PATTERNS];
        unsigned n = gray_sequence(seq);
        CHECK_INT_EQ(n, 42);
        CHECK_OK(ops->upload(st, seq, n));
        for (unsigned i = 0; i < n; i++) {
                struct imp_pattern got;
                CHECK_OK(imp_emu_usb_pattern(emu, i, &got));
                CHECK_MSG(same_pattern(&got, &seq[i]), "pattern %u differs after upload", i);
        }
        struct imp_projector_status s;
        uint64_t last_ns = 0;
        for (unsigned i = 0; i < n; i++) {
                CHECK_OK(ops->show(st, i));
                CHECK_OK(ops->get_status(st, &s));
                CHECK_INT_EQ(s.shown, i);
                CHECK_INT_EQ(s.n_uploaded, n);
                CHECK(!s.fault);
                CHECK_MSG(s.shown_at_ns >= last_ns && s.shown_at_ns > 0, "timestamp %llu after %llu",
                          (unsigned long long) s.shown_at_ns, (unsigned long long) last_ns);
                last_ns = s.shown_at_ns;
                struct imp_pattern desc;
                CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), i);
                CHECK_INT_EQ(imp_emu_rig_get_pattern_desc(rig, &desc), i);
                CHECK_MSG(same_pattern(&desc, &seq[i]), "rig shows another pattern than %u", i);
        }
        CHECK_ERR(ops->show(st, n), -EINVAL);
        CHECK_STR_CONTAINS(ops->last_error(st), "BAD_ARG");
        CHECK_OK(ops->dark(st));
        CHECK_OK(ops->get_status(st, &s));
        CHECK_INT_EQ(s.shown, -1);
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), -1);
        CHECK_OK(ops->trigger(st));
        CHECK_INT_EQ(imp_emu_usb_n_triggers(emu), 1);

        /* STALL on the SHOW frame: the driver clears the halt and re-sends once. */
        unsigned halts0 = imp_emu_usb_n_clear_halts(emu), cmds0 = imp_emu_usb_n_commands(emu);
        imp_emu_usb_stall_nth(emu, 1, 1);
        CHECK_OK(ops->show(st, 7));
        CHECK_INT_EQ(imp_emu_usb_shown(emu), 7);
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), 7);
        CHECK_INT_EQ(imp_emu_usb_n_clear_halts(emu) - halts0, 1);
        CHECK_INT_EQ(imp_emu_usb_n_commands(emu) - cmds0, 2);
        /* A STALL on every attempt (1 + 2 retries): the show fails, nothing changed. */
        imp_emu_usb_stall_nth(emu, 1, 3);
        CHECK_ERR(ops->show(st, 9), -EIO);
        CHECK_STR_CONTAINS(ops->last_error(st), "stalled");
        CHECK_STR_CONTAINS(ops->last_error(st), "gave up after 3 attempts");
        CHECK_INT_EQ(imp_emu_usb_shown(emu), 7);
        CHECK_OK(ops->show(st, 9));
        CHECK_INT_EQ(imp_emu_usb_shown(emu), 9);

        /* A lost reply: the driver times out (libusb discards the IN URB), re-sends the same
         * frame, and the device answers from its reply cache without showing twice. */
        void *st2 = NULL;
        CHECK_OK(ops->open("1d50:6020;timeout_ms=150;retries=1", 0, &st2));
        if (st2) {
                CHECK_OK(ops->get_status(st2, &s));
                unsigned count0 = imp_emu_usb_n_commands(emu);
                imp_emu_usb_drop_reply_nth(emu, 1, 1);
                CHECK_OK(ops->show(st2, 11));
                CHECK_INT_EQ(imp_emu_usb_n_commands(emu) - count0, 2);
                CHECK_INT_EQ(imp_emu_usb_shown(emu), 11);
                struct imp_projector_status s2;
                CHECK_OK(ops->get_status(st2, &s2));
                CHECK_INT_EQ(s2.shown, 11);
                /* Every reply lost: -ETIMEDOUT after 1 + 1 attempts. */
                unsigned triggers0 = imp_emu_usb_n_triggers(emu);
                imp_emu_usb_drop_reply_nth(emu, 1, 2);
                CHECK_ERR(ops->trigger(st2), -ETIMEDOUT);
                CHECK_INT_EQ(imp_emu_usb_n_triggers(emu) - triggers0, 1);   /* ran once, not twice */
                CHECK_STR_CONTAINS(ops->last_error(st2), "no reply within 150 ms");
                ops->close(st2);
        }

        /* Through the wrapper: blanked on open and on close, the backend chosen by name. */
        struct imp_projector *p = NULL;
        CHECK_OK(imp_projector_open("usb-dlp", "1d50:6020:EMU0001", 500, &p));
        if (p) {
                CHECK_INT_EQ(imp_emu_usb_shown(emu), -1);
                CHECK_OK(imp_projector_upload(p, seq, n));
                CHECK_OK(imp_projector_show(p, 5));
                CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), 5);
                imp_projector_close(p);
                CHECK_INT_EQ(imp_emu_usb_shown(emu), -1);
                p = NULL;
        }
        CHECK_OK(imp_projector_open("usb-dlp", "1d50:6020", 500, &p));
        CHECK_OK(p ? imp_projector_upload(p, seq, n) : -EIO);

        /* Unplugged: -ENODEV with a message that says so, now and later. */
        imp_emu_usb_disconnect(emu);
        if (p) {
                CHECK_ERR(imp_projector_show(p, 2), -ENODEV);
                CHECK_STR_CONTAINS(imp_projector_last_error(p), "disconnected");
                fprintf(stderr, "wrapper error text: %s\n", imp_projector_last_error(p));
                imp_projector_close(p);
        }
        CHECK_ERR(ops->show(st, 3), -ENODEV);
        CHECK_STR_CONTAINS(ops->last_error(st), "disconnected");
        CHECK_ERR(ops->get_status(st, &s), -ENODEV);
        ops->close(st);
        st = NULL;
        CHECK_ERR(ops->open("1d50:6020", 500, &st), -ENODEV);
        return TEST_DONE();
}
