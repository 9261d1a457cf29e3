/* Where a stage of imp_process_capture() lies in the whole run (process.h), shared by the
 * worker's job progress and `impasto process`'s overall ETA. */
#include <string.h>
#include "process.h"

/* Each stage's span of the whole run, roughly its share of the time on the demo scenes;
 * a stage not listed keeps the fraction where it is. */
static const struct { const char *stage; double from, to; } stage_spans[] = {
        { "hdr merge", 0.00, 0.25 },      { "decode", 0.25, 0.35 },      { "triangulate", 0.35, 0.40 },
        { "heightfield", 0.40, 0.45 },    { "boxes", 0.45, 0.50 },       { "dome hdr merge", 0.50, 0.70 },
        { "btf fit", 0.70, 0.95 },        { "validation", 0.95, 1.00 },
};

double imp_process_fraction(double previous, const char *stage, size_t done, size_t total) {
        for (size_t i = 0; i < sizeof stage_spans / sizeof stage_spans[0]; i++)
                if (!strcmp(stage, stage_spans[i].stage)) {
                        double f = stage_spans[i].from + (stage_spans[i].to - stage_spans[i].from) *
                                   (total ? (double) done / (double) total : 1.0);
                        return f > previous ? f : previous;
                }
        return previous;
}
