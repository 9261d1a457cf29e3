# The "usb-dlp" projector backend against the usbdevfs emulator (sim/emu/emu-usb.c), under
# umockdev-wrapper (the test re-executes itself there when the preload is missing).
if(TARGET impasto_emu AND IMPASTO_WITH_LIBUSB AND IMPASTO_WITH_UMOCKDEV)
  impasto_test(test-drv-projector-usb LABELS integration LIBS impasto_drivers impasto_emu TIMEOUT 60)
endif()
