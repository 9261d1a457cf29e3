# impastod and plans from clients: no @include escape, no FIFO stalling the loop, no
# existence oracle outside the plan directory, no expansion bomb (daemon/planpath.c,
# pipeline/model/plan.c). Modbus port 15917; run in a private network namespace.
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  impasto_test(test-daemon-plans LABELS integration fault LIBS impasto_proto impasto_pipeline impasto_emu TIMEOUT 120)
  add_dependencies(test-daemon-plans impastod)
  set_tests_properties(test-daemon-plans PROPERTIES RESOURCE_LOCK gvcp)
endif()
