/* `impasto export COPY_DIR --to FORMAT --out DIR [--triangles N]`: a digital copy in the
 * formats other tools read (docs/export.md; pipeline/export/export.h):
 *   tiff-height  DIR/height.tif: float32 heightmap, mm, pixel size in the resolution tags
 *   ply          DIR/mesh.ply: binary PLY mesh with normals and albedo per vertex
 *   glb          DIR/mesh.glb (+ albedo.png, normal.png): glTF 2.0 with textures
 *   lp           DIR/images/light-NNN.png, DIR/lights.lp, DIR/lights.dome: the raw dome stack of
 *                --capture CAPSET for RTI tools (RelightLab, RTIBuilder), one exposure
 *   openlime     DIR/{kd,ks,normals,gloss}.dzi (+ _files/), DIR/openlime.json, refit-error.tif:
 *                an OpenLIME BRDF layer, the Lafortune lobes refitted to its Ward model
 * Meshes are decimated to a regular sub-grid within the triangle budget (default 200000).
 * The copy is only read; DIR is created. */
#include <errno.h>
#include <getopt.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "commands.h"
#include "copy-load.h"
#include "export.h"
#include "json-util.h"
#include "log.h"

#define EXPORT_DEFAULT_TRIANGLES 200000

static void usage(FILE *f) {
        fprintf(f, "usage: impasto export COPY_DIR --to tiff-height|ply|glb|lp|openlime --out DIR [--triangles N]\n"
                   "                      [--capture CAPSET] [--exposure-index N]\n");
}

static int export_mesh(const struct imp_copy *c, const char *fmt, const char *out, size_t budget,
                       struct imp_error *err) {
        struct imp_mesh m;
        int r = imp_mesh_build(c, budget, &m, err);
        if (r < 0)
                return r;
        char path[PATH_MAX];
        bool ply = !strcmp(fmt, "ply");
        snprintf(path, sizeof path, "%s/mesh.%s", out, ply ? "ply" : "glb");
        r = ply ? imp_export_ply(&m, c, path, err) : imp_export_glb(&m, c, path, err);
        if (r >= 0)
                printf("%s: %zu vertices, %zu triangles (a vertex every %d texels, %.4g mm)\n", path, m.n_vertices,
                       m.n_triangles, m.step, m.step * c->pitch_mm);
        imp_mesh_done(&m);
        return r;
}

static int run(int argc, char **argv) {
        const char *fmt = NULL, *out = NULL, *capture = NULL;
        int exposure_index = -1;
        size_t budget = EXPORT_DEFAULT_TRIANGLES;
        static const struct option longopts[] = {
                { "to", required_argument, NULL, 't' }, { "out", required_argument, NULL, 'o' },
                { "triangles", required_argument, NULL, 'n' }, { "capture", required_argument, NULL, 'c' },
                { "exposure-index", required_argument, NULL, 'e' }, { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        while ((c = getopt_long(argc, argv, "t:o:h", longopts, NULL)) >= 0)
                switch (c) {
                case 't': fmt = optarg; break;
                case 'o': out = optarg; break;
                case 'n': {
                        char *end;
                        unsigned long long n = strtoull(optarg, &end, 10);
                        if (end == optarg || *end || n < 2 || n > (1ull << 31)) {
                                log_error("--triangles: expected 2..2^31, got '%s'", optarg);
                                return 2;
                        }
                        budget = (size_t) n;
                        break;
                }
                case 'c': capture = optarg; break;
                case 'e': {
                        char *end;
                        long n = strtol(optarg, &end, 10);
                        if (end == optarg || *end || n < 0 || n > 15) {
                                log_error("--exposure-index: expected 0..15, got '%s'", optarg);
                                return 2;
                        }
                        exposure_index = (int) n;
                        break;
                }
                case 'h': usage(stdout); return 0;
                default: usage(stderr); return 2;
                }
        if (optind + 1 != argc || !fmt || !out) {
                log_error(optind + 1 != argc ? "expected one COPY_DIR" : !fmt ? "missing --to" : "missing --out");
                usage(stderr);
                return 2;
        }
        if (strcmp(fmt, "tiff-height") && strcmp(fmt, "ply") && strcmp(fmt, "glb") && strcmp(fmt, "lp") &&
            strcmp(fmt, "openlime")) {
                log_error("--to: expected tiff-height, ply, glb, lp or openlime, got '%s'", fmt);
                return 2;
        }
        if (!strcmp(fmt, "lp") && !capture) {
                log_error("--to lp: the dome stack comes from the capture set: give --capture CAPSET");
                return 2;
        }
        /* the copy first: bad input leaves no empty output directory behind */
        struct imp_error err = {};
        struct imp_copy copy;
        int r = imp_copy_load(argv[optind], &copy, &err);
        if (r < 0) {
                log_error("%s: not a readable digital copy: %s", argv[optind], err.msg[0] ? err.msg : strerror(-r));
                imp_copy_done(&copy);
                return 3;
        }
        r = imp_mkdir_p(out, 0755);
        if (r < 0) {
                log_error("%s: %s", out, strerror(-r));
                imp_copy_done(&copy);
                return 1;
        }
        if (!strcmp(fmt, "tiff-height")) {
                char path[PATH_MAX];
                snprintf(path, sizeof path, "%s/height.tif", out);
                r = imp_export_tiff_height(&copy, path, &err);
                if (r >= 0)
                        printf("%s: %dx%d float32 heights in mm, %.6g mm per pixel\n", path, copy.nx, copy.ny,
                               copy.pitch_mm);
        } else if (!strcmp(fmt, "lp")) {
                struct imp_lp_summary sum;
                r = imp_export_lp(&copy, capture, out, exposure_index, &sum, &err);
                if (r >= 0)
                        printf("%s/lights.lp: %zu lights, %dx%d 16-bit PNGs at exposure %d (%.0f µs), %.1f mm wide\n",
                               out, sum.n_lights, sum.width, sum.height, sum.exposure_index, sum.exposure_us,
                               sum.image_width_mm);
        } else if (!strcmp(fmt, "openlime")) {
                double med, p95;
                r = imp_export_openlime(&copy, out, &med, &p95, &err);
                if (r >= 0)
                        printf("%s/openlime.json: BRDF layer %dx%d; Ward refit error (RMS / lobe RMS) median %.3f, "
                               "95th percentile %.3f\n", out, copy.nx, copy.ny, med, p95);
        } else
                r = export_mesh(&copy, fmt, out, budget, &err);
        imp_copy_done(&copy);
        if (r < 0) {
                log_error("%s", err.msg[0] ? err.msg : strerror(-r));
                return 1;
        }
        return 0;
}

const struct imp_command imp_cmd_export = {
        .name = "export",
        .summary = "write a digital copy for other tools (TIFF heightmap, PLY, glTF, RTI stack, OpenLIME)",
        .run = run,
};
