# The processing-cost knobs of `impasto process` that `impasto bench accuracy` passes as flags
# (each configuration its own exec'd process), and impasto-worker's worker_build record.
if(TARGET impasto AND TARGET impasto-worker)
  impasto_test(test-worker-process-flags LABELS integration LIBS impasto_pipeline TIMEOUT 120)
endif()
