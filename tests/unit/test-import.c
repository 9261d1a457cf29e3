/* Import of photometric stacks (pipeline/model/import-photometric.h), photometric-only
 * processing (pipeline/process-photometric.h) and normal comparison
 * (pipeline/eval/compare-normals.h) on synthetic stacks: every malformed input answered
 * with an error naming the file (and line), the images folder left untouched, a tilted
 * Lambertian plane recovered from 8- and 16-bit images with distant and near lights. */
#include <dirent.h>
#include <errno.h>
#include <sys/stat.h>
#include "captureset.h"
#include "compare-normals.h"
#include "import-photometric.h"
#include "process-photometric.h"
#include "quality.h"
#include "test.h"

#define W 48
#define H 36
#define N_LIGHTS 12
#define DEG (M_PI / 180.0)

static const double plane_n[3] = { 0.25, -0.15, 0.956556 };   /* normalised in main */

static void light_dir(int i, double ret[3]) {
        double el = (i < 6 ? 30 : 60) * DEG, az = (i * 60 + (i >= 6 ? 30 : 0)) * DEG;
        ret[0] = cos(el) * cos(az);
        ret[1] = cos(el) * sin(az);
        ret[2] = sin(el);
}

static void write_text(const char *path, const char *text) {
        FILE *f = fopen(path, "w");
        if (!f || fputs(text, f) < 0 || fclose(f)) {
                perror(path);
                exit(2);
        }
}

/* A Lambertian plane of normal n and albedo 0.6 under distant lights; 8 or 16 bits. */
static void write_stack(const char *dir, int bits, const double n[3]) {
        mkdir(dir, 0755);
        char path[512], lp[8192];
        int len = snprintf(lp, sizeof lp, "%d\n", N_LIGHTS);
        double levels = bits == 8 ? 255 : 65535;
        for (int i = 0; i < N_LIGHTS; i++) {
                double l[3];
                light_dir(i, l);
                double v = 0.6 * fmax(0, n[0] * l[0] + n[1] * l[1] + n[2] * l[2]);
                struct imp_image *img;
                if (imp_image_new(W, H, 1, bits == 8 ? IMP_PIX_U8 : IMP_PIX_U16, &img) < 0)
                        exit(2);
                for (int y = 0; y < H; y++)
                        for (int x = 0; x < W; x++) {
                                double dn = round(v * 0.9 * levels);
                                if (bits == 8)
                                        *imp_image_u8(img, x, y) = (uint8_t) dn;
                                else
                                        *imp_image_u16(img, x, y) = (uint16_t) dn;
                        }
                snprintf(path, sizeof path, "%s/light%02d.%s", dir, i, i % 2 ? "png" : "tif");
                struct imp_error err = {};
                int r = i % 2 ? imp_png_write(path, img, &err) : imp_tiff_write(path, img, NULL, &err);
                imp_image_free(img);
                if (r < 0) {
                        fprintf(stderr, "%s\n", err.msg);
                        exit(2);
                }
                /* a Windows-style directory in front of the name, as some tools write */
                len += snprintf(lp + len, sizeof lp - len, "%slight%02d.%s %.6f %.6f %.6f\n", i == 3 ? "C:\\rti\\" : "",
                                i, i % 2 ? "png" : "tif", l[0], l[1], l[2]);
        }
        snprintf(path, sizeof path, "%s/lights.lp", dir);
        write_text(path, lp);
}

/* Names and sizes of a folder's entries, to check the import does not touch it. */
static long folder_digest(const char *dir) {
        DIR *d = opendir(dir);
        long sum = 0;
        struct dirent *e;
        while (d && (e = readdir(d))) {
                if (e->d_name[0] == '.')
                        continue;   /* "..": the test writes its bad files beside the folder */
                char p[1024];
                struct stat st;
                snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
                if (stat(p, &st) == 0)
                        sum += (long) st.st_size * 31 + (long) st.st_mtime + (long) strlen(e->d_name) * 7;
        }
        if (d)
                closedir(d);
        return sum;
}

static int import_with(const char *images, const char *lp, const char *inten, const char *mask, double pixel_mm,
                       enum imp_lp_kind kind, const char *out, struct imp_error *err) {
        struct imp_import_photometric_options o;
        imp_import_photometric_options_default(&o);
        o.images_dir = images, o.lp_path = lp, o.intensities_path = inten, o.mask_path = mask;
        o.pixel_mm = pixel_mm, o.kind = kind;
        imp_error_clear(err);
        return imp_import_photometric(&o, out, err);
}

/* A malformed .lp: the error code and the message's file:line and expectation. */
static void check_bad_lp(const char *base, const char *images, const char *text, enum imp_lp_kind kind,
                         const char *want_where, const char *want_what) {
        static int k;
        char lp[512], out[512];
        snprintf(lp, sizeof lp, "%s/bad%d.lp", base, k);
        snprintf(out, sizeof out, "%s/bad-out%d", base, k++);
        write_text(lp, text);
        struct imp_error err = {};
        int r = import_with(images, lp, NULL, NULL, 0, kind, out, &err);
        CHECK_MSG(r == -EBADMSG || r == -EINVAL || r == -ENOENT, "bad lp %s: r = %d", text, r);
        CHECK_STR_CONTAINS(err.msg, want_where);
        CHECK_STR_CONTAINS(err.msg, want_what);
}

static void test_bad_lights(const char *base, const char *images) {
        check_bad_lp(base, images, "x12\nlight00.tif 0 0 1\n", IMP_LP_AUTO, ":1:", "number of lights");
        check_bad_lp(base, images, "3\nlight00.tif 0 0 1\nlight01.png 0 0.6 0.8\n", IMP_LP_AUTO, ":3:",
                     "announces 3 lights, found 2");
        check_bad_lp(base, images, "1\nlight00.tif 0 0 1\nlight01.png 0 0.6 0.8\n", IMP_LP_AUTO, ":3:", "more rows");
        check_bad_lp(base, images, "2\nlight00.tif 0 abc 1\nlight01.png 0 0.6 0.8\n", IMP_LP_AUTO, ":2:",
                     "y: expected a finite number, got 'abc'");
        check_bad_lp(base, images, "2\nlight00.tif 0 0\nlight01.png 0 0.6 0.8\n", IMP_LP_AUTO, ":2:", "filename x y z");
        check_bad_lp(base, images, "2\nlight00.tif 0 0 1\nlight01.png 0 0.5 0.7\n", IMP_LP_AUTO, ":3:",
                     "neither a unit direction");
        check_bad_lp(base, images, "2\nlight00.tif 0 0 1\nlight01.png 0 0.5 0.7\n", IMP_LP_DIRECTIONS, ":3:",
                     "expected a unit vector");
        check_bad_lp(base, images, "2\nlight00.tif 0 0 1\nlight01.png 0 0.8 -0.6\n", IMP_LP_AUTO, ":3:",
                     "above the surface");
        check_bad_lp(base, images, "2\nlight00.tif 0 0 1\nmissing.png 0 0.6 0.8\n", IMP_LP_AUTO, ":3:",
                     "'missing.png' not found");
        check_bad_lp(base, images, "", IMP_LP_AUTO, "bad", "empty");
        /* positions need a pixel size */
        check_bad_lp(base, images, "2\nlight00.tif 0 0 500\nlight01.png 0 300 400\n", IMP_LP_AUTO, "lights are positions",
                     "--pixel-size");
}

static void test_bad_inputs(const char *base, const char *images) {
        char lp[512], it[512], out[512], img[512], mask[512];
        snprintf(lp, sizeof lp, "%s/lights.lp", images);
        struct imp_error err = {};
        /* intensities: too few lines, a bad number */
        snprintf(it, sizeof it, "%s/short.txt", base);
        write_text(it, "1 1 1\n1 1 1\n");
        snprintf(out, sizeof out, "%s/o-short", base);
        CHECK_ERR(import_with(images, lp, it, NULL, 0, IMP_LP_AUTO, out, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "2 intensity lines, expected one per light of the .lp (12)");
        snprintf(it, sizeof it, "%s/badnum.txt", base);
        write_text(it, "1 1 1\n1 x 1\n");
        snprintf(out, sizeof out, "%s/o-badnum", base);
        CHECK_ERR(import_with(images, lp, it, NULL, 0, IMP_LP_AUTO, out, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "badnum.txt:2: value 2");
        /* a mask of another size */
        struct imp_image *m;
        CHECK_OK(imp_image_new(W + 1, H, 1, IMP_PIX_U8, &m));
        snprintf(mask, sizeof mask, "%s/mask.png", base);
        CHECK_OK(imp_png_write(mask, m, &err));
        imp_image_free(m);
        snprintf(out, sizeof out, "%s/o-mask", base);
        CHECK_ERR(import_with(images, lp, NULL, mask, 0, IMP_LP_AUTO, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "mask is 49x36, the images 48x36");
        /* mixed sizes: a copy of the folder with one image replaced */
        char mixed[256];
        snprintf(mixed, sizeof mixed, "%s/mixed", base);
        write_stack(mixed, 16, plane_n);
        CHECK_OK(imp_image_new(W, H + 2, 1, IMP_PIX_U16, &m));
        snprintf(img, sizeof img, "%s/light05.png", mixed);
        CHECK_OK(imp_png_write(img, m, &err));
        imp_image_free(m);
        snprintf(lp, sizeof lp, "%s/lights.lp", mixed);
        snprintf(out, sizeof out, "%s/o-mixed", base);
        CHECK_ERR(import_with(mixed, lp, NULL, NULL, 0, IMP_LP_AUTO, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "light05.png: 48x38, but");
        CHECK_STR_CONTAINS(err.msg, "all images must be the same size");
        /* mixed depths */
        CHECK_OK(imp_image_new(W, H, 1, IMP_PIX_U8, &m));
        CHECK_OK(imp_png_write(img, m, &err));
        imp_image_free(m);
        snprintf(out, sizeof out, "%s/o-depth", base);
        CHECK_ERR(import_with(mixed, lp, NULL, NULL, 0, IMP_LP_AUTO, out, &err), -EINVAL);
        CHECK_STR_CONTAINS(err.msg, "8-bit, but");
}

/* Angle between the processed normal at (x, y) and n, degrees. */
static double normal_err_deg(const struct imp_image *est, int x, int y, const double n[3]) {
        const float *p = imp_image_f32(est, x, y);
        return acos(fmin(1.0, p[0] * n[0] + p[1] * n[1] + p[2] * n[2])) / DEG;
}

static void test_plane(const char *base, int bits, const double n[3]) {
        char images[256], lp[512], set[512], copy[512];
        snprintf(images, sizeof images, "%s/plane%d", base, bits);
        write_stack(images, bits, n);
        snprintf(lp, sizeof lp, "%s/lights.lp", images);
        snprintf(set, sizeof set, "%s/set%d", base, bits);
        snprintf(copy, sizeof copy, "%s/copy%d", base, bits);
        long before = folder_digest(images);
        struct imp_error err = {};
        CHECK_OK(import_with(images, lp, NULL, NULL, 0, IMP_LP_AUTO, set, &err));
        CHECK_INT_EQ(folder_digest(images), before);
        struct imp_captureset *cs = NULL;
        CHECK_OK(imp_captureset_open(set, &cs, &err));
        if (!cs)
                return;
        CHECK_INT_EQ(imp_captureset_count(cs), N_LIGHTS);
        const struct imp_rig *rig = imp_captureset_rig(cs);
        CHECK_INT_EQ(rig->n_lights, N_LIGHTS);
        CHECK_INT_EQ(rig->cameras[0].sensor.bits, bits);
        double l3[3];
        light_dir(3, l3);
        CHECK_NEAR(rig->lights[3].pos_mm[0] / IMP_IMPORT_ORTHO_DISTANCE_MM, l3[0], 1e-6);
        CHECK_NEAR(rig->lights[3].pos_mm[1] / IMP_IMPORT_ORTHO_DISTANCE_MM, l3[1], 1e-6);
        imp_captureset_close(cs);
        struct imp_po_options po;
        imp_po_options_default(&po);
        CHECK_OK(imp_process_photometric(set, copy, &po, &err));
        struct imp_image *est = NULL;
        CHECK_OK(imp_normals_read(copy, &est, &err));
        if (!est)
                return;
        /* 8 bits: quantisation of 0.6·cos θ·0.9·255 moves the normal by up to ~0.3° */
        double tol = bits == 8 ? 0.5 : 0.05;
        CHECK_LE(normal_err_deg(est, W / 2, H / 2, n), tol);
        CHECK_LE(normal_err_deg(est, 0, 0, n), tol);
        imp_image_free(est);
        /* heights: a plane of slope −nx/nz along x; the integrated relief must follow it */
        struct imp_image *hf = NULL;
        char path[600], **names = NULL;
        snprintf(path, sizeof path, "%s/heightfield.exr", copy);
        CHECK_OK(imp_exr_read(path, &hf, &names, &err));
        if (!hf)
                return;
        int hc = imp_image_channel_index(names, "height"), fc = imp_image_channel_index(names, "flags");
        CHECK_INT_GE(hc, 0);
        CHECK_INT_GE(fc, 0);
        double dz = imp_image_f32(hf, W - 2, H / 2)[hc] - imp_image_f32(hf, 1, H / 2)[hc];
        CHECK_NEAR(dz, -n[0] / n[2] * (W - 3) * 1.0, 0.02 * (W - 3));   /* pixel 1 mm (no --pixel-size) */
        CHECK_INT_EQ(imp_image_f32(hf, W / 2, H / 2)[fc], 0);
        imp_strv_free(names);
        imp_image_free(hf);
}

/* Robust vs Woodham on a plane whose lights include a shadowed (black) sample: the robust
 * solve trims it, plain least squares is pulled off. */
static void test_shadow_trim(const char *base) {
        double n[3] = { 0, 0, 1 };
        char images[256], lp[512], set[512], cr[512], cw[512], img[600];
        snprintf(images, sizeof images, "%s/shadow", base);
        write_stack(images, 16, n);
        struct imp_image *m = NULL;
        struct imp_error err = {};
        snprintf(img, sizeof img, "%s/light01.png", images);   /* light 1: a cast shadow, 20 % left */
        CHECK_OK(imp_png_read(img, &m, &err));
        for (int y = 0; m && y < H; y++)
                for (int x = 0; x < W; x++)
                        *imp_image_u16(m, x, y) = (uint16_t) (*imp_image_u16(m, x, y) / 5);
        CHECK_OK(imp_png_write(img, m, &err));
        imp_image_free(m);
        snprintf(lp, sizeof lp, "%s/lights.lp", images);
        snprintf(set, sizeof set, "%s/shadow-set", base);
        snprintf(cr, sizeof cr, "%s/shadow-robust", base);
        snprintf(cw, sizeof cw, "%s/shadow-woodham", base);
        CHECK_OK(import_with(images, lp, NULL, NULL, 0, IMP_LP_AUTO, set, &err));
        struct imp_po_options po;
        imp_po_options_default(&po);
        po.btf = po.heights = false;
        CHECK_OK(imp_process_photometric(set, cr, &po, &err));
        po.method = IMP_PO_WOODHAM;
        CHECK_OK(imp_process_photometric(set, cw, &po, &err));
        struct imp_image *er = NULL, *ew = NULL;
        CHECK_OK(imp_normals_read(cr, &er, &err));
        CHECK_OK(imp_normals_read(cw, &ew, &err));
        if (er && ew) {
                CHECK_LE(normal_err_deg(er, 5, 5, n), 0.05);
                CHECK_GE(normal_err_deg(ew, 5, 5, n), 2.0);
        }
        imp_image_free(er);
        imp_image_free(ew);
}

/* compare-normals: a 16-bit PNG (n + 1) / 2 against a float EXR tilted by 12°. */
static void test_compare(const char *base) {
        struct imp_image *a, *b;
        struct imp_error err = {};
        CHECK_OK(imp_image_new(8, 4, 3, IMP_PIX_U16, &a));
        CHECK_OK(imp_image_new(8, 4, 3, IMP_PIX_F32, &b));
        double t = 12 * DEG;
        for (int y = 0; y < 4; y++)
                for (int x = 0; x < 8; x++) {
                        uint16_t *p = imp_image_u16(a, x, y);
                        p[0] = p[1] = 32768, p[2] = 65535;                       /* (0, 0, 1) */
                        float *q = imp_image_f32(b, x, y);
                        q[0] = (float) sin(t), q[1] = 0, q[2] = (float) cos(t);
                        if (x == 7)
                                q[0] = q[1] = q[2] = 0;                          /* no normal */
                }
        char pa[512], pb[512];
        snprintf(pa, sizeof pa, "%s/a.png", base);
        snprintf(pb, sizeof pb, "%s/b.exr", base);
        static const char *const names[] = { "nx", "ny", "nz" };
        CHECK_OK(imp_png_write(pa, a, &err));
        CHECK_OK(imp_exr_write(pb, b, names, false, &err));
        imp_image_free(a);
        imp_image_free(b);
        struct imp_image *ra = NULL, *rb = NULL;
        CHECK_OK(imp_normals_read(pa, &ra, &err));
        CHECK_OK(imp_normals_read(pb, &rb, &err));
        struct imp_normals_cmp c = {};
        CHECK_OK(imp_normals_compare(ra, rb, NULL, &c));
        CHECK_INT_EQ(c.n, 7 * 4);
        CHECK_NEAR(c.mean_deg, 12, 0.01);    /* 16-bit quantisation: < 0.002° */
        CHECK_NEAR(c.median_deg, 12, 0.01);
        CHECK_NEAR(c.within_10deg, 0, 1e-9);
        CHECK_NEAR(c.within_20deg, 1, 1e-9);
        char bad[512];
        snprintf(bad, sizeof bad, "%s/a.jpg", base);
        CHECK_ERR(imp_normals_read(bad, &ra, &err), -ENOENT);
        imp_image_free(ra);
        imp_image_free(rb);
}

int main(void) {
        const char *base = test_tmpdir();
        double n[3], len = sqrt(plane_n[0] * plane_n[0] + plane_n[1] * plane_n[1] + plane_n[2] * plane_n[2]);
        for (int k = 0; k < 3; k++)
                n[k] = plane_n[k] / len;
        char images[300];
        snprintf(images, sizeof images, "%.250s/good", base);
        write_stack(images, 16, n);
        long before = folder_digest(images);
        test_bad_lights(base, images);
        test_bad_inputs(base, images);
        CHECK_INT_EQ(folder_digest(images), before);
        test_plane(base, 16, n);
        test_plane(base, 8, n);
        test_shadow_trim(base);
        test_compare(base);
        return TEST_DONE();
}
