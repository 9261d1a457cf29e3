# `impasto view` (cli/cmd-view.c): the web page in cli/view/ is embedded in the binary at
# build time (cli/view/embed.cmake writes view-assets.c), so an installed impasto needs no
# data directory and the page always matches the server. libmicrohttpd is optional: without
# it `impasto view` says so and exits.
set(IMPASTO_VIEW_ASSETS
  ${CMAKE_CURRENT_SOURCE_DIR}/view/index.html
  ${CMAKE_CURRENT_SOURCE_DIR}/view/viewer.css
  ${CMAKE_CURRENT_SOURCE_DIR}/view/viewer.js
  ${CMAKE_CURRENT_SOURCE_DIR}/view/render.js
  ${CMAKE_CURRENT_SOURCE_DIR}/view/bench.html
  ${CMAKE_CURRENT_SOURCE_DIR}/view/bench.js
  ${CMAKE_CURRENT_SOURCE_DIR}/view/error.html)
string(REPLACE ";" "|" IMPASTO_VIEW_ASSET_LIST "${IMPASTO_VIEW_ASSETS}")
add_custom_command(
  OUTPUT ${CMAKE_CURRENT_BINARY_DIR}/view-assets.c
  COMMAND ${CMAKE_COMMAND} -DOUT=${CMAKE_CURRENT_BINARY_DIR}/view-assets.c
          "-DFILES=${IMPASTO_VIEW_ASSET_LIST}" -P ${CMAKE_CURRENT_SOURCE_DIR}/view/embed.cmake
  DEPENDS ${IMPASTO_VIEW_ASSETS} ${CMAKE_CURRENT_SOURCE_DIR}/view/embed.cmake
  COMMENT "Embedding the viewer's web page" VERBATIM)
target_sources(impasto PRIVATE ${CMAKE_CURRENT_BINARY_DIR}/view-assets.c)
target_link_libraries(impasto PRIVATE impasto_export)
pkg_check_modules(MHD IMPORTED_TARGET libmicrohttpd)
if(MHD_FOUND)
  target_link_libraries(impasto PRIVATE PkgConfig::MHD)
  target_compile_definitions(impasto PRIVATE IMPASTO_HAVE_MHD=1)
else()
  message(WARNING "impasto: libmicrohttpd not found: `impasto view` is built without its server")
endif()
