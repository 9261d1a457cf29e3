/* The re-read's Lanczos weights from one sin and one sincos per axis (lanczos_weights() in
 * pipeline/appearance/photometric.c, included here for its static functions) against the
 * kernel itself, kernel_weight() at every tap: for orders 1–4, plain and clamped, at
 * sub-pixel offsets over [0, 1) (a grid, the ends and the neighbours of the 1e-9 cut-off)
 * the weights and the normalised window agree within 1.5e-15 (a few units in the last place
 * of 1: both are as exact as double sins allow; a wrong sign or table entry is off by
 * more than 0.01). At offsets the fast form leaves to kernel_weight() (a sample on a
 * pixel) it declines, as it does for the cubic and prefiltered kernels. */
#include "../../pipeline/appearance/photometric.c"
#include "test.h"

static double max_diff, max_norm_diff;

static void compare(int kernel, int a, double f) {
        struct resample rs = { .a = a, .order = a, .kernel = kernel };
        double w[2 * PN_MAX_LANCZOS], ref[2 * PN_MAX_LANCZOS], s = 0, sr = 0;
        bool fast = lanczos_weights(&rs, f, w);
        CHECK_MSG(fast == (f >= 1e-9 && f <= 1 - 1e-9), "order %d f %.17g: fast form %s", a, f,
                  fast ? "taken" : "declined");
        if (!fast)
                return;
        for (int k = 0; k < 2 * a; k++) {
                ref[k] = kernel_weight(&rs, f + a - 1 - k);
                double d = fabs(w[k] - ref[k]);
                max_diff = fmax(max_diff, d);
                CHECK_MSG(d <= 1.5e-15, "order %d kernel %d f %.17g tap %d: %.17g vs %.17g", a, kernel, f, k, w[k],
                          ref[k]);
                s += w[k], sr += ref[k];
        }
        for (int k = 0; k < 2 * a; k++)
                max_norm_diff = fmax(max_norm_diff, fabs(w[k] / s - ref[k] / sr));
}

int main(void) {
        const double edge[] = { 0, 1e-9, nextafter(1e-9, 0), nextafter(1e-9, 1), 1e-6, 0.5, 1 - 1e-9,
                                nextafter(1 - 1e-9, 1), nextafter(1, 0) };
        for (int kernel = IMP_PN_KERNEL_LANCZOS; kernel <= IMP_PN_KERNEL_LANCZOS_CLAMPED; kernel++)
                for (int a = 1; a <= PN_MAX_LANCZOS; a++) {
                        for (int i = 0; i < 20000; i++)
                                compare(kernel, a, (i + 0.37) / 20000);
                        for (size_t i = 0; i < sizeof edge / sizeof edge[0]; i++)
                                compare(kernel, a, edge[i]);
                }
        CHECK_LE(max_norm_diff, 1.5e-15);
        fprintf(stderr, "largest difference from kernel_weight(): %.3g, normalised %.3g\n", max_diff, max_norm_diff);
        /* the other kernels, and a half width other than the order, stay with kernel_weight() */
        double w[2 * PN_MAX_LANCZOS];
        struct resample mitchell = { .a = 2, .order = 3, .kernel = IMP_PN_KERNEL_MITCHELL };
        struct resample pre = { .a = 3, .order = 2, .kernel = IMP_PN_KERNEL_PREFILTERED };
        CHECK(!lanczos_weights(&mitchell, 0.3, w));
        CHECK(!lanczos_weights(&pre, 0.3, w));
        return TEST_DONE();
}
