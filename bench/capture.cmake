# Capture to disk through impastod (bench/bench-capture-daemon.sh): the fake GigE camera with
# a settable software-trigger polling rate (bench-fake-camera.c, `-c fast`).
if(IMPASTO_WITH_ARAVIS)
  add_executable(bench-fake-camera ${CMAKE_CURRENT_SOURCE_DIR}/bench-fake-camera.c)
  target_link_libraries(bench-fake-camera PRIVATE PkgConfig::ARAVIS_PKG)
endif()
