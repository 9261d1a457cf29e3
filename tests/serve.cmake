# The simulated rig served through the real protocols (sim/serve.h) and the projector's
# Modbus backend. Each Modbus test has its own TCP port (158xx); tests with a GigE camera
# bind UDP 127.0.0.1:3956 and take RESOURCE_LOCK gvcp.
if(TARGET impasto_emu AND IMPASTO_WITH_MODBUS)
  impasto_test(test-drv-projector-modbus LABELS integration LIBS impasto_drivers impasto_emu TIMEOUT 60)
  if(IMPASTO_WITH_ARAVIS)
    impasto_test(test-sim-serve LABELS integration LIBS impasto_sim impasto_drivers TIMEOUT 60)
    set_tests_properties(test-sim-serve PROPERTIES RESOURCE_LOCK gvcp)
    # a gantry scene: the GRBL stage on a pseudo-terminal, frames rendered at the carriage (port 15933)
    impasto_test(test-sim-serve-gantry LABELS integration LIBS impasto_sim impasto_drivers TIMEOUT 120)
    set_tests_properties(test-sim-serve-gantry PROPERTIES RESOURCE_LOCK gvcp)
  endif()
endif()
