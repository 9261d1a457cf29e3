/* Photometric import benches (docs/import.md):
 *   bench-import export --scene FILE --out DIR [--exposure-us US]
 *       renders the scene's dome sweep (DIR/capture, with truth-normals.exr) and writes it as
 *       another rig would hand it over (DIR/stack: PNG + lights.lp + intensities.txt)
 *   bench-import woodham --scene FILE --work DIR [--exposure-us US]
 *       the same, then imports the stack and processes it twice — plain least-squares
 *       Lambertian photometric stereo (Woodham 1980) and `--photometric-only` — and prints
 *       both mean angular errors against the truth normals and their ratio
 *   bench-import native --capture SET --work DIR [--truth-normals FILE]
 *       the standard `impasto process` (structured light + dome) and `--photometric-only`
 *       on the same simulated capture set: their normals compared per camera pixel (the
 *       copy's texel under the pixel's point on the canvas plane). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include "bench-import-sim.h"
#include "numerics.h"
#include "compare-normals.h"
#include "import-photometric.h"
#include "heightfield.h"
#include "json-util.h"
#include "process.h"
#include "process-photometric.h"

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int cmp_deg(const void *a, const void *b) {
        double x = *(const double *) a, y = *(const double *) b;
        return (x > y) - (x < y);
}

static int export_stack(const char *scene, const char *work, double exposure_us, struct sim_export_info *info,
                        struct imp_error *err) {
        char cap[4200], stack[4200];
        snprintf(cap, sizeof cap, "%s/capture", work);
        snprintf(stack, sizeof stack, "%s/stack", work);
        int r = sim_dome_capture(scene, exposure_us, cap, err);
        if (r >= 0)
                r = sim_export_stack(cap, stack, info, err);
        return r;
}

/* Imports WORK/stack, processes it with `method`, compares with the truth. */
static int run_method(const char *work, const struct sim_export_info *info, enum imp_po_method method,
                      struct imp_normals_cmp *ret, double *ret_s, struct imp_error *err) {
        char stack[2048], lp[4200], inten[4200], set[4200], copy[4200], truth[4200], mask[4200];
        const char *name = method == IMP_PO_WOODHAM ? "woodham" : "robust";
        snprintf(stack, sizeof stack, "%s/stack", work);
        snprintf(lp, sizeof lp, "%s/lights.lp", stack);
        snprintf(inten, sizeof inten, "%s/intensities.txt", stack);
        snprintf(set, sizeof set, "%s/imported", work);
        snprintf(copy, sizeof copy, "%s/copy-%s", work, name);
        snprintf(truth, sizeof truth, "%s/capture/truth-normals.exr", work);
        snprintf(mask, sizeof mask, "%s/capture/truth-mask.png", work);
        struct imp_import_photometric_options io;
        imp_import_photometric_options_default(&io);
        io.images_dir = stack, io.lp_path = lp, io.intensities_path = inten;
        io.pixel_mm = info->pixel_mm, io.camera_distance_mm = info->camera_distance_mm;
        int r = 0;
        if (method == IMP_PO_ROBUST || access(set, F_OK) != 0)
                r = imp_import_photometric(&io, set, err);
        struct imp_po_options po;
        imp_po_options_default(&po);
        po.method = method;
        po.btf = false;
        po.heights = method == IMP_PO_ROBUST;
        double t0 = now_s();
        if (r < 0 || (r = imp_process_photometric(set, copy, &po, err)) < 0)
                return r;
        *ret_s = now_s() - t0;
        _cleanup_image_ struct imp_image *est = NULL, *tn = NULL, *mk = NULL;
        if ((r = imp_normals_read(copy, &est, err)) < 0 || (r = imp_normals_read(truth, &tn, err)) < 0 ||
            (r = imp_image_read(mask, &mk, err)) < 0)
                return r;
        r = imp_normals_compare(est, tn, mk, ret);
        return r < 0 ? imp_error_set(err, r, "compare: %s", strerror(-r)) : 0;
}

/* Channel `name` of an EXR at (x, y). */
static float chan(const struct imp_image *img, int c, int x, int y) {
        return imp_image_f32(img, x, y)[c];
}

/* The integrated heights against the truth, over pixels both have: RMS after removing the
 * mean (the integration's free constant) and after removing a best-fit plane (a tilt from
 * a normal bias), mm. */
static int height_error(const char *copy, const char *truth, double *ret_rms_mean, double *ret_rms_plane,
                        struct imp_error *err) {
        char path[4200];
        snprintf(path, sizeof path, "%.4000s/heightfield.exr", copy);
        _cleanup_image_ struct imp_image *a = NULL, *b = NULL;
        char **na = NULL, **nb = NULL;
        int r = imp_exr_read(path, &a, &na, err);
        if (r >= 0)
                r = imp_exr_read(truth, &b, &nb, err);
        int ha = r >= 0 ? imp_image_channel_index(na, "height") : -1, ma = r >= 0 ? imp_image_channel_index(na, "mask") : -1;
        int hb = r >= 0 ? imp_image_channel_index(nb, "height") : -1;
        imp_strv_free(na);
        imp_strv_free(nb);
        if (r < 0)
                return r;
        if (ha < 0 || ma < 0 || hb < 0)
                return imp_error_set(err, -EINVAL, "%s / %s: no height channel", path, truth);
        /* least squares d = c0 + c1 x + c2 y on the difference */
        double M[9] = {}, v[3] = {}, sum = 0, ss = 0;
        long n = 0;
        for (int y = 0; y < a->height; y++)
                for (int x = 0; x < a->width; x++) {
                        double d = chan(a, ha, x, y) - chan(b, hb, x, y), f[3] = { 1, x, y };
                        if (!(chan(a, ma, x, y) > 0) || !isfinite(d))
                                continue;
                        for (int j = 0; j < 3; j++) {
                                v[j] += f[j] * d;
                                for (int k = 0; k < 3; k++)
                                        M[3 * j + k] += f[j] * f[k];
                        }
                        sum += d, ss += d * d, n++;
                }
        if (n < 3)
                return imp_error_set(err, -ENODATA, "%s: no height to compare", copy);
        double lam[3], vec[9], c[3] = {};
        imp_eigen_sym3(M, lam, vec);
        for (int e = 0; e < 3; e++) {
                double p = (vec[3 * e] * v[0] + vec[3 * e + 1] * v[1] + vec[3 * e + 2] * v[2]) / lam[e];
                for (int k = 0; k < 3; k++)
                        c[k] += p * vec[3 * e + k];
        }
        double sp = 0;
        for (int y = 0; y < a->height; y++)
                for (int x = 0; x < a->width; x++) {
                        double d = chan(a, ha, x, y) - chan(b, hb, x, y);
                        if (chan(a, ma, x, y) > 0 && isfinite(d))
                                sp += (d - c[0] - c[1] * x - c[2] * y) * (d - c[0] - c[1] * x - c[2] * y);
                }
        *ret_rms_mean = sqrt(fmax(0, ss / n - (sum / n) * (sum / n)));
        *ret_rms_plane = sqrt(sp / n);
        return 0;
}

static int woodham(const char *scene, const char *work, double exposure_us) {
        struct imp_error err = {};
        struct sim_export_info info;
        struct imp_normals_cmp w, rb;
        double tw = 0, tr = 0;
        int r = export_stack(scene, work, exposure_us, &info, &err);
        if (r >= 0)
                r = run_method(work, &info, IMP_PO_ROBUST, &rb, &tr, &err);
        if (r >= 0)
                r = run_method(work, &info, IMP_PO_WOODHAM, &w, &tw, &err);
        if (r < 0) {
                fprintf(stderr, "bench-import: %s\n", err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        printf("scene %s: %d lights, %dx%d pixels (%.4f mm), %ld compared\n", scene, info.n_lights, info.width,
               info.height, info.pixel_mm, rb.n);
        printf("%-22s %9s %9s %9s %9s %9s %8s\n", "method", "mean_deg", "median", "p90", "<10deg", "<20deg", "seconds");
        printf("%-22s %9.3f %9.3f %9.3f %9.4f %9.4f %8.2f\n", "woodham (plain LS)", w.mean_deg, w.median_deg,
               w.p90_deg, w.within_10deg, w.within_20deg, tw);
        printf("%-22s %9.3f %9.3f %9.3f %9.4f %9.4f %8.2f\n", "photometric-only", rb.mean_deg, rb.median_deg,
               rb.p90_deg, rb.within_10deg, rb.within_20deg, tr);
        printf("ratio woodham / photometric-only (mean): %.2f\n", rb.mean_deg > 0 ? w.mean_deg / rb.mean_deg : 0);
        char copy[4200], truth[4200];
        double hm = 0, hp = 0;
        snprintf(copy, sizeof copy, "%s/copy-robust", work);
        snprintf(truth, sizeof truth, "%s/capture/truth-normals.exr", work);
        if (height_error(copy, truth, &hm, &hp, &err) < 0) {
                fprintf(stderr, "bench-import: %s\n", err.msg);
                return 1;
        }
        printf("photometric-only heights (integrated normals) vs truth: rms %.1f um after the mean, %.1f um after a plane\n",
               hm * 1000, hp * 1000);
        return 0;
}

/* Normal of the standard copy under pixel (x, y), in the image frame; false off its mask. */
static bool copy_normal_at(const struct imp_image *hf, int cnx, int cny, int cmask, const double c2w[16], double pitch,
                           const struct imp_pinhole *cam, int x, int y, double ret[3]) {
        double X[3], q[3];
        if (!imp_po_pixel_point(cam, x, y, X))
                return false;
        for (int j = 0; j < 3; j++)   /* canvas = Rᵀ (X − t) */
                q[j] = c2w[j] * (X[0] - c2w[3]) + c2w[4 + j] * (X[1] - c2w[7]) + c2w[8 + j] * (X[2] - c2w[11]);
        int u = (int) lround(q[0] / pitch), v = (int) lround(q[1] / pitch);
        if (u < 0 || v < 0 || u >= hf->width || v >= hf->height || !(imp_image_f32(hf, u, v)[cmask] > 0))
                return false;
        double nx = imp_image_f32(hf, u, v)[cnx], ny = imp_image_f32(hf, u, v)[cny];
        double n[3] = { nx, ny, sqrt(fmax(0, 1 - nx * nx - ny * ny)) }, w[3], c[3];
        for (int j = 0; j < 3; j++)
                w[j] = c2w[4 * j] * n[0] + c2w[4 * j + 1] * n[1] + c2w[4 * j + 2] * n[2];
        for (int j = 0; j < 3; j++)
                c[j] = cam->R[3 * j] * w[0] + cam->R[3 * j + 1] * w[1] + cam->R[3 * j + 2] * w[2];
        ret[0] = c[0], ret[1] = -c[1], ret[2] = -c[2];
        return true;
}

/* Angle between unit a and b (b normalised here), degrees. */
static double angle_deg(const float *a, const double *b) {
        double dot = (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) / sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
        return acos(fmax(-1, fmin(1, dot))) * 180 / M_PI;
}

static int native(const char *capture, const char *work, const char *truth_path) {
        char full[4200], po_dir[4200], path[4200];
        snprintf(full, sizeof full, "%.4000s/copy-standard", work);
        snprintf(po_dir, sizeof po_dir, "%.4000s/copy-photometric-only", work);
        struct imp_error err = {};
        struct imp_process_options o;
        struct imp_po_options po;
        imp_process_options_default(&o);
        imp_po_options_default(&po);
        po.btf = po.heights = false;
        struct imp_po_dome d = {};
        _cleanup_image_ struct imp_image *hf = NULL, *est = NULL, *truth = NULL;
        char **names = NULL;
        _cleanup_json_ json_t *cj = NULL;
        snprintf(path, sizeof path, "%.4000s/heightfield.exr", full);
        int r = imp_process_capture(capture, full, &o, &err);
        if (r >= 0 && (r = imp_process_photometric(capture, po_dir, &po, &err)) >= 0 &&
            (r = imp_exr_read(path, &hf, &names, &err)) >= 0 && (r = imp_normals_read(po_dir, &est, &err)) >= 0) {
                snprintf(path, sizeof path, "%.4000s/copy.json", full);
                r = imp_json_load(path, &cj, &err);
        }
        if (r >= 0)
                r = imp_po_dome_load(capture, &d, &err);
        if (r >= 0 && truth_path)
                r = imp_normals_read(truth_path, &truth, &err);
        if (r < 0) {
                imp_strv_free(names);
                fprintf(stderr, "bench-import: %s\n", err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        int cnx = imp_image_channel_index(names, "nx"), cny = imp_image_channel_index(names, "ny");
        int cmask = imp_image_channel_index(names, "mask");
        imp_strv_free(names);
        double c2w[16], pitch = json_real_value(json_object_get(cj, "pitch_mm")), sum = 0;
        for (int i = 0; i < 16; i++)
                c2w[i] = json_number_value(json_array_get(json_object_get(cj, "canvas_to_world"), (size_t) i));
        long n = 0;
        double sum_std = 0, sum_po = 0;
        _cleanup_free_ double *e = malloc((size_t) est->width * est->height * sizeof *e);
        for (int y = 0; e && y < est->height; y++)
                for (int x = 0; x < est->width; x++) {
                        double nc[3];
                        const float *p = imp_image_f32(est, x, y);
                        if (!copy_normal_at(hf, cnx, cny, cmask, c2w, pitch, &d.camera.model, x, y, nc))
                                continue;
                        if (truth) {
                                const float *t = imp_image_f32(truth, x, y);
                                double pd[3] = { p[0], p[1], p[2] };
                                if (!isfinite(t[0]))
                                        continue;
                                sum_std += angle_deg(t, nc);
                                sum_po += angle_deg(t, pd);
                        }
                        e[n] = angle_deg(p, nc);
                        sum += e[n++];
                }
        imp_po_dome_done(&d);
        if (!e || n == 0) {
                fprintf(stderr, "bench-import: no pixel in both copies\n");
                return 1;
        }
        qsort(e, (size_t) n, sizeof *e, cmp_deg);
        printf("standard process vs --photometric-only normals over %ld pixels: mean %.3f deg, median %.3f deg, "
               "p90 %.3f deg\n", n, sum / n, e[n / 2], e[(size_t) (0.9 * (n - 1))]);
        if (truth)
                printf("against the truth over the same pixels: standard %.3f deg mean, photometric-only %.3f deg mean\n",
                       sum_std / n, sum_po / n);
        return 0;
}

int main(int argc, char **argv) {
        const char *scene = NULL, *dir = NULL, *capture = NULL, *truth = NULL;
        double exposure_us = 10000;
        for (int i = 2; i + 1 < argc; i += 2) {
                if (!strcmp(argv[i], "--scene"))
                        scene = argv[i + 1];
                else if (!strcmp(argv[i], "--out") || !strcmp(argv[i], "--work"))
                        dir = argv[i + 1];
                else if (!strcmp(argv[i], "--truth-normals"))
                        truth = argv[i + 1];
                else if (!strcmp(argv[i], "--capture"))
                        capture = argv[i + 1];
                else if (!strcmp(argv[i], "--exposure-us"))
                        exposure_us = atof(argv[i + 1]);
        }
        if (argc >= 2 && !strcmp(argv[1], "native") && capture && dir)
                return native(capture, dir, truth);
        if (argc < 2 || !scene || !dir || !(exposure_us > 0)) {
                fprintf(stderr, "usage: bench-import export|woodham --scene FILE --out|--work DIR [--exposure-us US]\n"
                                "       bench-import native --capture SET --work DIR [--truth-normals FILE]\n");
                return 2;
        }
        if (!strcmp(argv[1], "woodham"))
                return woodham(scene, dir, exposure_us);
        struct imp_error err = {};
        struct sim_export_info info;
        int r = export_stack(scene, dir, exposure_us, &info, &err);
        if (r < 0) {
                fprintf(stderr, "bench-import: %s\n", err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        printf("impasto import photometric --images %s/stack --lights %s/stack/lights.lp --intensities "
               "%s/stack/intensities.txt --pixel-size %.9g --camera-distance %.9g --out %s/imported\n",
               dir, dir, dir, info.pixel_mm, info.camera_distance_mm, dir);
        return 0;
}
