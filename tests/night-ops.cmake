# The operator's night beyond test-install-night (tests/integration/daemon-night-ops.sh):
# a hanging hook killed at hook_timeout_s while the loop answers, disk_low in status, jobs
# follow to the end and Ctrl-C during jobs/scan follow (exit 130), queue add/move/cancel kept
# across a restart, the interrupted session after a SIGKILL in status and session.log, a
# damaged queue.json (not JSON; a wrong field type) set aside with the daemon running, and
# `impasto devices` with the rig unplugged. `impasto sim serve` (GigE on 127.0.0.1:3956,
# hence RESOURCE_LOCK gvcp; Modbus TCP 15881). About 90 s; 130 s on a loaded machine.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  add_test(NAME test-daemon-night-ops
    COMMAND bash ${CMAKE_CURRENT_SOURCE_DIR}/integration/daemon-night-ops.sh ${PROJECT_BINARY_DIR}
            ${PROJECT_SOURCE_DIR} 15881)
  set_tests_properties(test-daemon-night-ops PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 400
    RESOURCE_LOCK gvcp)
endif()
