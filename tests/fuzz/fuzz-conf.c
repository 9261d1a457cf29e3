/* Target 3: the configuration readers. The first byte picks the reader, the rest is the
 * file: 0 rig.json (imp_rig_from_json), 1 a scan plan against a small rig
 * (imp_plan_load_string, also what impastod reads from a client's plan path), 2 impastod.conf
 * (daemon/conf.c, night_conf_load) and 3 the rig config (daemon/rigcfg.c, rigcfg_load); 2 and
 * 3 only where the daemon is built (FUZZ_WITH_DAEMON). Checked: a refusal says why, and what
 * is accepted holds finite, in-range values. */
#include <math.h>
#include <string.h>
#include "fuzz.h"
#include "plan.h"
#include "rig.h"
#include "tiles.h"
#ifdef FUZZ_WITH_DAEMON
#include "impastod.h"
#include "night.h"
#endif

/* The rig the plans are expanded against: one 16 × 12 camera, a 32 × 24 projector, 2 lights. */
static const char small_rig[] =
        "{\"format\":\"impasto-rig\",\"version\":1,\"cameras\":[{\"name\":\"cam0\",\"model\":{\"width\":16,\"height\""
        ":12,\"fx\":68.58893249518748,\"fy\":68.58859661481284,\"cx\":7.9830112306093035,\"cy\":5.720429906"
        "628173,\"k1\":-0.07638511636835311,\"k2\":0.0,\"p1\":0.0002774164993867581,\"p2\":-0.0001362979489"
        "4447922,\"k3\":0.0,\"R\":[0.9999999814841007,-5.839905309041803e-06,-0.00019234784609124843,-5"
        ".791025543630089e-06,-0.9999999676944149,0.00025412129623231537,-0.00019234932392164572,-0"
        ".00025412017763574106,-0.9999999492123351],\"t\":[-29.95052893533064,19.94813318185196,300.0"
        "543119164772]},\"sensor\":{\"bits\":12,\"black_level_dn\":64.00243333333333,\"gain_e_per_dn\":2.50"
        "1654688788391,\"read_noise_e\":3.003423452101616,\"full_well_e\":10006.626051646406,\"dark_curr"
        "ent_e_per_s\":10.0,\"prnu\":0.005,\"quantum_scale\":600000.0,\"readout_us\":30000.0,\"bayer\":false"
        "}}],\"projector\":{\"name\":\"proj\",\"model\":{\"width\":32,\"height\":24,\"fx\":125.00124053266535,\"fy"
        "\":125.00379829638084,\"cx\":16.04682199149303,\"cy\":12.150957099493313,\"k1\":0.000780021893707"
        "5059,\"k2\":0.0,\"p1\":0.0004851863363354568,\"p2\":0.00023541962469341256,\"k3\":0.0,\"R\":[0.92736"
        "02086876614,-3.325224487905215e-05,-0.37416980401559047,0.0004898631848782885,-0.999999031"
        "1518172,0.0013029694881511419,-0.3741694848285163,-0.0013916140683258606,-0.92735929392735"
        "78],\"t\":[-27.98244514359186,19.585264383989443,311.2708914014937]},\"gamma\":2.1998072189230"
        "307,\"black_level\":0.010021429508924484,\"intensity\":0.072,\"defocus_px\":0.8},\"lights\":[{\"id\""
        ":0,\"pos_mm\":[513.0979624600649,19.97400558092238,129.52880434896556],\"intensity\":0.2002136"
        "0661112236,\"colour\":[1.0,1.0,1.0],\"axis\":[-0.9659258262890683,0.0,-0.2588190451025207],\"pr"
        "ofile_exp\":1.0},{\"id\":1,\"pos_mm\":[475.95286323048504,204.71419308161293,129.4710069515547]"
        ",\"intensity\":0.19969443851341107,\"colour\":[1.0,1.0,1.0],\"axis\":[-0.8923991008325228,-0.369"
        "6438106143861,-0.25881904510252074],\"profile_exp\":1.0}],\"settle_us\":2000.0}";

static void check_pinhole(const struct imp_pinhole *m, const char *what) {
        FUZZ_CHECK(m->width > 0 && m->height > 0, "%s: accepted a size of %dx%d", what, m->width, m->height);
        const double *v[] = { &m->fx, &m->fy, &m->cx, &m->cy, &m->k1, &m->k2, &m->p1, &m->p2, &m->k3 };
        for (size_t i = 0; i < sizeof v / sizeof v[0]; i++)
                FUZZ_CHECK(isfinite(*v[i]), "%s: accepted a non-finite intrinsic #%zu", what, i);
        FUZZ_CHECK(m->fx > 0 && m->fy > 0, "%s: accepted a focal length <= 0", what);
        for (int i = 0; i < 9; i++)
                FUZZ_CHECK(isfinite(m->R[i]), "%s: non-finite R", what);
        for (int i = 0; i < 3; i++)
                FUZZ_CHECK(isfinite(m->t[i]), "%s: non-finite t", what);
}

static void check_rig(const struct imp_rig *rig) {
        FUZZ_CHECK(rig->n_cameras >= 1 && rig->n_cameras <= 4, "accepted %d cameras", rig->n_cameras);
        for (int i = 0; i < rig->n_cameras; i++)
                check_pinhole(&rig->cameras[i].model, rig->cameras[i].name);
        if (rig->has_projector)
                check_pinhole(&rig->projector.model, "projector");
}

static void fuzz_rig(const char *text, size_t n) {
        json_error_t je;
        json_t *j = json_loadb(text, n, JSON_REJECT_DUPLICATES, &je);
        if (!j)
                return;
        struct imp_rig rig = {};
        struct imp_error err = {};
        int r = imp_rig_from_json(j, "rig.json", &rig, &err);
        if (r < 0)
                FUZZ_CHECK(err.msg[0], "rig refused (%d) without a message", r);
        else
                check_rig(&rig);
        imp_rig_free(&rig);
        json_decref(j);
}

static void fuzz_plan(const char *text) {
        static struct imp_rig rig;
        static bool loaded;
        struct imp_error err = {};
        if (!loaded) {
                json_t *j = json_loads(small_rig, 0, NULL);
                FUZZ_CHECK(j && imp_rig_from_json(j, "small rig", &rig, &err) == 0, "small rig: %s", err.msg);
                json_decref(j);
                loaded = true;
        }
        struct imp_plan *p = NULL;
        int r = imp_plan_load_string(text, "plan.cfg", &rig, &p, &err);
        if (getenv("FUZZ_VERBOSE"))
                fprintf(stderr, "plan: %d %s; %zu frames%s\n", r, err.msg, r < 0 ? 0 : imp_plan_count(p),
                        r < 0 || !imp_plan_tiles(p) ? "" : ", tiles");
        if (r < 0) {
                FUZZ_CHECK(err.msg[0], "plan refused (%d) without a message", r);
                return;
        }
        size_t n = imp_plan_count(p);
        FUZZ_CHECK(n <= IMP_PLAN_MAX_FRAMES, "plan of %zu frames accepted", n);
        for (size_t i = 0; i < n; i++) {
                const struct imp_frame_record *f = imp_plan_frame(p, i);
                FUZZ_CHECK(f->seq == (long long) i, "frame %zu has seq %lld", i, f->seq);
                FUZZ_CHECK(isfinite(f->exposure_us) && f->exposure_us > 0, "frame %zu: exposure %g us", i,
                           f->exposure_us);
                FUZZ_CHECK(isfinite(f->gain_db), "frame %zu: gain %g dB", i, f->gain_db);
                FUZZ_CHECK(f->light == -1 || (f->light >= 0 && f->light < 2), "frame %zu: light %d", i, f->light);
                FUZZ_CHECK(!strcmp(f->camera, "cam0"), "frame %zu: camera %s", i, f->camera);
        }
        if (imp_plan_tiles(p)) {
                /* what plan.estimate answers a client for a painting: finite figures */
                struct imp_plan_painting_opts o = { .speed_mm_s = IMP_PLAN_STAGE_SPEED_MM_S,
                                                    .settle_s = IMP_PLAN_SETTLE_S, .process_s = -1, .workers = 1 };
                json_t *est = imp_plan_painting_estimate_json(p, &rig, 1e6, &o);
                const char *key;
                json_t *v;
                json_object_foreach(est, key, v)
                        FUZZ_CHECK(!json_is_real(v) || isfinite(json_real_value(v)), "estimate: %s is %g", key,
                                   json_real_value(v));
                json_decref(est);
        }
        imp_plan_free(p);
}

#ifdef FUZZ_WITH_DAEMON
/* The one symbol of daemon/main.c the other daemon sources use; never reached from the
 * readers. */
void daemon_notify_status(struct daemon *d) {
        (void) d;
}

static void fuzz_daemon_conf(const char *text, size_t n) {
        const char *path = fuzz_write_file("impastod.conf", text, n);
        struct daemon *d = calloc(1, sizeof *d);
        char *argv[] = { "impastod", "--config", (char *) path, NULL };
        (void) night_conf_load(d, 3, argv, NULL);
        night_free(d);
        free(d);
}

static void fuzz_rigcfg(const char *text, size_t n) {
        const char *path = fuzz_write_file("rig.cfg", text, n);
        struct rigcfg *rc = NULL;
        struct imp_error err = {};
        int r = rigcfg_load(path, &rc, &err);
        if (r < 0) {
                FUZZ_CHECK(err.msg[0], "rig config refused (%d) without a message", r);
                return;
        }
        FUZZ_CHECK(rc->n_cameras >= 1, "rig config without cameras accepted");
        rigcfg_free(rc);
}
#endif

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
        if (size < 1)
                return 0;
        unsigned mode = data[0] % 4;
        /* the readers take NUL-terminated text */
        char *text = malloc(size);
        memcpy(text, data + 1, size - 1);
        text[size - 1] = '\0';
        switch (mode) {
        case 0:
                fuzz_rig(text, size - 1);
                break;
        case 1:
                fuzz_plan(text);
                break;
#ifdef FUZZ_WITH_DAEMON
        case 2:
                fuzz_daemon_conf(text, size - 1);
                break;
        case 3:
                fuzz_rigcfg(text, size - 1);
                break;
#endif
        default:
                break;
        }
        free(text);
        return 0;
}
