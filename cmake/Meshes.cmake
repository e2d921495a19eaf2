# The public meshes the shipped scenes, the tests and the benchmarks read are
# made by the build from Debian's packages (libcgal-demo's data set, tetgen)
# into BIOTGRID_MESH_DIR, which the `biotgrid` command searches by default
# (broker/cli/cmd.h, BG_CMD_MESH_FOLDER) and `cmake --install` installs beside
# the scenes. The steps are in cmake/make_meshes.cmake.
option(BIOTGRID_MESHES
       "Make the public meshes from Debian's libcgal-demo and tetgen (the shipped scenes and the tests need them)"
       ON)
set(BIOTGRID_MESH_DIR ${PROJECT_BINARY_DIR}/share/biotgrid/meshes)
set(BIOTGRID_MESH_FILES bunny.mesh bunny-fine.mesh lion-head.off armadillo.off)

if(BIOTGRID_MESHES)
  find_program(BIOTGRID_TETGEN tetgen)
  set(BIOTGRID_CGAL_DATA /usr/share/doc/libcgal-dev/data.tar.gz CACHE FILEPATH
      "libcgal-demo's data set (Debian package libcgal-demo)")
  if(NOT BIOTGRID_TETGEN OR NOT EXISTS ${BIOTGRID_CGAL_DATA})
    message(FATAL_ERROR
      "The public meshes are made from Debian's libcgal-demo (${BIOTGRID_CGAL_DATA}) and tetgen "
      "(found: '${BIOTGRID_TETGEN}'); install them (configs/debian-packages.txt lists every "
      "package), or configure with -DBIOTGRID_MESHES=OFF to build without the meshes (the tests "
      "then need them in BIOTGRID_MESH_PATH).")
  endif()
  set(outputs)
  foreach(f ${BIOTGRID_MESH_FILES})
    list(APPEND outputs ${BIOTGRID_MESH_DIR}/${f})
  endforeach()
  # Remade when the code that writes them changes, not on every relink.
  add_custom_command(OUTPUT ${outputs}
    COMMAND ${CMAKE_COMMAND} -DARCHIVE=${BIOTGRID_CGAL_DATA} -DTETGEN=${BIOTGRID_TETGEN}
            -DBIOTGRID=$<TARGET_FILE:biotgrid> -DOUT_DIR=${BIOTGRID_MESH_DIR}
            -DWORK_DIR=${PROJECT_BINARY_DIR}/mesh-work
            -P ${PROJECT_SOURCE_DIR}/cmake/make_meshes.cmake
    DEPENDS ${PROJECT_SOURCE_DIR}/cmake/make_meshes.cmake ${BIOTGRID_CGAL_DATA}
            ${PROJECT_SOURCE_DIR}/services/bg_mesh_simplify.c
            ${PROJECT_SOURCE_DIR}/services/bg_mesh_io.c ${PROJECT_SOURCE_DIR}/services/bg_mesh.c
    COMMENT "Making the public meshes from libcgal-demo's data set with tetgen"
    VERBATIM)
  add_custom_target(biotgrid_meshes ALL DEPENDS ${outputs})
  add_dependencies(biotgrid_meshes biotgrid)
  include(GNUInstallDirs)
  install(DIRECTORY ${BIOTGRID_MESH_DIR} DESTINATION ${CMAKE_INSTALL_DATADIR}/biotgrid)
endif()
