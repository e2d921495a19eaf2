# Makes the public meshes the shipped scenes, tests and benchmarks read, from
# Debian's packages, into OUT_DIR (run by the biotgrid_meshes target with
# cmake -P; see cmake/Meshes.cmake). Nothing here is downloaded and nothing
# is copied into the repository:
#   - the surfaces come from libcgal-demo's data set (ARCHIVE, a .tar.gz);
#   - `biotgrid mesh simplify` (BIOTGRID) makes the smaller surfaces;
#   - tetgen (TETGEN) fills closed surfaces with tetrahedra. Its output is
#     deterministic for a given input and switches, and so is the simplifier,
#     so every build makes the same meshes.
# Each mesh is written under a temporary name and renamed once complete, so
# an interrupted build never leaves half a mesh behind.
foreach(var ARCHIVE TETGEN BIOTGRID OUT_DIR WORK_DIR)
  if(NOT DEFINED ${var})
    message(FATAL_ERROR "make_meshes.cmake: -D${var}=... is required")
  endif()
endforeach()

file(REMOVE_RECURSE ${WORK_DIR})
file(MAKE_DIRECTORY ${WORK_DIR} ${OUT_DIR})
set(sources bunny00 armadillo lion-head)
set(patterns)
foreach(s ${sources})
  list(APPEND patterns data/meshes/${s}.off)
endforeach()
file(ARCHIVE_EXTRACT INPUT ${ARCHIVE} DESTINATION ${WORK_DIR} PATTERNS ${patterns})
foreach(s ${sources})
  if(NOT EXISTS ${WORK_DIR}/data/meshes/${s}.off)
    message(FATAL_ERROR "${ARCHIVE} holds no data/meshes/${s}.off (libcgal-demo changed?)")
  endif()
endforeach()
set(src ${WORK_DIR}/data/meshes)

# Runs a command in WORK_DIR and stops the build with its output if it fails.
function(run what)
  execute_process(COMMAND ${ARGN} WORKING_DIRECTORY ${WORK_DIR}
                  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "making ${what}: `${ARGN}` failed (${rc}):\n${out}${err}")
  endif()
endfunction()

# A closed surface simplified to `vertices` (0: as it is), filled by
# `tetgen -pq<ratio>`, written as MEDIT NAME.mesh.
function(tetrahedralize name surface vertices ratio)
  set(input ${surface})
  if(vertices GREATER 0)
    set(input ${WORK_DIR}/${name}-surface.off)
    run(${name} ${BIOTGRID} mesh simplify ${surface} ${input} --vertices ${vertices})
  else()
    file(COPY_FILE ${surface} ${WORK_DIR}/${name}-surface.off)
    set(input ${WORK_DIR}/${name}-surface.off)
  endif()
  run(${name} ${TETGEN} -pq${ratio} -Q ${input})
  run(${name} ${BIOTGRID} mesh convert ${WORK_DIR}/${name}-surface.1.node
      ${WORK_DIR}/${name}.part.mesh)
  file(RENAME ${WORK_DIR}/${name}.part.mesh ${OUT_DIR}/${name}.mesh)
endfunction()

# A surface simplified to `vertices` (0: copied as it is), as NAME.off.
function(surface name source vertices)
  if(vertices GREATER 0)
    run(${name} ${BIOTGRID} mesh simplify ${source} ${WORK_DIR}/${name}.part.off
        --vertices ${vertices})
  else()
    run(${name} ${BIOTGRID} mesh convert ${source} ${WORK_DIR}/${name}.part.off)
  endif()
  file(RENAME ${WORK_DIR}/${name}.part.off ${OUT_DIR}/${name}.off)
endfunction()

# The Stanford bunny as the editing, dynamics and inversion scenes use it
# (~30k tetrahedra), and a finer one for benchmarks (~200k).
tetrahedralize(bunny ${src}/bunny00.off 1500 2.0)
tetrahedralize(bunny-fine ${src}/bunny00.off 10000 2.0)
# A disk-like surface (one boundary loop) for parameterization.
surface(lion-head ${src}/lion-head.off 0)
# A closed surface for surface editing.
surface(armadillo ${src}/armadillo.off 3000)
file(REMOVE_RECURSE ${WORK_DIR})
