# Dome light and radiometric calibration of the simulated rig, end to end (issue #8):
# renders config/scenes/lights-spheres.cfg and a noisy flat-white, runs `impasto calibrate
# lights|radiometric`, compares with the simulator's truth. About 2 minutes on 2 cores,
# mostly rendering the 48 light frames at 0.02 mm pitch: slow.
impasto_test(test-calib-lights-sim LABELS slow integration LIBS impasto_pipeline TIMEOUT 900)
