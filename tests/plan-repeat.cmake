# Scan plans: the dome `repeat` key, runs of one state, the estimate (pipeline/model/plan.c).
impasto_test(test-plan-repeat LIBS impasto_pipeline)
# HDR merge of repeated exposures (pipeline/geometry/hdr.c n_frames, averaged by pipeline/process.c).
impasto_test(test-hdr-repeat LIBS impasto_pipeline)
