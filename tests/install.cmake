# `cmake --install` into a DESTDIR: installed units verified, the installed impastod started
# as its unit starts it in front of the emulated rig (tests/install/install-test.sh). Needs
# the whole tree built (cmake --install installs every target).
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  add_test(NAME test-install
    COMMAND sh ${PROJECT_SOURCE_DIR}/tests/install/install-test.sh ${PROJECT_SOURCE_DIR} ${PROJECT_BINARY_DIR})
  set_tests_properties(test-install PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 300)
endif()
