# The calibration chain of scripts/demo (docs/calibration.md, "The demo's calibration chain"):
# `impasto calibrate radiometric --rig BASE --out` writes the estimated sensor into a copy of
# BASE (tests/integration/calibrate-rig-chain.sh; a 48-frame 200 × 150 render, a few s).
# `calibrate lights --rig` is checked by test-calib-lights-sim (slow).
add_test(NAME test-calibrate-rig-chain
  COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/calibrate-rig-chain.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
set_tests_properties(test-calibrate-rig-chain PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 60)
# The whole chain of scripts/demo against the simulator's truth (tests/integration/
# calib-chain-sim.sh: `scripts/demo --calibrate-only`, ~6 min rendering the targets, ~2 min
# with IMPASTO_TARGET_CACHE=out/cache/targets): slow.
if(TARGET impasto_cv)
  add_test(NAME test-calib-chain-sim
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/calib-chain-sim.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
  set_tests_properties(test-calib-chain-sim PROPERTIES LABELS "slow;integration" SKIP_RETURN_CODE 77 TIMEOUT 1800)
endif()
