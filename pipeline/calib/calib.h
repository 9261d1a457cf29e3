/* Projector–camera calibration results (Moreno & Taubin 2012): the C-side structs the
 * OpenCV shim (pipeline/calib/cv/cv-calib.h) fills, their JSON form, a readable summary and the
 * conversion to the rig model. Pure C, no OpenCV; usable from C++ (extern "C").
 * Units: pixels for image quantities, the board's square unit for translations. */
#pragma once
#include <float.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <jansson.h>

#ifdef __cplusplus
extern "C" {
#endif
#include "error.h"
#include "image.h"

/* Intrinsic parameter order everywhere (OpenCV's): fx fy cx cy k1 k2 p1 p2 k3. */
#define IMP_CALIB_N_INTR        9
#define IMP_CALIB_MAX_CAPTURES  64
#define IMP_CALIB_MAX_WARNINGS  24
#define IMP_CALIB_WARNING_LEN   256

/* A relative 1σ of fx or fy above this means the focal length is not determined by the
 * views (e.g. every board fronto-parallel): flagged, warned, never reported as confident. */
#define IMP_CALIB_FOCAL_REL_STD_MAX     0.01
/* When no view tilts the board more than this from fronto-parallel, the focal length is
 * unobservable (f/Z scale ambiguity, Zhang 2000) whatever the local covariance claims:
 * near that degeneracy the fit wanders to a wrong f with a deceptively small σ. Flagged,
 * and σ(fx), σ(fy) are inflated to |f| (100 %) in std and cov. */
#define IMP_CALIB_MIN_TILT_DEG          10.0
/* A 1σ of cx or cy above this many pixels: principal point not determined. */
#define IMP_CALIB_PP_STD_MAX_PX         20.0
/* Fewer usable views than this is an error for the procam calibration. */
#define IMP_CALIB_MIN_VIEWS             3

enum {
        IMP_CALIB_FOCAL_UNDETERMINED = 1u << 0,  /* rel. std of fx/fy > IMP_CALIB_FOCAL_REL_STD_MAX */
        IMP_CALIB_PP_UNDETERMINED    = 1u << 1,  /* std of cx/cy > IMP_CALIB_PP_STD_MAX_PX */
        IMP_CALIB_FEW_VIEWS          = 1u << 2,  /* fewer than IMP_CALIB_MIN_VIEWS views */
        IMP_CALIB_RANK_DEFICIENT     = 1u << 3,  /* normal matrix singular: pseudo-inverse with
                                                    floored eigenvalues, so the std values are
                                                    huge (finite) placeholders, not data */
};

/* One set of planar-target observations: n object points (board frame, z = 0, square
 * units) and their n image points (pixels). Arrays are borrowed, not owned. */
struct imp_calib_view {
        int n;
        const double *obj;      /* 3n */
        const double *img;      /* 2n */
};

/* What the intrinsics fit estimates (imp_cv_calib_intrinsics_fit). */
enum {
        /* Hold k3 at 0 (OpenCV's CALIB_FIX_K3): a narrow field of view (the demo camera's is
         * 13°) does not determine the 6th-order term, which then soaks up noise and the
         * principal point (k3 = 145 against a true 0 on the simulated rig). */
        IMP_CALIB_FIT_FIX_K3 = 1u << 0,
        /* Hold k2 at 0 too (CALIB_FIX_K2): on the 16° demo camera k2 came out at −0.98 ± 1.6
         * against a true 0.02, harmless where the boards were but 0.2–0.4 px wrong beyond them,
         * in the corners of the view where the light calibration's mirrors sit (docs/calibration.md,
         * "Distortion terms a narrow lens cannot determine"). */
        IMP_CALIB_FIT_FIX_K2 = 1u << 1,
};
enum { IMP_CALIB_K3_AUTO = 0, IMP_CALIB_K3_FIT, IMP_CALIB_K3_FIX };
/* Below this diagonal field of view (first estimated with k3 = 0) IMP_CALIB_K3_AUTO keeps k3
 * at 0: at the image corner r⁶ is then < 3e-5 (the demo camera: 16°, the demo projector 18°;
 * fitted, k3 came out at 145 and −252 against a true 0), and the term cannot be told apart
 * from k1, k2. Wider devices (the real captures' 27° camera, 37° projector) fit it. */
#define IMP_CALIB_K3_MIN_FOV_DEG        20.0
/* Below this diagonal field of view IMP_CALIB_K3_AUTO in opts.k2 holds k2 at 0 as well: at
 * the corner of a 16° view r⁴ = 4e-4, so k2 moves a point by f·r⁵ = 0.3 px per unit of k2 —
 * a typical long lens's k2 (|k2| ≲ 0.1) by ≲ 0.03 px, while fitted from boards that never
 * fill the view it wandered by ±1.6 (1σ). The bias held: |k2|·f·r_c⁵ at the corner. */
#define IMP_CALIB_K2_MIN_FOV_DEG        20.0

/* A calibrated pinhole device with Brown–Conrady distortion (OpenCV's model). */
struct imp_calib_intrinsics {
        int width, height;                      /* pixels */
        double fx, fy, cx, cy;                  /* pixels */
        double dist[5];                         /* k1 k2 p1 p2 k3 */
        bool k3_fixed;                          /* k3 held at 0, not estimated (std, cov 0) */
        bool k2_fixed;                          /* k2 likewise (IMP_CALIB_FIT_FIX_K2) */
        double rms_px;                          /* RMS reprojection error over all points */
        double worst_px;                        /* largest single point residual */
        int worst_view, worst_point;            /* where it is */
        int n_views, n_points;
        /* First-order uncertainty: cov = σ² (JᵀJ)⁻¹ over intrinsics and every view's pose,
         * σ² = Σr² / (N − P) with N points and P parameters (OpenCV's convention, which is
         * conservative: the textbook 2N − P gives smaller values); this is the intrinsics
         * block (extrinsics marginalised). */
        double std[IMP_CALIB_N_INTR];           /* OpenCV's stdDeviationsIntrinsics */
        double cov[IMP_CALIB_N_INTR * IMP_CALIB_N_INTR];
        double sigma_px;                        /* σ, the residual scale used above */
        /* 1σ (worst direction) uncertainty of where a fixed camera-frame point reprojects,
         * for the point seen at the image centre and at the image corner (0, 0):
         * Σq = Jθ cov Jθᵀ, Jθ = ∂(projection)/∂(intrinsics). See docs/calibration.md. */
        double proj_unc_centre_px, proj_unc_corner_px;
        double max_tilt_deg;                    /* largest board tilt from fronto-parallel */
        unsigned flags;                         /* IMP_CALIB_* */
        /* Refined by Ceres after OpenCV's estimate (pipeline/calib/cv/ceres-calib.h): robust loss,
         * outliers dropped (rms, worst, n_points, std, cov over the inliers), and the
         * projection uncertainty is then mrcal's (poses compensating the intrinsics). */
        bool ceres_refined;
        int n_outliers;                         /* points dropped by the refinement */
        /* From the joint camera + projector refinement (ceres-procam.h): std, cov and the
         * projection uncertainty are blocks of the joint covariance. */
        bool joint_refined;
};

/* σ(fx), σ(fy) inflated to |f| (100 %) in std and cov, when no view tilts the board enough
 * (IMP_CALIB_MIN_TILT_DEG): the local covariance cannot be trusted there. */
static inline void imp_calib_inflate_focal(struct imp_calib_intrinsics *in) {
        for (int i = 0; i < 2; i++) {
                double f = fabs(i ? in->fy : in->fx), sd = in->std[i] > DBL_MIN ? in->std[i] : DBL_MIN;
                double s = (f > sd ? f : sd) / sd;
                in->std[i] *= s;
                for (int k = 0; k < IMP_CALIB_N_INTR; k++) {
                        in->cov[i * IMP_CALIB_N_INTR + k] *= s;
                        in->cov[k * IMP_CALIB_N_INTR + i] *= s;
                }
        }
}

struct imp_calib_stereo {
        /* Camera → projector: X_proj = R · X_cam + t (t in square units). */
        double R[9];                            /* row-major */
        double t[3];
        double rms_px;                          /* RMS over both devices' points (stereoCalibrate's,
                                                   or the joint fit's over its inliers) */
        double worst_view_rms_px;               /* worst per-view RMS (either device) */
        int worst_view;
        /* 1σ of the pose, from the joint refinement's covariance (have_std false without it):
         * rotation as the Rodrigues vector's components in degrees, translation in square
         * units; cov is the 6×6 block (r in rad, t) in the same convention as the intrinsics. */
        bool have_std;
        double r_std_deg[3], t_std[3];
        double cov[36];
};

/* The joint refinement of both devices, the board poses and the camera → projector pose
 * (pipeline/calib/cv/ceres-procam.h), as run by the procam calibration. */
struct imp_calib_joint {
        bool attempted;                         /* run (built with Ceres, not disabled, and the
                                                   per-device fits determine the intrinsics) */
        bool used;                              /* camera, projector, stereo come from it */
        bool converged;                         /* Ceres reported convergence */
        int iterations;
        double rms_camera_px, rms_projector_px; /* over the inliers */
        double rms_px;                          /* both devices */
        int outliers_camera, outliers_projector;
        bool k3_fixed_camera, k3_fixed_projector, k2_fixed_camera, k2_fixed_projector;
        char why_not_used[IMP_CALIB_WARNING_LEN];   /* when !used and it was not disabled */
};

struct imp_calib_capture {
        char dir[512];
        bool used;
        int n_corners_cam;                      /* chessboard corners found on the white frame */
        int n_corners_proj;                     /* corners that got a projector coordinate */
        int n_decoded_px;                       /* decoded camera pixels in all corner windows */
        char why[IMP_CALIB_WARNING_LEN];        /* why skipped, when !used */
};

struct imp_calib_procam_opts {
        int proj_w, proj_h;                     /* projector pixels */
        int board_cols, board_rows;             /* inner corners, e.g. 9 × 7 */
        double square;                          /* square side, length unit of the output */
        int black_threshold;                    /* white − black must exceed this (DN); default 40 */
        int white_threshold;                    /* GrayCodePattern white threshold; default 5 */
        int window_half_px;                     /* homography window half side; 0 = upstream's
                                                   ceil(camera width / 180) */
        /* Label the corners the same way in every view: board z towards the camera (mirrored
         * orderings flipped) and square (0, 0) — between corners 0, 1, cols, cols + 1 — black
         * (the 180° ambiguity; needs cols + rows odd). Off: OpenCV's order as found. */
        bool orient_board;
        /* World frame from a board lying on the canvas plane: capture `reference` (-1: none,
         * world = camera frame) shows the board with inner corner (0, 0) at canvas
         * (board_origin[0], board_origin[1], 0) and its axes along canvas x, y (needs
         * orient_board). The camera's pose in that frame comes from solvePnP. */
        int reference;
        double board_origin[2];                 /* square unit */
        /* k3 of both devices: IMP_CALIB_K3_AUTO (0, the default) holds it at 0 for a device
         * whose diagonal field of view is below IMP_CALIB_K3_MIN_FOV_DEG, fits it otherwise. */
        int k3;
        /* k2 of both devices, the same values: IMP_CALIB_K3_AUTO holds it at 0 below
         * IMP_CALIB_K2_MIN_FOV_DEG; _FIT fits it; _FIX holds it at 0. */
        int k2;
        /* OpenCV's calibrateCamera only, no Ceres refinement (which runs by default when
         * impasto is built with Ceres, on views that determine the focal length). */
        bool opencv_only;
        /* Skip the joint refinement (camera, projector and their pose in one problem); the
         * devices are then refined one by one and the pose is stereoCalibrate's. */
        bool no_joint;
};
static inline void imp_calib_procam_opts_default(struct imp_calib_procam_opts *o) {
        *o = (struct imp_calib_procam_opts) { .proj_w = 1024, .proj_h = 768, .board_cols = 9,
                .board_rows = 7, .square = 1.0, .black_threshold = 40, .white_threshold = 5,
                .window_half_px = 0, .reference = -1 };
}

/* Where the procedure gets its frames: frame `index` of capture `capture` as a u8 grey
 * image — index < n_pat: the Gray-code frames in OpenCV's GrayCodePattern order, n_pat:
 * white, n_pat + 1: black. The procedure frees it (imp_image_free). -errno with err
 * naming the file on failure. */
typedef int (*imp_calib_frame_loader)(void *user, int capture, int index, struct imp_image **ret,
                                      struct imp_error *err);

struct imp_calib_procam {
        struct imp_calib_intrinsics camera, projector;
        struct imp_calib_stereo stereo;
        struct imp_calib_joint joint;
        /* With opts.reference: the camera's pose in the canvas frame, X_cam = R·X_world + t
         * (t in square units), from the reference view, and that view's RMS residual. */
        bool have_world;
        int reference;
        double world_R[9], world_t[3];
        double world_rms_px;
        int window_half_px;                     /* the one used */
        int n_captures, n_used;
        struct imp_calib_capture captures[IMP_CALIB_MAX_CAPTURES];
        int n_warnings;
        char warnings[IMP_CALIB_MAX_WARNINGS][IMP_CALIB_WARNING_LEN];
};

/* The helpers below are inline so that the OpenCV shim (library impasto_cv, which does not
 * link impasto_pipeline) can use them too. */

/* Appends a warning; beyond IMP_CALIB_MAX_WARNINGS the last slot says some were dropped. */
static inline __attribute__((format(printf, 2, 3)))
void imp_calib_warn(struct imp_calib_procam *r, const char *fmt, ...) {
        va_list ap;
        if (r->n_warnings >= IMP_CALIB_MAX_WARNINGS) {
                snprintf(r->warnings[IMP_CALIB_MAX_WARNINGS - 1], IMP_CALIB_WARNING_LEN,
                         "more warnings were dropped");
                return;
        }
        va_start(ap, fmt);
        vsnprintf(r->warnings[r->n_warnings++], IMP_CALIB_WARNING_LEN, fmt, ap);
        va_end(ap);
}

/* Sets IMP_CALIB_FOCAL_UNDETERMINED / _PP_UNDETERMINED / _FEW_VIEWS in in->flags from
 * its std values and view count (keeps the other flags); returns the flags. A non-finite
 * or non-positive std counts as undetermined. */
static inline unsigned imp_calib_intrinsics_assess(struct imp_calib_intrinsics *in) {
        double rfx = in->fx != 0 ? in->std[0] / fabs(in->fx) : HUGE_VAL;
        double rfy = in->fy != 0 ? in->std[1] / fabs(in->fy) : HUGE_VAL;
        if (!(rfx <= IMP_CALIB_FOCAL_REL_STD_MAX) || !(rfy <= IMP_CALIB_FOCAL_REL_STD_MAX) ||
            !(in->std[0] > 0) || !(in->std[1] > 0))
                in->flags |= IMP_CALIB_FOCAL_UNDETERMINED;
        if (!(in->std[2] <= IMP_CALIB_PP_STD_MAX_PX) || !(in->std[3] <= IMP_CALIB_PP_STD_MAX_PX))
                in->flags |= IMP_CALIB_PP_UNDETERMINED;
        if (in->n_views < IMP_CALIB_MIN_VIEWS)
                in->flags |= IMP_CALIB_FEW_VIEWS;
        return in->flags;
}
/* One line per flag ("camera: focal length not determined by the views (fx 1σ 12 %)…"),
 * written into buf (lines end with '\n'); returns the number of flags described. */
static inline int imp_calib_flags_describe(const struct imp_calib_intrinsics *in, const char *who,
                                           char *buf, size_t size) {
        int n = 0;
        size_t o = 0;
        buf[0] = 0;
#define IMP_CALIB_DESCRIBE_(...) do { int w_ = snprintf(buf + o, o < size ? size - o : 0, __VA_ARGS__); \
                if (w_ > 0) { o += (size_t) w_; if (o > size) o = size; } \
                n++; } while (0)
        if (in->flags & IMP_CALIB_FOCAL_UNDETERMINED)
                IMP_CALIB_DESCRIBE_("%s: focal length not determined by the views (fx %.4g ± %.3g, "
                                    "fy %.4g ± %.3g px, 1σ; largest board tilt %.1f°); tilt the "
                                    "board towards and away from the device\n", who, in->fx,
                                    in->std[0], in->fy, in->std[1], in->max_tilt_deg);
        if (in->flags & IMP_CALIB_PP_UNDETERMINED)
                IMP_CALIB_DESCRIBE_("%s: principal point not determined by the views (cx %.4g ± %.3g, "
                                    "cy %.4g ± %.3g px, 1σ)\n", who, in->cx, in->std[2], in->cy,
                                    in->std[3]);
        if (in->flags & IMP_CALIB_FEW_VIEWS)
                IMP_CALIB_DESCRIBE_("%s: only %d view%s, at least %d needed for a trustworthy "
                                    "calibration\n", who, in->n_views, in->n_views == 1 ? "" : "s",
                                    IMP_CALIB_MIN_VIEWS);
        if (in->flags & IMP_CALIB_RANK_DEFICIENT)
                IMP_CALIB_DESCRIBE_("%s: the views leave some parameters undetermined (singular normal "
                                    "matrix); the reported uncertainties are lower bounds of "
                                    "'unknown'\n", who);
#undef IMP_CALIB_DESCRIBE_
        return n;
}

/* JSON (new reference; NULL only when out of memory). */
json_t *imp_calib_intrinsics_to_json(const struct imp_calib_intrinsics *in);
json_t *imp_calib_procam_to_json(const struct imp_calib_procam *r);
/* Readable summary. */
void imp_calib_procam_print(const struct imp_calib_procam *r, FILE *f);
/* Writes a rig.json (pipeline/model/rig.h) with one camera "camera0" at the world origin and
 * the projector "projector" posed by the stereo result. Translations are in the board's
 * square unit; rig.json expects mm, so pass square_mm_per_unit (1 when squares are in mm). */
int imp_calib_procam_save_rig(const struct imp_calib_procam *r, double mm_per_unit,
                              const char *path, struct imp_error *err);

struct imp_rig;
/* The full rig for processing: a copy of `base` (names, sensor model, projector photometry,
 * dome lights — what this calibration does not measure) with camera 0's and the
 * projector's intrinsics, distortion and pose replaced by the calibration: camera pose from
 * the reference view when r->have_world (else world = camera frame), projector pose =
 * stereo ∘ camera pose. Only camera 0 is kept. */
int imp_calib_procam_rig(const struct imp_calib_procam *r, double mm_per_unit, const struct imp_rig *base,
                         struct imp_rig *ret, struct imp_error *err);

/* ---- capture sets as calibration input (pipeline/model/captureset.h) ---- */

/* Capture sets holding, for one camera, Gray code on both axes with inverses (bits as
 * OpenCV uses for the projector: ⌈log2 w⌉, ⌈log2 h⌉), white and black, all at the first
 * exposure found. Frames are picked by their pattern descriptors (any order) and
 * normalised to 8 bits: (DN − black level) · 255 / (99th percentile of the white frame
 * − black level), clipped. Caller frees with imp_calib_sets_free(). */
struct imp_calib_sets;
int imp_calib_sets_open(const char *const *dirs, int n, int proj_w, int proj_h,
                        struct imp_calib_sets **ret, struct imp_error *err);
void imp_calib_sets_free(struct imp_calib_sets *s);
/* An imp_calib_frame_loader; user is the struct imp_calib_sets. */
int imp_calib_sets_load(void *user, int capture, int index, struct imp_image **ret, struct imp_error *err);
/* rig.json of set i (the capture device's description). */
const struct imp_rig *imp_calib_sets_rig(const struct imp_calib_sets *s, int i);

#ifdef __cplusplus
}
#endif
