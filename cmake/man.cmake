# Man pages and bash completion, each generated from one source:
# - docs/man/NAME.SECTION.md (a small Markdown subset, cmake/md2man.py) → roff; impasto(1)'s
#   command list and impastod(8)'s options come from the built programs' own help;
# - the bash completion (cmake/gen-completion.py) from `impasto help` and each command's --help.
# Both run the built programs, so they are made after them; not when cross-compiling.
find_program(IMPASTO_PYTHON3 python3)
if(NOT IMPASTO_PYTHON3 OR CMAKE_CROSSCOMPILING OR NOT TARGET impasto)
  message(STATUS "impasto: man pages and bash completion OFF (needs python3 and a native build)")
  return()
endif()
set(IMPASTO_MAN_BUILD ${PROJECT_BINARY_DIR}/man)
set(helps --help-of "impasto=$<TARGET_FILE:impasto>")
set(progs impasto)
if(TARGET impastod)
  list(APPEND helps --help-of "impastod=$<TARGET_FILE:impastod>")
  list(APPEND progs impastod)
endif()
set(IMPASTO_MAN_PAGES impasto.1 impastod.8 impastod.conf.5 impasto-capture-set.5 impasto-copy.5)
set(outputs)
foreach(page ${IMPASTO_MAN_PAGES})
  string(REGEX MATCH "[0-9]$" section ${page})
  add_custom_command(OUTPUT ${IMPASTO_MAN_BUILD}/${page}
    COMMAND ${CMAKE_COMMAND} -E make_directory ${IMPASTO_MAN_BUILD}
    COMMAND ${IMPASTO_PYTHON3} ${PROJECT_SOURCE_DIR}/cmake/md2man.py ${PROJECT_SOURCE_DIR}/docs/man/${page}.md
            ${IMPASTO_MAN_BUILD}/${page} --version ${PROJECT_VERSION} ${helps}
    DEPENDS ${PROJECT_SOURCE_DIR}/docs/man/${page}.md ${PROJECT_SOURCE_DIR}/cmake/md2man.py ${progs}
    COMMENT "man page ${page}" VERBATIM)
  list(APPEND outputs ${IMPASTO_MAN_BUILD}/${page})
  install(FILES ${IMPASTO_MAN_BUILD}/${page} DESTINATION ${CMAKE_INSTALL_MANDIR}/man${section})
endforeach()
add_custom_command(OUTPUT ${PROJECT_BINARY_DIR}/completion/impasto
  COMMAND ${CMAKE_COMMAND} -E make_directory ${PROJECT_BINARY_DIR}/completion
  COMMAND ${IMPASTO_PYTHON3} ${PROJECT_SOURCE_DIR}/cmake/gen-completion.py $<TARGET_FILE:impasto>
          ${PROJECT_BINARY_DIR}/completion/impasto
  DEPENDS ${PROJECT_SOURCE_DIR}/cmake/gen-completion.py impasto
  COMMENT "bash completion for impasto" VERBATIM)
add_custom_target(impasto-man ALL DEPENDS ${outputs} ${PROJECT_BINARY_DIR}/completion/impasto)
install(FILES ${PROJECT_BINARY_DIR}/completion/impasto DESTINATION ${CMAKE_INSTALL_DATADIR}/bash-completion/completions)
