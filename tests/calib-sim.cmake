# Calibration of the simulated demo rig from simulated chessboard targets (issue #8):
# renders config/scenes/target-*.cfg with `impasto sim render`, calibrates with
# `impasto calibrate procam --sets`, compares with the simulator's truth. About 6 minutes
# on 2 cores, mostly rendering: slow. OpenCV inside, so not under ASan (see calib.cmake).
if(TARGET impasto_cv)
  impasto_test(test-calib-sim LABELS slow integration LIBS impasto_pipeline impasto_cv TIMEOUT 900)
endif()
