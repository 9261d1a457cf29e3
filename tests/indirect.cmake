# Simulator interreflection (sim/indirect.c, seed 002 irradiance-vector grids). The test
# compiles sim/indirect.c itself so it does not depend on the rest of impasto_sim.
impasto_test(test-sim-indirect LABELS unit)
target_sources(test-sim-indirect PRIVATE ${PROJECT_SOURCE_DIR}/sim/indirect.c)
target_compile_options(test-sim-indirect PRIVATE -Werror)
target_include_directories(test-sim-indirect PRIVATE ${PROJECT_SOURCE_DIR}/sim
  ${PROJECT_SOURCE_DIR}/pipeline)
if(OpenMP_C_FOUND)
  target_link_libraries(test-sim-indirect PRIVATE OpenMP::OpenMP_C)
endif()
