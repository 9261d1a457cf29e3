# Hybrid renderer speed per mode, view and box size in the shape of the seed's Tables 1–2.
add_executable(bench-relief ${PROJECT_SOURCE_DIR}/bench/bench-relief.c)
target_link_libraries(bench-relief PRIVATE impasto_pipeline)
