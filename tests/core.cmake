# Base pieces: errors, logging, image formats, config, JSON, capture sets, rig model.
impasto_test(test-error)
