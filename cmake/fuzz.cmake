# IMPASTO_FUZZ (docs/fuzzing.md): every library is built with libFuzzer's coverage
# instrumentation (-fsanitize=fuzzer-no-link) so that tests/fuzz/ can link one fuzzer per
# target with -fsanitize=fuzzer. Needs clang and IMPASTO_SANITIZE (ASan+UBSan find the bugs).
if(IMPASTO_FUZZ)
  if(NOT CMAKE_C_COMPILER_ID MATCHES "Clang")
    message(FATAL_ERROR "IMPASTO_FUZZ=ON needs clang (CC=clang CXX=clang++), not ${CMAKE_C_COMPILER_ID}")
  endif()
  if(NOT IMPASTO_SANITIZE)
    message(FATAL_ERROR "IMPASTO_FUZZ=ON needs IMPASTO_SANITIZE=ON")
  endif()
  include(CheckCSourceCompiles)
  set(CMAKE_REQUIRED_FLAGS "-fsanitize=fuzzer")
  check_c_source_compiles("
#include <stddef.h>
#include <stdint.h>
int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) { (void) d; (void) n; return 0; }"
    IMPASTO_HAVE_LIBFUZZER)
  unset(CMAKE_REQUIRED_FLAGS)
  if(NOT IMPASTO_HAVE_LIBFUZZER)
    message(FATAL_ERROR "IMPASTO_FUZZ=ON: clang cannot link -fsanitize=fuzzer "
      "(scripts/bootstrap --fuzz installs libclang-rt-14-dev)")
  endif()
  # clang reads -Werror=format=2 as also erroring on vprintf-style wrappers; -Wimplicit-fallthrough=5 is GCC's
  add_compile_options(-fsanitize=fuzzer-no-link -Wno-error=format-nonliteral -Wno-unknown-warning-option)
  message(STATUS "impasto: libFuzzer harnesses ON (tests/fuzz)")
endif()
