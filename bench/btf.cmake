# Fit throughput (texels/s) and peak RSS of the per-texel Lafortune fit (issue #5).
add_executable(bench-fit ${PROJECT_SOURCE_DIR}/bench/bench-fit.c
  ${PROJECT_SOURCE_DIR}/pipeline/btf-samples.c ${PROJECT_SOURCE_DIR}/pipeline/btf-fit.c)
target_include_directories(bench-fit PRIVATE ${PROJECT_SOURCE_DIR}/pipeline ${PROJECT_SOURCE_DIR}/tests)
target_link_libraries(bench-fit PRIVATE impasto_core)
if(OpenMP_C_FOUND)
  target_link_libraries(bench-fit PRIVATE OpenMP::OpenMP_C)
endif()
