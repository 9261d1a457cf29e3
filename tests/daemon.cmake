# impastod end to end: the emulated rig in the test process (GigE camera on UDP 127.0.0.1:3956,
# hence RESOURCE_LOCK gvcp; Modbus dome on TCP 1585x, one port per test), impastod as a child
# process on a temporary socket and state directory, driven through the shared codec.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  foreach(t session kill hostile)
    if(t STREQUAL "session")
      set(labels integration)
    else()
      set(labels integration fault)
    endif()
    impasto_test(test-daemon-${t} LABELS ${labels} LIBS impasto_proto impasto_pipeline impasto_emu TIMEOUT 300)
    add_dependencies(test-daemon-${t} impastod)
    set_tests_properties(test-daemon-${t} PROPERTIES RESOURCE_LOCK gvcp)
  endforeach()
endif()

# test-daemon-limits PART: the socket's access control and limits (docs/security.md), one
# impastod per part; needs root (clients as other uids, a private /etc/group), else skipped.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-limits LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu
               TIMEOUT 120 ARGS roles)
  add_dependencies(test-daemon-limits impastod impasto)
  set_tests_properties(test-daemon-limits PROPERTIES RESOURCE_LOCK gvcp)
  foreach(part pidns slowreader slots devices instance verdict)
    add_test(NAME test-daemon-limits-${part} COMMAND test-daemon-limits ${part})
    set_tests_properties(test-daemon-limits-${part} PROPERTIES LABELS "integration;fault" SKIP_RETURN_CODE 77
                         TIMEOUT 120 RESOURCE_LOCK gvcp)
  endforeach()
endif()

# test-daemon-abuse: a slow reader, a slowloris, a memory-bomb plan and @include escapes at
# once during a capture (docs/security.md); needs root, else skipped.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-abuse LABELS integration stability fault LIBS impasto_proto impasto_pipeline impasto_emu
               TIMEOUT 180)
  add_dependencies(test-daemon-abuse impastod)
  set_tests_properties(test-daemon-abuse PROPERTIES RESOURCE_LOCK gvcp)
endif()
