# Structured-light decoding (pipeline/geometry/structured-light.c) and the OpenCV comparison.
impasto_test(test-sl-decode LIBS impasto_pipeline)
# The same checks on the decoder built without its AVX2 clones: the SSE2 code that a CPU
# without AVX2 runs (the clones are chosen by the CPU at load time, so a machine with AVX2
# never runs it otherwise).
impasto_test(test-sl-decode-sse2 SOURCE unit/test-sl-decode.c LIBS impasto_pipeline)
target_sources(test-sl-decode-sse2 PRIVATE ${PROJECT_SOURCE_DIR}/pipeline/geometry/structured-light.c)
target_compile_definitions(test-sl-decode-sse2 PRIVATE IMPASTO_SL_NO_CLONES)
impasto_test(test-sl-stability LABELS stability LIBS impasto_pipeline)
# σ and flags where the decoder's model breaks (contradicting phase, clipped phase frames).
impasto_test(test-sl-honest LABELS stability LIBS impasto_pipeline)
if(TARGET impasto_cv)
  # Real procam captures decoded by impasto and by OpenCV's GrayCodePattern.
  impasto_test(test-sl-procam LABELS unit LIBS impasto_pipeline impasto_cv)
endif()
# The 16-bit confidence and σ maps within their stated bounds (encoders and decoded maps).
impasto_test(test-sl-narrow LIBS impasto_pipeline)
impasto_test(test-sl-narrow-sse2 SOURCE unit/test-sl-narrow.c LIBS impasto_pipeline)
target_sources(test-sl-narrow-sse2 PRIVATE ${PROJECT_SOURCE_DIR}/pipeline/geometry/structured-light.c)
target_compile_definitions(test-sl-narrow-sse2 PRIVATE IMPASTO_SL_NO_CLONES)
