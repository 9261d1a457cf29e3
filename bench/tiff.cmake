# Capture-frame encoding: impasto's frame writer vs libtiff's own Zstandard encoder on the
# same frames (issue #7; docs/bench-capture.md).
add_executable(bench-tiff bench-tiff.c)
target_link_libraries(bench-tiff PRIVATE impasto_core)
