/* `impasto mosaic PAINTING_DIR --out DIR [--prior-only] [--register-on WHAT] [--register-smooth PX] [--tile-px N]
 * [--cache-mib N]`: one
 * copy of a whole painting from its tiles' copies (docs/mosaic.md; pipeline/mosaic/mosaic.h).
 * Prints the registration (per pair: residual before and after, shift, 1σ), the adjustment's
 * change from the stage prior, the seam step and, when the painting has truth (simulator:
 * truth/tile-poses.json, truth/height.exr), the scores against it. --prior-only places the
 * tiles from the stage poses alone, for the same figures without registration. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "commands.h"
#include "exit-codes.h"
#include "log.h"
#include "mosaic.h"
#include "numparse.h"

static void usage(FILE *f) {
        fprintf(f, "usage: impasto mosaic PAINTING_DIR --out DIR [--prior-only] [--register-on heights|normals|both]\n"
                   "                      [--register-smooth PX] [--tile-px N] [--cache-mib N]\n");
}

static void print_pairs(const struct imp_painting *p, const struct imp_mosaic_pair *pr, size_t n) {
        printf("pairs: %zu\n  %5s %5s  %9s %9s  %8s %8s %9s %7s  %s\n", n, "tile", "tile", "rms0 µm", "rms µm", "dx µm",
               "dy µm", "dθ °", "σxy µm", "inliers");
        for (size_t i = 0; i < n; i++) {
                const struct imp_mosaic_pair *q = &pr[i];
                if (!q->ok) {
                        printf("  %5u %5u  not registered: %s\n", p->tiles[q->a].index, p->tiles[q->b].index, q->why);
                        continue;
                }
                printf("  %5u %5u  %9.2f %9.2f  %8.1f %8.1f %9.4f %7.2f  %.0f%%\n", p->tiles[q->a].index,
                       p->tiles[q->b].index, q->rms_before_um, q->rms_after_um, 1e3 * q->meas[0], 1e3 * q->meas[1],
                       q->meas[2] * 180 / M_PI, fmax(q->sd_um[0], q->sd_um[1]), 100 * q->inlier_frac);
        }
}

static int registration(struct imp_painting *p, const struct imp_mosaic_options *o, struct imp_error *err) {
        struct imp_mosaic_pair *pairs = NULL;
        size_t n = 0;
        int r = imp_mosaic_register(p, o, &pairs, &n, err);
        if (r < 0)
                return r;
        print_pairs(p, pairs, n);
        struct imp_mosaic_adjust_stats st;
        r = imp_mosaic_adjust(p, pairs, n, &st, err);
        free(pairs);
        if (r < 0)
                return r;
        printf("adjustment: %zu pairs, change from the stage prior %.1f µm rms (max %.1f) at the tile corners, "
               "θ %.4f° rms; pair misfit %.2f µm rms; χ² pairs %.1f, priors %.1f\n", st.n_pairs_used, st.change_rms_um,
               st.change_max_um, st.theta_change_rms_deg, st.pair_resid_rms_um, st.chi2_pairs, st.chi2_priors);
        return 0;
}

/* The texels of the extent left uncovered, by cause (mosaic.h; the output tiles' masks are 0
 * there). */
static void print_uncovered(const struct imp_mosaic_figures *f) {
        const size_t *u = f->uncovered;
        printf("uncovered: %zu texels: %zu at the painting's edge (beyond every copy, up to %.3f mm in), %zu in gaps "
               "between copies, %zu at a copy's edge off its mask, %zu in holes of a copy\n",
               u[IMP_MOSAIC_UNCOVERED_EDGE] + u[IMP_MOSAIC_UNCOVERED_GAP] + u[IMP_MOSAIC_UNCOVERED_COPY_EDGE] +
                       u[IMP_MOSAIC_UNCOVERED_HOLE],
               u[IMP_MOSAIC_UNCOVERED_EDGE], f->edge_depth_mm, u[IMP_MOSAIC_UNCOVERED_GAP],
               u[IMP_MOSAIC_UNCOVERED_COPY_EDGE], u[IMP_MOSAIC_UNCOVERED_HOLE]);
}

static int mosaic(const char *dir, const char *out, const struct imp_mosaic_options *o) {
        struct imp_painting p;
        struct imp_error err = { 0 };
        int r = imp_painting_load(dir, &p, &err);
        if (r < 0) {
                log_error("%s", err.msg);
                imp_painting_done(&p);
                return IMP_EXIT_BAD_INPUT;
        }
        printf("%s: %zu tiles, %.0f × %.0f mm, stage prior σ %.3f mm, %.3f°%s\n", dir, p.n_tiles, p.extent_mm[0],
               p.extent_mm[1], p.sigma_mm, p.sigma_deg, o->prior_only ? " (placement from the stage prior only)" : "");
        struct imp_mosaic_truth_exr tx = { 0 };
        struct imp_mosaic_truth truth = { 0 };
        double seam;
        size_t ns;
        struct imp_mosaic_figures f;
        if ((!o->prior_only && (r = registration(&p, o, &err)) < 0) || (r = imp_mosaic_seam_step(&p, o, &seam, &ns, &err)) < 0)
                goto fail;
        printf("seam step: %.2f µm rms over %zu overlap points (the two copies' 5×5-texel means, before blending)\n",
               seam, ns);
        int tr = imp_mosaic_truth_load(&p, &tx, &truth, &err);
        if (tr < 0 && tr != -ENOENT) {
                r = tr;
                goto fail;
        }
        if ((r = imp_mosaic_write(&p, o, out, tr == 0 ? &truth : NULL, &f, &err)) < 0)
                goto fail;
        printf("%s: %zu × %zu texels in %zu × %zu tiles, %zu covered (%.3f%%), %zu doubled; %zu boxes (h_ref %.4f mm, δ0 %.4f mm); "
               "pyramid %d levels; %zu tile reads, at most %zu held\n", out, f.out_nx, f.out_ny, f.out_tiles_x, f.out_tiles_y,
               f.texels_covered, 100.0 * f.texels_covered / (f.out_nx * f.out_ny), f.texels_doubled, f.n_boxes, f.h_ref_mm,
               f.delta0_mm, f.pyramid_levels, f.input_loads, f.max_resident);
        print_uncovered(&f);
        struct imp_mosaic_reg_error re;
        if (imp_mosaic_registration_error(&p, &re) == 0)
                printf("truth: registration %.2f µm rms (gauge removed; absolute %.2f), mean %.2f, far corner %.2f (%.2f× mean), "
                       "max %.2f\n", re.rms_um, re.abs_rms_um, re.mean_um, re.far_corner_um,
                       re.mean_um > 0 ? re.far_corner_um / re.mean_um : 0, re.max_um);
        if (tr == 0) {
                printf("truth: height RMSE %.2f µm over %zu texels\n", f.height_rmse_um, f.height_n);
                printf("truth: output seam step %.2f µm (the blended mosaic's error jumps %.2f µm rms across %zu seam "
                       "segments, %.2f µm across the tiles' middles)\n", f.seam_out_step_um, f.seam_out_jump_um,
                       f.seam_out_n, f.seam_out_ref_um);
        }
        imp_mosaic_truth_done(&tx);
        imp_painting_done(&p);
        return IMP_EXIT_OK;
fail:
        log_error("%s", err.msg[0] ? err.msg : strerror(-r));
        imp_mosaic_truth_done(&tx);
        imp_painting_done(&p);
        return r == -EBADMSG || r == -ENOENT || r == -ENODATA || r == -EMEDIUMTYPE ? IMP_EXIT_BAD_INPUT : IMP_EXIT_FAILURE;
}

/* --register-on: the channels pairs are registered on (docs/mosaic.md: heights by default;
 * the normals help where the heights are noisy against them, e.g. 0.2 mm texels). */
static int parse_channels(const char *s, unsigned *ret) {
        static const struct { const char *name; unsigned ch; } names[] = {
                { "heights", IMP_MOSAIC_REG_HEIGHT }, { "normals", IMP_MOSAIC_REG_NORMALS },
                { "both", IMP_MOSAIC_REG_HEIGHT | IMP_MOSAIC_REG_NORMALS },
        };
        for (size_t i = 0; i < sizeof names / sizeof *names; i++)
                if (strcmp(s, names[i].name) == 0) {
                        *ret = names[i].ch;
                        return 0;
                }
        log_error("--register-on: expected heights, normals or both, got \"%s\"", s);
        return -EINVAL;
}

static int run(int argc, char **argv) {
        struct imp_mosaic_options o;
        imp_mosaic_options_default(&o);
        const char *out = NULL;
        static const struct option longopts[] = {
                { "out", required_argument, NULL, 'o' }, { "prior-only", no_argument, NULL, 'p' },
                { "tile-px", required_argument, NULL, 't' }, { "cache-mib", required_argument, NULL, 'c' },
                { "register-on", required_argument, NULL, 'r' }, { "register-smooth", required_argument, NULL, 's' },
                { "help", no_argument, NULL, 'h' }, {}
        };
        int c;
        long v;
        while ((c = getopt_long(argc, argv, "o:h", longopts, NULL)) >= 0)
                switch (c) {
                case 'o': out = optarg; break;
                case 'p': o.prior_only = true; break;
                case 'r':
                        if (parse_channels(optarg, &o.reg_channels) < 0)
                                return IMP_EXIT_USAGE;
                        break;
                case 's':       /* σ in texels of the heights' low-pass for registration (0.5); 0: none */
                        if (imp_parse_double("--register-smooth", optarg, 0, 20, &o.reg_smooth_px) < 0)
                                return IMP_EXIT_USAGE;
                        break;
                case 't':
                        if (imp_parse_int("--tile-px", optarg, 16, 8192, &o.out_tile_px) < 0)
                                return IMP_EXIT_USAGE;
                        break;
                case 'c':
                        if (imp_parse_long("--cache-mib", optarg, 64, 1L << 20, &v) < 0)
                                return IMP_EXIT_USAGE;
                        o.cache_bytes = (size_t) v << 20;
                        break;
                case 'h': usage(stdout); return IMP_EXIT_OK;
                default: usage(stderr); return IMP_EXIT_USAGE;
                }
        if (optind + 1 != argc || !out) {
                log_error(optind + 1 != argc ? "expected one PAINTING_DIR" : "missing --out");
                usage(stderr);
                return IMP_EXIT_USAGE;
        }
        return mosaic(argv[optind], out, &o);
}

const struct imp_command imp_cmd_mosaic = {
        .name = "mosaic",
        .summary = "one copy of a whole painting from its tiles' copies",
        .run = run,
        .hugepages = true,
};
