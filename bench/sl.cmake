# Structured-light decoding throughput: impasto vs OpenCV GrayCodePattern on real captures.
if(TARGET impasto_cv)
  add_executable(bench-decode bench-decode.c)
  target_link_libraries(bench-decode PRIVATE impasto_pipeline impasto_cv)
  target_compile_definitions(bench-decode PRIVATE
    IMPASTO_SHARED_DIR="${PROJECT_SOURCE_DIR}/../shared")
endif()
