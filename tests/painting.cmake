# Whole paintings: the plan's painting group, the simulated gantry (sim/gantry.c), stage
# errors, tile windows, painting.json and the painting-frame truth.
impasto_test(test-painting LABELS unit LIBS impasto_sim)
# Two tiles landed with different stage errors see one painting surface (sim/scene.c, render.c).
impasto_test(test-sim-painting-lattice LABELS unit LIBS impasto_sim)
# `plan estimate` of a painting plan: whole-painting figures, and a plan that cannot fit any
# disk (141 TB) refused with exit 3 and a message naming the bytes and the directory.
add_test(NAME test-painting-estimate COMMAND sh -c "\
  out=$($<TARGET_FILE:impasto> plan estimate ${PROJECT_SOURCE_DIR}/config/plans/painting-small.cfg \
        --scene ${PROJECT_SOURCE_DIR}/config/scenes/painting-small.cfg --json) && \
  echo \"$out\" | grep -q '\"painting\":{\"tiles\":9,\"cols\":3,\"rows\":3' && \
  printf 'dome = { lights = \"all\"; exposures_us = [10000.0]; repeat = 2000; };\\npainting = { extent_mm = [5000.0, 5000.0]; fov_mm = [20.0, 20.0]; };\\n' > huge-painting.cfg && \
  ! $<TARGET_FILE:impasto> plan estimate huge-painting.cfg --scene ${PROJECT_SOURCE_DIR}/config/scenes/painting-small.cfg --target . 2> err.txt; \
  rc=$?; grep -q 'on disk but . has' err.txt && test $rc -eq 0"
  WORKING_DIRECTORY ${CMAKE_CURRENT_BINARY_DIR})
set_tests_properties(test-painting-estimate PROPERTIES LABELS unit TIMEOUT 120)
# `plan estimate` of a whole painting within 10 % of the simulator's clock (sim info: computed,
# not wall time): painting-small, painting-300x200 and a slow gantry whose moves dominate.
add_test(NAME test-painting-estimate-clock COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/painting-estimate-clock.sh
  ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
set_tests_properties(test-painting-estimate-clock PROPERTIES LABELS unit TIMEOUT 120 SKIP_RETURN_CODE 77)
# The painting demo end to end on the small painting (scripts/demo-painting): through impastod,
# `sim serve` and the GRBL emulator (Modbus port 15933, the GigE port: run in a private network
# namespace), checking the figures it prints (~3 min on a loaded 2-core machine): slow; and the
# offline path (sim render, process, mosaic).
if(TARGET impastod AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  add_test(NAME test-painting-demo COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/painting-demo.sh
    ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR} 15933)
  set_tests_properties(test-painting-demo PROPERTIES LABELS "integration;slow" TIMEOUT 1800 SKIP_RETURN_CODE 77
                       RESOURCE_LOCK gvcp)
endif()
add_test(NAME test-painting-demo-offline COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/painting-demo.sh
  ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR} 0 --offline)
set_tests_properties(test-painting-demo-offline PROPERTIES LABELS "integration;slow" TIMEOUT 1800
                     SKIP_RETURN_CODE 77)
# Whole-painting sessions on the gantry (daemon/tile-session.c) against the GRBL emulator on a
# pseudo-terminal (no network).
if(TARGET impasto_emu)
  impasto_test(test-painting-stage LABELS integration fault LIBS impasto_drivers impasto_emu TIMEOUT 120)
  target_sources(test-painting-stage PRIVATE ${PROJECT_SOURCE_DIR}/daemon/tile-session.c)
  target_include_directories(test-painting-stage PRIVATE ${PROJECT_SOURCE_DIR}/daemon ${PROJECT_SOURCE_DIR}/sim/emu)
endif()
# impastod scanning a painting tile by tile on the GRBL emulator (daemon/session-painting.c):
# poses per frame, a job per tile, stage faults that pause and resume, status answered and
# pause soft-stopping while a move is pending, plan.estimate's painting figures, 3 SIGKILLs (Modbus port
# 15931); the slow variant kills it at 20 random points (port 15932). Run in a private network
# namespace.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-painting-daemon LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu
               TIMEOUT 300)
  target_include_directories(test-painting-daemon PRIVATE ${PROJECT_SOURCE_DIR}/sim/emu)
  add_dependencies(test-painting-daemon impastod impasto)
  set_tests_properties(test-painting-daemon PROPERTIES RESOURCE_LOCK gvcp)
  # The same session on the Modbus stage driver and emulator (ports 15933, 15934).
  add_test(NAME test-painting-daemon-modbus COMMAND test-painting-daemon modbus)
  set_tests_properties(test-painting-daemon-modbus PROPERTIES LABELS "integration;fault" SKIP_RETURN_CODE 77
                       TIMEOUT 300 RESOURCE_LOCK gvcp)
  add_test(NAME test-painting-daemon-kill COMMAND test-painting-daemon kill 20)
  set_tests_properties(test-painting-daemon-kill PROPERTIES LABELS "integration;fault;slow" SKIP_RETURN_CODE 77
                       TIMEOUT 900 RESOURCE_LOCK gvcp)
endif()
