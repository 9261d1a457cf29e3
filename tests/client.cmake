# The impasto client's daemon commands (against a scripted stand-in daemon), offline plan
# checks, and impasto-worker on a job queue.
if(TARGET impasto AND TARGET impasto_sim)
  impasto_test(test-cli-plan LIBS impasto_sim)
  impasto_test(test-cli-client LIBS impasto_pipeline)
endif()
if(TARGET impasto AND TARGET impasto-worker)
  impasto_test(test-worker LABELS integration LIBS impasto_pipeline)
endif()
