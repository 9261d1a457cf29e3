# scripts/demo's daemon flow on the small scene (tests/demo-small.sh): `impasto sim serve`
# (GigE camera on UDP 127.0.0.1:3956, hence RESOURCE_LOCK gvcp; Modbus on TCP 15871),
# impastod with its worker, the scan over the socket, compare against the served truth.
if(TARGET impastod AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  add_test(NAME test-demo-small
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/demo-small.sh ${PROJECT_SOURCE_DIR} ${PROJECT_BINARY_DIR} 15871)
  set_tests_properties(test-demo-small PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 90
    RESOURCE_LOCK gvcp)
endif()
