# Real backends of the driver classes; each builds only when its library was found
# (IMPASTO_WITH_*), and defines IMPASTO_HAVE_* so the wrappers list it by name.
set(IMP_BACKEND_DIR ${CMAKE_CURRENT_SOURCE_DIR}/backends)
target_include_directories(impasto_drivers PRIVATE ${IMP_BACKEND_DIR})
if(IMPASTO_WITH_ARAVIS)
  target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/camera-aravis.c)
  target_link_libraries(impasto_drivers PUBLIC PkgConfig::ARAVIS_PKG)
  target_compile_definitions(impasto_drivers PUBLIC IMPASTO_HAVE_ARAVIS=1)
endif()
if(IMPASTO_WITH_MODBUS)
  target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/dome-modbus.c
                 ${IMP_BACKEND_DIR}/modbus-link.c ${IMP_BACKEND_DIR}/projector-modbus.c
                 ${IMP_BACKEND_DIR}/stage-modbus.c)
  target_link_libraries(impasto_drivers PUBLIC PkgConfig::MODBUS_PKG)
  target_compile_definitions(impasto_drivers PUBLIC IMPASTO_HAVE_MODBUS=1)
endif()
# Stage "grbl": G-code over a serial line, termios only (docs/drivers.md, "Motion stage").
target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/stage-grbl.c)
if(IMPASTO_WITH_GPIOD)
  target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/dome-gpiod.c)
  target_link_libraries(impasto_drivers PUBLIC PkgConfig::GPIOD_PKG)
  target_compile_definitions(impasto_drivers PUBLIC IMPASTO_HAVE_GPIOD=1)
endif()
if(IMPASTO_WITH_V4L2)
  # Kernel V4L2 API only (<linux/videodev2.h>); libv4l2 is not linked.
  target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/camera-v4l2.c)
  target_link_libraries(impasto_drivers PUBLIC m)
  target_compile_definitions(impasto_drivers PUBLIC IMPASTO_HAVE_V4L2=1)
endif()
if(IMPASTO_WITH_LIBCAMERA)
  # A thin C++17 shim behind the C camera interface.
  target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/camera-libcamera.cpp)
  target_link_libraries(impasto_drivers PUBLIC PkgConfig::LIBCAMERA_PKG)
  target_compile_definitions(impasto_drivers PUBLIC IMPASTO_HAVE_LIBCAMERA=1)
endif()
if(IMPASTO_WITH_LIBUSB)
  # Projector "usb-dlp": framed commands over bulk endpoints (docs/projector-usb.md).
  target_sources(impasto_drivers PRIVATE ${IMP_BACKEND_DIR}/projector-usb.c)
  target_link_libraries(impasto_drivers PUBLIC PkgConfig::LIBUSB_PKG)
  target_compile_definitions(impasto_drivers PUBLIC IMPASTO_HAVE_LIBUSB=1)
endif()
