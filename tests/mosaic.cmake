# Registration and mosaic of a whole painting's tiles (pipeline/mosaic/, docs/mosaic.md).
impasto_test(test-mosaic LIBS impasto_mosaic TIMEOUT 300)
# The command as an operator runs it, with the stage-prior figures beside the registered ones.
impasto_test(test-mosaic-cli LIBS impasto_mosaic TIMEOUT 300)
add_dependencies(test-mosaic-cli impasto)
# The simulator's conventions: the painting truth's sample grid; registration on normals when heights are noisy.
impasto_test(test-mosaic-truth LIBS impasto_mosaic TIMEOUT 300)
# Pairs registered on heights, not on a normal map smaller than the heights (rendered copies').
impasto_test(test-mosaic-normals LIBS impasto_mosaic TIMEOUT 300)
# The seam step the output shows (blended copy against truth) beside the copies' disagreement.
impasto_test(test-mosaic-seam LIBS impasto_mosaic TIMEOUT 300)
# The extent covered to its edges with the plan's edge margin; uncovered texels counted by cause.
impasto_test(test-mosaic-coverage LIBS impasto_mosaic TIMEOUT 300)
# Pairs registered on heights low-passed below the detail whose copies depend on the camera's sampling.
impasto_test(test-mosaic-fine LIBS impasto_mosaic TIMEOUT 300)
