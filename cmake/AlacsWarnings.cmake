# Warnings are errors everywhere we own the code. The image kernels and the geometry add
# the conversion family (libcanard's set), where a silent narrowing is a wrong pixel or mm.
set(ALACS_WARNINGS -Wall -Wextra -Wpedantic -Werror -Wshadow -Wnon-virtual-dtor
    -Wold-style-cast -Wcast-align -Wunused -Woverloaded-virtual
    -Wimplicit-fallthrough)
set(ALACS_STRICT_WARNINGS -Wconversion -Wsign-conversion -Wdouble-promotion -Wswitch-enum)
# GCC 12 at -O2/-O3 reports -Wrestrict inside libstdc++ for `"literal" + std::string`
# (GCC bug 105329, fixed in 13): a false positive that -Werror would turn into a failed
# Release build. Only that one warning is relaxed, and only for GCC 12.
if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU" AND CMAKE_CXX_COMPILER_VERSION VERSION_GREATER_EQUAL 12
   AND CMAKE_CXX_COMPILER_VERSION VERSION_LESS 13)
  list(APPEND ALACS_WARNINGS -Wno-restrict)
endif()
# Under ASan+UBSan at -O1 (ALACS_SANITIZE), GCC's -Wmaybe-uninitialized fires inside
# libstdc++ (std::regex in Catch2, std::optional of vectors): false positives of the
# instrumentation. Relaxed there only; the Release build keeps the warning.
if(ALACS_SANITIZE AND CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
  list(APPEND ALACS_WARNINGS -Wno-maybe-uninitialized)
endif()

# alacs_expose_headers(NAME [HEADERS h...]): NAME's own headers, and no others, under an
# include root of its own in the build tree (build/include/NAME/<folder>/<header>, symlinks
# to edge/<folder>/<header>), so that `#include "motion/step_runner.h"` finds the header only
# in a target that links alacs_motion: a component that includes another's header without
# linking it fails to compile. Without HEADERS: every *.h and *.inl in the folders of its
# sources (or of its CMakeLists.txt for a header-only one).
function(alacs_expose_headers name)
  cmake_parse_arguments(ARG "" "" "HEADERS;SOURCES" ${ARGN})
  if(ARG_HEADERS)
    set(headers ${ARG_HEADERS})
  else()
    set(dirs ${CMAKE_CURRENT_SOURCE_DIR})
    if(ARG_SOURCES)
      set(dirs "")
      foreach(src ${ARG_SOURCES})
        get_filename_component(d ${CMAKE_CURRENT_SOURCE_DIR}/${src} DIRECTORY)
        list(APPEND dirs ${d})
      endforeach()
      list(REMOVE_DUPLICATES dirs)
    endif()
    set(headers "")
    foreach(d ${dirs})
      file(GLOB found CONFIGURE_DEPENDS ${d}/*.h ${d}/*.inl)
      list(APPEND headers ${found})
    endforeach()
  endif()
  set(root ${PROJECT_BINARY_DIR}/include/${name})
  file(REMOVE_RECURSE ${root})
  foreach(h ${headers})
    get_filename_component(abs ${h} ABSOLUTE BASE_DIR ${CMAKE_CURRENT_SOURCE_DIR})
    file(RELATIVE_PATH rel ${PROJECT_SOURCE_DIR}/edge ${abs})
    get_filename_component(dir ${root}/${rel} DIRECTORY)
    file(MAKE_DIRECTORY ${dir})
    file(CREATE_LINK ${abs} ${root}/${rel} SYMBOLIC)
  endforeach()
  get_target_property(type ${name} TYPE)
  if(type STREQUAL "INTERFACE_LIBRARY")
    target_include_directories(${name} INTERFACE ${root})
  else()
    target_include_directories(${name} PUBLIC ${root})
  endif()
endfunction()

# alacs_component(NAME SOURCES... [STRICT] [DEPS ...] [PRIVATE_DEPS ...] [HEADERS ...])
function(alacs_component name)
  cmake_parse_arguments(ARG "STRICT" "" "SOURCES;DEPS;PRIVATE_DEPS;HEADERS" ${ARGN})
  add_library(${name} STATIC ${ARG_SOURCES})
  alacs_expose_headers(${name} SOURCES ${ARG_SOURCES} HEADERS ${ARG_HEADERS})
  target_compile_options(${name} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:${ALACS_WARNINGS}> ${ALACS_SANITIZE_OPTIMIZE})
  if(ARG_STRICT)
    target_compile_options(${name} PRIVATE $<$<COMPILE_LANGUAGE:CXX>:${ALACS_STRICT_WARNINGS}>)
  endif()
  target_link_libraries(${name} PUBLIC ${ARG_DEPS} PRIVATE ${ARG_PRIVATE_DEPS})
endfunction()
