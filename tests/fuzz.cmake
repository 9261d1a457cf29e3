# Hostile input, found by coverage-guided fuzzing (docs/fuzzing.md). One harness per target
# in tests/fuzz/fuzz-<target>.c. Always: test-fuzz-<target> (label unit) replays every file
# of tests/fuzz/corpus/<target>/ (seeds and every crash a campaign found) through the
# harness. With -DIMPASTO_FUZZ=ON (clang): also the libFuzzer binary fuzz-<target>.
function(impasto_fuzz_target NAME)
  cmake_parse_arguments(F "" "" "LIBS" ${ARGN})
  set(corpus ${CMAKE_CURRENT_SOURCE_DIR}/fuzz/corpus/${NAME})
  impasto_test(test-fuzz-${NAME} SOURCE fuzz/replay.c LIBS ${F_LIBS} ARGS ${corpus} TIMEOUT 300)
  target_sources(test-fuzz-${NAME} PRIVATE fuzz/fuzz-${NAME}.c fuzz/fuzz-util.c)
  target_include_directories(test-fuzz-${NAME} PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/fuzz)
  if(IMPASTO_FUZZ)
    add_executable(fuzz-${NAME} fuzz/fuzz-${NAME}.c fuzz/fuzz-util.c)
    target_include_directories(fuzz-${NAME} PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/fuzz)
    target_link_libraries(fuzz-${NAME} PRIVATE ${F_LIBS} impasto_core)
    target_link_options(fuzz-${NAME} PRIVATE -fsanitize=fuzzer)
  endif()
endfunction()

if(TARGET impasto_proto)
  impasto_fuzz_target(proto LIBS impasto_proto)
endif()
impasto_fuzz_target(captureset LIBS impasto_model)
