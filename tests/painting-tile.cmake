# A painting's tile processed as one (pipeline/process-painting.h): no frame search, the
# painting's pitch, copy.json provenance.painting_tile; impasto process and impasto-worker.
if(TARGET impasto AND TARGET impasto-worker)
  impasto_test(test-painting-tile LABELS integration LIBS impasto_pipeline TIMEOUT 300)
endif()
# Hostile painting.json given to impasto mosaic and to impasto process of a tile: refused with
# the file and field, nothing read outside the painting, bounded, a FIFO not waited on.
impasto_test(test-painting-inputs LABELS unit LIBS impasto_mosaic impasto_pipeline)
