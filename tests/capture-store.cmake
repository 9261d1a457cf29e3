# Readers never change a capture set and never accept a wrong one; repair is explicit and
# moves into quarantine/ (tests/integration/capture-store-integrity.sh; a 54-frame render of
# config/scenes/small.cfg, ~10 s, and one --no-btf process).
if(TARGET impasto)
  add_test(NAME test-capture-store-integrity
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/capture-store-integrity.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
  set_tests_properties(test-capture-store-integrity PROPERTIES LABELS "integration;fault" SKIP_RETURN_CODE 77
    TIMEOUT 300)
endif()
