# BTF samples and per-texel Lafortune fit (pipeline/btf-*.c, issue #5). The tests build
# the two sources into their own small library so that they do not wait on the rest of
# impasto_pipeline; the code is the same that impasto_pipeline globs.
add_library(impasto_btf_test STATIC ${PROJECT_SOURCE_DIR}/pipeline/btf-samples.c
  ${PROJECT_SOURCE_DIR}/pipeline/btf-fit.c)
target_include_directories(impasto_btf_test PUBLIC ${PROJECT_SOURCE_DIR}/pipeline)
target_link_libraries(impasto_btf_test PUBLIC impasto_core)
if(OpenMP_C_FOUND)
  target_link_libraries(impasto_btf_test PUBLIC OpenMP::OpenMP_C)
endif()

impasto_test(test-btf-samples LIBS impasto_btf_test)
impasto_test(test-btf-fit LIBS impasto_btf_test)
impasto_test(test-btf-stability SOURCE unit/test-btf-stability.c LABELS stability LIBS impasto_btf_test)
