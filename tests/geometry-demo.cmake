# Geometry accuracy end to end through the impasto binary (issue #4 acceptance): a reduced
# scene in the fast suite, the full demo scene under `slow`. docs/geometry.md has the figures.
impasto_test(test-geometry-demo LABELS integration LIBS impasto_pipeline ARGS small TIMEOUT 120)
impasto_test(test-geometry-demo-full SOURCE unit/test-geometry-demo.c LABELS slow
             LIBS impasto_pipeline ARGS demo TIMEOUT 1800)
if(TARGET impasto)
  add_dependencies(test-geometry-demo impasto)
  add_dependencies(test-geometry-demo-full impasto)
endif()
