# Processing on a real Slurm (docs/scale-out.md): munged, slurmctld and slurmd started by the
# test in its own network namespace, a three-tile batch submitted as a job array with one task
# killed mid-run and retried, the copies compared with local processing byte for byte.
# ~80 s on the shared 2-CPU machine; skipped (77) only when slurm-wlm or munge is missing.
if(TARGET impasto AND TARGET impasto-worker)
  add_test(NAME test-slurm-batch
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/slurm-batch.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR} 3)
  set_tests_properties(test-slurm-batch PROPERTIES LABELS "integration;fault" SKIP_RETURN_CODE 77
    TIMEOUT 300 RUN_SERIAL TRUE)
endif()
# impasto-worker --capture alone (no Slurm needed): killed mid-run, rerun from scratch to the
# reference copy, a finished job rerun as a no-op, a copy under construction locked.
if(TARGET impasto AND TARGET impasto-worker)
  add_test(NAME test-worker-oneshot
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/slurm-worker-oneshot.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
  set_tests_properties(test-worker-oneshot PROPERTIES LABELS "integration;fault" SKIP_RETURN_CODE 77 TIMEOUT 120)
endif()
# impasto-worker --batch --finish (no Slurm needed): the mosaic of a two-tile painting batch
# equals `impasto mosaic` by hand; a failed mosaic fails the batch; one capture: no mosaic.
if(TARGET impasto AND TARGET impasto-worker)
  add_test(NAME test-worker-finish
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/worker-finish.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
  set_tests_properties(test-worker-finish PROPERTIES LABELS "integration" SKIP_RETURN_CODE 77 TIMEOUT 180)
endif()
# A 20-tile painting (5 x 4 tiles of tests/data/worker-painting.cfg) through the one-node Slurm:
# every tile copy and the finish step's mosaic equal local processing's. Several minutes: slow.
if(TARGET impasto AND TARGET impasto-worker)
  add_test(NAME test-slurm-painting
    COMMAND bash ${PROJECT_SOURCE_DIR}/tests/integration/slurm-painting.sh ${PROJECT_BINARY_DIR} ${PROJECT_SOURCE_DIR})
  set_tests_properties(test-slurm-painting PROPERTIES LABELS "integration;slow" SKIP_RETURN_CODE 77
    TIMEOUT 1800 RUN_SERIAL TRUE)
endif()
