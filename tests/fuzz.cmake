# Hostile input, found by coverage-guided fuzzing (docs/fuzzing.md). One harness per target
# in tests/fuzz/fuzz-<target>.c. Always: test-fuzz-<target> (label unit) replays every file
# of tests/fuzz/corpus/<target>/ (seeds and every crash a campaign found) through the
# harness. With -DIMPASTO_FUZZ=ON (clang): also the libFuzzer binary fuzz-<target>.
function(impasto_fuzz_target NAME)
  cmake_parse_arguments(F "" "" "LIBS;SOURCES;DEFINES" ${ARGN})
  set(corpus ${CMAKE_CURRENT_SOURCE_DIR}/fuzz/corpus/${NAME})
  # lsan.supp: libconfig's own leak on a syntax error (docs/fuzzing.md), replayed all the same
  impasto_test(test-fuzz-${NAME} SOURCE fuzz/replay.c LIBS ${F_LIBS} ARGS ${corpus} TIMEOUT 300
    ENV LSAN_OPTIONS=suppressions=${CMAKE_CURRENT_SOURCE_DIR}/fuzz/lsan.supp)
  target_sources(test-fuzz-${NAME} PRIVATE fuzz/fuzz-${NAME}.c fuzz/fuzz-util.c ${F_SOURCES})
  target_include_directories(test-fuzz-${NAME} PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/fuzz)
  target_compile_definitions(test-fuzz-${NAME} PRIVATE ${F_DEFINES})
  if(IMPASTO_FUZZ)
    add_executable(fuzz-${NAME} fuzz/fuzz-${NAME}.c fuzz/fuzz-util.c ${F_SOURCES})
    target_include_directories(fuzz-${NAME} PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/fuzz)
    target_compile_definitions(fuzz-${NAME} PRIVATE ${F_DEFINES})
    target_link_libraries(fuzz-${NAME} PRIVATE ${F_LIBS} impasto_core)
    target_link_options(fuzz-${NAME} PRIVATE -fsanitize=fuzzer)
  endif()
endfunction()

if(TARGET impasto_proto)
  impasto_fuzz_target(proto LIBS impasto_proto)
endif()
impasto_fuzz_target(captureset LIBS impasto_model)
# The daemon's own readers (impastod.conf, the rig config) with the daemon's sources but
# its main(), where impastod is built.
if(TARGET impastod)
  file(GLOB fuzz_daemon_sources ${PROJECT_SOURCE_DIR}/daemon/*.c)
  list(REMOVE_ITEM fuzz_daemon_sources ${PROJECT_SOURCE_DIR}/daemon/main.c)
  impasto_fuzz_target(conf LIBS impasto_proto impasto_drivers impasto_model PkgConfig::SYSTEMD_PKG
    SOURCES ${fuzz_daemon_sources} DEFINES FUZZ_WITH_DAEMON)
  target_include_directories(test-fuzz-conf PRIVATE ${PROJECT_SOURCE_DIR}/daemon)
  if(IMPASTO_FUZZ)
    target_include_directories(fuzz-conf PRIVATE ${PROJECT_SOURCE_DIR}/daemon)
  endif()
  # What impastod reads back from its own state directory: jobs, queue.json, sessions
  impasto_fuzz_target(state LIBS impasto_proto impasto_drivers impasto_model PkgConfig::SYSTEMD_PKG
    SOURCES ${fuzz_daemon_sources})
  target_include_directories(test-fuzz-state PRIVATE ${PROJECT_SOURCE_DIR}/daemon)
  if(IMPASTO_FUZZ)
    target_include_directories(fuzz-state PRIVATE ${PROJECT_SOURCE_DIR}/daemon)
  endif()
else()
  impasto_fuzz_target(conf LIBS impasto_model)
endif()
if(TARGET impasto_export)
  impasto_fuzz_target(painting LIBS impasto_export impasto_model)
endif()
impasto_fuzz_target(image LIBS impasto_core)
