# Photometric normal refinement from the dome sweep (pipeline/appearance/photometric.c).
impasto_test(test-photometric LIBS impasto_pipeline)
# Photometric normals outside their model: dark paint, inter-reflection, few lights.
impasto_test(test-photometric-stability LABELS stability LIBS impasto_pipeline)
# What the fit's residuals cannot show: an ambient term under one usable elevation, and
# refined normals biased against the geometric ones.
impasto_test(test-photometric-honest LABELS unit stability LIBS impasto_pipeline)
# σ_n and flags of normals one texel cannot represent (pipeline/appearance/normal-trust.h).
impasto_test(test-normal-trust LABELS unit stability LIBS impasto_pipeline)
# The Lanczos re-read from frames interleaved by light equals the re-read from the frames.
impasto_test(test-photometric-reread LIBS impasto_pipeline)
# Where the normal map puts ridges sharper than a pixel: the re-read's kernel. Renders a
# scene (8 s of CPU in the release build, 144 s under ASan): integration, not in the ASan set.
impasto_test(test-photometric-kernel LABELS integration LIBS impasto_pipeline)
# The photometric texel model against main's copy of it before it was made faster
# (tests/unit/pn-model-peer.c): the same flags, normals within 1e-6 rad.
impasto_test(test-photometric-model LIBS impasto_pipeline)
target_sources(test-photometric-model PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/unit/pn-model-peer.c)
# The re-read's Lanczos weights from one sin and one sincos per axis against the kernel.
impasto_test(test-photometric-lanczos LIBS impasto_pipeline)

# The BTF fit's local frames from the photometric model on its own samples (btf.h
# struct imp_btf_frames, imp_photometric_frames).
impasto_test(test-btf-frames LIBS impasto_pipeline)
