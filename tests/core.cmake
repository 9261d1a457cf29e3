# Base pieces: errors, logging, image formats, config, JSON, capture sets, rig model.
impasto_test(test-error)
impasto_test(test-numerics)
impasto_test(test-hugepages)

# The layer rule of docs/layout.md: no lower layer includes a higher layer's header.
add_test(NAME test-layers COMMAND python3 ${CMAKE_CURRENT_SOURCE_DIR}/layout/check-layers.py ${PROJECT_SOURCE_DIR})
set_tests_properties(test-layers PROPERTIES LABELS unit TIMEOUT 300)

# No function outside tests/ longer than 120 lines, unless it is a documented hot loop
# (a `/* hot loop: … */` comment on the line before its signature).
add_test(NAME test-long-functions COMMAND python3 ${CMAKE_CURRENT_SOURCE_DIR}/layout/long-functions.py
  ${PROJECT_SOURCE_DIR}/pipeline ${PROJECT_SOURCE_DIR}/daemon ${PROJECT_SOURCE_DIR}/cli ${PROJECT_SOURCE_DIR}/sim
  ${PROJECT_SOURCE_DIR}/drivers ${PROJECT_SOURCE_DIR}/proto ${PROJECT_SOURCE_DIR}/bench)
set_tests_properties(test-long-functions PROPERTIES LABELS unit TIMEOUT 300)
