# Multi-resolution view-dependent texture (pipeline/appearance/multires.c, seed 003).
impasto_test(test-multires LIBS impasto_pipeline)
