# Calibration of the simulated demo rig from simulated chessboard targets:
# renders config/scenes/target-*.cfg with `impasto sim render`, calibrates with
# `impasto calibrate procam --sets` (with --opencv-only, with --no-joint: each device refined
# alone and stereoCalibrate's pose, then the default joint refinement), compares with the
# simulator's truth. About 9 minutes on 2 idle cores (20 on a loaded machine), mostly
# rendering and reading 588 frames three times: slow. With IMPASTO_TARGET_CACHE=DIR set
# (scripts/demo's out/cache/targets) the renders found there are used instead (~3 minutes).
# OpenCV inside, so not under ASan (see calib.cmake).
if(TARGET impasto_cv)
  impasto_test(test-calib-sim LABELS slow integration LIBS impasto_pipeline impasto_cv TIMEOUT 1800)
endif()
