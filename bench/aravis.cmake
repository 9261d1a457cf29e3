# GigE Vision capture: impasto's Aravis backend vs arv-camera-test-0.8 on the same emulated
# camera (bench/capture-vs-arv.sh runs both). The camera is another process, so the client's
# CPU time is its own.
if(IMPASTO_WITH_ARAVIS)
  add_executable(bench-aravis ${CMAKE_CURRENT_SOURCE_DIR}/bench-aravis.c)
  target_link_libraries(bench-aravis PRIVATE impasto_drivers)
endif()
