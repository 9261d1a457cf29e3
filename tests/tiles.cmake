# Tile plans for whole paintings (pipeline/model/tiles.c).
impasto_test(test-tiles LABELS unit LIBS impasto_model)
