/* OpenCV XML calibrations for `import sl` (pipeline/calib/cv/cv-procam-xml.h): the file
 * procam-calibration's calibrate.py writes, read into a rig; a missing key named; the
 * import fills the device sizes from the frames and --projector. */
#include <errno.h>
#include <sys/stat.h>
#include "captureset.h"
#include "cv-procam-xml.h"
#include "import-sl.h"
#include "test.h"

static const char xml_head[] =
        "<?xml version=\"1.0\"?>\n<opencv_storage>\n<img_shape>30 40</img_shape>\n<rms>0.25</rms>\n"
        "<cam_int type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt>\n"
        "  <data>1000. 0. 20.5 0. 1001. 15.5 0. 0. 1.</data></cam_int>\n"
        "<cam_dist type_id=\"opencv-matrix\"><rows>1</rows><cols>5</cols><dt>d</dt>\n"
        "  <data>-0.1 0.02 0.001 -0.002 0.003</data></cam_dist>\n"
        "<proj_int type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt>\n"
        "  <data>800. 0. 8. 0. 801. 4. 0. 0. 1.</data></proj_int>\n"
        "<proj_dist type_id=\"opencv-matrix\"><rows>1</rows><cols>5</cols><dt>d</dt>\n"
        "  <data>0.05 0. 0. 0. 0.</data></proj_dist>\n";
static const char xml_rot[] =
        "<roration type_id=\"opencv-matrix\"><rows>3</rows><cols>3</cols><dt>d</dt>\n"
        "  <data>1. 0. 0. 0. 1. 0. 0. 0. 1.</data></roration>\n";
static const char xml_trans[] =
        "<translation type_id=\"opencv-matrix\"><rows>3</rows><cols>1</cols><dt>d</dt>\n"
        "  <data>95.6 -622.9 -239.3</data></translation>\n";

static void write_text(const char *path, const char *a, const char *b, const char *c) {
        FILE *f = fopen(path, "w");
        if (!f || fprintf(f, "%s%s%s</opencv_storage>\n", a, b, c) < 0 || fclose(f))
                exit(2);
}

int main(void) {
        const char *base = test_tmpdir();
        char good[512], bad[512], frames[512], out[512];
        snprintf(good, sizeof good, "%s/calibration_result.xml", base);
        snprintf(bad, sizeof bad, "%s/no-translation.xml", base);
        write_text(good, xml_head, xml_rot, xml_trans);
        write_text(bad, xml_head, xml_rot, "");
        struct imp_error err = {};
        struct imp_rig rig = {};
        CHECK_OK(imp_cv_procam_xml_rig(good, &rig, &err));
        CHECK_NEAR(rig.cameras[0].model.fy, 1001, 1e-9);
        CHECK_NEAR(rig.cameras[0].model.k3, 0.003, 1e-12);
        CHECK_NEAR(rig.projector.model.cx, 8, 1e-9);
        CHECK_NEAR(rig.projector.model.t[1], -622.9, 1e-9);
        CHECK(rig.has_projector);
        CHECK_ERR(imp_cv_procam_xml_rig(bad, &(struct imp_rig) {}, &err), -EBADMSG);
        CHECK_STR_CONTAINS(err.msg, "no 'translation'");
        /* 16 frames of a 16×8 projector, 40×30 camera */
        snprintf(frames, sizeof frames, "%s/frames", base);
        mkdir(frames, 0755);
        for (int i = 0; i < 16; i++) {
                struct imp_image *img;
                char p[600];
                if (imp_image_new(40, 30, 1, IMP_PIX_U8, &img) < 0)
                        return 2;
                snprintf(p, sizeof p, "%s/graycode_%02d.png", frames, i);
                CHECK_OK(imp_png_write(p, img, &err));
                imp_image_free(img);
        }
        snprintf(out, sizeof out, "%s/set", base);
        struct imp_import_sl_options o = { frames, IMP_SL_ORDER_OPENCV_GRAYCODE, 16, 8, good, &rig };
        CHECK_OK(imp_import_sl(&o, out, &err));
        struct imp_captureset *cs = NULL;
        CHECK_OK(imp_captureset_open(out, &cs, &err));
        if (cs) {
                const struct imp_rig *r = imp_captureset_rig(cs);
                CHECK_INT_EQ(r->cameras[0].model.width, 40);
                CHECK_INT_EQ(r->cameras[0].model.height, 30);
                CHECK_INT_EQ(r->projector.model.width, 16);
                CHECK_NEAR(r->projector.model.t[2], -239.3, 1e-9);
                imp_captureset_close(cs);
        }
        imp_rig_free(&rig);
        return TEST_DONE();
}
