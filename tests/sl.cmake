# Structured-light decoding (pipeline/geometry/structured-light.c) and the OpenCV comparison.
impasto_test(test-sl-decode LIBS impasto_pipeline)
impasto_test(test-sl-stability LABELS stability LIBS impasto_pipeline)
# σ and flags where the decoder's model breaks (contradicting phase, clipped phase frames).
impasto_test(test-sl-honest LABELS stability LIBS impasto_pipeline)
if(TARGET impasto_cv)
  # Real procam captures decoded by impasto and by OpenCV's GrayCodePattern.
  impasto_test(test-sl-procam LABELS unit LIBS impasto_pipeline impasto_cv)
endif()
