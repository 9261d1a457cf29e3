# impastod with a damaged session.json and a crash's unrecorded frame: the session is listed
# as damaged and session.resume rebuilds it from the set; the frame goes to quarantine/
# (daemon/store.c, daemon/session.c). Modbus port 15918; run in a private network namespace.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-recover LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu TIMEOUT 120)
  add_dependencies(test-daemon-recover impastod)
  set_tests_properties(test-daemon-recover PROPERTIES RESOURCE_LOCK gvcp)
endif()
