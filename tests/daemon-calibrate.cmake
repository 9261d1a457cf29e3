# impastod's `calibrate`, plan-path confinement and socket activation (issues #7, #8), as
# shell scripts in tests/integration/ driving the real binaries:
# - test-daemon-calibrate: `impasto sim serve` (GigE camera on 127.0.0.1:3956, hence
#   RESOURCE_LOCK gvcp; Modbus on TCP 15895) with a noisy flat white target; the daemon
#   captures the photon-transfer plan, runs the radiometric routine as its own job (SIGKILLed
#   once mid-routine), stores calibration versions 1 and 2; plan paths outside --plan-dir
#   refused. About 15 s.
# - test-daemon-socket-activation: impastod exec'd by systemd-socket-activate (LISTEN_FDS=1,
#   fd 3) serves the inherited socket and creates none of its own. About 1 s.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  add_test(NAME test-daemon-calibrate
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/integration/daemon-calibrate.sh ${PROJECT_BINARY_DIR}
            ${PROJECT_SOURCE_DIR} 15895)
  set_tests_properties(test-daemon-calibrate PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 400
    RESOURCE_LOCK gvcp)
endif()
if(TARGET impastod)
  add_test(NAME test-daemon-socket-activation
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/integration/daemon-socket-activation.sh ${PROJECT_BINARY_DIR}
            ${PROJECT_SOURCE_DIR})
  set_tests_properties(test-daemon-socket-activation PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 60)
endif()
# - test-daemon-fulldisk: a real full disk: a private mount namespace with a 16 MiB tmpfs as
#   the state directory, filled during a sweep (in-process emulators of
#   tests/unit/test-daemon-harness.c, GVCP and Modbus TCP 15896); skipped without root or
#   when unshare/mount is not permitted. About 5 s.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-fulldisk SOURCE integration/test-daemon-fulldisk.c LABELS integration fault
    LIBS impasto_proto impasto_pipeline impasto_emu TIMEOUT 120)
  add_dependencies(test-daemon-fulldisk impastod)
  set_tests_properties(test-daemon-fulldisk PROPERTIES RESOURCE_LOCK gvcp)
endif()
# - test-daemon-calibrate-lights: the daemon calibrates the 56 dome lights from the mirror
#   target captured at three board heights (lights-target-raised and -mid as sessions, then
#   lights-target by `calibrate start lights` with mirror detection and the two sessions at
#   40 and 20 mm; Modbus TCP 15897), compared with the truth. 2 to 7
#   minutes (110 s at load 2, 397 s at load 10-12 on 2 cores), mostly rendering: slow.
# - test-daemon-calibrate-camera: camera (and projector) calibration through the daemon from
#   four board poses (target-3, -8, -10 captured as sessions, target-0 by `calibrate camera`
#   as the canvas reference; Modbus TCP 15898), compared with the truth. About 5 minutes,
#   mostly rendering: slow; needs OpenCV.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  foreach(routine_port lights:15897 camera:15898)
    string(REPLACE ":" ";" rp ${routine_port})
    list(GET rp 0 routine)
    list(GET rp 1 port)
    if(routine STREQUAL "camera" AND NOT TARGET impasto_cv)
      continue()
    endif()
    add_test(NAME test-daemon-calibrate-${routine}
      COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/integration/daemon-calibrate-${routine}.sh ${PROJECT_BINARY_DIR}
              ${PROJECT_SOURCE_DIR} ${port})
    set_tests_properties(test-daemon-calibrate-${routine} PROPERTIES LABELS "integration;slow"
      SKIP_RETURN_CODE 77 TIMEOUT 1200 RESOURCE_LOCK gvcp)
  endforeach()
endif()
