# Base pieces: errors, logging, image formats, config, JSON, capture sets, rig model.
impasto_test(test-error)
impasto_test(test-numerics)

# The layer rule of docs/layout.md: no lower layer includes a higher layer's header.
add_test(NAME test-layers COMMAND python3 ${CMAKE_CURRENT_SOURCE_DIR}/layout/check-layers.py ${PROJECT_SOURCE_DIR})
set_tests_properties(test-layers PROPERTIES LABELS unit TIMEOUT 300)
