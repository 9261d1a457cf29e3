# Throughput of the photometric texel model against main's copy of it (bench-pn-model.c;
# the copy and the texels in tests/unit/, shared with test-photometric-model).
add_executable(bench-pn-model ${PROJECT_SOURCE_DIR}/bench/bench-pn-model.c
  ${PROJECT_SOURCE_DIR}/tests/unit/pn-model-peer.c)
target_include_directories(bench-pn-model PRIVATE ${PROJECT_SOURCE_DIR}/tests ${PROJECT_SOURCE_DIR}/tests/unit)
target_link_libraries(bench-pn-model PRIVATE impasto_pipeline)
