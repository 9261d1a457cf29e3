# Camera-only calibration, `impasto calibrate camera` (cli/calibrate-camera.c,
# pipeline/calib/calib-camera.c, pipeline/calib/cv/cv-calib-camera.cpp). OpenCV inside, so
# labelled integration, not run under ASan (see calib.cmake) — except the C half:
# image normalisation, a capture set's calibration frame, JSON and rig.json output.
impasto_test(test-calib-camera-io LIBS impasto_pipeline)
if(TARGET impasto_cv)
  # Synthetic corners through imp_cv_calib_camera (intrinsics back within issue #8's limits
  # and 3σ, a mislabelled view rejected, a board seen once) and the command on synthetic
  # PNGs (result, rig.json, exit codes of bad input). A few seconds.
  impasto_test(test-calib-camera LABELS integration stability LIBS impasto_cv impasto_pipeline TIMEOUT 120)
  # The wide-field target set config/scenes/calib-wide-*.cfg rendered and calibrated with
  # the command, against the simulator's truth and its measured noise floor. About 2.5 min
  # on 2 shared cores (20 renders): slow.
  impasto_test(test-calib-camera-sim LABELS slow integration LIBS impasto_pipeline impasto_cv TIMEOUT 900)
endif()
