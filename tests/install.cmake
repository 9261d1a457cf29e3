# `cmake --install` into a DESTDIR: installed units verified, the installed impastod started
# as its unit starts it in front of the emulated rig (tests/install/install-test.sh). Needs
# the whole tree built (cmake --install installs every target).
if(TARGET impastod AND TARGET impasto_emu AND IMPASTO_WITH_ARAVIS AND IMPASTO_WITH_MODBUS)
  add_test(NAME test-install
    COMMAND sh ${PROJECT_SOURCE_DIR}/tests/install/install-test.sh ${PROJECT_SOURCE_DIR} ${PROJECT_BINARY_DIR})
  # Both run `impasto sim serve`: its GigE camera binds UDP 127.0.0.1:3956 (RESOURCE_LOCK gvcp,
  # as every test with an emulated camera) and its Modbus controller TCP 15020. Without the
  # lock a concurrent test's fake camera answered this one's control reads while its frames
  # went elsewhere: every resume timed out on a grab (CI, session 10).
  set_tests_properties(test-install PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 300
                       RESOURCE_LOCK gvcp)
  # The same, then a queued two-painting night on the installed daemon and config: an injected
  # camera fault, a SIGKILL, a failed job; status, report, session.log and the hook checked
  # (tests/install/night.sh; ~16 s).
  add_test(NAME test-install-night
    COMMAND sh ${PROJECT_SOURCE_DIR}/tests/install/install-test.sh ${PROJECT_SOURCE_DIR} ${PROJECT_BINARY_DIR} night)
  set_tests_properties(test-install-night PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 900
                       RESOURCE_LOCK gvcp)
endif()
