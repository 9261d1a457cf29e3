# Projector–camera calibration (pipeline/calib/calib.c, pipeline/calib/cv/cv-calib.cpp).
# All three run OpenCV's calibration code, which trips LeakSanitizer in OpenCV's own
# thread-local caches, so they are labelled integration (not run under ASan in CI).
if(TARGET impasto_cv)
  # The five real captures of kamino410/procam-calibration (tests/../shared/data).
  impasto_test(test-calib-procam LABELS integration LIBS impasto_cv impasto_pipeline TIMEOUT 120)
  # Rendered chessboards seen by a known camera: the intrinsics must come back.
  impasto_test(test-calib-synth LABELS integration LIBS impasto_cv impasto_pipeline TIMEOUT 120)
  # Degenerate view sets: fronto-parallel boards, one view; flags and finite outputs.
  impasto_test(test-calib-stability LABELS integration LIBS impasto_cv impasto_pipeline TIMEOUT 120)
  # Ceres bundle refinement: agrees with OpenCV on clean corners; robust loss and outlier
  # rejection keep fx within 0.1 % with corners moved 20 px; the joint camera + projector
  # refinement recovers a synthetic rig with errors within 3σ over 5 seeds, drops bad
  # projector corners, and falls back when the devices disagree (skips without Ceres).
  impasto_test(test-calib-ceres LABELS integration LIBS impasto_cv impasto_pipeline TIMEOUT 120)
endif()
if(TARGET impasto_cv)
  # The joint camera + projector refinement on degenerate views (fronto-parallel boards, one
  # or two views): flagged, finite, σ covering the truth (skips without Ceres).
  impasto_test(test-calib-joint-stability LABELS stability LIBS impasto_cv impasto_pipeline TIMEOUT 120)
endif()
