# Issue #9: `impasto bench accuracy --quick` end to end (about a minute on 2 cores: one
# rich rendering of the demo-like study scene, then nine processed configurations).
impasto_test(test-accuracy-quick LABELS slow TIMEOUT 900)
