# Simulator interreflection (sim/indirect.c, seed 002 irradiance-vector grids).
impasto_test(test-sim-indirect LABELS unit LIBS impasto_sim)
