# Install rules for what is not a binary: systemd units, sysusers/tmpfiles snippets, the
# default rig config, the plan presets and the operator docs. Paths inside the units and the
# daemon's compiled-in defaults come from the install prefix chosen at configure time
# (-DCMAKE_INSTALL_PREFIX, default /usr/local; a package uses /usr, which puts the config in
# /etc/impasto). docs/install.md describes the result.
set(IMPASTO_CONF_DIR ${CMAKE_INSTALL_FULL_SYSCONFDIR}/impasto)
set(IMPASTO_UNIT_DIR ${CMAKE_INSTALL_PREFIX}/lib/systemd/system)
set(IMPASTO_UNITS_BUILD ${PROJECT_BINARY_DIR}/systemd)

foreach(unit impastod.service impastod.socket impasto-worker@.service impasto.tmpfiles impastod.conf)
  configure_file(${PROJECT_SOURCE_DIR}/systemd/${unit}.in ${IMPASTO_UNITS_BUILD}/${unit} @ONLY)
endforeach()
install(FILES ${IMPASTO_UNITS_BUILD}/impastod.service ${IMPASTO_UNITS_BUILD}/impastod.socket
              ${IMPASTO_UNITS_BUILD}/impasto-worker@.service
        DESTINATION lib/systemd/system)
install(FILES systemd/impasto.sysusers DESTINATION lib/sysusers.d RENAME impasto.conf)
install(FILES ${IMPASTO_UNITS_BUILD}/impasto.tmpfiles DESTINATION lib/tmpfiles.d RENAME impasto.conf)

# Config: the documented rig config (the simulated rig's, to edit for real devices), the
# plan presets in the folder the unit passes as --plan-dir, every example kept alongside.
# rig.cfg is the operator's once edited: installed only where there is none yet (the
# example stays in examples/rigs/sim.cfg).
install(CODE "
  set(rig \"\$ENV{DESTDIR}${IMPASTO_CONF_DIR}/rig.cfg\")
  if(EXISTS \"\${rig}\")
    message(STATUS \"Keeping: \${rig} (the example is examples/rigs/sim.cfg)\")
  else()
    file(INSTALL \"${PROJECT_SOURCE_DIR}/config/rigs/sim.cfg\" DESTINATION \"${IMPASTO_CONF_DIR}\"
         RENAME rig.cfg)
  endif()")
# impastod.conf likewise: the operator's once edited (the example stays in
# examples/impastod.conf).
install(CODE "
  set(conf \"\$ENV{DESTDIR}${IMPASTO_CONF_DIR}/impastod.conf\")
  if(EXISTS \"\${conf}\")
    message(STATUS \"Keeping: \${conf} (the example is examples/impastod.conf)\")
  else()
    file(INSTALL \"${IMPASTO_UNITS_BUILD}/impastod.conf\" DESTINATION \"${IMPASTO_CONF_DIR}\")
  endif()")
install(FILES ${IMPASTO_UNITS_BUILD}/impastod.conf DESTINATION ${CMAKE_INSTALL_SYSCONFDIR}/impasto/examples)
install(DIRECTORY config/plans/ DESTINATION ${CMAKE_INSTALL_SYSCONFDIR}/impasto/plans)
install(DIRECTORY config/ DESTINATION ${CMAKE_INSTALL_SYSCONFDIR}/impasto/examples)
# What Documentation= in the units names.
install(FILES docs/install.md README.md DESTINATION ${CMAKE_INSTALL_DOCDIR})
# impasto(1), impastod(8), impastod.conf(5), the two formats' pages and the bash completion.
include(${CMAKE_CURRENT_LIST_DIR}/man.cmake)

# The daemon's defaults follow the same prefix (daemon/main.c falls back to /usr/... without).
if(TARGET impastod)
  target_compile_definitions(impastod PRIVATE
    IMPASTO_DEFAULT_RIG="${IMPASTO_CONF_DIR}/rig.cfg"
    IMPASTO_DEFAULT_WORKER="${CMAKE_INSTALL_FULL_BINDIR}/impasto-worker"
    IMPASTO_DEFAULT_CLI="${CMAKE_INSTALL_FULL_BINDIR}/impasto"
    IMPASTO_DEFAULT_CONF="${IMPASTO_CONF_DIR}/impastod.conf")
endif()

# The paths above are fixed when configuring: an install to another prefix gets units that
# point at the configured one. Said at install time rather than found by systemd later.
install(CODE "
  if(NOT CMAKE_INSTALL_PREFIX STREQUAL \"${CMAKE_INSTALL_PREFIX}\")
    message(WARNING \"impasto: installing to \${CMAKE_INSTALL_PREFIX}, but the units and impastod's defaults \"
                    \"name ${CMAKE_INSTALL_PREFIX} (configure with -DCMAKE_INSTALL_PREFIX=\${CMAKE_INSTALL_PREFIX})\")
  endif()")
