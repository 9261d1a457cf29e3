/* Round trip on the simulator (docs/import.md): config/scenes/small.cfg's dome sweep is
 * rendered into a capture set, exported as another rig would write it (16-bit PNG, .lp with
 * light positions, intensities), imported with `import photometric` and processed with
 * --photometric-only; its normals must be the native set's within 0.2° (mean), and both
 * near the truth. */
#include "bench-import-sim.h"
#include "compare-normals.h"
#include "import-photometric.h"
#include "process-photometric.h"
#include "test.h"

int main(void) {
        const char *base = test_tmpdir();
        char cap[512], stack[512], lp[600], inten[600], set[512], c_nat[512], c_imp[512], truth[600], mask[600];
        snprintf(cap, sizeof cap, "%s/capture", base);
        snprintf(stack, sizeof stack, "%s/stack", base);
        snprintf(lp, sizeof lp, "%s/lights.lp", stack);
        snprintf(inten, sizeof inten, "%s/intensities.txt", stack);
        snprintf(set, sizeof set, "%s/imported", base);
        snprintf(c_nat, sizeof c_nat, "%s/copy-native", base);
        snprintf(c_imp, sizeof c_imp, "%s/copy-imported", base);
        snprintf(truth, sizeof truth, "%s/truth-normals.exr", cap);
        snprintf(mask, sizeof mask, "%s/truth-mask.png", cap);
        struct imp_error err = {};
        struct sim_export_info info = {};
        int r = sim_dome_capture(IMPASTO_SOURCE_DIR "/config/scenes/small.cfg", 10000, cap, &err);
        CHECK_MSG(r >= 0, "capture: %s", err.msg);
        r = sim_export_stack(cap, stack, &info, &err);
        CHECK_MSG(r >= 0, "export: %s", err.msg);
        CHECK_NEAR(info.pixel_mm, 0.06, 1e-6);          /* 300 mm / fx 5000 */
        CHECK_NEAR(info.camera_distance_mm, 300, 1e-6);
        struct imp_import_photometric_options io;
        imp_import_photometric_options_default(&io);
        io.images_dir = stack, io.lp_path = lp, io.intensities_path = inten;
        io.pixel_mm = info.pixel_mm, io.camera_distance_mm = info.camera_distance_mm;
        r = imp_import_photometric(&io, set, &err);
        CHECK_MSG(r >= 0, "import: %s", err.msg);
        struct imp_po_options po;
        imp_po_options_default(&po);
        po.heights = false;
        r = imp_process_photometric(cap, c_nat, &po, &err);
        CHECK_MSG(r >= 0, "native: %s", err.msg);
        r = imp_process_photometric(set, c_imp, &po, &err);
        CHECK_MSG(r >= 0, "imported: %s", err.msg);
        struct imp_image *nat = NULL, *imp = NULL, *tn = NULL, *mk = NULL;
        CHECK_OK(imp_normals_read(c_nat, &nat, &err));
        CHECK_OK(imp_normals_read(c_imp, &imp, &err));
        CHECK_OK(imp_normals_read(truth, &tn, &err));
        CHECK_OK(imp_image_read(mask, &mk, &err));
        if (!nat || !imp || !tn || !mk)
                return TEST_DONE();
        struct imp_normals_cmp rt = {}, a = {}, b = {};
        CHECK_OK(imp_normals_compare(imp, nat, mk, &rt));
        CHECK_OK(imp_normals_compare(nat, tn, mk, &a));
        CHECK_OK(imp_normals_compare(imp, tn, mk, &b));
        fprintf(stderr, "round trip: mean %.4f° p90 %.4f° over %ld pixels; vs truth: native %.3f°, imported %.3f°\n",
                rt.mean_deg, rt.p90_deg, rt.n, a.mean_deg, b.mean_deg);
        CHECK_INT_EQ(rt.n, 320 * 240);
        CHECK_LE(rt.mean_deg, 0.2);
        CHECK_LE(rt.p90_deg, 0.2);
        /* both near the truth: 12 lights, noise on (0.54° measured) */
        CHECK_LE(a.mean_deg, 1.0);
        CHECK_LE(fabs(a.mean_deg - b.mean_deg), 0.05);
        imp_image_free(nat);
        imp_image_free(imp);
        imp_image_free(tn);
        imp_image_free(mk);
        return TEST_DONE();
}
