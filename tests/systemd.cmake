# systemd units: `systemd-analyze verify` on a copy of the units configured into the build
# tree (cmake/install.cmake) whose ExecStart= points at the build's binaries; any message
# about impasto's units fails the test (skipped without systemd-analyze).
set(IMPASTO_VERIFY_IMPASTOD ${PROJECT_BINARY_DIR}/daemon/impastod)
add_test(NAME test-systemd-verify
  COMMAND sh ${PROJECT_SOURCE_DIR}/tests/systemd-verify.sh ${PROJECT_BINARY_DIR}/systemd
          ${IMPASTO_VERIFY_IMPASTOD} ${PROJECT_BINARY_DIR}/cli/impasto-worker
          ${PROJECT_SOURCE_DIR}/systemd/impasto.sysusers)
set_tests_properties(test-systemd-verify PROPERTIES LABELS unit SKIP_RETURN_CODE 77 TIMEOUT 60)
