# Issue #5 acceptance: appearance figures end to end through the impasto binary (sim render →
# process --holdout → compare), and `impasto render` on the resulting copy. The demo test
# leaves its copy in the build tree; the render test uses it through a CTest fixture.
impasto_test(test-appearance-demo LABELS integration TIMEOUT 120)
impasto_test(test-render-cli LABELS integration TIMEOUT 60)
set_tests_properties(test-appearance-demo PROPERTIES FIXTURES_SETUP appearance_copy)
set_tests_properties(test-render-cli PROPERTIES FIXTURES_REQUIRED appearance_copy)
