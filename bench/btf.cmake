# Fit throughput (texels/s) and peak RSS of the per-texel Lafortune fit.
add_executable(bench-fit ${PROJECT_SOURCE_DIR}/bench/bench-fit.c)
target_include_directories(bench-fit PRIVATE ${PROJECT_SOURCE_DIR}/tests)
target_link_libraries(bench-fit PRIVATE impasto_pipeline)

# Diagnosis of the held-out re-render error on a simulated capture (true vs fitted
# geometry and BRDF through the validation's extraction and shading).
add_executable(diag-rerender ${PROJECT_SOURCE_DIR}/bench/diag-rerender.c)
target_link_libraries(diag-rerender PRIVATE impasto_pipeline)
