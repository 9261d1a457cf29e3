# Geometry pipeline (issue #4 stages 1, 3, 4, 5): HDR merge, triangulation, heightfield,
# relief boxes, copy-vs-truth comparison; hard numerical cases under the stability label.
impasto_test(test-hdr LIBS impasto_pipeline)
impasto_test(test-triangulate LIBS impasto_pipeline)
impasto_test(test-heightfield LIBS impasto_pipeline)
# The heightfield's parallel parts (row bands, per-thread sums) against one thread.
impasto_test(test-heightfield-bands LIBS impasto_pipeline)
impasto_test(test-boxes LIBS impasto_pipeline)
impasto_test(test-geometry-stability LABELS stability LIBS impasto_pipeline)
# The canvas between paint bars 5 mm high that cut the ground into pockets (relief_pockets):
# kept, with the bars' tops, and no frame (deep or 0.3 mm proud) taken for paint.
impasto_test(test-canvas-relief LIBS impasto_pipeline)
# Heights from positions and normals (pipeline/geometry/fuse.c, Nehab et al. 2005): synthetic
# surfaces with a known answer.
impasto_test(test-fuse LIBS impasto_pipeline)
# The back-off over longer baselines: coherently wrong normals on a ridge's flanks.
impasto_test(test-fuse-segment LIBS impasto_pipeline)
# Gradient rows weighted by their normal's σ (fuse.h row_weight_max).
impasto_test(test-fuse-weights LIBS impasto_pipeline)
# Fusion where the normals are wrong: back-off and the σ of filled texels.
impasto_test(test-fuse-stability LABELS stability LIBS impasto_pipeline)
# Projector-shadow fill (heightfield.h shadow_fill_px, fuse.h mask value 2): synthetic
# canvas in a raised frame with an undecoded strip along one wall.
impasto_test(test-shadow-fill LIBS impasto_pipeline)
# The same end to end on a small rendered scene with a frame and a dome (~10 s).
impasto_test(test-shadow-fill-render LABELS integration LIBS impasto_pipeline TIMEOUT 120)
if(TARGET impasto)
  add_dependencies(test-shadow-fill-render impasto)
endif()
