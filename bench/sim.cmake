# Simulator throughput: ms per frame of the demo scene with each effect alone on `direct`.
add_executable(bench-sim-effects ${CMAKE_CURRENT_SOURCE_DIR}/bench-sim-effects.c)
target_link_libraries(bench-sim-effects PRIVATE impasto_sim)
target_compile_definitions(bench-sim-effects PRIVATE IMPASTO_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
