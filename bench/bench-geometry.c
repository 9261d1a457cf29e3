/* Geometry pipeline throughput on a synthetic 4-Mpix input (2048 × 2048): HDR merge of 3
 * exposures, triangulation (both projector coordinates), heightfield extraction and
 * resampling, relief boxes. Prints Mpix/s per stage, the CPU seconds of all threads and of
 * the main thread (what a stage runs on one core shows there: with OMP_WAIT_POLICY=passive
 * the waiting threads burn none, and the main thread's seconds are a stage's wall time on
 * free cores, whatever else the machine runs) and the peak RSS (getrusage). Input
 * generation is not timed. Usage: bench-geometry [side_px] (default 2048). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/resource.h>
#include <string.h>
#include <time.h>
#include "boxes.h"
#include "hdr.h"
#include "heightfield.h"
#include "triangulate.h"

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double clock_s(clockid_t id) {
        struct timespec ts;
        clock_gettime(id, &ts);
        return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double cpu0, main0;   /* process and main-thread CPU at the stage's start */

static void mark(void) {
        cpu0 = clock_s(CLOCK_PROCESS_CPUTIME_ID);
        main0 = clock_s(CLOCK_THREAD_CPUTIME_ID);
}

static double peak_rss_mib(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return ru.ru_maxrss / 1024.0;   /* Linux: kilobytes */
}

static double relief(double x, double y) { return 0.3 * sin(x / 4) * cos(y / 3); }

static void row(const char *stage, double mpix, double sec, double rss) {
        double cpu = clock_s(CLOCK_PROCESS_CPUTIME_ID) - cpu0, main_cpu = clock_s(CLOCK_THREAD_CPUTIME_ID) - main0;
        printf("| %-28s | %7.2f | %8.3f | %8.2f | %8.3f | %8.3f | %9.0f |\n", stage, mpix, sec, mpix / sec, cpu,
               main_cpu, rss);
}

int main(int argc, char **argv) {
        int side = argc > 1 ? atoi(argv[1]) : 2048;
        if (side < 64 || side > 8192) {
                fprintf(stderr, "side must be 64..8192\n");
                return 2;
        }
        double mpix = side * (double) side / 1e6;
        int r;
        printf("impasto geometry benchmark: %dx%d (%.2f Mpix)\n\n", side, side, mpix);
        printf("| %-28s | %7s | %8s | %8s | %8s | %8s | %9s |\n", "stage", "Mpix", "s", "Mpix/s", "CPU s", "main s",
               "RSS MiB");
        printf("|------------------------------|---------|----------|----------|----------|----------|-----------|\n");

        /* 1. HDR merge of 3 exposures (12-bit, mid-tone scene with a saturated corner). */
        struct imp_sensor s = { .bits = 12, .black_level_dn = 64, .gain_e_per_dn = 2, .read_noise_e = 3,
                                .full_well_e = 10000, .quantum_scale = 1e6 };
        struct imp_image *f[3];
        struct imp_hdr_exposure st[3];
        uint64_t z = 1;
        for (int k = 0; k < 3; k++) {
                double t_us = 250.0 * (1 << (2 * k));
                if ((r = imp_image_new(side, side, 1, IMP_PIX_U16, &f[k])) < 0)
                        return 1;
                st[k] = (struct imp_hdr_exposure) { .frame = f[k], .exposure_us = t_us };
                for (int y = 0; y < side; y++)
                        for (int x = 0; x < side; x++) {
                                z = z * 6364136223846793005ULL + 1442695040888963407ULL;
                                double V = 0.05 + 20.0 * x / side * y / side;
                                double e = V * s.quantum_scale * t_us * 1e-6;
                                e += sqrt(e + 9) * (((z >> 40) / 16777216.0) - 0.5) * 3.46;
                                double dn = fmin(fmax(round(e / s.gain_e_per_dn + 64), 0), 4095);
                                *imp_image_u16(f[k], x, y) = (uint16_t) dn;
                        }
        }
        struct imp_hdr_result hres = {};
        double t0 = now_s();
        mark();
        if ((r = imp_hdr_merge(st, 3, &s, NULL, &hres)) < 0)
                return 1;
        row("HDR merge (3 exposures)", mpix, now_s() - t0, peak_rss_mib());
        imp_hdr_result_done(&hres);
        for (int k = 0; k < 3; k++)
                imp_image_free(f[k]);

        /* 2. Triangulation: camera above, projector at 20°, distortion on both. */
        struct imp_pinhole cam = { .width = side, .height = side, .fx = side * 1.6, .fy = side * 1.6,
                                   .cx = 0.5 * (side - 1), .cy = 0.5 * (side - 1), .k1 = -0.05, .k2 = 0.01 };
        struct imp_pinhole proj = { .width = 1920, .height = 1080, .fx = 3000, .fy = 3000, .cx = 959.5, .cy = 539.5,
                                    .k1 = 0.03 };
        double eye_c[3] = { 0, 0, 600 }, eye_p[3] = { 600 * sin(0.349), 0, 600 * cos(0.349) };
        double tgt[3] = { 0, 0, 0 }, right[3] = { 1, 0, 0 };
        imp_pinhole_look_at(&cam, eye_c, tgt, right);
        imp_pinhole_look_at(&proj, eye_p, tgt, right);
        size_t N = (size_t) side * side;
        float *px = malloc(N * sizeof(float)), *py = malloc(N * sizeof(float));
        if (!px || !py)
                return 1;
        #pragma omp parallel for schedule(static)
        for (int y = 0; y < side; y++)
                for (int x = 0; x < side; x++) {
                        size_t i = (size_t) y * side + x;
                        double pix[2] = { x, y }, o[3], d[3], u[2];
                        imp_pinhole_ray_world(&cam, pix, o, d);
                        double lam = -o[2] / d[2];   /* intersect z = relief by 3 fixed-point steps */
                        for (int it = 0; it < 3; it++)
                                lam = (relief(o[0] + lam * d[0], o[1] + lam * d[1]) - o[2]) / d[2];
                        double X[3] = { o[0] + lam * d[0], o[1] + lam * d[1], o[2] + lam * d[2] };
                        px[i] = py[i] = -1;
                        if (imp_pinhole_project(&proj, X, u)) {
                                px[i] = (float) (u[0] + 0.5);
                                py[i] = (float) (u[1] + 0.5);
                        }
                }
        struct imp_projector_coords pc = { .width = side, .height = side, .proj_x = px, .proj_y = py };
        struct imp_range_image range = {};
        t0 = now_s();
        mark();
        if ((r = imp_triangulate(&cam, &proj, &pc, NULL, &range)) < 0)
                return 1;
        row("triangulation (x and y)", mpix, now_s() - t0, peak_rss_mib());
        free(px);
        free(py);

        /* 3. Heightfield. */
        struct imp_heightfield hf = {};
        t0 = now_s();
        mark();
        if ((r = imp_heightfield_from_range(&range, NULL, &hf)) < 0) {
                fprintf(stderr, "heightfield: %s\n", strerror(-r));
                return 1;
        }
        row("heightfield (range px)", mpix, now_s() - t0, peak_rss_mib());
        double hmpix = hf.nx * (double) hf.ny / 1e6;
        imp_range_image_done(&range);

        /* 4. Boxes. */
        struct imp_boxes b = {};
        t0 = now_s();
        mark();
        if ((r = imp_boxes_classify(&hf, NULL, &b)) < 0)
                return 1;
        row("relief boxes (texels)", hmpix, now_s() - t0, peak_rss_mib());
        printf("\nrange points %zu, heightfield %dx%d at %.4f mm, %zu boxes; peak RSS %.0f MiB\n",
               hf.n_range_points, hf.nx, hf.ny, hf.pitch_mm, b.n_boxes, peak_rss_mib());
        imp_boxes_done(&b);
        imp_heightfield_done(&hf);
        return 0;
}
