# `impasto view` (docs/viewer.md) and `impasto export` (docs/export.md).
# The browser test drives Debian's headless chromium (SwiftShader WebGL2) through the
# DevTools protocol against the copy test-appearance-demo leaves behind (CTest fixture);
# it skips (77) only when chromium is not installed.
add_test(NAME test-view-browser
  COMMAND /usr/bin/python3 ${CMAKE_CURRENT_SOURCE_DIR}/view/test-view-browser.py
          ${PROJECT_BINARY_DIR} ${PROJECT_BINARY_DIR}/tests/appearance-small/copy)
set_tests_properties(test-view-browser PROPERTIES LABELS integration SKIP_RETURN_CODE 77 TIMEOUT 600
  FIXTURES_REQUIRED appearance_copy)
impasto_test(test-view-pack LIBS impasto_export)
# Exports read back by libtiff and assimp (skipped from the build without assimp).
pkg_check_modules(ASSIMP IMPORTED_TARGET assimp)
pkg_check_modules(VIPS IMPORTED_TARGET vips)
if(ASSIMP_FOUND)
  impasto_test(test-export LABELS integration LIBS impasto_export PkgConfig::ASSIMP PkgConfig::TIFF TIMEOUT 120)
  if(VIPS_FOUND)
    target_link_libraries(test-export PRIVATE PkgConfig::VIPS)
    target_compile_definitions(test-export PRIVATE IMPASTO_HAVE_VIPS=1)
  endif()
else()
  message(WARNING "impasto: assimp not found: test-export (mesh read-back) is not built")
endif()
impasto_test(test-export-lp LABELS integration LIBS PkgConfig::PNG PkgConfig::TIFF TIMEOUT 120)
set_tests_properties(test-export-lp PROPERTIES FIXTURES_REQUIRED appearance_copy)
