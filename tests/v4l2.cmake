# Camera backends on kernel interfaces: V4L2 against the umockdev-emulated /dev/video0
# (the test re-executes itself under umockdev-wrapper), libcamera for "no camera → -ENODEV"
# only (there is no libcamera emulator; skipped when its camera manager cannot start).
if(TARGET impasto_emu AND IMPASTO_WITH_V4L2 AND IMPASTO_WITH_UMOCKDEV)
  impasto_test(test-drv-v4l2 LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 60)
endif()
if(IMPASTO_WITH_LIBCAMERA)
  impasto_test(test-drv-libcamera LABELS unit integration LIBS impasto_drivers TIMEOUT 60)
endif()
if(TARGET test-drv-libcamera)
  target_include_directories(test-drv-libcamera PRIVATE ${PROJECT_SOURCE_DIR}/drivers/backends)
endif()
