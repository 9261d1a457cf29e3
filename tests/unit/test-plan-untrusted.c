/* Scan plans from people who may not be trusted (impastod's clients): a plan read as text may
 * not @include (libconfig would open the file with the reader's rights and quote its name and
 * syntax errors), and a plan whose expansion explodes (every factor within its cap, their
 * product ~1e11 frames) is refused from the counts, before anything is allocated, with a
 * message naming the fields. The address space is capped at 1 GiB (outside ASan) so that the
 * unfixed expansion fails fast instead of taking the machine's memory. */
#include <sys/resource.h>
#include <time.h>
#include "plan.h"
#include "unit/test.h"

static void make_rig(struct imp_rig *rig, int width, int height) {
        *rig = (struct imp_rig) { .n_cameras = 1, .settle_us = 500 };
        struct imp_rig_camera *c = &rig->cameras[0];
        snprintf(c->name, sizeof c->name, "cam0");
        c->model = (struct imp_pinhole) { .width = width, .height = height, .fx = 100, .fy = 100, .cx = 32, .cy = 16,
                                          .R = { 1, 0, 0, 0, 1, 0, 0, 0, 1 }, .t = { 0, 0, 500 } };
        c->sensor = (struct imp_sensor) { .bits = 16, .gain_e_per_dn = 1, .full_well_e = 60000, .quantum_scale = 1,
                                          .readout_us = 1000 };
        rig->n_lights = 12;
        rig->lights = calloc(12, sizeof *rig->lights);
        for (int i = 0; i < 12; i++)
                rig->lights[i] = (struct imp_rig_light) { .id = i, .pos_mm = { 100.0 * i, 0, 500 }, .intensity = 1,
                                                          .colour = { 1, 1, 1 }, .axis = { 0, 0, -1 } };
}

static int load(const struct imp_rig *rig, const char *text, struct imp_plan **p, struct imp_error *e) {
        *p = NULL;
        *e = (struct imp_error) { 0 };
        return imp_plan_load_string(text, "client.cfg", rig, p, e);
}

static double now_ms(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec * 1e3 + ts.tv_nsec / 1e6;
}

static void test_include(const struct imp_rig *rig) {
        char secret[512];
        snprintf(secret, sizeof secret, "%s/secret.cfg", test_tmpdir());
        FILE *f = fopen(secret, "we");
        fputs("this is { not a plan\n", f);
        fclose(f);
        /* the directive before, indented, after other settings, in capitals */
        static const char *const before[] = { "", "  ", "dome = { exposures_us = [1.0]; };\n" };
        static const char *const directive[] = { "@include", "@include", "@INCLUDE" };
        static const char *const forms[] = { "plain", "indented", "capitals" };
        for (size_t i = 0; i < ARRAY_SIZE(forms); i++) {
                char text[1024];
                snprintf(text, sizeof text, "%s%s \"%s\"\n", before[i], directive[i], secret);
                struct imp_plan *p;
                struct imp_error e;
                int r = load(rig, text, &p, &e);
                CHECK_MSG(r == -EINVAL, "%s: %d (%s)", forms[i], r, e.msg);
                CHECK_STR_CONTAINS(e.msg, "@include");
                CHECK_STR_CONTAINS(e.msg, "client.cfg:");
                CHECK_MSG(!strstr(e.msg, "secret"), "%s: names the included file: %s", forms[i], e.msg);
                imp_plan_free(p);
        }
        /* The line of the directive is named. */
        struct imp_plan *p;
        struct imp_error e;
        CHECK_ERR(load(rig, "dome = { exposures_us = [1.0]; };\n\n@include \"/etc/passwd\"\n", &p, &e), -EINVAL);
        CHECK_STR_CONTAINS(e.msg, "client.cfg:3: @include");
        /* A file plan may still include (a person's own files, relative to the plan). */
        char part[512], main_plan[512];
        snprintf(part, sizeof part, "%s/part.cfg", test_tmpdir());
        snprintf(main_plan, sizeof main_plan, "%s/main.cfg", test_tmpdir());
        f = fopen(part, "we");
        fputs("dome = { exposures_us = [1000.0]; };\n", f);
        fclose(f);
        f = fopen(main_plan, "we");
        fputs("@include \"part.cfg\"\n", f);
        fclose(f);
        CHECK_OK(imp_plan_load(main_plan, rig, &p, &e));
        CHECK_INT_EQ(p ? imp_plan_count(p) : 0, 12);
        imp_plan_free(p);
}

static void test_bomb(const struct imp_rig *rig, const struct imp_rig *big_rig) {
        /* 149 bytes: 100000 tiles × 12 lights × 8 exposures × 10000 repeats = 9.6e10 frames. */
        const char *bomb = "tiles=100000;dome={lights=\"all\";repeat=10000;\n"
                           "exposures_us=[1.0,2.0,3.0,4.0,5.0,6.0,7.0,8.0];};\n";
        CHECK_LE(strlen(bomb), 150);
        struct imp_plan *p;
        struct imp_error e;
        double t0 = now_ms();
        int r = load(rig, bomb, &p, &e);
        double ms = now_ms() - t0;
        CHECK_MSG(r == -E2BIG, "bomb: %d (%s)", r, e.msg);
        CHECK_STR_CONTAINS(e.msg, "client.cfg: the plan expands to 9.6e+10 frames");
        CHECK_STR_CONTAINS(e.msg, "tiles 100000");
        CHECK_STR_CONTAINS(e.msg, "dome (lights × exposures_us × repeat)");
        fprintf(stderr, "bomb refused in %.3f ms: %s\n", ms, e.msg);
        imp_plan_free(p);
        /* Structured light and dark frames explode the same way. */
        CHECK_ERR(load(rig, "tiles=100000;dark={count=1000;};dome={lights=[0];exposures_us=[1.0,2.0,3.0,4.0,5.0,6.0,7.0,8.0];};\n",
                       &p, &e), -E2BIG);
        CHECK_STR_CONTAINS(e.msg, "dark.count");
        /* Within the frame cap but over the bytes on disk: 900000 frames of 200 MP, 360 TB. */
        CHECK_ERR(load(big_rig, "tiles=1000;dome={lights=[0];repeat=900;exposures_us=[1.0];};\n", &p, &e), -E2BIG);
        CHECK_STR_CONTAINS(e.msg, "bytes on disk");
        /* Just under the cap is accepted: 12 lights × 8 exposures × 10000 repeats = 960000. */
        CHECK_OK(load(rig, "dome={lights=\"all\";repeat=10000;exposures_us=[1.0,2.0,3.0,4.0,5.0,6.0,7.0,8.0];};\n",
                      &p, &e));
        CHECK_INT_EQ(p ? imp_plan_count(p) : 0, 960000);
        imp_plan_free(p);
}

int main(void) {
#if !defined(__SANITIZE_ADDRESS__)
        struct rlimit rl = { 1ULL << 30, 1ULL << 30 };
        (void) setrlimit(RLIMIT_AS, &rl);
#endif
        struct imp_rig rig, big;
        make_rig(&rig, 64, 32);
        make_rig(&big, 20000, 10000);
        test_include(&rig);
        test_bomb(&rig, &big);
        imp_rig_free(&rig);
        imp_rig_free(&big);
        return TEST_DONE();
}
