# impastod.conf errors name FILE:LINE and the field; scheduler = "slurm" without its settings
# is refused (tests/install/daemon-conf.sh; the daemon stops before it binds anything).
add_test(NAME test-daemon-conf
  COMMAND sh ${PROJECT_SOURCE_DIR}/tests/install/daemon-conf.sh ${PROJECT_BINARY_DIR})
set_tests_properties(test-daemon-conf PROPERTIES LABELS unit SKIP_RETURN_CODE 77 TIMEOUT 120)
