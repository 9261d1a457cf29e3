/* The "gpiod" dome backend (real libgpiod 1.6) against an emulated gpiochip0 answered by a
 * umockdev ioctl handler (sim/emu/emu-gpio.c): one line per LED, active-low honoured, one
 * light at a time, a failed set leaves every LED off, a busy line refuses the dome.
 * Needs the umockdev preload: without it the test re-executes itself under
 * umockdev-wrapper, and skips (77) when that is not installed. */
#include <unistd.h>
#include "dome.h"
#include "emu.h"
#include "unit/test.h"

#define N_LINES 16
#define BASE 4          /* light i is line BASE + i */
#define N_LIGHTS 8
#define ADDRESS "gpiochip0;lines=4-11;active_low=1"

static void reexec_under_umockdev(char **argv) {
        if (imp_emu_gpio_available())
                return;
        if (getenv("IMPASTO_UMOCKDEV_REEXEC"))
                TEST_SKIP("umockdev preload not active even under umockdev-wrapper");
        setenv("IMPASTO_UMOCKDEV_REEXEC", "1", 1);
        char *args[] = { "umockdev-wrapper", argv[0], NULL };
        execvp(args[0], args);
        TEST_SKIP("umockdev-wrapper not found (%m): cannot emulate /dev/gpiochip0");
}

/* Physical levels of the LED lines: with active-low wiring, lit = 0. */
static void check_only_lit(struct imp_emu_gpio *emu, int lit) {
        for (unsigned i = 0; i < N_LIGHTS; i++)
                CHECK_MSG(imp_emu_gpio_line_level(emu, BASE + i) == ((int) i == lit ? 0 : 1),
                          "line %u (light %u) at level %d, light %d should be the only one lit",
                          BASE + i, i, imp_emu_gpio_line_level(emu, BASE + i), lit);
}

int main(int argc, char **argv) {
        reexec_under_umockdev(argv);
        _cleanup_(imp_emu_rig_freep) struct imp_emu_rig *rig = NULL;
        CHECK_OK(imp_emu_rig_new(N_LIGHTS, &rig));
        _cleanup_(imp_emu_gpio_freep) struct imp_emu_gpio *emu = NULL;
        struct imp_emu_gpio_config cfg = { .n_lines = N_LINES, .light_line_base = BASE,
                                           .n_lights = N_LIGHTS, .leds_active_low = true };
        int r = imp_emu_gpio_new(&cfg, rig, &emu);
        CHECK_OK(r);
        if (r < 0)
                return TEST_DONE();

        struct imp_dome *d = NULL;
        CHECK_OK(imp_dome_open("gpiod", ADDRESS, 0, &d));
        if (!d)
                return TEST_DONE();
        struct imp_dome_info info;
        CHECK_OK(imp_dome_get_info(d, &info));
        CHECK_INT_EQ(info.n_lights, N_LIGHTS);
        CHECK_INT_EQ(info.n_axes, 0);
        /* Requested lines driven inactive (high, LEDs dark); the others untouched. */
        check_only_lit(emu, -1);
        CHECK_INT_EQ(imp_emu_gpio_line_level(emu, 0), -1);
        CHECK_INT_EQ(imp_emu_gpio_line_level(emu, BASE + N_LIGHTS), -1);

        CHECK_OK(imp_dome_set_light(d, 3, 1000, 0));
        check_only_lit(emu, 3);
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), 3);
        unsigned sets0 = imp_emu_gpio_n_set_calls(emu);
        CHECK_OK(imp_dome_set_light(d, 5, 1000, 0));
        check_only_lit(emu, 5);
        /* 3 went off in its own step before 5 came on: never both. */
        CHECK_INT_EQ(imp_emu_gpio_n_set_calls(emu) - sets0, 2);
        CHECK_INT_EQ(imp_emu_rig_max_lights_on(rig), 1);
        struct imp_dome_state st;
        CHECK_OK(imp_dome_get_state(d, &st));
        CHECK_INT_EQ(st.n_on, 1);
        CHECK_INT_EQ(st.level_permille[5], 1000);
        CHECK_ERR(imp_dome_move_to(d, 0, 1000, 100), -EINVAL);   /* no axes */

        /* The set that switches 5 off fails: the wrapper's all-off still leaves all dark. */
        imp_emu_gpio_fail_set_nth(emu, 1, EIO);
        CHECK_ERR(imp_dome_set_light(d, 2, 1000, 0), -EIO);
        CHECK_STR_CONTAINS(imp_dome_last_error(d), "light 5 off before light 2");
        CHECK(imp_dome_lights_known(d));
        check_only_lit(emu, -1);
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), -1);
        CHECK_OK(imp_dome_set_light(d, 2, 1000, 0));
        check_only_lit(emu, 2);
        imp_dome_close(d);
        d = NULL;
        /* Released lines are no longer driven (umockdev reports the closed fd a moment later). */
        for (int i = 0; i < 200 && imp_emu_gpio_line_level(emu, BASE + 2) != -1; i++)
                usleep(5000);
        CHECK_INT_EQ(imp_emu_gpio_line_level(emu, BASE + 2), -1);

        /* Another consumer holds light 4's line: the dome refuses, nothing is driven. */
        imp_emu_gpio_set_busy(emu, BASE + 4, true);
        CHECK_ERR(imp_dome_open("gpiod", ADDRESS, 0, &d), -EBUSY);
        CHECK(d == NULL);
        for (unsigned i = 0; i < N_LINES; i++)
                CHECK_INT_EQ(imp_emu_gpio_line_level(emu, i), -1);
        CHECK_INT_EQ(imp_emu_rig_lit_light(rig), -1);
        imp_emu_gpio_set_busy(emu, BASE + 4, false);

        /* Bad addresses. */
        CHECK_ERR(imp_dome_open("gpiod", "gpiochip0;lines=9-3", 0, &d), -EINVAL);
        CHECK_ERR(imp_dome_open("gpiod", "gpiochip0", 0, &d), -ENOENT);
        CHECK(imp_dome_open("gpiod", "gpiochip7;lines=0", 0, &d) < 0);
        (void) argc;
        return TEST_DONE();
}
