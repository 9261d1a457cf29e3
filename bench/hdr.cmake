# HDR merge: impasto's noise-model merge vs OpenCV's MergeDebevec on synthetic stacks.
if(TARGET impasto_cv)
  add_executable(bench-hdr bench-hdr.c)
  target_link_libraries(bench-hdr PRIVATE impasto_pipeline impasto_cv)
endif()
