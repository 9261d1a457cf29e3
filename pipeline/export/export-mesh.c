/* Meshes of the heightfield and their texture maps: PLY, glTF binary (export.h). */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "export.h"
#include "image.h"
#include "json-util.h"

void imp_mesh_done(struct imp_mesh *m) {
        if (!m)
                return;
        free(m->pos);
        free(m->normal);
        free(m->uv);
        free(m->rgb);
        free(m->texel);
        free(m->tri);
        memset(m, 0, sizeof *m);
}

static uint8_t srgb8(double v) {
        v = v < 0 ? 0 : v > 1 ? 1 : v;
        double s = v <= 0.0031308 ? 12.92 * v : 1.055 * pow(v, 1 / 2.4) - 0.055;
        return (uint8_t) lround(s * 255);
}

static void unit_normal(const struct imp_copy *c, size_t k, float n[3]) {
        double x = c->normal_x[k], y = c->normal_y[k], q = x * x + y * y;
        double z = q < 1 ? sqrt(1 - q) : 0, s = q > 1 ? 1 / sqrt(q) : 1;
        n[0] = (float) (x * s), n[1] = (float) (y * s), n[2] = (float) z;
}

/* Grid lines of a step: 0, step, 2·step, … and the last texel. */
static int grid_lines(int n, int step, int *ret) {
        int m = 0;
        for (int i = 0; i < n - 1; i += step)
                ret[m++] = i;
        ret[m++] = n - 1;
        return m;
}

static size_t count_triangles(const struct imp_copy *c, int step, int *gx, int *gy) {
        int mx = grid_lines(c->nx, step, gx), my = grid_lines(c->ny, step, gy);
        size_t t = 0;
        for (int b = 0; b + 1 < my; b++)
                for (int a = 0; a + 1 < mx; a++) {
                        const uint8_t *M = c->mask;
                        size_t n = (size_t) c->nx;
                        t += 2 * (M[gy[b] * n + gx[a]] && M[gy[b] * n + gx[a + 1]] && M[gy[b + 1] * n + gx[a]] &&
                                  M[gy[b + 1] * n + gx[a + 1]]);
                }
        return t;
}

static int mesh_alloc(struct imp_mesh *m, size_t nv, size_t nt) {
        m->pos = malloc(sizeof(float) * 3 * (nv ? nv : 1));
        m->normal = malloc(sizeof(float) * 3 * (nv ? nv : 1));
        m->uv = malloc(sizeof(float) * 2 * (nv ? nv : 1));
        m->rgb = malloc(3 * (nv ? nv : 1));
        m->texel = malloc(sizeof(int32_t) * 2 * (nv ? nv : 1));
        m->tri = malloc(sizeof(uint32_t) * 3 * (nt ? nt : 1));
        return m->pos && m->normal && m->uv && m->rgb && m->texel && m->tri ? 0 : -ENOMEM;
}

/* Vertices at every grid point on the mask (index map idx), then two triangles per cell. */
static void mesh_fill(const struct imp_copy *c, struct imp_mesh *m, const int *gx, int mx, const int *gy, int my,
                      uint32_t *idx) {
        size_t v = 0, t = 0;
        for (int b = 0; b < my; b++)
                for (int a = 0; a < mx; a++) {
                        int i = gx[a], j = gy[b];
                        size_t k = (size_t) j * c->nx + i;
                        idx[(size_t) b * mx + a] = UINT32_MAX;
                        if (!c->mask[k])
                                continue;
                        idx[(size_t) b * mx + a] = (uint32_t) v;
                        m->pos[3 * v] = (float) (i * c->pitch_mm), m->pos[3 * v + 1] = (float) (j * c->pitch_mm);
                        m->pos[3 * v + 2] = c->height[k];
                        unit_normal(c, k, &m->normal[3 * v]);
                        m->uv[2 * v] = (float) ((i + 0.5) / c->nx), m->uv[2 * v + 1] = (float) ((j + 0.5) / c->ny);
                        for (int q = 0; q < 3; q++)
                                m->rgb[3 * v + q] = srgb8(c->brdf[k].rho_d[q]);
                        m->texel[2 * v] = i, m->texel[2 * v + 1] = j;
                        v++;
                }
        for (int b = 0; b + 1 < my; b++)
                for (int a = 0; a + 1 < mx; a++) {
                        uint32_t p00 = idx[(size_t) b * mx + a], p10 = idx[(size_t) b * mx + a + 1];
                        uint32_t p01 = idx[(size_t) (b + 1) * mx + a], p11 = idx[(size_t) (b + 1) * mx + a + 1];
                        if (p00 == UINT32_MAX || p10 == UINT32_MAX || p01 == UINT32_MAX || p11 == UINT32_MAX)
                                continue;
                        uint32_t *T = &m->tri[3 * t];
                        T[0] = p00, T[1] = p10, T[2] = p11, T[3] = p00, T[4] = p11, T[5] = p01;
                        t += 2;
                }
        m->n_vertices = v;
        m->n_triangles = t;
}

int imp_mesh_build(const struct imp_copy *c, size_t max_triangles, struct imp_mesh *m, struct imp_error *err) {
        memset(m, 0, sizeof *m);
        if (max_triangles < 2)
                return imp_error_set(err, -EINVAL, "triangle budget %zu: expected at least 2", max_triangles);
        _cleanup_free_ int *gx = malloc(sizeof(int) * (size_t) (c->nx + 1));
        _cleanup_free_ int *gy = malloc(sizeof(int) * (size_t) (c->ny + 1));
        if (!gx || !gy)
                return imp_error_set(err, -ENOMEM, "out of memory");
        /* the step of a full grid that fits, then larger until the masked grid fits */
        int step = IMP_MAX(1, (int) floor(sqrt(2.0 * (c->nx - 1) * (c->ny - 1) / (double) max_triangles)));
        size_t nt = count_triangles(c, step, gx, gy);
        while (nt > max_triangles && step < IMP_MAX(c->nx, c->ny))
                nt = count_triangles(c, ++step, gx, gy);
        if (nt > max_triangles)
                return imp_error_set(err, -E2BIG, "no sub-grid of the copy fits %zu triangles", max_triangles);
        int mx = grid_lines(c->nx, step, gx), my = grid_lines(c->ny, step, gy);
        _cleanup_free_ uint32_t *idx = malloc(sizeof(uint32_t) * (size_t) mx * my);
        if (!idx || mesh_alloc(m, (size_t) mx * my, nt) < 0) {
                imp_mesh_done(m);
                return imp_error_set(err, -ENOMEM, "out of memory for a mesh of %zu triangles", nt);
        }
        m->step = step;
        mesh_fill(c, m, gx, mx, gy, my, idx);
        return 0;
}

int imp_export_ply(const struct imp_mesh *m, const struct imp_copy *c, const char *path, struct imp_error *err) {
        FILE *f = fopen(path, "wbe");
        if (!f)
                return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        fprintf(f, "ply\nformat binary_little_endian 1.0\ncomment impasto export: units mm, canvas frame\n"
                   "comment pitch_mm %.17g step_texels %d\nelement vertex %zu\nproperty float x\nproperty float y\n"
                   "property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\n"
                   "property uchar green\nproperty uchar blue\nelement face %zu\n"
                   "property list uchar int vertex_indices\nend_header\n",
                c->pitch_mm, m->step, m->n_vertices, m->n_triangles);
        for (size_t v = 0; v < m->n_vertices; v++) {
                fwrite(&m->pos[3 * v], sizeof(float), 3, f);
                fwrite(&m->normal[3 * v], sizeof(float), 3, f);
                fwrite(&m->rgb[3 * v], 1, 3, f);
        }
        for (size_t t = 0; t < m->n_triangles; t++) {
                uint8_t three = 3;
                int32_t ix[3] = { (int32_t) m->tri[3 * t], (int32_t) m->tri[3 * t + 1], (int32_t) m->tri[3 * t + 2] };
                fwrite(&three, 1, 1, f);
                fwrite(ix, sizeof(int32_t), 3, f);
        }
        bool ok = !ferror(f);
        ok = (fclose(f) == 0) && ok;
        return ok ? 0 : imp_error_set(err, -EIO, "%s: write failed", path);
}

static int slurp(const char *path, uint8_t **ret, size_t *ret_size, struct imp_error *err) {
        FILE *f = fopen(path, "rbe");
        if (!f)
                return imp_error_set(err, -errno, "%s: %s", path, strerror(errno));
        fseek(f, 0, SEEK_END);
        long n = ftell(f);
        fseek(f, 0, SEEK_SET);
        uint8_t *b = n >= 0 ? malloc((size_t) n + 1) : NULL;
        bool ok = b && fread(b, 1, (size_t) n, f) == (size_t) n;
        fclose(f);
        if (!ok) {
                free(b);
                return imp_error_set(err, -EIO, "%s: read failed", path);
        }
        *ret = b;
        *ret_size = (size_t) n;
        return 0;
}

int imp_export_maps(const struct imp_copy *c, const char *dir, uint8_t **ret_albedo, size_t *ret_albedo_size,
                    uint8_t **ret_normal, size_t *ret_normal_size, struct imp_error *err) {
        _cleanup_image_ struct imp_image *alb = NULL, *nrm = NULL;
        int r;
        if ((r = imp_image_new(c->nx, c->ny, 3, IMP_PIX_U8, &alb)) < 0 ||
            (r = imp_image_new(c->nx, c->ny, 3, IMP_PIX_U8, &nrm)) < 0)
                return imp_error_set(err, r, "out of memory");
        for (int j = 0; j < c->ny; j++)
                for (int i = 0; i < c->nx; i++) {
                        size_t k = (size_t) j * c->nx + i;
                        float n[3];
                        unit_normal(c, k, n);
                        for (int q = 0; q < 3; q++) {
                                imp_image_u8(alb, i, j)[q] = srgb8(c->brdf[k].rho_d[q]);
                                imp_image_u8(nrm, i, j)[q] = (uint8_t) lround(127.5 * (n[q] + 1));
                        }
                }
        char pa[4096], pn[4096];
        snprintf(pa, sizeof pa, "%s/albedo.png", dir);
        snprintf(pn, sizeof pn, "%s/normal.png", dir);
        if ((r = imp_png_write(pa, alb, err)) < 0 || (r = imp_png_write(pn, nrm, err)) < 0)
                return r;
        if (ret_albedo && (r = slurp(pa, ret_albedo, ret_albedo_size, err)) < 0)
                return r;
        if (ret_normal && (r = slurp(pn, ret_normal, ret_normal_size, err)) < 0) {
                if (ret_albedo)
                        free(*ret_albedo);
                return r;
        }
        return 0;
}
