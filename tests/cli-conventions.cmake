# The client's conventions: strict numbers and "did you mean" (unit), and the commands as an
# operator types them: --version, help [CMD], a mistyped command (tests/install/cli-conventions.sh).
impasto_test(test-cli-numparse LIBS impasto_pipeline)
target_sources(test-cli-numparse PRIVATE ${PROJECT_SOURCE_DIR}/cli/numparse.c ${PROJECT_SOURCE_DIR}/cli/help.c)
target_include_directories(test-cli-numparse PRIVATE ${PROJECT_SOURCE_DIR}/cli)
add_test(NAME test-cli-conventions
  COMMAND sh ${PROJECT_SOURCE_DIR}/tests/install/cli-conventions.sh ${PROJECT_BINARY_DIR})
set_tests_properties(test-cli-conventions PROPERTIES LABELS unit SKIP_RETURN_CODE 77 TIMEOUT 60)
