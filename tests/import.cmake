# Captures from other rigs (docs/import.md): the photometric import, --photometric-only and
# compare-normals on synthetic stacks; the simulator round trip (export → import → process
# gives the native set's normals).
impasto_test(test-import LIBS impasto_pipeline)
impasto_test(test-import-roundtrip LABELS integration TIMEOUT 600 LIBS impasto_pipeline impasto_sim
  SOURCE unit/test-import-roundtrip.c)
target_sources(test-import-roundtrip PRIVATE ${PROJECT_SOURCE_DIR}/bench/bench-import-sim.c)
target_include_directories(test-import-roundtrip PRIVATE ${PROJECT_SOURCE_DIR}/bench)
# Gray-code sequences in OpenCV's order (import sl); the real capture part reads
# ../shared/data/procam-graycode (skipped when absent) and decodes 1280x1024 frames.
impasto_test(test-import-sl LABELS integration LIBS impasto_pipeline)
if(TARGET impasto_cv)
  impasto_test(test-import-sl-xml LIBS impasto_pipeline impasto_cv)
endif()
# imp_range_from_set decodes coords_only: the same range image as a decode with every map.
impasto_test(test-process-range LIBS impasto_pipeline)
