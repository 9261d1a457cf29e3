/* Throughput of the BTF stage with 64 lights on synthetic data, all cores (OpenMP):
 * (1) the per-texel Lafortune fit alone on precomputed samples of three materials,
 * (2) the tiled driver (sample extraction with shadow/hidden ray casting + fit + fill)
 * on a 256×256 heightfield, nearly flat (pitch 0.25 mm, ±0.2 mm) and rough like paint
 * (pitch 0.05 mm, ±1 mm: long shadow rays, many shadowed samples). Prints a table with
 * texels/s and peak RSS. --fit-only: (1) alone (for profiles). --checksum: an FNV-1a 64 of
 * every fitted texel of each fit-only case (one pass each) and of each grid: two builds
 * fit (and extract) bit-identically when their lines are equal. --grid: (2) alone (extraction profiles, e.g. under callgrind
 * with --toggle-collect=imp_btf_fit_grid). "mixed, 36 samples": the mixed texels thinned
 * to about the demo's sample count. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#include "btf.h"
#include "unit/btf-synth.h"

enum { NL = 64, TEXELS = 8192 };

static double now_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_MONOTONIC, &ts);
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static double cpu_s(void) {
        struct timespec ts;
        clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
        return ts.tv_sec + 1e-9 * ts.tv_nsec;
}

static long peak_rss_kb(void) {
        struct rusage ru;
        getrusage(RUSAGE_SELF, &ru);
        return ru.ru_maxrss;
}

static const struct imp_lafortune mats[3] = {
        { .rho_d = { 0.6f, 0.45f, 0.3f }, .cx = -1, .cy = -1, .cz = 1, .k = 10 },
        { .rho_d = { 0.35f, 0.3f, 0.25f }, .rho_s = { 0.4f, 0.4f, 0.4f }, .cx = -1, .cy = -1, .cz = 1, .k = 20 },
        { .rho_d = { 0.2f, 0.25f, 0.3f }, .rho_s = { 0.8f, 0.8f, 0.8f }, .cx = -1, .cy = -1, .cz = 1, .k = 100 },
};

static bool checksum;

static uint64_t fnv(uint64_t h, const void *p, size_t n) {
        const uint8_t *b = p;
        for (size_t i = 0; i < n; i++)
                h = (h ^ b[i]) * 0x100000001b3ull;
        return h;
}

/* thin: 9 of each 16 samples kept (≈ 36 of 64), about the demo capture's samples per
 * texel (49 fit lights, some shadowed): a count that is not a whole number of vectors. */
static void bench_fit(const struct imp_rig_light *L, int mat, bool thin, const char *name) {
        static struct imp_btf_sample s[TEXELS][NL];
        static int n[TEXELS];
        static struct imp_btf_texel out[TEXELS];
        const double eye[3] = { 0, 0, 300 }, up[3] = { 0, 0, 1 };
        uint64_t rng = 42;
        for (int i = 0; i < TEXELS; i++) {
                double P[3] = { -150.0 + 300.0 * synth_uniform(&rng), -150.0 + 300.0 * synth_uniform(&rng), 0 };
                n[i] = synth_samples(P, up, eye, L, NL, &mats[mat < 0 ? i % 3 : mat], 0.01, &rng, s[i]);
                if (thin) {
                        int m = 0;
                        for (int j = 0; j < n[i]; j++)
                                if (j % 16 < 9)
                                        s[i][m++] = s[i][j];
                        n[i] = m;
                }
        }
        struct imp_btf_fit_params fp;
        imp_btf_fit_params_default(&fp);
        int reps = 0;
        double t0 = now_s(), c0 = cpu_s(), t;
        do {
#pragma omp parallel for schedule(dynamic, 32)
                for (int i = 0; i < TEXELS; i++)
                        imp_btf_fit_texel(s[i], n[i], &fp, &out[i]);
                reps++;
                t = now_s() - t0;
        } while (t < 1.0 && !checksum);
        if (checksum) {
                uint64_t h = 0xcbf29ce484222325ull;
                for (int i = 0; i < TEXELS; i++)
                        h = fnv(h, &out[i], sizeof out[i]);
                printf("fit only, %-18s %016llx\n", name, (unsigned long long) h);
                return;
        }
        double c = cpu_s() - c0;
        printf("| fit only, %-18s | %8d | %10.0f | %9.2f | %10.0f |\n", name, TEXELS * reps, TEXELS * reps / t,
               1e6 * t / (TEXELS * reps), TEXELS * reps / c);
}

static void bench_grid(const struct imp_rig_light *L, bool rough) {
        enum { G = 256, CAM = 512 };
        float *h = calloc(G * G, sizeof *h), *nrm = calloc(3 * G * G, sizeof *nrm);
        struct imp_image *frames[NL] = { 0 };
        struct imp_btf_texel *tex = malloc(G * G * sizeof *tex);
        if (!h || !nrm || !tex)
                exit(1);
        const double pitch = rough ? 0.05 : 0.25;
        for (int i = 0; i < G * G; i++) {
                int u = i % G, v = i / G;
                nrm[3 * i + 2] = 1.0f;
                h[i] = (float) (0.2 * sin(i * 0.05) * cos(i / G * 0.07));   /* mild relief */
                if (rough)          /* brush ridges, ±1 mm over a few mm */
                        h[i] = (float) (0.6 * sin(u * 0.045) * cos(v * 0.06) + 0.4 * sin(0.11 * u + 0.07 * v));
        }
        if (rough)                  /* normals from central differences */
                for (int v = 0; v < G; v++)
                        for (int u = 0; u < G; u++) {
                                int ul = u > 0 ? u - 1 : u, ur = u < G - 1 ? u + 1 : u;
                                int vd = v > 0 ? v - 1 : v, vu = v < G - 1 ? v + 1 : v;
                                double gx = (h[v * G + ur] - h[v * G + ul]) / ((ur - ul) * pitch);
                                double gy = (h[vu * G + u] - h[vd * G + u]) / ((vu - vd) * pitch);
                                double nn = sqrt(gx * gx + gy * gy + 1.0);
                                float *q = &nrm[3 * (v * G + u)];
                                q[0] = (float) (-gx / nn);
                                q[1] = (float) (-gy / nn);
                                q[2] = (float) (1.0 / nn);
                        }
        struct imp_btf_heightfield hf = { .width = G, .height = G, .pitch_mm = pitch, .height_mm = h, .normal = nrm,
                .canvas_to_world = { 1, 0, 0, 30, 0, 1, 0, 10, 0, 0, 1, 0, 0, 0, 0, 1 } };
        struct imp_pinhole cam;
        const double eye[3] = { 0, 0, 300 }, target[3] = { 30 + 0.5 * G * pitch, 10 + 0.5 * G * pitch, 0 };
        synth_camera(&cam, eye, target, CAM, CAM, 2600.0);
        uint64_t rng = 3;
        for (int j = 0; j < NL; j++) {
                if (imp_image_new(CAM, CAM, 3, IMP_PIX_F32, &frames[j]) < 0)
                        exit(1);
                for (int y = 0; y < CAM; y++)
                        for (int x = 0; x < 3 * CAM; x++)
                                ((float *) imp_image_row(frames[j], y))[x] = (float) (0.3 + 0.01 * synth_gauss(&rng));
        }
        struct imp_btf_capture cap = { .camera = &cam, .lights = L, .n_lights = NL,
                                       .frames = (const struct imp_image *const *) frames };
        struct imp_btf_sample_params sp;
        struct imp_btf_fit_params fp;
        imp_btf_sample_params_default(&sp);
        imp_btf_fit_params_default(&fp);
        struct imp_btf_stats st;
        double t0 = now_s(), c0 = cpu_s();
        int r = imp_btf_fit_grid(&hf, &cap, &sp, &fp, 64, tex, &st);
        double t = now_s() - t0, c = cpu_s() - c0;
        if (checksum) {
                uint64_t hs = 0xcbf29ce484222325ull;
                for (int i = 0; i < G * G; i++)
                        hs = fnv(hs, &tex[i], sizeof tex[i]);
                printf("grid, %-6s (r=%d, samples %ld, shadowed %ld) %016llx\n", rough ? "rough" : "flat", r,
                       st.n_samples, st.n_shadowed, (unsigned long long) hs);
        } else {
                printf("| extract + fit + fill, %-6s | %8d | %10.0f | %9.2f | %10.0f |  (r=%d, hidden %ld, shadowed samples %ld)\n",
                       rough ? "rough" : "flat", G * G, G * G / t, 1e6 * t / (G * G), G * G / c, r, st.n_hidden,
                       st.n_shadowed);
        }
        for (int j = 0; j < NL; j++)
                imp_image_free(frames[j]);
        free(h);
        free(nrm);
        free(tex);
}

/* The memory goal of issue #5: a 4-Mpix × 64-light tile. A 2048 × 2048 heightfield at
 * 0.05 mm (rough, as bench_grid) under a 2048 × 2048 camera (one texel per pixel, 300 mm
 * above), with 64 HDR frames as the dome stage of `impasto process` holds them (f32, 1
 * channel mono or 3 colour, plus the u8 validity image), the whole-grid texel output,
 * normals and heights; the BTF stage (imp_btf_fit_grid: extraction + fit, one sample
 * buffer per thread) over `rows` rows of it (all rows: 2048; the stage's own buffers do
 * not grow with the rows). Frames are a semi-glossy material (ρd 0.5, ρs 0.3, k 20) shaded on the flat
 * plane with 1 % noise: the fit does real work. Prints time and peak RSS. */
static int bench_big(const struct imp_rig_light *L, int rows, int channels) {
        enum { G = 2048 };
        const double pitch = 0.05;
        size_t nt = (size_t) G * G;
        float *h = malloc(nt * sizeof *h), *nrm = malloc(3 * nt * sizeof *nrm);
        struct imp_btf_texel *tex = calloc(nt, sizeof *tex);
        struct imp_image *frames[NL] = { 0 }, *valid[NL] = { 0 };
        if (!h || !nrm || !tex)
                return 1;
        for (size_t i = 0; i < nt; i++) {
                int u = (int) (i % G), v = (int) (i / G);
                h[i] = (float) (0.6 * sin(u * 0.045) * cos(v * 0.06) + 0.4 * sin(0.11 * u + 0.07 * v));
        }
        for (int v = 0; v < G; v++)
                for (int u = 0; u < G; u++) {
                        int ul = u > 0 ? u - 1 : u, ur = u < G - 1 ? u + 1 : u, vd = v > 0 ? v - 1 : v, vu = v < G - 1 ? v + 1 : v;
                        double gx = (h[v * G + ur] - h[v * G + ul]) / ((ur - ul) * pitch);
                        double gy = (h[vu * G + u] - h[vd * G + u]) / ((vu - vd) * pitch), nn = sqrt(gx * gx + gy * gy + 1.0);
                        float *q = &nrm[3 * ((size_t) v * G + u)];
                        q[0] = (float) (-gx / nn), q[1] = (float) (-gy / nn), q[2] = (float) (1.0 / nn);
                }
        struct imp_pinhole cam;
        const double eye[3] = { 0.5 * G * pitch, 0.5 * G * pitch, 300 }, target[3] = { eye[0], eye[1], 0 };
        synth_camera(&cam, eye, target, G, G, 300.0 / pitch);
        const struct imp_lafortune mat = { .rho_d = { 0.5f, 0.5f, 0.5f }, .rho_s = { 0.3f, 0.3f, 0.3f },
                                           .cx = -1, .cy = -1, .cz = 1, .k = 20 };
        double t0 = now_s();
        for (int j = 0; j < NL; j++) {
                if (imp_image_new(G, G, channels, IMP_PIX_F32, &frames[j]) < 0 ||
                    imp_image_new(G, G, 1, IMP_PIX_U8, &valid[j]) < 0)
                        return 1;
#pragma omp parallel for schedule(static)
                for (int py = 0; py < G; py++) {
                        uint64_t rng = 1 + (uint64_t) j * G + py;
                        const double up[3] = { 0, 0, 1 };
                        for (int px = 0; px < G; px++) {
                                double P[3] = { eye[0] + (px - cam.cx) * pitch, eye[1] + (py - cam.cy) * pitch, 0 };
                                double v[3], l[3], ec, V = 0.0;
                                if (synth_geometry(P, up, eye, &L[j], v, l, &ec))
                                        V = ec * imp_lafortune_eval(&mat, 0, v, l) * (1.0 + 0.01 * synth_gauss(&rng));
                                float *q = imp_image_f32(frames[j], px, py);
                                for (int c = 0; c < channels; c++)
                                        q[c] = (float) V;
                                *imp_image_u8(valid[j], px, py) = 0;
                        }
                }
        }
        double t_render = now_s() - t0;
        long rss_frames = peak_rss_kb();
        /* canvas (u, v)·pitch + (0, 0, h) = world: the grid under the camera */
        struct imp_btf_heightfield hf = { .width = G, .height = rows, .pitch_mm = pitch, .height_mm = h, .normal = nrm,
                .canvas_to_world = { 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1 } };
        struct imp_btf_capture cap = { .camera = &cam, .lights = L, .n_lights = NL,
                                       .frames = (const struct imp_image *const *) frames,
                                       .valid = (const struct imp_image *const *) valid };
        struct imp_btf_sample_params sp;
        struct imp_btf_fit_params fp;
        imp_btf_sample_params_default(&sp);
        imp_btf_fit_params_default(&fp);
        struct imp_btf_stats st = { 0 };
        double c0 = cpu_s();
        t0 = now_s();
        int r = imp_btf_fit_grid(&hf, &cap, &sp, &fp, 64, tex, &st);
        double t = now_s() - t0, cpu = cpu_s() - c0;
        size_t fb = (size_t) NL * nt * (channels * sizeof(float) + 1);
        printf("4-Mpix tile: %d×%d texels, %d lights, %s frames (%.0f MB with validity), rendered in %.1f s\n", G, G, NL,
               channels == 1 ? "mono" : "colour", fb / 1048576.0, t_render);
        printf("BTF stage over %d rows (%d texels): r=%d, %.1f s wall, %.1f s CPU, %.0f texels/s wall, %.0f texels/s per CPU-second; "
               "samples %ld, shadowed %ld\n", rows, G * rows, r, t, cpu, G * rows / t, G * rows / cpu, st.n_samples, st.n_shadowed);
        printf("peak RSS: %.0f MB after the frames, %.0f MB after the stage (goal: 4096 MB)\n", rss_frames / 1024.0,
               peak_rss_kb() / 1024.0);
        for (int j = 0; j < NL; j++) {
                imp_image_free(frames[j]);
                imp_image_free(valid[j]);
        }
        free(h);
        free(nrm);
        free(tex);
        return r < 0;
}

int main(int argc, char **argv) {
        struct imp_rig_light L[NL];
        const double elev[4] = { 12, 30, 50, 70 }, c[3] = { 0, 0, 0 };
        synth_dome(L, elev, 4, 16, 500.0, c, 1.0, 0.0);
        if (argc > 1 && !strcmp(argv[1], "--big")) {
                /* bench-fit --big [ROWS [CHANNELS]]: the 4-Mpix × 64-light memory figure */
                int rows = argc > 2 ? atoi(argv[2]) : 2048, ch = argc > 3 ? atoi(argv[3]) : 1;
                const double cb[3] = { 51.2, 51.2, 0 };
                synth_dome(L, elev, 4, 16, 500.0, cb, 1.0, 0.0);
                if (rows < 1 || rows > 2048 || (ch != 1 && ch != 3)) {
                        fprintf(stderr, "usage: bench-fit [--big [ROWS 1..2048 [CHANNELS 1|3]]]\n");
                        return 2;
                }
                return bench_big(L, rows, ch);
        }
        int threads = 1;
#ifdef _OPENMP
        threads = omp_get_max_threads();
#endif
        checksum = argc > 1 && !strcmp(argv[1], "--checksum");
        bool fit_only = argc > 1 && !strcmp(argv[1], "--fit-only");
        if (!checksum)
                printf("BTF fit, %d lights, %d threads\n\n", NL, threads);
        /* texels per CPU-second: what one free core does; the machine is shared */
        if (!checksum) {
                printf("| case                         | texels   | texels/s   | µs/texel  | per CPU-s  |\n");
                printf("|------------------------------|----------|------------|-----------|------------|\n");
        }
        bool grid_only = argc > 1 && !strcmp(argv[1], "--grid");
        if (!grid_only) {
                bench_fit(L, 0, false, "matte");
                bench_fit(L, 1, false, "semi-glossy k=20");
                bench_fit(L, 2, false, "glossy k=100");
                bench_fit(L, -1, false, "mixed");
                bench_fit(L, -1, true, "mixed, 36 samples");
        }
        if (fit_only)
                return 0;
        bench_grid(L, false);
        bench_grid(L, true);
        if (checksum)
                return 0;
        printf("\npeak RSS: %.1f MB (of which the %d input frames 512×512 RGB f32: %.1f MB; fit-only "
               "sample arrays %.1f MB)\n", peak_rss_kb() / 1024.0, NL, NL * 512.0 * 512 * 12 / 1048576.0,
               (double) TEXELS * NL * sizeof(struct imp_btf_sample) / 1048576.0);
        return 0;
}
