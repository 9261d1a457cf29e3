/* `impasto bench accuracy`: the sweep's configurations and measured results,
 * shared by the sweep (bench/accuracy.c) and its outputs — tables, Pareto fronts, SVG
 * plots, presets and the generated report (bench/accuracy-report.c). */
#pragma once
#include <stdbool.h>
#include <stddef.h>

/* One configuration: a scan plan (what the rig captures) and processing options. The
 * capture is derived from one rich rendering per scene by taking the frames the plan
 * names, so most configurations cost only processing. */
struct acc_config {
        const char *name;             /* short id, shown on the plots */
        const char *knob;             /* what it varies against the baseline */
        /* capture */
        int axes;                     /* 1: columns only, 2: columns and rows */
        bool inverse;                 /* Gray planes followed by their inverses */
        int phase_steps;              /* 0: Gray code only; 3, 4, 6, 12 */
        int phase_periods;            /* 1: 16 px; 2: 16 and 64 px */
        unsigned sl_exposures;        /* bit i: structured-light exposure i of the rich plan */
        int lights;                   /* dome lights: 0 (no sweep), 12, 24, 48 */
        unsigned dome_exposures;      /* bit i: dome exposure i of the rich plan */
        bool bin2;                    /* 2×2 binned frames (camera at half resolution) */
        /* processing */
        bool gray_decode;             /* decode the Gray code alone (phase frames ignored) */
        bool btf;
        int threads;                  /* 0: OpenMP default */
        int btf_max_iter;             /* 0: default */
        int btf_robust_passes;        /* -1: default */
        bool no_shadow_test;
        int cell_px;                  /* relief box size n; 0: default */
        /* where it runs */
        bool quick;                   /* part of the --quick sweep */
        bool hard;                    /* also on the harder scene */
};

struct acc_result {
        const struct acc_config *cfg;
        const char *scene;            /* scene name (study-demo, study-glossy) */
        char plan_path[512];
        bool ok;                      /* processed and compared */
        /* capture */
        size_t frames;
        double capture_s;             /* imp_plan_estimate_s of the plan */
        double sim_capture_s;         /* the simulator's clock replayed over the set */
        /* processing: `impasto process SET --out COPY --quiet` + process_flags, its own
         * process (fork and exec); wall, CPU and peak RSS from wait4 */
        char process_flags[128];
        char set_dir[512];            /* the derived set (removed after the sweep without --keep-sets) */
        double wall_s, cpu_s;
        long peak_rss_kib;
        double load_before, load_after;   /* 1-minute load average around the run (-1: unknown) */
        long long copy_bytes;
        /* accuracy */
        double height_rmse_um, normal_err_deg, mask_iou;
        long long nan_count;
        double rho_d_err, lobe_k_err, rerender_rmse;   /* -1: not measured */
        /* analysis */
        bool front_capture, front_processing;
        const char *preset;           /* "draft", "standard", "archival" or NULL */
};

/* The simulator's cost per effect (bench-sim-effects' measurement on a study scene). */
struct acc_effect_cost {
        char effect[24];
        double view_s, ms_per_frame;
        unsigned long long shading_evals, shadow_rays, shadow_steps, random_draws, projector_lookups,
                distortion_evals;
};

struct acc_study {
        const char *out_dir;
        const char *repo_dir;         /* NULL: do not write docs/ and config/plans/ */
        bool quick;
        const char *scenes[2];
        int n_scenes;
        double render_wall_s[2], render_cpu_s[2];
        size_t render_frames[2];
        double sl_exposures_us[3], dome_exposures_us[3];
        struct acc_result *results;
        size_t n_results;
        struct acc_effect_cost effects[16];
        int n_effects;
        const char *effects_scene;
        double total_wall_s;
        double load_start, load_end;  /* 1-minute load average at the study's start and end */
};

/* Marks the Pareto fronts (per scene) and picks the presets (on the first scene). */
void acc_analyse(struct acc_study *st);
/* Writes results.csv, results.json, the SVG plots, presets/ and the report into out_dir,
 * and with repo_dir also docs/accuracy-vs-time.md, the SVGs in docs/accuracy/ and
 * config/plans/{draft,standard,archival}.cfg + presets.json. Logs what fails. */
int acc_write_outputs(const struct acc_study *st);
/* The plan text of a configuration for a rig whose dome has n_rig_lights lights with the
 * given ids. Caller frees. */
char *acc_plan_text(const struct acc_config *c, const struct acc_study *st, const int *light_ids,
                    int n_rig_lights);
