# impastod's streamed runs (constant-state frames captured free-running) on the emulated rig,
# and test-daemon-kill again with a plan of repeat runs (seeded kills mid-run). GigE camera
# on UDP 127.0.0.1:3956 (RESOURCE_LOCK gvcp); Modbus ports 15900 and 15901.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-stream LABELS integration LIBS impasto_proto impasto_pipeline impasto_emu TIMEOUT 120)
  add_dependencies(test-daemon-stream impastod)
  set_tests_properties(test-daemon-stream PROPERTIES RESOURCE_LOCK gvcp)
  add_test(NAME test-daemon-kill-repeat COMMAND test-daemon-kill repeat)   # target from daemon.cmake
  set_tests_properties(test-daemon-kill-repeat PROPERTIES LABELS "integration;fault;slow" SKIP_RETURN_CODE 77
    TIMEOUT 300 RESOURCE_LOCK gvcp)
endif()
# - test-daemon-replug: the camera unplugged mid-capture (streamed run, then triggered
#   sweep), the session pauses with a fault, the camera comes back, resume completes the set
#   frame for frame (Modbus TCP 15902).
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-replug LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu
               TIMEOUT 240)
  add_dependencies(test-daemon-replug impastod)
  set_tests_properties(test-daemon-replug PROPERTIES RESOURCE_LOCK gvcp)
endif()
# - test-daemon-pause-reopen: a camera stalls once past its frame timeout, the session (one
#   attempt per step) pauses, the resume opens the camera afresh and completes the set frame
#   for frame (Modbus TCP 15904).
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-pause-reopen LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu
               TIMEOUT 180)
  add_dependencies(test-daemon-pause-reopen impastod)
  set_tests_properties(test-daemon-pause-reopen PROPERTIES RESOURCE_LOCK gvcp)
endif()
