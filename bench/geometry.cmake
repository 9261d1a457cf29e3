# Geometry pipeline throughput: each stage on a synthetic 4-Mpix input (not run by CTest).
add_executable(bench-geometry ${CMAKE_CURRENT_SOURCE_DIR}/bench-geometry.c)
target_link_libraries(bench-geometry PRIVATE impasto_pipeline)
