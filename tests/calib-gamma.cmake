# The projector's gamma: `impasto calibrate radiometric --projector-set` on a
# flat white board under phase-shift frames, written into a copy of a base rig
# (tests/integration/calibrate-projector-gamma.sh; five 200 × 150 renders, ~10 s; 30-45 s on
# 2 shared cores at load 15, hence the generous timeout).
add_test(NAME test-calibrate-projector-gamma
  COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/calibrate-projector-gamma.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
set_tests_properties(test-calibrate-projector-gamma PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 240)
