# Image type and its file formats (PNG, TIFF, OpenEXR): round trips and bad input.
impasto_test(test-image)
impasto_test(test-image-bad)
impasto_test(test-image-arena LABELS unit)
