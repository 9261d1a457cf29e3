# Dome light and radiometric calibration (pipeline/calib/calib-lights.c, pipeline/calib/calib-radiometric.c,
# issue #8). Synthetic frames made in the tests with the simulator's models; no OpenCV.
impasto_test(test-calib-radiometric LIBS impasto_pipeline TIMEOUT 60)
impasto_test(test-calib-lights LIBS impasto_pipeline TIMEOUT 60)
# Saturated highlights, near-parallel rays: flags, inflated σ, finite outputs.
impasto_test(test-calib-lights-stability LABELS stability LIBS impasto_pipeline TIMEOUT 60)
# Mirror-sphere detection in a max-over-lights image, balls, half balls and caps (analytic).
impasto_test(test-calib-lights-detect LIBS impasto_pipeline TIMEOUT 60)
# Joint refinement of lights and mirror centres on synthetic highlights (no rendering).
impasto_test(test-calib-lights-joint LIBS impasto_pipeline TIMEOUT 60)
# Joint refinement with nearly parallel rays, one height, a light seen once: flags, finite.
impasto_test(test-calib-lights-joint-stability LABELS stability LIBS impasto_pipeline TIMEOUT 60)
