# Photometric normal refinement from the dome sweep (pipeline/appearance/photometric.c, issue #4).
impasto_test(test-photometric LIBS impasto_pipeline)
