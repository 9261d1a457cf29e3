# BTF samples and per-texel Lafortune fit (pipeline/btf-*.c).
impasto_test(test-btf-samples LIBS impasto_pipeline)
impasto_test(test-btf-fit LIBS impasto_pipeline)
impasto_test(test-btf-stability SOURCE unit/test-btf-stability.c LABELS stability LIBS impasto_pipeline)
impasto_test(test-btf-horizon LIBS impasto_pipeline)
impasto_test(test-btf-band LIBS impasto_pipeline)
impasto_test(test-btf-march LIBS impasto_pipeline)
