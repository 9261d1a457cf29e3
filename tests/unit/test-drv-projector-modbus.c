/* The "modbus" projector backend and the projector wrapper against the emulated controller's
 * sequencer (sim/emu/emu-modbus.c, written from docs/dome-registers.md): upload, show, dark,
 * trigger, status, capacity, bad descriptors, faults, blanking on failure, and -EOPNOTSUPP
 * for slots a backend leaves NULL. */
#include "emu.h"
#include "projector.h"
#include "unit/test.h"

#define PORT 15841
/* Generous: nothing here waits for a timeout, and a loaded CI machine can stall a reply. */
#define ADDR "127.0.0.1:15841;timeout_ms=3000"

static unsigned make_sequence(struct imp_pattern *p, unsigned max) {
        unsigned n = 0;
        p[n++] = (struct imp_pattern) { .kind = IMP_PAT_WHITE };
        p[n++] = (struct imp_pattern) { .kind = IMP_PAT_BLACK };
        for (int axis = 0; axis < 2; axis++)
                for (int b = 0; b < 8; b++)
                        for (int inv = 0; inv < 2; inv++)
                                p[n++] = (struct imp_pattern) { .kind = IMP_PAT_GRAY, .axis = axis, .bit = b,
                                                                .nbits = 8, .inverse = inv };
        for (int s = 0; s < 4; s++)
                p[n++] = (struct imp_pattern) { .kind = IMP_PAT_PHASE, .period_px = 16.25, .step = s, .steps = 4 };
        CHECK(n <= max);
        return n;
}

static bool same(const struct imp_pattern *a, const struct imp_pattern *b) {
        return a->kind == b->kind && a->axis == b->axis && a->bit == b->bit && a->nbits == b->nbits &&
               a->inverse == b->inverse && a->period_px == b->period_px && a->step == b->step && a->steps == b->steps;
}

/* A backend with only the required slots, to see the wrapper answer -EOPNOTSUPP. */
static int min_open(const char *a, unsigned t, void **s) { (void) a, (void) t; *s = NULL; return 0; }
static void min_close(void *s) { (void) s; }

int main(void) {
        struct imp_emu_modbus_config cfg = { .port = PORT, .n_lights = 4, .projector_width = 256,
                                             .projector_height = 192, .max_patterns = 40 };
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        CHECK_OK(imp_emu_rig_new(4, &rig));
        _cleanup_(imp_emu_modbus_freep) struct imp_emu_modbus *emu = NULL;
        int r = imp_emu_modbus_new(&cfg, rig, &emu);
        if (r == -EADDRINUSE)
                TEST_SKIP("TCP port %d is in use", PORT);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();

        CHECK_ERR(imp_projector_open("nonesuch", ADDR, 0, &(struct imp_projector *){ NULL }), -ENOENT);
        CHECK_ERR(imp_projector_open("modbus", "127.0.0.1", 0, &(struct imp_projector *){ NULL }), -EINVAL);
        CHECK_ERR(imp_projector_open("modbus", "127.0.0.1:15841;retries=0", 0, &(struct imp_projector *){ NULL }),
                  -EINVAL);
        _cleanup_(imp_projector_closep) struct imp_projector *p = NULL;
        imp_emu_rig_set_pattern_desc(rig, 3, &(struct imp_pattern) { .kind = IMP_PAT_WHITE });
        CHECK_OK(imp_projector_open("modbus", ADDR, 0, &p));
        if (!p)
                return TEST_DONE();
        /* Open blanks. */
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), -1);
        struct imp_projector_info info;
        CHECK_OK(imp_projector_get_info(p, &info));
        CHECK_INT_EQ(info.width, 256);
        CHECK_INT_EQ(info.height, 192);
        CHECK_INT_EQ(info.max_patterns, 40);

        /* Nothing uploaded: nothing to show. */
        CHECK_ERR(imp_projector_show(p, 0), -EINVAL);
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "holds 0");

        struct imp_pattern seq[64];
        unsigned n = make_sequence(seq, 64);
        CHECK_INT_EQ(n, 38);
        CHECK_OK(imp_projector_upload(p, seq, n));
        CHECK_INT_EQ(imp_emu_modbus_projector_count(emu), n);
        for (unsigned i = 0; i < n; i++) {
                CHECK_OK(imp_projector_show(p, i));
                struct imp_pattern d;
                CHECK_INT_EQ(imp_emu_rig_get_pattern_desc(rig, &d), i);
                CHECK_MSG(same(&d, &seq[i]), "pattern %u arrived as kind %d bit %d inv %d period %g", i, d.kind,
                          d.bit, d.inverse, d.period_px);
        }
        struct imp_projector_status st;
        CHECK_OK(imp_projector_get_status(p, &st));
        CHECK_INT_EQ(st.shown, (int) n - 1);
        CHECK_INT_EQ(st.n_uploaded, n);
        CHECK(!st.fault);
        CHECK(st.shown_at_ns > 0);
        CHECK_OK(imp_projector_dark(p));
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), -1);
        CHECK_OK(imp_projector_get_status(p, &st));
        CHECK_INT_EQ(st.shown, -1);
        CHECK_OK(imp_projector_trigger(p));
        CHECK_OK(imp_projector_trigger(p));
        CHECK_INT_EQ(imp_emu_modbus_projector_triggers(emu), 2);

        /* Too many patterns for this sequencer (40), and over the interface's limit. */
        struct imp_pattern many[IMP_PROJECTOR_MAX_PATTERNS + 1];
        for (unsigned i = 0; i < ARRAY_SIZE(many); i++)
                many[i] = (struct imp_pattern) { .kind = IMP_PAT_WHITE };
        CHECK_ERR(imp_projector_upload(p, many, 41), -E2BIG);
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "holds 40");
        CHECK_ERR(imp_projector_upload(p, many, ARRAY_SIZE(many)), -E2BIG);
        /* Bad descriptors are refused on the host, naming the pattern. */
        struct imp_pattern bad[2] = { { .kind = IMP_PAT_WHITE }, { .kind = IMP_PAT_GRAY, .bit = 8, .nbits = 8 } };
        CHECK_ERR(imp_projector_upload(p, bad, 2), -EINVAL);
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "pattern 1");
        bad[1] = (struct imp_pattern) { .kind = IMP_PAT_PHASE, .period_px = 16.333, .steps = 3 };
        CHECK_ERR(imp_projector_upload(p, bad, 2), -EINVAL);
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "0.01 px");
        bad[1].period_px = 0.0 / 0.0;
        CHECK_ERR(imp_projector_upload(p, bad, 2), -EINVAL);

        /* A Modbus exception on show: error, projector dark, nothing left on. */
        CHECK_OK(imp_projector_upload(p, seq, 4));
        CHECK_OK(imp_projector_show(p, 2));
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), 2);
        imp_emu_modbus_fail_nth(emu, 1, 4);
        CHECK_ERR(imp_projector_show(p, 3), -EIO);
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "show pattern 3");
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "exception");
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), -1);
        CHECK_INT_EQ(imp_emu_modbus_projector_shown(emu), -1);

        /* A latched LED fault: show refused, status reports it, clearing is the controller's. */
        CHECK_OK(imp_projector_show(p, 1));
        imp_emu_modbus_projector_fault(emu, 3);
        CHECK_INT_EQ(imp_emu_rig_get_pattern(rig), -1);
        CHECK_ERR(imp_projector_show(p, 0), -EIO);
        CHECK_OK(imp_projector_get_status(p, &st));
        CHECK(st.fault);
        CHECK_INT_EQ(st.fault_code, 3);
        CHECK_INT_EQ(st.shown, -1);

        /* The controller gone: failure within the retry budget, not a hang. */
        imp_emu_modbus_free(emu);
        emu = NULL;
        CHECK(imp_projector_show(p, 0) < 0);
        CHECK(imp_projector_dark(p) < 0);
        CHECK_STR_CONTAINS(imp_projector_last_error(p), "dark");
        imp_projector_close(p);
        p = NULL;

        /* Slots a backend leaves NULL. */
        const struct imp_projector_ops min_ops = { .name = "min", .open = min_open, .close = min_close };
        _cleanup_(imp_projector_closep) struct imp_projector *m = NULL;
        CHECK_OK(imp_projector_open_ops(&min_ops, "anything", 0, &m));
        if (m) {
                CHECK_OK(imp_projector_get_info(m, &info));
                CHECK_INT_EQ(info.max_patterns, IMP_PROJECTOR_MAX_PATTERNS);
                CHECK_ERR(imp_projector_upload(m, seq, 1), -EOPNOTSUPP);
                CHECK_ERR(imp_projector_show(m, 0), -EOPNOTSUPP);
                CHECK_ERR(imp_projector_dark(m), -EOPNOTSUPP);
                CHECK_ERR(imp_projector_trigger(m), -EOPNOTSUPP);
                CHECK_ERR(imp_projector_get_status(m, &st), -EOPNOTSUPP);
        }
        CHECK_ERR(imp_projector_open_ops(&(struct imp_projector_ops) { .name = "x" }, "a", 0, &m), -EINVAL);
        CHECK(imp_projector_backend("modbus") != NULL);
        CHECK(imp_projector_backend("min") == NULL);
        return TEST_DONE();
}
