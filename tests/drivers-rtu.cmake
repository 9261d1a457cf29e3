# Issue #6 driver gaps: the Modbus dome over RTU (the emulator serves RTU on a pseudo-
# terminal; no TCP port), and an Aravis camera unplugged mid-stream and plugged back in
# (binds UDP 127.0.0.1:3956, so RESOURCE_LOCK gvcp).
if(TARGET impasto_emu)
  if(IMPASTO_WITH_MODBUS)
    impasto_test(test-drv-modbus-rtu LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 60)
  endif()
endif()
if(TARGET impasto_emu AND IMPASTO_WITH_ARAVIS)
  impasto_test(test-drv-aravis-replug LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 60)
  set_tests_properties(test-drv-aravis-replug PROPERTIES RESOURCE_LOCK gvcp)
endif()
