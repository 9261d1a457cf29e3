# Scan plans from clients: no @include in a plan read as text, and the expansion capped before
# anything is allocated (pipeline/model/plan.c).
impasto_test(test-plan-untrusted LABELS unit fault LIBS impasto_pipeline TIMEOUT 60)
