# impastod's capture store under a full disk and a read-only file system (a private tmpfs:
# root only, else skipped), with the store writer holding frames; Modbus port 15890.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-store LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu TIMEOUT 120)
  add_dependencies(test-daemon-store impastod)
  set_tests_properties(test-daemon-store PROPERTIES RESOURCE_LOCK gvcp)
endif()
