# The hard-case suite (docs/hard-cases.md, docs/copy-quality.md): right, honestly
# uncertain, or refused. The fast part: the deep and the oblique frame and the camera rolled
# 37° (geometry only), strokes of impasto 3.5 mm high whose canvas must be kept (NAME@IOU:
# mask IoU over the measurable canvas; main kept 0.32 of it) and the refusals (invalid
# parameters at load, an implausible placement,
# a defocused projector, whose reason must name the Gray code); the whole suite with
# every stage under `slow` (`impasto bench hard` writes the table).
impasto_test(test-hard-fast SOURCE unit/test-hard-suite.c LABELS stability TIMEOUT 900
             ARGS --no-btf --plan hard-geometry deep-frame oblique-frame rotated-37 impasto-3.5mm@0.65 invalid-k0 invalid-rho
                  invalid-dark-dome tilted-55! defocus!Gray)
# --all: every config/scenes/hard-*.cfg must be listed here.
impasto_test(test-hard-suite LABELS stability slow TIMEOUT 3600
             ARGS --all ambient ambient-weak black-glossy dark-paint deep-frame deep-frame-8mm distortion dropped-frames
                  flush-frame flush-frame-pale grazing-dome high-gain hot-pixels interreflection
                  invalid-dark-dome invalid-dark-projector invalid-k0 invalid-rho oblique-deep oblique-frame
                  oblique-frame-35 oblique-shallow-30 one-light overexposed shallow-frame tilted-10 tilted-25
                  tilted-55! tiny-coverage
                  ambient-dark!projector defocus!Gray distortion-oblique featureless high-relief hot-rotated-37
                  impasto-2mm@0.65 impasto-3.5mm@0.65 impasto-5mm@0.65
                  low-relief mirror-gloss off-centre overexposed-grazing rotated-90 rotated-180 rotated-37
                  tilted-ambient)
if(TARGET impasto)
  add_dependencies(test-hard-fast impasto)
  add_dependencies(test-hard-suite impasto)
endif()
# Placement under a deep box frame on a synthetic range image (no rendering).
impasto_test(test-hard-placement LABELS stability unit LIBS impasto_pipeline)
# σ_h of heights the fusion moved (no rendering).
impasto_test(test-hard-sigma LABELS stability unit LIBS impasto_pipeline)
# Unflagged normals honest on a flush frame with every stage (the rims of relief and of
# flagged regions, normal-trust.h): at most 1 % beyond 3σ_n, none more than 10° off.
impasto_test(test-hard-normals SOURCE unit/test-hard-suite.c LABELS stability TIMEOUT 900 ARGS flush-frame)
if(TARGET impasto)
  add_dependencies(test-hard-normals impasto)
endif()
