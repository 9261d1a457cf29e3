# Hybrid bump / relief-mapping renderer of the digital copy (issue #5 stage 4, seed §5).
impasto_test(test-relief-render LIBS impasto_pipeline)
