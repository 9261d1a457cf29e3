# Simulator: scene model, renderer effects, ground truth, `impasto sim`.
impasto_test(test-sim-radiometry LIBS impasto_sim)
impasto_test(test-sim-shadow LIBS impasto_sim)
impasto_test(test-sim-determinism LIBS impasto_sim)
impasto_test(test-sim-effects LIBS impasto_sim)
impasto_test(test-sim-parse LIBS impasto_sim)
impasto_test(test-sim-cli LABELS integration LIBS impasto_sim)
