# Motion stage drivers against their emulators: Modbus TCP on 127.0.0.1:15861 and 15862 (run inside a
# private network namespace when others test at once), GRBL on a pseudo-terminal.
if(TARGET impasto_emu)
  if(IMPASTO_WITH_MODBUS)
    impasto_test(test-drv-stage-modbus LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 120)
  endif()
  impasto_test(test-drv-stage-grbl LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 120)
endif()
