# Photometric import: the simulated export (`bench-import export`) and the Woodham baseline
# against `--photometric-only` (`bench-import woodham`), docs/import.md.
add_executable(bench-import ${PROJECT_SOURCE_DIR}/bench/bench-import.c ${PROJECT_SOURCE_DIR}/bench/bench-import-sim.c)
target_link_libraries(bench-import PRIVATE impasto_pipeline impasto_sim)

# Real chessboard captures through `import sl`: plane RMS of impasto's and OpenCV's
# triangulation of the same correspondences (needs OpenCV).
if(TARGET impasto_cv)
  add_executable(bench-import-sl ${PROJECT_SOURCE_DIR}/bench/bench-import-sl.c)
  target_link_libraries(bench-import-sl PRIVATE impasto_pipeline impasto_cv)
endif()
