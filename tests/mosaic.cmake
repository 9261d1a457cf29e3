# Registration and mosaic of a whole painting's tiles (pipeline/mosaic/, docs/mosaic.md).
impasto_test(test-mosaic LIBS impasto_mosaic TIMEOUT 300)
