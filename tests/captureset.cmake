# Config, JSON, rig model and capture sets (pipeline/core/conf.c, json-util.c,
# pipeline/model/rig.c, pipeline/model/captureset.c).
impasto_test(test-conf)
impasto_test(test-json-util)
impasto_test(test-rig LIBS impasto_pipeline)
impasto_test(test-captureset LIBS impasto_pipeline)
impasto_test(test-captureset-crash LABELS fault TIMEOUT 60 LIBS impasto_pipeline)
