# Whole paintings: the plan's painting group, the simulated gantry (sim/gantry.c), stage
# errors, tile windows, painting.json and the painting-frame truth.
impasto_test(test-painting LABELS unit LIBS impasto_sim)
