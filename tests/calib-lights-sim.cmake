# Dome light and radiometric calibration of the simulated rig, end to end:
# renders config/scenes/lights-target{,-mid,-raised}.cfg (the mirror target at 0, 20 and
# 40 mm) and a noisy flat-white, runs `impasto calibrate lights|radiometric` (sphere
# detection, per-light triangulation and the joint refinement, free and dome-constrained,
# .lp export and import), compares with the simulator's truth. About 8 minutes on 2 loaded cores, mostly rendering the
# 3 × 56 light frames at 0.02 mm pitch: slow.
impasto_test(test-calib-lights-sim LABELS slow integration LIBS impasto_pipeline TIMEOUT 1800)
