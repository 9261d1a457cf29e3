/* Test helper for the mosaic tests: register a synthetic painting's pairs with given options,
 * adjust, and score the pairs and the placement against the synthetic truth. */
#pragma once
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "mosaic.h"
#include "test.h"

struct mosaic_fit {
        struct imp_mosaic_reg_error reg;
        double dy_short_um;             /* mean over vertical neighbour pairs of true − measured dy */
        size_t ok, n;
};

/* The true relative y shift of b to a about the overlap centre c (b's correction minus a's). */
static inline double mosaic_true_dy(const struct imp_mosaic_tile *a, const struct imp_mosaic_tile *b, const double c[2]) {
        double cy[2];
        const struct imp_mosaic_tile *t[2] = { a, b };
        for (int k = 0; k < 2; k++)
                cy[k] = t[k]->truth[1] - t[k]->nominal_mm[1] + t[k]->truth[2] * (c[0] - t[k]->nominal_mm[0]);
        return cy[1] - cy[0];
}

/* Registers and adjusts the painting in dir with options o; ret gets the figures. */
static inline void mosaic_fit_run(const char *dir, const struct imp_mosaic_options *o, struct mosaic_fit *ret) {
        struct imp_painting p;
        struct imp_error err = { 0 };
        memset(ret, 0, sizeof *ret);
        CHECK_OK(imp_painting_load(dir, &p, &err));
        CHECK(p.has_truth);
        struct imp_mosaic_pair *pairs = NULL;
        CHECK_OK(imp_mosaic_register(&p, o, &pairs, &ret->n, &err));
        double s = 0;
        int nv = 0;
        for (size_t i = 0; i < ret->n; i++) {
                const struct imp_mosaic_pair *pr = &pairs[i];
                ret->ok += pr->ok;
                const struct imp_mosaic_tile *a = &p.tiles[pr->a], *b = &p.tiles[pr->b];
                if (pr->ok && a->col == b->col && b->row == a->row + 1)
                        s += 1e3 * (mosaic_true_dy(a, b, pr->c_mm) - pr->meas[1]), nv++;
        }
        ret->dy_short_um = nv ? s / nv : NAN;
        struct imp_mosaic_adjust_stats st;
        CHECK_OK(imp_mosaic_adjust(&p, pairs, ret->n, &st, &err));
        CHECK_OK(imp_mosaic_registration_error(&p, &ret->reg));
        free(pairs);
        imp_painting_done(&p);
}
