/* Camera-ray / projector triangulation with reprojection-error refinement and first-order
 * uncertainty (see triangulate.h). The pinhole maths lives here too (with the analytic
 * Jacobian that rig.h does not offer) so the refinement can differentiate through the
 * projector's distortion. */
#include <math.h>
#include <string.h>
#include "numerics.h"
#include "triangulate.h"

#define TRI_DEFAULT_SIGMA_PX      0.1
#define TRI_DEFAULT_MIN_CONF      0.05
#define TRI_DEFAULT_MIN_ANGLE     (2.0 * M_PI / 180.0)
#define TRI_GN_MAX_ITER           20
#define TRI_GN_TOL_MM             1e-9
#define TRI_UNDISTORT_MAX_ITER    30

void imp_triangulate_options_default(struct imp_triangulate_options *opt) {
        *opt = (struct imp_triangulate_options) {
                .sigma_proj_px = TRI_DEFAULT_SIGMA_PX,
                .min_confidence = TRI_DEFAULT_MIN_CONF,
                .min_angle_rad = TRI_DEFAULT_MIN_ANGLE,
                .proj_offset_px = 0.5,
                .use_both = true,
        };
}

void imp_projector_coords_from_sl(const struct imp_sl_result *sl, struct imp_projector_coords *ret) {
        *ret = (struct imp_projector_coords) {
                .width = sl->width, .height = sl->height,
                .proj_x = sl->proj_x, .proj_y = sl->proj_y,
                .sl_flags = sl->flags, .confidence = sl->confidence, .sigma_px = sl->sigma_px,
        };
}

int imp_range_image_init(struct imp_range_image *r, int width, int height) {
        if (!r || width <= 0 || height <= 0)
                return -EINVAL;
        size_t n = (size_t) width * height;
        _cleanup_free_ float *xyz = calloc(n * 3, sizeof(float));
        _cleanup_free_ float *sig = calloc(n, sizeof(float));
        _cleanup_free_ uint8_t *val = calloc(n, 1);
        _cleanup_free_ uint16_t *fl = calloc(n, sizeof(uint16_t));
        if (!xyz || !sig || !val || !fl)
                return -ENOMEM;
        *r = (struct imp_range_image) {
                .width = width, .height = height,
                .xyz = TAKE_PTR(xyz), .sigma_mm = TAKE_PTR(sig), .valid = TAKE_PTR(val),
                .flags = TAKE_PTR(fl),
        };
        return 0;
}

void imp_range_image_done(struct imp_range_image *r) {
        if (!r)
                return;
        free(r->xyz);
        free(r->sigma_mm);
        free(r->valid);
        free(r->flags);
        *r = (struct imp_range_image) {};
}

/* Brown–Conrady distortion of normalised (x, y) with its 2×2 Jacobian (row-major). */
static void distort(const struct imp_pinhole *m, double x, double y, double ret_d[2], double ret_J[4]) {
        double r2 = x * x + y * y;
        double rad = 1 + r2 * (m->k1 + r2 * (m->k2 + r2 * m->k3));
        double drad = m->k1 + r2 * (2 * m->k2 + 3 * m->k3 * r2);    /* ∂rad/∂r2 */
        ret_d[0] = x * rad + 2 * m->p1 * x * y + m->p2 * (r2 + 2 * x * x);
        ret_d[1] = y * rad + m->p1 * (r2 + 2 * y * y) + 2 * m->p2 * x * y;
        if (ret_J) {
                ret_J[0] = rad + 2 * x * x * drad + 2 * m->p1 * y + 6 * m->p2 * x;
                ret_J[1] = 2 * x * y * drad + 2 * m->p1 * x + 2 * m->p2 * y;
                ret_J[2] = 2 * x * y * drad + 2 * m->p1 * x + 2 * m->p2 * y;
                ret_J[3] = rad + 2 * y * y * drad + 6 * m->p1 * y + 2 * m->p2 * x;
        }
}

/* Newton inversion of the distortion; starts at the distorted point. */
static void undistort(const struct imp_pinhole *m, double xd, double yd, double ret[2]) {
        double x = xd, y = yd;
        for (int it = 0; it < TRI_UNDISTORT_MAX_ITER; it++) {
                double d[2], J[4];
                distort(m, x, y, d, J);
                double rx = d[0] - xd, ry = d[1] - yd;
                double det = J[0] * J[3] - J[1] * J[2];
                if (fabs(det) < 1e-12)
                        break;
                double dx = (J[3] * rx - J[1] * ry) / det, dy = (-J[2] * rx + J[0] * ry) / det;
                x -= dx;
                y -= dy;
                if (fabs(dx) + fabs(dy) < 1e-15)
                        break;
        }
        ret[0] = x;
        ret[1] = y;
}

static void mat_vec(const double R[9], const double v[3], double o[3]) {
        for (int i = 0; i < 3; i++)
                o[i] = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
}
static void mat_t_vec(const double R[9], const double v[3], double o[3]) {
        for (int i = 0; i < 3; i++)
                o[i] = R[i] * v[0] + R[3 + i] * v[1] + R[6 + i] * v[2];
}

bool imp_triangulate_project(const struct imp_pinhole *m, const double X[3], double ret_px[2],
                             double ret_J[6]) {
        double Xc[3];
        mat_vec(m->R, X, Xc);
        for (int i = 0; i < 3; i++)
                Xc[i] += m->t[i];
        if (!(Xc[2] > 0))
                return false;
        double iz = 1.0 / Xc[2], x = Xc[0] * iz, y = Xc[1] * iz, d[2], Jd[4];
        distort(m, x, y, d, Jd);
        ret_px[0] = m->fx * d[0] + m->cx;
        ret_px[1] = m->fy * d[1] + m->cy;
        if (ret_J) {
                /* ∂(x,y)/∂Xc = [[iz, 0, −x iz], [0, iz, −y iz]]; then ·R for world. */
                double Jn[6] = { iz, 0, -x * iz, 0, iz, -y * iz };
                double Jp[6];
                for (int c = 0; c < 3; c++) {
                        Jp[c] = m->fx * (Jd[0] * Jn[c] + Jd[1] * Jn[3 + c]);
                        Jp[3 + c] = m->fy * (Jd[2] * Jn[c] + Jd[3] * Jn[3 + c]);
                }
                for (int r = 0; r < 2; r++)
                        for (int c = 0; c < 3; c++)
                                ret_J[3 * r + c] = Jp[3 * r] * m->R[c] + Jp[3 * r + 1] * m->R[3 + c] +
                                                   Jp[3 * r + 2] * m->R[6 + c];
        }
        return true;
}

void imp_triangulate_ray(const struct imp_pinhole *m, const double px[2], double ret_C[3],
                         double ret_d[3]) {
        double n[2];
        undistort(m, (px[0] - m->cx) / m->fx, (px[1] - m->cy) / m->fy, n);
        double dc[3] = { n[0], n[1], 1.0 }, d[3];
        mat_t_vec(m->R, dc, d);
        double l = sqrt(imp_dot3(d, d));
        for (int i = 0; i < 3; i++)
                ret_d[i] = d[i] / l;
        mat_t_vec(m->R, m->t, ret_C);
        for (int i = 0; i < 3; i++)
                ret_C[i] = -ret_C[i];
}

/* Start value of λ on the camera ray (C, d) from the undistorted projector geometry.
 * axis: -1 both coordinates, 0 column only, 1 row only. */
static bool initial_lambda(const struct imp_pinhole *proj, const double C[3], const double d[3],
                           const double p[2], int axis, double *ret_lambda) {
        double Cp[3], dp[3];
        double q[2] = { axis == 1 ? proj->cx : p[0], axis == 0 ? proj->cy : p[1] };
        imp_triangulate_ray(proj, q, Cp, dp);
        double w0[3] = { C[0] - Cp[0], C[1] - Cp[1], C[2] - Cp[2] };
        if (axis < 0) {
                double b = imp_dot3(d, dp), dd = imp_dot3(d, w0), e = imp_dot3(dp, w0), den = 1 - b * b;
                if (den < 1e-12)
                        return false;
                *ret_lambda = (b * e - dd) / den;
                return true;
        }
        /* Plane through Cp containing the projector's undistorted column (row): in the
         * device frame  X − x_n Z = 0  (Y − y_n Z = 0). */
        double n_dev[3] = { axis == 0 ? 1 : 0, axis == 1 ? 1 : 0, 0 }, xn[2];
        undistort(proj, (q[0] - proj->cx) / proj->fx, (q[1] - proj->cy) / proj->fy, xn);
        n_dev[2] = -xn[axis];
        double nw[3];
        mat_t_vec(proj->R, n_dev, nw);
        double den = imp_dot3(nw, d);
        if (fabs(den) < 1e-12)
                return false;
        *ret_lambda = -imp_dot3(nw, w0) / den;
        return true;
}

/* Gauss–Newton on λ; returns false when it leaves the domain (behind a device). On success
 * *ret_jj = |∂π/∂λ|² over the used coordinates at the solution. */
static bool refine_lambda(const struct imp_pinhole *proj, const double C[3], const double d[3],
                          const double p[2], int axis, double *lambda, double *ret_jj) {
        double lam = *lambda, jj = 0;
        for (int it = 0; it < TRI_GN_MAX_ITER; it++) {
                double X[3] = { C[0] + lam * d[0], C[1] + lam * d[1], C[2] + lam * d[2] }, u[2], J[6];
                if (!(lam > 0) || !imp_triangulate_project(proj, X, u, J))
                        return false;
                double jl[2] = { imp_dot3(J, d), imp_dot3(J + 3, d) }, num = 0;
                jj = 0;
                for (int k = 0; k < 2; k++) {
                        if (axis >= 0 && k != axis)
                                continue;
                        num += jl[k] * (u[k] - p[k]);
                        jj += jl[k] * jl[k];
                }
                if (!(jj > 0))
                        return false;
                double step = num / jj;
                lam -= step;
                if (fabs(step) < TRI_GN_TOL_MM)
                        break;
        }
        if (!(lam > 0) || !isfinite(lam))
                return false;
        *lambda = lam;
        *ret_jj = jj;
        return true;
}

/* What a point inherits from the decoder's flags. */
static uint16_t texel_flags(uint16_t sl) {
        return (uint16_t) ((sl & IMP_SL_SATURATED ? IMP_TEXEL_SATURATED : 0) |
                           (sl & IMP_SL_PHASE_REJECTED ? IMP_TEXEL_PHASE_REJECTED : 0));
}

int imp_triangulate(const struct imp_pinhole *cam, const struct imp_pinhole *proj,
                    const struct imp_projector_coords *pc, const struct imp_triangulate_options *opt,
                    struct imp_range_image *ret) {
        struct imp_triangulate_options defaults;
        if (!cam || !proj || !pc || !ret || pc->width <= 0 || pc->height <= 0 ||
            !(cam->fx > 0) || !(cam->fy > 0) || !(proj->fx > 0) || !(proj->fy > 0))
                return -EINVAL;
        if (!opt) {
                imp_triangulate_options_default(&defaults);
                opt = &defaults;
        }
        if (!(opt->sigma_proj_px > 0))
                return -EINVAL;
        struct imp_range_image r;
        int k = imp_range_image_init(&r, pc->width, pc->height);
        if (k < 0)
                return k;
        double Cc[3], Cp[3], dummy[3], ctr[2] = { proj->cx, proj->cy };
        imp_triangulate_ray(cam, ctr, Cc, dummy);
        imp_triangulate_ray(proj, ctr, Cp, dummy);
        memcpy(r.camera_centre_mm, Cc, sizeof Cc);
        double cos_min = cos(opt->min_angle_rad);
        int w = pc->width, h = pc->height;
        size_t n_valid = 0;
        double foot_sum = 0, inv_f = 1 / sqrt(cam->fx * cam->fy);

        #pragma omp parallel for schedule(dynamic, 8) reduction(+:n_valid, foot_sum)
        for (int y = 0; y < h; y++)
                for (int x = 0; x < w; x++) {
                        size_t i = (size_t) y * w + x;
                        bool vx = pc->proj_x && isfinite(pc->proj_x[i]) &&
                                  (pc->sl_flags ? (pc->sl_flags[i] & IMP_SL_VALID_X) != 0 :
                                   pc->valid_x ? pc->valid_x[i] != 0 : true);
                        bool vy = pc->proj_y && isfinite(pc->proj_y[i]) &&
                                  (pc->sl_flags ? (pc->sl_flags[i] & IMP_SL_VALID_Y) != 0 :
                                   pc->valid_y ? pc->valid_y[i] != 0 : true);
                        /* Outside the projector (decoders write −1 there): not a measurement. */
                        vx = vx && pc->proj_x[i] >= 0 && pc->proj_x[i] <= proj->width;
                        vy = vy && pc->proj_y[i] >= 0 && pc->proj_y[i] <= proj->height;
                        if (!opt->use_both && vx)
                                vy = false;
                        double conf = pc->confidence ? imp_sl_conf(pc->confidence[i]) : 1.0;
                        if ((!vx && !vy) || !(conf >= opt->min_confidence))
                                continue;
                        int axis = vx && vy ? -1 : vx ? 0 : 1;
                        double p[2] = { vx ? pc->proj_x[i] - opt->proj_offset_px : 0,
                                        vy ? pc->proj_y[i] - opt->proj_offset_px : 0 };
                        double px[2] = { x, y }, C[3], d[3], lam, jj;
                        imp_triangulate_ray(cam, px, C, d);
                        if (!initial_lambda(proj, C, d, p, axis, &lam) ||
                            !refine_lambda(proj, C, d, p, axis, &lam, &jj))
                                continue;
                        double X[3] = { C[0] + lam * d[0], C[1] + lam * d[1], C[2] + lam * d[2] };
                        double v[3] = { X[0] - Cp[0], X[1] - Cp[1], X[2] - Cp[2] };
                        double lv = sqrt(imp_dot3(v, v));
                        if (!(lv > 0) || fabs(imp_dot3(v, d)) / lv > cos_min)
                                continue;
                        double sp = opt->sigma_proj_px / fmin(conf, 1.0);
                        if (pc->sigma_px && imp_sl_sigma(pc->sigma_px[i]) > sp)
                                sp = imp_sl_sigma(pc->sigma_px[i]);
                        double sigma = sp / sqrt(jj);
                        if (!isfinite(sigma))
                                continue;
                        for (int c = 0; c < 3; c++)
                                r.xyz[3 * i + c] = (float) X[c];
                        r.sigma_mm[i] = (float) sigma;
                        r.valid[i] = axis < 0 ? IMP_RANGE_BOTH : axis == 0 ? IMP_RANGE_COLUMN : IMP_RANGE_ROW;
                        r.flags[i] = texel_flags(pc->sl_flags ? pc->sl_flags[i] : 0);
                        foot_sum += fabs(lam) * inv_f;
                        n_valid++;
                }
        r.n_valid = n_valid;
        r.footprint_mm = n_valid ? foot_sum / n_valid : 0;
        *ret = r;
        return 0;
}
