# Photometric import: the simulated export (`bench-import export`) and the Woodham baseline
# against `--photometric-only` (`bench-import woodham`), docs/import.md.
add_executable(bench-import ${PROJECT_SOURCE_DIR}/bench/bench-import.c ${PROJECT_SOURCE_DIR}/bench/bench-import-sim.c)
target_link_libraries(bench-import PRIVATE impasto_pipeline impasto_sim)
