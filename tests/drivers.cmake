# Drivers against the emulators (sim/emu). Tests that use the GigE fake camera bind UDP
# 127.0.0.1:3956 and take RESOURCE_LOCK gvcp; each Modbus test has its own TCP port
# (158xx); the gpiochip test runs under umockdev-wrapper (LD_PRELOAD of umockdev).
if(TARGET impasto_emu)
  if(IMPASTO_WITH_MODBUS)
    impasto_test(test-drv-modbus LABELS integration LIBS impasto_drivers impasto_emu TIMEOUT 60)
    impasto_test(test-drv-modbus-fault LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 60)
  endif()
  if(IMPASTO_WITH_ARAVIS)
    impasto_test(test-drv-aravis LABELS integration LIBS impasto_drivers impasto_emu TIMEOUT 60)
    set_tests_properties(test-drv-aravis PROPERTIES RESOURCE_LOCK gvcp)
    # a controller SIGKILLed mid-acquisition; the next one must get frames (~5 s: the heartbeat)
    impasto_test(test-drv-aravis-takeover LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 60)
    set_tests_properties(test-drv-aravis-takeover PROPERTIES RESOURCE_LOCK gvcp)
  endif()
  if(IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
    impasto_test(test-drv-sync LABELS integration LIBS impasto_drivers impasto_emu TIMEOUT 60)
    set_tests_properties(test-drv-sync PROPERTIES RESOURCE_LOCK gvcp)
  endif()
  if(IMPASTO_WITH_GPIOD AND IMPASTO_WITH_UMOCKDEV)
    # The test re-executes itself under umockdev-wrapper when the preload is missing.
    impasto_test(test-drv-gpiod LABELS integration LIBS impasto_drivers impasto_emu TIMEOUT 60)
  endif()
endif()
