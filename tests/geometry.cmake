# Geometry pipeline (issue #4 stages 1, 3, 4, 5): HDR merge, triangulation, heightfield,
# relief boxes, copy-vs-truth comparison; hard numerical cases under the stability label.
impasto_test(test-hdr LIBS impasto_pipeline)
impasto_test(test-triangulate LIBS impasto_pipeline)
impasto_test(test-heightfield LIBS impasto_pipeline)
impasto_test(test-boxes LIBS impasto_pipeline)
impasto_test(test-geometry-stability LABELS stability LIBS impasto_pipeline)
# Heights from positions and normals (pipeline/fuse.c, Nehab et al. 2005): synthetic
# surfaces with a known answer.
impasto_test(test-fuse LIBS impasto_pipeline)
